//! Motion profiles: never over the speed and acceleration limits, always ending exactly
//! on the target step (property tests over random moves), and both arms arriving together
//! on a straight line that keeps the collision guard.

use firmware::motion::{MoveProfile, plan_move};
use proptest::prelude::*;

/// The reference arms: 60 °/s and 180 °/s² at 80 steps/°.
const VMAX: f32 = 4800.0;
const AMAX: f32 = 14_400.0;
const EPS: f32 = 1e-3;

/// Sample the profile densely and check speed, acceleration, monotone position, step
/// timing and the exact end.
fn check_profile(profile: &MoveProfile, vmax: f32, amax: f32) -> Result<(), TestCaseError> {
    let duration = profile.duration_s();
    let samples = 4000;
    let dt = duration / samples as f32;
    let mut last_speed = profile.speed_at(0.0);
    let mut last_position = profile.start_steps();
    for i in 1..=samples + 10 {
        let t = i as f32 * dt;
        let speed = profile.speed_at(t);
        prop_assert!(speed <= vmax * (1.0 + EPS), "speed {speed} at {t}");
        if dt > 1e-6 {
            let accel = (speed - last_speed).abs() / dt;
            // The speed is continuous and piecewise linear, so its difference quotient is
            // bounded by the acceleration; the tolerance covers f32 rounding of v.
            prop_assert!(
                accel <= amax * (1.0 + EPS) + 0.01 / dt,
                "accel {accel} at {t}"
            );
        }
        last_speed = speed;
        let position = profile.position_at((t * 1e6) as u64);
        prop_assert!(
            (position - last_position) * profile.direction() >= 0,
            "position went back at {t}"
        );
        last_position = position;
    }
    prop_assert_eq!(
        profile.position_at(profile.duration_us()),
        profile.target_steps()
    );
    prop_assert_eq!(
        profile.position_at(profile.duration_us() + 1_000_000),
        profile.target_steps()
    );
    // Step times: increasing, no two steps closer than the speed limit allows, last at the end.
    let mut last_us = 0u64;
    for k in 1..=profile.step_count() {
        let at = profile.step_time_us(k);
        prop_assert!(at >= last_us);
        if k > 1 {
            prop_assert!(
                (at - last_us) as f32 >= 1e6 / vmax * (1.0 - 1e-2) - 1.0,
                "steps {k} too close"
            );
        }
        last_us = at;
    }
    prop_assert_eq!(last_us, profile.duration_us());
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn fastest_profiles_keep_the_limits_and_end_on_target(start in -8000i32..8000, target in -8000i32..8000) {
        let profile = MoveProfile::fastest(start, target, 0.0, VMAX, AMAX);
        prop_assert_eq!(profile.target_steps(), target);
        check_profile(&profile, VMAX, AMAX)?;
        // Not slower than needed: the textbook trapezoid time.
        let d = (target - start).abs() as f32;
        let best = if d >= VMAX * VMAX / AMAX { d / VMAX + VMAX / AMAX } else { 2.0 * (d / AMAX).sqrt() };
        prop_assert!((profile.duration_s() - best).abs() <= 1e-4 * best.max(1.0));
    }

    #[test]
    fn both_arms_arrive_together_on_a_straight_line(
        from_i in 0i32..6800, from_r in 0i32..6800, to_i in 0i32..6800, to_r in 0i32..6800,
    ) {
        let [source, detector] = plan_move([from_i, from_r], [to_i, to_r], VMAX, AMAX);
        prop_assert_eq!(source.target_steps(), to_i);
        prop_assert_eq!(detector.target_steps(), to_r);
        check_profile(&source, VMAX, AMAX)?;
        check_profile(&detector, VMAX, AMAX)?;
        if source.step_count() > 0 && detector.step_count() > 0 {
            prop_assert_eq!(source.duration_us(), detector.duration_us());
        }
        // Straight line in (θi, θr): the collision guard (a half-plane) holds in between
        // when it holds at both ends, to within the one-step rounding of each arm.
        let guard = 800;
        if from_i + from_r >= guard && to_i + to_r >= guard {
            let end = source.duration_us().max(detector.duration_us());
            for i in 0..=500u64 {
                let t = end * i / 500;
                prop_assert!(source.position_at(t) + detector.position_at(t) >= guard - 2);
            }
        }
    }

    #[test]
    fn ramped_stops_keep_the_limits(start in -8000i32..8000, up in any::<bool>(), speed in 0.0f32..VMAX) {
        let direction = if up { 1 } else { -1 };
        let profile = MoveProfile::stop(start, direction, speed, VMAX, AMAX);
        check_profile(&profile, VMAX, AMAX)?;
        // It brakes: never shorter than the braking distance, at most one step more.
        let braking = speed * speed / (2.0 * AMAX);
        prop_assert!(profile.step_count() as f32 >= braking - 1e-3);
        prop_assert!(profile.step_count() as f32 <= braking + 1.0 + 1e-3);
        if profile.step_count() > 0 {
            prop_assert_eq!(profile.direction(), direction);
        }
    }
}
