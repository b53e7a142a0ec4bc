//! The home switches: debounced ([`firmware::switches`]), so that a glitch shorter than
//! `HOME_SWITCH_DEBOUNCE_SAMPLES` polls neither trips a homing nor stops the device, and a
//! held press does; and watched outside homing, where a press is a fail-safe stop that
//! costs the homing.

use crate::common;

use common::Bench;
use firmware::switches::{HOME_SWITCH_DEBOUNCE_SAMPLES, HomeSwitch};
use proptest::prelude::*;
use protocol::*;

/// The longest run of `true` in `samples`.
fn longest_press(samples: &[bool]) -> usize {
    samples
        .split(|&pressed| !pressed)
        .map(<[bool]>::len)
        .max()
        .unwrap_or(0)
}

#[test]
fn a_single_sample_does_not_make_a_state_three_do() {
    let mut switch = HomeSwitch::new();
    // The first state after boot is made like any other, and is no press.
    for steps in 0..3 {
        assert_eq!(switch.sample(false, steps), None);
    }
    assert!(!switch.state().unwrap().pressed);
    // One sample, two samples: glitches.
    assert_eq!(switch.sample(true, 10), None);
    assert_eq!(switch.sample(false, 11), None);
    assert_eq!(switch.sample(true, 12), None);
    assert_eq!(switch.sample(true, 13), None);
    assert_eq!(switch.sample(false, 14), None);
    assert!(!switch.state().unwrap().pressed);
    // Held: a press, from where it began.
    assert_eq!(switch.sample(true, 20), None);
    assert_eq!(switch.sample(true, 21), None);
    assert_eq!(switch.sample(true, 22), Some(true));
    assert_eq!(switch.state().unwrap().since_steps, 20);
    assert_eq!(switch.sample(false, 30), None);
    assert_eq!(switch.sample(false, 31), None);
    assert_eq!(switch.sample(false, 32), Some(false));
    // Standing on the switch at power-on is no press.
    let mut on = HomeSwitch::new();
    for steps in 0..5 {
        assert_eq!(on.sample(true, steps), None);
    }
    assert!(on.state().unwrap().pressed);
}

/// A parked, homed bench with the heartbeat running.
fn parked() -> Bench {
    let mut bench = Bench::new();
    bench.home();
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(40, 40))),
        Ok(Reply::Ack)
    );
    bench
}

#[test]
fn a_held_press_outside_homing_stops_and_costs_the_homing() {
    // Parked: the arms stood still, yet the homing is lost (the arm is where its count
    // says it is not).
    let mut bench = parked();
    bench.hw_mut().arms[1].switch_stuck = true;
    bench.run_ms(u64::from(HOME_SWITCH_DEBOUNCE_SAMPLES) - 1);
    assert!(
        bench.stopped_reasons().is_empty(),
        "not before the debounce"
    );
    bench.tick();
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HardwareFault]);
    let status = bench.status();
    assert_eq!(status.state, DeviceState::Stopped);
    assert!(!status.homed_i && !status.homed_r);
    // Held on: no second stop.
    bench.run_ms(50);
    assert_eq!(bench.stopped_reasons().len(), 1);
    bench.hw_mut().arms[1].switch_stuck = false;
    // Released for the debounce (a Home within it would find the switch still pressed).
    bench.run_ms(u64::from(HOME_SWITCH_DEBOUNCE_SAMPLES));
    bench.home();
    // Mid-move: the move is answered with the stop and the arms ramp down.
    let seq = bench.send(Command::MoveTo(Geometry::from_whole_deg(20, 60)));
    bench.run_ms(300);
    bench.hw_mut().arms[0].switch_stuck = true;
    let reply = bench.wait_reply(seq);
    assert_eq!(reply, Err(DeviceError::new(ErrorCode::HardwareFault)));
    bench.hw_mut().arms[0].switch_stuck = false;
    bench.wait_at_rest();
    let status = bench.status();
    assert_eq!(status.state, DeviceState::Stopped);
    assert_eq!(status.position, bench.hw().true_geometry());
}

#[test]
fn the_switches_pressed_during_and_after_homing_stop_nothing() {
    // Homing presses both switches (several times) and leaves the arms resting on them;
    // the first move leaves them.
    let mut bench = Bench::new();
    assert!(bench.hw().arms.iter().all(|arm| !arm.switch_stuck));
    bench.home();
    assert!(bench.stopped_reasons().is_empty());
    bench.run_ms(100);
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(30, 30))),
        Ok(Reply::Ack)
    );
    assert_eq!(
        bench.home(),
        HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(0)
        }
    );
    assert!(bench.stopped_reasons().is_empty());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Any pattern of raw samples: the debounced state changes exactly when a run of
    /// `HOME_SWITCH_DEBOUNCE_SAMPLES` equal samples says so, from where the run began.
    #[test]
    fn the_debounced_state_follows_runs_of_three(samples in prop::collection::vec(any::<bool>(), 1..60)) {
        let n = usize::from(HOME_SWITCH_DEBOUNCE_SAMPLES);
        let mut switch = HomeSwitch::new();
        let mut model: Option<(bool, i32)> = None;
        for (i, &pressed) in samples.iter().enumerate() {
            let change = switch.sample(pressed, i as i32 * 7);
            let run_start = i + 1 - samples[..=i].iter().rev().take_while(|&&p| p == pressed).count();
            let made = i + 1 - run_start >= n && model.map(|(p, _)| p) != Some(pressed);
            let expected_change = (made && model.is_some()).then_some(pressed);
            if made {
                // The run's start, but not before the sample after the last state (a run that
                // began under the old state is counted from where it differed).
                model = Some((pressed, run_start as i32 * 7));
            }
            prop_assert_eq!(change, expected_change, "at {}", i);
            prop_assert_eq!(switch.state().map(|s| (s.pressed, s.since_steps)), model);
        }
    }

    /// A parked, homed device sees a random pattern on a switch: it stops exactly when the
    /// pattern holds a press for `HOME_SWITCH_DEBOUNCE_SAMPLES` polls in a row.
    #[test]
    fn glitches_do_not_stop_the_device_a_held_press_does(
        samples in prop::collection::vec(prop::bool::weighted(0.4), 1..40),
        arm in 0usize..2,
    ) {
        let mut bench = parked();
        for &pressed in &samples {
            bench.hw_mut().arms[arm].switch_stuck = pressed;
            bench.tick();
        }
        bench.hw_mut().arms[arm].switch_stuck = false;
        bench.run_ms(5);
        let held = longest_press(&samples) >= usize::from(HOME_SWITCH_DEBOUNCE_SAMPLES);
        // One stop: after it the arms are not homed, and a second press stops nothing more.
        prop_assert_eq!(bench.stopped_reasons().len(), usize::from(held), "{:?}", samples);
        prop_assert_eq!(bench.status().homed_i, !held);
    }
}

#[test]
fn a_glitch_during_the_homings_search_is_no_trip() {
    // Two samples of a press mid-search (raw, it was a trip there, far from the switch, and
    // the approach after the back-off found nothing): the homing goes on and is exact.
    let mut bench = Bench::new();
    let seq = bench.send(Command::Home);
    bench.run_ms(300);
    for _ in 1..HOME_SWITCH_DEBOUNCE_SAMPLES {
        bench.hw_mut().arms[0].switch_stuck = true;
        bench.tick();
    }
    bench.hw_mut().arms[0].switch_stuck = false;
    assert!(matches!(bench.wait_reply(seq), Ok(Reply::Homed(_))));
    assert_eq!(bench.status().position, bench.hw().true_geometry());
    assert!(bench.stopped_reasons().is_empty());
}
