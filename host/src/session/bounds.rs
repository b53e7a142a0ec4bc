//! The bounds on one run of a session: re-measure rounds and device time (the folder's
//! size is bounded where it is written, [`crate::output::folder::record`]). Every loop of the
//! session already ends when it stops making progress (six rounds without a reading, eight
//! recoveries in a row); these end the loops that make progress that never adds up to a
//! result: a link that loses a reading in every round, a calibration that converts no
//! reading, so that the same stretch is measured again and again (issue 30 D4: "round
//! 901", 473 MB in 120 s). A bound hit stops the session on the fail-safe path (arms
//! stopped, lamp off, every reading kept), says which bound in `session.json` and
//! `session.log`, and prints the command that resumes: a resume is a new run with its own
//! bounds, for after the cable, the instrument or the file has been seen to.
use super::{Session, SessionError};
use crate::instrument::link::Transport;
use std::time::Duration;

/// Re-measure rounds in one run: each round of a stage after its first (geometries or
/// stretches of a sweep lost on the link, superseded or left without a usable bin). A
/// fault-free session makes none or one. Measured in process on G (`gonio measure --sim G
/// --spots 1 --faults …`, six seeds each): with the reliability campaign's faults (corrupt
/// 0.003, drop 0.01, an unplug) at most 5 (sweep), 4 (adaptive), 10 (paper, one stage per
/// δ); with the pty faults (corrupt 0.0068, drop 0.0132) at most 15 (paper); at
/// corrupt 0.01 and drop 0.02, 13–23 (paper). Forty is well above every one of them; the
/// loop of issue 30 D4 was at round 901.
pub const MAX_REMEASURE_ROUNDS: u32 = 40;

/// Device time of one run, seconds, at an integration time of 100 ms or less (waiting
/// for the operator left out): the longest fault-free session of docs/TRADE.md is the
/// paper's policy on G, 73.6 s (Strategy 2 down to δ = 1°, 103 geometries); the worst
/// fault of the reliability campaign costs 74 s more; a lost-steps re-measurement can
/// double the readings. 600 s is four times that sum. A link that loses 2 % of its frames
/// and corrupts 1 % of its bytes once reached it with the sweep policy (G, 6 seeds of 6:
/// about 260 stretches measured again each on its own, each lost sweep end waited 5 s
/// for); with nearby stretches swept as one the same sessions take 46–56 s (issue 30).
/// A link worse than that stops here, saying so, and a resume on a mended link goes on.
pub const MAX_DEVICE_SECONDS: f64 = 600.0;

/// [`MAX_DEVICE_SECONDS`] for `integration_ms`: readings take longer in proportion above
/// 100 ms.
pub fn device_seconds_limit(integration_ms: u16) -> f64 {
    MAX_DEVICE_SECONDS * (f64::from(integration_ms) / 100.0).max(1.0)
}

/// What the run has spent against its bounds.
#[derive(Default)]
pub(super) struct Tally {
    /// Re-measure rounds so far.
    pub(super) rounds: u32,
    /// When the run's device time began (after the resumed readings' marks).
    pub(super) started: Option<Duration>,
    /// A device-time limit other than [`device_seconds_limit`]'s (the tests').
    pub(super) device_limit_s: Option<f64>,
}

impl<T: Transport> Session<'_, T> {
    /// One more re-measure round (`what`, for the record); stops the session past
    /// [`MAX_REMEASURE_ROUNDS`]. The device time is checked too.
    pub(super) fn remeasure_round(&mut self, what: &str) -> Result<(), SessionError> {
        self.bounds.rounds += 1;
        if self.bounds.rounds > MAX_REMEASURE_ROUNDS {
            let text = format!(
                "stopped at the bound on re-measure rounds: {MAX_REMEASURE_ROUNDS} rounds of measuring again in this run (the last: {what}), more than any session needs: the link or the instrument is failing, or the readings cannot be converted with the calibration; every reading so far is kept"
            );
            self.decide(&text);
            return Err(SessionError::Bound(text));
        }
        self.within_device_time()
    }

    /// Stops the session once its device time (waiting for the operator left out) passes
    /// [`device_seconds_limit`].
    pub(super) fn within_device_time(&mut self) -> Result<(), SessionError> {
        let Some(started) = self.bounds.started else {
            return Ok(());
        };
        let spent =
            self.now().saturating_sub(started).as_secs_f64() - self.clock.waiting_us as f64 * 1e-6;
        let limit = self
            .bounds
            .device_limit_s
            .unwrap_or_else(|| device_seconds_limit(self.plan.integration_ms));
        if spent > limit {
            let text = format!(
                "stopped at the bound on device time: {spent:.0} s in this run (waiting for the operator left out), past the limit of {limit:.0} s at {} ms integration, more than any session needs: the link or the instrument is failing; every reading so far is kept",
                self.plan.integration_ms
            );
            self.decide(&text);
            return Err(SessionError::Bound(text));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::instrument::link::{Client, RetryPolicy};
    use crate::instrument::sim::SimOptions;
    use crate::session::{
        DiscardRecorder, Plan, Policy, PolicyChoice, Session, SessionError, SimulatedOperator,
    };

    /// A session past its device-time bound stops with the bound named, rather than run on
    /// (issue 30 D4). The limit is made small here; the real one is ten minutes.
    #[test]
    fn a_session_past_its_device_time_stops_saying_so() {
        let instrument = SimOptions::default().instrument("G").expect("sim");
        let mut client = Client::new(instrument, RetryPolicy::default());
        let info = client.hello().expect("hello");
        let plan = Plan {
            sample: "G".into(),
            integration_ms: info.default_integration_ms,
            policy: Policy::from(PolicyChoice::Paper),
            acceptance_deg: f64::from(info.acceptance_deg),
            white_check: false,
            white_drift_limit: 0.005,
        };
        let (mut recorder, mut operator) = (DiscardRecorder, SimulatedOperator);
        let mut session = Session::new(&mut client, info, plan, &mut recorder, &mut operator);
        session.bounds.device_limit_s = Some(5.0);
        match session.run() {
            Err(SessionError::Bound(text)) => {
                assert!(text.contains("bound on device time"), "{text}")
            }
            Err(e) => panic!("stopped otherwise: {e}"),
            Ok(_) => panic!("a session past its device-time bound finished"),
        }
    }
}

/// Bytes a session's folder may hold. A finished sweep session of G holds 2.5 MB (1,400
/// bins: `points.jsonl` 0.54 MB, `session.json` 0.76 MB, the report and plots); the whole
/// plane is about 2,800 bins, and lost steps can have much of it measured again: about
/// 10 MB at most. 64 MiB is six times that; the loop of issue 30 D4 wrote 473 MB in 120 s.
pub const MAX_FOLDER_BYTES: u64 = 64 << 20;

/// The folder reached [`MAX_FOLDER_BYTES`]: what a recorder's write fails with (as the
/// payload of an [`std::io::Error`]), and the session stops on it.
#[derive(Debug)]
pub struct FolderFull {
    /// The folder's size, bytes.
    pub bytes: u64,
}

impl std::fmt::Display for FolderFull {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "stopped at the bound on the folder's size: it holds {:.1} MiB, past the limit of {} MiB, more than any session needs: the session is measuring the same readings again and again; every reading so far is kept",
            self.bytes as f64 / f64::from(1u32 << 20),
            MAX_FOLDER_BYTES >> 20
        )
    }
}

impl std::error::Error for FolderFull {}
