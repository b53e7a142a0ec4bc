//! Model averaging: an interval of σ, ρs, ρd or η from the members of the family, each
//! weighed by its Akaike weight, as the quantiles of the mixture of their distributions.
//!
//! Why a mixture and not the union of the members' intervals: on a sheet the paper's model
//! describes, every nested member with one more term fits as well (its cost is never
//! higher), so it is always within Akaike's 2 of the best, and its interval, which holds
//! how far the free term lets σ trade with it, is always covered: the union covered
//! exact-TSL σ in 100 % of 320 sessions at ten times the noise's width (docs/ACCURACY.md).
//! Weighed, such a member counts for what the data say of it (e^{−1} of the paper's model
//! where its term fitted to nothing, more where it fits better), and the interval is the
//! model-averaged distribution's 2.5 and 97.5 % quantiles (Burnham & Anderson's model
//! averaging; with one member it is that member's interval).
use crate::analysis::fit::covariance::Z_975;

/// One member's share in the average: its weight (not normalised), its estimate and the
/// 95 % interval it is taken with, read as a split normal: a normal of its own standard
/// deviation on each side of the estimate. A side of zero width is a bound the member's
/// term sits at, the mass of that half on the estimate itself (the normal censored at the
/// bound: [`super::merge`]'s inward interval).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Share {
    pub weight: f64,
    pub estimate: f64,
    pub interval: (f64, f64),
}

impl Share {
    fn below_sd(&self) -> f64 {
        (self.estimate - self.interval.0).max(0.0) / Z_975
    }

    fn above_sd(&self) -> f64 {
        (self.interval.1 - self.estimate).max(0.0) / Z_975
    }

    /// The share's cumulative distribution at `x`.
    fn cdf(&self, x: f64) -> f64 {
        let normal = |z: f64| 0.5 * libm::erfc(-z * std::f64::consts::FRAC_1_SQRT_2);
        if x < self.estimate {
            let sd = self.below_sd();
            if sd > 0.0 {
                normal((x - self.estimate) / sd)
            } else {
                0.0
            }
        } else {
            let sd = self.above_sd();
            if sd > 0.0 {
                normal((x - self.estimate) / sd)
            } else {
                1.0
            }
        }
    }

    fn usable(&self) -> bool {
        self.weight.is_finite()
            && self.weight > 0.0
            && self.estimate.is_finite()
            && self.interval.0.is_finite()
            && self.interval.1.is_finite()
    }
}

/// The mixture's 2.5 and 97.5 % quantiles; None without a share of finite numbers and
/// positive weight.
pub(super) fn interval(shares: &[Share]) -> Option<(f64, f64)> {
    let shares: Vec<Share> = shares.iter().copied().filter(Share::usable).collect();
    let total: f64 = shares.iter().map(|s| s.weight).sum();
    if shares.is_empty() || !(total > 0.0) {
        return None;
    }
    let cdf = |x: f64| shares.iter().map(|s| s.weight * s.cdf(x)).sum::<f64>() / total;
    // Every share's cdf is 0 or below 1e-20 ten standard deviations out: the quantiles
    // wanted lie inside.
    let lo = shares
        .iter()
        .map(|s| s.estimate - 10.0 * s.below_sd())
        .fold(f64::INFINITY, f64::min);
    let hi = shares
        .iter()
        .map(|s| s.estimate + 10.0 * s.above_sd())
        .fold(f64::NEG_INFINITY, f64::max);
    Some((
        quantile(&cdf, 0.025, (lo, hi)),
        quantile(&cdf, 0.975, (lo, hi)),
    ))
}

/// The least x in `bracket` with cdf(x) ≥ p, by bisection (cdf is monotone and may jump).
fn quantile(cdf: &dyn Fn(f64) -> f64, p: f64, (mut lo, mut hi): (f64, f64)) -> f64 {
    if cdf(lo) >= p {
        return lo;
    }
    // 200 halvings reach f64's resolution from any finite bracket.
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if cdf(mid) >= p {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

/// Akaike weights e^{−Δ/2} of `informations` against the least of them (1 for the best).
pub(super) fn akaike_weights(informations: &[f64]) -> Vec<f64> {
    let best = informations
        .iter()
        .copied()
        .filter(|a| a.is_finite())
        .fold(f64::INFINITY, f64::min);
    informations
        .iter()
        .map(|&a| {
            if a.is_finite() && best.is_finite() {
                (-(a - best) / 2.0).exp()
            } else {
                0.0
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn share(weight: f64, estimate: f64, half_width: f64) -> Share {
        Share {
            weight,
            estimate,
            interval: (estimate - half_width, estimate + half_width),
        }
    }

    /// A share of weight 1 with the interval `(lo, hi)` about `estimate`.
    fn split(estimate: f64, lo: f64, hi: f64) -> Share {
        Share {
            weight: 1.0,
            estimate,
            interval: (lo, hi),
        }
    }

    fn assert_interval(shares: &[Share], (lo, hi): (f64, f64)) {
        let (a, b) = interval(shares).expect("an interval");
        assert!((a - lo).abs() < 1e-9 && (b - hi).abs() < 1e-9, "{a} {b}");
    }

    #[test]
    fn one_share_gives_back_its_own_interval() {
        assert_interval(&[share(0.3, 20.0, 1.5)], (18.5, 21.5));
        // Split: each side its own.
        assert_interval(&[split(20.0, 19.0, 23.0)], (19.0, 23.0));
    }

    #[test]
    fn a_light_wide_share_widens_less_than_the_union() {
        // The paper's model and a nested member at e^{-1} of its weight, three times wider.
        let shares = [share(1.0, 20.0, 0.5), share((-1.0f64).exp(), 20.0, 1.5)];
        let (lo, hi) = interval(&shares).unwrap();
        assert!(lo > 18.5 && lo < 19.5 && (hi - 20.0 - (20.0 - lo)).abs() < 1e-9);
        // Two members far apart, equally weighed: the interval spans both.
        let (lo, hi) = interval(&[share(1.0, 20.0, 0.5), share(1.0, 24.0, 0.5)]).unwrap();
        assert!(lo < 20.0 && hi > 24.0, "{lo} {hi}");
    }

    #[test]
    fn a_share_at_a_bound_reaches_only_its_inward_side() {
        // Its upper side at zero width: half its mass on the estimate; the 97.5 % quantile
        // of it alone is the estimate, the 2.5 % one its lower end.
        assert_interval(&[split(22.0, 20.0, 22.0)], (20.0, 22.0));
    }

    #[test]
    fn shares_of_no_weight_or_not_finite_are_left_out() {
        assert_eq!(interval(&[]), None);
        assert_eq!(interval(&[share(0.0, 20.0, 1.0)]), None);
        let nan = split(f64::NAN, 1.0, 2.0);
        assert_interval(&[nan, share(1.0, 20.0, 1.0)], (19.0, 21.0));
    }

    #[test]
    fn akaike_weights_are_relative_to_the_best() {
        let w = akaike_weights(&[100.0, 102.0, f64::NAN, 110.0]);
        assert!((w[0] - 1.0).abs() < 1e-12);
        assert!((w[1] - (-1.0f64).exp()).abs() < 1e-12);
        assert_eq!(w[2], 0.0);
        assert!((w[3] - (-5.0f64).exp()).abs() < 1e-12);
    }
}
