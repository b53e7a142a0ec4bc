//! The one fail-safe stop path and what it does to the homing: a stop with both arms at
//! rest and no driver fault keeps it (a ramped stop loses no steps, and a still arm none at
//! all), one mid-move or on a driver fault loses it until the next `Home`.

use crate::common;

use common::Bench;
use firmware::hardware::Arm;
use protocol::*;

fn homed_bench() -> Bench {
    let mut bench = Bench::new();
    bench.home();
    bench
}

fn moving(bench: &Bench) -> bool {
    firmware::Arms::is_moving(bench.hw(), Arm::Source)
        || firmware::Arms::is_moving(bench.hw(), Arm::Detector)
}

fn upload(bench: &mut Bench, schedule_id: u16, geometries: &[Geometry]) {
    let chunk = ScheduleChunk {
        schedule_id,
        total_len: geometries.len() as u16,
        offset: 0,
        geometries: heapless::Vec::from_slice(geometries).unwrap(),
    };
    assert!(matches!(
        bench.ask(Command::UploadSchedule(chunk)),
        Ok(Reply::ScheduleLoaded { .. })
    ));
}

fn run(bench: &mut Bench, schedule_id: u16, integration_ms: u16) {
    let run = RunSchedule {
        schedule_id,
        source: ScheduleSource::Uploaded,
        integration_ms,
        target: Target::Sample,
    };
    assert!(matches!(
        bench.ask(Command::RunSchedule(run)),
        Ok(Reply::ScheduleStarted { .. })
    ));
}

/// Run silent (no frame from the host) until the device takes its stop; returns whether
/// an arm was moving when it did.
fn silent_until_stopped(bench: &mut Bench) -> bool {
    bench.heartbeat_every_ms = None;
    let before = bench.stopped_reasons().len();
    for _ in 0..10_000 {
        let was_moving = moving(bench);
        bench.tick();
        if bench.stopped_reasons().len() > before {
            bench.heartbeat_every_ms = Some(500);
            return was_moving;
        }
    }
    panic!("no fail-safe stop")
}

#[test]
fn heartbeat_loss_while_parked_with_the_lamp_on_keeps_the_homing() {
    let mut bench = homed_bench();
    let parked = Geometry::from_whole_deg(45, 45);
    assert_eq!(bench.ask(Command::MoveTo(parked)), Ok(Reply::Ack));
    assert_eq!(bench.ask(Command::SetLamp { on: true }), Ok(Reply::Ack));
    // The operator takes their time at a prompt; the host sends nothing.
    assert!(!silent_until_stopped(&mut bench), "the arms were parked");
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HeartbeatLost]);
    assert!(!bench.hw().lamp_on(), "the lamp goes off");
    let status = bench.status();
    assert_eq!(
        status.state,
        DeviceState::Idle,
        "not Stopped: nothing was lost"
    );
    assert!(status.homed_i && status.homed_r);
    assert_eq!(
        status.fault,
        Some(ErrorCode::HeartbeatLost),
        "the stop is on record"
    );
    assert!(!status.lamp_on);
    assert_eq!(status.position, bench.hw().true_geometry());
    // The session goes on without a new Home.
    let next = Geometry::from_whole_deg(20, 0);
    assert_eq!(bench.ask(Command::MoveTo(next)), Ok(Reply::Ack));
    assert_eq!(bench.hw().true_geometry(), next);
    assert_eq!(bench.ask(Command::SetLamp { on: true }), Ok(Reply::Ack));
    assert!(matches!(
        bench.ask(Command::TakeReading {
            integration_ms: 100,
            target: Target::Sample,
            range: None
        }),
        Ok(Reply::Reading(_))
    ));
    // And the next Home finds no lost steps.
    assert_eq!(
        bench.home(),
        HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(0)
        }
    );
}

#[test]
fn heartbeat_loss_mid_move_loses_the_homing() {
    let mut bench = homed_bench();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    // Long moves back and forth with short readings: the arms are under way most of the
    // time. The first move (from the switches, 87.5°, to (0°, 85°)) and its reading take
    // 1.9 s, so 2 s of silence after the start land in the second move.
    let far = [
        Geometry::from_whole_deg(0, 85),
        Geometry::from_whole_deg(85, 0),
    ];
    upload(&mut bench, 5, &[far[0], far[1], far[0], far[1]]);
    run(&mut bench, 5, 10);
    assert!(silent_until_stopped(&mut bench), "the stop came mid-move");
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HeartbeatLost]);
    assert!(!bench.hw().lamp_on());
    let done = bench.schedule_done(5).expect("the schedule ends");
    assert_eq!(
        (done.readings, done.error),
        (1, Some(ErrorCode::HeartbeatLost))
    );
    // While the arms ramp down the device is stopped, and stays so at rest.
    assert_eq!(bench.status().state, DeviceState::Stopped);
    bench.wait_at_rest();
    assert_eq!(bench.hw().profiles_over_limits, 0);
    let status = bench.status();
    assert_eq!(status.state, DeviceState::Stopped);
    assert_eq!(status.fault, Some(ErrorCode::HeartbeatLost));
    assert!(
        !status.homed_i && !status.homed_r,
        "conservative mid-move: not homed"
    );
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(30, 30))),
        Err(DeviceError::new(ErrorCode::NotHomed))
    );
    // The ramped stop lost nothing, as the re-home shows; the fault is cleared.
    assert_eq!(
        bench.home(),
        HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(0)
        }
    );
    let status = bench.status();
    assert_eq!((status.state, status.fault), (DeviceState::Idle, None));
}

#[test]
fn heartbeat_loss_during_a_schedules_integration_keeps_the_homing() {
    let mut bench = homed_bench();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    // One geometry, a long integration: the arms get there in under a second and then
    // stand still for 5 s while the reading integrates.
    upload(
        &mut bench,
        6,
        &[
            Geometry::from_whole_deg(60, 60),
            Geometry::from_whole_deg(20, 20),
        ],
    );
    run(&mut bench, 6, 5_000);
    bench.run_ms(1_200);
    assert!(!moving(&bench));
    assert_eq!(bench.status().state, DeviceState::RunningSchedule);
    assert!(!silent_until_stopped(&mut bench), "the arms stood still");
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HeartbeatLost]);
    let done = bench
        .schedule_done(6)
        .expect("the schedule ends with the reason");
    assert_eq!(
        (done.readings, done.error),
        (0, Some(ErrorCode::HeartbeatLost))
    );
    assert!(
        bench.streamed(6).is_empty(),
        "no half-integrated reading is streamed"
    );
    assert!(!bench.hw().lamp_on());
    let status = bench.status();
    assert_eq!(status.state, DeviceState::Idle);
    assert!(status.homed_i && status.homed_r);
    assert_eq!(status.fault, Some(ErrorCode::HeartbeatLost));
    assert_eq!(status.schedule, None);
    // The host re-runs what was lost without homing again.
    upload(
        &mut bench,
        7,
        &[
            Geometry::from_whole_deg(60, 60),
            Geometry::from_whole_deg(20, 20),
        ],
    );
    run(&mut bench, 7, 100);
    let done = bench.wait_schedule(7);
    assert_eq!(done.error, None);
    assert_eq!(bench.streamed(7).len(), 2);
}

#[test]
fn heartbeat_loss_while_a_reading_integrates_answers_it_and_keeps_the_homing() {
    let mut bench = homed_bench();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    let seq = bench.send(Command::TakeReading {
        integration_ms: 5_000,
        target: Target::Sample,
        range: None,
    });
    assert!(!silent_until_stopped(&mut bench));
    assert_eq!(
        bench.reply(seq),
        Some(Err(DeviceError::new(ErrorCode::HeartbeatLost)))
    );
    let status = bench.status();
    assert_eq!(status.state, DeviceState::Idle);
    assert!(status.homed_i && status.homed_r);
}

#[test]
fn a_driver_fault_at_rest_still_loses_the_homing() {
    let mut bench = homed_bench();
    bench
        .ask(Command::MoveTo(Geometry::from_whole_deg(30, 30)))
        .unwrap();
    // A de-energised motor may have moved: the step count no longer says where the arm is.
    bench.hw_mut().arms[1].driver_fault = true;
    // While DIAG is high (until the poll that takes the stop), nothing moves (detail: the arm).
    let refused = Err(DeviceError::with_detail(ErrorCode::HardwareFault, 1));
    let seq = bench.send(Command::MoveTo(Geometry::from_whole_deg(40, 40)));
    assert_eq!(bench.reply(seq), Some(refused));
    bench.run_ms(2);
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HardwareFault]);
    let status = bench.status();
    assert_eq!(status.state, DeviceState::Stopped);
    assert!(!status.homed_i && !status.homed_r);
    assert_eq!(status.fault, Some(ErrorCode::HardwareFault));
    // The faulted driver is disabled (which clears a TMC2209's latched DIAG); the healthy
    // one holds its arm. The stop is taken once, not at every poll.
    assert!(!bench.hw().arms[1].driver_enabled && bench.hw().arms[0].driver_enabled);
    bench.run_ms(100);
    assert_eq!(bench.stopped_reasons().len(), 1);
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(40, 40))),
        Err(DeviceError::new(ErrorCode::NotHomed))
    );
    // The fault went away: the next Home clears it (EN cycled) and searches (the count of a
    // de-energised motor is no guide) and reports the step error.
    assert_eq!(
        bench.home(),
        HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(0)
        }
    );
    assert!(bench.hw().arms[1].driver_enabled);
    // A second driver fault is a new occurrence: a new stop.
    bench.hw_mut().arms[0].driver_fault = true;
    bench.run_ms(2);
    assert_eq!(
        bench.stopped_reasons(),
        [ErrorCode::HardwareFault, ErrorCode::HardwareFault]
    );
}

#[test]
fn a_dead_detector_at_rest_keeps_the_homing() {
    // A fault of the ADC, not of the arms: the reading fails, the arms' count stands.
    let mut bench = homed_bench();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    bench.hw_mut().detector_dead = true;
    let reading = bench.ask(Command::TakeReading {
        integration_ms: 100,
        target: Target::Sample,
        range: None,
    });
    assert_eq!(reading, Err(DeviceError::new(ErrorCode::HardwareFault)));
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HardwareFault]);
    assert!(!bench.hw().lamp_on());
    let status = bench.status();
    assert_eq!(status.state, DeviceState::Idle);
    assert!(status.homed_i && status.homed_r);
    assert_eq!(status.fault, Some(ErrorCode::HardwareFault));
}

#[test]
fn abort_in_a_moves_settle_answers_the_move_and_keeps_the_homing() {
    // Abort is the host's stop, not a fail-safe one: it ends what runs the same way (the
    // pending move is answered) and keeps the lamp and the homing, mid-move or not.
    let mut bench = homed_bench();
    let target = Geometry::from_whole_deg(50, 30);
    let seq = bench.send(Command::MoveTo(target));
    while moving(&bench) {
        bench.tick();
    }
    assert_eq!(bench.hw().true_geometry(), target);
    assert_eq!(bench.reply(seq), None, "still settling");
    assert_eq!(bench.ask(Command::Abort), Ok(Reply::Ack));
    assert_eq!(
        bench.reply(seq),
        Some(Err(DeviceError::new(ErrorCode::Aborted)))
    );
    let status = bench.status();
    assert_eq!((status.state, status.fault), (DeviceState::Idle, None));
    assert!(status.homed_i && status.homed_r);
}

mod random {
    use super::*;
    use firmware::device::{DRIVER_RECHECK_US, DRIVER_RESET_US};
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// A driver fault at a random moment of a move, on either arm, gone or still there
        /// at the next `Home`: the faulted driver is disabled at the stop (its steps end
        /// there), the other arm ramps down enabled; a `Home` cycles EN (off for
        /// `DRIVER_RESET_US`) and homes when the fault went away, and refuses (the arm in
        /// the detail, the driver off again) while it persists.
        #[test]
        fn a_driver_fault_disables_its_driver_and_clears_on_home_once_gone(
            at_ms in 0u64..1_600,
            faulted in 0usize..2,
            persists in any::<bool>(),
        ) {
            let mut bench = homed_bench();
            let seq = bench.send(Command::MoveTo(Geometry::from_whole_deg(10, 40)));
            bench.run_ms(at_ms);
            let healthy = 1 - faulted;
            let healthy_was_moving = bench.hw().arms[healthy].step_timer_running();
            bench.hw_mut().arms[faulted].driver_fault = true;
            bench.hw_mut().arms[faulted].driver_fault_persists = persists;
            bench.tick();
            prop_assert_eq!(bench.stopped_reasons(), [ErrorCode::HardwareFault]);
            let arm = bench.hw().arms[faulted];
            prop_assert!(!arm.driver_enabled && !arm.step_timer_running(), "faulted arm off and still");
            prop_assert!(bench.hw().arms[healthy].driver_enabled);
            if healthy_was_moving {
                prop_assert!(bench.hw().arms[healthy].step_timer_running(), "the healthy arm ramps down");
            }
            let _ = bench.wait_reply(seq);
            bench.wait_at_rest();
            prop_assert!(!bench.hw().arms[faulted].driver_enabled);
            let refused = Err(DeviceError::with_detail(ErrorCode::HardwareFault, faulted as i32));
            if persists {
                prop_assert_eq!(bench.ask(Command::Home), refused);
                prop_assert!(!bench.hw().arms[faulted].driver_enabled, "off again");
                prop_assert_eq!(bench.hw().arms[faulted].driver_disables, 3);
                let status = bench.status();
                prop_assert_eq!(status.state, DeviceState::Stopped);
                prop_assert_eq!(status.fault, Some(ErrorCode::HardwareFault));
                prop_assert_eq!(bench.hw().arms[healthy].driver_disables, 0);
                bench.hw_mut().arms[faulted].driver_fault_persists = false;
            }
            // The fault went away: EN off for the reset time, then on, then the homing.
            let home = bench.send(Command::Home);
            bench.run_ms(DRIVER_RESET_US / 1000 - 1);
            prop_assert!(!bench.hw().arms[faulted].driver_enabled);
            bench.run_ms(2);
            prop_assert!(bench.hw().arms[faulted].driver_enabled);
            bench.run_ms(DRIVER_RECHECK_US / 1000);
            prop_assert!(matches!(bench.wait_reply(home), Ok(Reply::Homed(_))));
            prop_assert!(bench.hw().arms.iter().all(|arm| arm.driver_enabled));
            prop_assert_eq!(bench.hw().arms[healthy].driver_disables, 0, "the healthy driver kept its arm");
            let status = bench.status();
            prop_assert_eq!(status.state, DeviceState::Idle);
            prop_assert_eq!(status.fault, None);
            prop_assert_eq!(status.position, bench.hw().true_geometry());
        }

        /// The host goes silent at a random moment of a Strategy 1 run: the stop keeps the
        /// homing exactly when both arms stood still, the step count is the truth either way
        /// (a ramped stop loses nothing), and the device then accepts what it should.
        #[test]
        fn a_stop_at_any_moment_keeps_the_homing_exactly_when_the_arms_stood_still(silent_from_ms in 0u64..11_000) {
            let mut bench = homed_bench();
            bench.ask(Command::SetLamp { on: true }).unwrap();
            let run = RunSchedule { schedule_id: 1, source: ScheduleSource::Strategy1, integration_ms: 100, target: Target::Sample };
            let started = matches!(bench.ask(Command::RunSchedule(run)), Ok(Reply::ScheduleStarted { .. }));
            prop_assert!(started);
            bench.run_ms(silent_from_ms);
            // The lamp stays on after the run, so the silence always ends in a stop.
            let was_moving = silent_until_stopped(&mut bench);
            let done = bench.schedule_done(1).expect("the schedule ended, completed or stopped");
            prop_assert!(done.error.is_none() || done.error == Some(ErrorCode::HeartbeatLost), "{:?}", done);
            if done.error.is_none() {
                prop_assert!(!was_moving, "a finished schedule leaves the arms parked");
            }
            bench.wait_at_rest();
            let status = bench.status();
            prop_assert_eq!(status.homed_i && status.homed_r, !was_moving);
            prop_assert_eq!(status.state, if was_moving { DeviceState::Stopped } else { DeviceState::Idle });
            prop_assert_eq!(status.fault, Some(ErrorCode::HeartbeatLost));
            prop_assert_eq!(status.position, bench.hw().true_geometry());
            prop_assert!(!bench.hw().lamp_on());
            let next = Geometry::from_whole_deg(30, 30);
            if bench.status().homed_i {
                prop_assert_eq!(bench.ask(Command::MoveTo(next)), Ok(Reply::Ack));
                prop_assert_eq!(bench.hw().true_geometry(), next);
            } else {
                prop_assert_eq!(bench.ask(Command::MoveTo(next)), Err(DeviceError::new(ErrorCode::NotHomed)));
            }
            prop_assert_eq!(bench.home(), HomeReport { step_error_i: Some(0), step_error_r: Some(0) });
        }
    }
}
