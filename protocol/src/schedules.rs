//! The measurement schedules of the method (Akao et al., Tables 2, 4 and 5).
//!
//! All geometries lie in the specular plane at θi ∈ {20, 30, 45, 60}° with
//! 0 ≤ θr ≤ 70°, in whole degrees as in the paper. Generated lists are sorted by θi,
//! then θr (the paper's order); the order the arms visit them is planned elsewhere.

use crate::geometry::Geometry;
use heapless::Vec;

/// Longest schedule any generator makes (the full grid, 284) and the most a device must hold.
pub const MAX_SCHEDULE_LEN: usize = 288;

/// A list of geometries.
pub type Schedule = Vec<Geometry, MAX_SCHEDULE_LEN>;

/// Incidence angles of the method, degrees.
pub const INCIDENCE_DEG: [i32; 4] = [20, 30, 45, 60];

/// Largest detection angle of the method, degrees.
pub const THETA_R_MAX_DEG: i32 = 70;

/// The M of Table 4 with their nominal interval δ in degrees.
pub const STRATEGY1: [(u16, u8); 8] = [
    (12, 35),
    (16, 24),
    (20, 18),
    (24, 14),
    (36, 9),
    (60, 5),
    (76, 4),
    (144, 2),
];

/// The δ of Table 5, degrees.
pub const STRATEGY2_DELTAS: core::ops::RangeInclusive<u8> = 1..=10;

/// Half-width of Strategy 2's dense band around the specular direction, degrees.
pub const STRATEGY2_HALF_WIDTH_DEG: i32 = 10;

/// Nominal δ of Strategy 1 with `m` geometries, or `None` for an M not in Table 4.
pub fn strategy1_nominal_delta_deg(m: u16) -> Option<u8> {
    STRATEGY1.iter().find(|&&(mm, _)| mm == m).map(|&(_, d)| d)
}

/// Table 2: θi ∈ {20, 30, 45, 60}° × θr = 0…70° in 1° steps, 284 geometries.
pub fn full_grid() -> Schedule {
    let mut out = Schedule::new();
    for theta_i in INCIDENCE_DEG {
        for theta_r in 0..=THETA_R_MAX_DEG {
            // Capacity is a constant above 284: cannot fail.
            let _ = out.push(Geometry::from_whole_deg(theta_i, theta_r));
        }
    }
    out
}

/// `numerator / denominator` rounded half up (all operands non-negative).
const fn round_half_up(numerator: i32, denominator: i32) -> i32 {
    (2 * numerator + denominator) / (2 * denominator)
}

/// How many equal intervals go into [0, θi] and [θi, 70] when `intervals` are shared
/// between them: the split with the smallest largest interval; on a tie, more intervals
/// in the longer section.
fn strategy1_split(theta_i: i32, intervals: i32) -> (i32, i32) {
    let below = theta_i;
    let above = THETA_R_MAX_DEG - theta_i;
    let mut best = (1, intervals - 1);
    for n_below in 1..intervals {
        let n_above = intervals - n_below;
        // Compare max(below/n_below, above/n_above) by cross-multiplication (exact).
        let worst = |(nb, na): (i32, i32)| -> (i32, i32) {
            if below * na >= above * nb {
                (below, nb)
            } else {
                (above, na)
            }
        };
        let (wn, wd) = worst((n_below, n_above));
        let (bn, bd) = worst(best);
        let longer_gets_more = if above >= below {
            n_above > best.1
        } else {
            n_below > best.0
        };
        if wn * bd < bn * wd || (wn * bd == bn * wd && longer_gets_more) {
            best = (n_below, n_above);
        }
    }
    best
}

/// Strategy 1 with `m` geometries (Table 4): per θi, M/4 detection angles that always
/// include 0, θi and 70°, the sections [0, θi] and [θi, 70] each divided equally, with
/// the number of intervals per section chosen to make the largest interval smallest.
/// Angles are rounded to whole degrees, halves up, as the paper lists them.
///
/// M = 12 is exactly `strategy1-m12.csv`. For the larger M the paper's printed lists are
/// partly illegible; this rule reproduces every legible entry but θi = 20° at M = 24,
/// where the paper has (0, 20, 33, 45, 58, 70) and the rule a finer split of [0, 20].
/// Returns `None` for an M not in Table 4.
pub fn strategy1(m: u16) -> Option<Schedule> {
    strategy1_nominal_delta_deg(m)?;
    let per_incidence = i32::from(m / 4);
    let mut out = Schedule::new();
    for theta_i in INCIDENCE_DEG {
        let (n_below, n_above) = strategy1_split(theta_i, per_incidence - 1);
        for j in 0..n_below {
            let _ = out.push(Geometry::from_whole_deg(
                theta_i,
                round_half_up(theta_i * j, n_below),
            ));
        }
        for j in 0..=n_above {
            let theta_r = theta_i + round_half_up((THETA_R_MAX_DEG - theta_i) * j, n_above);
            let _ = out.push(Geometry::from_whole_deg(theta_i, theta_r));
        }
    }
    Some(out)
}

/// Strategy 2 with interval `delta_deg` (Table 5): per θi, {0, θi, 70} and θi + kδ for
/// k = −n…n, n = ceil(10/δ), kept where 0 ≤ θr ≤ 70; at θi = 60° the fixed point
/// (60, 70) is left out when δ does not divide 10. Returns `None` for δ outside 1…10.
pub fn strategy2(delta_deg: u8) -> Option<Schedule> {
    if !STRATEGY2_DELTAS.contains(&delta_deg) {
        return None;
    }
    let delta = i32::from(delta_deg);
    let n = (STRATEGY2_HALF_WIDTH_DEG + delta - 1) / delta;
    let mut out = Schedule::new();
    for theta_i in INCIDENCE_DEG {
        let mut theta_rs: Vec<i32, 32> = Vec::new();
        let keep_70 = theta_i != 60 || STRATEGY2_HALF_WIDTH_DEG % delta == 0;
        let fixed = [Some(0), Some(theta_i), keep_70.then_some(THETA_R_MAX_DEG)];
        let band = (-n..=n)
            .map(|k| theta_i + k * delta)
            .filter(|r| (0..=THETA_R_MAX_DEG).contains(r));
        for theta_r in fixed.into_iter().flatten().chain(band) {
            if !theta_rs.contains(&theta_r) {
                // At most 3 + 21 points: fits in 32.
                let _ = theta_rs.push(theta_r);
            }
        }
        theta_rs.sort_unstable();
        for theta_r in theta_rs {
            let _ = out.push(Geometry::from_whole_deg(theta_i, theta_r));
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn theta_rs(schedule: &Schedule, theta_i: i32) -> std::vec::Vec<i32> {
        schedule
            .iter()
            .filter(|g| g.theta_i.ticks() == theta_i * 80)
            .map(|g| g.theta_r.ticks() / 80)
            .collect()
    }

    #[test]
    fn strategy1_sizes_match_table4() {
        for (m, _) in STRATEGY1 {
            let s = strategy1(m).unwrap();
            assert_eq!(s.len(), usize::from(m), "M = {m}");
            for theta_i in INCIDENCE_DEG {
                let rs = theta_rs(&s, theta_i);
                assert!(
                    rs.contains(&0) && rs.contains(&theta_i) && rs.contains(&70),
                    "M = {m}, θi = {theta_i}"
                );
                assert!(
                    rs.windows(2).all(|w| w[0] < w[1]),
                    "M = {m}, θi = {theta_i}: {rs:?}"
                );
            }
        }
        assert!(strategy1(13).is_none());
    }

    #[test]
    fn strategy1_reproduces_legible_table4_entries() {
        let s16 = strategy1(16).unwrap();
        assert_eq!(theta_rs(&s16, 20), [0, 20, 45, 70]);
        assert_eq!(theta_rs(&s16, 30), [0, 30, 50, 70]);
        assert_eq!(theta_rs(&s16, 45), [0, 23, 45, 70]);
        assert_eq!(theta_rs(&s16, 60), [0, 30, 60, 70]);
        let s20 = strategy1(20).unwrap();
        assert_eq!(theta_rs(&s20, 20), [0, 20, 37, 53, 70]);
        assert_eq!(theta_rs(&s20, 30), [0, 15, 30, 50, 70]);
        assert_eq!(theta_rs(&s20, 45), [0, 23, 45, 58, 70]);
        assert_eq!(theta_rs(&s20, 60), [0, 20, 40, 60, 70]);
        let s24 = strategy1(24).unwrap();
        assert_eq!(theta_rs(&s24, 30), [0, 15, 30, 43, 57, 70]);
        assert_eq!(theta_rs(&s24, 45), [0, 15, 30, 45, 58, 70]);
    }

    #[test]
    fn strategy2_bounds() {
        assert!(strategy2(0).is_none());
        assert!(strategy2(11).is_none());
        assert_eq!(full_grid().len(), 284);
    }
}
