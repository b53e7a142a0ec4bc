//! Sweeps: the detector arm read while it moves at a constant top speed across θr with
//! the source arm held, one bin of detector blocks per few hundredths of a degree. A sweep
//! gets a whole incidence's profile in the time Strategy 1 spends on a reading or two,
//! because the arms neither stop nor settle between its bins. This module plans them and
//! times them as the firmware will run them ([`Motion::sweep_us`]); the session runs them
//! and the fit models each bin's travel ([`crate::analysis::model::evaluate_reading`]).
use crate::instrument::calibration::Calibration;
use crate::session::MeasuredPoint;
use crate::session::order::Motion;
use protocol::{Geometry, Reading};
use serde::Serialize;

/// θr swept at every incidence by a full-plane pass, degrees (Strategy 1's and Table 2's
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
    pub to_deg: f64,
    /// The profile's top speed, °/s (reached only where the sweep is long enough).
    pub speed_deg_per_s: f64,
    /// Bin length, degrees.
    pub bin_deg: f64,
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
    pub fn sweep_us(&self, motion: &Motion) -> u64 {
        motion.sweep_us(self.from_deg, self.to_deg, self.speed_deg_per_s)
    }
}

/// The full-plane pass: the four incidences of Strategy 1 (20°, 30°, 45°, 60°), θr over
/// 0…70° at each, at top speed `speed_deg_per_s` and bins of `bin_deg`, the direction
/// alternating so that each sweep starts where the last one ended (the detector arm only
/// waits for the source arm's move between them).
pub fn full_plane(speed_deg_per_s: f64, bin_deg: f64) -> Vec<SweepPlan> {
    protocol::schedules::INCIDENCE_DEG
        .iter()
        .enumerate()
        .map(|(k, &theta_i)| {
            let (from_deg, to_deg) = if k % 2 == 0 { (0.0, THETA_R_MAX_DEG) } else { (THETA_R_MAX_DEG, 0.0) };
            SweepPlan { theta_i_deg: f64::from(theta_i), from_deg, to_deg, speed_deg_per_s, bin_deg }
        })
        .collect()
}

/// Device time of `plans` run in order from where the arms are (`here`): for each, the
/// move to its start and the settle after it, then the sweep, µs. A plan outside the
/// arms' angles counts as no time (the instrument refuses it before it moves).
pub fn device_us(motion: &Motion, here: Geometry, plans: &[SweepPlan]) -> u64 {
    let mut at = here;
    let mut total = 0u64;
    for plan in plans {
        let (Some(start), Some(end)) = (plan.start(), plan.end()) else { continue };
        let moving = motion.move_us(at, start);
        // A move of nothing needs no settling.
        let settling = if moving > 0 { motion.settle_us() } else { 0 };
        total = total.saturating_add(moving).saturating_add(settling).saturating_add(plan.sweep_us(motion));
        at = end;
    }
    total
}

/// One bin as the instrument reported it, in the host's units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BinReading {
    /// θr at the start of its first block, degrees (from the detector arm's step count).
    pub start_deg: f64,
    /// θr at the end of its last block, degrees.
    pub end_deg: f64,
    /// Mean of its blocks, ADC counts (dark offset included).
    pub mean_counts: f32,
    /// Blocks averaged (at least one).
    pub blocks: u16,
    /// The detector range it was read on.
    pub range: u8,
    /// Saturated on the least sensitive (or the forced) range: a lower bound, not a value.
    pub saturated: bool,
    /// Device time at its end, µs.
    pub device_time_us: u64,
}

/// A bin as a recorded reading: θr at the middle of its travel less the amplifier's lag
/// (while the arm moves at v the reading trails the angle by v·τ of the range's time
/// constant; the mean of that exponential kernel, its spread (vτ)² being second order),
/// its travel as the span, and its raw reading with the noise of its blocks as the
/// calibration's dark and white readings give it ([`Calibration::block_std_counts`]), not
/// their own scatter, which holds the scene's slope across the bin. Then converted like
/// any reading. `block_s` is one detector block, `tau_s` the range's time constant.
#[allow(clippy::too_many_arguments)]
pub fn bin_point(
    theta_i_deg: f64,
    bin: &BinReading,
    sweep_id: u16,
    index: u16,
    block_s: f64,
    tau_s: f64,
    calibration: &Calibration,
) -> MeasuredPoint {
    let span = (bin.end_deg - bin.start_deg).abs();
    let direction = (bin.end_deg - bin.start_deg).signum();
    let seconds = f64::from(bin.blocks.max(1)) * block_s;
    let lag_deg = span / seconds * tau_s;
    let net = calibration.net_counts(&Reading { mean_counts: bin.mean_counts, std_counts: 0.0, samples: 1, range: bin.range, integration_ms: 1, saturated: false }).unwrap_or(0.0);
    let std_counts = calibration.block_std_counts(bin.range, net).unwrap_or(f64::NAN) as f32;
    let reading = Reading {
        mean_counts: bin.mean_counts,
        std_counts,
        samples: u32::from(bin.blocks),
        range: bin.range,
        integration_ms: (seconds * 1e3).round().clamp(1.0, f64::from(u16::MAX)) as u16,
        saturated: bin.saturated,
    };
    let mut point = MeasuredPoint {
        theta_i_deg,
        theta_r_deg: 0.5 * (bin.start_deg + bin.end_deg) - direction * lag_deg,
        theta_r_span_deg: span,
        radiance_factor: None,
        std: None,
        reading,
        schedule_id: sweep_id,
        index,
        device_time_us: bin.device_time_us,
        note: None,
        superseded: false,
    };
    point.convert_with(calibration);
    point
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_plane_pass_covers_every_incidence_and_alternates() {
        let pass = full_plane(60.0, 0.1);
        assert_eq!(pass.len(), 4);
        for pair in pass.windows(2) {
            assert_eq!(pair[0].to_deg, pair[1].from_deg, "each sweep starts where the last ended");
        }
        assert!(pass.iter().all(|p| p.bins() == 700));
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
        let short = SweepPlan { theta_i_deg: 60.0, from_deg: 58.0, to_deg: 62.0, speed_deg_per_s: 60.0, bin_deg: 0.05 };
        let triangle = 2.0 * (4.0_f64 / 180.0).sqrt();
        assert!((short.sweep_us(&motion) as f64 * 1e-6 - triangle).abs() < 0.005);
        assert_eq!(short.bins(), 80);
    }

    #[test]
    fn bins_round_up_to_cover_the_sweep() {
        let plan = SweepPlan { theta_i_deg: 45.0, from_deg: 40.0, to_deg: 41.0, speed_deg_per_s: 10.0, bin_deg: 0.3 };
        assert_eq!(plan.bins(), 4);
        assert_eq!(SweepPlan { bin_deg: 0.25, ..plan }.bins(), 4);
        assert_eq!(SweepPlan { to_deg: 39.0, ..plan }.bins(), 4, "backwards alike");
    }

    #[test]
    fn a_bin_is_recorded_at_its_middle_less_the_lag_with_its_blocks_noise() {
        use crate::instrument::calibration::{Tile, WhitePoint};
        let reading = |mean_counts: f32, std_counts: f32, range: u8| Reading { mean_counts, std_counts, samples: 100, range, integration_ms: 100, saturated: false };
        let calibration = Calibration::new(
            "test".into(),
            Tile::default(),
            vec![1.0, 0.1, 0.01],
            vec![reading(200.0, 10.0, 0), reading(200.0, 10.0, 1), reading(200.0, 10.0, 2)],
            vec![WhitePoint { theta_i_deg: 60.0, reading: reading(10_200.0, 30.0, 0) }],
        );
        // 0.1° in two 1 ms blocks: 50 °/s; with τ = 0.2 ms the reading trails by 0.01°.
        let bin = BinReading { start_deg: 59.95, end_deg: 60.05, mean_counts: 5_200.0, blocks: 2, range: 0, saturated: false, device_time_us: 9 };
        let up = bin_point(60.0, &bin, 3, 7, 1e-3, 2e-4, &calibration);
        assert!((up.theta_r_deg - 59.99).abs() < 1e-12 && (up.theta_r_span_deg - 0.1).abs() < 1e-12, "{up:?}");
        let down = bin_point(60.0, &BinReading { start_deg: 60.05, end_deg: 59.95, ..bin }, 3, 7, 1e-3, 2e-4, &calibration);
        assert!((down.theta_r_deg - 60.01).abs() < 1e-12, "backwards it trails the other way: {down:?}");
        // Half the white's net counts: half its radiance factor; the noise of two blocks.
        assert!((up.radiance_factor.unwrap() - 0.5 * 0.99).abs() < 1e-12);
        let block = calibration.block_std_counts(0, 5_000.0).unwrap();
        assert!((up.std.unwrap() - block / 2f64.sqrt() / 10_000.0 * 0.99).abs() < 1e-9, "{:?}", up.std);
        assert_eq!((up.schedule_id, up.index, up.reading.samples, up.reading.integration_ms), (3, 7, 2, 2));
        // A saturated bin is not converted: its mean is only a lower bound.
        let saturated = bin_point(60.0, &BinReading { saturated: true, ..bin }, 3, 8, 1e-3, 2e-4, &calibration);
        assert!(saturated.radiance_factor.is_none() && saturated.note.is_some());
    }
}
