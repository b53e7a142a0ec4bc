//! The device on fake hardware: homing, every refusal, the heartbeat, abort, retries,
//! uploads and whole schedule runs, on a virtual clock.

use crate::common;

use common::{Bench, Hw, glossy_scene};
use firmware::config::InstrumentConfig;
use firmware::hardware::{Arm, ResetCause};
use firmware::schedule::STRATEGY1_ORDER;
use firmware::testing::FakeHardware;
use protocol::*;

fn err(code: ErrorCode) -> Result<Reply, DeviceError> {
    Err(DeviceError::new(code))
}

fn err_detail(code: ErrorCode, detail: i32) -> Result<Reply, DeviceError> {
    Err(DeviceError::with_detail(code, detail))
}

fn homed_bench() -> Bench {
    let mut bench = Bench::new();
    bench.home();
    bench
}

fn run_strategy1(bench: &mut Bench, schedule_id: u16) -> Result<Reply, DeviceError> {
    bench.ask(Command::RunSchedule(RunSchedule {
        schedule_id,
        source: ScheduleSource::Strategy1,
        integration_ms: 100,
        target: Target::Sample,
    }))
}

#[test]
fn homing_finds_both_switches_and_sets_the_positions() {
    let mut bench = Bench::new();
    let status = bench.status();
    assert!(!status.homed_i && !status.homed_r);
    let report = bench.home();
    // First homing after power-up: nothing to compare with.
    assert_eq!(
        report,
        HomeReport {
            step_error_i: None,
            step_error_r: None
        }
    );
    let status = bench.status();
    assert!(status.homed_i && status.homed_r);
    assert_eq!(status.state, DeviceState::Idle);
    assert_eq!(status.fault, None);
    // The step count now is the true angle.
    assert_eq!(status.position, bench.hw().true_geometry());
    // Homing never drives an arm back into the working range's far side.
    for arm in &bench.hw().arms {
        assert!(arm.travel_ticks.0 >= Angle::from_whole_deg(30).ticks());
    }
    assert_eq!(bench.hw().profiles_over_limits, 0);
}

#[test]
fn rehoming_reports_lost_steps() {
    let mut bench = homed_bench();
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(40, 50))),
        Ok(Reply::Ack)
    );
    // The source arm slips 37 steps: its true angle lags its count.
    bench.hw_mut().lose_steps(Arm::Source, 37);
    let report = bench.home();
    assert_eq!(
        report,
        HomeReport {
            step_error_i: Some(-37),
            step_error_r: Some(0)
        }
    );
    assert_eq!(bench.status().position, bench.hw().true_geometry());
}

#[test]
fn homing_fails_clearly_when_the_switch_is_missing_or_stuck() {
    let config = InstrumentConfig::REFERENCE;
    let mut hardware: Hw =
        FakeHardware::new(&config, glossy_scene, Geometry::from_whole_deg(30, 30));
    hardware.arms[1].switch_missing = true;
    let mut bench = Bench::with_hardware(hardware, ResetCause::PowerOn);
    assert_eq!(
        bench.ask(Command::Home),
        err_detail(ErrorCode::HomeSwitchNotFound, 1)
    );
    bench.wait_idle();
    // The search is bounded: no further than the search range from where it started.
    let (_, highest) = bench.hw().arms[1].travel_ticks;
    assert!(highest <= Angle::from_whole_deg(30).ticks() + config.home_search_range.ticks() + 80);
    let status = bench.status();
    assert!(!status.homed_i && !status.homed_r);
    assert_eq!(status.fault, Some(ErrorCode::HomeSwitchNotFound));

    let mut hardware: Hw =
        FakeHardware::new(&config, glossy_scene, Geometry::from_whole_deg(30, 30));
    hardware.arms[0].switch_stuck = true;
    let mut bench = Bench::with_hardware(hardware, ResetCause::PowerOn);
    assert_eq!(
        bench.ask(Command::Home),
        err_detail(ErrorCode::HomeSwitchStuck, 0)
    );
}

#[test]
fn every_refusal_comes_before_any_motion() {
    let mut bench = Bench::new();
    let target = Geometry::from_whole_deg(30, 40);
    // Not homed.
    assert_eq!(bench.ask(Command::MoveTo(target)), err(ErrorCode::NotHomed));
    assert_eq!(
        bench.ask(Command::TakeReading {
            integration_ms: 100,
            target: Target::Sample,
            range: None
        }),
        err(ErrorCode::NotHomed)
    );
    assert_eq!(run_strategy1(&mut bench, 1), err(ErrorCode::NotHomed));
    assert_eq!(bench.hw().profiles_started, 0);

    bench.home();
    let started = bench.hw().profiles_started;
    // Outside 0…85°, with the arm in the detail.
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(86, 20))),
        err_detail(ErrorCode::OutOfRange, 0)
    );
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(20, 86))),
        err_detail(ErrorCode::OutOfRange, 1)
    );
    let below = Geometry::new(Angle::from_whole_deg(20), Angle::from_ticks(-1));
    assert_eq!(
        bench.ask(Command::MoveTo(below)),
        err_detail(ErrorCode::OutOfRange, 1)
    );
    // Collision guard θi + θr ≥ 10°: 9.9875° is refused, 10° is not.
    let too_close = Geometry::new(Angle::from_whole_deg(5), Angle::from_ticks(5 * 80 - 1));
    assert_eq!(
        bench.ask(Command::MoveTo(too_close)),
        err(ErrorCode::CollisionGuard)
    );
    // Integration time 0 or over the maximum.
    assert_eq!(
        bench
            .ask(Command::TakeReading {
                integration_ms: 0,
                target: Target::Sample,
                range: None
            })
            .unwrap_err()
            .code,
        ErrorCode::InvalidArgument
    );
    assert_eq!(
        bench
            .ask(Command::TakeDark {
                integration_ms: 10_001
            })
            .unwrap_err()
            .code,
        ErrorCode::InvalidArgument
    );
    assert_eq!(
        bench.hw().profiles_started,
        started,
        "no refused command moved an arm"
    );

    // Busy while another move runs; abort is accepted.
    let moving = bench.send(Command::MoveTo(Geometry::from_whole_deg(5, 5)));
    bench.run_ms(50);
    let started = bench.hw().profiles_started;
    assert_eq!(bench.ask(Command::MoveTo(target)), err(ErrorCode::Busy));
    assert_eq!(bench.ask(Command::Home), err(ErrorCode::Busy));
    assert_eq!(run_strategy1(&mut bench, 2), err(ErrorCode::Busy));
    assert_eq!(bench.hw().profiles_started, started);
    assert_eq!(bench.ask(Command::Abort), Ok(Reply::Ack));
    assert_eq!(bench.reply(moving), Some(err(ErrorCode::Aborted)));
    bench.wait_idle();
    assert_eq!(bench.hw().profiles_over_limits, 0);
    // A ramped abort loses no steps: still homed, and the count is the true angle.
    let status = bench.status();
    assert!(status.homed_i && status.homed_r);
    assert_eq!(status.state, DeviceState::Idle);
    assert_eq!(status.position, bench.hw().true_geometry());
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(5, 5))),
        Ok(Reply::Ack)
    );
    assert_eq!(bench.hw().true_geometry(), Geometry::from_whole_deg(5, 5));
}

#[test]
fn heartbeat_loss_stops_the_arms_and_the_lamp() {
    let mut bench = homed_bench();
    assert_eq!(bench.ask(Command::SetLamp { on: true }), Ok(Reply::Ack));
    assert_eq!(
        run_strategy1(&mut bench, 7),
        Ok(Reply::ScheduleStarted {
            schedule_id: 7,
            len: 12
        })
    );
    let last_heard = bench.now_us;
    bench.heartbeat_every_ms = None;
    bench.run_ms(1999);
    assert!(
        bench.stopped_reasons().is_empty(),
        "2 s of silence are allowed"
    );
    bench.run_ms(2);
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HeartbeatLost]);
    assert!(bench.now_us - last_heard <= 2_001_000);
    // 2 s into Strategy 1 the arms are on their way to the third geometry: a stop
    // mid-move, which costs the homing (tests/it/failsafe.rs has the stops at rest).
    assert!(
        firmware::Arms::is_moving(bench.hw(), Arm::Source),
        "the stop came mid-move"
    );
    assert!(!bench.hw().lamp_on());
    let done = bench.schedule_done(7).expect("the schedule ends");
    assert_eq!(done.error, Some(ErrorCode::HeartbeatLost));
    // The arms ramp down (within the limits) and stop.
    bench.run_ms(1000);
    assert!(!firmware::Arms::is_moving(bench.hw(), Arm::Source));
    assert!(!firmware::Arms::is_moving(bench.hw(), Arm::Detector));
    assert_eq!(bench.hw().profiles_over_limits, 0);
    let status = bench.status();
    assert_eq!(status.state, DeviceState::Stopped);
    assert_eq!(status.fault, Some(ErrorCode::HeartbeatLost));
    assert!(!status.lamp_on && !status.homed_i && !status.homed_r);
    // Re-homing clears the fault and finds no lost steps.
    bench.heartbeat_every_ms = Some(500);
    let report = bench.home();
    assert_eq!(
        report,
        HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(0)
        }
    );
    assert_eq!(bench.status().state, DeviceState::Idle);
}

#[test]
fn heartbeat_is_needed_only_while_moving_or_lit() {
    let mut bench = homed_bench();
    bench.heartbeat_every_ms = None;
    bench.run_ms(10_000);
    assert!(bench.stopped_reasons().is_empty());
    // Any frame counts, not only heartbeats.
    assert_eq!(bench.ask(Command::SetLamp { on: true }), Ok(Reply::Ack));
    for _ in 0..4 {
        bench.run_ms(1500);
        bench.status();
    }
    assert!(bench.stopped_reasons().is_empty());
    bench.run_ms(2001);
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HeartbeatLost]);
    assert!(!bench.hw().lamp_on());
}

#[test]
fn driver_fault_takes_the_fail_safe_stop() {
    let mut bench = homed_bench();
    let seq = bench.send(Command::MoveTo(Geometry::from_whole_deg(10, 10)));
    bench.run_ms(200);
    bench.hw_mut().arms[0].driver_fault = true;
    bench.run_ms(1);
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HardwareFault]);
    assert_eq!(bench.reply(seq), Some(err(ErrorCode::HardwareFault)));
    assert_eq!(bench.status().fault, Some(ErrorCode::HardwareFault));
}

#[test]
fn watchdog_reset_leaves_the_arms_unhomed_and_says_so() {
    let config = InstrumentConfig::REFERENCE;
    let hardware: Hw = FakeHardware::new(&config, glossy_scene, Geometry::from_whole_deg(50, 20));
    let mut bench = Bench::with_hardware(hardware, ResetCause::Watchdog);
    let status = bench.status();
    assert_eq!(status.fault, Some(ErrorCode::WatchdogReset));
    assert_eq!(status.state, DeviceState::Stopped);
    assert!(!status.homed_i && !status.homed_r);
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(30, 30))),
        err(ErrorCode::NotHomed)
    );
    // A reset forgets the count: nothing to compare on the first homing.
    assert_eq!(
        bench.home(),
        HomeReport {
            step_error_i: None,
            step_error_r: None
        }
    );
    let status = bench.status();
    assert_eq!((status.fault, status.state), (None, DeviceState::Idle));
}

#[test]
fn a_repeated_sequence_number_is_not_executed_twice() {
    let mut bench = homed_bench();
    let request = Request {
        seq: 1000,
        command: Command::MoveTo(Geometry::from_whole_deg(45, 45)),
    };
    bench.send_bytes(&common::frame(&request));
    bench.run_ms(100);
    let started = bench.hw().profiles_started;
    // The host retries while the move runs: no second move, no early reply.
    bench.send_bytes(&common::frame(&request));
    assert_eq!(bench.hw().profiles_started, started);
    assert!(bench.reply(1000).is_none());
    bench.wait_idle();
    assert_eq!(bench.replies(1000), [Ok(Reply::Ack)]);
    // And after the reply: answered again from the cache, still not moved again.
    bench.send_bytes(&common::frame(&request));
    bench.run_ms(10);
    assert_eq!(bench.replies(1000), [Ok(Reply::Ack), Ok(Reply::Ack)]);
    assert_eq!(bench.hw().profiles_started, started);
}

#[test]
fn heartbeats_do_not_push_a_pending_reply_out_of_the_cache() {
    let mut bench = Bench::new();
    let request = Request {
        seq: 2000,
        command: Command::Home,
    };
    bench.send_bytes(&common::frame(&request));
    // The host keeps the link alive while the arms home; the Home reply then gets lost
    // and the host retries it after the heartbeats and a status were answered.
    for _ in 0..3 {
        bench.run_ms(300);
        assert_eq!(bench.ask(Command::Heartbeat), Ok(Reply::Ack));
    }
    bench.wait_idle();
    assert!(bench.ask(Command::GetStatus).is_ok());
    let started = bench.hw().profiles_started;
    assert_eq!(bench.replies(2000).len(), 1);
    bench.send_bytes(&common::frame(&request));
    bench.run_ms(10);
    assert_eq!(bench.replies(2000).len(), 2, "the retry is answered");
    assert_eq!(bench.replies(2000)[0], bench.replies(2000)[1]);
    assert_eq!(
        bench.hw().profiles_started,
        started,
        "the arms homed a second time"
    );
}

fn chunk(schedule_id: u16, total_len: u16, offset: u16, geometries: &[Geometry]) -> Command {
    Command::UploadSchedule(ScheduleChunk {
        schedule_id,
        total_len,
        offset,
        geometries: heapless::Vec::from_slice(geometries).unwrap(),
    })
}

#[test]
fn chunked_upload_runs_in_the_order_given() {
    let mut bench = homed_bench();
    // 40 geometries of Strategy 2 (δ = 2°), deliberately in reverse: the host plans.
    let mut geometries: Vec<Geometry> = protocol::schedules::strategy2(2)
        .unwrap()
        .iter()
        .copied()
        .take(40)
        .collect();
    geometries.reverse();
    let loaded = |received| {
        Ok(Reply::ScheduleLoaded {
            schedule_id: 3,
            received,
            total_len: 40,
        })
    };
    assert_eq!(bench.ask(chunk(3, 40, 0, &geometries[..16])), loaded(16));
    // Out of order: refused with the expected offset.
    assert_eq!(
        bench.ask(chunk(3, 40, 20, &geometries[20..36])),
        err_detail(ErrorCode::BadSchedule, 16)
    );
    // Incomplete: cannot run yet.
    let run = RunSchedule {
        schedule_id: 3,
        source: ScheduleSource::Uploaded,
        integration_ms: 50,
        target: Target::Sample,
    };
    assert_eq!(
        bench.ask(Command::RunSchedule(run)),
        err(ErrorCode::NoSchedule)
    );
    assert_eq!(bench.ask(chunk(3, 40, 16, &geometries[16..32])), loaded(32));
    assert_eq!(bench.ask(chunk(3, 40, 32, &geometries[32..])), loaded(40));
    // Wrong id.
    assert_eq!(
        bench.ask(Command::RunSchedule(RunSchedule {
            schedule_id: 4,
            ..run
        })),
        err(ErrorCode::NoSchedule)
    );
    assert_eq!(
        bench.ask(Command::RunSchedule(run)),
        Ok(Reply::ScheduleStarted {
            schedule_id: 3,
            len: 40
        })
    );
    let done = bench.wait_schedule(3);
    assert_eq!((done.readings, done.error), (40, None));
    let streamed = bench.streamed(3);
    let visited: Vec<Geometry> = streamed.iter().map(|r| r.geometry).collect();
    assert_eq!(visited, geometries);
    assert!(
        streamed
            .iter()
            .enumerate()
            .all(|(i, r)| usize::from(r.index) == i && r.reading.integration_ms == 50)
    );
}

#[test]
fn uploads_beyond_the_limits_are_refused() {
    let mut bench = Bench::new();
    let g = [Geometry::from_whole_deg(20, 20)];
    assert_eq!(
        bench.ask(chunk(1, 289, 0, &g)),
        err_detail(ErrorCode::ScheduleTooLong, 288)
    );
    assert_eq!(
        bench.ask(chunk(1, 288, 0, &g)),
        Ok(Reply::ScheduleLoaded {
            schedule_id: 1,
            received: 1,
            total_len: 288
        })
    );
    assert_eq!(
        bench.ask(chunk(2, 1, 0, &[Geometry::from_whole_deg(90, 20)])),
        err_detail(ErrorCode::OutOfRange, 0)
    );
    assert_eq!(
        bench.ask(chunk(2, 1, 0, &[Geometry::from_whole_deg(3, 3)])),
        err(ErrorCode::CollisionGuard)
    );
    assert_eq!(
        bench.ask(chunk(2, 1, 0, &[g[0], g[0]])).unwrap_err().code,
        ErrorCode::BadSchedule
    );
}

#[test]
fn strategy1_runs_in_the_built_in_order_and_streams_every_reading() {
    let mut bench = homed_bench();
    assert_eq!(bench.ask(Command::SetLamp { on: true }), Ok(Reply::Ack));
    let started_us = bench.now_us;
    assert_eq!(
        run_strategy1(&mut bench, 12),
        Ok(Reply::ScheduleStarted {
            schedule_id: 12,
            len: 12
        })
    );
    let done = bench.wait_schedule(12);
    assert_eq!((done.readings, done.error), (12, None));
    let streamed = bench.streamed(12);
    assert_eq!(streamed.len(), 12);
    for (i, (reading, &geometry)) in streamed.iter().zip(&STRATEGY1_ORDER).enumerate() {
        assert_eq!(usize::from(reading.index), i);
        assert_eq!(
            reading.geometry, geometry,
            "readings carry the geometry reached"
        );
        assert_eq!(reading.target, Target::Sample);
        assert!(reading.device_time_us > started_us);
        let r = reading.reading;
        assert!(
            !r.saturated && r.samples >= 95 && r.integration_ms == 100,
            "{r:?}"
        );
        // Auto-ranging: the glossy specular peak on the least sensitive range, the diffuse
        // part on the most sensitive; never saturated, never deep in the noise.
        let expected_range = if geometry.is_specular() { 2 } else { 0 };
        assert_eq!(r.range, expected_range, "{geometry}: {r:?}");
        let full_scale = 65_535.0;
        assert!(
            r.mean_counts < 0.98 * full_scale && r.mean_counts > 0.05 * full_scale,
            "{geometry}: {r:?}"
        );
    }
    assert!(
        streamed
            .windows(2)
            .all(|w| w[0].device_time_us < w[1].device_time_us)
    );
    // The whole run: 6.98 s of moves, 12 × (100 ms settle + 100 ms integration), plus the
    // re-integrations auto-ranging needed.
    let seconds = done.device_us as f64 / 1e6;
    eprintln!("Strategy 1, built-in order: device time {seconds:.3} s");
    assert!((9.0..12.5).contains(&seconds), "{seconds}");
    assert_eq!(bench.hw().profiles_over_limits, 0);
}

#[test]
fn strategy1_built_in_order_beats_the_papers_order() {
    let mut bench = homed_bench();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    run_strategy1(&mut bench, 1).unwrap();
    let built_in = bench.wait_schedule(1).device_us;

    let mut bench = homed_bench();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    let paper = protocol::schedules::strategy1(12).unwrap();
    bench.ask(chunk(2, 12, 0, &paper)).unwrap();
    let run = RunSchedule {
        schedule_id: 2,
        source: ScheduleSource::Uploaded,
        integration_ms: 100,
        target: Target::Sample,
    };
    bench.ask(Command::RunSchedule(run)).unwrap();
    let in_paper_order = bench.wait_schedule(2).device_us;
    eprintln!(
        "Strategy 1 device time: built-in order {built_in} µs, paper's order {in_paper_order} µs"
    );
    assert!(built_in + 5_000_000 < in_paper_order);
}

#[test]
fn dark_readings_one_per_range_with_the_lamp_off() {
    let mut bench = Bench::new();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    let Ok(Reply::Dark(readings)) = bench.ask(Command::TakeDark {
        integration_ms: 100,
    }) else {
        panic!("no dark")
    };
    assert_eq!(
        readings.iter().map(|r| r.range).collect::<Vec<_>>(),
        [0, 1, 2]
    );
    assert!(!bench.hw().lamp_on());
    for r in &readings {
        // Dark ≈ 0.3 % of full scale, noise 0.02 %.
        assert!((r.mean_counts - 0.003 * 65_535.0).abs() < 5.0, "{r:?}");
        assert!(r.std_counts > 5.0 && r.std_counts < 25.0, "{r:?}");
        assert!(!r.saturated && r.samples >= 95);
    }
}

#[test]
fn saturation_on_the_least_sensitive_range_is_flagged() {
    fn blinding(_: f32, _: f32) -> f32 {
        500.0 * 65_535.0
    }
    let mut bench = Bench::with_scene(blinding);
    bench.home();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    let Ok(Reply::Reading(r)) = bench.ask(Command::TakeReading {
        integration_ms: 100,
        target: Target::Sample,
        range: None,
    }) else {
        panic!("no reading")
    };
    assert_eq!(r.range, 2);
    assert!(r.saturated, "{r:?}");
}

#[test]
fn take_reading_picks_the_range() {
    let mut bench = homed_bench();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    bench
        .ask(Command::MoveTo(Geometry::from_whole_deg(60, 60)))
        .unwrap();
    let Ok(Reply::Reading(r)) = bench.ask(Command::TakeReading {
        integration_ms: 100,
        target: Target::Sample,
        range: None,
    }) else {
        panic!("no reading")
    };
    assert_eq!((r.range, r.saturated), (2, false));
    bench
        .ask(Command::MoveTo(Geometry::from_whole_deg(60, 0)))
        .unwrap();
    let Ok(Reply::Reading(r)) = bench.ask(Command::TakeReading {
        integration_ms: 100,
        target: Target::Sample,
        range: None,
    }) else {
        panic!("no reading")
    };
    assert_eq!((r.range, r.saturated), (0, false));
}

#[test]
fn the_device_state_fits_the_ram_budget() {
    // The board keeps the device in a static (or its task's future): it must leave most of
    // the 24 KiB static RAM budget to USB and the executor. The uploaded schedule
    // (288 × 8 bytes) and the link's frame buffers dominate.
    let size = core::mem::size_of::<firmware::Device<Hw>>() - core::mem::size_of::<Hw>();
    eprintln!("Device state without the hardware: {size} bytes");
    assert!(size <= 4 * 1024, "{size}");
}

#[test]
fn integration_times_outside_the_limits_are_refused_with_the_limit_broken() {
    let config = InstrumentConfig::REFERENCE;
    let (min, max) = (config.min_integration_ms, config.max_integration_ms);
    let mut bench = homed_bench();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    let reading = |integration_ms| Command::TakeReading {
        integration_ms,
        target: Target::Sample,
        range: None,
    };
    let forced = |integration_ms| Command::TakeReading {
        integration_ms,
        target: Target::Sample,
        range: Some(1),
    };
    let dark = |integration_ms| Command::TakeDark { integration_ms };
    let schedule = |integration_ms| {
        Command::RunSchedule(RunSchedule {
            schedule_id: 1,
            source: ScheduleSource::Strategy1,
            integration_ms,
            target: Target::Sample,
        })
    };
    let started = bench.hw().profiles_started;
    for command in [reading, forced, dark, schedule] {
        for too_short in [0, 1, min - 1] {
            assert_eq!(
                bench.ask(command(too_short)),
                err_detail(ErrorCode::InvalidArgument, i32::from(min)),
                "{too_short} ms"
            );
        }
        for too_long in [max + 1, u16::MAX] {
            assert_eq!(
                bench.ask(command(too_long)),
                err_detail(ErrorCode::InvalidArgument, i32::from(max)),
                "{too_long} ms"
            );
        }
    }
    assert_eq!(bench.hw().profiles_started, started, "nothing started");
    // Both limits themselves are accepted; the shortest still gives a mean and a spread.
    let Ok(Reply::Reading(r)) = bench.ask(reading(min)) else {
        panic!("no reading at {min} ms")
    };
    assert!(r.samples >= 5 && r.std_counts > 0.0, "{r:?}");
    let Ok(Reply::Reading(r)) = bench.ask(forced(max)) else {
        panic!("no reading at {max} ms")
    };
    assert_eq!(r.integration_ms, max);
}

/// The same signal everywhere: 60 000 counts on the most sensitive range (92 % of full
/// scale, below saturation), 6 000 on the next, 600 on the least.
fn even_scene(_: f32, _: f32) -> f32 {
    60_000.0
}

fn forced_reading(bench: &mut Bench, range: u8, integration_ms: u16) -> Result<Reply, DeviceError> {
    bench.ask(Command::TakeReading {
        integration_ms,
        target: Target::WhiteReference,
        range: Some(range),
    })
}

#[test]
fn forced_ranges_read_one_scene_at_the_configured_gain_ratio() {
    let config = InstrumentConfig::REFERENCE;
    let mut bench = Bench::with_scene(even_scene);
    bench.home();
    let Ok(Reply::Dark(dark)) = bench.ask(Command::TakeDark {
        integration_ms: 500,
    }) else {
        panic!("no dark")
    };
    bench.ask(Command::SetLamp { on: true }).unwrap();
    // Net signal and its standard error (the reading's and the dark's), per range.
    let mut net = Vec::new();
    let se = |r: &Reading| r.std_counts / (r.samples as f32).sqrt();
    for range in [0u8, 1, 2] {
        let started = bench.now_us;
        let Ok(Reply::Reading(r)) = forced_reading(&mut bench, range, 500) else {
            panic!("no reading on {range}")
        };
        // One integration: the range's settle time and the integration time, nothing more.
        let took_ms = (bench.now_us - started) / 1000;
        let one_ms = u64::from(config.range_settle_ms) + 500;
        assert!(
            (one_ms..=one_ms + 2).contains(&took_ms),
            "range {range}: {took_ms} ms"
        );
        assert_eq!(
            (r.range, r.saturated, r.integration_ms),
            (range, false, 500),
            "{r:?}"
        );
        assert!(r.samples >= 495, "{r:?}");
        let d = &dark[usize::from(range)];
        net.push((r.mean_counts - d.mean_counts, se(&r).hypot(se(d))));
    }
    for range in 1..3 {
        let ((low, low_se), (high, high_se)) = (net[range], net[range - 1]);
        let measured = low / high;
        let configured = config.detector_ranges[range].relative_gain
            / config.detector_ranges[range - 1].relative_gain;
        // Within four standard errors of the ratio (noise only: the model has no other error).
        let tolerance = 4.0 * measured * (low_se / low).hypot(high_se / high);
        assert!(
            tolerance < 0.01 * configured,
            "the test resolves the ratio to 1 %: {tolerance}"
        );
        assert!(
            (measured - configured).abs() < tolerance,
            "range {range}: ratio {measured} ± {tolerance}, configured {configured}"
        );
    }
}

#[test]
fn a_forced_range_is_never_retaken_and_says_when_it_saturates() {
    let mut bench = homed_bench();
    bench.ask(Command::SetLamp { on: true }).unwrap();
    // On the glossy specular peak the most sensitive range saturates (auto-ranging takes
    // range 2 there): forced onto range 0 it stays there, flagged.
    bench
        .ask(Command::MoveTo(Geometry::from_whole_deg(60, 60)))
        .unwrap();
    let started = bench.now_us;
    let Ok(Reply::Reading(r)) = forced_reading(&mut bench, 0, 100) else {
        panic!("no reading")
    };
    assert_eq!((r.range, r.saturated), (0, true), "{r:?}");
    assert!(bench.now_us - started <= 107_000, "re-taken");
    assert_eq!(bench.hw().range(), 0);
    // Off the peak the least sensitive range reads low (auto-ranging would go more
    // sensitive): forced, it stays.
    bench
        .ask(Command::MoveTo(Geometry::from_whole_deg(60, 0)))
        .unwrap();
    let Ok(Reply::Reading(r)) = forced_reading(&mut bench, 2, 100) else {
        panic!("no reading")
    };
    assert_eq!((r.range, r.saturated), (2, false), "{r:?}");
    // Auto-ranging after forced readings starts from its own last range and still works.
    let Ok(Reply::Reading(r)) = bench.ask(Command::TakeReading {
        integration_ms: 100,
        target: Target::Sample,
        range: None,
    }) else {
        panic!("no reading")
    };
    assert_eq!((r.range, r.saturated), (0, false));
    // A range the device does not have: refused, the detail is how many it has.
    for range in [3u8, 4, 255] {
        assert_eq!(
            forced_reading(&mut bench, range, 100),
            err_detail(ErrorCode::InvalidArgument, 3),
            "range {range}"
        );
    }
}
