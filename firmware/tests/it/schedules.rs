//! The built-in Strategy 1 order: the method's 12 geometries, and the fastest order under
//! the library's own motion planner (re-running the offline Held–Karp search).

use firmware::config::InstrumentConfig;
use firmware::motion::{angle_to_steps, deg_to_steps, move_duration_us};
use firmware::schedule::STRATEGY1_ORDER;
use protocol::Geometry;

fn steps(g: Geometry) -> [i32; 2] {
    [angle_to_steps(g.theta_i), angle_to_steps(g.theta_r)]
}

fn move_us(from: [i32; 2], to: Geometry) -> u64 {
    let config = InstrumentConfig::REFERENCE;
    move_duration_us(
        from,
        steps(to),
        deg_to_steps(config.max_speed_deg_per_s),
        deg_to_steps(config.accel_deg_per_s2),
    )
}

/// Where homing leaves both arms.
fn home() -> [i32; 2] {
    let switch = angle_to_steps(InstrumentConfig::REFERENCE.home_switch);
    [switch, switch]
}

fn order_move_us(order: &[Geometry]) -> u64 {
    let mut here = home();
    let mut total = 0;
    for &g in order {
        total += move_us(here, g);
        here = steps(g);
    }
    total
}

#[test]
fn strategy1_order_is_a_permutation_of_the_method() {
    let mut method: Vec<Geometry> = protocol::schedules::strategy1(12).unwrap().to_vec();
    let mut ours = STRATEGY1_ORDER.to_vec();
    method.sort();
    ours.sort();
    assert_eq!(ours, method);
}

#[test]
fn strategy1_order_is_optimal() {
    let points: Vec<Geometry> = protocol::schedules::strategy1(12).unwrap().to_vec();
    let n = points.len();
    // Held–Karp: best[mask][last] = least move time visiting `mask`, ending at `last`.
    let mut best = vec![vec![u64::MAX; n]; 1 << n];
    for (i, &p) in points.iter().enumerate() {
        best[1 << i][i] = move_us(home(), p);
    }
    for mask in 1..(1usize << n) {
        for last in 0..n {
            let here = best[mask][last];
            if here == u64::MAX {
                continue;
            }
            for next in 0..n {
                if mask & (1 << next) != 0 {
                    continue;
                }
                let t = here + move_us(steps(points[last]), points[next]);
                let slot = &mut best[mask | (1 << next)][next];
                *slot = (*slot).min(t);
            }
        }
    }
    let optimum = *best[(1 << n) - 1].iter().min().unwrap();
    let ours = order_move_us(&STRATEGY1_ORDER);
    let paper = order_move_us(&points);
    eprintln!(
        "Strategy 1 move time from home: built-in order {ours} µs, optimum {optimum} µs, paper's order {paper} µs"
    );
    assert_eq!(ours, optimum);
    assert!(
        ours * 10 < paper * 6,
        "the built-in order saves over 40 % of the move time"
    );
}
