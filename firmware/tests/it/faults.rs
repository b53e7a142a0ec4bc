//! The firmware's own faults: the fault handlers' stop (outputs first), the record that
//! survives the reset and the reset cause made of it, and the device's fail-safe stop on
//! a late step interrupt and on lost detector samples.

use crate::common;

use common::{Bench, Hw, glossy_scene};
use firmware::config::InstrumentConfig;
use firmware::fault::{
    FaultRecord, MAGIC, ResetFlags, SafeOutputs, make_safe, panic_error, processor_fault_error,
    reset_cause,
};
use firmware::hardware::{Arm, Arms, ResetCause};
use firmware::sampling::SampleLoss;
use firmware::testing::FakeHardware;
use proptest::prelude::*;
use protocol::*;

fn err(code: ErrorCode) -> Result<Reply, DeviceError> {
    Err(DeviceError::new(code))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn a_record_survives_as_the_reset_cause(code in any::<u16>(), detail in any::<i32>(), pin in any::<bool>(), watchdog in any::<bool>()) {
        let error = DeviceError::with_detail(ErrorCode::from(code), detail);
        let record = FaultRecord::new(error);
        prop_assert_eq!(record.error(), Some(error));
        // Whatever flags the reset set (the handler's own reset sets software and pin; a
        // watchdog that fired in a slow handler, the watchdog): the record says why.
        let flags = ResetFlags { power: false, pin, software: true, watchdog };
        prop_assert_eq!(reset_cause(flags, &record), ResetCause::Fault(error));
        // Across a power cycle the record is not this boot's news.
        prop_assert_eq!(reset_cause(ResetFlags { power: true, ..flags }, &record), ResetCause::PowerOn);
    }

    #[test]
    fn random_ram_is_never_a_record(words in any::<[u32; 4]>(), with_magic in any::<bool>()) {
        let mut words = words;
        if with_magic {
            words[0] = MAGIC;
        }
        // Only a check word computed from the rest makes a record (2^-32 by chance).
        let record = FaultRecord(words);
        if let Some(error) = record.error() {
            prop_assert_eq!(FaultRecord::new(error), record);
        }
        let flags = ResetFlags { power: false, pin: true, software: false, watchdog: false };
        if record.error().is_none() {
            prop_assert_eq!(reset_cause(flags, &record), ResetCause::ResetPin);
        }
    }
}

#[test]
fn reset_causes_without_a_record() {
    let none = FaultRecord::CLEARED;
    let flags = |power, pin, software, watchdog| ResetFlags {
        power,
        pin,
        software,
        watchdog,
    };
    assert_eq!(
        reset_cause(flags(true, true, false, false), &none),
        ResetCause::PowerOn
    );
    assert_eq!(
        reset_cause(flags(false, true, false, true), &none),
        ResetCause::Watchdog
    );
    // A debugger's reset request sets software and pin.
    assert_eq!(
        reset_cause(flags(false, true, true, false), &none),
        ResetCause::Software
    );
    assert_eq!(
        reset_cause(flags(false, true, false, false), &none),
        ResetCause::ResetPin
    );
    assert_eq!(none.error(), None);
}

#[test]
fn a_processor_fault_below_the_stack_is_a_stack_overflow() {
    let limit = 0x2000_0000;
    assert_eq!(
        processor_fault_error(limit - 32, limit, 0).code,
        ErrorCode::StackOverflow
    );
    assert_eq!(
        processor_fault_error(limit + 16, limit, 0).code,
        ErrorCode::StackOverflow
    );
    let fault = processor_fault_error(limit + 0x400, limit, 0x0800_1234);
    assert_eq!(
        fault,
        DeviceError::with_detail(ErrorCode::ProcessorFault, 0x0800_1234)
    );
    assert_eq!(
        panic_error(417),
        DeviceError::with_detail(ErrorCode::Panic, 417)
    );
}

#[derive(Default)]
struct Recorder(Vec<&'static str>);

impl SafeOutputs for Recorder {
    fn stop_step_timers(&mut self) {
        self.0.push("timers");
    }
    fn disable_drivers(&mut self) {
        self.0.push("drivers");
    }
    fn lamp_off(&mut self) {
        self.0.push("lamp");
    }
}

#[test]
fn the_safe_stop_ends_the_pulses_first() {
    let mut outputs = Recorder::default();
    make_safe(&mut outputs);
    assert_eq!(outputs.0, ["timers", "drivers", "lamp"]);
}

fn homed_bench() -> Bench {
    let mut bench = Bench::new();
    bench.home();
    bench
}

/// A panic in the middle of a move with the lamp on, the fault handler's stop, the reset,
/// and what the next boot tells the host (the library's side of the board's handler; the
/// on-target tests do it with a real panic under QEMU).
#[test]
fn a_panic_mid_move_stops_everything_and_is_reported_after_the_reset() {
    let mut bench = homed_bench();
    assert_eq!(bench.ask(Command::SetLamp { on: true }), Ok(Reply::Ack));
    bench.send(Command::MoveTo(Geometry::from_whole_deg(10, 70)));
    bench.run_ms(300);
    assert!(bench.hw().is_moving(Arm::Source) || bench.hw().is_moving(Arm::Detector));
    // The handler: outputs first.
    let hardware = bench.device.hardware_mut();
    make_safe(hardware);
    let stopped_at = hardware.true_geometry();
    let record = FaultRecord::new(panic_error(123));
    assert!(!hardware.is_moving(Arm::Source) && !hardware.is_moving(Arm::Detector));
    assert!(
        hardware
            .arms
            .iter()
            .all(|arm| !arm.driver_enabled && !arm.step_timer_running())
    );
    assert!(!hardware.lamp_on());
    // Time passes; nothing moves any more.
    hardware.advance_to(bench.now_us + 2_000_000);
    assert_eq!(hardware.true_geometry(), stopped_at);
    // The reset: the handler's SYSRESETREQ sets the software and pin flags.
    let cause = reset_cause(
        ResetFlags {
            power: false,
            pin: true,
            software: true,
            watchdog: false,
        },
        &record,
    );
    let config = InstrumentConfig::REFERENCE;
    let hardware: Hw = FakeHardware::new(&config, glossy_scene, stopped_at);
    let mut bench = Bench::with_hardware(hardware, cause);
    let info = match bench.ask(Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    }) {
        Ok(Reply::Hello(info)) => info,
        other => panic!("{other:?}"),
    };
    assert_eq!(
        info.reset_cause,
        ResetCause::Fault(DeviceError::with_detail(ErrorCode::Panic, 123))
    );
    let status = bench.status();
    assert_eq!(
        (status.state, status.fault),
        (DeviceState::Stopped, Some(ErrorCode::Panic))
    );
    assert!(!status.homed_i && !status.homed_r && !status.lamp_on);
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(30, 30))),
        err(ErrorCode::NotHomed)
    );
    bench.home();
    let status = bench.status();
    assert_eq!((status.state, status.fault), (DeviceState::Idle, None));
}

#[test]
fn a_late_step_interrupt_stops_the_move_and_costs_the_homing() {
    let mut bench = homed_bench();
    let seq = bench.send(Command::MoveTo(Geometry::from_whole_deg(60, 60)));
    bench.run_ms(150);
    bench.hw_mut().arms[1].step_late = true;
    bench.run_ms(1);
    assert_eq!(bench.stopped_reasons(), [ErrorCode::StepLate]);
    assert_eq!(bench.reply(seq), Some(err(ErrorCode::StepLate)));
    bench.wait_at_rest();
    let status = bench.status();
    assert_eq!(
        (status.state, status.fault),
        (DeviceState::Stopped, Some(ErrorCode::StepLate))
    );
    assert!(!status.homed_i && !status.homed_r);
    // The step count is still near the truth: the next homing is the quick one and
    // reports the error (none here: the model lost no step).
    assert_eq!(
        bench.home(),
        HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(0)
        }
    );
}

#[test]
fn lost_samples_fail_the_reading_and_an_adc_overrun_stops_even_when_idle() {
    let mut bench = homed_bench();
    let seq = bench.send(Command::TakeReading {
        integration_ms: 100,
        target: Target::Sample,
        range: None,
    });
    bench.run_ms(40);
    bench.hw_mut().sample_loss = Some(SampleLoss::RingFull);
    bench.run_ms(1);
    assert_eq!(bench.reply(seq), Some(err(ErrorCode::AdcOverrun)));
    assert_eq!(bench.stopped_reasons(), [ErrorCode::AdcOverrun]);
    // Arms at rest: the homing stays.
    let status = bench.status();
    assert_eq!(
        (status.state, status.fault, status.homed_i),
        (DeviceState::Idle, Some(ErrorCode::AdcOverrun), true)
    );
    // Idle: a full ring is nobody's loss, an overrun of the ADC path is a fault.
    bench.hw_mut().sample_loss = Some(SampleLoss::RingFull);
    bench.run_ms(5);
    assert_eq!(bench.stopped_reasons().len(), 1);
    bench.hw_mut().sample_loss = Some(SampleLoss::DmaLapped);
    bench.run_ms(1);
    assert_eq!(
        bench.stopped_reasons(),
        [ErrorCode::AdcOverrun, ErrorCode::AdcOverrun]
    );
    // A reading after it is fine.
    assert!(matches!(
        bench.ask(Command::TakeReading {
            integration_ms: 50,
            target: Target::Sample,
            range: None
        }),
        Ok(Reply::Reading(_))
    ));
}

#[test]
fn a_stop_in_the_same_instant_as_the_start_stops_the_move() {
    // A move and an abort in one USB packet: the stop comes at zero speed (a stop ramp of
    // no steps), which used to leave the move running to its end.
    let mut bench = homed_bench();
    let start = bench.hw().true_geometry();
    let mut bytes = common::frame(&Request {
        seq: 500,
        command: Command::MoveTo(Geometry::from_whole_deg(10, 70)),
    });
    bytes.extend(common::frame(&Request {
        seq: 501,
        command: Command::Abort,
    }));
    bench.send_bytes(&bytes);
    bench.wait_at_rest();
    assert_eq!(bench.reply(501), Some(Ok(Reply::Ack)));
    assert_eq!(bench.reply(500), Some(err(ErrorCode::Aborted)));
    assert_eq!(
        bench.hw().true_geometry(),
        start,
        "the arms moved after the abort"
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    /// The resets since power-on: a power-on starts from zero, every other reset adds one
    /// to its cause, and RAM that holds no history (random after power-up) counts from
    /// zero instead of being read as counts.
    #[test]
    fn the_reset_history_counts_each_cause_since_power_on(words in any::<[u32; 4]>(), causes in proptest::collection::vec(0u8..5, 0..40)) {
        use firmware::fault::ResetHistory;
        let cause = |k: u8| match k {
            0 => ResetCause::PowerOn,
            1 => ResetCause::Watchdog,
            2 => ResetCause::Fault(DeviceError::new(ErrorCode::Panic)),
            3 => ResetCause::ResetPin,
            _ => ResetCause::Software,
        };
        let random = ResetHistory(words);
        // Random RAM is a history only by chance (2^-32): then it is a valid one.
        let mut history = ResetHistory::after_reset(&random, ResetCause::PowerOn);
        prop_assert_eq!(history.counts(), Some(ResetCounts::default()));
        let mut expected = ResetCounts::default();
        for &k in &causes {
            history = ResetHistory::after_reset(&history, cause(k));
            match k {
                0 => expected = ResetCounts::default(),
                1 => expected.watchdog += 1,
                2 => expected.fault += 1,
                3 => expected.pin += 1,
                _ => expected.software += 1,
            }
            prop_assert_eq!(history.counts(), Some(expected));
        }
        // A first boot after flashing (a software reset, no history yet) counts itself.
        if random.counts().is_none() {
            let first = ResetHistory::after_reset(&random, ResetCause::Software);
            prop_assert_eq!(first.counts(), Some(ResetCounts { software: 1, ..ResetCounts::default() }));
        }
    }
}

#[test]
fn reset_counts_saturate() {
    use firmware::fault::ResetHistory;
    let mut history = ResetHistory::after_reset(&ResetHistory([0; 4]), ResetCause::PowerOn);
    for _ in 0..70_000 {
        history = ResetHistory::after_reset(&history, ResetCause::Watchdog);
    }
    assert_eq!(history.counts().unwrap().watchdog, u16::MAX);
}
