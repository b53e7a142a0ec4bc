//! The instrument's angular response and arm zero from sweeps of the detector across a
//! mirror's specular peak (a black glass standard): pure numbers in, figures with their
//! uncertainties out (`gonio characterize` takes the sweeps, `instrument::profile` keeps
//! the figures).
//!
//! A mirror reflects the source into one direction, so what the detector reads as its arm
//! crosses that direction is the instrument's whole in-plane response: the detector's
//! acceptance and the source's divergence together, in their real shape. A sweep's bins are
//! contiguous and each is the mean of the response over its own travel, so the bins are a
//! histogram of the response: its area, centroid and variance follow from sums over them
//! (the variance needs no correction for the bins' width: the spread within each bin makes
//! up what the bins' centres lose, Sheppard's correction in reverse).
//!
//! The peak's position is the arm zero: at the true specular direction θr = θi, so a peak
//! the firmware puts at θr = θi − δ says every θr the firmware reports is δ short. A sweep
//! up and a sweep down give it twice; their difference (after the amplifier's lag, which
//! the caller has taken out) is the detector arm's backlash.
use crate::analysis::model::{DetectorResponse, MAX_RESPONSE_STEPS};

/// One bin of a sweep across the peak.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceBin {
    /// Where the detector arm was on average while the bin was read (firmware θr, the
    /// amplifier's lag taken out), degrees.
    pub theta_r_deg: f64,
    /// Its travel, degrees.
    pub span_deg: f64,
    /// Signal above dark, counts (any unit common to the sweep).
    pub signal: f64,
    /// Standard uncertainty of `signal`.
    pub std: f64,
}

/// A sweep across the peak at one incidence, in one direction.
#[derive(Clone, Debug, PartialEq)]
pub struct Trace {
    /// θi, degrees.
    pub theta_i_deg: f64,
    /// +1 up (θr increasing), −1 down.
    pub direction: f64,
    /// Its bins, in any order.
    pub bins: Vec<TraceBin>,
}

/// What one sweep says about the peak.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Peak {
    /// θi, degrees.
    pub theta_i_deg: f64,
    /// +1 up, −1 down.
    pub direction: f64,
    /// The peak's centroid (firmware θr), degrees.
    pub centroid_deg: f64,
    /// Its standard uncertainty from the bins' noise, degrees.
    pub centroid_u_deg: f64,
    /// Full width at half maximum, degrees.
    pub fwhm_deg: f64,
    /// Variance about the centroid, degrees².
    pub variance_deg2: f64,
    /// Area above the baseline (signal × degrees).
    pub area: f64,
    /// Highest bin above the baseline.
    pub peak_signal: f64,
    /// The peak's region (firmware θr from, to): beyond it only noise was seen.
    pub region_deg: (f64, f64),
}

/// Why a sweep gives no peak.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PeakError {
    /// Too few bins to see a peak and its surroundings.
    #[error("a sweep at θi = {theta_i_deg}° has {bins} usable bins: a peak needs at least 20")]
    TooFewBins {
        /// θi.
        theta_i_deg: f64,
        /// Bins.
        bins: usize,
    },
    /// The highest bin does not stand out of the noise.
    #[error(
        "no specular peak at θi = {theta_i_deg}°: the highest bin is {snr:.1} standard deviations above the baseline (is the black glass on the port, the lamp on?)"
    )]
    NoPeak {
        /// θi.
        theta_i_deg: f64,
        /// Its height over its noise.
        snr: f64,
    },
    /// The peak runs into an end of the sweep: the sweep did not cover it.
    #[error(
        "the peak at θi = {theta_i_deg}° reaches the end of the sweep ({edge_deg:.2}°): the arm zero or the response is larger than the sweep allows for"
    )]
    Truncated {
        /// θi.
        theta_i_deg: f64,
        /// The end it runs into.
        edge_deg: f64,
    },
}

/// Share of the sweep at each end taken as the baseline (no peak there).
const BASELINE_SHARE: f64 = 0.15;
/// The peak's region ends where the signal falls below this fraction of its height, plus
/// [`REGION_MARGIN`] of the distance out: beyond, only noise would be summed.
const REGION_LEVEL: f64 = 0.005;
/// See [`REGION_LEVEL`].
const REGION_MARGIN: f64 = 0.25;
/// Bins in a row below the level that end the peak's region.
const QUIET_BINS: usize = 12;
/// A peak must stand this many standard deviations above the baseline.
const MIN_SNR: f64 = 20.0;

/// The bins in θr order, with the baseline (the median of the outer bins) taken out.
fn sorted_above_baseline(trace: &Trace) -> Result<(Vec<TraceBin>, f64), PeakError> {
    let mut bins: Vec<TraceBin> = trace
        .bins
        .iter()
        .copied()
        .filter(|b| b.theta_r_deg.is_finite() && b.signal.is_finite() && b.span_deg >= 0.0)
        .collect();
    if bins.len() < 20 {
        return Err(PeakError::TooFewBins {
            theta_i_deg: trace.theta_i_deg,
            bins: bins.len(),
        });
    }
    bins.sort_by(|a, b| a.theta_r_deg.total_cmp(&b.theta_r_deg));
    let edge = ((bins.len() as f64 * BASELINE_SHARE) as usize).max(3);
    let mut outer: Vec<f64> = bins[..edge]
        .iter()
        .chain(&bins[bins.len() - edge..])
        .map(|b| b.signal)
        .collect();
    outer.sort_by(f64::total_cmp);
    let baseline = outer[outer.len() / 2];
    for b in &mut bins {
        b.signal -= baseline;
    }
    Ok((bins, baseline))
}

/// The peak of one sweep.
pub fn measure_peak(trace: &Trace) -> Result<Peak, PeakError> {
    let (bins, _) = sorted_above_baseline(trace)?;
    let (top, top_bin) = bins
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.signal.total_cmp(&b.1.signal))
        .map(|(k, b)| (k, *b))
        .unwrap_or((0, bins[0]));
    let noise = {
        let mut s: Vec<f64> = bins
            .iter()
            .map(|b| b.std)
            .filter(|s| s.is_finite())
            .collect();
        s.sort_by(f64::total_cmp);
        s.get(s.len() / 2).copied().unwrap_or(0.0).max(1e-300)
    };
    let snr = top_bin.signal / noise;
    if !(snr >= MIN_SNR) {
        return Err(PeakError::NoPeak {
            theta_i_deg: trace.theta_i_deg,
            snr,
        });
    }
    let height = top_bin.signal;
    // Walking out from the top, the last bin above the level (REGION_LEVEL of the height,
    // or four standard deviations of a bin where the noise is higher) before
    // [`QUIET_BINS`] in a row below it: isolated noise beyond does not stretch the region.
    let level = (REGION_LEVEL * height).max(4.0 * noise);
    let walk = |indices: &mut dyn Iterator<Item = usize>| {
        let mut last = top;
        let mut quiet = 0;
        for k in indices {
            if bins[k].signal > level {
                last = k;
                quiet = 0;
            } else {
                quiet += 1;
                if quiet >= QUIET_BINS {
                    break;
                }
            }
        }
        last
    };
    let lo_k = walk(&mut (0..top).rev());
    let hi_k = walk(&mut (top + 1..bins.len()));
    let (first, last) = (bins[0].theta_r_deg, bins[bins.len() - 1].theta_r_deg);
    let lo =
        bins[lo_k].theta_r_deg - REGION_MARGIN * (top_bin.theta_r_deg - bins[lo_k].theta_r_deg);
    let hi =
        bins[hi_k].theta_r_deg + REGION_MARGIN * (bins[hi_k].theta_r_deg - top_bin.theta_r_deg);
    if lo <= first || hi >= last {
        return Err(PeakError::Truncated {
            theta_i_deg: trace.theta_i_deg,
            edge_deg: if lo <= first { first } else { last },
        });
    }
    let region: Vec<&TraceBin> = bins
        .iter()
        .filter(|b| b.theta_r_deg >= lo && b.theta_r_deg <= hi)
        .collect();
    let area: f64 = region.iter().map(|b| b.signal * b.span_deg).sum();
    let centroid = region
        .iter()
        .map(|b| b.theta_r_deg * b.signal * b.span_deg)
        .sum::<f64>()
        / area;
    let variance = region
        .iter()
        .map(|b| (b.theta_r_deg - centroid).powi(2) * b.signal * b.span_deg)
        .sum::<f64>()
        / area;
    // ∂c/∂s_k = span_k (u_k − c)/A: the centroid's noise from the bins' own.
    let centroid_u = region
        .iter()
        .map(|b| ((b.theta_r_deg - centroid) * b.span_deg / area * b.std).powi(2))
        .sum::<f64>()
        .sqrt();
    Ok(Peak {
        theta_i_deg: trace.theta_i_deg,
        direction: trace.direction,
        centroid_deg: centroid,
        centroid_u_deg: centroid_u,
        fwhm_deg: fwhm(&bins, height),
        variance_deg2: variance,
        area,
        peak_signal: height,
        region_deg: (lo, hi),
    })
}

/// Full width at half `height`: the outermost crossings of half height, each placed by
/// linear interpolation between the bins either side (outermost, so that noise on a
/// flat top does not cut the width short).
fn fwhm(bins: &[TraceBin], height: f64) -> f64 {
    let half = 0.5 * height;
    let crossing = |a: &TraceBin, b: &TraceBin| {
        let t = (half - a.signal) / (b.signal - a.signal);
        a.theta_r_deg + t.clamp(0.0, 1.0) * (b.theta_r_deg - a.theta_r_deg)
    };
    let left = bins
        .windows(2)
        .find(|w| w[0].signal < half && w[1].signal >= half)
        .map(|w| crossing(&w[0], &w[1]));
    let right = bins
        .windows(2)
        .rev()
        .find(|w| w[0].signal >= half && w[1].signal < half)
        .map(|w| crossing(&w[0], &w[1]));
    match (left, right) {
        (Some(l), Some(r)) if r > l => r - l,
        _ => f64::NAN,
    }
}

/// A figure with its standard uncertainty. Not determined: NaN, written as JSON `null`
/// and read back as NaN.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Measured {
    /// The value.
    #[serde(deserialize_with = "nan_if_null")]
    pub value: f64,
    /// Its standard uncertainty.
    #[serde(deserialize_with = "nan_if_null")]
    pub u: f64,
}

fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(<Option<f64> as serde::Deserialize>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Mean of `values` and its standard error (the values' own scatter over √n; with one
/// value, `fallback_u`).
pub fn mean_and_error(values: &[f64], fallback_u: f64) -> Measured {
    let n = values.len() as f64;
    if values.is_empty() {
        return Measured {
            value: f64::NAN,
            u: f64::NAN,
        };
    }
    let mean = values.iter().sum::<f64>() / n;
    if values.len() < 2 {
        return Measured {
            value: mean,
            u: fallback_u,
        };
    }
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    Measured {
        value: mean,
        u: (var / n).sqrt(),
    }
}

/// The response as the fit uses it ([`DetectorResponse`]): every trace's bins, its
/// baseline taken out, normalised by its peak's area and centred on its centroid, pooled
/// onto a grid of `grid_deg` (the bins' width) and summed into a cumulative distribution;
/// the histogram's steps then span the response from its 0.1 % to its 99.9 % point, at
/// most [`MAX_RESPONSE_STEPS`] and about an eighth of the FWHM wide each, and each step's
/// share is the distribution's rise across it. Steps laid from the distribution's own
/// points put a top-hat's edges on step edges (a grid laid from a threshold cuts the edge
/// steps in two, which inflates the variance by a quarter of a step squared); the steps'
/// offsets are last scaled so that the histogram has the peaks' own variance, the moment a
/// lobe wider than the response feels first. Returns the response and the steps' standard
/// uncertainties (the traces' scatter about the pooled mean, over √n).
pub fn response_steps(
    traces: &[Trace],
    peaks: &[Peak],
    fwhm_deg: f64,
) -> Option<(DetectorResponse, Vec<f64>)> {
    let grid = traces
        .iter()
        .flat_map(|t| t.bins.iter().map(|b| b.span_deg))
        .filter(|s| *s > 0.0)
        .fold(f64::INFINITY, f64::min);
    if !(grid.is_finite() && fwhm_deg > 0.0) || traces.len() != peaks.len() {
        return None;
    }
    // Pooled density on the grid: index k covers [k·grid, (k+1)·grid) about the centroid.
    let mut cells: std::collections::BTreeMap<i64, (f64, f64, usize)> = Default::default();
    for (trace, peak) in traces.iter().zip(peaks) {
        let Ok((bins, _)) = sorted_above_baseline(trace) else {
            continue;
        };
        // Only the peak's region: the noise beyond would walk the distribution's tails out.
        for b in bins
            .into_iter()
            .filter(|b| b.theta_r_deg >= peak.region_deg.0 && b.theta_r_deg <= peak.region_deg.1)
        {
            let k = ((b.theta_r_deg - peak.centroid_deg) / grid).floor() as i64;
            let r = b.signal / peak.area;
            let cell = cells.entry(k).or_insert((0.0, 0.0, 0));
            cell.0 += r;
            cell.1 += r * r;
            cell.2 += 1;
        }
    }
    let density: Vec<(f64, f64, f64)> = cells
        .iter()
        .map(|(&k, &(sum, sum2, n))| {
            let mean = sum / n as f64;
            let var = (sum2 / n as f64 - mean * mean).max(0.0) / n as f64;
            (k as f64 * grid, mean, var)
        })
        .collect();
    let total: f64 = density.iter().map(|d| d.1 * grid).sum();
    if !(total > 0.0) {
        return None;
    }
    // The cumulative distribution at each cell's upper edge.
    let mut cdf = Vec::with_capacity(density.len());
    let mut running = 0.0;
    for &(lo, r, _) in &density {
        running += r * grid / total;
        cdf.push((lo + grid, running));
    }
    let quantile = |q: f64| -> f64 {
        let k = cdf.partition_point(|&(_, c)| c < q);
        let (x1, c1) = cdf[k.min(cdf.len() - 1)];
        let (x0, c0) = if k == 0 { (x1 - grid, 0.0) } else { cdf[k - 1] };
        if c1 > c0 {
            x0 + (q - c0) / (c1 - c0) * (x1 - x0)
        } else {
            x1
        }
    };
    let (lo, hi) = (quantile(0.001), quantile(0.999));
    if !(hi > lo) {
        return None;
    }
    let n = (((hi - lo) / (fwhm_deg / 8.0)).ceil() as usize).clamp(4, MAX_RESPONSE_STEPS);
    let step = (hi - lo) / n as f64;
    let at = |x: f64| -> f64 {
        // The CDF at x, linear within a cell.
        let k = cdf.partition_point(|&(edge, _)| edge < x);
        if k >= cdf.len() {
            return 1.0;
        }
        let (x1, c1) = cdf[k];
        let (x0, c0) = if k == 0 { (x1 - grid, 0.0) } else { cdf[k - 1] };
        (c0 + (x - x0) / (x1 - x0) * (c1 - c0)).clamp(0.0, 1.0)
    };
    let shares: Vec<f64> = (0..n)
        .map(|j| {
            let a = lo + j as f64 * step;
            (at(a + step) - at(a)).max(0.0)
        })
        .collect();
    let errors: Vec<f64> = (0..n)
        .map(|j| {
            let (a, b) = (lo + j as f64 * step, lo + (j + 1) as f64 * step);
            density
                .iter()
                .filter(|d| d.0 + 0.5 * grid >= a && d.0 + 0.5 * grid < b)
                .map(|d| d.2 * grid * grid)
                .sum::<f64>()
                .sqrt()
                / total
        })
        .collect();
    let first = lo + 0.5 * step;
    let histogram = DetectorResponse::from_steps(step, first, &shares).ok()?;
    // Centred, and scaled to the peaks' variance.
    let mean = histogram.mean_deg();
    let variance: f64 =
        peaks.iter().map(|p| p.variance_deg2).sum::<f64>() / peaks.len().max(1) as f64;
    let scale = if variance > 0.0 && histogram.variance_deg2() > 0.0 {
        (variance / histogram.variance_deg2()).sqrt()
    } else {
        1.0
    };
    let response =
        DetectorResponse::from_steps(step * scale, (first - mean) * scale, &shares).ok()?;
    Some((response, errors))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Gaussian response of FWHM 1.2° at θr = 45.13 (zero −0.13°), bins of 0.025° over
    /// ±4°, read without noise.
    fn gaussian_trace(direction: f64) -> Trace {
        let sd = 1.2 / 2.354_820_045;
        let bins = (0..320)
            .map(|k| {
                let a = 41.0 + 0.025 * k as f64;
                let b = a + 0.025;
                let cdf = |x: f64| 0.5 * (1.0 + libm::erf((x - 45.13) / (sd * 2f64.sqrt())));
                TraceBin {
                    theta_r_deg: 0.5 * (a + b),
                    span_deg: 0.025,
                    signal: 1000.0 * (cdf(b) - cdf(a)) / 0.025 + 3.0,
                    std: 0.5,
                }
            })
            .collect();
        Trace {
            theta_i_deg: 45.0,
            direction,
            bins,
        }
    }

    #[test]
    fn a_gaussian_peak_gives_its_centroid_width_and_area() {
        let peak = measure_peak(&gaussian_trace(1.0)).unwrap();
        assert!((peak.centroid_deg - 45.13).abs() < 1e-4, "{peak:?}");
        assert!((peak.fwhm_deg - 1.2).abs() < 2e-3, "{peak:?}");
        let sd = 1.2 / 2.354_820_045;
        assert!(
            (peak.variance_deg2 / (sd * sd) - 1.0).abs() < 5e-3,
            "{peak:?}"
        );
        assert!((peak.area / 1000.0 - 1.0).abs() < 2e-3, "{peak:?}");
        let traces = [gaussian_trace(1.0), gaussian_trace(-1.0)];
        let peaks = [peak, peak];
        let (response, errors) = response_steps(&traces, &peaks, peak.fwhm_deg).unwrap();
        assert!(response.steps().len() <= MAX_RESPONSE_STEPS);
        assert_eq!(errors.len(), response.steps().len());
        assert!(response.mean_deg().abs() < 1e-12);
        assert!(
            (response.variance_deg2() / (sd * sd) - 1.0).abs() < 0.02,
            "{} vs {}",
            response.variance_deg2(),
            sd * sd
        );
    }

    #[test]
    fn flat_sweeps_and_peaks_cut_by_the_sweep_are_refused() {
        let mut flat = gaussian_trace(1.0);
        for b in &mut flat.bins {
            b.signal = 3.0;
        }
        assert!(matches!(measure_peak(&flat), Err(PeakError::NoPeak { .. })));
        let mut cut = gaussian_trace(1.0);
        cut.bins.retain(|b| b.theta_r_deg < 45.3);
        assert!(matches!(
            measure_peak(&cut),
            Err(PeakError::Truncated { .. })
        ));
        let short = Trace {
            bins: gaussian_trace(1.0).bins[..5].to_vec(),
            ..gaussian_trace(1.0)
        };
        assert!(matches!(
            measure_peak(&short),
            Err(PeakError::TooFewBins { .. })
        ));
    }

    #[test]
    fn the_mean_of_repeats_carries_their_scatter() {
        let m = mean_and_error(&[1.0, 1.2, 0.8, 1.0], 0.0);
        assert!((m.value - 1.0).abs() < 1e-12);
        assert!((m.u - (0.08f64 / 3.0 / 4.0).sqrt()).abs() < 1e-12);
        assert_eq!(mean_and_error(&[2.0], 0.3), Measured { value: 2.0, u: 0.3 });
    }
}
