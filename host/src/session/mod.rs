//! The measurement session: one state machine from connection to report.
//!
//! Home → dark → white (the operator places the tile) → lost-steps check → Strategy 1 on
//! the instrument → fit and σ_l check → refinements by the chosen policy, sending only
//! geometries not yet measured → lost-steps check → classification → optional white
//! check. Every reading is handed to the [`Recorder`] as it arrives, so nothing measured is
//! lost; a session can start from readings already taken ([`Session::resume_from`]) and
//! then measures only what is missing.
//!
//! The bench is not kind to it, and it carries on through what a bench does:
//! - a person at a prompt for minutes ([`prompt`]): the arms are parked, the lamp kept on
//!   and the instrument kept alive by heartbeats;
//! - a link that corrupts, drops or is pulled out ([`recovery`]): after any reconnection
//!   and any refusal the instrument's state is read and brought back to a known one
//!   before anything else is sent; a silent instrument is given up after 10 s;
//! - arms that slip ([`steps`]): a Home before the report compares the switches with the
//!   step counts; readings taken while an arm was off are superseded and measured again,
//!   and the result is flagged.
//!
//! Every decision goes through [`Recorder::decision`], on the failure path too.

pub mod adaptive;
pub mod bounds;
pub mod characterize;
pub mod gains;
pub mod multi_spot;
pub mod operator;
pub mod order;
mod prompt;
mod recovery;
mod refining;
pub mod saturation;
mod schedule;
mod steps;
pub mod sweep_bins;
pub mod sweep_policy;
mod white;

pub use operator::{
    DelayedOperator, Operator, Placement, PromptOperator, SimulatedOperator, WallClockOperator,
    ask_lay,
};
pub use steps::{STEP_TOLERANCE_TICKS, StepCheck};

use crate::analysis::fit::{FitOptions, Observation, SharedError};
use crate::analysis::flags::Flag;
use crate::analysis::model;
use crate::analysis::result::{Readings, Report, analyse_with_shared, to_json};
use crate::analysis::sweep_design;
use crate::instrument::calibration::{Calibration, CalibrationError, Tile, unix_now_s};
use crate::instrument::link::{Client, LinkError, Transport};
use crate::instrument::profile::ProfileInUse;
use adaptive::AdaptiveTargets;
use order::Motion;
use protocol::schedules::{strategy1, strategy2};
use protocol::{DeviceInfo, ErrorCode, Geometry, Reading};
use recovery::Failure;
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::time::Duration;

/// How refinements are chosen, on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum PolicyChoice {
    /// The paper's (Fig. 10): Strategy 2 with decreasing δ (10°, 9°, … 1°) until σ > σ_l.
    Paper,
    /// Batches chosen from the current fit where they shrink σ's uncertainty the most per
    /// second, until σ is within ±3 % (95 %), the class is settled and σ > σ_l.
    Adaptive,
    /// Sweeps only: θr 0…70° at θi = 20° and 60° at full speed, then sweeps across the
    /// specular peak chosen by the information they bring per second, until the adaptive
    /// policy's targets (and the rest of the full plane where the fit lacks fit).
    Sweep,
    /// The adaptive policy with sweeps across the specular peak as candidates next to its
    /// batches of point readings: each round measures whichever is predicted to shrink σ's
    /// variance more per device second.
    Mixed,
}

impl PolicyChoice {
    /// Its name on the command line, in session.json and the studies' files.
    pub fn name(self) -> &'static str {
        match self {
            PolicyChoice::Paper => "paper",
            PolicyChoice::Adaptive => "adaptive",
            PolicyChoice::Sweep => "sweep",
            PolicyChoice::Mixed => "mixed",
        }
    }
}

impl From<PolicyChoice> for Policy {
    fn from(choice: PolicyChoice) -> Policy {
        match choice {
            PolicyChoice::Paper => Policy::Paper,
            PolicyChoice::Adaptive => Policy::Adaptive(AdaptiveTargets::default()),
            PolicyChoice::Sweep => Policy::Sweep(sweep_policy::SweepTargets::default()),
            PolicyChoice::Mixed => Policy::Mixed(
                AdaptiveTargets::default(),
                sweep_policy::SweepTargets::default(),
            ),
        }
    }
}

/// What the session measures after (or instead of) Strategy 1.
#[derive(Clone, Debug, PartialEq)]
pub enum Policy {
    /// The paper's: Strategy 1, then Strategy 2 with decreasing δ until σ > σ_l.
    Paper,
    /// Strategy 1, then batches by sequential design ([`crate::session::adaptive`]).
    Adaptive(AdaptiveTargets),
    /// One fixed schedule and nothing else (the trade study's Strategy 1 at M, Strategy 2 at δ).
    Fixed(FixedSchedule),
    /// A first pass of sweeps, then sweeps across the peak ([`crate::analysis::sweep_design`], [`sweep_policy`]).
    Sweep(sweep_policy::SweepTargets),
    /// Strategy 1, then the adaptive policy's batches or sweeps across the peak (at the
    /// sweep targets' speeds), whichever brings more per device second.
    Mixed(AdaptiveTargets, sweep_policy::SweepTargets),
}

/// A schedule of the method, measured alone.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FixedSchedule {
    /// Strategy 1 with M geometries (Table 4).
    Strategy1 {
        /// M.
        m: u16,
    },
    /// Strategy 2 at δ (Table 5).
    Strategy2 {
        /// δ, degrees.
        delta_deg: u8,
    },
}

impl FixedSchedule {
    /// Its geometries, in the order the paper lists them; empty for an M or δ it lacks.
    pub fn geometries(self) -> Vec<Geometry> {
        let s = match self {
            FixedSchedule::Strategy1 { m } => strategy1(m),
            FixedSchedule::Strategy2 { delta_deg } => strategy2(delta_deg),
        };
        s.map(|s| s.to_vec()).unwrap_or_default()
    }
}

/// What the session is asked to do.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Sample name for the report and files.
    pub sample: String,
    /// Integration time of every reading.
    pub integration_ms: u16,
    /// What to measure after Strategy 1.
    pub policy: Policy,
    /// Detector acceptance to model in the fit, degrees (from the handshake by default).
    pub acceptance_deg: f64,
    /// Re-read the white tile at the end (every calibrated incidence angle) and report the
    /// drift.
    pub white_check: bool,
    /// White drift beyond which the result is marked, as a fraction.
    pub white_drift_limit: f64,
}

/// Decimals of a degree a computed angle is recorded to (a sweep's bin's θr and travel,
/// the angles of readings.csv): a ten-thousandth of a degree is far below the motors'
/// microstep (0.0125°), the arm zero's uncertainty and the bins' lag correction, and the
/// arithmetic of a bin's centre leaves float noise beyond it (`0.09999999999999432` for 0.1).
const ANGLE_DECIMALS: i32 = 4;

/// An angle, degrees, as it is recorded: rounded to [`ANGLE_DECIMALS`] (−0 as 0).
pub(crate) fn recorded_angle(deg: f64) -> f64 {
    let scale = 10f64.powi(ANGLE_DECIMALS);
    (deg * scale).round() / scale + 0.0
}

/// One measured geometry, as recorded.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeasuredPoint {
    /// Incidence angle reached, degrees.
    pub theta_i_deg: f64,
    /// Detection angle reached, degrees; for a sweep's bin, the middle of its travel.
    pub theta_r_deg: f64,
    /// How far the detector arm moved while the reading integrated, degrees: a sweep's
    /// bin spans θr ± span/2; 0 for a reading taken with the arms still (and for every
    /// reading recorded before sweeps existed).
    #[serde(default)]
    pub theta_r_span_deg: f64,
    /// Radiance factor; `None` when the reading cannot be converted (see `note`).
    pub radiance_factor: Option<f64>,
    /// Its standard uncertainty.
    pub std: Option<f64>,
    /// The raw reading.
    pub reading: Reading,
    /// Schedule and index it streamed as.
    pub schedule_id: u16,
    /// Index in the schedule.
    pub index: u16,
    /// Device time of the reading, µs since the instrument's boot.
    pub device_time_us: u64,
    /// Why it could not be converted.
    pub note: Option<String>,
    /// Taken while an arm may have been off its step count (lost steps found, or a check
    /// that could not be made): kept in the record, left out of the fit, measured again.
    #[serde(default)]
    pub superseded: bool,
    /// Why a sweep's bin is no value at all (every block blanked by a range switch, or a
    /// part of them: the mean is of part of the interval): kept in the record, never
    /// converted — by the session, a gain calibration's re-conversion or a re-analysis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unusable: Option<String>,
}

impl MeasuredPoint {
    /// Its radiance factor and own standard uncertainty from the raw reading with
    /// `calibration` (or why it cannot be converted, in `note`). The one conversion of the
    /// session, of a gain calibration's re-conversion and of the folder's checks: a reading's
    /// record is its raw reading; what it converts to follows from the calibration.
    pub(crate) fn convert_with(&mut self, calibration: &Calibration) {
        if let Some(why) = &self.unusable {
            (self.radiance_factor, self.std, self.note) = (None, None, Some(why.clone()));
            return;
        }
        if self.theta_r_span_deg > 0.0 {
            // A sweep's bin carries its blocks' noise as the calibration gives it
            // (sweep_bins::bin_point): a calibration that learnt more (a range's own noise, with
            // its gain ratio) gives it again.
            let net = calibration.net_counts(&self.reading).unwrap_or(0.0);
            if let Ok(block_std) = calibration.block_std_counts(self.reading.range, net) {
                self.reading.std_counts = block_std as f32;
            }
        }
        match calibration.radiance_factor(self.theta_i_deg, &self.reading) {
            Ok((r, u)) => (self.radiance_factor, self.std, self.note) = (Some(r), Some(u), None),
            Err(e) => {
                (self.radiance_factor, self.std, self.note) = (None, None, Some(e.to_string()))
            }
        }
    }

    /// Why its numbers cannot be a reading of the instrument (an angle off any arm's
    /// travel, a value not finite or beyond what any detector range counts), if they cannot.
    /// What a file says is checked before it is used: `points.jsonl` is read through this.
    pub(crate) fn implausible(&self) -> Option<String> {
        /// Far beyond any arm's travel, degrees.
        const MAX_ANGLE_DEG: f64 = 360.0;
        /// Far beyond any detector's full scale (a 32-bit converter), counts.
        const MAX_COUNTS: f64 = 1e10;
        /// Far beyond the radiance factor of a mirror's peak through the acceptance.
        const MAX_RADIANCE_FACTOR: f64 = 1e6;
        let angle = |what: &str, v: f64| {
            (!(v.is_finite() && v.abs() <= MAX_ANGLE_DEG))
                .then(|| format!("{what} {v}° is not an angle of the instrument"))
        };
        let within = |what: &str, v: f64, low: f64, high: f64| {
            (!(v.is_finite() && (low..=high).contains(&v)))
                .then(|| format!("{what} {v} is not in [{low}, {high}]"))
        };
        let counts = f64::from(self.reading.mean_counts);
        let counts_std = f64::from(self.reading.std_counts);
        angle("theta_i_deg", self.theta_i_deg)
            .or_else(|| angle("theta_r_deg", self.theta_r_deg))
            .or_else(|| {
                within(
                    "theta_r_span_deg",
                    self.theta_r_span_deg,
                    0.0,
                    MAX_ANGLE_DEG,
                )
            })
            .or_else(|| {
                self.radiance_factor.and_then(|r| {
                    within(
                        "radiance_factor",
                        r,
                        -MAX_RADIANCE_FACTOR,
                        MAX_RADIANCE_FACTOR,
                    )
                })
            })
            .or_else(|| {
                self.std
                    .and_then(|u| within("std", u, 0.0, MAX_RADIANCE_FACTOR))
            })
            .or_else(|| within("reading.mean_counts", counts, -MAX_COUNTS, MAX_COUNTS))
            .or_else(|| within("reading.std_counts", counts_std, 0.0, MAX_COUNTS))
    }

    fn geometry(&self) -> Option<Geometry> {
        Geometry::from_deg(self.theta_i_deg, self.theta_r_deg)
    }
}

/// Progress for a display.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Geometries measured in this stage.
    pub done: usize,
    /// Geometries planned in this stage.
    pub planned: usize,
    /// Estimated device time left in this stage.
    pub remaining: Duration,
}

/// Where readings and decisions go as they happen (files, a progress bar).
pub trait Recorder {
    /// A new calibration.
    fn calibration(&mut self, calibration: &Calibration) -> std::io::Result<()>;
    /// A new reading. A point reading is durable when this returns; a sweep's bin (one
    /// every 1–2 ms, faster than a disk syncs) once [`Recorder::sweep_done`] returns.
    fn point(&mut self, point: &MeasuredPoint) -> std::io::Result<()>;
    /// A sweep's bins are all recorded (or the sweep ended early): make them durable. A
    /// power loss before it costs the bins of the sweep in progress, which a resume finds
    /// uncovered and measures again.
    fn sweep_done(&mut self) -> std::io::Result<()> {
        Ok(())
    }
    /// Readings recorded earlier are superseded (`superseded` is now set on each; `why`
    /// says what was found). They stay in the record; their geometries are measured again.
    fn superseded(&mut self, points: &[MeasuredPoint], why: &str) -> std::io::Result<()> {
        let _ = (points, why);
        Ok(())
    }
    /// A stage begins (`what`), with its geometry count.
    fn stage(&mut self, what: &str, planned: usize);
    /// Progress within the stage.
    fn progress(&mut self, progress: Progress);
    /// A decision of the session, in words.
    fn decision(&mut self, text: &str);
}

/// A [`Recorder`] that keeps nothing: for campaigns of simulated sessions, which keep
/// only the [`Outcome`].
pub struct DiscardRecorder;

impl Recorder for DiscardRecorder {
    fn calibration(&mut self, _: &Calibration) -> std::io::Result<()> {
        Ok(())
    }
    fn point(&mut self, _: &MeasuredPoint) -> std::io::Result<()> {
        Ok(())
    }
    fn stage(&mut self, _: &str, _: usize) {}
    fn progress(&mut self, _: Progress) {}
    fn decision(&mut self, _: &str) {}
}

/// One fit of the session and what followed from it.
#[derive(Clone, Debug, Serialize)]
pub struct FitStep {
    /// After what it was made ("strategy1", "strategy2 δ=3°").
    pub after: String,
    /// The full report (the `gonio fit --json` object).
    pub report: serde_json::Value,
}

/// A refinement taken, and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Refinement {
    /// Strategy 2's δ (the paper's policy); `None` for an adaptive batch.
    pub delta_deg: Option<u8>,
    /// Geometries it added (not measured before).
    pub added: usize,
    /// Why.
    pub reason: String,
    /// A batch or sweep round that tests the model off the peak (the tails and the whole θr
    /// range, [`adaptive::lack_of_fit_batch`]; for sweeps the rest of the full plane),
    /// taken because the fit was flagged lack-of-fit or its model was extended by a term
    /// (the reason says which): these count against [`adaptive::LACK_OF_FIT_BATCHES`].
    /// Sessions of the first version did not record it: read as false.
    #[serde(default)]
    pub lack_of_fit: bool,
}

/// What the session went through to keep the instrument and the link in hand.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Recoveries {
    /// Times the link was lost and the instrument greeted again.
    pub reconnections: u32,
    /// Times the instrument's state was read and brought back to a known one (after a
    /// reconnection, a refusal or a stop).
    pub(crate) state_recoveries: u32,
    /// Refusals (busy, not homed, …) recovered from.
    pub refusals: u32,
    /// Fail-safe stops the instrument made on its own (heartbeat lost, …).
    pub stops: u32,
    /// Times the homing was lost and done again.
    pub rehomings: u32,
    /// Times the lamp had gone off and was lit again.
    pub lamp_relit: u32,
    /// Readings lost on the link (or with an aborted schedule) and measured again.
    pub readings_remeasured: usize,
    /// Device time from each failure to the instrument being ready again, seconds.
    pub seconds: f64,
}

impl Recoveries {
    /// Whether anything had to be recovered.
    pub fn any(&self) -> bool {
        self.reconnections + self.state_recoveries + self.refusals + self.stops > 0
            || self.readings_remeasured > 0
    }
}

/// What a session produced.
pub struct Outcome {
    /// Without an instrument profile: what the readings give through the widest and the
    /// narrowest response the declared one may stand for (`None` with a profile).
    pub instrument_bound: Option<InstrumentBound>,
    /// Every reading, superseded ones included (marked).
    pub points: Vec<MeasuredPoint>,
    /// The calibration used.
    pub calibration: Calibration,
    /// Every fit.
    pub fits: Vec<FitStep>,
    /// Every refinement.
    pub refinements: Vec<Refinement>,
    /// The final analysis.
    pub report: Report,
    /// Device time measuring the sample (Strategy 1 to the last refinement, re-measured
    /// readings and the white check; without the lost-steps check and waiting for the
    /// operator), seconds.
    pub device_seconds: f64,
    /// Device time of homing and calibration before it, seconds.
    pub setup_seconds: f64,
    /// Device time of the lost-steps check(s) before the report, seconds.
    pub(crate) check_seconds: f64,
    /// Device time of the whole session, waiting for the operator included, seconds.
    pub(crate) session_seconds: f64,
    /// White drift at the end, fraction (when checked).
    pub white_drift: Option<f64>,
    /// The drift exceeded the limit: the result is marked.
    pub white_drift_exceeded: bool,
    /// Every Home of the session and the step errors it found.
    pub step_checks: Vec<StepCheck>,
    /// What was recovered.
    pub recoveries: Recoveries,
    /// Every decision, in order (also given to the recorder as it was made).
    pub decisions: Vec<String>,
    /// Every condition that makes the result less than clean (and the informational ones).
    pub flags: Vec<Flag>,
    /// What the final analysis was made with besides the readings and the calibration.
    pub(crate) analysis_settings: AnalysisSettings,
    /// When the final analysis was made (the calibration's age in its budget is as of it).
    pub(crate) analysed_unix_s: u64,
}

impl Outcome {
    /// No flag but the informational ones.
    pub fn ok(&self) -> bool {
        crate::analysis::flags::ok(&self.flags)
    }

    /// The readings the result rests on (superseded ones left out).
    pub fn current_points(&self) -> impl Iterator<Item = &MeasuredPoint> {
        self.points.iter().filter(|p| !p.superseded)
    }

    /// How many geometries the fit had: current readings with a radiance factor (a
    /// sweep's blanked bins and unconvertible readings are recorded but carry none).
    /// The count every output states (issue 31: "1400 geometries" was printed for a
    /// sweep whose readings.csv and fit had 1,385).
    pub fn usable_readings(&self) -> usize {
        self.current_points()
            .filter(|p| p.radiance_factor.is_some())
            .count()
    }
}

/// How the link was lost for good.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkLoss {
    /// The port went away (cable out, instrument off): the last I/O error.
    PortGone(String),
    /// The port is there but nothing answers (a frozen instrument).
    NoAnswer,
    /// Bytes keep coming but no frame of them can be read (a link that is all noise, a
    /// port at the wrong settings, another device): reconnecting was given up after a
    /// minute of greetings none of which was answered.
    Unreadable {
        /// Frames that could not be read meanwhile.
        garbled: u32,
    },
}

/// Why a session failed.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The link failed beyond recovery.
    #[error(transparent)]
    Link(LinkError),
    /// Nothing heard from the instrument for the give-up time.
    #[error("{}", lost_text(.link, .loss, .silent_for, .decisions))]
    Lost {
        /// The link (a port path, the simulator).
        link: String,
        /// Which way it was lost.
        loss: LinkLoss,
        /// How long nothing was heard.
        silent_for: Duration,
        /// The session's decisions so far.
        decisions: Vec<String>,
    },
    /// The instrument refused or failed a command in a way the host cannot mend.
    #[error("the instrument refused {command}: {error}; {advice}")]
    Refused {
        /// What was refused.
        command: &'static str,
        /// The device's reason.
        error: protocol::DeviceError,
        /// What it means and what to do.
        advice: String,
    },
    /// Another instrument answers on the link than the one the session started with.
    #[error(
        "another instrument answers on the link after the reconnection (serial number {found}, the session started on {expected}): stopped rather than mix two instruments' readings"
    )]
    OtherInstrument {
        /// The session's instrument.
        expected: String,
        /// The one answering now.
        found: String,
    },
    /// The instrument stopped on its own and did not recover.
    #[error("the instrument stopped: {0}")]
    Stopped(ErrorCode),
    /// Calibration.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// Recording failed: stop rather than measure what cannot be kept.
    #[error("cannot record the session: {0}")]
    Record(std::io::Error),
    /// The operator could not be asked.
    #[error("cannot ask the operator: {0}")]
    Operator(std::io::Error),
    /// Not enough convertible readings for a fit.
    #[error("the fit failed: {0}")]
    Fit(String),
    /// The analysis of the readings failed.
    #[error("the fit failed: {0}")]
    Analysis(PointsAnalysisError),
    /// The readings saturated the detector and too few were left for a fit: said as
    /// such, with what to change (resuming would saturate again).
    #[error("{0}")]
    Saturated(Box<saturation::Saturation>),
    /// The user interrupted the session (Ctrl-C; see [`Client::set_interrupt`]).
    #[error("interrupted by the user")]
    Interrupted,
    /// Too many attempts without progress.
    #[error("{0}")]
    GaveUp(String),
    /// A bound on the run was reached ([`bounds`]: re-measure rounds, device time, the
    /// folder's size): stopped on the fail-safe path, every reading kept.
    #[error("{0}")]
    Bound(String),
}

impl SessionError {
    /// A recorder's error: the folder's bound ([`bounds::FolderFull`]) is a bound of the
    /// run, anything else a record that failed.
    pub(crate) fn record(error: std::io::Error) -> SessionError {
        match error
            .get_ref()
            .and_then(|e| e.downcast_ref::<bounds::FolderFull>())
        {
            Some(full) => SessionError::Bound(full.to_string()),
            None => SessionError::Record(error),
        }
    }
}

fn lost_text(link: &str, loss: &LinkLoss, silent_for: &Duration, decisions: &[String]) -> String {
    let what = match loss {
        LinkLoss::PortGone(error) => format!(
            "the instrument's port is gone ({link}: {error}) and nothing was heard from it for {:.1} s: reconnect the cable or power the instrument",
            silent_for.as_secs_f64()
        ),
        LinkLoss::NoAnswer => format!(
            "the port is there ({link}) but the instrument has not answered for {:.1} s: it is frozen or without power; power-cycle it",
            silent_for.as_secs_f64()
        ),
        LinkLoss::Unreadable { garbled } => format!(
            "bytes keep coming on {link} but nothing could be read from them for {:.1} s ({garbled} garbled frames, no answer to a greeting): the link is too noisy, the port is at the wrong settings or another device is on it; check the cable and the port",
            silent_for.as_secs_f64()
        ),
    };
    let shown = decisions.len().min(12);
    let mut text = format!("gave up: {what}");
    if shown > 0 {
        text.push_str(&format!(
            "\ndecisions so far{}:",
            if shown < decisions.len() {
                format!(" (the last {shown} of {})", decisions.len())
            } else {
                String::new()
            }
        ));
        for d in &decisions[decisions.len() - shown..] {
            text.push_str("\n  ");
            text.push_str(d);
        }
    }
    text
}

impl From<LinkError> for SessionError {
    fn from(error: LinkError) -> SessionError {
        match error {
            LinkError::Interrupted => SessionError::Interrupted,
            other => SessionError::Link(other),
        }
    }
}

/// The running session.
pub struct Session<'a, T: Transport> {
    client: &'a mut Client<T>,
    info: DeviceInfo,
    plan: Plan,
    recorder: &'a mut dyn Recorder,
    operator: &'a mut dyn Operator,
    points: Vec<MeasuredPoint>,
    calibration: Option<Calibration>,
    next_schedule_id: u16,
    motion: Motion,
    /// Every geometry the session means to have a reading of, in the order first wanted.
    wanted: Vec<Geometry>,
    /// Every sweep the session means to have the bins of, in the order first wanted.
    wanted_sweeps: Vec<sweep_design::SweepPlan>,
    decisions: Vec<String>,
    flags: BTreeSet<Flag>,
    steps: steps::StepState,
    /// The lamp's and the link's state, and the recoveries so far.
    link: LinkState,
    /// What the session was given besides its plan (the builder methods').
    given: Given,
    /// Device time spent besides the sample's readings, and the last analysis's time.
    clock: Clock,
    /// What the session resumed from.
    resume: Resumed,
    /// What the run has spent against its bounds.
    bounds: bounds::Tally,
}

/// The lamp's and the link's state, and the recoveries so far.
#[derive(Default)]
struct LinkState {
    /// The lamp should be on (after the dark readings).
    lamp_wanted: bool,
    /// The lamp went off while wanted (a fail-safe stop): its output since is not the
    /// calibration's for sure, so the white tile is read again at the end.
    lamp_went_off: bool,
    /// The last I/O error of the link, to tell a vanished port from a silent instrument.
    last_io_error: Option<String>,
    recoveries: Recoveries,
}

/// What a session was given besides its plan.
struct Given {
    /// See [`Session::with_calibration_limit`].
    max_calibration_age: Option<Duration>,
    /// The white tile's certificate, for a calibration taken in this session.
    tile: Tile,
    /// See [`Session::with_arm_zero_uncertainty`].
    arm_zero_uncertainty_deg: f64,
    /// See [`Session::at_spot`].
    spot: Option<(u16, u16)>,
    /// See [`Session::with_profile`].
    profile: Option<ProfileInUse>,
    /// See [`Session::with_model_extensions`].
    model_extensions: bool,
}

/// Device time spent besides the sample's readings, and the last analysis's time.
#[derive(Default)]
struct Clock {
    /// Time spent waiting for the operator on the transport's clock (for the bounds), µs.
    waiting_us: u64,
    /// Device time spent waiting for the operator, on [`Session::device_now`]'s clock, µs.
    device_waiting_us: u64,
    /// Device time spent on lost-steps checks before the report, µs.
    final_check_us: u64,
    /// The time of the last analysis (the calibration's age in the budget is as of it).
    analysed_unix_s: u64,
    /// The device's uptime last read ([`Session::device_now`]), µs.
    device_uptime_us: u64,
    /// Device time of earlier boots of the instrument in this session (the uptime
    /// restarts when it resets), µs.
    device_earlier_boots_us: u64,
}

/// What a session resumed from.
#[derive(Default)]
struct Resumed {
    /// It started from readings of an earlier run.
    resumed: bool,
    /// Resumed readings superseded by a later reading of their geometry whose mark a crash
    /// kept from the record: marked there when the session starts.
    unrecorded_marks: Vec<MeasuredPoint>,
    /// Device time the resumed readings span (from the first to the last, on each boot
    /// of the instrument), µs: the interrupted run's measuring, counted in the session's
    /// device time.
    device_us: u64,
}

/// What a session measured and how long it took, for [`Session::finish`].
struct Finished {
    fits: Vec<FitStep>,
    refinements: Vec<Refinement>,
    report: Report,
    device_seconds: f64,
    setup_seconds: f64,
    session_seconds: f64,
    white_drift: Option<f64>,
    white_drift_exceeded: bool,
}

impl<'a, T: Transport> Session<'a, T> {
    /// A session on a connected instrument (after the handshake gave `info`).
    pub fn new(
        client: &'a mut Client<T>,
        info: DeviceInfo,
        plan: Plan,
        recorder: &'a mut dyn Recorder,
        operator: &'a mut dyn Operator,
    ) -> Self {
        let motion = Motion::from_info(&info).unwrap_or_else(|_| Motion::reference());
        Session {
            client,
            info,
            plan,
            recorder,
            operator,
            points: Vec::new(),
            calibration: None,
            next_schedule_id: 1,
            motion,
            wanted: Vec::new(),
            wanted_sweeps: Vec::new(),
            decisions: Vec::new(),
            flags: BTreeSet::new(),
            steps: steps::StepState::default(),
            link: LinkState::default(),
            given: Given {
                max_calibration_age: None,
                tile: Tile::default(),
                arm_zero_uncertainty_deg: crate::analysis::fit::DEFAULT_ARM_ZERO_UNCERTAINTY_DEG,
                spot: None,
                profile: None,
                model_extensions: crate::analysis::fit::on_by_default(),
            },
            clock: Clock::default(),
            resume: Resumed::default(),
            bounds: bounds::Tally::default(),
        }
    }

    /// Spot `spot` of `of` of a multi-spot session ([`crate::session::multi_spot`]): a spot
    /// after the first asks the operator to move the sheet before its first reading (a
    /// spot resumed with readings does not: the sheet has not moved since).
    pub(crate) fn at_spot(mut self, spot: u16, of: u16) -> Self {
        self.given.spot = Some((spot, of));
        self
    }

    /// The standard uncertainty of the detector arm's zero, degrees (default
    /// [`crate::analysis::fit::DEFAULT_ARM_ZERO_UNCERTAINTY_DEG`]): a shared error of every
    /// reading in the fit wherever the data do not call for a fitted offset.
    pub(crate) fn with_arm_zero_uncertainty(mut self, deg: f64) -> Self {
        self.given.arm_zero_uncertainty_deg = deg;
        self
    }

    /// The instrument profile in force ([`crate::instrument::profile`]): the fit models
    /// its measured response and takes its arm zero (and that zero's uncertainty) instead
    /// of the declared ones. `None`: the declared ones, and the result says so
    /// ([`Flag::InstrumentDeclared`]).
    pub(crate) fn with_profile(mut self, profile: Option<ProfileInUse>) -> Self {
        self.given.profile = profile;
        self
    }

    /// Whether the fit tests the model's extensions (default:
    /// [`crate::analysis::fit::on_by_default`]): a test or a study sets it for its own
    /// sessions without touching the process's environment.
    pub fn with_model_extensions(mut self, on: bool) -> Self {
        self.given.model_extensions = on;
        self
    }

    /// The white tile's certificate for a calibration taken in this session (default:
    /// [`Tile::default`]); a calibration reused or resumed keeps its own.
    pub fn with_tile(mut self, tile: Tile) -> Self {
        self.given.tile = tile;
        self
    }

    /// The oldest calibration accepted. One reused from an earlier session is refused at
    /// the start when older (`Calibration::load`, the caller's); one that passes this age
    /// before the session reports (a long or a late-resumed session) flags the result
    /// `calibration-stale`. Without it, no age is checked.
    pub fn with_calibration_limit(mut self, max_age: Duration) -> Self {
        self.given.max_calibration_age = Some(max_age);
        self
    }

    /// Continue from readings (and a calibration) an earlier session recorded.
    ///
    /// A geometry recorded more than once without a mark (the mark of a superseded
    /// reading was not written before a crash) keeps its last reading: a geometry is
    /// measured again only after its earlier reading was superseded.
    pub(crate) fn resume_from(
        mut self,
        calibration: Option<Calibration>,
        mut points: Vec<MeasuredPoint>,
    ) -> Self {
        self.next_schedule_id = points
            .iter()
            .map(|p| p.schedule_id)
            .max()
            .unwrap_or(0)
            .wrapping_add(1)
            .max(1);
        let mut seen = BTreeSet::new();
        for point in points.iter_mut().rev() {
            if let Some(g) = point.geometry().filter(|_| !point.superseded)
                && !seen.insert(g)
            {
                point.superseded = true;
                self.resume.unrecorded_marks.push(point.clone());
            }
        }
        for g in points.iter().filter_map(MeasuredPoint::geometry) {
            if !self.wanted.contains(&g) {
                self.wanted.push(g);
            }
        }
        self.resume.resumed = !points.is_empty();
        self.resume.device_us = resumed_span_us(&points);
        self.calibration = calibration;
        self.points = points;
        self
    }

    /// Use a calibration from an earlier session instead of taking one.
    pub fn with_calibration(mut self, calibration: Calibration) -> Self {
        self.calibration = Some(calibration);
        self
    }

    /// A decision, to the recorder and the session's own list.
    fn decide(&mut self, text: &str) {
        self.recorder.decision(text);
        self.decisions.push(text.to_string());
    }

    /// The transport's clock.
    fn now(&self) -> Duration {
        self.client.transport().now()
    }

    /// The instrument's clock, for the device time a session reports: the transport's
    /// clock where that is the device's (the simulator in process), else the device's
    /// uptime (`GetStatus`), continued across a reset of the instrument (whose uptime
    /// starts again from 0). The host's wall clock is not the device's: over a
    /// pseudo-terminal the simulator runs ahead of it (issue 31: 2.4 device s printed
    /// for a session whose readings span 19.5 s).
    pub(super) fn device_now(&mut self) -> Result<Duration, SessionError> {
        if self.client.transport().now_is_device_time() {
            return Ok(self.now());
        }
        let uptime_us = self.status()?.uptime_us;
        if uptime_us < self.clock.device_uptime_us {
            self.clock.device_earlier_boots_us += self.clock.device_uptime_us;
        }
        self.clock.device_uptime_us = uptime_us;
        Ok(Duration::from_micros(
            self.clock.device_earlier_boots_us + uptime_us,
        ))
    }

    /// Run the whole session.
    pub fn run(mut self) -> Result<Outcome, SessionError> {
        let started = self.start()?;
        // Setup (homing, dark, white) is the same whatever the policy and a calibration
        // serves many sheets: the sample's device time is counted from here.
        let measuring_from = self.device_now()?;
        let waiting_before = self.clock.device_waiting_us;
        let setup_seconds = (measuring_from.saturating_sub(started)).as_secs_f64()
            - self.clock.device_waiting_us as f64 * 1e-6;
        let mut fits = Vec::new();
        let mut refinements = Vec::new();
        let first_name = self.first_stage()?;
        let mut report = self.analyse()?;
        fits.push(FitStep {
            after: first_name,
            report: to_json(&report),
        });
        self.refine(&mut report, &mut fits, &mut refinements)?;
        self.check_before_report(&mut report, &mut fits, &mut refinements)?;
        let (white_drift, white_drift_exceeded) = if self.plan.white_check
            || self.link.lamp_went_off
        {
            if !self.plan.white_check {
                self.decide("the lamp went off during the session: reading the white tile again to see whether its output came back");
            }
            self.white_check()?
        } else {
            (None, false)
        };
        let ended = self.device_now()?;
        let measuring_us = (ended.saturating_sub(measuring_from)).as_micros() as u64;
        let device_us = measuring_us
            .saturating_sub(self.clock.final_check_us)
            .saturating_sub(self.clock.device_waiting_us - waiting_before)
            + self.resume.device_us;
        self.finish(Finished {
            fits,
            refinements,
            report,
            device_seconds: device_us as f64 * 1e-6,
            setup_seconds,
            session_seconds: (ended.saturating_sub(started)).as_secs_f64(),
            white_drift,
            white_drift_exceeded,
        })
    }

    /// Up to the first reading of the sample: resumed readings' marks recorded, the arms
    /// homed (and checked, for a resumed session), the calibration taken or the lamp lit
    /// for the one given, the sheet moved to its next spot. Returns when the session's
    /// time started (after the resumed readings' marks).
    fn start(&mut self) -> Result<Duration, SessionError> {
        if !self.resume.unrecorded_marks.is_empty() {
            let marks = std::mem::take(&mut self.resume.unrecorded_marks);
            self.decide(&format!("{} resumed readings were measured again before the crash: the later reading of each geometry is kept", marks.len()));
            self.recorder
                .superseded(
                    &marks,
                    "measured again before a crash kept the mark from the record",
                )
                .map_err(SessionError::record)?;
        }
        if self.info.reset_cause.fault().is_some() {
            // A fault the instrument took before this session (a panic, a processor fault,
            // the watchdog): the homing that follows starts afresh.
            self.decide(&format!(
                "the instrument last restarted after a fault: {}",
                self.info.reset_cause
            ));
        }
        // The bounds run on the transport's clock (a limit of the host's wait), the
        // reported times on the device's.
        self.bounds.started = Some(self.now());
        let started = self.device_now()?;
        // The resumed readings were taken under an earlier process: a Home now tells
        // whether the arms still agree with their step counts (`steps`).
        self.ensure_ready(self.resume.resumed)?;
        if self.calibration.is_none() {
            self.calibrate()?;
        } else {
            self.link.lamp_wanted = true;
            self.lamp_on()?;
        }
        if let Some((spot, of)) = self
            .given
            .spot
            .filter(|(spot, _)| *spot > 1 && !self.resume.resumed)
        {
            self.ask_operator(Placement::NextSpot { spot, of })?;
            self.client.transport_mut().sample_moved();
        }
        Ok(started)
    }

    /// The first stage of the plan's policy (the sweep policy's first pass, a fixed
    /// schedule, else Strategy 1); returns its name.
    fn first_stage(&mut self) -> Result<String, SessionError> {
        match &self.plan.policy {
            Policy::Sweep(targets) => {
                let targets = *targets;
                let here = self.status()?.position;
                let pass = sweep_design::first_pass_from(
                    &self.motion,
                    here,
                    targets
                        .pass_speed_deg_per_s
                        .min(f64::from(self.info.max_speed_deg_per_s)),
                    targets.pass_bin_deg,
                );
                let incidences: Vec<String> =
                    pass.iter().map(|p| format!("{}°", p.theta_i_deg)).collect();
                let name = format!(
                    "first pass ({} sweeps of θr 0–{}° at θi = {}, {} °/s, bins of {}°)",
                    pass.len(),
                    sweep_design::THETA_R_MAX_DEG,
                    incidences.join(" and "),
                    targets
                        .pass_speed_deg_per_s
                        .min(f64::from(self.info.max_speed_deg_per_s)),
                    targets.pass_bin_deg
                );
                self.decide(&name);
                self.sweep_stage(&name, &pass)?;
                Ok(name)
            }
            policy => {
                let first = match policy {
                    Policy::Fixed(schedule) => schedule.geometries(),
                    _ => strategy1(12).map(|s| s.to_vec()).unwrap_or_default(),
                };
                let name = match policy {
                    Policy::Fixed(FixedSchedule::Strategy1 { m }) => {
                        format!("strategy 1 ({m} geometries)")
                    }
                    Policy::Fixed(FixedSchedule::Strategy2 { delta_deg }) => {
                        format!("strategy 2, δ = {delta_deg}° ({} geometries)", first.len())
                    }
                    _ => "strategy 1 (12 geometries)".into(),
                };
                self.measure(&name, &first)?;
                Ok(name)
            }
        }
    }

    /// Before reporting: do the step counts still agree with the switches? Readings taken
    /// while an arm was off are measured again after the re-home (the check's Home), the
    /// policy refines from the corrected fit, and the arms are checked again.
    fn check_before_report(
        &mut self,
        report: &mut Report,
        fits: &mut Vec<FitStep>,
        refinements: &mut Vec<Refinement>,
    ) -> Result<(), SessionError> {
        for round in 1..=steps::MAX_CHECK_ROUNDS {
            let check_started = self.device_now()?;
            let clean = self.check_steps("before the report")?;
            self.clock.final_check_us +=
                (self.device_now()?.saturating_sub(check_started)).as_micros() as u64;
            if clean && self.missing().is_empty() && self.uncovered_sweeps().is_empty() {
                break;
            }
            if round == steps::MAX_CHECK_ROUNDS {
                self.decide(&format!("the arms lost steps at {round} checks in a row: the instrument needs attention; the result is flagged lost-steps"));
                break;
            }
            let missing = self.missing();
            if !missing.is_empty() {
                self.measure(
                    &format!(
                        "measuring again {} readings taken while an arm was off",
                        missing.len()
                    ),
                    &missing,
                )?;
            }
            let uncovered = self.uncovered_sweeps();
            if !uncovered.is_empty() {
                self.sweep_stage(
                    &format!(
                        "measuring again {} stretches of sweeps taken while an arm was off",
                        uncovered.len()
                    ),
                    &[],
                )?;
            }
            *report = self.analyse()?;
            fits.push(FitStep {
                after: format!("re-measured after lost steps (check {round})"),
                report: to_json(report),
            });
            self.refine(report, fits, refinements)?;
        }
        Ok(())
    }

    /// The outcome: the session's flags (white drift, a stale calibration, the analysis's
    /// own, a recovered link, a resume) added to what was measured.
    fn finish(mut self, done: Finished) -> Result<Outcome, SessionError> {
        let calibration = self
            .calibration
            .take()
            .ok_or(SessionError::Fit("no calibration".into()))?;
        if done.white_drift_exceeded {
            self.flags.insert(Flag::WhiteDrift);
        }
        let age = calibration.age(unix_now_s());
        if let Some(limit) = self.given.max_calibration_age.filter(|limit| age > *limit) {
            self.decide(&format!(
                "the calibration is {:.1} h old at the end of the session (limit {:.1} h): result flagged calibration-stale",
                age.as_secs_f64() / 3600.0,
                limit.as_secs_f64() / 3600.0
            ));
            self.flags.insert(Flag::CalibrationStale);
        }
        // The analysis's own flags (lack-of-fit, not-identified, sigma-not-resolved).
        self.flags.extend(done.report.flags.iter().copied());
        let instrument_bound = if self.given.profile.is_none() {
            Some(self.bound_by_declared_response(&done.report))
        } else {
            None
        };
        if self.link.recoveries.any() {
            self.flags.insert(Flag::LinkRecovered);
        }
        if self.resume.resumed {
            self.flags.insert(Flag::Resumed);
        }
        Ok(Outcome {
            instrument_bound,
            points: self.points,
            calibration,
            fits: done.fits,
            refinements: done.refinements,
            report: done.report,
            device_seconds: done.device_seconds,
            setup_seconds: done.setup_seconds,
            check_seconds: self.clock.final_check_us as f64 * 1e-6,
            session_seconds: done.session_seconds,
            white_drift: done.white_drift,
            white_drift_exceeded: done.white_drift_exceeded,
            step_checks: self.steps.checks,
            recoveries: self.link.recoveries,
            decisions: self.decisions,
            flags: self.flags.into_iter().collect(),
            analysis_settings: AnalysisSettings {
                acceptance_deg: self.plan.acceptance_deg,
                arm_zero_uncertainty_deg: self.given.arm_zero_uncertainty_deg,
                instrument_profile: self.given.profile.clone(),
                model_extensions: self.given.model_extensions,
            },
            analysed_unix_s: self.clock.analysed_unix_s,
        })
    }

    /// Without an instrument profile: the readings analysed again through the widest and
    /// narrowest response the declared one may stand for
    /// ([`crate::analysis::flags::DECLARED_RESPONSE_BOUND_DEG`]); a class that changes
    /// within that bound is flagged [`Flag::InstrumentSensitive`], and the decisions give σ
    /// and the class at each width.
    fn bound_by_declared_response(&mut self, report: &Report) -> InstrumentBound {
        let now = self.clock.analysed_unix_s;
        let mut bound = InstrumentBound {
            widths_deg: crate::analysis::flags::DECLARED_RESPONSE_BOUND_DEG.to_vec(),
            sigma_deg: None,
            rho_s: None,
            rho_d: None,
            classes: Vec::new(),
        };
        let widen = |range: &mut Option<[f64; 2]>, value: Option<f64>| {
            if let Some(v) = value.filter(|v| v.is_finite()) {
                let r = range.get_or_insert([v, v]);
                r[0] = r[0].min(v);
                r[1] = r[1].max(v);
            }
        };
        for k in [model::SIGMA, model::RHO_S, model::RHO_D] {
            let range = match k {
                model::SIGMA => &mut bound.sigma_deg,
                model::RHO_S => &mut bound.rho_s,
                _ => &mut bound.rho_d,
            };
            widen(range, report.fit.reported(k));
            if let Some((lo, hi)) = report.fit.ci95[k] {
                widen(range, Some(lo));
                widen(range, Some(hi));
            }
        }
        let mut seen = Vec::new();
        for width in crate::analysis::flags::DECLARED_RESPONSE_BOUND_DEG {
            let settings = AnalysisSettings {
                acceptance_deg: width,
                ..self.analysis_settings()
            };
            if let Ok(again) = analyse_points(
                &self.plan.sample,
                &self.points,
                self.calibration.as_ref(),
                &settings,
                now,
            ) {
                seen.push((
                    width,
                    again.classification.class,
                    again.fit.params.sigma_deg,
                ));
                for k in [model::SIGMA, model::RHO_S, model::RHO_D] {
                    let range = match k {
                        model::SIGMA => &mut bound.sigma_deg,
                        model::RHO_S => &mut bound.rho_s,
                        _ => &mut bound.rho_d,
                    };
                    widen(range, again.fit.reported(k));
                    if let Some((lo, hi)) = again.fit.ci95[k] {
                        widen(range, Some(lo));
                        widen(range, Some(hi));
                    }
                }
                bound
                    .classes
                    .push(again.classification.class_name().to_string());
            }
        }
        let nominal = report.classification.class;
        if seen.iter().any(|(_, class, _)| *class != nominal) {
            let text = seen
                .iter()
                .map(|(w, c, s)| {
                    format!(
                        "{} (σ {s:.3}°) at {w}°",
                        c.map_or("undecided", |c| c.name())
                    )
                })
                .collect::<Vec<_>>()
                .join(", ");
            self.decide(&format!(
                "without an instrument profile the class depends on the detector's response: {} at the declared {}°, {text}: result flagged instrument-sensitive",
                report.classification.class_name(),
                self.plan.acceptance_deg
            ));
            self.flags.insert(Flag::InstrumentSensitive);
        }
        bound
    }

    /// Where the arms are now.
    fn arm_position(&mut self) -> Result<Geometry, SessionError> {
        Ok(self.status()?.position)
    }

    /// Every usable reading (converted, not superseded) as a fit observation with its
    /// index in `points`.
    fn usable_points(&self) -> impl Iterator<Item = (usize, Observation)> + '_ {
        let (indices, observations) = usable_observations(&self.points);
        indices.into_iter().zip(observations)
    }

    /// Geometries with a current reading (not superseded). A reading that could not be
    /// converted counts: measuring it again would give the same.
    fn measured(&self) -> BTreeSet<Geometry> {
        self.points
            .iter()
            .filter(|p| !p.superseded)
            .filter_map(MeasuredPoint::geometry)
            .collect()
    }

    /// Geometries wanted and not measured (lost on the link, superseded), in the order
    /// first wanted.
    fn missing(&self) -> Vec<Geometry> {
        let measured = self.measured();
        self.wanted
            .iter()
            .copied()
            .filter(|g| !measured.contains(g))
            .collect()
    }

    /// Fit everything measured so far, check σ against σ_l and classify, as of now (the
    /// calibration's age sets the lamp drift's share); the time is kept for the record.
    fn analyse(&mut self) -> Result<Report, SessionError> {
        let now = unix_now_s();
        self.clock.analysed_unix_s = now;
        analyse_points(
            &self.plan.sample,
            &self.points,
            self.calibration.as_ref(),
            &self.analysis_settings(),
            now,
        )
        .map_err(|error| {
            // Too few geometries because readings saturated: the fit's count of them says
            // nothing of why, nor of what to change.
            let too_few = matches!(
                &error,
                PointsAnalysisError::Fit(e)
                    if matches!(e.source, crate::analysis::fit::FitError::TooFewGeometries { .. })
            );
            let saturation = too_few
                .then(|| {
                    saturation::of(
                        &self.points,
                        self.calibration.as_ref(),
                        self.info.detector_ranges.len(),
                        error.to_string(),
                    )
                })
                .flatten();
            match saturation {
                Some(s) => SessionError::Saturated(Box::new(s)),
                None => SessionError::Analysis(error),
            }
        })
    }

    /// What the session's analysis is made with besides the readings.
    fn analysis_settings(&self) -> AnalysisSettings {
        AnalysisSettings {
            acceptance_deg: self.plan.acceptance_deg,
            arm_zero_uncertainty_deg: self.given.arm_zero_uncertainty_deg,
            instrument_profile: self.given.profile.clone(),
            model_extensions: self.given.model_extensions,
        }
    }
}

/// What a session's readings give through the bound on an unmeasured detector response:
/// each parameter's range over the 95 % intervals at the declared response and at each
/// width of the bound, and the class at each width. An honest interval where the
/// instrument was not characterized: the statistical interval holds only for the
/// declared response.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InstrumentBound {
    /// The top-hat widths analysed, degrees.
    pub widths_deg: Vec<f64>,
    /// σ's range, degrees.
    pub sigma_deg: Option<[f64; 2]>,
    /// ρs's range.
    pub rho_s: Option<[f64; 2]>,
    /// ρd's range.
    pub rho_d: Option<[f64; 2]>,
    /// The class at each width.
    pub classes: Vec<String>,
}

/// What an analysis of a session's readings is made with besides the readings and the
/// calibration: recorded in the result so that a re-analysis makes the same one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct AnalysisSettings {
    /// Detector acceptance modelled in the fit, degrees (the declared top-hat; a profile's
    /// measured response replaces it).
    pub acceptance_deg: f64,
    /// Standard uncertainty of the detector arm's zero, degrees (a profile's replaces it).
    pub arm_zero_uncertainty_deg: f64,
    /// The instrument profile in force, if one was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instrument_profile: Option<ProfileInUse>,
    /// The fit tested the model's extensions and added those the data called for
    /// ([`crate::analysis::fit::Extension`]). Absent (false) in folders analysed before
    /// the extensions existed: `gonio fit DIR` then makes the analysis they recorded.
    #[serde(default)]
    pub model_extensions: bool,
}

/// The readings the result rests on (converted, not superseded, each still geometry
/// once: the first reading of it), as fit observations, with their indices in `points`.
/// A sweep's bins are each their own reading (two sweeps may put bins at one θr).
pub(crate) fn usable_observations(points: &[MeasuredPoint]) -> (Vec<usize>, Vec<Observation>) {
    let (indices, observations, _) = usable_observations_scaled(points);
    (indices, observations)
}

/// [`usable_observations`] with how the bins' noise was scaled to their scatter.
pub(crate) fn usable_observations_scaled(
    points: &[MeasuredPoint],
) -> (Vec<usize>, Vec<Observation>, sweep_bins::NoiseScaling) {
    let (indices, mut observations) = first_readings(points);
    let scaling = sweep_bins::scale_bin_noise(points, &indices, &mut observations);
    (indices, observations, scaling)
}

fn first_readings(points: &[MeasuredPoint]) -> (Vec<usize>, Vec<Observation>) {
    let mut seen = BTreeSet::new();
    points
        .iter()
        .enumerate()
        .filter(|(_, p)| !p.superseded)
        .filter_map(|(k, p)| {
            let (Some(radiance_factor), Some(g)) = (p.radiance_factor, p.geometry()) else {
                return None;
            };
            let first = p.theta_r_span_deg > 0.0 || seen.insert(g);
            first.then_some((
                k,
                Observation {
                    theta_i_deg: p.theta_i_deg,
                    theta_r_deg: p.theta_r_deg,
                    radiance_factor,
                    std: p.std,
                    theta_r_span_deg: p.theta_r_span_deg,
                },
            ))
        })
        .unzip()
}

/// Why a session's readings cannot be analysed. Its message is the whole story: no
/// `source`, so an error chain (`{:#}`) does not say the fit's error twice.
#[derive(Debug, thiserror::Error)]
pub enum PointsAnalysisError {
    /// The calibration cannot give the errors the readings share.
    #[error("{0}")]
    SharedErrors(CalibrationError),
    /// The fit failed.
    #[error("{0}")]
    Fit(crate::analysis::result::AnalysisError),
    /// The instrument profile's response cannot be modelled.
    #[error("the instrument profile's response: {0}")]
    Profile(String),
}

impl From<CalibrationError> for PointsAnalysisError {
    fn from(error: CalibrationError) -> Self {
        PointsAnalysisError::SharedErrors(error)
    }
}

impl From<crate::analysis::result::AnalysisError> for PointsAnalysisError {
    fn from(error: crate::analysis::result::AnalysisError) -> Self {
        PointsAnalysisError::Fit(error)
    }
}

/// What the session's analysis fits, before its settings are applied: the readings the
/// result rests on (their indices in `points`; a sweep's bins with their noise scaled to
/// their scatter), the variance that scaling leaves in χ², and the errors the calibration
/// shares among them. What `readings.shared-errors.json` records beside `readings.csv`
/// ([`crate::output::shared_errors`]), so that the folder's data alone re-analyse.
pub(crate) struct PointsAnalysisInputs {
    /// Index in `points` of each observation.
    pub indices: Vec<usize>,
    /// The observations as fitted (θr as the firmware reported it: a profile's zero is
    /// added by [`analyse_inputs`]).
    pub observations: Vec<Observation>,
    /// [`FitOptions::noise_scale_log_variance`].
    pub noise_scale_log_variance: f64,
    /// The calibration's shared errors, one entry per observation in each.
    pub shared: Vec<SharedError>,
}

/// [`PointsAnalysisInputs`] of `points` (marks applied, converted with `calibration`), the
/// shared errors as of `now_unix_s`.
pub(crate) fn analysis_inputs(
    points: &[MeasuredPoint],
    calibration: Option<&Calibration>,
    now_unix_s: u64,
) -> Result<PointsAnalysisInputs, PointsAnalysisError> {
    let (indices, observations, scaling) = usable_observations_scaled(points);
    let noise_scale_log_variance = scaling.chi2_log_variance(observations.len());
    let shared = match calibration {
        Some(calibration) => gains::shared_errors(
            calibration,
            &indices
                .iter()
                .filter_map(|&k| points.get(k))
                .collect::<Vec<_>>(),
            now_unix_s,
        )?,
        None => Vec::new(),
    };
    Ok(PointsAnalysisInputs {
        indices,
        observations,
        noise_scale_log_variance,
        shared,
    })
}

/// The session's analysis of `points` (marks applied, converted with `calibration`): the
/// fit with the calibration's shared errors as of `now_unix_s`, the σ_l check and the
/// class. What a session reports, and what `gonio fit DIR` makes again from its folder.
pub(crate) fn analyse_points(
    sample: &str,
    points: &[MeasuredPoint],
    calibration: Option<&Calibration>,
    settings: &AnalysisSettings,
    now_unix_s: u64,
) -> Result<Report, PointsAnalysisError> {
    let inputs = analysis_inputs(points, calibration, now_unix_s)?;
    // Lines of readings.csv: a header, then one per reading.
    let lines: Vec<usize> = inputs.indices.iter().map(|k| k + 2).collect();
    analyse_inputs(
        "readings.csv",
        sample,
        inputs.observations,
        &lines,
        &inputs.shared,
        inputs.noise_scale_log_variance,
        settings,
    )
}

/// The session's analysis of observations already chosen (θr as the firmware reported
/// it) with their shared errors, under the session's `settings`: a profile's arm zero
/// added to every θr and its response modelled, the `instrument-declared` flag without
/// one. [`analyse_points`] and the re-analysis of `readings.csv` with its shared-errors
/// file both come through here.
pub(crate) fn analyse_inputs(
    source: &str,
    sample: &str,
    mut observations: Vec<Observation>,
    lines: &[usize],
    shared: &[SharedError],
    noise_scale_log_variance: f64,
    settings: &AnalysisSettings,
) -> Result<Report, PointsAnalysisError> {
    // A profile's arm zero: every θr as the firmware reported it lacks the zero measured
    // at its incidence on the black glass.
    let response = match &settings.instrument_profile {
        Some(profile) => {
            for o in &mut observations {
                o.theta_r_deg = profile.corrected_theta_r(o.theta_i_deg, o.theta_r_deg);
            }
            Some(
                profile
                    .response()
                    .map_err(|e| PointsAnalysisError::Profile(e.to_string()))?,
            )
        }
        None => None,
    };
    let readings = Readings {
        source,
        sample,
        observations: &observations,
        lines,
    };
    let options = FitOptions {
        acceptance_deg: Some(settings.acceptance_deg),
        response,
        arm_zero_uncertainty_deg: settings
            .instrument_profile
            .as_ref()
            .map_or(settings.arm_zero_uncertainty_deg, |p| p.arm_zero_u_deg),
        noise_scale_log_variance,
        extensions: settings.model_extensions,
        ..FitOptions::default()
    };
    let mut report = analyse_with_shared(&readings, shared, &options, None)?;
    if settings.instrument_profile.is_none() {
        report.flags.push(Flag::InstrumentDeclared);
        report.flags.sort();
        report.flags.dedup();
    }
    Ok(report)
}

/// ", σ ≤ σ_l = …°" of a report whose σ fails the check (the value, so a reader sees how
/// far the sampling is from resolving the peak).
fn sigma_l_text(report: &crate::analysis::result::Report) -> String {
    match report.check {
        Some(check) => format!(
            ", σ ≤ σ_l = {:.3}° (δ = {:.2}°)",
            check.sigma_l_deg,
            report.delta.map_or(f64::NAN, |d| d.deg)
        ),
        None => ", σ_l unknown (no δ found)".to_string(),
    }
}

/// The model a fit was extended to, in words ("the model extended (terms: haze lobe, lobe
/// shape)"); `None` for the paper's model. A model grown on the readings so far is tested
/// where it has not been before it is reported, as a flagged fit is (both policies).
fn extended_model(fit: &crate::analysis::fit::FitResult) -> Option<String> {
    let extension = fit.extension.as_ref()?;
    (!extension.terms.is_empty()).then(|| {
        let names: Vec<&str> = extension.terms.iter().map(|t| t.name).collect();
        format!("the model extended (terms: {})", names.join(", "))
    })
}

/// What flagged a fit lack-of-fit, in words: the χ² test's and the structure test's
/// p-values, where they were made.
fn lack_of_fit_evidence(fit: &crate::analysis::fit::FitResult) -> String {
    // Plain below a thousandth would read 0.000 for a flag's typical p-values.
    let p = |p: f64| {
        if p >= 1e-3 {
            format!("{p:.3}")
        } else {
            format!("{p:.1e}")
        }
    };
    let chi2 = fit.gof_p.map(|v| format!("χ² p = {}", p(v)));
    let structure = fit
        .structure
        .map(|s| format!("structure p = {}", p(s.p_value)));
    let parts: Vec<String> = chi2.into_iter().chain(structure).collect();
    if parts.is_empty() {
        "no test p-value".to_string()
    } else {
        parts.join(", ")
    }
}

/// How one step of the session failed: something to recover from, or the end.
enum StepError {
    Failure(Failure),
    Fatal(SessionError),
}

impl StepError {
    fn from_link(error: LinkError) -> StepError {
        match recovery::classify(error) {
            Ok(failure) => StepError::Failure(failure),
            Err(fatal) => StepError::Fatal(fatal),
        }
    }
}

impl From<LinkError> for StepError {
    fn from(error: LinkError) -> StepError {
        StepError::from_link(error)
    }
}

/// The device time resumed readings span, µs: from the first to the last in the order
/// recorded, on each boot of the instrument (a reading stamped earlier than the one
/// before it was taken after a reset, whose clock started again).
fn resumed_span_us(points: &[MeasuredPoint]) -> u64 {
    points
        .windows(2)
        .map(|w| w[1].device_time_us.saturating_sub(w[0].device_time_us))
        .sum()
}
