//! The measurement session: one state machine from connection to report.
//!
//! Home → dark → white (the operator places the tile) → Strategy 1 on the instrument →
//! fit and σ_l check → refinements by the chosen policy, sending only geometries not yet
//! measured → classification → optional white check. Every reading is handed to the
//! [`Recorder`] as it arrives, so nothing measured is lost; a session can start from
//! readings already taken ([`Session::resume_from`]) and then measures only what is missing.
//!
//! The link can fail under it (corruption, a lost stream reading, a pulled cable): lost
//! readings are measured again, duplicates dropped, and after a reconnection the session
//! says hello again, re-homes if the instrument lost its homing, and carries on.

pub mod adaptive;
pub mod gains;
pub mod operator;
pub mod order;

pub use operator::{Operator, Placement, PromptOperator, SimulatedOperator};

use crate::instrument::calibration::{Calibration, CalibrationError, Tile, WhitePoint, instrument_name};
use crate::analysis::report::{Report, analyse_with_shared, to_json};
use crate::output::dataset::DataSet;
use crate::analysis::fit::{FitOptions, Observation};
use adaptive::AdaptiveTargets;
use crate::instrument::link::{Client, LinkError, Transport};
use order::Motion;
use protocol::schedules::{INCIDENCE_DEG, strategy1, strategy2};
use protocol::{
    Command, DeviceInfo, DeviceMessage, ErrorCode, Geometry, Reading, Reply, RunSchedule, SCHEDULE_CHUNK_LEN,
    ScheduleChunk, ScheduleSource, Target,
};
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
}

impl From<PolicyChoice> for Policy {
    fn from(choice: PolicyChoice) -> Policy {
        match choice {
            PolicyChoice::Paper => Policy::Paper,
            PolicyChoice::Adaptive => Policy::Adaptive(AdaptiveTargets::default()),
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
    /// Re-read the white tile at the end and report the drift.
    pub white_check: bool,
    /// White drift beyond which the result is marked, as a fraction.
    pub white_drift_limit: f64,
}

/// One measured geometry, as recorded.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeasuredPoint {
    /// Incidence angle reached, degrees.
    pub theta_i_deg: f64,
    /// Detection angle reached, degrees.
    pub theta_r_deg: f64,
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
}

impl MeasuredPoint {
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
    /// A new reading.
    fn point(&mut self, point: &MeasuredPoint) -> std::io::Result<()>;
    /// A stage begins (`what`), with its geometry count.
    fn stage(&mut self, what: &str, planned: usize);
    /// Progress within the stage.
    fn progress(&mut self, progress: Progress);
    /// A decision of the session, in words.
    fn decision(&mut self, text: &str);
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
#[derive(Clone, Debug, Serialize)]
pub struct Refinement {
    /// Strategy 2's δ (the paper's policy); `None` for an adaptive batch.
    pub delta_deg: Option<u8>,
    /// Geometries it added (not measured before).
    pub added: usize,
    /// Why.
    pub reason: String,
}

/// What a session produced.
pub struct Outcome {
    /// Every reading.
    pub points: Vec<MeasuredPoint>,
    /// The calibration used.
    pub calibration: Calibration,
    /// Every fit.
    pub fits: Vec<FitStep>,
    /// Every refinement.
    pub refinements: Vec<Refinement>,
    /// The final analysis.
    pub report: Report,
    /// Device time measuring the sample (Strategy 1 to the last refinement and the white
    /// check), seconds.
    pub device_seconds: f64,
    /// Device time of homing and calibration before it, seconds.
    pub setup_seconds: f64,
    /// White drift at the end, fraction (when checked).
    pub white_drift: Option<f64>,
    /// The drift exceeded the limit: the result is marked.
    pub white_drift_exceeded: bool,
    /// Every condition that makes the result less than clean (and the informational ones).
    pub flags: Vec<crate::analysis::flags::Flag>,
}

impl Outcome {
    /// No flag but the informational ones.
    pub fn ok(&self) -> bool {
        crate::analysis::flags::ok(&self.flags)
    }
}

/// Why a session failed.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The link failed beyond recovery.
    #[error(transparent)]
    Link(LinkError),
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
    /// The user interrupted the session (Ctrl-C; see [`Client::set_interrupt`]).
    #[error("interrupted by the user")]
    Interrupted,
    /// Too many attempts to measure the same geometries.
    #[error("geometries still missing after {0} attempts; the link or instrument is failing")]
    GaveUp(u32),
}

impl From<LinkError> for SessionError {
    fn from(error: LinkError) -> SessionError {
        match error {
            LinkError::Interrupted => SessionError::Interrupted,
            other => SessionError::Link(other),
        }
    }
}

/// Attempts at a stage's missing geometries, and at reconnecting.
const MAX_ATTEMPTS: u32 = 8;

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
    device_time_used_us: u64,
    motion: Motion,
    /// The white tile's certificate, for a calibration taken in this session.
    tile: Tile,
}

impl<'a, T: Transport> Session<'a, T> {
    /// A session on a connected instrument (after the handshake gave `info`).
    pub fn new(client: &'a mut Client<T>, info: DeviceInfo, plan: Plan, recorder: &'a mut dyn Recorder, operator: &'a mut dyn Operator) -> Self {
        let motion = Motion::from_info(&info).unwrap_or_else(|_| Motion::reference());
        Session { client, info, plan, recorder, operator, points: Vec::new(), calibration: None, next_schedule_id: 1, device_time_used_us: 0, motion, tile: Tile::default() }
    }

    /// Continue from readings (and a calibration) an earlier session recorded.
    pub fn resume_from(mut self, calibration: Option<Calibration>, points: Vec<MeasuredPoint>) -> Self {
        self.next_schedule_id = points.iter().map(|p| p.schedule_id).max().unwrap_or(0).wrapping_add(1).max(1);
        self.calibration = calibration;
        self.points = points;
        self
    }

    /// Use a calibration from an earlier session instead of taking one.
    pub fn with_calibration(mut self, calibration: Calibration) -> Self {
        self.calibration = Some(calibration);
        self
    }

    /// The white tile's certificate for a calibration taken in this session (default:
    /// [`Tile::default`]); a calibration reused or resumed keeps its own.
    pub fn with_tile(mut self, tile: Tile) -> Self {
        self.tile = tile;
        self
    }

    /// Run the whole session.
    pub fn run(mut self) -> Result<Outcome, SessionError> {
        let started_us = self.uptime_us()?;
        self.ensure_ready()?;
        if self.calibration.is_none() {
            self.calibrate()?;
        }
        self.lamp_on()?;
        // Setup (homing, dark, white) is the same whatever the policy and a calibration
        // serves many sheets: the sample's device time is counted from here.
        let measuring_from_us = self.uptime_us()?;
        let setup_seconds = measuring_from_us.saturating_sub(started_us) as f64 * 1e-6;
        let mut fits = Vec::new();
        let mut refinements = Vec::new();
        let first = match self.plan.policy {
            Policy::Fixed(schedule) => schedule.geometries(),
            Policy::Paper | Policy::Adaptive(_) => strategy1(12).map(|s| s.to_vec()).unwrap_or_default(),
        };
        let first_name = match self.plan.policy {
            Policy::Fixed(FixedSchedule::Strategy1 { m }) => format!("strategy 1 ({m} geometries)"),
            Policy::Fixed(FixedSchedule::Strategy2 { delta_deg }) => format!("strategy 2, δ = {delta_deg}° ({} geometries)", first.len()),
            _ => "strategy 1 (12 geometries)".into(),
        };
        self.measure(&first_name, &first)?;
        let mut report = self.analyse()?;
        fits.push(FitStep { after: first_name, report: to_json(&report) });
        match self.plan.policy {
            Policy::Paper => self.refine_like_the_paper(&mut report, &mut fits, &mut refinements)?,
            Policy::Adaptive(targets) => {
                self.refine_adaptively(targets, &mut report, &mut fits, &mut refinements)?;
                // Never below the paper's criterion: if the batches did not get σ > σ_l, the
                // paper's policy finishes the job.
                self.refine_like_the_paper(&mut report, &mut fits, &mut refinements)?;
            }
            Policy::Fixed(_) => {}
        }
        let (white_drift, white_drift_exceeded) = if self.plan.white_check { self.white_check()? } else { (None, false) };
        self.device_time_used_us += self.uptime_us()?.saturating_sub(measuring_from_us);
        let calibration = self.calibration.take().ok_or(SessionError::Fit("no calibration".into()))?;
        Ok(Outcome {
            points: self.points,
            calibration,
            fits,
            refinements,
            report,
            device_seconds: self.device_time_used_us as f64 * 1e-6,
            setup_seconds,
            white_drift,
            white_drift_exceeded,
            flags: if white_drift_exceeded { vec![crate::analysis::flags::Flag::WhiteDrift] } else { Vec::new() },
        })
    }

    /// The paper's policy: Strategy 2 with decreasing δ until σ > σ_l, sending only
    /// geometries not measured yet.
    fn refine_like_the_paper(&mut self, report: &mut Report, fits: &mut Vec<FitStep>, refinements: &mut Vec<Refinement>) -> Result<(), SessionError> {
        for delta in (1..=10u8).rev() {
            let check = report.check;
            if check.is_some_and(|c| c.sigma_ok) {
                break;
            }
            let schedule: Vec<Geometry> = strategy2(delta).map(|s| s.to_vec()).unwrap_or_default();
            let added = schedule.iter().filter(|g| !self.measured().contains(g)).count();
            if added == 0 {
                continue;
            }
            let reason = match (report.fit.sigma_deg(), check) {
                (Some(sigma), Some(c)) => format!("σ = {sigma:.3}° ≤ σ_l = {:.3}° (δ = {:.1}°)", c.sigma_l_deg, c.delta_deg),
                (None, _) => "σ not resolved by the geometries measured".to_string(),
                (Some(sigma), None) => format!("σ = {sigma:.3}° but no δ: no neighbours of the specular direction"),
            };
            self.recorder.decision(&format!("refine with Strategy 2 at δ = {delta}° ({added} new geometries): {reason}"));
            refinements.push(Refinement { delta_deg: Some(delta), added, reason });
            self.measure(&format!("strategy 2, δ = {delta}° ({added} new geometries)"), &schedule)?;
            *report = self.analyse()?;
            fits.push(FitStep { after: format!("strategy2 δ={delta}°"), report: to_json(report) });
        }
        Ok(())
    }

    /// The adaptive policy ([`crate::session::adaptive`]): batches where they shrink σ's
    /// uncertainty most per device second, until the targets are met. Rough papers whose
    /// Strategy 1 already passes σ_l stop at once: their class rests on ρs and ρd, which
    /// Strategy 1 measures, and more readings near the peak would not move it.
    fn refine_adaptively(&mut self, targets: AdaptiveTargets, report: &mut Report, fits: &mut Vec<FitStep>, refinements: &mut Vec<Refinement>) -> Result<(), SessionError> {
        for batch_number in 1..=targets.max_batches {
            let sigma_ok = report.check.is_some_and(|c| c.sigma_ok);
            let rough = report.classification.group == Some(crate::analysis::classify::Group::Rough);
            let precise = adaptive::sigma_rel_half_width(&report.fit).is_some_and(|w| w <= targets.sigma_rel_half_width);
            let settled = report.classification.confidence >= targets.class_confidence;
            if sigma_ok && (rough || (precise && settled)) {
                return Ok(());
            }
            let observations: Vec<Observation> = self.usable_points().map(|(_, o)| o).collect();
            let measured = self.measured();
            let here = self.arm_position()?;
            let integration_ms = u32::from(self.plan.integration_ms);
            let (batch, reason) = if adaptive::sigma_resolved(&report.fit) {
                let batch = adaptive::next_batch(&report.fit, &observations, &measured, here, &self.motion, integration_ms, targets.batch);
                let width = adaptive::sigma_rel_half_width(&report.fit).unwrap_or(f64::INFINITY);
                (batch, format!("σ = {:.3}° ± {:.1} % (95 %), class {} at {:.2}{}", report.fit.sigma_deg().unwrap_or(f64::NAN), 100.0 * width, report.classification.class_name(), report.classification.confidence, if sigma_ok { "" } else { ", σ ≤ σ_l" }))
            } else {
                (Some(adaptive::probe(&observations, &measured)), "σ not resolved: probe around the strongest specular peak".to_string())
            };
            let Some(batch) = batch.filter(|b| !b.is_empty()) else {
                self.recorder.decision("adaptive: no geometry left that would help; the paper's policy takes over if σ ≤ σ_l");
                return Ok(());
            };
            self.recorder.decision(&format!("adaptive batch {batch_number} ({} geometries): {reason}", batch.len()));
            refinements.push(Refinement { delta_deg: None, added: batch.len(), reason });
            self.measure(&format!("adaptive batch {batch_number} ({} geometries)", batch.len()), &batch)?;
            *report = self.analyse()?;
            fits.push(FitStep { after: format!("adaptive batch {batch_number}"), report: to_json(report) });
        }
        Ok(())
    }

    /// Where the arms are now.
    fn arm_position(&mut self) -> Result<Geometry, SessionError> {
        match self.retrying(Command::GetStatus)? {
            Reply::Status(status) => Ok(status.position),
            other => Err(LinkError::UnexpectedReply { command: "GetStatus", reply: Box::new(other) }.into()),
        }
    }

    /// Every usable reading as a fit observation with its index in `points`; a geometry
    /// measured twice (after a lost stream end) counts once.
    fn usable_points(&self) -> impl Iterator<Item = (usize, Observation)> + '_ {
        let mut seen = BTreeSet::new();
        self.points.iter().enumerate().filter_map(move |(k, p)| {
            let (Some(radiance_factor), Some(g)) = (p.radiance_factor, p.geometry()) else { return None };
            seen.insert(g).then_some((k, Observation { theta_i_deg: p.theta_i_deg, theta_r_deg: p.theta_r_deg, radiance_factor, std: p.std }))
        })
    }

    fn uptime_us(&mut self) -> Result<u64, SessionError> {
        match self.retrying(Command::GetStatus)? {
            Reply::Status(status) => Ok(status.uptime_us),
            other => Err(LinkError::UnexpectedReply { command: "GetStatus", reply: Box::new(other) }.into()),
        }
    }

    /// Geometries with a usable reading.
    fn measured(&self) -> BTreeSet<Geometry> {
        self.points.iter().filter(|p| p.radiance_factor.is_some()).filter_map(MeasuredPoint::geometry).collect()
    }

    /// A request, reconnecting and retrying once the link comes back.
    fn retrying(&mut self, command: Command) -> Result<Reply, SessionError> {
        for _ in 0..MAX_ATTEMPTS {
            match self.client.request(command.clone()) {
                Ok(reply) => return Ok(reply),
                Err(error) if recoverable(&error) => self.recover(&error)?,
                Err(error) => return Err(error.into()),
            }
        }
        Err(SessionError::GaveUp(MAX_ATTEMPTS))
    }

    /// After a link failure: reconnect, then make the instrument ready again.
    fn recover(&mut self, why: &LinkError) -> Result<(), SessionError> {
        self.reconnect(why)?;
        self.ensure_ready()
    }

    /// [`Session::make_ready`], through link failures.
    fn ensure_ready(&mut self) -> Result<(), SessionError> {
        for _ in 0..MAX_ATTEMPTS {
            match self.make_ready() {
                Err(SessionError::Link(error)) if recoverable(&error) => self.reconnect(&error)?,
                other => return other,
            }
        }
        Err(SessionError::GaveUp(MAX_ATTEMPTS))
    }

    /// After a link failure: wait for the instrument and say hello again.
    fn reconnect(&mut self, why: &LinkError) -> Result<(), SessionError> {
        self.recorder.decision(&format!("link lost ({why}); reconnecting"));
        for _ in 0..MAX_ATTEMPTS * 4 {
            let _ = self.client.transport_mut().reconnect();
            match self.client.hello() {
                Ok(_) => return Ok(()),
                Err(LinkError::Interrupted) => return Err(SessionError::Interrupted),
                Err(_) => self.client.transport_mut().pause(Duration::from_millis(500)),
            }
        }
        Err(SessionError::Link(LinkError::NoReply { seq: 0, command: "Hello", attempts: MAX_ATTEMPTS * 4 }))
    }

    /// Homed and lit, whatever happened before (a power cycle, a safe stop).
    fn make_ready(&mut self) -> Result<(), SessionError> {
        let Reply::Status(status) = self.client.request(Command::GetStatus)? else {
            return Err(SessionError::Fit("unexpected status reply".into()));
        };
        if let Some(fault) = status.fault {
            self.recorder.decision(&format!("instrument reports {fault}; homing again"));
        }
        if !(status.homed_i && status.homed_r) {
            self.recorder.stage("homing", 0);
            if let Reply::Homed(report) = self.client.request(Command::Home)? {
                for (arm, error) in [("source", report.step_error_i), ("detector", report.step_error_r)] {
                    if let Some(steps) = error.filter(|e| *e != 0) {
                        self.recorder.decision(&format!("{arm} arm lost {} steps ({:.4}°) before re-homing", -steps, -f64::from(steps) * protocol::Angle::RESOLUTION_DEG));
                    }
                }
            }
        }
        if self.calibration.is_some() {
            self.lamp_on()?;
        }
        Ok(())
    }

    fn lamp_on(&mut self) -> Result<(), SessionError> {
        self.retrying(Command::SetLamp { on: true }).map(|_| ())
    }

    /// Dark per range (lamp off), then the white tile at θr = 0 for every incidence angle.
    fn calibrate(&mut self) -> Result<(), SessionError> {
        self.recorder.stage("dark and white calibration", INCIDENCE_DEG.len());
        let integration_ms = self.plan.integration_ms;
        let Reply::Dark(dark) = self.retrying(Command::TakeDark { integration_ms })? else {
            return Err(SessionError::Fit("unexpected dark reply".into()));
        };
        self.lamp_on()?;
        self.operator.place(Placement::WhiteTile).map_err(SessionError::Operator)?;
        let mut white = Vec::new();
        for theta_i in INCIDENCE_DEG {
            self.retrying(Command::MoveTo(Geometry::from_whole_deg(theta_i, 0)))?;
            let Reply::Reading(reading) = self.retrying(Command::TakeReading { integration_ms, target: Target::WhiteReference, range: None })? else {
                return Err(SessionError::Fit("unexpected reading reply".into()));
            };
            white.push(WhitePoint { theta_i_deg: f64::from(theta_i), reading });
        }
        self.operator.place(Placement::Sample).map_err(SessionError::Operator)?;
        let gains = self.info.detector_ranges.iter().map(|r| f64::from(r.relative_gain)).collect();
        let calibration = Calibration::new(instrument_name(&self.info), self.tile, gains, dark.to_vec(), white);
        self.recorder.calibration(&calibration).map_err(SessionError::Record)?;
        self.calibration = Some(calibration);
        Ok(())
    }

    /// Measure every geometry of `schedule` not yet measured, re-measuring lost ones.
    fn measure(&mut self, stage: &str, schedule: &[Geometry]) -> Result<(), SessionError> {
        let is_builtin_s1 = strategy1(12).is_some_and(|s| s.as_slice() == schedule);
        self.recorder.stage(stage, schedule.len());
        for attempt in 0..MAX_ATTEMPTS {
            let measured = self.measured();
            let missing: Vec<Geometry> = schedule.iter().copied().filter(|g| !measured.contains(g)).collect();
            if missing.is_empty() {
                return self.calibrate_gains();
            }
            let source = if is_builtin_s1 && missing.len() == schedule.len() { None } else { Some(missing.as_slice()) };
            match self.run_schedule(source, schedule.len()) {
                Ok(()) => {}
                Err(SessionError::Link(error)) if recoverable(&error) => self.recover(&error)?,
                Err(SessionError::Stopped(reason)) => {
                    self.recorder.decision(&format!("the instrument stopped ({reason}); making it ready again"));
                    self.ensure_ready()?;
                }
                Err(other) => return Err(other),
            }
            if attempt > 0 {
                self.recorder.decision(&format!("re-measuring geometries lost on the link (attempt {})", attempt + 1));
            }
        }
        Err(SessionError::GaveUp(MAX_ATTEMPTS))
    }

    /// Run the built-in Strategy 1 (`None`) or upload and run a list, recording readings.
    fn run_schedule(&mut self, list: Option<&[Geometry]>, stage_len: usize) -> Result<(), SessionError> {
        let schedule_id = self.next_schedule_id;
        self.next_schedule_id = self.next_schedule_id.wrapping_add(1).max(1);
        let source = match list {
            None => ScheduleSource::Strategy1,
            Some(list) => {
                // The firmware visits a list in the order sent: send the fastest.
                let here = self.arm_position()?;
                let planned = crate::session::order::plan(&self.motion, here, list);
                if list.len() > 1 {
                    self.recorder.decision(&format!(
                        "visiting order of {} geometries: {:.2} s of travel, {:.3}× the {} and {:.2}× the order listed",
                        list.len(),
                        planned.travel_us as f64 * 1e-6,
                        planned.travel_ratio_to_best(),
                        if planned.exact { "fastest" } else { "lower bound" },
                        planned.travel_ratio_to_given()
                    ));
                }
                let list = planned.order.as_slice();
                let total_len = list.len() as u16;
                for (k, chunk) in list.chunks(SCHEDULE_CHUNK_LEN).enumerate() {
                    let geometries = heapless::Vec::from_slice(chunk).unwrap_or_default();
                    let offset = (k * SCHEDULE_CHUNK_LEN) as u16;
                    self.client.request(Command::UploadSchedule(ScheduleChunk { schedule_id, total_len, offset, geometries }))?;
                }
                ScheduleSource::Uploaded
            }
        };
        let run = RunSchedule { schedule_id, source, integration_ms: self.plan.integration_ms, target: Target::Sample };
        let Reply::ScheduleStarted { len, .. } = self.client.request(Command::RunSchedule(run))? else {
            return Err(SessionError::Fit("unexpected reply to RunSchedule".into()));
        };
        let mut seen = BTreeSet::new();
        let already = stage_len.saturating_sub(usize::from(len));
        let started = self.client.transport_mut().now();
        loop {
            match self.client.next_unsolicited(Duration::from_secs(5))? {
                Some(DeviceMessage::Reading(r)) if r.schedule_id == schedule_id => {
                    if !seen.insert(r.index) {
                        continue; // a duplicate
                    }
                    self.record(r.geometry, r.reading, schedule_id, r.index, r.device_time_us)?;
                    let done = seen.len();
                    let per_reading = (self.client.transport_mut().now() - started) / done as u32;
                    let remaining = per_reading * (usize::from(len) - done.min(usize::from(len))) as u32;
                    self.recorder.progress(Progress { done: already + done, planned: stage_len, remaining });
                }
                Some(DeviceMessage::ScheduleDone(done)) if done.schedule_id == schedule_id => {
                    return match done.error {
                        None | Some(ErrorCode::Aborted) => Ok(()),
                        Some(reason) => Err(SessionError::Stopped(reason)),
                    };
                }
                Some(DeviceMessage::Stopped { reason }) => return Err(SessionError::Stopped(reason)),
                // Stale messages of an earlier schedule: nothing to do with this one.
                Some(_) => {}
                // Silence: the end may have been lost on the link. Ask.
                None => {
                    if let Reply::Status(status) = self.retrying(Command::GetStatus)? {
                        if status.schedule.is_none_or(|(id, _)| id != schedule_id) {
                            return Ok(());
                        }
                    }
                }
            }
        }
    }

    fn record(&mut self, geometry: Geometry, reading: Reading, schedule_id: u16, index: u16, device_time_us: u64) -> Result<(), SessionError> {
        let (theta_i_deg, theta_r_deg) = (geometry.theta_i.deg(), geometry.theta_r.deg());
        let converted = self
            .calibration
            .as_ref()
            .ok_or(SessionError::Fit("no calibration".into()))?
            .radiance_factor(theta_i_deg, &reading);
        let (radiance_factor, std, note) = match converted {
            Ok((r, u)) => (Some(r), Some(u), None),
            Err(e) => (None, None, Some(e.to_string())),
        };
        let point = MeasuredPoint { theta_i_deg, theta_r_deg, radiance_factor, std, reading, schedule_id, index, device_time_us, note };
        self.recorder.point(&point).map_err(SessionError::Record)?;
        self.points.push(point);
        Ok(())
    }

    /// Fit everything measured so far, check σ against σ_l and classify.
    fn analyse(&self) -> Result<Report, SessionError> {
        // Lines of readings.csv: a header, then one per reading.
        let (indices, observations): (Vec<usize>, _) = self.usable_points().unzip();
        let shared = self.shared_errors_of(&indices)?;
        let set = DataSet { sample: self.plan.sample.clone(), observations, lines: indices.iter().map(|k| k + 2).collect() };
        let options = FitOptions { acceptance_deg: Some(self.plan.acceptance_deg), ..FitOptions::default() };
        analyse_with_shared(std::path::Path::new("readings.csv"), &set, &shared, &options, None).map_err(SessionError::Fit)
    }

    /// Re-read the white tile at θi = 20°, θr = 0 and compare with the calibration.
    fn white_check(&mut self) -> Result<(Option<f64>, bool), SessionError> {
        self.operator.place(Placement::WhiteTile).map_err(SessionError::Operator)?;
        self.retrying(Command::MoveTo(Geometry::from_whole_deg(20, 0)))?;
        let integration_ms = self.plan.integration_ms;
        let Reply::Reading(reading) = self.retrying(Command::TakeReading { integration_ms, target: Target::WhiteReference, range: None })? else {
            return Err(SessionError::Fit("unexpected reading reply".into()));
        };
        self.operator.place(Placement::Sample).map_err(SessionError::Operator)?;
        let calibration = self.calibration.as_ref().ok_or(SessionError::Fit("no calibration".into()))?;
        let (r, _) = calibration.radiance_factor(20.0, &reading)?;
        let drift = r / calibration.white_radiance_factor - 1.0;
        let exceeded = drift.abs() > self.plan.white_drift_limit;
        if exceeded {
            self.recorder.decision(&format!("white drifted by {:.2} % (limit {:.2} %): result marked", 100.0 * drift, 100.0 * self.plan.white_drift_limit));
        }
        Ok((Some(drift), exceeded))
    }
}

/// Failures a reconnection can cure.
fn recoverable(error: &LinkError) -> bool {
    match error {
        LinkError::Io(_) | LinkError::NoReply { .. } => true,
        // A device that was reset or re-plugged wants a new hello.
        LinkError::Device { error, .. } => error.code == ErrorCode::VersionMismatch,
        _ => false,
    }
}
