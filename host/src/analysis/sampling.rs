//! The sampling interval δ of a data set and the adequacy check σ > σ_l (Akao et al.).
use protocol::schedules;
use serde::Serialize;
use std::collections::BTreeSet;

/// Where a δ came from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum DeltaSource {
    /// The data set is exactly Strategy 1 with `m` geometries (Table 4's nominal δ).
    Strategy1 {
        /// M.
        m: u16,
    },
    /// The data set is exactly Strategy 2 at its δ (Table 5).
    Strategy2,
    /// Measured from the geometries (largest gap around the specular direction).
    Measured,
    /// Given by the user (`--delta`).
    Given,
}

/// δ of a data set, degrees, and its source.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Delta {
    /// δ, degrees.
    pub deg: f64,
    /// Where it came from.
    pub source: DeltaSource,
}

/// σ_l = δ / (4·sqrt(2 ln 2)): the σ whose lobe FWHM in θr equals δ.
pub fn sigma_l_deg(delta_deg: f64) -> f64 {
    delta_deg / crate::analysis::model::FWHM_PER_SIGMA
}

/// Geometries as whole ticks of the protocol's angle resolution, for exact comparison.
fn tick_set(geometries: &[(f64, f64)]) -> Option<BTreeSet<(i32, i32)>> {
    geometries
        .iter()
        .map(|&(ti, tr)| {
            let g = protocol::Geometry::from_deg(ti, tr)?;
            Some((g.theta_i.ticks(), g.theta_r.ticks()))
        })
        .collect()
}

fn schedule_set(s: &schedules::Schedule) -> BTreeSet<(i32, i32)> {
    s.iter()
        .map(|g| (g.theta_i.ticks(), g.theta_r.ticks()))
        .collect()
}

/// The nominal δ when the geometries are exactly one of the method's schedules.
pub(crate) fn nominal_delta(geometries: &[(f64, f64)]) -> Option<Delta> {
    let set = tick_set(geometries)?;
    for (m, delta) in schedules::STRATEGY1 {
        if let Some(s) = schedules::strategy1(m)
            && schedule_set(&s) == set
        {
            return Some(Delta {
                deg: f64::from(delta),
                source: DeltaSource::Strategy1 { m },
            });
        }
    }
    for delta in schedules::STRATEGY2_DELTAS {
        if let Some(s) = schedules::strategy2(delta)
            && schedule_set(&s) == set
        {
            return Some(Delta {
                deg: f64::from(delta),
                source: DeltaSource::Strategy2,
            });
        }
    }
    None
}

/// δ measured from the geometries: for each incidence angle, the larger of the gaps from
/// the specular direction to the nearest measured θr below and above it (one side when
/// the other has none); the smallest of these over incidence angles. `None` when no
/// incidence angle has a measured neighbour.
///
/// One sort by θi and one pass over each incidence angle's readings: O(n log n) in the
/// number of readings (a data set of a million distinct θi takes a fraction of a second;
/// `benches/sampling.rs`).
pub fn measured_delta_deg(geometries: &[(f64, f64)]) -> Option<f64> {
    // A NaN θi is no incidence angle (it equals nothing, itself included).
    let mut sorted: Vec<(f64, f64)> = geometries
        .iter()
        .copied()
        .filter(|g| !g.0.is_nan())
        .collect();
    sorted.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    let mut smallest: Option<f64> = None;
    // Runs of equal θi (−0 and +0 are equal, and adjacent in this order).
    for group in sorted.chunk_by(|a, b| a.0 == b.0) {
        let ti = group[0].0;
        let (mut below, mut above) = (None::<f64>, None::<f64>);
        for &(_, tr) in group {
            if tr < ti {
                below = Some(below.map_or(tr, |b| b.max(tr)));
            } else if tr > ti {
                above = Some(above.map_or(tr, |a| a.min(tr)));
            }
        }
        let gap = match (below, above) {
            (Some(b), Some(a)) => (ti - b).max(a - ti),
            (Some(b), None) => ti - b,
            (None, Some(a)) => a - ti,
            (None, None) => continue,
        };
        if smallest.is_none_or(|s| gap.total_cmp(&s).is_lt()) {
            smallest = Some(gap);
        }
    }
    smallest
}

/// δ of a data set: `given` if any, else the schedule's nominal δ, else the measured one.
pub fn delta(geometries: &[(f64, f64)], given_deg: Option<f64>) -> Option<Delta> {
    if let Some(deg) = given_deg {
        return Some(Delta {
            deg,
            source: DeltaSource::Given,
        });
    }
    nominal_delta(geometries).or_else(|| {
        measured_delta_deg(geometries).map(|deg| Delta {
            deg,
            source: DeltaSource::Measured,
        })
    })
}

/// The verdict of the adequacy check.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SigmaCheck {
    /// δ, degrees.
    pub delta_deg: f64,
    /// σ_l, degrees.
    pub sigma_l_deg: f64,
    /// σ > σ_l; false when σ is unresolved or absent.
    pub sigma_ok: bool,
}

/// σ > σ_l(δ)? An unresolved σ (`None`) never passes.
pub fn check_sigma(sigma_deg: Option<f64>, delta_deg: f64) -> SigmaCheck {
    let sigma_l = sigma_l_deg(delta_deg);
    SigmaCheck {
        delta_deg,
        sigma_l_deg: sigma_l,
        sigma_ok: sigma_deg.is_some_and(|s| s > sigma_l),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::strategy::Strategy as _;

    fn pairs(s: &schedules::Schedule) -> Vec<(f64, f64)> {
        s.iter()
            .map(|g| (g.theta_i.deg(), g.theta_r.deg()))
            .collect()
    }

    #[test]
    fn schedules_get_their_nominal_delta() {
        let s1 = pairs(&schedules::strategy1(12).unwrap());
        assert_eq!(delta(&s1, None).unwrap().deg, 35.0);
        for d in 1..=10u8 {
            let s2 = pairs(&schedules::strategy2(d).unwrap());
            assert_eq!(delta(&s2, None).unwrap().deg, f64::from(d));
            assert_eq!(measured_delta_deg(&s2), Some(f64::from(d)), "δ {d}");
        }
        assert_eq!(
            measured_delta_deg(&pairs(&schedules::full_grid())),
            Some(1.0)
        );
        assert_eq!(delta(&s1, Some(7.5)).unwrap().deg, 7.5);
    }

    /// The quadratic version this replaced (a pass over every reading per incidence
    /// angle), as the reference the fast one must agree with.
    fn quadratic_reference(geometries: &[(f64, f64)]) -> Option<f64> {
        let mut incidences: Vec<f64> = geometries.iter().map(|g| g.0).collect();
        incidences.sort_by(f64::total_cmp);
        incidences.dedup();
        incidences
            .iter()
            .filter_map(|&ti| {
                let (mut below, mut above) = (None::<f64>, None::<f64>);
                for &(t, tr) in geometries {
                    if t != ti {
                        continue;
                    }
                    if tr < ti {
                        below = Some(below.map_or(tr, |b| b.max(tr)));
                    } else if tr > ti {
                        above = Some(above.map_or(tr, |a| a.min(tr)));
                    }
                }
                match (below, above) {
                    (Some(b), Some(a)) => Some((ti - b).max(a - ti)),
                    (Some(b), None) => Some(ti - b),
                    (None, Some(a)) => Some(a - ti),
                    (None, None) => None,
                }
            })
            .min_by(f64::total_cmp)
    }

    proptest::proptest! {
        #[test]
        fn the_fast_delta_is_the_quadratic_one(
            geometries in proptest::collection::vec(
                (
                    proptest::prop_oneof![0u8..20, proptest::strategy::Just(0)].prop_map(|k| f64::from(k) * 2.5),
                    proptest::prop_oneof![
                        (0u16..400).prop_map(|k| f64::from(k) * 0.25),
                        proptest::strategy::Just(f64::NAN),
                        proptest::strategy::Just(-0.0),
                    ],
                ),
                0..60,
            ),
            specials in proptest::collection::vec(proptest::prop_oneof![
                proptest::strategy::Just((f64::NAN, 3.0)),
                proptest::strategy::Just((-0.0, 1.0)),
                proptest::strategy::Just((0.0, -1.0)),
                proptest::strategy::Just((f64::INFINITY, 2.0)),
            ], 0..4),
        ) {
            let mut all = geometries;
            all.extend(specials);
            let (fast, slow) = (measured_delta_deg(&all), quadratic_reference(&all));
            proptest::prop_assert_eq!(fast.map(f64::to_bits), slow.map(f64::to_bits), "{:?}", all);
        }
    }

    #[test]
    fn a_million_distinct_incidence_angles_take_one_sort() {
        // A million readings, each θi its own (the quadratic version made 10¹² passes
        // over them: hours). θi k·80/n, θr on both sides at gaps that shrink with k except
        // one: δ is the gap of the last θi, 0.25°, and no other.
        let n = 1_000_000;
        let mut geometries = Vec::with_capacity(2 * n);
        // In a scrambled order (k·7919 mod n visits every k once: n is not a multiple of 7919).
        for k in (0..n).map(|i| i * 7919 % n) {
            let ti = 5.0 + 80.0 * k as f64 / n as f64;
            let gap = if k == n - 1 {
                0.25
            } else {
                0.5 + 4.0 * (1.0 - k as f64 / n as f64)
            };
            geometries.push((ti, ti - gap));
            geometries.push((ti, ti + 0.5 * gap));
        }
        assert_eq!(measured_delta_deg(&geometries), Some(0.25));
    }

    #[test]
    fn measured_delta_is_the_smallest_of_the_largest_gaps() {
        // θi 20: neighbours 15 and 22 → 5; θi 40: neighbours 38, 41 → 2.
        let g = [
            (20.0, 15.0),
            (20.0, 20.0),
            (20.0, 22.0),
            (40.0, 38.0),
            (40.0, 41.0),
            (40.0, 0.0),
        ];
        assert_eq!(measured_delta_deg(&g), Some(2.0));
        assert!((sigma_l_deg(4.71) - 1.0).abs() < 1e-3);
    }
}
