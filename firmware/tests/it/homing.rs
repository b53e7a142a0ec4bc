//! The quick re-home: on arms homed since reset, `Home` goes at full speed to 1.5° short of
//! where the count puts the switch and approaches slowly from there. Its step error is as
//! exact as the full homing's, whatever the error (ahead of the count by more than the
//! margin: the switch trips during the fast move; behind by more than the approach covers:
//! the full search). Device times are measured here in virtual time (deterministic) and
//! bounded; the table in `firmware/src/homing.rs` is this test's output.

use crate::common;

use common::{Bench, Hw, glossy_scene};
use firmware::config::InstrumentConfig;
use firmware::hardware::{Arm, ResetCause};
use firmware::testing::FakeHardware;
use protocol::*;

/// Home and return the report and the device time it took, µs.
fn timed_home(bench: &mut Bench) -> (HomeReport, u64) {
    let started = bench.now_us;
    let report = bench.home();
    (report, bench.now_us - started)
}

/// The first (full) homing of arms standing at `at`.
fn full_homing_from(at: Geometry) -> (HomeReport, u64) {
    let config = InstrumentConfig::REFERENCE;
    let hardware: Hw = FakeHardware::new(&config, glossy_scene, at);
    let mut bench = Bench::with_hardware(hardware, ResetCause::PowerOn);
    timed_home(&mut bench)
}

/// A homed bench whose arms were moved to `at`, then `lost` steps lost on `arm` (the true
/// angle falls behind the count by `lost`; negative: ahead); the re-home and its time.
fn quick_rehome_from(at: Geometry, lost: Option<(Arm, i32)>) -> (Bench, HomeReport, u64) {
    let mut bench = Bench::new();
    bench.home();
    assert_eq!(bench.ask(Command::MoveTo(at)), Ok(Reply::Ack));
    if let Some((arm, steps)) = lost {
        bench.hw_mut().lose_steps(arm, steps);
    }
    let (report, us) = timed_home(&mut bench);
    (bench, report, us)
}

fn expected_report(lost: Option<(Arm, i32)>) -> HomeReport {
    let mut errors = [Some(0), Some(0)];
    if let Some((arm, steps)) = lost {
        // Where the switch is minus where the arm believed it was: behind by `steps`.
        errors[arm.index()] = Some(-steps);
    }
    HomeReport {
        step_error_i: errors[0],
        step_error_r: errors[1],
    }
}

const POSITIONS: [(i32, i32); 3] = [(20, 0), (45, 45), (60, 70)];

/// The quick re-home from a measuring position, 40 steps lost or not: at most 3 s of device
/// time (measured 1.4–2.8 s), and at most three quarters of the full homing from the same
/// place (measured 2.8–5.8 s).
const QUICK_BOUND_US: u64 = 3_000_000;

#[test]
fn quick_rehome_is_exact_and_fast_from_measuring_positions() {
    let s = |us: u64| us as f64 / 1e6;
    eprintln!("device time of Home, both arms, s:");
    eprintln!("from       full   quick  src-40  det-40  src+40  det+40");
    for (i, r) in POSITIONS {
        let at = Geometry::from_whole_deg(i, r);
        let (full_report, full_us) = full_homing_from(at);
        assert_eq!(
            full_report,
            HomeReport {
                step_error_i: None,
                step_error_r: None
            }
        );
        let mut row = format!("({i:2},{r:2})  {:5.2}", s(full_us));
        let cases = [
            None,
            Some((Arm::Source, 40)),
            Some((Arm::Detector, 40)),
            Some((Arm::Source, -40)),
            Some((Arm::Detector, -40)),
        ];
        for lost in cases {
            let (bench, report, us) = quick_rehome_from(at, lost);
            assert_eq!(report, expected_report(lost), "from {at}, {lost:?}");
            assert_eq!(
                bench.device.status().position,
                bench.hw().true_geometry(),
                "the count is the truth again"
            );
            assert_eq!(bench.hw().profiles_over_limits, 0);
            assert!(
                us <= QUICK_BOUND_US,
                "quick re-home from {at}, {lost:?}: {} s",
                s(us)
            );
            assert!(
                us * 4 <= full_us * 3,
                "quick re-home from {at}, {lost:?}: {} s against {} s full",
                s(us),
                s(full_us)
            );
            row += &format!("  {:5.2} ", s(us));
        }
        eprintln!("{row}");
    }
}

#[test]
fn an_arm_further_than_it_believes_trips_during_the_fast_move() {
    // 2.5° ahead of its count (more than the 1.5° margin): the switch trips at full
    // speed's deceleration; stop, back off, approach slowly. The error is still exact.
    let config = InstrumentConfig::REFERENCE;
    let switch = config.home_switch.ticks();
    for arm in Arm::BOTH {
        let lost = Some((arm, -200));
        let (bench, report, us) = quick_rehome_from(Geometry::from_whole_deg(45, 45), lost);
        assert_eq!(report, expected_report(lost));
        assert_eq!(bench.device.status().position, bench.hw().true_geometry());
        // Overshoot past the switch: about the error beyond the margin (1°), no more than
        // the full search's own stop (1.1°) on top.
        let (_, highest) = bench.hw().arms[arm.index()].travel_ticks;
        assert!(
            highest <= switch + 80 + 90,
            "overshoot {} ticks",
            highest - switch
        );
        eprintln!("{arm:?} 2.5° ahead: {:.2} s", us as f64 / 1e6);
        assert!(us <= 5_000_000);
    }
}

#[test]
fn an_arm_far_ahead_of_its_count_backs_off_past_its_overshoot() {
    // 8° ahead (a gross fault): the switch trips with the fast move still at speed, the arm
    // stops 6.5° beyond it. A back-off of the usual 3° would leave the switch pressed and
    // call it stuck; the back-off covers the overshoot, and the error is exact.
    for arm in Arm::BOTH {
        let lost = Some((arm, -640));
        let (bench, report, us) = quick_rehome_from(Geometry::from_whole_deg(45, 45), lost);
        assert_eq!(report, expected_report(lost));
        assert_eq!(bench.device.status().position, bench.hw().true_geometry());
        assert_eq!(bench.hw().profiles_over_limits, 0);
        eprintln!("{arm:?} 8° ahead: {:.2} s", us as f64 / 1e6);
    }
}

#[test]
fn an_arm_far_behind_its_count_falls_back_to_the_full_search() {
    // 5° behind (more than the approach covers): the slow approach ends without the
    // switch, the full search finds it; the error is exact.
    for arm in Arm::BOTH {
        let lost = Some((arm, 400));
        let (bench, report, us) = quick_rehome_from(Geometry::from_whole_deg(45, 45), lost);
        assert_eq!(report, expected_report(lost));
        assert_eq!(bench.device.status().position, bench.hw().true_geometry());
        eprintln!("{arm:?} 5° behind: {:.2} s", us as f64 / 1e6);
    }
}

#[test]
fn rehoming_on_the_switch_and_just_after_homing() {
    // Home twice in a row (the arms stand just past the trip point): quick and exact.
    let mut bench = Bench::new();
    bench.home();
    let (report, us) = timed_home(&mut bench);
    assert_eq!(
        report,
        HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(0)
        }
    );
    assert!(us <= QUICK_BOUND_US, "{us}");
    // An arm sitting on its switch (pressed before anything moves): back off, approach.
    bench.hw_mut().lose_steps(Arm::Source, -30);
    let (report, _) = timed_home(&mut bench);
    assert_eq!(
        report,
        HomeReport {
            step_error_i: Some(30),
            step_error_r: Some(0)
        }
    );
}

#[test]
fn after_a_fail_safe_stop_mid_move_the_rehome_is_quick_and_exact() {
    // The count survives a ramped stop; the homing is withdrawn to be safe, and the quick
    // re-home gives it back and shows nothing was lost.
    let mut bench = Bench::new();
    bench.home();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    let far = [
        Geometry::from_whole_deg(0, 85),
        Geometry::from_whole_deg(85, 0),
    ];
    let chunk = ScheduleChunk {
        schedule_id: 1,
        total_len: 2,
        offset: 0,
        geometries: heapless::Vec::from_slice(&far).unwrap(),
    };
    bench.ask(Command::UploadSchedule(chunk)).unwrap();
    let run = RunSchedule {
        schedule_id: 1,
        source: ScheduleSource::Uploaded,
        integration_ms: 10,
        target: Target::Sample,
    };
    bench.ask(Command::RunSchedule(run)).unwrap();
    bench.heartbeat_every_ms = None;
    bench.run_ms(2_100);
    bench.heartbeat_every_ms = Some(500);
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HeartbeatLost]);
    bench.wait_at_rest();
    assert!(!bench.status().homed_i);
    let (report, us) = timed_home(&mut bench);
    assert_eq!(
        report,
        HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(0)
        }
    );
    assert!(us <= QUICK_BOUND_US, "{us}");
}

#[test]
fn after_a_driver_fault_the_rehome_searches() {
    // A de-energised motor may have moved anywhere: the count is no guide to go fast by.
    let mut bench = Bench::new();
    bench.home();
    bench
        .ask(Command::MoveTo(Geometry::from_whole_deg(45, 45)))
        .unwrap();
    bench.hw_mut().arms[0].driver_fault = true;
    bench.run_ms(2);
    bench.hw_mut().arms[0].driver_fault = false;
    // The arm dropped 10° while its driver was off.
    bench.hw_mut().lose_steps(Arm::Source, 800);
    let (report, us) = timed_home(&mut bench);
    assert_eq!(
        report,
        HomeReport {
            step_error_i: Some(-800),
            step_error_r: Some(0)
        }
    );
    let (_, full_us) = full_homing_from(Geometry::from_whole_deg(35, 45));
    assert!(
        us + 200_000 >= full_us,
        "searched: {us} µs against {full_us} µs"
    );
}

mod random {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        /// From anywhere in the working range, with any number of steps lost (or gained) on
        /// either arm, the re-home reports the error exactly and the count is the truth
        /// again; with up to 40 steps lost it stays within the quick bound.
        #[test]
        fn the_rehome_step_error_is_exact_from_anywhere(
            theta_i in 0i32..=85, theta_r in 10i32..=85,
            arm in prop_oneof![Just(Arm::Source), Just(Arm::Detector)],
            lost in -1200i32..=1200,
        ) {
            let at = Geometry::from_whole_deg(theta_i, theta_r);
            // The mechanics end where a full-speed stop past the switch would (87.5° + 10°):
            // no arm stands further out, whatever its count says.
            let believed = if arm == Arm::Source { theta_i } else { theta_r };
            prop_assume!(believed * 80 - lost <= 7800);
            let (bench, report, us) = quick_rehome_from(at, Some((arm, lost)));
            prop_assert_eq!(report, expected_report(Some((arm, lost))));
            prop_assert_eq!(bench.device.status().position, bench.hw().true_geometry());
            prop_assert_eq!(bench.hw().profiles_over_limits, 0);
            if lost.abs() <= 40 {
                prop_assert!(us <= QUICK_BOUND_US, "{} µs", us);
            }
        }
    }
}

/// `DeviceInfo::longest_home_ms` bounds every homing, failures included (a host waits for
/// the answer that long): full homings from across the range, quick re-homes with steps
/// lost either way (the fall-back to the full search included), and a missing switch.
#[test]
fn every_homing_ends_within_the_announced_longest() {
    let config = InstrumentConfig::REFERENCE;
    let longest_us = firmware::homing::longest_homing_us(&config);
    assert_eq!(
        config.device_info("").longest_home_ms as u64,
        longest_us.div_ceil(1000)
    );
    let mut worst = 0u64;
    for theta_i in (0..=85).step_by(17) {
        for theta_r in (0..=85).step_by(17) {
            let (_, us) = full_homing_from(Geometry::from_whole_deg(theta_i, theta_r));
            worst = worst.max(us);
        }
    }
    for lost in [-900, -400, -40, 40, 400, 900] {
        let (_, _, us) = quick_rehome_from(
            Geometry::from_whole_deg(10, 20),
            Some((Arm::Detector, lost)),
        );
        worst = worst.max(us);
    }
    // A switch that never trips: the search runs out, and the answer comes in time too.
    let hardware: Hw = FakeHardware::new(&config, glossy_scene, Geometry::from_whole_deg(0, 40));
    let mut bench = Bench::with_hardware(hardware, ResetCause::PowerOn);
    bench.hw_mut().arms[0].switch_missing = true;
    let started = bench.now_us;
    assert_eq!(
        bench.ask(Command::Home),
        Err(DeviceError::with_detail(ErrorCode::HomeSwitchNotFound, 0))
    );
    worst = worst.max(bench.now_us - started);
    println!(
        "longest homing measured {:.2} s, announced {:.2} s",
        worst as f64 * 1e-6,
        longest_us as f64 * 1e-6
    );
    assert!(
        worst <= longest_us,
        "a homing took {worst} µs, over the announced {longest_us} µs"
    );
    // A bound, not a guess: within twice the worst seen.
    assert!(
        longest_us <= 2 * worst + 2_000_000,
        "the bound {longest_us} µs is loose against {worst} µs"
    );
}
