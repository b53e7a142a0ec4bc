//! The collision guard through a stop: both arms stop together on the line of the move they
//! were making ([`firmware::motion::ArmMotion::stop_both`]), so wherever a move's endpoints
//! keep θi + θr ≥ the guard, the arms keep it at rest after an abort or a fail-safe stop at
//! any moment, and on the way there (a property over random moves and stop moments), to
//! within the one-step rounding of each arm.

use crate::common;

use common::Bench;
use firmware::config::InstrumentConfig;
use firmware::motion::{angle_to_steps, deg_to_steps, move_duration_us};
use firmware::sampling::SampleLoss;
use protocol::*;
use std::sync::atomic::{AtomicI32, Ordering};

/// What the rounding of each arm to whole steps may cost, ticks: one step per arm.
const ROUNDING_TICKS: i32 = 2;

/// How the stop is made.
#[derive(Clone, Copy, Debug)]
enum Stop {
    /// The host's `Abort`.
    Abort,
    /// A fail-safe stop (lost detector samples: nothing of the arms is at fault, so both
    /// ramp down).
    FailSafe,
}

fn guard_ticks() -> i32 {
    InstrumentConfig::REFERENCE.collision_min_sum.ticks()
}

fn sum(bench: &Bench) -> i32 {
    let g = bench.hw().true_geometry();
    g.theta_i.ticks() + g.theta_r.ticks()
}

fn moving(bench: &Bench) -> bool {
    firmware::Arms::is_moving(bench.hw(), firmware::Arm::Source)
        || firmware::Arms::is_moving(bench.hw(), firmware::Arm::Detector)
}

/// Move from `from` to `to` on a homed bench, stop `stop_ms` into the move, and return
/// the lowest θi + θr (ticks) from the stop until the arms rest, and where they rest.
fn stop_during(
    bench: &mut Bench,
    from: Geometry,
    to: Geometry,
    stop_ms: u64,
    how: Stop,
) -> (i32, Geometry) {
    assert_eq!(bench.ask(Command::MoveTo(from)), Ok(Reply::Ack));
    let seq = bench.send(Command::MoveTo(to));
    bench.run_ms(stop_ms);
    match how {
        Stop::Abort => {
            bench.send(Command::Abort);
        }
        Stop::FailSafe => {
            bench.hw_mut().sample_loss = Some(SampleLoss::AdcOverrun);
            bench.tick();
        }
    }
    let mut lowest = sum(bench);
    for _ in 0..5_000 {
        if !moving(bench) {
            break;
        }
        bench.tick();
        lowest = lowest.min(sum(bench));
    }
    assert!(!moving(bench), "the arms come to rest");
    // The move was answered (done or stopped) one way or another.
    let _ = bench.wait_reply(seq);
    (lowest, bench.hw().true_geometry())
}

#[test]
fn a_stop_at_peak_speed_of_a_move_along_the_guard_keeps_it() {
    // The review's case: (20°, 0°) → (0°, 10°), the source arm leads (1,600 steps, a
    // triangle whose peak, full speed, is at 1/3 s). Braked each at full deceleration the
    // detector arm stopped first and the arms rested at (0.01°, 7.50°): 7.51°.
    let config = InstrumentConfig::REFERENCE;
    let (from, to) = (
        Geometry::from_whole_deg(20, 0),
        Geometry::from_whole_deg(0, 10),
    );
    let peak_ms = (deg_to_steps(config.max_speed_deg_per_s) / deg_to_steps(config.accel_deg_per_s2)
        * 1000.0) as u64;
    assert_eq!(peak_ms, 333);
    for how in [Stop::Abort, Stop::FailSafe] {
        let mut bench = Bench::new();
        bench.home();
        let (lowest, rest) = stop_during(&mut bench, from, to, peak_ms, how);
        println!("{how:?} at {peak_ms} ms: rest at {rest}, lowest θi + θr {lowest} ticks");
        // On the line θi/20° + θr/10° = 1: the source arm has 10° to go at most and the
        // detector arm half its remaining travel short of 10°.
        let (i, r) = (rest.theta_i.ticks(), rest.theta_r.ticks());
        assert!(
            (i * 10 + r * 20 - 1600 * 10).abs() <= 20 + 10,
            "{rest} off the line"
        );
        assert!(
            i + r >= guard_ticks() - ROUNDING_TICKS,
            "{rest}: {} ticks",
            i + r
        );
        assert!(
            lowest >= guard_ticks() - ROUNDING_TICKS,
            "{lowest} ticks on the way"
        );
    }
}

mod random {
    use super::*;
    use proptest::prelude::*;

    /// The lowest θi + θr − guard found so far on the way and at rest, ticks (printed as
    /// they fall).
    static WORST_MARGIN: AtomicI32 = AtomicI32::new(i32::MAX);
    static WORST_REST_MARGIN: AtomicI32 = AtomicI32::new(i32::MAX);

    /// A legal geometry: a third on the guard's edge, a third within 15° of it (a move from
    /// there to the edge, the slower arm at half speed, is where braking each arm at full
    /// deceleration undershot most: 2.5°), the others anywhere.
    fn legal() -> impl Strategy<Value = Geometry> {
        let max = angle_to_steps(InstrumentConfig::REFERENCE.arm_max);
        let guard = guard_ticks();
        let near = |most: i32| {
            (0..=most, 0..=1000i32).prop_map(move |(extra, share)| {
                let sum = guard + extra;
                let i = sum * share / 1000;
                [i, sum - i]
            })
        };
        let anywhere = (0..=max, 0..=max)
            .prop_map(move |(i, extra)| [i, ((guard - i).max(0) + extra).min(max)]);
        prop_oneof![near(8), near(1200), anywhere]
            .prop_map(|[i, r]| Geometry::new(Angle::from_ticks(i), Angle::from_ticks(r)))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// A stop at any moment of any legal move keeps the guard, at rest and on the way.
        #[test]
        fn a_stop_at_any_moment_of_a_legal_move_keeps_the_guard(
            from in legal(),
            to in legal(),
            at in 0.0f64..1.0,
            abort in any::<bool>(),
        ) {
            let config = InstrumentConfig::REFERENCE;
            let steps = |g: Geometry| [g.theta_i.ticks(), g.theta_r.ticks()];
            let duration_us = move_duration_us(
                steps(from),
                steps(to),
                deg_to_steps(config.max_speed_deg_per_s),
                deg_to_steps(config.accel_deg_per_s2),
            );
            let stop_ms = (duration_us as f64 * at / 1000.0) as u64;
            let how = if abort { Stop::Abort } else { Stop::FailSafe };
            let mut bench = Bench::new();
            // Homing is most of the case's time; the reference bench stands at (30°, 30°).
            bench.home();
            let (lowest, rest) = stop_during(&mut bench, from, to, stop_ms, how);
            let margin = lowest - guard_ticks();
            if WORST_MARGIN.fetch_min(margin, Ordering::Relaxed) > margin {
                println!("worst margin so far {margin} ticks: {from} → {to} stopped at {stop_ms} ms ({how:?}), rest at {rest}");
            }
            let rest_margin = rest.theta_i.ticks() + rest.theta_r.ticks() - guard_ticks();
            if WORST_REST_MARGIN.fetch_min(rest_margin, Ordering::Relaxed) > rest_margin {
                println!("worst margin at rest so far {rest_margin} ticks: {from} → {to} stopped at {stop_ms} ms ({how:?}), rest at {rest}");
            }
            prop_assert!(rest_margin >= -ROUNDING_TICKS);
            prop_assert!(margin >= -ROUNDING_TICKS, "{} → {} stopped at {} ms: {} ticks under the guard, rest at {}", from, to, stop_ms, -margin, rest);
            // At rest between the move's endpoints, arm by arm.
            for (arm, (a, b)) in steps(from).into_iter().zip(steps(to)).enumerate() {
                let x = steps(rest)[arm];
                prop_assert!(x >= a.min(b) && x <= a.max(b), "arm {} at {} outside {}..{}", arm, x, a, b);
            }
        }
    }
}
