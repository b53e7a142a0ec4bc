//! The design of sweeps, pure: the passes over whole lines and the order that is fastest
//! from where the arms are, their device time as the firmware will run them, the sweeps
//! across the specular peak chosen by the drop of σ's variance per device second, the bin
//! lengths, and the dwell model that places each bin where the arm stood on average.
//!
//! A sweep reads the detector arm while it moves at a constant top speed across θr with
//! the source arm held, one bin of detector blocks per few hundredths of a degree: it gets
//! a whole incidence's profile in the time Strategy 1 spends on a reading or two, because
//! the arms neither stop nor settle between its bins. Nothing here talks to the
//! instrument: the session runs the sweeps (`session::sweep_policy`), records their bins
//! (`session::sweep_bins`), and the fit models each bin's travel
//! ([`crate::analysis::model::evaluate_reading`]). The arms' times come through
//! [`ArmTiming`], which the instrument's motion model ([`crate::analysis::motion::Motion`])
//! implements.
use crate::analysis::fit::{FitResult, Observation};
use crate::analysis::linalg::spd_inverse_free;
use crate::analysis::model::{self, SIGMA};
use protocol::Geometry;
use serde::Serialize;

/// The arms' device times the design needs, as the firmware's motion profiles give them
/// ([`crate::analysis::motion::Motion`] implements it from the instrument's limits).
pub trait ArmTiming {
    /// The move of both arms from `from` to `to`, µs.
    fn move_us(&self, from: Geometry, to: Geometry) -> u64;
    /// Settling after a move, µs.
    fn settle_us(&self) -> u64;
    /// A sweep of the detector arm from `from_deg` to `to_deg` at a top speed of
    /// `speed_deg_per_s`, from rest to rest, µs.
    fn sweep_us(&self, from_deg: f64, to_deg: f64, speed_deg_per_s: f64) -> u64;
}

/// θr swept on every whole line (the first pass's and the full plane's), degrees (Strategy 1's and Table 2's
/// range).
pub const THETA_R_MAX_DEG: f64 = protocol::schedules::THETA_R_MAX_DEG as f64;

/// A sweep of the detector arm at one incidence.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SweepPlan {
    /// The source arm's angle, held, degrees.
    pub theta_i_deg: f64,
    /// Where the detector arm starts (at rest) and the first bin starts, degrees.
    pub from_deg: f64,
    /// Where it stops and the last bin ends, degrees (below `from_deg`: backwards).
    pub(crate) to_deg: f64,
    /// The profile's top speed, °/s (reached only where the sweep is long enough).
    pub(crate) speed_deg_per_s: f64,
    /// Bin length, degrees.
    pub(crate) bin_deg: f64,
}

impl SweepPlan {
    /// Bins the sweep gives: its length over the bin length, the last one shorter when
    /// they do not divide.
    pub fn bins(&self) -> usize {
        let length = (self.to_deg - self.from_deg).abs();
        ((length / self.bin_deg) - 1e-9).ceil().max(1.0) as usize
    }

    /// Where the arms are when it starts.
    pub fn start(&self) -> Option<Geometry> {
        Geometry::from_deg(self.theta_i_deg, self.from_deg)
    }

    /// Where they are when it ends.
    pub fn end(&self) -> Option<Geometry> {
        Geometry::from_deg(self.theta_i_deg, self.to_deg)
    }

    /// The sweep's own time (the detector arm from rest to rest), µs.
    pub(crate) fn sweep_us(&self, motion: &impl ArmTiming) -> u64 {
        motion.sweep_us(self.from_deg, self.to_deg, self.speed_deg_per_s)
    }
}

/// The sweep policy's first pass: θr over 0…70° at Strategy 1's lowest and highest
/// incidence only. Two lines hold every parameter (ρd off the peak, σ and ρs across it,
/// the Fresnel term's rise from 20° to 60°) and take 4.9 s from the park, where the four of
/// the full plane take 8.8 s (`the_pass_from_the_park_is_at_the_kinematic_floor`): a rough
/// paper needs nothing more, a glossy one's peak is then swept slowly where σ needs it, and
/// a fit the model does not describe gets the rest of the full plane before it is
/// reported (more lines for the goodness of fit to test).
pub(crate) const FIRST_PASS_INCIDENCE_DEG: [i32; 2] = [20, 60];

/// Sweeps of θr over 0…70° at each of `incidences_deg` in that order, at top speed
/// `speed_deg_per_s` and bins of `bin_deg`, the direction alternating so that each sweep
/// starts where the last one ended (the detector arm only waits for the source arm's move
/// between them).
pub fn lines(incidences_deg: &[i32], speed_deg_per_s: f64, bin_deg: f64) -> Vec<SweepPlan> {
    incidences_deg
        .iter()
        .enumerate()
        .map(|(k, &theta_i)| {
            let (from_deg, to_deg) = if k % 2 == 0 {
                (0.0, THETA_R_MAX_DEG)
            } else {
                (THETA_R_MAX_DEG, 0.0)
            };
            SweepPlan {
                theta_i_deg: f64::from(theta_i),
                from_deg,
                to_deg,
                speed_deg_per_s,
                bin_deg,
            }
        })
        .collect()
}

/// The full-plane pass: the four incidences of Strategy 1 (20°, 30°, 45°, 60°), as
/// [`lines`] lays them out.
pub fn full_plane(speed_deg_per_s: f64, bin_deg: f64) -> Vec<SweepPlan> {
    lines(
        &protocol::schedules::INCIDENCE_DEG,
        speed_deg_per_s,
        bin_deg,
    )
}

/// [`lines`] at `incidences_deg` (ascending) in the order that is fastest from where the
/// arms are (`here`): the incidences ascending or descending, the first sweep forwards or
/// backwards (then alternating). From the park position (85°, 85°) that is θi = 60° first,
/// from θr = 70°: for the full plane 1.3 s less device time than starting at (20°, 0°).
pub(crate) fn lines_from(
    motion: &impl ArmTiming,
    here: Geometry,
    incidences_deg: &[i32],
    speed_deg_per_s: f64,
    bin_deg: f64,
) -> Vec<SweepPlan> {
    let forwards = lines(incidences_deg, speed_deg_per_s, bin_deg);
    let flip = |plans: &[SweepPlan]| {
        plans
            .iter()
            .map(|p| SweepPlan {
                from_deg: p.to_deg,
                to_deg: p.from_deg,
                ..*p
            })
            .collect::<Vec<_>>()
    };
    let descending: Vec<SweepPlan> = {
        let mut d = forwards.clone();
        d.reverse();
        // Reversed, the last sweep's direction leads: keep each sweep starting where the
        // one before it ended.
        flip(&d)
    };
    let candidates = [
        flip(&forwards),
        descending.clone(),
        flip(&descending),
        forwards,
    ];
    candidates
        .into_iter()
        .min_by_key(|plans| device_us(motion, here, plans))
        .unwrap_or_default()
}

/// The full-plane pass in the order that is fastest from `here` ([`lines_from`]).
pub fn full_plane_from(
    motion: &impl ArmTiming,
    here: Geometry,
    speed_deg_per_s: f64,
    bin_deg: f64,
) -> Vec<SweepPlan> {
    lines_from(
        motion,
        here,
        &protocol::schedules::INCIDENCE_DEG,
        speed_deg_per_s,
        bin_deg,
    )
}

/// The sweep policy's first pass ([`FIRST_PASS_INCIDENCE_DEG`]) in the order that is
/// fastest from `here`.
pub(crate) fn first_pass_from(
    motion: &impl ArmTiming,
    here: Geometry,
    speed_deg_per_s: f64,
    bin_deg: f64,
) -> Vec<SweepPlan> {
    lines_from(
        motion,
        here,
        &FIRST_PASS_INCIDENCE_DEG,
        speed_deg_per_s,
        bin_deg,
    )
}

/// Device time of `plans` run in order from where the arms are (`here`): for each, the
/// move to its start and the settle after it, then the sweep, µs. A plan outside the
/// arms' angles counts as no time (the instrument refuses it before it moves).
pub fn device_us(motion: &impl ArmTiming, here: Geometry, plans: &[SweepPlan]) -> u64 {
    let mut at = here;
    let mut total = 0u64;
    for plan in plans {
        let (Some(start), Some(end)) = (plan.start(), plan.end()) else {
            continue;
        };
        let moving = motion.move_us(at, start);
        // A move of nothing needs no settling.
        let settling = if moving > 0 { motion.settle_us() } else { 0 };
        total = total
            .saturating_add(moving)
            .saturating_add(settling)
            .saturating_add(plan.sweep_us(motion));
        at = end;
    }
    total
}

/// A received bin as the dwell model needs it ([`dwell_centres_steps`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BinStamp {
    /// Its index in the sweep.
    pub index: u16,
    /// The detector arm's step count at the end of its last block.
    pub(crate) end_steps: i32,
    /// Blocks averaged.
    pub blocks: u16,
    /// Every block of its interval was averaged (not blanked, not empty): its block count
    /// is its length.
    pub whole: bool,
}

/// Where the detector arm stood on average while each bin's blocks were taken, steps: the
/// time-average of its step count over the bin, from the firmware's own profile of the
/// sweep (`profile`, started at rest at `from_steps`) and the instrument's block clock.
///
/// Why: the arm stands on whole microsteps between step pulses, and a bin's interval is
/// read from the step count at block ends. Its middle is where the arm was on average only
/// when the pulses fall at random within the blocks; they do not — the sweep's profile is
/// started on a poll of the block clock, so at 60 °/s (4.8 steps a block) the pulses keep
/// one phase against the blocks, and at low step rates (the ramps, slow sweeps) a bin's
/// few pulses fall late in it. The middle then trails the arm's mean by up to a third of a
/// step (0.004°), the same way in every bin of a sweep; at G's peak that biased σ by
/// +0.06 % and put its 95 % interval round the truth in 81 % of sessions.
///
/// The block clock's phase against the profile's start is not reported: it is found as
/// the one (to the µs) for which the firmware's binning (a bin closes on the first block
/// whose end passes its nominal end) gives every received bin's end step count, and every
/// whole bin's block count. `None` when no phase does (a profile or clock other than this
/// model's): the bins keep their middles. Bins not received are `None`.
pub(crate) fn dwell_centres_steps(
    profile: &firmware::motion::MoveProfile,
    from_steps: i32,
    to_steps: i32,
    bin_ticks: u16,
    bins: u16,
    block_us: u32,
    stamps: &[BinStamp],
) -> Option<Vec<Option<f64>>> {
    if stamps.is_empty() || bins == 0 || block_us == 0 || bin_ticks == 0 {
        return None;
    }
    let block = i64::from(block_us);
    let direction = (to_steps - from_steps).signum();
    let nominal_end = |index: u16| {
        if index + 1 >= bins {
            to_steps
        } else {
            from_steps + direction * (i32::from(index) + 1) * i32::from(bin_ticks)
        }
    };
    let position = |elapsed_us: i64| {
        if elapsed_us <= 0 {
            from_steps
        } else {
            profile.position_at(elapsed_us as u64)
        }
    };
    let last_block = (profile.duration_us() as i64) / block + 3;
    let by_index: std::collections::BTreeMap<u16, &BinStamp> =
        stamps.iter().map(|s| (s.index, s)).collect();
    // The block (counted from the first one the sweep's binning took) that closes each
    // bin, for the first block ending `first_end_us` after the profile's start; `None` as
    // soon as a received bin disagrees.
    let closing_blocks = |first_end_us: i64| -> Option<Vec<i64>> {
        let mut closing = Vec::with_capacity(usize::from(bins));
        let mut index = 0u16;
        let mut previous = -1i64;
        for j in 0..=last_block {
            if index >= bins {
                break;
            }
            let end = position(first_end_us + j * block);
            if direction * (end - nominal_end(index)) < 0 {
                continue;
            }
            if let Some(stamp) = by_index.get(&index)
                && (stamp.end_steps != end
                    || (stamp.whole && i64::from(stamp.blocks) != j - previous))
            {
                return None;
            }
            closing.push(j);
            previous = j;
            index += 1;
        }
        (index >= bins).then_some(closing)
    };
    // The first block ends within one block after the profile's start (a block that ended
    // before it was taken at rest), or up to one block before it on a board whose
    // interrupt came late.
    let matching: Vec<(i64, Vec<i64>)> = (-block + 1..=block)
        .filter_map(|first_end_us| closing_blocks(first_end_us).map(|c| (first_end_us, c)))
        .collect();
    if matching.is_empty() {
        return None;
    }
    let step_time_us = |k: u32| f64::from(profile.step_time_s(k)) * 1e6;
    let steps_done = |elapsed_us: i64| (position(elapsed_us) - from_steps).abs();
    // ∫ steps done dt over [a, b] µs: the count at b for the whole interval less, for each
    // pulse inside it, the time before it.
    let integral = |a: i64, b: i64| {
        let (done_a, done_b) = (steps_done(a), steps_done(b));
        let mut total = f64::from(done_b) * (b - a) as f64;
        for k in (done_a + 1)..=done_b {
            total -= (step_time_us(k as u32) - a as f64).max(0.0);
        }
        total
    };
    // Every phase that gives the bins is as likely (between pulses a bin's stamps cannot
    // tell them apart: at 7.5 °/s a pulse comes every 1.7 blocks): each bin's centre is
    // its mean over them.
    let mut sums = vec![0.0; usize::from(bins)];
    for (first_end_us, closing) in &matching {
        let mut start_block = 0i64;
        for (index, &j) in closing.iter().enumerate() {
            let (a, b) = (
                first_end_us + (start_block - 1) * block,
                first_end_us + j * block,
            );
            if b > a {
                sums[index] += integral(a, b) / (b - a) as f64;
            }
            start_block = j + 1;
        }
    }
    let phases = matching.len() as f64;
    let out = (0..usize::from(bins))
        .map(|index| {
            by_index
                .contains_key(&(index as u16))
                .then(|| f64::from(from_steps) + f64::from(direction) * sums[index] / phases)
        })
        .collect();
    Some(out)
}

/// The narrowest bin a sweep at `speed_deg_per_s` can have: one detector block's travel,
/// rounded up to the arms' 0.0125° ticks.
pub(crate) fn min_bin_deg(speed_deg_per_s: f64, block_s: f64) -> f64 {
    let tick = protocol::Angle::RESOLUTION_DEG;
    ((speed_deg_per_s * block_s / tick).ceil().max(1.0)) * tick
}

/// A bin length for a lobe of standard deviation `lobe_sd_deg` in θr swept at
/// `speed_deg_per_s`: a sixth of the lobe's width, so the bins resolve its shape (the fit
/// models their travel, so nothing is lost but resolution), and never under one block.
pub(crate) fn bin_for_lobe(lobe_sd_deg: f64, speed_deg_per_s: f64, block_s: f64) -> f64 {
    let tick = protocol::Angle::RESOLUTION_DEG;
    let wanted = ((lobe_sd_deg / 6.0) / tick).floor().max(1.0) * tick;
    wanted.max(min_bin_deg(speed_deg_per_s, block_s))
}

/// The lobe's standard deviation in θr as the detector sees it, degrees: the TS lobe's
/// 2σ widened by the acceptance window (a uniform window of width a adds a²/12).
pub(crate) fn lobe_sd_deg(sigma_deg: f64, acceptance_deg: Option<f64>) -> f64 {
    let a = acceptance_deg.unwrap_or(0.0);
    ((2.0 * sigma_deg).powi(2) + a * a / 12.0).sqrt()
}

/// Top speeds the design considers for sweeps across a peak, °/s: the instrument's
/// fastest and three slower ones, each halving the noise variance per degree.
pub(crate) const DESIGN_SPEEDS_DEG_PER_S: [f64; 4] = [60.0, 30.0, 15.0, 7.5];

/// Sweeps across the specular peak at each of Strategy 1's incidences: ±3 lobe standard
/// deviations (at least ±1°) about specular, at each of [`DESIGN_SPEEDS_DEG_PER_S`] (up to
/// the instrument's own top speed), bins from [`bin_for_lobe`], each started at the end
/// nearer the detector's position `from_theta_r_deg`.
pub(crate) fn peak_candidates(
    sigma_deg: f64,
    acceptance_deg: Option<f64>,
    max_speed_deg_per_s: f64,
    block_s: f64,
    from_theta_r_deg: f64,
) -> Vec<SweepPlan> {
    let sd = lobe_sd_deg(sigma_deg, acceptance_deg);
    let half = (3.0 * sd).clamp(1.0, 15.0);
    let tick = protocol::Angle::RESOLUTION_DEG;
    let round = |deg: f64| (deg / tick).round() * tick;
    let mut out = Vec::new();
    for &theta_i in &protocol::schedules::INCIDENCE_DEG {
        let centre = f64::from(theta_i);
        let (lo, hi) = (
            round((centre - half).max(0.0)),
            round((centre + half).min(THETA_R_MAX_DEG)),
        );
        let (from_deg, to_deg) = if (from_theta_r_deg - lo).abs() <= (from_theta_r_deg - hi).abs() {
            (lo, hi)
        } else {
            (hi, lo)
        };
        for &speed in DESIGN_SPEEDS_DEG_PER_S
            .iter()
            .filter(|&&v| v <= max_speed_deg_per_s)
        {
            out.push(SweepPlan {
                theta_i_deg: centre,
                from_deg,
                to_deg,
                speed_deg_per_s: speed,
                bin_deg: bin_for_lobe(sd, speed, block_s),
            });
        }
    }
    out
}

/// The information a sweep's bins would bring, as the fit would model them (each bin's
/// travel through the acceptance), with the noise `per_block_variance` predicts for one
/// detector block at a bin's radiance factor over the blocks a bin gets (the sweep's time
/// shared out over its bins).
pub(crate) fn sweep_information(
    fit: &FitResult,
    plan: &SweepPlan,
    motion: &impl ArmTiming,
    block_s: f64,
    per_block_variance: &dyn Fn(f64) -> f64,
) -> [[f64; 4]; 4] {
    let free = fit.model.0;
    let bins = plan.bins();
    let blocks = (plan.sweep_us(motion) as f64 * 1e-6 / block_s / bins as f64).max(1.0);
    let step = (plan.to_deg - plan.from_deg) / bins as f64;
    let mut information = [[0.0; 4]; 4];
    for k in 0..bins {
        let centre = plan.from_deg + (k as f64 + 0.5) * step;
        let (value, g) = model::evaluate_reading(
            &fit.params,
            plan.theta_i_deg,
            centre,
            step.abs(),
            fit.acceptance_deg,
        );
        let j: [f64; 4] = std::array::from_fn(|i| if free[i] { g[i] } else { 0.0 });
        let variance = (per_block_variance(value) / blocks).max(1e-18);
        for a in 0..4 {
            for b in 0..4 {
                information[a][b] += j[a] * j[b] / variance;
            }
        }
    }
    information
}

/// The information the readings taken bring (as the fit modelled them), each with the
/// variance it was given.
pub(crate) fn readings_information(fit: &FitResult, observations: &[Observation]) -> [[f64; 4]; 4] {
    let free = fit.model.0;
    let mut information = [[0.0; 4]; 4];
    for o in observations {
        let Some(std) = o.std else { continue };
        let (_, g) = model::evaluate_reading(
            &fit.params,
            o.theta_i_deg,
            o.theta_r_deg,
            o.theta_r_span_deg,
            fit.acceptance_deg,
        );
        let j: [f64; 4] = std::array::from_fn(|i| if free[i] { g[i] } else { 0.0 });
        let variance = (std * std).max(1e-18);
        for a in 0..4 {
            for b in 0..4 {
                information[a][b] += j[a] * j[b] / variance;
            }
        }
    }
    information
}

/// A design's choice: the sweeps, and what they are predicted to leave of σ's 95 %
/// half-width relative to σ.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SweepDesign {
    /// The sweeps, in the order to run them.
    pub plans: Vec<SweepPlan>,
    /// σ's predicted 95 % relative half-width after them.
    pub(crate) predicted_rel_half_width: f64,
    /// Their device time with the moves between them, seconds.
    pub seconds: f64,
    /// The drop of σ's variance (the readings' noise part, degrees²) they are predicted to
    /// bring.
    pub(crate) sigma_variance_drop: f64,
}

/// A candidate sweep of the design with its score (the drop of σ's variance per device
/// second), the information with it, σ's variance then, and its device seconds.
type Candidate = (f64, SweepPlan, [[f64; 4]; 4], f64, f64);

/// Sweeps across the peak chosen greedily by the drop of σ's variance per device second
/// (the move to each sweep's start, its settling and the sweep itself), until σ's 95 %
/// relative half-width is predicted to reach `target_rel_half_width` or `max_sweeps` are
/// chosen. The fit's variance of σ holds errors the readings share (the white, darks,
/// tile, gains) that more readings do not shrink: the prediction takes the fit's variance
/// less the part the readings' own noise leaves, which is what the sweeps reduce.
/// Nothing is chosen when σ is not fitted or no candidate helps.
#[allow(clippy::too_many_arguments)]
pub(crate) fn design_peak_sweeps(
    fit: &FitResult,
    observations: &[Observation],
    here: Geometry,
    motion: &impl ArmTiming,
    max_speed_deg_per_s: f64,
    block_s: f64,
    per_block_variance: &dyn Fn(f64) -> f64,
    target_rel_half_width: f64,
    max_sweeps: usize,
) -> SweepDesign {
    let none = SweepDesign {
        plans: Vec::new(),
        predicted_rel_half_width: f64::INFINITY,
        seconds: 0.0,
        sigma_variance_drop: 0.0,
    };
    let (Some(sigma), Some(se)) = (fit.sigma_deg(), fit.std_error(SIGMA)) else {
        return none;
    };
    let free = fit.model.0;
    let mut information = readings_information(fit, observations);
    let Some(noise_cov) = spd_inverse_free(&information, &free) else {
        return none;
    };
    // What the readings' noise contributes now; the rest of the fit's variance stays.
    let floor = (se * se - noise_cov[SIGMA][SIGMA]).max(0.0);
    let half_width = |noise_var: f64| 1.96 * (floor + noise_var).max(0.0).sqrt() / sigma;
    let mut noise_var = noise_cov[SIGMA][SIGMA];
    let noise_var_now = noise_var;
    let mut design = SweepDesign {
        plans: Vec::new(),
        predicted_rel_half_width: half_width(noise_var),
        seconds: 0.0,
        sigma_variance_drop: 0.0,
    };
    let mut at = here;
    while design.plans.len() < max_sweeps && design.predicted_rel_half_width > target_rel_half_width
    {
        let mut best: Option<Candidate> = None;
        for plan in peak_candidates(
            sigma,
            fit.acceptance_deg,
            max_speed_deg_per_s,
            block_s,
            at.theta_r.deg(),
        ) {
            let Some(start) = plan.start() else { continue };
            let added = sweep_information(fit, &plan, motion, block_s, per_block_variance);
            let total: [[f64; 4]; 4] =
                std::array::from_fn(|a| std::array::from_fn(|b| information[a][b] + added[a][b]));
            let Some(cov) = spd_inverse_free(&total, &free) else {
                continue;
            };
            let moving = motion.move_us(at, start);
            let seconds = (moving
                + if moving > 0 { motion.settle_us() } else { 0 }
                + plan.sweep_us(motion)) as f64
                * 1e-6;
            let score = (noise_var - cov[SIGMA][SIGMA]) / seconds;
            if score.is_finite() && score > 0.0 && best.as_ref().is_none_or(|b| score > b.0) {
                best = Some((score, plan, total, cov[SIGMA][SIGMA], seconds));
            }
        }
        let Some((_, plan, total, var, seconds)) = best else {
            break;
        };
        information = total;
        noise_var = var;
        design.plans.push(plan);
        design.seconds += seconds;
        design.predicted_rel_half_width = half_width(noise_var);
        design.sigma_variance_drop = noise_var_now - noise_var;
        at = plan.end().unwrap_or(at);
    }
    design
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::motion::Motion;

    #[test]
    fn a_full_plane_pass_covers_every_incidence_and_alternates() {
        let pass = full_plane(60.0, 0.1);
        assert_eq!(pass.len(), 4);
        for pair in pass.windows(2) {
            assert_eq!(
                pair[0].to_deg, pair[1].from_deg,
                "each sweep starts where the last ended"
            );
        }
        assert!(pass.iter().all(|p| p.bins() == 700));
    }

    #[test]
    fn the_pass_starts_at_the_end_nearest_the_arms() {
        let motion = Motion::reference();
        let park = Geometry::from_deg(85.0, 85.0).unwrap();
        let pass = full_plane_from(&motion, park, 60.0, 0.1);
        assert_eq!(
            (pass[0].theta_i_deg, pass[0].from_deg),
            (60.0, 70.0),
            "{pass:?}"
        );
        for pair in pass.windows(2) {
            assert_eq!(
                pair[0].to_deg, pair[1].from_deg,
                "each sweep starts where the last ended"
            );
        }
        let mut incidences: Vec<f64> = pass.iter().map(|p| p.theta_i_deg).collect();
        incidences.sort_by(f64::total_cmp);
        assert_eq!(incidences, [20.0, 30.0, 45.0, 60.0]);
        let fixed = device_us(&motion, park, &full_plane(60.0, 0.1));
        assert!(
            device_us(&motion, park, &pass) + 1_000_000 < fixed,
            "saves more than a second from the park"
        );
        let low = Geometry::from_deg(20.0, 0.0).unwrap();
        assert_eq!(
            full_plane_from(&motion, low, 60.0, 0.1),
            full_plane(60.0, 0.1),
            "from (20°, 0°) the ascending order is fastest"
        );
    }

    /// From the park (85°, 85°) the pass is at the reference kinematics' floor for four
    /// held-θi sweeps of 0…70°: each sweep from rest to rest at most 60 °/s and 180 °/s²
    /// (1.5 s), the source arm's approach to its first incidence (25° from the park: 0.75 s)
    /// and its three moves between incidences (15°, 15°, 10°, too short to reach top speed:
    /// 2√(d/a) each, 1.626 s together), each followed by the 100 ms settle: 8.776 s, the
    /// closed forms here against the planner's times. So the issue's ≤ 8 s for a sample
    /// cannot be met by held-θi sweeps over Strategy 1's lines on this instrument.
    #[test]
    fn the_pass_from_the_park_is_at_the_kinematic_floor() {
        let motion = Motion::reference();
        let park = Geometry::from_deg(85.0, 85.0).unwrap();
        let pass = full_plane_from(&motion, park, 60.0, 0.1);
        let accel = 180.0_f64;
        let triangular = |d: f64| 2.0 * (d / accel).sqrt();
        let trapezoid = |d: f64| d / 60.0 + 60.0 / accel;
        let floor_s = 4.0 * trapezoid(70.0)
            + trapezoid(25.0)
            + 2.0 * triangular(15.0)
            + triangular(10.0)
            + 4.0 * 0.1;
        let planned_s = device_us(&motion, park, &pass) as f64 * 1e-6;
        assert!((floor_s - 8.776).abs() < 0.001, "{floor_s}");
        assert!(
            (planned_s - floor_s).abs() < 0.005,
            "planned {planned_s} s against the floor {floor_s} s"
        );
    }

    /// The firmware's own binning of a sweep (its `Binner`, the block ends at
    /// `first_end_us + j·block` after the profile's start, the arm on the profile's step
    /// count), and the time-average of the step count over each bin by brute force (1 µs).
    fn firmware_bins(
        motion: &Motion,
        from: i32,
        to: i32,
        speed_mdeg: u32,
        bin_ticks: u16,
        first_end_us: i64,
    ) -> (Vec<BinStamp>, Vec<f64>, u16) {
        use firmware::hardware::Sample;
        use firmware::sweep::{Binner, BlockClass};
        let profile = motion.sweep_profile(from, to, speed_mdeg);
        let sweep = protocol::Sweep {
            sweep_id: 1,
            theta_i: protocol::Angle::from_deg(60.0).unwrap(),
            from: protocol::Angle::from_ticks(from),
            to: protocol::Angle::from_ticks(to),
            speed_mdeg_per_s: speed_mdeg,
            bin_ticks,
            range: None,
            target: protocol::Target::Sample,
        };
        let bins = ((to - from).unsigned_abs().div_ceil(u32::from(bin_ticks))) as u16;
        let mut binner = Binner::new(&sweep, bins);
        let at = |t: i64| {
            if t <= 0 {
                from
            } else {
                profile.position_at(t as u64)
            }
        };
        let (mut stamps, mut means) = (Vec::new(), Vec::new());
        let mut started = first_end_us - 1000;
        let mut j = 0i64;
        while !binner.is_done() {
            let end_us = first_end_us + j * 1000;
            let sample = Sample {
                counts: 100,
                detector_steps: at(end_us),
            };
            if let Some(bin) = binner.block(
                sample,
                BlockClass::Kept {
                    range: 0,
                    saturated: false,
                },
                0,
                end_us as u64,
            ) {
                stamps.push(BinStamp {
                    index: bin.index,
                    end_steps: bin.end.ticks(),
                    blocks: bin.blocks,
                    whole: true,
                });
                let n = (end_us - started) as f64;
                means.push(
                    (started..end_us)
                        .map(|t| f64::from(at(t) + at(t + 1)) * 0.5)
                        .sum::<f64>()
                        / n,
                );
                started = end_us;
            }
            j += 1;
        }
        (stamps, means, bins)
    }

    /// The dwell model finds the block clock's phase from the bins' step counts and puts
    /// each bin at the arm's time-averaged position, over phases drawn for this run, for
    /// the pass's speed and the slow peak sweeps': within 0.014 step of the brute-force
    /// average at 60 °/s, and within a tenth of a step (0.0013°) at 7.5–30 °/s, where a
    /// pulse comes only every one to two blocks and the stamps leave the phase uncertain by
    /// hundreds of µs. The intervals' middles are off by 0.6–1.8 steps (the first bin,
    /// which starts at rest; a third of a step in the ramps). Stamps that no phase gives
    /// are refused (the middles are used).
    #[test]
    fn the_dwell_model_puts_each_bin_where_the_arm_stood_on_average() {
        let motion = Motion::reference();
        let drawn = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| d.subsec_nanos() as i64);
        for (k, (from, to, speed_mdeg, bin_ticks)) in [
            (5600, 0, 60_000u32, 8u16),
            (0, 5600, 60_000, 8),
            (4400, 5200, 7_500, 2),
            (5200, 4400, 15_000, 4),
            (4000, 4800, 30_000, 3),
        ]
        .into_iter()
        .enumerate()
        {
            let first_end_us = 1 + (drawn + 7919 * k as i64).rem_euclid(1000);
            let (stamps, means, bins) =
                firmware_bins(&motion, from, to, speed_mdeg, bin_ticks, first_end_us);
            let profile = motion.sweep_profile(from, to, speed_mdeg);
            let centres = dwell_centres_steps(&profile, from, to, bin_ticks, bins, 1000, &stamps)
                .expect("a phase gives the firmware's bins");
            let mut worst_model: f64 = 0.0;
            let mut worst_middle: f64 = 0.0;
            let mut previous_end = from;
            for (stamp, mean) in stamps.iter().zip(&means) {
                let centre =
                    centres[usize::from(stamp.index)].expect("every bin received has a centre");
                worst_model = worst_model.max((centre - mean).abs());
                worst_middle = worst_middle
                    .max((0.5 * f64::from(previous_end + stamp.end_steps) - mean).abs());
                previous_end = stamp.end_steps;
            }
            println!(
                "{from}→{to} at {speed_mdeg} m°/s, bins of {bin_ticks}, first block end {first_end_us} µs: model within {worst_model:.4} steps, middles {worst_middle:.3}"
            );
            assert!(
                worst_model < 0.1,
                "{from}→{to} at {speed_mdeg}: {worst_model} steps"
            );
            assert!(worst_middle > 0.5, "the case shows what the model corrects");
            // A lost bin has no centre; the others keep theirs.
            let lost: Vec<BinStamp> = stamps.iter().copied().filter(|s| s.index != 3).collect();
            let partial =
                dwell_centres_steps(&profile, from, to, bin_ticks, bins, 1000, &lost).unwrap();
            assert!(partial[3].is_none() && partial[4] == centres[4]);
            // A step count the profile cannot give at any phase.
            let mut wrong = stamps.clone();
            wrong[5].end_steps += 3 * (to - from).signum();
            assert_eq!(
                dwell_centres_steps(&profile, from, to, bin_ticks, bins, 1000, &wrong),
                None
            );
        }
    }

    /// The sweep policy's first pass from the park: θi = 60° first (from θr = 70°, the
    /// end nearer the park), then 20° from θr = 0°, where the first sweep ended: the source
    /// arm's approach (25°: 0.75 s) and its 40° move (0.667 s at top speed and two ramps of
    /// 1/3 s), each settled (0.1 s), and two 1.5 s sweeps: 4.95 s, against the full
    /// plane's 8.78 s.
    #[test]
    fn the_first_pass_is_two_lines_in_under_five_seconds() {
        let motion = Motion::reference();
        let park = Geometry::from_deg(85.0, 85.0).unwrap();
        let pass = first_pass_from(&motion, park, 60.0, 0.1);
        let at: Vec<(f64, f64, f64)> = pass
            .iter()
            .map(|p| (p.theta_i_deg, p.from_deg, p.to_deg))
            .collect();
        assert_eq!(at, [(60.0, 70.0, 0.0), (20.0, 0.0, 70.0)]);
        let trapezoid = |d: f64| d / 60.0 + 60.0 / 180.0;
        let floor_s = 2.0 * trapezoid(70.0) + trapezoid(25.0) + trapezoid(40.0) + 2.0 * 0.1;
        let planned_s = device_us(&motion, park, &pass) as f64 * 1e-6;
        assert!((floor_s - 4.95).abs() < 0.001, "{floor_s}");
        assert!(
            (planned_s - floor_s).abs() < 0.005,
            "planned {planned_s} s against {floor_s} s"
        );
        // Every order of the two lines from the park is slower or the same.
        for plans in [
            lines(&FIRST_PASS_INCIDENCE_DEG, 60.0, 0.1),
            lines(&[60, 20], 60.0, 0.1),
        ] {
            assert!(device_us(&motion, park, &plans) >= device_us(&motion, park, &pass));
        }
        // No sweep breaks the collision guard (θi + θr ≥ 10°) at any point.
        for p in &pass {
            assert!(p.theta_i_deg + p.from_deg.min(p.to_deg) >= 10.0);
        }
    }

    /// The reference instrument (60 °/s, 180 °/s²): a 70° sweep at full speed is 1.5 s with
    /// its ramps (50° at 60 °/s and two 10° ramps of 1/3 s), and the whole plane, the source
    /// arm's three moves and their settling included, is within the 10 s.
    #[test]
    fn a_full_plane_pass_takes_what_the_reference_instrument_allows() {
        let motion = Motion::reference();
        let pass = full_plane(60.0, 0.1);
        let one = pass[0].sweep_us(&motion) as f64 * 1e-6;
        assert!((one - (50.0 / 60.0 + 2.0 / 3.0)).abs() < 0.01, "{one} s");
        let start = pass[0].start().unwrap();
        let total = device_us(&motion, start, &pass) as f64 * 1e-6;
        assert!(total < 10.0 && total > 4.0 * one, "{total} s");
        // Slower is longer; a short sweep never reaches its top speed.
        assert!(full_plane(30.0, 0.1)[0].sweep_us(&motion) > pass[0].sweep_us(&motion));
        let short = SweepPlan {
            theta_i_deg: 60.0,
            from_deg: 58.0,
            to_deg: 62.0,
            speed_deg_per_s: 60.0,
            bin_deg: 0.05,
        };
        let triangle = 2.0 * (4.0_f64 / 180.0).sqrt();
        assert!((short.sweep_us(&motion) as f64 * 1e-6 - triangle).abs() < 0.005);
        assert_eq!(short.bins(), 80);
    }

    #[test]
    fn bins_round_up_to_cover_the_sweep() {
        let plan = SweepPlan {
            theta_i_deg: 45.0,
            from_deg: 40.0,
            to_deg: 41.0,
            speed_deg_per_s: 10.0,
            bin_deg: 0.3,
        };
        assert_eq!(plan.bins(), 4);
        assert_eq!(
            SweepPlan {
                bin_deg: 0.25,
                ..plan
            }
            .bins(),
            4
        );
        assert_eq!(
            SweepPlan {
                to_deg: 39.0,
                ..plan
            }
            .bins(),
            4,
            "backwards alike"
        );
    }

    fn fitted(
        sigma_deg: f64,
        rho_s: f64,
        rho_d: f64,
        eta: f64,
        step_deg: f64,
        relative_noise: f64,
    ) -> (FitResult, Vec<Observation>) {
        let truth = crate::analysis::model::Params {
            sigma_deg,
            rho_s,
            rho_d,
            eta,
        };
        let mut observations = Vec::new();
        for theta_i in [20.0, 30.0, 45.0, 60.0] {
            let mut theta_r = 0.0;
            while theta_r <= 70.0 {
                let value =
                    model::evaluate_reading(&truth, theta_i, theta_r, step_deg, Some(1.0)).0;
                observations.push(Observation {
                    theta_i_deg: theta_i,
                    theta_r_deg: theta_r,
                    radiance_factor: value,
                    std: Some(relative_noise * value + 1e-4),
                    theta_r_span_deg: step_deg,
                });
                theta_r += step_deg;
            }
        }
        // The paper's model: what the design is tested on is the noise's share of σ's
        // variance, which sweeps shrink; the extensions' model-form share is a floor they
        // leave (`floor` in `design_peak_sweeps`).
        let options = crate::analysis::fit::FitOptions {
            extensions: false,
            ..crate::analysis::fit::FitOptions::default()
        };
        (
            crate::analysis::fit::fit(&observations, &options).expect("fit"),
            observations,
        )
    }

    /// After a coarse, noisy pass over glossy paper, the design sweeps across the peak
    /// until σ is predicted to the target, each sweep lowering the prediction; a rough
    /// paper's σ, already known well, gets none.
    #[test]
    fn the_design_sweeps_the_peak_until_sigma_is_known_to_the_target() {
        let motion = Motion::reference();
        let block_s = 1.024e-3;
        let (fit, observations) = fitted(0.8, 57.8, 0.855, 1.19, 1.0, 0.02);
        let now = 1.96 * fit.std_error(SIGMA).unwrap() / fit.sigma_deg().unwrap();
        // 2 % per bin at a 1° bin of ~16 blocks: a block has √16 times that noise.
        let per_block = |r: f64| (0.02 * r * 4.0).powi(2);
        let here = Geometry::from_deg(60.0, 0.0).unwrap();
        let design = design_peak_sweeps(
            &fit,
            &observations,
            here,
            &motion,
            60.0,
            block_s,
            &per_block,
            0.5 * now,
            6,
        );
        assert!(
            !design.plans.is_empty() && design.predicted_rel_half_width <= 0.5 * now,
            "{now} → {design:?}"
        );
        for plan in &design.plans {
            assert!(
                (plan.from_deg - plan.theta_i_deg).abs() <= 15.0
                    && (plan.to_deg - plan.theta_i_deg).abs() <= 15.0,
                "{plan:?}: across the peak"
            );
            assert!(
                plan.bin_deg >= min_bin_deg(plan.speed_deg_per_s, block_s)
                    && plan.bin_deg <= lobe_sd_deg(0.8, Some(1.0)) / 6.0 + 1e-9,
                "{plan:?}"
            );
        }
        assert!(design.seconds > 0.0 && design.seconds < 10.0, "{design:?}");
        // Fewer sweeps allowed, a wider prediction.
        let one = design_peak_sweeps(
            &fit,
            &observations,
            here,
            &motion,
            60.0,
            block_s,
            &per_block,
            0.0,
            1,
        );
        assert_eq!(one.plans.len(), 1);
        assert!(
            one.predicted_rel_half_width < now
                && one.predicted_rel_half_width >= design.predicted_rel_half_width
        );
        let (rough, rough_obs) = fitted(21.7, 0.409, 0.414, 3.0, 1.0, 0.002);
        let rough_now = 1.96 * rough.std_error(SIGMA).unwrap() / rough.sigma_deg().unwrap();
        let design = design_peak_sweeps(
            &rough,
            &rough_obs,
            here,
            &motion,
            60.0,
            block_s,
            &per_block,
            rough_now * 1.01,
            6,
        );
        assert!(design.plans.is_empty(), "{design:?}");
    }

    #[test]
    fn bins_never_go_below_one_block_and_resolve_the_lobe() {
        let block_s = 1.024e-3;
        assert!(
            (min_bin_deg(60.0, block_s) - 0.0625).abs() < 1e-12,
            "0.0614° rounded up to 5 ticks"
        );
        assert!((min_bin_deg(1.0, block_s) - 0.0125).abs() < 1e-12);
        // G's lobe (σ = 0.8°, 1° window): sd 1.63°, bins of 0.2625°; at 60 °/s still above a block.
        let sd = lobe_sd_deg(0.8, Some(1.0));
        assert!((sd - (2.56f64 + 1.0 / 12.0).sqrt()).abs() < 1e-12);
        assert!((bin_for_lobe(sd, 60.0, block_s) - 0.2625).abs() < 1e-12);
        assert!(
            (bin_for_lobe(0.05, 60.0, block_s) - 0.0625).abs() < 1e-12,
            "a lobe too narrow for the speed gets one block"
        );
    }
}
