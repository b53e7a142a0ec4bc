//! The white tile: the calibration (dark, then white at every incidence angle, checked
//! for lost steps while the tile is still on the port), single readings, and the white
//! check at the end.
use super::recovery::{self, Failure};
use super::{Placement, Session, SessionError, steps};
use crate::instrument::calibration::{Calibration, WhitePoint, instrument_name};
use crate::instrument::link::{LinkError, Transport};
use protocol::schedules::INCIDENCE_DEG;
use protocol::{Command, DeviceMessage, ErrorCode, Geometry, Reading, Reply, Target};
use std::time::Duration;

impl<T: Transport> Session<'_, T> {
    pub(super) fn lamp_on(&mut self) -> Result<(), SessionError> {
        self.retrying(Command::SetLamp { on: true }).map(|_| ())
    }

    /// Dark per range (lamp off), then the white tile at θr = 0 for every incidence angle,
    /// then a lost-steps check while the tile is still on the port (the white readings
    /// are taken again at once if an arm was off: see [`steps`]).
    pub(super) fn calibrate(&mut self) -> Result<(), SessionError> {
        self.recorder
            .stage("dark and white calibration", INCIDENCE_DEG.len());
        let integration_ms = self.plan.integration_ms;
        self.link.lamp_wanted = false;
        let Reply::Dark(dark) = self.retrying(Command::TakeDark { integration_ms })? else {
            return Err(SessionError::Fit("unexpected dark reply".into()));
        };
        self.link.lamp_wanted = true;
        self.lamp_on()?;
        self.ask_operator(Placement::WhiteTile)?;
        let mut white = Vec::new();
        for attempt in 1..=steps::MAX_CHECK_ROUNDS {
            let slips_before = self.steps.slips;
            white.clear();
            for theta_i in INCIDENCE_DEG {
                let reading =
                    self.reading_at(Geometry::from_whole_deg(theta_i, 0), Target::WhiteReference)?;
                white.push(WhitePoint {
                    theta_i_deg: f64::from(theta_i),
                    reading,
                });
            }
            self.check_steps("after the white calibration")?;
            if self.steps.slips == slips_before {
                break;
            }
            if attempt == steps::MAX_CHECK_ROUNDS {
                return Err(SessionError::GaveUp(format!(
                    "an arm lost steps during each of {attempt} white calibrations: the instrument needs attention (see the decisions)"
                )));
            }
            self.decide("the white readings were taken while an arm was off its step count: taking them again (the tile is still on the port)");
        }
        self.ask_operator(Placement::Sample)?;
        let gains = self
            .info
            .detector_ranges
            .iter()
            .map(|r| f64::from(r.relative_gain))
            .collect();
        let calibration = Calibration::new(
            instrument_name(&self.info),
            self.given.tile.clone(),
            gains,
            dark.to_vec(),
            white,
        );
        self.recorder
            .calibration(&calibration)
            .map_err(SessionError::record)?;
        self.calibration = Some(calibration);
        Ok(())
    }

    /// Move to `geometry` and take one reading there. After any recovery the move is made
    /// again: a recovery may have re-homed the arms. The reading is kept only if the lamp
    /// is still on after it (see [`Session::lamp_went_out`]).
    pub(super) fn reading_at(
        &mut self,
        geometry: Geometry,
        target: Target,
    ) -> Result<Reading, SessionError> {
        let integration_ms = self.plan.integration_ms;
        for _ in 0..recovery::MAX_RECOVERIES {
            let recoveries = self.link.recoveries.state_recoveries;
            self.retrying(Command::MoveTo(geometry))?;
            let reply = self.retrying(Command::TakeReading {
                integration_ms,
                target,
                range: None,
            })?;
            if let Some(failure) = self.lamp_went_out()? {
                self.recover(failure)?;
                continue;
            }
            if self.link.recoveries.state_recoveries != recoveries {
                continue;
            }
            return match reply {
                Reply::Reading(reading) => Ok(reading),
                other => Err(LinkError::UnexpectedReply {
                    command: "TakeReading",
                    reply: Box::new(other),
                }
                .into()),
            };
        }
        Err(SessionError::GaveUp(format!(
            "no reading at θi = {}°, θr = {}° after {} recoveries",
            geometry.theta_i.deg(),
            geometry.theta_r.deg(),
            recovery::MAX_RECOVERIES
        )))
    }

    /// Whether the instrument stopped on its own without the host hearing it in time: a
    /// `Stopped` waiting in the queue, or the status showing the lamp off while the session
    /// needs it. A fail-safe stop of arms at rest keeps the homing and leaves the device
    /// idle, so it carries out the next command with the lamp off; a reading taken then is
    /// dark, and the `Stopped` that says so may be lost on the link. So the lamp is checked
    /// after every single reading and around every schedule.
    pub(super) fn lamp_went_out(&mut self) -> Result<Option<Failure>, SessionError> {
        let mut stopped = None;
        while let Ok(Some(message)) = self.client.next_unsolicited(Duration::ZERO) {
            if let DeviceMessage::Stopped { reason } = message {
                stopped = Some(reason);
            }
        }
        if let Some(reason) = stopped {
            return Ok(Some(Failure::Stopped(reason)));
        }
        if !self.link.lamp_wanted {
            return Ok(None);
        }
        let status = self.status()?;
        Ok((!status.lamp_on)
            .then(|| Failure::Stopped(status.fault.unwrap_or(ErrorCode::HeartbeatLost))))
    }

    /// Re-read the white tile at every calibrated incidence angle (θr = 0) and compare
    /// with the calibration: the drift is the mean ratio's departure from 1. One reading
    /// against one would carry the noise of both (about 0.14 % at 100 ms), a third of the
    /// default 0.5 % limit; the mean over the calibration's incidence angles (four on the
    /// reference instrument) halves it, so a flag means a lamp that drifted, not a noisy
    /// pair.
    pub(super) fn white_check(&mut self) -> Result<(Option<f64>, bool), SessionError> {
        self.ask_operator(Placement::WhiteTile)?;
        let mut ratios = Vec::new();
        for theta_i in INCIDENCE_DEG {
            let reading =
                self.reading_at(Geometry::from_whole_deg(theta_i, 0), Target::WhiteReference)?;
            let calibration = self
                .calibration
                .as_ref()
                .ok_or(SessionError::Fit("no calibration".into()))?;
            let (r, _) = calibration.radiance_factor(f64::from(theta_i), &reading)?;
            ratios.push(r / calibration.white_radiance_factor);
        }
        let drift = ratios.iter().sum::<f64>() / ratios.len().max(1) as f64 - 1.0;
        // A drift or a limit that is not a number is no proof of a steady lamp.
        let exceeded = !matches!(
            drift.abs().partial_cmp(&self.plan.white_drift_limit),
            Some(std::cmp::Ordering::Less | std::cmp::Ordering::Equal)
        );
        if exceeded {
            self.decide(&format!(
                "white drifted by {:.2} % (limit {:.2} %): result flagged white-drift",
                100.0 * drift,
                100.0 * self.plan.white_drift_limit
            ));
        } else {
            self.decide(&format!(
                "white check: drift {:.3} % (limit {:.2} %)",
                100.0 * drift,
                100.0 * self.plan.white_drift_limit
            ));
        }
        Ok((Some(drift), exceeded))
    }
}
