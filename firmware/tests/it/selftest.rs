//! The self-test ([`Command::SelfTest`]) on fake hardware: what it counts and times, that
//! nothing moves and the counts are put back, that it costs the homing, and that each
//! injected fault shows in its report (the host's limits are tested in `host`).

use crate::common;

use common::Bench;
use firmware::hardware::Arm;
use proptest::prelude::*;
use protocol::*;

fn self_test(bench: &mut Bench) -> SelfTestReport {
    match bench.ask(Command::SelfTest) {
        Ok(Reply::SelfTest(report)) => report,
        other => panic!("self-test answered {other:?}"),
    }
}

#[test]
fn pulses_are_counted_and_timed_and_nothing_moves() {
    let mut bench = Bench::new();
    bench.home();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    let before = bench.hw().true_geometry();
    let counts = Arm::BOTH.map(|arm| firmware::Arms::position_steps(bench.hw(), arm));
    let report = self_test(&mut bench);
    for pulses in [report.pulses_source, report.pulses_detector] {
        assert_eq!(pulses.steps_expected, SELF_TEST_PULSE_STEPS);
        assert_eq!(pulses.steps_counted, SELF_TEST_PULSE_STEPS);
        // 50° at 60°/s and 180°/s²: 50/60 + 1/3 s.
        assert!(
            (i64::from(pulses.duration_expected_us) - 1_166_667).abs() < 2,
            "{pulses:?}"
        );
        // Seen at rest at the first poll after the end (the bench polls every ms).
        let late = i64::from(pulses.duration_measured_us) - i64::from(pulses.duration_expected_us);
        assert!((0..=1_000).contains(&late), "{pulses:?}");
    }
    // One block per ms of the fake's 1 kHz detector.
    assert!(
        report.blocks_counted.abs_diff(report.blocks_expected) <= 1,
        "{report:?}"
    );
    assert_eq!(report.sample_losses, 0);
    assert_eq!(report.step_deadline_us, 12);
    assert_eq!(
        (report.range_selected, report.range_read_back),
        (0, Some(0))
    );
    assert!(!report.driver_fault_source && !report.driver_fault_detector);
    // Nothing moved, the counts are back, the lamp is off, the drivers too; not homed.
    let hw = bench.hw();
    assert_eq!(hw.true_geometry(), before);
    assert_eq!(
        Arm::BOTH.map(|arm| firmware::Arms::position_steps(hw, arm)),
        counts
    );
    assert!(!hw.lamp_on());
    assert!(hw.arms.iter().all(|arm| !arm.driver_enabled));
    let status = bench.status();
    assert!(!status.homed_i && !status.homed_r);
    assert_eq!(status.state, DeviceState::Idle);
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_deg(45.0, 45.0).unwrap())),
        Err(DeviceError::new(ErrorCode::NotHomed))
    );
    // A Home searches again and finds the arms where they were: no step error.
    let report = bench.home();
    assert_eq!(
        (report.step_error_i, report.step_error_r),
        (Some(0), Some(0))
    );
}

#[test]
fn each_fault_shows_in_the_report() {
    let mut bench = Bench::new();
    {
        let hw = bench.hw_mut();
        hw.arms[0].switch_stuck = true;
        hw.arms[1].diag_stuck = true;
        hw.clocks.hse_measured_hz = Some(8_000_000);
        hw.clocks.sysclk_measured_hz = Some(30_720_000);
        hw.step_timer_scale = 1.02;
        hw.worst_step_late_us = 9;
        hw.longest_interrupts_off_us = Some(31);
        hw.range_lines_read = Some(2);
        hw.resets.watchdog = 4;
        hw.stack_use = Some(firmware::StackUse {
            used_bytes: 100_000,
            size_bytes: 106_496,
        });
    }
    let report = self_test(&mut bench);
    assert!(report.switch_source && !report.switch_detector);
    assert!(!report.driver_fault_source && report.driver_fault_detector);
    assert_eq!(report.hse_measured_hz, Some(8_000_000));
    assert_eq!(report.sysclk_measured_hz, Some(30_720_000));
    let slow = report.pulses_source;
    assert!(
        f64::from(slow.duration_measured_us) > 1.019 * f64::from(slow.duration_expected_us),
        "{slow:?}"
    );
    assert_eq!(report.worst_step_late_us, 9);
    assert_eq!(report.longest_interrupts_off_us, Some(31));
    assert_eq!(report.range_read_back, Some(2));
    assert_eq!(report.resets_since_power_on.unwrap().watchdog, 4);
    assert_eq!(report.stack_used_bytes, Some(100_000));
}

#[test]
fn lost_samples_are_counted() {
    let mut bench = Bench::new();
    let seq = bench.send(Command::SelfTest);
    bench.run_ms(300);
    bench.hw_mut().sample_loss = Some(firmware::sampling::SampleLoss::RingFull);
    let Ok(Reply::SelfTest(report)) = bench.wait_reply(seq) else {
        panic!("no report");
    };
    assert_eq!(report.sample_losses, 1);
}

#[test]
fn refused_while_busy_and_ended_by_abort() {
    let mut bench = Bench::new();
    let home = bench.send(Command::Home);
    bench.run_ms(5);
    assert_eq!(
        bench.ask(Command::SelfTest),
        Err(DeviceError::new(ErrorCode::Busy))
    );
    bench.wait_reply(home).unwrap();
    let counts = Arm::BOTH.map(|arm| firmware::Arms::position_steps(bench.hw(), arm));
    let before = bench.hw().true_geometry();
    let seq = bench.send(Command::SelfTest);
    bench.run_ms(400);
    assert_eq!(bench.ask(Command::Abort), Ok(Reply::Ack));
    assert_eq!(
        bench.wait_reply(seq),
        Err(DeviceError::new(ErrorCode::Aborted))
    );
    bench.wait_at_rest();
    assert_eq!(bench.hw().true_geometry(), before);
    assert_eq!(
        Arm::BOTH.map(|arm| firmware::Arms::position_steps(bench.hw(), arm)),
        counts
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Whatever the step timers' pace, the pulse check measures it: the measured duration
    /// over the expected is the pace, to within the poll.
    #[test]
    fn the_pulse_rate_is_what_the_timer_runs(error_ppm in -50_000i32..50_000) {
        let mut bench = Bench::new();
        let scale = 1.0 + error_ppm as f32 * 1e-6;
        bench.hw_mut().step_timer_scale = scale;
        let report = self_test(&mut bench);
        for pulses in [report.pulses_source, report.pulses_detector] {
            let expected = f64::from(pulses.duration_expected_us) * f64::from(scale);
            let measured = f64::from(pulses.duration_measured_us);
            prop_assert!((measured - expected).abs() <= 1_001.0, "{:?} {}", pulses, expected);
            prop_assert_eq!(pulses.steps_counted, SELF_TEST_PULSE_STEPS);
        }
    }
}
