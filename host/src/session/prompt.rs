//! Waiting for the person at the instrument.
//!
//! Before a prompt the arms are parked at the far end of their working range
//! (θi = θr = the instrument's `arm_max`, 85° on the reference instrument) and stay
//! still until the person is done:
//! - it is the farthest the arms get from the normal, so the space over the port, where
//!   the hands and the tile go, is free, and the arms are as far from each other (and
//!   from a knock) as they can be;
//! - it is next to the home switches (87.5°, beyond the range on the same side), so the
//!   Home of the next lost-steps check starts there and is short;
//! - a heartbeat loss there (a host that stalls, a cable pulled during the prompt) stops
//!   arms that stand still: the firmware keeps the homing (a ramped stop of arms at rest
//!   loses no steps), only the lamp goes off.
//!
//! The lamp stays ON while the person works, kept so by heartbeats. The LED's output
//! depends on its junction temperature: switched off for the minute a person takes and
//! on again, it would come back cooler and brighter and drift for minutes while it warms
//! up, so the white readings would not hold for the sample readings after them, unless
//! every prompt were followed by a warm-up wait. Keeping it on costs nothing but
//! heartbeats, which the host sends anyway. If the instrument stops all the same (a
//! heartbeat loss), the host lights the lamp again and, because its output since is not
//! the calibration's for sure, reads the white tile again at the end (`white-drift`
//! flags it if it did not come back).
use super::recovery::Failure;
use super::{Placement, Session, SessionError};
use crate::instrument::link::Transport;
use protocol::{Command, DeviceMessage, Geometry};
use std::time::Duration;

/// How often the operator is asked whether they are done, on the transport's clock.
const ANSWER_POLL: Duration = Duration::from_millis(100);

impl<T: Transport> Session<'_, T> {
    /// Where the arms wait while the person works.
    pub(super) fn park_geometry(&self) -> Geometry {
        Geometry::new(self.info.arm_max, self.info.arm_max)
    }

    /// Park the arms, ask the operator for `placement`, and keep the instrument alive
    /// (heartbeats, recovery of the link, the lamp lit) until they answer.
    pub(super) fn ask_operator(&mut self, placement: Placement) -> Result<(), SessionError> {
        let park = self.park_geometry();
        self.retrying(Command::MoveTo(park))?;
        let asked_at = self.now();
        let asked_on_device = self.device_now()?;
        self.decide(&format!(
            "asking the operator: {} (arms parked at θi = θr = {}°, clear of the port; lamp kept on)",
            placement.instruction().to_lowercase(),
            park.theta_i.deg()
        ));
        self.operator
            .ask(placement, asked_at)
            .map_err(SessionError::Operator)?;
        loop {
            let now = self.now();
            if self
                .operator
                .answered(now)
                .map_err(SessionError::Operator)?
            {
                break;
            }
            let failure = match self.client.keep_alive(ANSWER_POLL) {
                Ok(()) => self.stop_heard(),
                Err(error) => match super::recovery::classify(error) {
                    Ok(failure) => {
                        if let Failure::Link(crate::instrument::link::LinkError::Io(io)) = &failure
                        {
                            self.link.last_io_error = Some(io.to_string());
                        }
                        Some(failure)
                    }
                    Err(fatal) => return Err(fatal),
                },
            };
            if let Some(failure) = failure {
                self.recover(failure)?;
            }
        }
        let waited = self.now() - asked_at;
        self.clock.waiting_us += waited.as_micros() as u64;
        self.clock.device_waiting_us +=
            (self.device_now()?.saturating_sub(asked_on_device)).as_micros() as u64;
        self.decide(&format!(
            "the operator answered after {:.1} s",
            waited.as_secs_f64()
        ));
        Ok(())
    }

    /// A stop the instrument announced while the host only kept it alive.
    fn stop_heard(&mut self) -> Option<Failure> {
        let mut stop = None;
        while let Ok(Some(message)) = self.client.next_unsolicited(Duration::ZERO) {
            if let DeviceMessage::Stopped { reason } = message {
                stop = Some(Failure::Stopped(reason));
            }
        }
        stop
    }
}
