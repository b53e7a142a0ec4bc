//! Scenarios of the whole device on the fake hardware, written without `std` so that the
//! same code runs on the host (`tests/it/scenarios.rs`, `examples/scenarios.rs`) and compiled
//! for the Cortex-M4 under QEMU (`firmware/target-tests`): the handshake, homing, a whole
//! Strategy 1, a sweep across the specular peak with its range switches, and the fail-safe
//! paths. Each returns a digest of every byte the device
//! sent (FNV-1a), so that the two runs can be compared byte for byte.
//!
//! A scenario talks to the device through the real framing, polled every millisecond of
//! virtual time like the board does, with a heartbeat every 500 ms unless it stops them.

use crate::config::InstrumentConfig;
use crate::device::Device;
use crate::fault::{FaultRecord, ResetFlags, make_safe, panic_error, reset_cause};
use crate::hardware::{Arm, Arms, ResetCause};
use crate::sampling::SampleLoss;
use crate::schedule::STRATEGY1_ORDER;
use crate::testing::{FakeHardware, Scene};
use protocol::{
    Command, DeviceError, DeviceInfo, DeviceMessage, DeviceState, ErrorCode, FrameDecoder,
    Geometry, HomeReport, MAX_FRAME_LEN, PROTOCOL_VERSION, Reply, Request, RunSchedule,
    ScheduleDone, ScheduleSource, Status, Sweep, SweepBin, SweepPlan, Target,
};

/// Why a scenario failed: what did not hold, and where (the line in this file).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Failure {
    /// The check.
    pub what: &'static str,
    /// Its line.
    pub line: u32,
}

/// A scenario's outcome: the digest of what the device sent, or the first failed check.
pub type Outcome = Result<u32, Failure>;

/// One scenario.
pub struct Scenario {
    /// Its name.
    pub name: &'static str,
    /// Run it.
    pub run: fn() -> Outcome,
}

macro_rules! ensure {
    ($cond:expr, $what:literal) => {
        if !$cond {
            return Err(Failure {
                what: $what,
                line: line!(),
            });
        }
    };
}

/// Every scenario, in order.
pub const SCENARIOS: &[Scenario] = &[
    Scenario {
        name: "handshake",
        run: handshake,
    },
    Scenario {
        name: "homing",
        run: homing,
    },
    Scenario {
        name: "strategy1",
        run: strategy1,
    },
    Scenario {
        name: "sweep",
        run: sweep,
    },
    Scenario {
        name: "heartbeat_loss",
        run: heartbeat_loss,
    },
    Scenario {
        name: "driver_fault",
        run: driver_fault,
    },
    Scenario {
        name: "late_step",
        run: late_step,
    },
    Scenario {
        name: "adc_overrun",
        run: adc_overrun,
    },
    Scenario {
        name: "watchdog_reset",
        run: watchdog_reset,
    },
    Scenario {
        name: "panic_safe_stop",
        run: panic_safe_stop,
    },
];

/// Signal on the most sensitive range: a mid-scale diffuse sheet with a specular peak.
#[derive(Clone, Copy)]
pub struct SheetScene;

impl Scene for SheetScene {
    fn signal_counts(&self, theta_i_deg: f32, theta_r_deg: f32) -> f32 {
        let half = (theta_i_deg - theta_r_deg) / 2.0;
        let peak = libm::expf(-(half * half) / (2.0 * 0.8 * 0.8));
        // 30 % of full scale diffuse, the peak 60 times that (auto-ranging goes down).
        0.3 * 65_535.0 * (1.0 + 60.0 * peak)
    }
}

/// The fake hardware these scenarios run on.
pub type Hw = FakeHardware<SheetScene>;

/// What the device sent, read as the host would.
struct Received {
    decoder: FrameDecoder,
    digest: u32,
    /// The request waited for, and its answer once it came.
    awaiting: Option<u32>,
    answer: Option<Result<Reply, DeviceError>>,
    stops: heapless::Vec<ErrorCode, 8>,
    streamed: heapless::Vec<(u16, Geometry), 16>,
    done: Option<ScheduleDone>,
    bad_frames: u32,
    sweep: SweepSeen,
}

/// What a sweep's bins showed, as they came (a bin is not kept: 200 of them would double
/// the bench, and the target's stack holds two benches).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct SweepSeen {
    /// Bins received.
    bins: u16,
    /// Every bin had the next index and started where the one before ended (the first at
    /// `first_start`).
    tiled: bool,
    /// Where the first bin started and the last one ended.
    first_start: Option<protocol::Angle>,
    last_end: Option<protocol::Angle>,
    /// Bit r set: a bin on range r with blocks in it.
    ranges: u8,
    /// Bins that lost blocks to a range switch's blanking; bins flagged saturated or empty.
    blanked: u16,
    saturated: u16,
    empty: u16,
    /// The range of the last bin, and how many times it changed from bin to bin.
    last_range: Option<u8>,
    switches: u16,
    /// `SweepDone`'s count.
    done: Option<u16>,
}

impl SweepSeen {
    fn bin(&mut self, bin: &SweepBin) {
        if self.bins == 0 {
            self.tiled = bin.index == 0;
            self.first_start = Some(bin.start);
        } else {
            self.tiled &= bin.index == self.bins && Some(bin.start) == self.last_end;
        }
        self.bins += 1;
        self.last_end = Some(bin.end);
        if bin.flags & SweepBin::EMPTY == 0 {
            self.ranges |= 1 << bin.range;
        }
        self.blanked += u16::from(bin.flags & SweepBin::BLANKED != 0);
        self.saturated += u16::from(bin.flags & SweepBin::SATURATED != 0);
        self.empty += u16::from(bin.flags & SweepBin::EMPTY != 0);
        if self.last_range.is_some_and(|r| r != bin.range) {
            self.switches += 1;
        }
        self.last_range = Some(bin.range);
    }
}

impl Received {
    fn bytes(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            self.digest = (self.digest ^ u32::from(byte)).wrapping_mul(0x0100_0193);
            match self.decoder.push::<DeviceMessage>(byte) {
                None => {}
                Some(Err(_)) => self.bad_frames += 1,
                Some(Ok(message)) => self.message(message),
            }
        }
    }

    fn message(&mut self, message: DeviceMessage) {
        match message {
            DeviceMessage::Reply { seq, result } if Some(seq) == self.awaiting => {
                self.answer = Some(result)
            }
            DeviceMessage::Reply { .. } | DeviceMessage::FrameRejected { .. } => {}
            DeviceMessage::SweepBin(bin) => self.sweep.bin(&bin),
            DeviceMessage::SweepDone { bins, .. } => self.sweep.done = Some(bins),
            DeviceMessage::Reading(reading) => {
                let _ = self.streamed.push((reading.index, reading.geometry));
            }
            DeviceMessage::ScheduleDone(done) => self.done = Some(done),
            DeviceMessage::Stopped { reason } => {
                let _ = self.stops.push(reason);
            }
        }
    }
}

/// The device on fake hardware, talked to like the host does.
pub struct Bench {
    /// The device.
    pub device: Device<Hw>,
    now_us: u64,
    next_seq: u32,
    /// A heartbeat every this many ms while waiting (`None`: silent).
    heartbeat_every_ms: Option<u64>,
    rx: Received,
}

impl Bench {
    /// Arms standing at `at` (unknown to the firmware), out of a reset for `cause`.
    pub fn new(at: Geometry, cause: ResetCause) -> Bench {
        let config = InstrumentConfig::REFERENCE;
        let hardware = FakeHardware::new(&config, SheetScene, at);
        Bench {
            device: Device::new(config, hardware, cause).with_serial_number("SCENARIO"),
            now_us: 0,
            next_seq: 1,
            heartbeat_every_ms: Some(500),
            rx: Received {
                decoder: FrameDecoder::new(),
                digest: 0x811c_9dc5,
                awaiting: None,
                answer: None,
                stops: heapless::Vec::new(),
                streamed: heapless::Vec::new(),
                done: None,
                bad_frames: 0,
                sweep: SweepSeen::default(),
            },
        }
    }

    /// The digest of every byte the device sent so far.
    pub fn digest(&self) -> u32 {
        self.rx.digest
    }

    fn hw(&self) -> &Hw {
        self.device.hardware()
    }

    /// The fake hardware (what a fault handler makes safe).
    pub fn hw_mut(&mut self) -> &mut Hw {
        self.device.hardware_mut()
    }

    /// Virtual time, µs.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    fn send(&mut self, command: Command) -> u32 {
        let seq = self.next_seq;
        self.next_seq += 1;
        let mut buf = [0u8; MAX_FRAME_LEN];
        if let Ok(frame) = protocol::encode_frame(&Request { seq, command }, &mut buf) {
            let rx = &mut self.rx;
            self.device
                .receive(frame, self.now_us, &mut |bytes: &[u8]| rx.bytes(bytes));
        }
        seq
    }

    /// One millisecond of virtual time.
    fn tick(&mut self) {
        self.now_us += 1000;
        if self
            .heartbeat_every_ms
            .is_some_and(|every| self.now_us.is_multiple_of(every * 1000))
        {
            let awaiting = self.rx.awaiting;
            self.send(Command::Heartbeat);
            self.rx.awaiting = awaiting;
        }
        let now = self.now_us;
        self.device.hardware_mut().advance_to(now);
        let rx = &mut self.rx;
        self.device.poll(now, &mut |bytes: &[u8]| rx.bytes(bytes));
    }

    fn run_ms(&mut self, ms: u64) {
        for _ in 0..ms {
            self.tick();
        }
    }

    /// Send `command` and wait (at most a minute of virtual time) for its answer.
    fn ask(&mut self, command: Command) -> Option<Result<Reply, DeviceError>> {
        let seq = self.next_seq;
        self.rx.awaiting = Some(seq);
        self.rx.answer = None;
        self.send(command);
        for _ in 0..60_000 {
            if let Some(answer) = self.rx.answer.take() {
                self.rx.awaiting = None;
                return Some(answer);
            }
            self.tick();
        }
        None
    }

    fn status(&mut self) -> Option<Status> {
        match self.ask(Command::GetStatus) {
            Some(Ok(Reply::Status(status))) => Some(status),
            _ => None,
        }
    }

    fn hello(&mut self) -> Option<DeviceInfo> {
        match self.ask(Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        }) {
            Some(Ok(Reply::Hello(info))) => Some(info),
            _ => None,
        }
    }

    fn home(&mut self) -> Option<HomeReport> {
        match self.ask(Command::Home) {
            Some(Ok(Reply::Homed(report))) => Some(report),
            _ => None,
        }
    }

    fn moving(&self) -> bool {
        Arm::BOTH.iter().any(|&arm| self.hw().is_moving(arm))
    }

    fn wait_at_rest(&mut self) {
        for _ in 0..60_000 {
            if !self.moving() && self.device.is_idle() {
                return;
            }
            self.tick();
        }
    }
}

fn err(code: ErrorCode) -> Option<Result<Reply, DeviceError>> {
    Some(Err(DeviceError::new(code)))
}

/// A homed bench at (30°, 30°) after a power-on.
fn homed() -> Result<Bench, Failure> {
    let mut bench = Bench::new(Geometry::from_whole_deg(30, 30), ResetCause::PowerOn);
    ensure!(bench.hello().is_some(), "hello answered");
    ensure!(
        bench.home()
            == Some(HomeReport {
                step_error_i: None,
                step_error_r: None
            }),
        "first homing"
    );
    Ok(bench)
}

fn handshake() -> Outcome {
    let mut bench = Bench::new(Geometry::from_whole_deg(30, 30), ResetCause::PowerOn);
    ensure!(
        bench.ask(Command::Home)
            == Some(Err(DeviceError::with_detail(
                ErrorCode::VersionMismatch,
                PROTOCOL_VERSION.into()
            ))),
        "nothing before hello"
    );
    ensure!(
        bench.ask(Command::Hello {
            protocol_version: PROTOCOL_VERSION + 1
        }) == Some(Err(DeviceError::with_detail(
            ErrorCode::VersionMismatch,
            PROTOCOL_VERSION.into()
        ))),
        "another version refused with ours"
    );
    let Some(info) = bench.hello() else {
        return Err(Failure {
            what: "hello",
            line: line!(),
        });
    };
    ensure!(
        info.protocol_version == PROTOCOL_VERSION,
        "protocol version"
    );
    ensure!(
        info.firmware_version.as_str() == crate::FIRMWARE_VERSION,
        "firmware version"
    );
    ensure!(
        info.heartbeat_timeout_ms == InstrumentConfig::REFERENCE.heartbeat_timeout_ms,
        "heartbeat timeout announced"
    );
    ensure!(info.reset_cause == ResetCause::PowerOn, "reset cause");
    ensure!(info.serial_number.as_str() == "SCENARIO", "serial number");
    let Some(status) = bench.status() else {
        return Err(Failure {
            what: "status",
            line: line!(),
        });
    };
    ensure!(
        status.state == DeviceState::Idle && !status.homed_i && status.fault.is_none(),
        "idle, not homed"
    );
    ensure!(bench.rx.bad_frames == 0, "every frame readable");
    Ok(bench.digest())
}

fn homing() -> Outcome {
    let mut bench = homed()?;
    let Some(status) = bench.status() else {
        return Err(Failure {
            what: "status",
            line: line!(),
        });
    };
    ensure!(
        status.homed_i && status.homed_r && status.position == bench.hw().true_geometry(),
        "homed where it is"
    );
    ensure!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(45, 45))) == Some(Ok(Reply::Ack)),
        "move"
    );
    ensure!(
        bench.hw().true_geometry() == Geometry::from_whole_deg(45, 45),
        "arrived"
    );
    ensure!(bench.hw().profiles_over_limits == 0, "within the limits");
    // 37 steps lost on the source arm: the quick re-home says so, exactly.
    bench.hw_mut().lose_steps(Arm::Source, 37);
    ensure!(
        bench.home()
            == Some(HomeReport {
                step_error_i: Some(-37),
                step_error_r: Some(0)
            }),
        "step error"
    );
    ensure!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(5, 2)))
            == err(ErrorCode::CollisionGuard),
        "collision guard"
    );
    Ok(bench.digest())
}

fn strategy1() -> Outcome {
    let mut bench = homed()?;
    ensure!(
        bench.ask(Command::SetLamp { on: true }) == Some(Ok(Reply::Ack)),
        "lamp"
    );
    let run = RunSchedule {
        schedule_id: 7,
        source: ScheduleSource::Strategy1,
        integration_ms: 50,
        target: Target::Sample,
    };
    ensure!(
        bench.ask(Command::RunSchedule(run))
            == Some(Ok(Reply::ScheduleStarted {
                schedule_id: 7,
                len: 12
            })),
        "started"
    );
    for _ in 0..120_000 {
        if bench.rx.done.is_some() {
            break;
        }
        bench.tick();
    }
    let Some(done) = bench.rx.done else {
        return Err(Failure {
            what: "schedule done",
            line: line!(),
        });
    };
    ensure!(done.error.is_none() && done.readings == 12, "completed");
    ensure!(bench.rx.streamed.len() == 12, "twelve readings");
    for (k, &(index, geometry)) in bench.rx.streamed.iter().enumerate() {
        ensure!(
            usize::from(index) == k && geometry == STRATEGY1_ORDER[k],
            "in order, where planned"
        );
    }
    ensure!(
        bench.rx.stops.is_empty() && bench.hw().profiles_over_limits == 0,
        "no stop, within limits"
    );
    Ok(bench.digest())
}

/// A sweep of the detector arm across the specular peak at θi = 30° (θr 20° → 40° at
/// 20 °/s, 0.1° bins), auto-ranged: the diffuse part on the most sensitive range, the peak
/// (61 times brighter) on the least, blocks blanked after each switch, the bins tiling the
/// sweep, as many as planned.
fn sweep() -> Outcome {
    let mut bench = homed()?;
    ensure!(
        bench.ask(Command::SetLamp { on: true }) == Some(Ok(Reply::Ack)),
        "lamp"
    );
    let (from, to) = (
        protocol::Angle::from_whole_deg(20),
        protocol::Angle::from_whole_deg(40),
    );
    let sweep = Sweep {
        sweep_id: 9,
        theta_i: protocol::Angle::from_whole_deg(30),
        from,
        to,
        speed_mdeg_per_s: 20_000,
        bin_ticks: 8,
        range: None,
        target: Target::Sample,
    };
    let Some(Ok(Reply::Sweep(SweepPlan { bins, duration_ms }))) = bench.ask(Command::Sweep(sweep))
    else {
        return Err(Failure {
            what: "sweep accepted",
            line: line!(),
        });
    };
    ensure!(bins == 200, "the plan's bins");
    for _ in 0..u64::from(duration_ms) + 1000 {
        if bench.rx.sweep.done.is_some() {
            break;
        }
        bench.tick();
    }
    let seen = bench.rx.sweep;
    ensure!(
        seen.done == Some(bins) && seen.bins == bins,
        "every bin, then SweepDone"
    );
    ensure!(
        seen.tiled && seen.first_start == Some(from) && seen.last_end == Some(to),
        "the bins tile the sweep"
    );
    ensure!(
        seen.ranges == 0b111 && seen.switches >= 4,
        "up to the least sensitive range and back"
    );
    ensure!(
        seen.blanked >= seen.switches && seen.saturated == 0 && seen.empty < 10,
        "switches blanked, nothing saturated"
    );
    ensure!(
        bench.hw().true_geometry() == Geometry::new(sweep.theta_i, to),
        "the arm rests on `to`"
    );
    ensure!(
        bench.rx.stops.is_empty() && bench.hw().profiles_over_limits == 0,
        "no stop, within limits"
    );
    Ok(bench.digest())
}

fn heartbeat_loss() -> Outcome {
    let mut bench = homed()?;
    ensure!(
        bench.ask(Command::SetLamp { on: true }) == Some(Ok(Reply::Ack)),
        "lamp"
    );
    bench.heartbeat_every_ms = None;
    bench.run_ms(u64::from(InstrumentConfig::REFERENCE.heartbeat_timeout_ms) + 100);
    ensure!(
        bench.rx.stops.as_slice() == [ErrorCode::HeartbeatLost],
        "stopped for the heartbeat"
    );
    ensure!(!bench.hw().lamp_on(), "lamp off");
    bench.heartbeat_every_ms = Some(500);
    let Some(status) = bench.status() else {
        return Err(Failure {
            what: "status",
            line: line!(),
        });
    };
    // At rest: the homing stays.
    ensure!(
        status.fault == Some(ErrorCode::HeartbeatLost) && status.homed_i && !status.lamp_on,
        "status"
    );
    Ok(bench.digest())
}

fn driver_fault() -> Outcome {
    let mut bench = homed()?;
    bench.send(Command::MoveTo(Geometry::from_whole_deg(70, 70)));
    bench.run_ms(200);
    // A shorted coil: DIAG again whenever the driver is enabled.
    bench.hw_mut().arms[1].driver_fault = true;
    bench.hw_mut().arms[1].driver_fault_persists = true;
    bench.run_ms(1);
    ensure!(
        bench.rx.stops.as_slice() == [ErrorCode::HardwareFault],
        "stopped for the driver"
    );
    ensure!(
        !bench.hw().arms[1].driver_enabled,
        "the faulted driver is disabled"
    );
    bench.wait_at_rest();
    ensure!(
        bench.ask(Command::Home)
            == Some(Err(DeviceError::with_detail(ErrorCode::HardwareFault, 1))),
        "no homing while the fault persists"
    );
    ensure!(
        !bench.hw().arms[1].driver_enabled,
        "disabled again after the check"
    );
    bench.hw_mut().arms[1].driver_fault_persists = false;
    let Some(status) = bench.status() else {
        return Err(Failure {
            what: "status",
            line: line!(),
        });
    };
    ensure!(
        status.state == DeviceState::Stopped && !status.homed_r,
        "not homed after a fault mid-move"
    );
    // The next Home cycles EN, which clears the latch: it homes.
    ensure!(bench.home().is_some(), "homes again");
    ensure!(bench.hw().arms[1].driver_enabled, "enabled again");
    Ok(bench.digest())
}

fn late_step() -> Outcome {
    let mut bench = homed()?;
    bench.send(Command::MoveTo(Geometry::from_whole_deg(60, 20)));
    bench.run_ms(100);
    bench.hw_mut().arms[0].step_late = true;
    bench.run_ms(1);
    ensure!(
        bench.rx.stops.as_slice() == [ErrorCode::StepLate],
        "stopped for the late step"
    );
    bench.wait_at_rest();
    let Some(status) = bench.status() else {
        return Err(Failure {
            what: "status",
            line: line!(),
        });
    };
    ensure!(
        status.state == DeviceState::Stopped && !status.homed_i && !status.homed_r,
        "homing lost"
    );
    ensure!(status.fault == Some(ErrorCode::StepLate), "the reason");
    ensure!(
        bench.home()
            == Some(HomeReport {
                step_error_i: Some(0),
                step_error_r: Some(0)
            }),
        "quick re-home, exact"
    );
    Ok(bench.digest())
}

fn adc_overrun() -> Outcome {
    let mut bench = homed()?;
    let seq = bench.next_seq;
    bench.rx.awaiting = Some(seq);
    bench.send(Command::TakeReading {
        integration_ms: 100,
        target: Target::Sample,
        range: None,
    });
    bench.run_ms(30);
    bench.hw_mut().sample_loss = Some(SampleLoss::DmaLapped);
    bench.run_ms(1);
    ensure!(
        bench.rx.answer == err(ErrorCode::AdcOverrun),
        "the reading fails"
    );
    ensure!(
        bench.rx.stops.as_slice() == [ErrorCode::AdcOverrun],
        "stopped for the overrun"
    );
    match bench.ask(Command::TakeReading {
        integration_ms: 50,
        target: Target::Sample,
        range: None,
    }) {
        Some(Ok(Reply::Reading(reading))) => ensure!(
            reading.samples > 30 && !reading.saturated,
            "a reading after it"
        ),
        _ => {
            return Err(Failure {
                what: "a reading after it",
                line: line!(),
            });
        }
    }
    Ok(bench.digest())
}

fn watchdog_reset() -> Outcome {
    let mut bench = Bench::new(Geometry::from_whole_deg(50, 20), ResetCause::Watchdog);
    let Some(info) = bench.hello() else {
        return Err(Failure {
            what: "hello",
            line: line!(),
        });
    };
    ensure!(info.reset_cause == ResetCause::Watchdog, "announced");
    let Some(status) = bench.status() else {
        return Err(Failure {
            what: "status",
            line: line!(),
        });
    };
    ensure!(
        status.state == DeviceState::Stopped && status.fault == Some(ErrorCode::WatchdogReset),
        "stopped"
    );
    ensure!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(30, 30))) == err(ErrorCode::NotHomed),
        "not homed"
    );
    ensure!(bench.home().is_some(), "homes");
    Ok(bench.digest())
}

/// A homed bench mid-move with the lamp on: a fault handler's worst moment.
pub fn moving_with_lamp_on() -> Result<Bench, Failure> {
    let mut bench = homed()?;
    ensure!(
        bench.ask(Command::SetLamp { on: true }) == Some(Ok(Reply::Ack)),
        "lamp"
    );
    bench.send(Command::MoveTo(Geometry::from_whole_deg(15, 70)));
    bench.run_ms(250);
    ensure!(
        bench.moving() && bench.hw().lamp_on(),
        "moving at the fault, lamp on"
    );
    Ok(bench)
}

/// What a fault handler does, on the library's side (the target tests also do it with a
/// real panic and a real reset): outputs safe mid-move with the lamp on, the record, and
/// the next boot's report.
fn panic_safe_stop() -> Outcome {
    let mut bench = moving_with_lamp_on()?;
    let later = bench.now_us + 1_000_000;
    let hardware = bench.hw_mut();
    make_safe(hardware);
    let record = FaultRecord::new(panic_error(321));
    ensure!(hardware_is_safe(hardware), "outputs safe");
    let at = hardware.true_geometry();
    hardware.advance_to(later);
    ensure!(bench.hw().true_geometry() == at, "nothing moves after");
    let digest = bench.digest();
    let flags = ResetFlags {
        power: false,
        pin: true,
        software: true,
        watchdog: false,
    };
    report_after_reset(at, reset_cause(flags, &record), panic_error(321)).map(|d| d ^ digest)
}

/// Whether the fake hardware is as a fault handler must leave it: step timers stopped,
/// drivers disabled, lamp off.
pub fn hardware_is_safe(hardware: &Hw) -> bool {
    hardware
        .arms
        .iter()
        .all(|arm| !arm.step_timer_running() && !arm.driver_enabled)
        && !hardware.lamp_on()
}

/// The boot after a fault reset for `cause`, arms at `at`: the handshake and the status say
/// `expected`, the arms are not homed until a homing.
pub fn report_after_reset(at: Geometry, cause: ResetCause, expected: DeviceError) -> Outcome {
    let mut bench = Bench::new(at, cause);
    let Some(info) = bench.hello() else {
        return Err(Failure {
            what: "hello after the reset",
            line: line!(),
        });
    };
    ensure!(
        info.reset_cause == ResetCause::Fault(expected),
        "the reason announced"
    );
    let Some(status) = bench.status() else {
        return Err(Failure {
            what: "status",
            line: line!(),
        });
    };
    ensure!(
        status.state == DeviceState::Stopped && status.fault == Some(expected.code),
        "stopped with the reason"
    );
    ensure!(
        !status.homed_i && !status.homed_r && !status.lamp_on,
        "not homed, lamp off"
    );
    ensure!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(30, 30))) == err(ErrorCode::NotHomed),
        "no motion unhomed"
    );
    ensure!(bench.home().is_some(), "homes");
    let Some(status) = bench.status() else {
        return Err(Failure {
            what: "status",
            line: line!(),
        });
    };
    ensure!(
        status.state == DeviceState::Idle && status.fault.is_none(),
        "fault cleared by homing"
    );
    Ok(bench.digest())
}
