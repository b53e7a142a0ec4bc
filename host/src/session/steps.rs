//! Lost steps: the arms' step counts checked against the home switches.
//!
//! A stepper that stalls (a snag, a driver fault, a knock on the arm) loses steps without
//! telling anyone: the firmware believes the arm is where it sent it, and every reading
//! after that is at another geometry than the one recorded. On G a 40-step (0.5°) slip
//! gave σ = 0.72° instead of 0.80° and ρs 48 instead of 57, "class G, 100 %", exit 0.
//!
//! The only witness is the home switch: a `Home` finds where the switch trips and reports
//! how far that is from where the step count put it ([`protocol::HomeReport`]). Every Home
//! of a session is therefore a check:
//! - before the report (the check every session pays: its cost is in docs/TRADE.md);
//! - after the white calibration, while the tile is still on the port, so that white
//!   readings taken with an arm off are taken again without asking the operator;
//! - whenever a recovery homes again, and at the start of a resumed session.
//!
//! A check that finds an arm off by more than [`STEP_TOLERANCE_TICKS`] supersedes every
//! reading taken since the last good check (kept in the record, marked, left out of the
//! fit), the Home has put the count right, the session measures those geometries again
//! and checks again. The result is flagged `lost-steps` even when every number was
//! measured again: the numbers are then right, but the instrument slipped and needs
//! attention. A Home whose report was lost with the link, or an instrument that
//! restarted (no count to compare), cannot vouch for the readings since the last check:
//! they are measured again too, without the flag (nothing was found wrong).
use super::{Session, SessionError, StepError};
use crate::analysis::flags::Flag;
use crate::instrument::link::Transport;
use protocol::{Command, ErrorCode, HomeReport, Reply};
use serde::Serialize;

/// Step errors up to this many microsteps (0.05°) are the switch's own repeatability,
/// not lost steps. The slow re-approach locates the trip to 0.2 microstep and a
/// mechanical switch repeats to a few more; a stalled stepper loses whole steps, 16
/// microsteps (0.2°) at the least, so a real slip is well beyond it.
pub const STEP_TOLERANCE_TICKS: i32 = 4;

/// Checks before the report (and white calibrations) in a row that may find lost steps
/// before the session stops re-measuring and reports the result flagged.
pub(super) const MAX_CHECK_ROUNDS: u32 = 3;

/// One Home of the session and what it found.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StepCheck {
    /// When in the session ("before the report", "on re-homing", …).
    pub when: String,
    /// Source arm: switch minus step count at the trip, microsteps; `None`: nothing to
    /// compare (the first homing since power-up).
    pub step_error_i: Option<i32>,
    /// Detector arm: likewise.
    pub step_error_r: Option<i32>,
    /// Device time the Home took, seconds.
    pub device_seconds: f64,
    /// An arm was off by more than [`STEP_TOLERANCE_TICKS`].
    pub lost_steps: bool,
    /// Readings it superseded.
    pub superseded: usize,
}

/// The session's bookkeeping of checks.
#[derive(Debug, Default)]
pub(super) struct StepState {
    /// `points[..checked_upto]` were taken before the last good check (or are
    /// superseded): every later one is not vouched for yet.
    pub(crate) checked_upto: usize,
    /// Lost steps found, or checks that could not be made, so far.
    pub slips: u32,
    /// A Home was sent and its report not received yet.
    pub(crate) home_in_flight: bool,
    /// The arms were homed in this session (a later Home without a count to compare
    /// means the instrument restarted).
    pub(crate) homed_once: bool,
    /// The last fault of the instrument already told in a decision.
    pub(crate) fault_reported: Option<ErrorCode>,
    /// Every Home.
    pub checks: Vec<StepCheck>,
}

impl<T: Transport> Session<'_, T> {
    /// One Home, its report taken as a check.
    pub(super) fn home(&mut self, when: &str) -> Result<(), StepError> {
        self.recorder.stage("homing", 0);
        self.steps.home_in_flight = true;
        let started = self.now();
        match self.request(Command::Home)? {
            Reply::Homed(report) => {
                let took = (self.now() - started).as_secs_f64();
                self.on_home_report(report, when, took)
                    .map_err(StepError::Fatal)
            }
            other => Err(StepError::Fatal(
                crate::instrument::link::LinkError::UnexpectedReply {
                    command: "Home",
                    reply: Box::new(other),
                }
                .into(),
            )),
        }
    }

    /// Check the arms for lost steps now (a Home, through failures). Returns whether they
    /// were clean: no slip found, and every check since the call could be made.
    pub(super) fn check_steps(&mut self, when: &str) -> Result<bool, SessionError> {
        let slips = self.steps.slips;
        for _ in 0..super::recovery::MAX_RECOVERIES {
            match self.home(when) {
                Ok(()) => return Ok(self.steps.slips == slips),
                Err(StepError::Failure(failure)) => self.recover(failure)?,
                Err(StepError::Fatal(error)) => return Err(error),
            }
        }
        Err(SessionError::GaveUp(format!(
            "the lost-steps check {when} could not be made after {} recoveries",
            super::recovery::MAX_RECOVERIES
        )))
    }

    /// What a Home found.
    fn on_home_report(
        &mut self,
        report: HomeReport,
        when: &str,
        took_s: f64,
    ) -> Result<(), SessionError> {
        self.steps.home_in_flight = false;
        // A Home clears the instrument's fault: a later one is a new stop.
        self.steps.fault_reported = None;
        let arms = [
            ("source", report.step_error_i),
            ("detector", report.step_error_r),
        ];
        let lost: Vec<(&str, i32)> = arms
            .iter()
            .filter_map(|&(arm, e)| {
                e.filter(|e| e.abs() > STEP_TOLERANCE_TICKS)
                    .map(|e| (arm, e))
            })
            .collect();
        let unknown = arms.iter().any(|(_, e)| e.is_none());
        let mut check = StepCheck {
            when: when.to_string(),
            step_error_i: report.step_error_i,
            step_error_r: report.step_error_r,
            device_seconds: took_s,
            lost_steps: !lost.is_empty(),
            superseded: 0,
        };
        if !lost.is_empty() {
            self.flags.insert(Flag::LostSteps);
            self.steps.slips += 1;
            let words: Vec<String> = lost
                .iter()
                .map(|(arm, e)| {
                    let deg = f64::from(*e) * protocol::Angle::RESOLUTION_DEG;
                    let sense = if *e < 0 { "short of" } else { "beyond" };
                    format!(
                        "the {arm} arm stood {} steps ({:.3}°) {sense} its step count",
                        e.abs(),
                        deg.abs()
                    )
                })
                .collect();
            let words = words.join(" and ");
            check.superseded =
                self.supersede_since_check(&format!("lost steps {when}: {words}"))?;
            self.decide(&format!(
                "LOST STEPS found {when}: {words}; re-homed; {} readings taken since the last good check are superseded and measured again; the result is flagged lost-steps",
                check.superseded
            ));
        } else if unknown && self.steps.homed_once {
            self.steps.slips += 1;
            check.superseded = self.supersede_since_check(&format!(
                "the instrument restarted: no step count to check {when}"
            ))?;
            self.decide(&format!(
                "the instrument has no step count to compare {when} (it restarted): the {} readings since the last check cannot be vouched for; superseded and measured again",
                check.superseded
            ));
        } else if unknown && self.steps.checked_upto < self.points.len() {
            // The first homing of a resumed session on an instrument that restarted since.
            self.decide(&format!(
                "the instrument restarted since the {} earlier readings were taken: they cannot be checked for lost steps (kept)",
                self.points.len() - self.steps.checked_upto
            ));
            self.steps.checked_upto = self.points.len();
        } else {
            self.steps.checked_upto = self.points.len();
            if !unknown {
                self.decide(&format!(
                    "lost-steps check {when}: source {} steps, detector {} steps off (tolerance {STEP_TOLERANCE_TICKS}); {:.1} s",
                    report.step_error_i.unwrap_or(0),
                    report.step_error_r.unwrap_or(0),
                    took_s
                ));
            }
        }
        self.steps.homed_once = true;
        self.steps.checks.push(check);
        Ok(())
    }

    /// A Home's report was lost: the readings since the last check are not vouched for.
    pub(super) fn steps_unverified(&mut self, why: &str) -> Result<(), SessionError> {
        self.steps.home_in_flight = false;
        if !self.steps.homed_once {
            // The first homing since power-up: it had no count to compare anyway.
            self.steps.homed_once = true;
            return Ok(());
        }
        self.steps.slips += 1;
        let superseded = self.supersede_since_check(why)?;
        self.decide(&format!("{why}: the {superseded} readings since the last check cannot be vouched for; superseded and measured again"));
        Ok(())
    }

    /// Mark every reading since the last good check superseded; returns how many.
    fn supersede_since_check(&mut self, why: &str) -> Result<usize, SessionError> {
        let from = self.steps.checked_upto.min(self.points.len());
        let superseded = self.supersede(from, |_| true, why)?;
        self.steps.checked_upto = self.points.len();
        Ok(superseded)
    }

    /// Mark every reading of schedule `schedule_id` superseded; returns how many.
    pub(super) fn supersede_schedule(
        &mut self,
        schedule_id: u16,
        why: &str,
    ) -> Result<usize, SessionError> {
        self.supersede(0, |p| p.schedule_id == schedule_id, why)
    }

    /// Mark the readings from index `from` on that `which` selects superseded, and tell the
    /// recorder; returns how many.
    fn supersede(
        &mut self,
        from: usize,
        which: impl Fn(&super::MeasuredPoint) -> bool,
        why: &str,
    ) -> Result<usize, SessionError> {
        let mut marked = Vec::new();
        let from = from.min(self.points.len());
        for point in &mut self.points[from..] {
            if !point.superseded && which(point) {
                point.superseded = true;
                marked.push(point.clone());
            }
        }
        if !marked.is_empty() {
            self.recorder
                .superseded(&marked, why)
                .map_err(SessionError::record)?;
        }
        Ok(marked.len())
    }
}
