//! The sweep policy as the session runs it: its targets; a stage of sweeps measured on the
//! instrument, each sweep's bins recorded as they stream, and whatever of its θr range is
//! left without a usable bin — bins lost on the link, bins blanked by a range switch or
//! empty, bins superseded after lost steps — measured again by short sweeps over just
//! those intervals, until every planned sweep is covered; then the rounds of sweeps across
//! the peak. What to sweep is designed in [`crate::analysis::sweep_design`]; how a bin
//! becomes a reading is [`super::sweep_bins`]'s.
use super::recovery::Failure;
use super::sweep_bins::{BinReading, bin_point};
use super::{MeasuredPoint, Progress, Session, SessionError, StepError};
use crate::analysis::sweep_design::{self, BinStamp, SweepPlan, dwell_centres_steps, min_bin_deg};
use crate::instrument::link::{LinkError, Transport};
use firmware::motion::angle_to_steps;
use protocol::{Angle, Command, DeviceMessage, Reply, Sweep, SweepBin, Target};
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::time::Duration;

/// Targets and limits of the sweep policy.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepTargets {
    /// The first pass's (and the full plane's) top speed, °/s (the instrument's own maximum at most).
    pub(crate) pass_speed_deg_per_s: f64,
    /// The first pass's (and the full plane's) bin length, degrees.
    pub(crate) pass_bin_deg: f64,
    /// Stop when σ's 95 % half-width relative to σ is at most this …
    pub(crate) sigma_rel_half_width: f64,
    /// … and the class confidence is at least this (the adaptive policy's targets).
    pub class_confidence: f64,
    /// Sweeps across the peak per round (one fit after each round).
    pub(crate) sweeps_per_round: usize,
    /// Rounds before giving up on the targets.
    pub(crate) max_rounds: usize,
}

impl Default for SweepTargets {
    fn default() -> Self {
        let adaptive = crate::session::adaptive::AdaptiveTargets::default();
        SweepTargets {
            pass_speed_deg_per_s: 60.0,
            pass_bin_deg: 0.1,
            sigma_rel_half_width: adaptive.sigma_rel_half_width,
            class_confidence: adaptive.class_confidence,
            sweeps_per_round: 2,
            max_rounds: 4,
        }
    }
}

/// Least relative narrowing of σ's interval a round of peak sweeps must be predicted to
/// bring for it to be run.
const MIN_PREDICTED_GAIN: f64 = 0.1;

/// Rounds of a sweep stage without a new bin before the session gives up on it.
const MAX_STALLED_ROUNDS: u32 = 6;

/// How far apart two bins' intervals may be and still count as touching, degrees: the
/// lag correction moves a bin's recorded middle by v·τ (0.03° at 60 °/s on the most
/// sensitive range) and the step counts' quantisation by a tick.
const COVER_TOLERANCE_DEG: f64 = 0.05;

/// The shortest stretch measured again, degrees: shorter gaps are closed by a sweep of
/// this length about them (a few bins, a triangular profile).
const SHORTEST_RESWEEP_DEG: f64 = 0.5;

/// The widest stretch left without a usable bin by a range switch's blanking that is not
/// measured again, degrees. A switch blanks its block and the new range's settling (at
/// most 4.5 ms, 5 blocks: 0.36° at 60 °/s, with the part-blanked bins either side under
/// 0.5°); the bins either side are there, and where σ needs the flank the peak sweeps
/// that follow are slow (15 °/s: a blanking of 0.09°). A re-sweep of such a stretch costs
/// an approach, a settle and two ramps (≈ 0.6 s of device time each) and would be
/// blanked at the same level again. Stretches lost on the link, or superseded after lost
/// steps, are always measured again.
const MAX_BLANKED_GAP_DEG: f64 = 0.5;

/// Device time a sweep of its own costs besides its travel, seconds, at the least: the
/// request and its answer, the approach, the settle (100 ms on the reference instrument),
/// the ramps up and down (a 0.5° stretch at 180 °/s² is ramps only, 0.1 s) and the wait for
/// its end. Stretches to measure again closer than the sweep covers in this time (30° at
/// 60 °/s, 7.5° at 15 °/s) are swept as one: the ground between them costs less swept
/// than travelled to and started afresh. On a link that loses one frame in five (corrupt
/// 0.01, drop 0.02) the first pass left 263 stretches a few tenths of a degree apart,
/// each swept on its own, and a sweep session of G reached its 600 s bound on device time
/// with them (issue 30); swept as one per line they take a few rounds of a few seconds.
const MERGE_GAP_S: f64 = 0.5;

/// The stretches of `lo ..= hi` that `intervals` (sorted here) leave uncovered, beyond
/// [`COVER_TOLERANCE_DEG`].
fn gaps_in(lo: f64, hi: f64, intervals: &mut [(f64, f64)]) -> Vec<(f64, f64)> {
    intervals.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut at = lo;
    let mut gaps = Vec::new();
    for &(a, b) in intervals.iter().filter(|(a, b)| *b > lo && *a < hi) {
        if a > at + COVER_TOLERANCE_DEG {
            gaps.push((at, a));
        }
        at = at.max(b);
    }
    if hi > at + COVER_TOLERANCE_DEG {
        gaps.push((at, hi));
    }
    gaps
}

impl<T: Transport> Session<'_, T> {
    /// Measure every sweep of `plans` (and any wanted sweep still not covered), measuring
    /// again what was lost.
    pub(super) fn sweep_stage(
        &mut self,
        stage: &str,
        plans: &[SweepPlan],
    ) -> Result<(), SessionError> {
        for plan in plans {
            if !self.wanted_sweeps.contains(plan) {
                self.wanted_sweeps.push(*plan);
            }
        }
        let planned: usize = if plans.is_empty() {
            self.uncovered_sweeps().iter().map(SweepPlan::bins).sum()
        } else {
            plans.iter().map(SweepPlan::bins).sum()
        };
        self.recorder.stage(stage, planned);
        let mut stalled = 0;
        let mut round = 0;
        let mut done = 0;
        loop {
            let gaps = self.uncovered_sweeps();
            if gaps.is_empty() {
                return self.calibrate_gains();
            }
            round += 1;
            self.within_device_time()?;
            if round > 1 {
                let bins: usize = gaps.iter().map(SweepPlan::bins).sum();
                self.remeasure_round(&format!(
                    "{} stretch{} of sweeps, {bins} bins",
                    gaps.len(),
                    if gaps.len() == 1 { "" } else { "es" }
                ))?;
                self.decide(&format!(
                    "measuring again {} stretch{} of θr left without a usable bin (lost on the link, blanked by a range switch over more than {MAX_BLANKED_GAP_DEG}°, or superseded), {bins} bins (round {round})",
                    gaps.len(),
                    if gaps.len() == 1 { "" } else { "es" }
                ));
            }
            let before = self.points.len();
            for plan in gaps {
                match self.run_sweep(&plan, &mut done, planned) {
                    Ok(()) => {}
                    Err(StepError::Failure(failure)) => {
                        self.recover(failure)?;
                        break;
                    }
                    Err(StepError::Fatal(error)) => return Err(error),
                }
            }
            if self.points.len() == before {
                stalled += 1;
                if stalled >= MAX_STALLED_ROUNDS {
                    return Err(SessionError::GaveUp(format!(
                        "{} sweeps still not covered after {stalled} rounds without a bin: the link or the instrument is failing",
                        self.uncovered_sweeps().len()
                    )));
                }
            } else {
                stalled = 0;
            }
        }
    }

    /// The sweep policy after its first pass: rounds of sweeps across the specular
    /// peak, designed on the current fit by the drop of σ's variance per device second
    /// ([`sweep_design::design_peak_sweeps`]), until σ is known to the target and the class
    /// is settled, as the adaptive policy stops (a rough paper whose pass already passes
    /// σ_l stops at once). A fit whose σ the pass did not resolve gets slow sweeps across
    /// every incidence's specular direction first; a fit flagged lack-of-fit carries on
    /// only while its σ is not known well, and keeps its flag.
    pub(super) fn refine_by_sweeps(
        &mut self,
        targets: SweepTargets,
        report: &mut crate::analysis::result::Report,
        fits: &mut Vec<super::FitStep>,
        refinements: &mut Vec<super::Refinement>,
    ) -> Result<(), SessionError> {
        let SweepTargets {
            sigma_rel_half_width,
            class_confidence,
            max_rounds,
            ..
        } = targets;
        for round in 1..=max_rounds {
            let sigma_ok = report.check.is_some_and(|c| c.sigma_ok);
            let rough =
                report.classification.group == Some(crate::analysis::classify::Group::Rough);
            let width = super::adaptive::sigma_rel_half_width(&report.fit);
            let precise = width.is_some_and(|w| w <= sigma_rel_half_width);
            let settled = report.classification.confidence >= class_confidence;
            // A model grown by a term was chosen on the incidences swept so far: the others
            // test it (a σ that varies with θi is then read between them, not interpolated)
            // before it is reported, as a flagged fit's are.
            let extended = super::extended_model(&report.fit);
            let done = sigma_ok && (rough || (precise && settled)) && !report.fit.lack_of_fit;
            if done && extended.is_none() {
                return Ok(());
            }
            let here = self.status()?.position;
            let block_s = self.block_s();
            // A fit the model does not describe is tested on the whole plane before it is
            // reported.
            let why = if report.fit.lack_of_fit {
                Some(format!(
                    "lack-of-fit after {} readings (χ² p = {:.1e})",
                    report.fit.n,
                    report.fit.gof_p.unwrap_or(f64::NAN)
                ))
            } else {
                extended
            };
            if let Some(why) = why
                && self.full_plane_round(round, here, &targets, &why, report, fits, refinements)?
            {
                continue;
            }
            if done {
                return Ok(());
            }
            if report.fit.lack_of_fit && precise && sigma_ok {
                self.decide("sweeps: lack-of-fit with σ known to its target: the bins already span the whole plane, more would not tell the model from the sheet; the result keeps the flag");
                return Ok(());
            }
            let (plans, reason, predicted) =
                self.peak_round_design(&targets, report, width, here, block_s);
            if plans.is_empty() {
                self.decide("sweeps: no sweep left that would help; the result is as measured");
                return Ok(());
            }
            // What the readings share (or a sheet the model does not describe) can leave σ's
            // interval where more sweeps will not move it: rounds that would narrow it by
            // under a tenth are not run.
            if let (Some(now), Some(after)) = (width, predicted)
                && after > (1.0 - MIN_PREDICTED_GAIN) * now
            {
                self.decide(&format!(
                    "sweeps: the best sweeps across the peak would take σ's interval only from ± {:.1} % to ± {:.1} %; the result is as measured",
                    100.0 * now,
                    100.0 * after
                ));
                return Ok(());
            }
            let (name, lack_of_fit) = (format!("sweep round {round}"), report.fit.lack_of_fit);
            let stage = format!("{name} ({})", sweeps_text(plans.len()));
            self.sweep_round(
                &name,
                &stage,
                reason,
                lack_of_fit,
                &plans,
                report,
                fits,
                refinements,
            )?;
        }
        Ok(())
    }

    /// The rest of the full plane, for a fit flagged lack-of-fit or a model extended (`why`
    /// says which): the lines the first pass left out may show where the sheet departs
    /// from the model (or that the departure was the noise's), and a flag or a term then
    /// rests on every incidence of Strategy 1. Whether a round was measured (none is left
    /// once the whole plane is).
    #[allow(clippy::too_many_arguments)]
    fn full_plane_round(
        &mut self,
        round: usize,
        here: protocol::Geometry,
        targets: &SweepTargets,
        why: &str,
        report: &mut crate::analysis::result::Report,
        fits: &mut Vec<super::FitStep>,
        refinements: &mut Vec<super::Refinement>,
    ) -> Result<bool, SessionError> {
        let max_speed = f64::from(self.info.max_speed_deg_per_s);
        let rest = self.rest_of_full_plane(
            here,
            targets.pass_speed_deg_per_s.min(max_speed),
            targets.pass_bin_deg,
        );
        if rest.is_empty() {
            return Ok(false);
        }
        let incidences: Vec<String> = rest.iter().map(|p| format!("{}°", p.theta_i_deg)).collect();
        let reason = format!(
            "{why}: θr 0–{}° at θi = {} too, the rest of the full plane",
            sweep_design::THETA_R_MAX_DEG,
            incidences.join(" and ")
        );
        let stage = format!(
            "sweep round {round}: the rest of the full plane ({})",
            sweeps_text(rest.len())
        );
        self.sweep_round(
            &format!("sweep round {round}"),
            &stage,
            reason,
            true,
            &rest,
            report,
            fits,
            refinements,
        )?;
        Ok(true)
    }

    /// The next round of sweeps across the peak, with why and σ's predicted relative half
    /// width after it: designed on the fit when σ is known, else slow sweeps across the
    /// specular direction at every incidence.
    fn peak_round_design(
        &self,
        targets: &SweepTargets,
        report: &crate::analysis::result::Report,
        width: Option<f64>,
        here: protocol::Geometry,
        block_s: f64,
    ) -> (Vec<SweepPlan>, String, Option<f64>) {
        use sweep_design::{design_peak_sweeps, peak_candidates};
        let max_speed = f64::from(self.info.max_speed_deg_per_s);
        match report.fit.sigma_deg() {
            Some(_) if width.is_some() => {
                let observations: Vec<_> = self.usable_points().map(|(_, o)| o).collect();
                let per_block = self.per_block_variance();
                let design = design_peak_sweeps(
                    &report.fit,
                    &observations,
                    here,
                    &self.motion,
                    max_speed,
                    block_s,
                    &per_block,
                    targets.sigma_rel_half_width,
                    targets.sweeps_per_round,
                );
                let reason = format!(
                    "σ = {:.3}° ± {:.1} % (95 %), class {} at {:.2}: {} sweep{} across the peak predicted to bring it to ± {:.1} % in {:.1} device s",
                    report.fit.sigma_deg().unwrap_or(f64::NAN),
                    100.0 * width.unwrap_or(f64::INFINITY),
                    report.classification.class_name(),
                    report.classification.confidence,
                    design.plans.len(),
                    if design.plans.len() == 1 { "" } else { "s" },
                    100.0 * design.predicted_rel_half_width,
                    design.seconds
                );
                (design.plans, reason, Some(design.predicted_rel_half_width))
            }
            _ => {
                // Unresolved: slow sweeps across specular at every incidence, bins fine
                // enough for the narrowest lobe the fit allows.
                let plans: Vec<SweepPlan> = peak_candidates(
                    0.25,
                    report.fit.acceptance_deg,
                    max_speed,
                    block_s,
                    here.theta_r.deg(),
                )
                .into_iter()
                .filter(|p| p.speed_deg_per_s == 15.0_f64.min(max_speed))
                .collect();
                (
                    plans,
                    "σ not resolved by the pass: slow sweeps across the specular direction at every incidence".to_string(),
                    None,
                )
            }
        }
    }

    /// One round of sweeps as a refinement: the decision (`name`, its sweeps and bins,
    /// `reason`), the refinement's record, the sweeps measured as stage `stage`, and the fit
    /// after them, recorded as after `name`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn sweep_round(
        &mut self,
        name: &str,
        stage: &str,
        reason: String,
        lack_of_fit: bool,
        plans: &[SweepPlan],
        report: &mut crate::analysis::result::Report,
        fits: &mut Vec<super::FitStep>,
        refinements: &mut Vec<super::Refinement>,
    ) -> Result<(), SessionError> {
        let bins: usize = plans.iter().map(SweepPlan::bins).sum();
        self.decide(&format!(
            "{name} ({}, {bins} bins): {reason}",
            sweeps_text(plans.len())
        ));
        refinements.push(super::Refinement {
            delta_deg: None,
            added: bins,
            reason,
            lack_of_fit,
        });
        self.sweep_stage(stage, plans)?;
        *report = self.analyse()?;
        fits.push(super::FitStep {
            after: name.to_string(),
            report: crate::analysis::result::to_json(report),
        });
        Ok(())
    }

    /// The full plane's lines ([`sweep_design::full_plane`]) that no wanted sweep has run
    /// whole yet, in the order fastest from `here`.
    fn rest_of_full_plane(
        &self,
        here: protocol::Geometry,
        speed_deg_per_s: f64,
        bin_deg: f64,
    ) -> Vec<SweepPlan> {
        let whole = |p: &SweepPlan| {
            p.from_deg.min(p.to_deg) <= 0.0
                && p.from_deg.max(p.to_deg) >= sweep_design::THETA_R_MAX_DEG
        };
        let missing: Vec<i32> = protocol::schedules::INCIDENCE_DEG
            .into_iter()
            .filter(|&theta_i| {
                !self
                    .wanted_sweeps
                    .iter()
                    .any(|p| p.theta_i_deg == f64::from(theta_i) && whole(p))
            })
            .collect();
        sweep_design::lines_from(&self.motion, here, &missing, speed_deg_per_s, bin_deg)
    }

    /// The predicted variance of one detector block's radiance factor at a radiance
    /// factor, from the readings taken: each reading's variance times its blocks, fitted
    /// as a floor and a relative term.
    pub(super) fn per_block_variance(&self) -> impl Fn(f64) -> f64 + use<T> {
        let per_block: Vec<crate::analysis::fit::Observation> = self
            .usable_points()
            .filter_map(|(k, o)| {
                let blocks = f64::from(self.points[k].reading.samples.max(1));
                Some(crate::analysis::fit::Observation {
                    std: Some(o.std? * blocks.sqrt()),
                    ..o
                })
            })
            .collect();
        let noise = super::adaptive::NoiseModel::fit(&per_block);
        move |r: f64| noise.variance(r)
    }

    /// The sweeps that would cover what the wanted sweeps still lack: for each wanted sweep,
    /// its θr range less the intervals of the usable bins at its incidence (converted and not
    /// superseded, or saturated: measuring those again would saturate again), each gap
    /// widened to [`SHORTEST_RESWEEP_DEG`], at the sweep's speed and bin length.
    pub(super) fn uncovered_sweeps(&self) -> Vec<SweepPlan> {
        let mut out = Vec::new();
        for plan in &self.wanted_sweeps {
            let (lo, hi) = (
                plan.from_deg.min(plan.to_deg),
                plan.from_deg.max(plan.to_deg),
            );
            let mut covered: Vec<(f64, f64)> = self
                .points
                .iter()
                .filter(|p| {
                    !p.superseded && p.theta_r_span_deg > 0.0 && p.theta_i_deg == plan.theta_i_deg
                })
                .filter(|p| p.radiance_factor.is_some() || p.reading.saturated)
                .map(|p| {
                    (
                        p.theta_r_deg - 0.5 * p.theta_r_span_deg,
                        p.theta_r_deg + 0.5 * p.theta_r_span_deg,
                    )
                })
                .collect();
            // Every bin received (usable or blanked): a gap only blanked bins fill was
            // received, and a short one is left as it is (MAX_BLANKED_GAP_DEG).
            let mut received: Vec<(f64, f64)> = self
                .points
                .iter()
                .filter(|p| {
                    !p.superseded && p.theta_r_span_deg > 0.0 && p.theta_i_deg == plan.theta_i_deg
                })
                .map(|p| {
                    (
                        p.theta_r_deg - 0.5 * p.theta_r_span_deg,
                        p.theta_r_deg + 0.5 * p.theta_r_span_deg,
                    )
                })
                .collect();
            let not_received = gaps_in(lo, hi, &mut received);
            let gaps: Vec<(f64, f64)> = gaps_in(lo, hi, &mut covered)
                .into_iter()
                .filter(|&(a, b)| {
                    b - a > MAX_BLANKED_GAP_DEG || not_received.iter().any(|&(c, d)| c < b && d > a)
                })
                .collect();
            let block_s = self.block_s();
            let shortest =
                SHORTEST_RESWEEP_DEG.max(2.0 * min_bin_deg(plan.speed_deg_per_s, block_s));
            let tick = Angle::RESOLUTION_DEG;
            // In the wanted sweep's direction, so that a whole sweep runs as planned (the
            // passes alternate to start each sweep where the last one ended).
            let backwards = plan.to_deg < plan.from_deg;
            let widened = gaps.into_iter().map(|(a, b)| {
                let middle = 0.5 * (a + b);
                let half = (0.5 * (b - a)).max(0.5 * shortest);
                (
                    ((middle - half).max(0.0) / tick).floor() * tick,
                    ((middle + half) / tick).ceil() * tick,
                )
            });
            // Stretches closer than the sweep covers in MERGE_GAP_S are one: sweeping the
            // ground between them costs less than a sweep of its own.
            let merge_deg = MERGE_GAP_S * plan.speed_deg_per_s;
            let mut merged: Vec<(f64, f64)> = Vec::new();
            for (low, high) in widened {
                match merged.last_mut() {
                    Some(last) if low - last.1 <= merge_deg => last.1 = last.1.max(high),
                    _ => merged.push((low, high)),
                }
            }
            let mut stretches: Vec<SweepPlan> = merged
                .into_iter()
                .map(|(low, high)| {
                    let bin_deg = plan
                        .bin_deg
                        .min(high - low)
                        .max(min_bin_deg(plan.speed_deg_per_s, block_s));
                    let (from_deg, to_deg) = if backwards { (high, low) } else { (low, high) };
                    SweepPlan {
                        from_deg,
                        to_deg,
                        bin_deg,
                        ..*plan
                    }
                })
                .collect();
            if backwards {
                stretches.reverse();
            }
            out.extend(stretches);
        }
        out
    }

    /// One detector block, seconds, as the instrument announced it.
    pub(super) fn block_s(&self) -> f64 {
        f64::from(self.info.detector_block_us.max(1)) * 1e-6
    }

    /// Run one sweep and record its bins; the lost ones are found by [`Self::uncovered_sweeps`].
    fn run_sweep(
        &mut self,
        plan: &SweepPlan,
        done: &mut usize,
        planned: usize,
    ) -> Result<(), StepError> {
        let mut received = Vec::new();
        let mut sent = None;
        let streamed = self.stream_sweep(plan, done, planned, &mut received, &mut sent);
        // The bins received are recorded however the sweep ended (the dwell model wants
        // the whole sweep's stamps), then checked against the lamp, then made durable.
        let recorded = self.record_bins(plan.theta_i_deg, sent.as_ref(), &received);
        let checked = match (streamed, recorded) {
            (_, Err(error)) => Err(StepError::Fatal(error)),
            (Ok(sweep_id), Ok(())) => self.lit_throughout(sweep_id),
            (Err(error), Ok(())) => Err(error),
        };
        let synced = self
            .recorder
            .sweep_done()
            .map_err(|e| StepError::Fatal(SessionError::record(e)));
        checked.and(synced)
    }

    /// Run the sweep, collecting its bins (once each) into `received` and the request the
    /// instrument accepted, with its bin count, into `sent`; the sweep's id when it ended.
    fn stream_sweep(
        &mut self,
        plan: &SweepPlan,
        done: &mut usize,
        planned: usize,
        received: &mut Vec<SweepBin>,
        sent: &mut Option<(Sweep, u16)>,
    ) -> Result<u16, StepError> {
        let sweep_id = self.next_schedule_id;
        self.next_schedule_id = self.next_schedule_id.wrapping_add(1).max(1);
        if let Some(failure) = self.lamp_went_out().map_err(StepError::Fatal)? {
            return Err(StepError::Failure(failure));
        }
        let (Some(theta_i), Some(from), Some(to)) = (
            Angle::from_deg(plan.theta_i_deg),
            Angle::from_deg(plan.from_deg),
            Angle::from_deg(plan.to_deg),
        ) else {
            return Err(StepError::Fatal(SessionError::Fit(format!(
                "a sweep outside the arms' angles: {plan:?}"
            ))));
        };
        let tick = Angle::RESOLUTION_DEG;
        let command = Sweep {
            sweep_id,
            theta_i,
            from,
            to,
            speed_mdeg_per_s: (plan.speed_deg_per_s * 1000.0).round() as u32,
            bin_ticks: (plan.bin_deg / tick)
                .round()
                .clamp(1.0, f64::from(u16::MAX)) as u16,
            range: None,
            target: Target::Sample,
        };
        let bins = match self.request(Command::Sweep(command))? {
            Reply::Sweep(planned) => planned.bins,
            other => {
                return Err(StepError::Fatal(
                    LinkError::UnexpectedReply {
                        command: "Sweep",
                        reply: Box::new(other),
                    }
                    .into(),
                ));
            }
        };
        *sent = Some((command, bins));
        let mut seen = BTreeSet::new();
        let started = self.now();
        loop {
            // Its end follows its last bin at once: past that bin, a silence of a reply's
            // time means the end was lost on the link (one frame in five at corrupt 0.01,
            // drop 0.02), and the status says so sooner than the 5 s wait that suits the
            // approach and the bins.
            let wait = if bins > 0 && seen.contains(&(bins - 1)) {
                self.client.policy().reply_timeout
            } else {
                Duration::from_secs(5)
            };
            let message = self
                .client
                .next_unsolicited(wait)
                .map_err(StepError::from_link)?;
            match message {
                Some(DeviceMessage::SweepBin(bin)) if bin.sweep_id == sweep_id => {
                    if !seen.insert(bin.index) {
                        continue; // a duplicate
                    }
                    received.push(bin);
                    *done += 1;
                    let per_bin = (self.now() - started) / seen.len() as u32;
                    let remaining = per_bin * u32::from(bins).saturating_sub(seen.len() as u32);
                    self.recorder.progress(Progress {
                        done: (*done).min(planned),
                        planned,
                        remaining,
                    });
                }
                Some(DeviceMessage::SweepDone { sweep_id: id, .. }) if id == sweep_id => {
                    self.link.recoveries.readings_remeasured +=
                        usize::from(bins).saturating_sub(seen.len());
                    return Ok(sweep_id);
                }
                Some(DeviceMessage::Stopped { reason }) => {
                    return Err(StepError::Failure(Failure::Stopped(reason)));
                }
                // Stale messages of an earlier schedule or sweep.
                Some(_) => {}
                // Silence: the end may have been lost on the link. Ask.
                None => {
                    if let Reply::Status(status) = self.request(Command::GetStatus)?
                        && status.schedule.is_none_or(|(id, _)| id != sweep_id)
                    {
                        // Bins lost on the link (a gap in the indices): measured again.
                        self.link.recoveries.readings_remeasured +=
                            usize::from(bins).saturating_sub(seen.len());
                        return Ok(sweep_id);
                    }
                }
            }
        }
    }

    /// Record a sweep's bins, each at where the arm stood on average while it was read
    /// ([`sweep_design::dwell_centres_steps`]; the middle of its interval when the model
    /// finds no phase of the block clock that gives the bins received).
    fn record_bins(
        &mut self,
        theta_i_deg: f64,
        sent: Option<&(Sweep, u16)>,
        bins: &[SweepBin],
    ) -> Result<(), SessionError> {
        if bins.is_empty() {
            return Ok(());
        }
        let centres = sent.and_then(|(command, total)| {
            let (from, to) = (angle_to_steps(command.from), angle_to_steps(command.to));
            let profile = self
                .motion
                .sweep_profile(from, to, command.speed_mdeg_per_s);
            let stamps: Vec<BinStamp> = bins
                .iter()
                .map(|b| BinStamp {
                    index: b.index,
                    end_steps: angle_to_steps(b.end),
                    blocks: b.blocks,
                    whole: !b.is_blanked() && !b.is_empty(),
                })
                .collect();
            dwell_centres_steps(
                &profile,
                from,
                to,
                command.bin_ticks,
                *total,
                self.info.detector_block_us,
                &stamps,
            )
        });
        if centres.is_none() {
            self.decide(&format!(
                "sweep {}: no phase of the block clock gives its {} bins' step counts as the firmware's profile would; the bins are taken at their intervals' middles",
                bins[0].sweep_id,
                bins.len()
            ));
        }
        for bin in bins {
            let centre_deg = centres
                .as_ref()
                .and_then(|c| c.get(usize::from(bin.index)).copied().flatten())
                .map(|steps| steps * Angle::RESOLUTION_DEG);
            self.record_bin(theta_i_deg, bin, centre_deg)?;
        }
        Ok(())
    }

    /// Record one bin: usable, or kept in the record with why it is not (blanked, empty).
    fn record_bin(
        &mut self,
        theta_i_deg: f64,
        bin: &SweepBin,
        centre_deg: Option<f64>,
    ) -> Result<(), SessionError> {
        let calibration = self
            .calibration
            .as_ref()
            .ok_or(SessionError::Fit("no calibration".into()))?;
        let reading = BinReading {
            start_deg: bin.start.deg(),
            end_deg: bin.end.deg(),
            mean_counts: bin.mean_counts,
            blocks: bin.blocks.max(1),
            range: bin.range,
            saturated: bin.is_saturated(),
            device_time_us: bin.device_time_us,
            centre_deg,
        };
        let tau_s = self
            .info
            .detector_ranges
            .get(usize::from(bin.range))
            .map_or(0.0, |r| f64::from(r.time_constant_us) * 1e-6);
        let mut point: MeasuredPoint = bin_point(
            theta_i_deg,
            &reading,
            bin.sweep_id,
            bin.index,
            self.block_s(),
            tau_s,
            calibration,
        );
        let unusable = if bin.is_empty() {
            Some("no usable detector block in this bin (all within a range switch's settling)")
        } else if bin.is_blanked() {
            Some(
                "blocks of this bin were dropped after a range switch: its mean is of part of its interval only; measured again",
            )
        } else {
            None
        };
        if let Some(why) = unusable {
            point.unusable = Some(why.to_string());
            point.convert_with(calibration);
        }
        self.recorder.point(&point).map_err(SessionError::record)?;
        self.points.push(point);
        Ok(())
    }
}

/// "1 sweep", "2 sweeps".
pub(super) fn sweeps_text(n: usize) -> String {
    format!("{n} sweep{}", if n == 1 { "" } else { "s" })
}
