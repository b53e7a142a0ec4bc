//! A sweep's bins as readings: each bin the instrument reports recorded where the arm
//! stood on average while it was read, less the amplifier's lag, with its blocks' noise
//! ([`bin_point`]); then each range's bins' noise scaled to their own scatter
//! ([`scale_bin_noise`]). Where the bins were planned and where the arm stood is the
//! design's ([`crate::analysis::sweep_design`]).
use crate::analysis::fit::Observation;
use crate::instrument::calibration::Calibration;
use crate::session::MeasuredPoint;
use protocol::Reading;

/// One bin as the instrument reported it, in the host's units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BinReading {
    /// θr at the start of its first block, degrees (from the detector arm's step count).
    pub(crate) start_deg: f64,
    /// θr at the end of its last block, degrees.
    pub(crate) end_deg: f64,
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
    /// Where the arm stood on average while it was read, degrees ([`crate::analysis::sweep_design::dwell_centres_steps`]);
    /// `None`: the middle of its interval.
    pub(crate) centre_deg: Option<f64>,
}

/// A bin as a recorded reading: θr where the arm stood on average while it was read (the
/// dwell model's, [`BinReading::centre_deg`], else the middle of its travel) less the amplifier's lag
/// (while the arm moves at v the reading trails the angle by v·τ of the range's time
/// constant; the mean of that exponential kernel, its spread (vτ)² being second order),
/// its travel as the span, and its raw reading with the noise of its blocks as the
/// calibration's dark and white readings give it ([`Calibration::block_std_counts`]), not
/// their own scatter, which holds the scene's slope across the bin. Then converted like
/// any reading. `block_s` is one detector block, `tau_s` the range's time constant.
#[allow(clippy::too_many_arguments)]
pub(crate) fn bin_point(
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
    let net = calibration
        .net_counts(&Reading {
            mean_counts: bin.mean_counts,
            std_counts: 0.0,
            samples: 1,
            range: bin.range,
            integration_ms: 1,
            saturated: false,
        })
        .unwrap_or(0.0);
    let std_counts = calibration
        .block_std_counts(bin.range, net)
        .unwrap_or(f64::NAN) as f32;
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
        // Recorded to the precision readings.csv writes, so that the CSV holds exactly
        // what the analysis fits.
        theta_r_deg: super::recorded_angle(
            bin.centre_deg
                .unwrap_or(0.5 * (bin.start_deg + bin.end_deg))
                - direction * lag_deg,
        ),
        // (A travel is never rounded down to 0, which would make the bin a still reading.)
        theta_r_span_deg: if span > 0.0 {
            super::recorded_angle(span).max(1e-4)
        } else {
            0.0
        },
        radiance_factor: None,
        std: None,
        reading,
        schedule_id: sweep_id,
        index,
        device_time_us: bin.device_time_us,
        note: None,
        superseded: false,
        unusable: None,
    };
    point.convert_with(calibration);
    point
}

/// Fewest windows of neighbouring bins on a range for their scatter to set its noise
/// (fewer: the range takes the factor of all ranges' windows together).
const MIN_NOISE_WINDOWS: usize = 30;

/// Neighbouring bins in one window of the noise estimate: a fourth divided difference.
const NOISE_WINDOW: usize = 5;

/// The median of χ² with one degree of freedom.
const CHI2_1_MEDIAN: f64 = 0.454_936;

/// n times the variance of ln(median of n overlapping windows' z / [`CHI2_1_MEDIAN`]) under
/// the model: 10.2 by Monte Carlo (4,000 sweeps each of 40 to 2,800 evenly spaced bins;
/// 2.2 for independent χ²₁ draws, the overlap of neighbouring windows makes it 4.6 times
/// that). `the_noise_factor_s_spread_and_bias_are_as_stated` checks it.
const MEDIAN_LOG_VARIANCE_PER_WINDOW: f64 = 10.2;

/// n times the median's relative bias over n windows (the sample median of few χ²₁ draws
/// lies above the distribution's): about 4.5, from the same Monte Carlo.
const MEDIAN_BIAS_PER_WINDOW: f64 = 4.5;

/// One detector range's bins' noise as scaled to their own scatter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct RangeNoiseScale {
    /// The detector range.
    pub range: u8,
    /// Factor the calibration's variance was multiplied by.
    pub factor: f64,
    /// Variance of ln `factor` (its uncertainty as an estimate).
    pub(crate) log_variance: f64,
    /// Windows it was estimated from (the pooled windows of every range when the range
    /// had fewer than [`MIN_NOISE_WINDOWS`] of its own).
    pub windows: usize,
    /// Observations scaled by it.
    pub observations: usize,
}

/// How the bins' noise was scaled.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct NoiseScaling {
    /// Each range scaled.
    pub ranges: Vec<RangeNoiseScale>,
}

impl NoiseScaling {
    /// Variance of the log of χ²'s scale that the estimated factors leave, for a fit of
    /// `n` observations: Σ (share of the observations)² · each factor's log-variance (each
    /// range's share of χ² is about its share of the observations; a point reading's noise
    /// is its own and shares nothing). What the χ² test takes
    /// ([`crate::analysis::gof::chi2_upper_tail_scaled`]).
    pub(crate) fn chi2_log_variance(&self, n: usize) -> f64 {
        if n == 0 {
            return 0.0;
        }
        self.ranges
            .iter()
            .map(|r| (r.observations as f64 / n as f64).powi(2) * r.log_variance)
            .sum()
    }
}

/// The factor and its log-variance from `z` (sorted), `None` when it is not a number.
fn median_factor(z: &[f64]) -> Option<(f64, f64)> {
    let n = z.len() as f64;
    let factor = z[z.len() / 2] / CHI2_1_MEDIAN / (1.0 + MEDIAN_BIAS_PER_WINDOW / n);
    (factor.is_finite() && factor > 0.0).then_some((factor, MEDIAN_LOG_VARIANCE_PER_WINDOW / n))
}

/// The windows' z of `observations` by range: each window five neighbouring bins of one
/// sweep on one range (see [`scale_bin_noise`]), in the order of the bins.
fn window_z_by_range(
    points: &[MeasuredPoint],
    indices: &[usize],
    observations: &[Observation],
) -> std::collections::BTreeMap<u8, Vec<f64>> {
    let mut z_by_range: std::collections::BTreeMap<u8, Vec<f64>> =
        std::collections::BTreeMap::new();
    for w in 0..observations.len().saturating_sub(NOISE_WINDOW - 1) {
        let window: Vec<&MeasuredPoint> = indices[w..w + NOISE_WINDOW]
            .iter()
            .filter_map(|&k| points.get(k))
            .collect();
        let Some(first) = window.first() else {
            continue;
        };
        let neighbours = window.len() == NOISE_WINDOW
            && window.iter().all(|p| {
                p.theta_r_span_deg > 0.0
                    && p.schedule_id == first.schedule_id
                    && p.reading.range == first.reading.range
                    && !p.reading.saturated
            })
            && window
                .windows(2)
                .all(|pair| pair[1].index == pair[0].index.wrapping_add(1));
        if !neighbours {
            continue;
        }
        let obs = &observations[w..w + NOISE_WINDOW];
        let weights: Vec<f64> = (0..NOISE_WINDOW)
            .map(|j| {
                1.0 / (0..NOISE_WINDOW)
                    .filter(|&k| k != j)
                    .map(|k| obs[j].theta_r_deg - obs[k].theta_r_deg)
                    .product::<f64>()
            })
            .collect();
        let mut variance = 0.0;
        let mut difference = 0.0;
        for (o, wj) in obs.iter().zip(&weights) {
            let Some(s) = o.std else {
                variance = f64::NAN;
                break;
            };
            variance += wj * wj * s * s;
            difference += wj * o.radiance_factor;
        }
        if variance > 0.0 && variance.is_finite() && difference.is_finite() {
            z_by_range
                .entry(first.reading.range)
                .or_default()
                .push(difference * difference / variance);
        }
    }
    z_by_range
}

/// Each range's bins' noise scaled to their own scatter: the calibration's model of one
/// block's noise ([`bin_point`]) is of steady readings (the white tile, the gain ratios'),
/// but a bin of one or two blocks is what the fit weighs, and on the simulated reference
/// instrument a bin's variance was about 1.2 times the model's on a rough paper's broad
/// lobe (the cause is not established: the simulator's block noise is independent and a
/// linear scene's bins scatter as stated, so the arm's dwell on whole microsteps within a
/// bin and the model's estimate from few steady readings are suspects); 2,800 bins made a
/// lack-of-fit flag of that alone in two sessions of five.
///
/// The scatter is measured by fourth divided differences of five neighbouring bins of one
/// sweep on one range (their θr unevenly spaced: bins are whole blocks), which vanish for
/// any cubic: z = (Σ wⱼrⱼ)² / Σ wⱼ²sⱼ², wⱼ = 1/Πₖ≠ⱼ(θⱼ − θₖ), is χ²₁ when the noise model
/// is right, and its median χ²₁'s. The lobe's slope and curvature cancel; what is left of
/// G's peak (σ 0.8°, bins 0.1°) adds under a tenth to z at the peak. So a sheet the model
/// does not describe still fails the goodness of fit: its misfit is smooth on the scale of
/// five bins. A range with fewer than [`MIN_NOISE_WINDOWS`] windows takes the factor of
/// every range's windows together (its bins scatter as the others' do), or keeps the model
/// when there are not that many in all. The factor is an estimate — ln of it has a
/// variance of [`MEDIAN_LOG_VARIANCE_PER_WINDOW`] over the windows, 6 % in sd for a pass —
/// which the χ² test takes into account ([`NoiseScaling::chi2_log_variance`]).
pub(crate) fn scale_bin_noise(
    points: &[MeasuredPoint],
    indices: &[usize],
    observations: &mut [Observation],
) -> NoiseScaling {
    let z_by_range = window_z_by_range(points, indices, observations);
    let mut pooled: Vec<f64> = z_by_range.values().flatten().copied().collect();
    pooled.sort_by(f64::total_cmp);
    let pooled_factor = (pooled.len() >= MIN_NOISE_WINDOWS)
        .then(|| median_factor(&pooled))
        .flatten();
    let mut bin_ranges: Vec<u8> = indices
        .iter()
        .filter_map(|&k| points.get(k))
        .filter(|p| p.theta_r_span_deg > 0.0)
        .map(|p| p.reading.range)
        .collect();
    bin_ranges.sort_unstable();
    bin_ranges.dedup();
    let mut scaling = NoiseScaling::default();
    for range in bin_ranges {
        let own = z_by_range
            .get(&range)
            .filter(|z| z.len() >= MIN_NOISE_WINDOWS)
            .and_then(|z| {
                let mut z = z.clone();
                z.sort_by(f64::total_cmp);
                median_factor(&z).map(|f| (f, z.len()))
            });
        let Some(((factor, log_variance), windows)) =
            own.or_else(|| pooled_factor.map(|f| (f, pooled.len())))
        else {
            continue;
        };
        let mut scaled = 0;
        for (o, &k) in observations.iter_mut().zip(indices) {
            let Some(p) = points.get(k) else { continue };
            if p.theta_r_span_deg > 0.0 && p.reading.range == range {
                // Never below what the ADC's resolution alone leaves: on a quiet detector
                // most windows of a smooth profile read the same counts, their differences
                // are 0 and so is the median.
                let counts = crate::analysis::calibration::standard_error_counts(&p.reading);
                let resolution = p.std.map_or(0.0, |s| {
                    s * crate::analysis::calibration::RESOLUTION_STD_COUNTS / counts
                });
                o.std = o.std.map(|s| (s * factor.sqrt()).max(resolution));
                scaled += 1;
            }
        }
        scaling.ranges.push(RangeNoiseScale {
            range,
            factor,
            log_variance,
            windows,
            observations: scaled,
        });
    }
    scaling
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bins of a lobe with noise 1.5 times what their std says, over several seeds: the
    /// scale found is 1.5² within its sampling error, applied to every bin of that range and
    /// to no other reading; the narrow peak's curvature does not move it.
    #[test]
    fn bins_noise_is_scaled_to_their_own_scatter() {
        use rand::{Rng, SeedableRng};
        use rand_distr::StandardNormal;
        for seed in 1..=5u64 {
            let mut rng = rand_chacha::ChaCha12Rng::seed_from_u64(seed);
            let mut points = Vec::new();
            for k in 0..700u16 {
                // Bins of one or two blocks: unevenly spaced, as a sweep's are.
                let theta_r = 0.05 + 0.1 * f64::from(k) + if k % 3 == 1 { 0.03 } else { 0.0 };
                let truth = 0.85 + 60.0 * (-(theta_r - 20.0).powi(2) / (2.0 * 0.8 * 0.8)).exp();
                let std = 0.002 * (1.0 + truth / 10.0);
                let noise: f64 = rng.sample(StandardNormal);
                points.push(test_bin(
                    20.0,
                    theta_r,
                    truth + 1.5 * std * noise,
                    std,
                    0,
                    k,
                ));
            }
            // A point reading (no span) is left as it is.
            let mut still = points[0].clone();
            (still.theta_r_span_deg, still.schedule_id, still.theta_r_deg) = (0.0, 2, 45.0);
            points.push(still);
            let (indices, observations) = crate::session::usable_observations(&points);
            let scaled: Vec<f64> = observations
                .iter()
                .zip(&indices)
                .map(|(o, &k)| o.std.unwrap() / points[k].std.unwrap())
                .collect();
            let factor = scaled[0].powi(2);
            // The median of 696 χ²₁ draws: 1σ ≈ 6 %, and overlapping windows are correlated.
            assert!((factor / 2.25 - 1.0).abs() < 0.2, "seed {seed}: {factor}");
            assert!(scaled[..700].iter().all(|&s| (s * s - factor).abs() < 1e-9));
            assert_eq!(scaled[700], 1.0, "a point reading keeps its own noise");
        }
    }

    /// Bin `index` of sweep 1, 0.1° long, converted to `radiance_factor` ± `std` on `range`.
    fn test_bin(
        theta_i_deg: f64,
        theta_r_deg: f64,
        radiance_factor: f64,
        std: f64,
        range: u8,
        index: u16,
    ) -> MeasuredPoint {
        MeasuredPoint {
            theta_i_deg,
            theta_r_deg,
            theta_r_span_deg: 0.1,
            radiance_factor: Some(radiance_factor),
            std: Some(std),
            reading: Reading {
                mean_counts: 1000.0,
                std_counts: 10.0,
                samples: 2,
                range,
                integration_ms: 2,
                saturated: false,
            },
            schedule_id: 1,
            index,
            device_time_us: 0,
            note: None,
            superseded: false,
            unusable: None,
        }
    }

    /// Bins of one sweep whose noise is exactly their std, `n` of them.
    fn noisy_bins(
        rng: &mut rand_chacha::ChaCha12Rng,
        n: u16,
        range_of: impl Fn(u16) -> u8,
    ) -> Vec<MeasuredPoint> {
        use rand::Rng;
        use rand_distr::StandardNormal;
        (0..n)
            .map(|k| {
                let theta_r = 0.05 + 0.1 * f64::from(k) + if k % 3 == 1 { 0.03 } else { 0.0 };
                let std = 0.004;
                let noise: f64 = rng.sample(StandardNormal);
                test_bin(
                    30.0,
                    theta_r,
                    0.4 + 0.002 * theta_r + std * noise,
                    std,
                    range_of(k),
                    k,
                )
            })
            .collect()
    }

    /// Over 400 sweeps of bins whose noise is exactly the stated, the factor is 1 on
    /// average (the small-sample bias corrected) and ln of it has the stated variance, at a
    /// pass's count of windows and at a short range's; so the χ² test's allowance is the
    /// factor's real spread.
    #[test]
    fn the_noise_factor_s_spread_and_bias_are_as_stated() {
        use rand::SeedableRng;
        for (bins, tolerance) in [(700u16, 0.2), (80, 0.25)] {
            let mut logs = Vec::new();
            let mut stated = 0.0;
            for seed in 0..400u64 {
                let mut rng = rand_chacha::ChaCha12Rng::seed_from_u64(1000 + seed);
                let points = noisy_bins(&mut rng, bins, |_| 0);
                let (indices, mut observations) = crate::session::first_readings(&points);
                let scaling = scale_bin_noise(&points, &indices, &mut observations);
                assert_eq!(scaling.ranges.len(), 1);
                logs.push(scaling.ranges[0].factor.ln());
                stated = scaling.ranges[0].log_variance;
            }
            let n = logs.len() as f64;
            let mean = logs.iter().sum::<f64>() / n;
            let variance = logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / (n - 1.0);
            // The mean of 400 logs has sd √(variance/400): about 0.003 and 0.018.
            assert!(
                mean.abs() < 4.0 * (variance / n).sqrt() + 0.01,
                "{bins} bins: mean ln factor {mean}"
            );
            assert!(
                (variance / stated - 1.0).abs() < tolerance,
                "{bins} bins: variance {variance} against stated {stated}"
            );
        }
    }

    /// A range with too few windows of its own takes every range's pooled factor and its
    /// uncertainty; the χ² allowance weighs each range by its share of the observations.
    #[test]
    fn a_short_range_takes_the_pooled_factor() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha12Rng::seed_from_u64(3);
        // 600 bins on range 0, 20 in the middle on range 1 (fewer than 30 windows).
        let mut points = noisy_bins(&mut rng, 620, |k| u8::from((300..320).contains(&k)));
        for p in &mut points {
            p.radiance_factor = p.radiance_factor.map(|r| 0.4 + 2.0 * (r - 0.4));
        }
        let (indices, mut observations) = crate::session::first_readings(&points);
        let scaling = scale_bin_noise(&points, &indices, &mut observations);
        assert_eq!(scaling.ranges.len(), 2, "{scaling:?}");
        let (own, short) = (scaling.ranges[0], scaling.ranges[1]);
        assert_eq!((own.range, short.range), (0, 1));
        assert!(
            own.windows < 600 && short.windows >= own.windows,
            "{scaling:?}"
        );
        assert!((own.factor / 4.0 - 1.0).abs() < 0.25, "{own:?}");
        assert!((short.factor / own.factor - 1.0).abs() < 0.1, "{short:?}");
        assert_eq!(own.observations + short.observations, 620);
        let v = scaling.chi2_log_variance(620);
        let expected = (600.0f64 / 620.0).powi(2) * own.log_variance
            + (20.0f64 / 620.0).powi(2) * short.log_variance;
        assert!((v - expected).abs() < 1e-15);
        assert_eq!(NoiseScaling::default().chi2_log_variance(10), 0.0);
    }

    #[test]
    fn a_bin_is_recorded_at_its_mean_position_less_the_lag_with_its_blocks_noise() {
        use crate::instrument::calibration::{Tile, WhitePoint};
        let reading = |mean_counts: f32, std_counts: f32, range: u8| Reading {
            mean_counts,
            std_counts,
            samples: 100,
            range,
            integration_ms: 100,
            saturated: false,
        };
        let calibration = Calibration::new(
            "test".into(),
            Tile::default(),
            vec![1.0, 0.1, 0.01],
            vec![
                reading(200.0, 10.0, 0),
                reading(200.0, 10.0, 1),
                reading(200.0, 10.0, 2),
            ],
            vec![WhitePoint {
                theta_i_deg: 60.0,
                reading: reading(10_200.0, 30.0, 0),
            }],
        );
        // 0.1° in two 1 ms blocks: 50 °/s; with τ = 0.2 ms the reading trails by 0.01°.
        let bin = BinReading {
            start_deg: 59.95,
            end_deg: 60.05,
            mean_counts: 5_200.0,
            blocks: 2,
            range: 0,
            saturated: false,
            device_time_us: 9,
            centre_deg: None,
        };
        let up = bin_point(60.0, &bin, 3, 7, 1e-3, 2e-4, &calibration);
        assert!(
            (up.theta_r_deg - 59.99).abs() < 1e-12 && (up.theta_r_span_deg - 0.1).abs() < 1e-12,
            "{up:?}"
        );
        let down = bin_point(
            60.0,
            &BinReading {
                start_deg: 60.05,
                end_deg: 59.95,
                ..bin
            },
            3,
            7,
            1e-3,
            2e-4,
            &calibration,
        );
        assert!(
            (down.theta_r_deg - 60.01).abs() < 1e-12,
            "backwards it trails the other way: {down:?}"
        );
        // Where the dwell model put the arm's mean, less the lag.
        let dwelt = bin_point(
            60.0,
            &BinReading {
                centre_deg: Some(59.997),
                ..bin
            },
            3,
            7,
            1e-3,
            2e-4,
            &calibration,
        );
        assert!(
            (dwelt.theta_r_deg - 59.987).abs() < 1e-12
                && (dwelt.theta_r_span_deg - 0.1).abs() < 1e-12,
            "{dwelt:?}"
        );
        // Half the white's net counts: half its radiance factor; the noise of two blocks.
        assert!((up.radiance_factor.unwrap() - 0.5 * 0.99).abs() < 1e-12);
        let block = calibration.block_std_counts(0, 5_000.0).unwrap();
        assert!(
            (up.std.unwrap() - block / 2f64.sqrt() / 10_000.0 * 0.99).abs() < 1e-9,
            "{:?}",
            up.std
        );
        assert_eq!(
            (
                up.schedule_id,
                up.index,
                up.reading.samples,
                up.reading.integration_ms
            ),
            (3, 7, 2, 2)
        );
        // A saturated bin is not converted: its mean is only a lower bound.
        let saturated = bin_point(
            60.0,
            &BinReading {
                saturated: true,
                ..bin
            },
            3,
            8,
            1e-3,
            2e-4,
            &calibration,
        );
        assert!(saturated.radiance_factor.is_none() && saturated.note.is_some());
    }
}
