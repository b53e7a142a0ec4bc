//! The device: carries out host commands and keeps the instrument's state.
//!
//! HOW A BOARD DRIVES IT (board and simulator alike):
//! 1. At boot: `Device::new(InstrumentConfig::REFERENCE, hardware, reset_cause)`, then
//!    [`Device::with_serial_number`] with the board's unique ID (the STM32's 96-bit UID in
//!    hex; the simulator's own), announced in the handshake. `hardware` implements
//!    [`crate::hardware::Arms`], [`crate::hardware::Detector`] and
//!    [`crate::hardware::Lamp`] (timer-driven step generators, home switches, driver
//!    fault pins, TIA range pins + ADC samples, lamp pin) and `reset_cause` comes from
//!    RCC_CSR and the board's fault record ([`crate::fault`]): after an IWDG reset
//!    ([`ResetCause::Watchdog`]) or the fail-safe reset of a panic or a processor fault
//!    ([`ResetCause::Fault`]) it is reported as a fault, arms not homed; the handshake
//!    announces it. `new` switches the lamp off.
//! 2. For every chunk of bytes from USB: `device.receive(bytes, now_us, &mut send)`;
//!    `send` gets whole frames to write back, in order.
//! 3. Often, and at least every millisecond while anything runs (homing samples the
//!    switches and readings drain ADC samples here): `device.poll(now_us, &mut send)`.
//!    It advances moves, homing, readings and schedules, streams readings, and makes the
//!    fail-safe stop on heartbeat loss or a driver fault. Feed the IWDG after each poll,
//!    so a hung loop resets the MCU.
//! 4. On USB disconnect or reset: `device.disconnected()` (a partial frame and the reply
//!    cache are dropped; the next host must say hello). After a refused hello,
//!    `device.take_refused_version()` gives the host's version for the log.
//!
//! `now_us` is one monotonic clock (µs since boot) for both calls. Long commands (Home,
//! MoveTo, TakeReading, TakeDark) are answered when done, from `poll`; a schedule answers
//! at once and then streams.
//!
//! THE LINK ([`crate::link`]): each sequence number is carried out once (a retry is
//! answered from the reply cache). `Hello` always starts a fresh link: it is carried out
//! whatever its number, and it empties the cache and forgets the request in progress (so a
//! new host process may start again at 1); what runs goes on, and its reply is sent but
//! not cached. A frame with a good CRC and a readable `seq` that holds no command of this
//! version is answered `NotSupported` under that `seq`.
//!
//! SAFETY: one fail-safe stop path ([`Device::fail_safe_stop`]), taken on heartbeat loss
//! (no frame for `heartbeat_timeout_ms` while an arm moves, the lamp is on, or a homing or
//! schedule runs), on a driver fault, on a dead detector, when the arms come to rest off
//! their target, on a step interrupt that ran too late ([`ErrorCode::StepLate`]: the arms
//! always lose their homing) and on lost detector samples ([`ErrorCode::AdcOverrun`]: an
//! overrun of the ADC path is seen at the poll after it, reading or not; a reading with a
//! gap fails). The board's panic
//! and processor-fault handlers have their own stop, outputs first, then a reset
//! ([`crate::fault`]). It ramps both arms down, switches the lamp off, ends whatever runs (a
//! pending command is answered with the reason, a schedule ends with it), records the
//! reason in `Status::fault` and sends `Stopped`. The homing survives it only when it
//! cannot have been spoiled, and the decision is made there, from the state at the moment
//! of the stop:
//! - both arms at rest (no profile running, no move left unfinished) and no driver fault:
//!   the arms keep their homing and the device is `Idle`; motion commands are accepted
//!   without a new `Home`. A still arm loses no steps, and the session (an operator at a
//!   prompt, a pulled cable while the arms are parked) need not start over;
//! - an arm moving, a homing under way, a move that ended off target, or a driver fault
//!   (a de-energised motor may have moved): the arms count as not homed and the device is
//!   `Stopped` until the next `Home`, which reports the step error. A ramped stop loses no
//!   counted steps either, but mid-move the board cannot prove it (a step generator late, a
//!   stall), so it is conservative there.
//!
//! A driver fault takes the stop once, when it begins, and the faulted arm's driver is
//! disabled at once (its steps end; the other arm ramps down). While a driver reports a
//! fault, moves, sweeps and schedules are refused (`HardwareFault`, detail: the arm). The
//! next `Home` clears it: a driver disabled by the stop or reporting a fault is disabled for
//! [`DRIVER_RESET_US`], enabled, and its DIAG read again (a TMC2209 latches DIAG until EN
//! goes high); a fault still there refuses the `Home` (`HardwareFault`, detail: the arm) and
//! the driver is disabled again.
//!
//! `Abort` is the host's stop, not a fail-safe one: it ends everything the same way but
//! keeps the lamp and the homing, mid-move too (the host asked for it, on a healthy board,
//! and a ramped stop loses no steps). `TakeDark` leaves the lamp off.
//!
//! HOMING: the first `Home` after reset searches for both switches
//! ([`crate::homing::ArmHoming::new`]). Later ones, on arms whose step count still says
//! where they are (homed since reset, no driver fault since), are quick
//! ([`crate::homing::ArmHoming::quick`]: full speed to 1.5° short of where the count puts
//! the switch, then the slow approach): 1.4–2.8 s from the measuring positions instead of
//! 2.8–5.8 s (table in [`crate::homing`]), so a session can re-home at its end to check
//! for lost steps. The step error is exact either way.

use crate::config::InstrumentConfig;
use crate::detector::{Integration, RangedReading, ReadingProgress, is_saturated};
use crate::hardware::{Arm, Hardware, ResetCause};
use crate::homing::{ArmHoming, HomingStatus};
use crate::link::{Incoming, Link};
use crate::motion::{ArmMotion, angle_to_steps, deg_to_steps, plan_move, steps_to_angle};
use crate::schedule::{STRATEGY1_ORDER, UploadedSchedule};
use crate::selftest::SelfTestRun;
use crate::sweep::{AutoRange, Binner, check_sweep, sweep_profile};
use crate::switches::{HomeSwitch, SwitchState};
use protocol::{
    Command, DeviceError, DeviceInfo, DeviceMessage, DeviceState, ErrorCode, Geometry, HomeReport,
    MAX_RANGES, PROTOCOL_VERSION, Reading, Reply, RunSchedule, ScheduleDone, ScheduleSource,
    Status, StreamReading, Sweep, SweepPlan, Target,
};

/// How long a `Home` keeps a faulted driver disabled to clear its fault, µs. A TMC2209
/// latches DIAG (a short, an over-temperature shutdown) until EN goes high; its datasheet
/// names no minimum EN-high time (the flags reset while the driver is disabled, and its
/// inputs are sampled at its 12 MHz clock, so microseconds would do). 10 ms is generous and
/// lets the coil currents decay (L/R of a few ms) before the bridge switches on again; it
/// is nothing next to a homing. Unverified on hardware.
pub const DRIVER_RESET_US: u64 = 10_000;

/// How long after a driver is enabled again its DIAG is read, µs: a short is seen once the
/// bridge drives the coils (within a few chopper cycles, tens of µs); an over-temperature at
/// once. Two polls at 1 kHz, so the reading is one taken after the driver was enabled.
pub const DRIVER_RECHECK_US: u64 = 2_000;

/// A sweep whose detector gives no block for this long has a dead detector: fail-safe stop
/// ([`ErrorCode::HardwareFault`]); without blocks its last bin would never close.
const SWEEP_SILENT_BLOCKS: u64 = 20;

/// A move under way: where to, whether the arms actually move, and the settle deadline
/// once they are there.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Travel {
    target: [i32; 2],
    moved: bool,
    settle_until_us: Option<u64>,
}

/// One step of a running schedule.
#[derive(Clone, Copy, Debug, PartialEq)]
enum RunStep {
    Travel(Travel),
    Measure(RangedReading),
}

/// A running schedule.
#[derive(Clone, Copy, Debug, PartialEq)]
struct ScheduleRun {
    schedule_id: u16,
    source: ScheduleSource,
    len: u16,
    /// Readings streamed so far; also the index of the geometry being visited.
    index: u16,
    integration_ms: u16,
    target: Target,
    started_us: u64,
    step: RunStep,
}

/// Where a running sweep is.
#[derive(Clone, Copy, Debug, PartialEq)]
enum SweepPhase {
    /// Both arms to (θi, `from`) and settling there (always, also without a move: the
    /// range is found at rest), then until the auto-ranging has found the range.
    Approach(Travel),
    /// The detector arm's profile runs; its blocks make the bins.
    Sweeping(Binner),
}

/// A running sweep ([`crate::sweep`]).
#[derive(Clone, Copy, Debug, PartialEq)]
struct SweepRun {
    sweep: Sweep,
    bins: u16,
    ranging: AutoRange,
    phase: SweepPhase,
    /// When the detector last gave a block.
    last_block_us: u64,
}

/// A `Home`'s clearing of driver faults: EN cycled on the arms marked in `arms`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct DriverReset {
    arms: [bool; 2],
    /// Disabled until then (`enabled` false), or enabled and read again then.
    until_us: u64,
    enabled: bool,
}

/// What the device is doing. Long commands keep the sequence number they answer.
#[derive(Clone, Debug, PartialEq)]
enum Activity {
    Idle,
    Homing {
        seq: u32,
        arms: [ArmHoming; 2],
        trips: [Option<i32>; 2],
        /// Driver faults being cleared before the arms move.
        reset: Option<DriverReset>,
    },
    Moving {
        seq: u32,
        travel: Travel,
    },
    Reading {
        seq: u32,
        reading: RangedReading,
    },
    Dark {
        seq: u32,
        integration: Integration,
        readings: heapless::Vec<Reading, MAX_RANGES>,
    },
    Schedule(ScheduleRun),
    Sweep(SweepRun),
    /// The self-test's pulse checks ([`crate::selftest`]).
    SelfTest {
        seq: u32,
        run: SelfTestRun,
    },
    /// Arms ramping down after an abort or a fault; nothing new starts until they rest.
    Stopping,
}

/// The firmware's state machine, over the board's hardware `H`.
pub struct Device<H: Hardware> {
    config: InstrumentConfig,
    link: Link,
    hardware: H,
    /// Set by a `Hello` with our protocol version; until then only `Hello` is served.
    handshake_done: bool,
    /// Protocol version of the last refused `Hello`, for the board's log.
    refused_version: Option<u16>,
    now_us: u64,
    /// When the host was last heard (any frame).
    last_heard_us: u64,
    lamp_on: bool,
    homed: [bool; 2],
    /// Homed at least once since reset: the step count still means something after a
    /// fault, so re-homing can report the step error.
    homed_since_reset: [bool; 2],
    /// The step count still bounds where the arm is (homed since reset and no driver
    /// fault since): the next `Home` may be the quick one.
    count_trusted: [bool; 2],
    /// A driver reported a fault at the last poll (the stop was taken when it began).
    driver_fault_seen: bool,
    /// The arm's driver was disabled by a fault stop; the next `Home` enables it again.
    driver_off: [bool; 2],
    /// The home switches, debounced at every poll.
    switches: [HomeSwitch; 2],
    /// The last fault, until cleared by homing.
    fault: Option<ErrorCode>,
    /// In the safe state after a fault that cost the homing (or a watchdog reset) until
    /// homed.
    safe_stopped: bool,
    motion: ArmMotion,
    activity: Activity,
    uploaded: UploadedSchedule,
    /// Range of the last reading: where auto-ranging starts next.
    last_range: u8,
    /// Announced in the handshake; see [`Device::with_serial_number`].
    serial_number: heapless::String<24>,
    /// Why the MCU last came out of reset, announced in the handshake.
    reset_cause: ResetCause,
}

type Answer = Option<Result<Reply, DeviceError>>;

impl<H: Hardware> Device<H> {
    /// A device just out of reset, driving `hardware`.
    pub fn new(config: InstrumentConfig, mut hardware: H, reset_cause: ResetCause) -> Device<H> {
        hardware.set_lamp(false);
        // After a watchdog reset or a fault of the firmware's own, the arms may have moved
        // while nobody counted: not homed, and the reason stands until the next homing.
        let fault = reset_cause.fault();
        Device {
            config,
            link: Link::new(),
            hardware,
            handshake_done: false,
            refused_version: None,
            now_us: 0,
            last_heard_us: 0,
            lamp_on: false,
            homed: [false; 2],
            homed_since_reset: [false; 2],
            count_trusted: [false; 2],
            driver_fault_seen: false,
            driver_off: [false; 2],
            switches: [HomeSwitch::new(); 2],
            fault,
            safe_stopped: fault.is_some(),
            motion: ArmMotion::new(),
            activity: Activity::Idle,
            uploaded: UploadedSchedule::new(),
            last_range: 0,
            serial_number: heapless::String::new(),
            reset_cause,
        }
    }

    /// The instrument's unique serial number for the handshake (the board: the MCU's
    /// unique ID; the simulator: one of its own). Text beyond 24 characters is cut.
    pub fn with_serial_number(mut self, serial_number: &str) -> Device<H> {
        self.serial_number.clear();
        for c in serial_number.chars() {
            if self.serial_number.push(c).is_err() {
                break;
            }
        }
        self
    }

    /// The instrument's configuration.
    pub fn config(&self) -> &InstrumentConfig {
        &self.config
    }

    /// The hardware (for the simulator and tests).
    pub fn hardware(&self) -> &H {
        &self.hardware
    }

    /// The hardware, mutable (for the simulator and tests: advancing virtual time).
    pub fn hardware_mut(&mut self) -> &mut H {
        &mut self.hardware
    }

    /// Whether a host with our protocol version has said hello.
    pub fn handshake_done(&self) -> bool {
        self.handshake_done
    }

    /// Device time of the last frame from the host, read or not: the heartbeat timeout
    /// runs from it.
    pub fn last_heard_us(&self) -> u64 {
        self.last_heard_us
    }

    /// Whether nothing runs (no command in progress, arms at rest).
    pub fn is_idle(&self) -> bool {
        self.activity == Activity::Idle
    }

    /// Take (and clear) the version of a host refused since the last call, for logging.
    pub fn take_refused_version(&mut self) -> Option<u16> {
        self.refused_version.take()
    }

    /// The host went away (USB reset, cable pulled): partial frames and the reply cache
    /// are dropped and a new session must say hello again. Whatever runs goes on until the
    /// heartbeat times out.
    pub fn disconnected(&mut self) {
        self.link.reset();
        self.handshake_done = false;
    }

    /// Feed bytes received from the host at device time `now_us`; frames to send back go
    /// to `send`, in order.
    pub fn receive(&mut self, bytes: &[u8], now_us: u64, send: &mut impl FnMut(&[u8])) {
        self.now_us = now_us;
        for &byte in bytes {
            let Some(incoming) = self.link.push(byte, send) else {
                continue;
            };
            // Any frame, even one we could not read, shows the host is alive.
            self.last_heard_us = now_us;
            if let Incoming::Fresh(request) = incoming {
                // A Hello's repeat is carried out again (it changes nothing twice), so its
                // reply must not take the cache from the new session's first command.
                let uncached = request.command.is_read_only()
                    || matches!(request.command, Command::Hello { .. });
                match self.execute(request.seq, &request.command, send) {
                    Some(result) if uncached => self.link.reply_uncached(request.seq, result, send),
                    Some(result) => self.link.reply(request.seq, result, send),
                    None => self.link.begin(request.seq),
                }
            }
        }
    }

    /// Advance whatever runs to device time `now_us`; messages go to `send`.
    pub fn poll(&mut self, now_us: u64, send: &mut impl FnMut(&[u8])) {
        self.now_us = now_us;
        // Once per occurrence: while the fault persists, motion is refused instead. A
        // `Home` clearing a fault reads DIAG itself, and answers with what it finds.
        let driver_fault = Arm::BOTH.iter().any(|&arm| self.hardware.driver_fault(arm));
        // Nor the self-test, which runs with the drivers off and reports what DIAG reads.
        let clearing = matches!(
            self.activity,
            Activity::Homing { reset: Some(_), .. } | Activity::SelfTest { .. }
        );
        if driver_fault && !self.driver_fault_seen && !clearing {
            self.fail_safe_stop(ErrorCode::HardwareFault, send);
        }
        self.driver_fault_seen = driver_fault;
        // A step interrupt too late: a step may have gone uncounted (the timer stopped).
        if Arm::BOTH
            .iter()
            .any(|&arm| self.hardware.take_step_fault(arm))
        {
            self.fail_safe_stop(ErrorCode::StepLate, send);
        }
        // The ADC path overran: seen when it happens, reading or not.
        if self.hardware.take_sample_fault().is_some() {
            self.fail_safe_stop(ErrorCode::AdcOverrun, send);
        }
        self.watch_switches(send);
        let needs_host = self.lamp_on
            || matches!(
                self.activity,
                Activity::Homing { .. }
                    | Activity::Moving { .. }
                    | Activity::Schedule(_)
                    | Activity::Sweep(_)
            );
        let silent_us = now_us.saturating_sub(self.last_heard_us);
        if needs_host && silent_us > u64::from(self.config.heartbeat_timeout_ms) * 1000 {
            self.fail_safe_stop(ErrorCode::HeartbeatLost, send);
        }
        match core::mem::replace(&mut self.activity, Activity::Idle) {
            Activity::Idle => {}
            Activity::Homing {
                seq,
                arms,
                trips,
                reset,
            } => self.poll_homing(seq, arms, trips, reset, send),
            Activity::Moving { seq, travel } => match self.advance_travel(travel) {
                Ok(Some(travel)) => self.activity = Activity::Moving { seq, travel },
                Ok(None) => self.link.finish(seq, Ok(Reply::Ack), send),
                Err(code) => {
                    self.activity = Activity::Moving { seq, travel };
                    self.fail_safe_stop(code, send);
                }
            },
            Activity::Reading { seq, mut reading } => {
                match reading.poll(&mut self.hardware, &self.config, now_us) {
                    ReadingProgress::Running => self.activity = Activity::Reading { seq, reading },
                    ReadingProgress::Done(done) => {
                        // A forced range says nothing about where auto-ranging should start.
                        if !reading.is_forced() {
                            self.last_range = done.range;
                        }
                        self.link.finish(seq, Ok(Reply::Reading(done)), send);
                    }
                    ReadingProgress::NoSamples => {
                        self.activity = Activity::Reading { seq, reading };
                        self.fail_safe_stop(ErrorCode::HardwareFault, send);
                    }
                    ReadingProgress::SamplesLost(_) => {
                        self.activity = Activity::Reading { seq, reading };
                        self.fail_safe_stop(ErrorCode::AdcOverrun, send);
                    }
                }
            }
            Activity::Dark {
                seq,
                mut integration,
                mut readings,
            } => match integration.poll(&mut self.hardware, now_us) {
                Err(_) => {
                    self.activity = Activity::Dark {
                        seq,
                        integration,
                        readings,
                    };
                    self.fail_safe_stop(ErrorCode::AdcOverrun, send);
                }
                Ok(None) => {
                    self.activity = Activity::Dark {
                        seq,
                        integration,
                        readings,
                    }
                }
                Ok(Some(stats)) if stats.count() == 0 => {
                    self.activity = Activity::Dark {
                        seq,
                        integration,
                        readings,
                    };
                    self.fail_safe_stop(ErrorCode::HardwareFault, send);
                }
                Ok(Some(stats)) => {
                    let saturated = is_saturated(&self.config, integration.range(), stats.max());
                    let _ = readings.push(integration.reading(&stats, saturated));
                    let next = integration.range() + 1;
                    if usize::from(next) < self.config.detector_ranges.len().min(MAX_RANGES) {
                        let ms = readings[0].integration_ms;
                        let integration =
                            Integration::start(&mut self.hardware, &self.config, next, ms, now_us);
                        self.activity = Activity::Dark {
                            seq,
                            integration,
                            readings,
                        };
                    } else {
                        self.link.finish(seq, Ok(Reply::Dark(readings)), send);
                    }
                }
            },
            Activity::Schedule(run) => self.poll_schedule(run, send),
            Activity::Sweep(run) => self.poll_sweep(run, send),
            Activity::SelfTest { seq, mut run } => {
                match run.poll(&mut self.hardware, &self.config, now_us) {
                    Some(report) => self.link.finish(seq, Ok(Reply::SelfTest(report)), send),
                    None => self.activity = Activity::SelfTest { seq, run },
                }
            }
            Activity::Stopping => {
                if self.motion.any_moving(&self.hardware) {
                    self.activity = Activity::Stopping;
                }
            }
        }
    }

    /// Sample both home switches (debounced, [`crate::switches`]) and stop on a press
    /// outside homing: the arm is at or past its switch, beyond the working range, where
    /// its step count says it is not (steps lost or gained, a switch or its wire at fault).
    /// A fail-safe stop that costs the homing, whatever the arms did (`HardwareFault`: no
    /// code of its own, to keep the wire's error codes as they are). Only a press counts,
    /// not a switch found pressed: an arm rests on its switch after homing, and may stand
    /// on it at power-on. Not while the arms are not homed either: no move can run then,
    /// a ramp under way is an earlier stop's (whose reason stands), and the homing the stop
    /// would cost is lost already.
    fn watch_switches(&mut self, send: &mut impl FnMut(&[u8])) {
        let mut pressed = false;
        for arm in Arm::BOTH {
            let raw = self.hardware.home_switch_pressed(arm);
            let steps = self.hardware.position_steps(arm);
            pressed |= self.switches[arm.index()].sample(raw, steps) == Some(true);
        }
        let expected = matches!(self.activity, Activity::Homing { .. }) || self.homed == [false; 2];
        if pressed && !expected {
            self.stop_losing_homing(ErrorCode::HardwareFault, send);
        }
    }

    /// The debounced state of the arm's home switch; before the first is made (the first
    /// few polls after boot), released at the arm's count now.
    fn switch_state(&self, arm: Arm) -> SwitchState {
        self.switches[arm.index()].state().unwrap_or(SwitchState {
            pressed: false,
            since_steps: self.hardware.position_steps(arm),
        })
    }

    /// The fail-safe stop, the one path every fault takes: ramp both arms down, lamp off,
    /// end whatever runs (a pending command is answered with `reason`, a schedule ends with
    /// it), record the fault, tell the host (`Stopped`). Whether the homing survives is
    /// decided here, from the state before the ramps start: it does when both arms are at
    /// rest with no move left unfinished and no driver reports a fault (the device is
    /// then `Idle`); otherwise the arms count as not homed until the next `Home` (the
    /// device is `Stopped`). See the module doc.
    pub fn fail_safe_stop(&mut self, reason: ErrorCode, send: &mut impl FnMut(&[u8])) {
        // A late step interrupt may have cost a step whatever the arms do now.
        self.fail_safe_stop_with(reason, reason == ErrorCode::StepLate, send);
    }

    /// The fail-safe stop after which the arms count as not homed, whatever they did.
    fn stop_losing_homing(&mut self, reason: ErrorCode, send: &mut impl FnMut(&[u8])) {
        self.fail_safe_stop_with(reason, true, send);
    }

    fn fail_safe_stop_with(
        &mut self,
        reason: ErrorCode,
        loses_homing: bool,
        send: &mut impl FnMut(&[u8]),
    ) {
        let driver_fault = Arm::BOTH.map(|arm| self.hardware.driver_fault(arm));
        let keeps_homing = !loses_homing && !self.mid_move() && !driver_fault.contains(&true);
        for arm in Arm::BOTH {
            // A faulted driver is disabled at once, its arm's steps ended: its motion is
            // lost anyway, a shorted bridge must not stay on through the ramp, and a TMC2209
            // clears DIAG only while disabled. The other arm ramps down (in `halt`).
            if driver_fault[arm.index()] {
                self.motion.stop_dead(&mut self.hardware, arm, self.now_us);
                self.hardware.set_driver_enabled(arm, false);
                self.driver_off[arm.index()] = true;
            }
        }
        self.halt(reason, send);
        self.hardware.set_lamp(false);
        self.lamp_on = false;
        self.fault = Some(reason);
        if !keeps_homing {
            self.homed = [false; 2];
            self.safe_stopped = true;
        }
        for arm in Arm::BOTH {
            // A de-energised motor may have moved anywhere: the next Home searches.
            if driver_fault[arm.index()] {
                self.count_trusted[arm.index()] = false;
            }
        }
        self.link.send(&DeviceMessage::Stopped { reason }, send);
    }

    /// Whether the arms are under way: a profile running, a homing (whose moves follow
    /// each other), a stop ramp, or a move whose arms came to rest short of its target.
    fn mid_move(&self) -> bool {
        if self.motion.any_moving(&self.hardware) {
            return true;
        }
        match &self.activity {
            Activity::Homing { .. } | Activity::Stopping | Activity::SelfTest { .. } => true,
            Activity::Moving { travel, .. } => self.positions() != travel.target,
            Activity::Schedule(ScheduleRun {
                step: RunStep::Travel(travel),
                ..
            }) => self.positions() != travel.target,
            Activity::Sweep(SweepRun {
                phase: SweepPhase::Approach(travel),
                ..
            }) => self.positions() != travel.target,
            Activity::Sweep(SweepRun { sweep, .. }) => {
                self.positions() != [angle_to_steps(sweep.theta_i), angle_to_steps(sweep.to)]
            }
            Activity::Idle
            | Activity::Reading { .. }
            | Activity::Dark { .. }
            | Activity::Schedule(_) => false,
        }
    }

    /// End whatever runs with `reason`: arms ramp down, a pending command is answered, a
    /// schedule ends.
    fn halt(&mut self, reason: ErrorCode, send: &mut impl FnMut(&[u8])) {
        let max_speed = deg_to_steps(self.config.max_speed_deg_per_s);
        let accel = deg_to_steps(self.config.accel_deg_per_s2);
        // Together, on the line they move along: the collision guard holds at rest.
        self.motion
            .stop_both(&mut self.hardware, max_speed, accel, self.now_us);
        match core::mem::replace(&mut self.activity, Activity::Idle) {
            Activity::Homing { seq, .. }
            | Activity::Moving { seq, .. }
            | Activity::Reading { seq, .. }
            | Activity::Dark { seq, .. } => {
                self.link.finish(seq, Err(DeviceError::new(reason)), send)
            }
            Activity::SelfTest { seq, run } => {
                run.cancel(&mut self.hardware);
                self.link.finish(seq, Err(DeviceError::new(reason)), send)
            }
            Activity::Schedule(run) => {
                let done = ScheduleDone {
                    schedule_id: run.schedule_id,
                    readings: run.index,
                    device_us: self.now_us.saturating_sub(run.started_us),
                    error: Some(reason),
                };
                self.link.send(&DeviceMessage::ScheduleDone(done), send);
            }
            // Answered when it started; the host has every bin sent, each named.
            Activity::Sweep(_) | Activity::Idle | Activity::Stopping => {}
        }
        if self.motion.any_moving(&self.hardware) {
            self.activity = Activity::Stopping;
        }
    }

    fn execute(&mut self, seq: u32, command: &Command, send: &mut impl FnMut(&[u8])) -> Answer {
        if let Command::Hello { protocol_version } = *command {
            // A fresh link, whoever says it: the reply cache and the request in progress
            // belong to the host before.
            self.link.new_session();
            return Some(if protocol_version == PROTOCOL_VERSION {
                self.handshake_done = true;
                Ok(Reply::Hello(DeviceInfo {
                    reset_cause: self.reset_cause,
                    ..self.config.device_info(&self.serial_number)
                }))
            } else {
                self.handshake_done = false;
                self.refused_version = Some(protocol_version);
                Err(DeviceError::with_detail(
                    ErrorCode::VersionMismatch,
                    i32::from(PROTOCOL_VERSION),
                ))
            });
        }
        if !self.handshake_done {
            return Some(Err(DeviceError::with_detail(
                ErrorCode::VersionMismatch,
                i32::from(PROTOCOL_VERSION),
            )));
        }
        let result = match command {
            Command::Hello { .. } | Command::Heartbeat => Ok(Reply::Ack),
            Command::GetStatus => Ok(Reply::Status(self.status())),
            Command::Abort => {
                self.halt(ErrorCode::Aborted, send);
                Ok(Reply::Ack)
            }
            Command::SetLamp { on } => self.set_lamp(*on),
            Command::Home => return self.start_homing(seq),
            Command::MoveTo(geometry) => return self.start_move_to(seq, *geometry),
            Command::TakeReading {
                integration_ms,
                target: _,
                range,
            } => {
                return self.start_reading(seq, *integration_ms, *range);
            }
            Command::TakeDark { integration_ms } => return self.start_dark(seq, *integration_ms),
            Command::UploadSchedule(chunk) => self.upload(chunk),
            Command::RunSchedule(run) => self.start_schedule(run),
            Command::Sweep(sweep) => self.start_sweep(sweep),
            Command::SelfTest => return self.start_self_test(seq),
        };
        Some(result)
    }

    /// Start the self-test ([`crate::selftest`]): refused while anything runs. The arms
    /// lose their homing at once (their drivers go off), and the next `Home` searches.
    fn start_self_test(&mut self, seq: u32) -> Answer {
        if let Err(error) = self.busy() {
            return Some(Err(error));
        }
        if self.motion.any_moving(&self.hardware) {
            return Some(Err(DeviceError::new(ErrorCode::Busy)));
        }
        self.lamp_on = false;
        self.homed = [false; 2];
        self.count_trusted = [false; 2];
        let run = SelfTestRun::start(&mut self.hardware, &self.config, self.now_us);
        self.activity = Activity::SelfTest { seq, run };
        None
    }

    fn busy(&self) -> Result<(), DeviceError> {
        if self.activity == Activity::Idle {
            Ok(())
        } else {
            Err(DeviceError::new(ErrorCode::Busy))
        }
    }

    /// Refuse motion while a driver reports a fault (detail: the arm).
    fn require_drivers(&self) -> Result<(), DeviceError> {
        match Arm::BOTH
            .into_iter()
            .find(|&arm| self.hardware.driver_fault(arm))
        {
            Some(arm) => Err(DeviceError::with_detail(
                ErrorCode::HardwareFault,
                arm.index() as i32,
            )),
            None => Ok(()),
        }
    }

    fn require_homed(&self) -> Result<(), DeviceError> {
        if self.homed == [true, true] {
            Ok(())
        } else {
            Err(DeviceError::new(ErrorCode::NotHomed))
        }
    }

    /// Refuse an integration time outside `min_integration_ms ..= max_integration_ms`;
    /// the detail is the limit it broke.
    fn check_integration(&self, integration_ms: u16) -> Result<(), DeviceError> {
        let (min, max) = (
            self.config.min_integration_ms,
            self.config.max_integration_ms,
        );
        if integration_ms < min.max(1) {
            Err(DeviceError::with_detail(
                ErrorCode::InvalidArgument,
                i32::from(min),
            ))
        } else if integration_ms > max {
            Err(DeviceError::with_detail(
                ErrorCode::InvalidArgument,
                i32::from(max),
            ))
        } else {
            Ok(())
        }
    }

    /// The number of detector ranges a forced range must stay below.
    fn range_count(&self) -> usize {
        self.config.detector_ranges.len().min(MAX_RANGES)
    }

    fn set_lamp(&mut self, on: bool) -> Result<Reply, DeviceError> {
        let measuring = matches!(
            self.activity,
            Activity::Reading { .. }
                | Activity::Dark { .. }
                | Activity::Schedule(_)
                | Activity::Sweep(_)
        );
        // Off is always allowed (safety); on would spoil a reading under way.
        if on && measuring {
            return Err(DeviceError::new(ErrorCode::Busy));
        }
        self.hardware.set_lamp(on);
        self.lamp_on = on;
        Ok(Reply::Ack)
    }

    /// Start a `Home`. A driver disabled by a fault stop, or one reporting a fault now, is
    /// first cycled (disabled for [`DRIVER_RESET_US`], enabled, DIAG read again
    /// [`DRIVER_RECHECK_US`] later): a fault that went away is cleared so, one still there
    /// refuses the `Home` (`HardwareFault`, detail: the arm). Without this a TMC2209's latched
    /// DIAG refused all motion until a power cycle.
    fn start_homing(&mut self, seq: u32) -> Answer {
        if let Err(error) = self.busy() {
            return Some(Err(error));
        }
        self.homed = [false; 2];
        let cycle =
            Arm::BOTH.map(|arm| self.driver_off[arm.index()] || self.hardware.driver_fault(arm));
        for arm in Arm::BOTH {
            if cycle[arm.index()] {
                self.hardware.set_driver_enabled(arm, false);
                // A de-energised motor may have moved: the homing searches.
                self.count_trusted[arm.index()] = false;
            }
        }
        let reset = cycle.contains(&true).then_some(DriverReset {
            arms: cycle,
            until_us: self.now_us + DRIVER_RESET_US,
            enabled: false,
        });
        let arms = Arm::BOTH.map(|arm| {
            if self.count_trusted[arm.index()] {
                ArmHoming::quick(arm)
            } else {
                ArmHoming::new(arm)
            }
        });
        self.activity = Activity::Homing {
            seq,
            arms,
            trips: [None; 2],
            reset,
        };
        None
    }

    fn poll_homing(
        &mut self,
        seq: u32,
        mut arms: [ArmHoming; 2],
        mut trips: [Option<i32>; 2],
        reset: Option<DriverReset>,
        send: &mut impl FnMut(&[u8]),
    ) {
        if let Some(mut reset) = reset {
            if self.now_us >= reset.until_us && !reset.enabled {
                // Off long enough: on again, and DIAG read once it has settled.
                for arm in Arm::BOTH {
                    if reset.arms[arm.index()] {
                        self.hardware.set_driver_enabled(arm, true);
                    }
                }
                reset.enabled = true;
                reset.until_us = self.now_us + DRIVER_RECHECK_US;
            }
            if self.now_us < reset.until_us {
                self.activity = Activity::Homing {
                    seq,
                    arms,
                    trips,
                    reset: Some(reset),
                };
                return;
            }
            let faulted = Arm::BOTH.map(|arm| self.hardware.driver_fault(arm));
            if let Some(arm) = Arm::BOTH.into_iter().find(|arm| faulted[arm.index()]) {
                // Still there: off again (a short must not stay driven), and refused.
                for arm in Arm::BOTH {
                    if faulted[arm.index()] {
                        self.hardware.set_driver_enabled(arm, false);
                        self.driver_off[arm.index()] = true;
                    }
                }
                self.fault = Some(ErrorCode::HardwareFault);
                self.safe_stopped = true;
                let refused =
                    DeviceError::with_detail(ErrorCode::HardwareFault, arm.index() as i32);
                self.link.finish(seq, Err(refused), send);
                return;
            }
            self.driver_off = [false; 2];
        }
        for arm in Arm::BOTH {
            if trips[arm.index()].is_some() {
                continue;
            }
            let switch = self.switch_state(arm);
            match arms[arm.index()].poll(
                &mut self.hardware,
                &mut self.motion,
                &self.config,
                switch,
                self.now_us,
            ) {
                HomingStatus::Running => {}
                HomingStatus::Homed { trip_steps } => trips[arm.index()] = Some(trip_steps),
                HomingStatus::Failed(error) => {
                    // The other arm stops too; the host hears which arm failed and how.
                    self.halt(error.code, send);
                    self.link.finish(seq, Err(error), send);
                    self.fault = Some(error.code);
                    return;
                }
            }
        }
        let [Some(trip_i), Some(trip_r)] = trips else {
            self.activity = Activity::Homing {
                seq,
                arms,
                trips,
                reset: None,
            };
            return;
        };
        let switch = angle_to_steps(self.config.home_switch);
        let mut errors = [None; 2];
        for (arm, trip) in Arm::BOTH.into_iter().zip([trip_i, trip_r]) {
            let i = arm.index();
            // Where the switch is, minus where the arm believed it was when it tripped:
            // negative when the arm fell short of its step count (steps lost on the way out).
            errors[i] = self.homed_since_reset[i].then_some(switch - trip);
            let here = self.hardware.position_steps(arm);
            self.hardware
                .set_position_steps(arm, switch + (here - trip));
            self.homed[i] = true;
            self.homed_since_reset[i] = true;
            self.count_trusted[i] = true;
        }
        self.fault = None;
        self.safe_stopped = false;
        let report = HomeReport {
            step_error_i: errors[0],
            step_error_r: errors[1],
        };
        self.link.finish(seq, Ok(Reply::Homed(report)), send);
    }

    /// Refuse a target outside the working range or breaking the collision guard.
    pub fn check_target(&self, geometry: Geometry) -> Result<(), DeviceError> {
        check_target(&self.config, geometry)
    }

    fn positions(&self) -> [i32; 2] {
        Arm::BOTH.map(|arm| self.hardware.position_steps(arm))
    }

    fn position(&self) -> Geometry {
        let [i, r] = self.positions();
        Geometry::new(steps_to_angle(i), steps_to_angle(r))
    }

    fn start_travel(&mut self, geometry: Geometry) -> Travel {
        let from = self.positions();
        let target = [
            angle_to_steps(geometry.theta_i),
            angle_to_steps(geometry.theta_r),
        ];
        let profiles = plan_move(
            from,
            target,
            deg_to_steps(self.config.max_speed_deg_per_s),
            deg_to_steps(self.config.accel_deg_per_s2),
        );
        for arm in Arm::BOTH {
            self.motion
                .start(&mut self.hardware, arm, profiles[arm.index()], self.now_us);
        }
        Travel {
            target,
            moved: from != target,
            settle_until_us: None,
        }
    }

    /// `Ok(None)` when arrived and settled; an error when the arms came to rest elsewhere.
    fn advance_travel(&mut self, mut travel: Travel) -> Result<Option<Travel>, ErrorCode> {
        if self.motion.any_moving(&self.hardware) {
            return Ok(Some(travel));
        }
        if self.positions() != travel.target {
            return Err(ErrorCode::HardwareFault);
        }
        let settle_us = if travel.moved {
            u64::from(self.config.settle_ms) * 1000
        } else {
            0
        };
        let until = *travel
            .settle_until_us
            .get_or_insert(self.now_us + settle_us);
        Ok((self.now_us < until).then_some(travel))
    }

    fn start_move_to(&mut self, seq: u32, geometry: Geometry) -> Answer {
        let checks = self
            .busy()
            .and_then(|_| self.require_drivers())
            .and_then(|_| self.require_homed());
        if let Err(error) = checks.and_then(|_| self.check_target(geometry)) {
            return Some(Err(error));
        }
        let travel = self.start_travel(geometry);
        if !travel.moved {
            return Some(Ok(Reply::Ack));
        }
        self.activity = Activity::Moving { seq, travel };
        None
    }

    fn start_reading(&mut self, seq: u32, integration_ms: u16, range: Option<u8>) -> Answer {
        let checks = self
            .busy()
            .and_then(|_| self.require_homed())
            .and_then(|_| self.check_integration(integration_ms));
        if let Err(error) = checks {
            return Some(Err(error));
        }
        let reading = match range {
            None => RangedReading::auto(
                &mut self.hardware,
                &self.config,
                self.last_range,
                integration_ms,
                self.now_us,
            ),
            Some(range) if usize::from(range) < self.range_count() => RangedReading::forced(
                &mut self.hardware,
                &self.config,
                range,
                integration_ms,
                self.now_us,
            ),
            Some(_) => {
                return Some(Err(DeviceError::with_detail(
                    ErrorCode::InvalidArgument,
                    self.range_count() as i32,
                )));
            }
        };
        self.activity = Activity::Reading { seq, reading };
        None
    }

    fn start_dark(&mut self, seq: u32, integration_ms: u16) -> Answer {
        if let Err(error) = self
            .busy()
            .and_then(|_| self.check_integration(integration_ms))
        {
            return Some(Err(error));
        }
        self.hardware.set_lamp(false);
        self.lamp_on = false;
        let integration = Integration::start(
            &mut self.hardware,
            &self.config,
            0,
            integration_ms,
            self.now_us,
        );
        self.activity = Activity::Dark {
            seq,
            integration,
            readings: heapless::Vec::new(),
        };
        None
    }

    fn upload(&mut self, chunk: &protocol::ScheduleChunk) -> Result<Reply, DeviceError> {
        if matches!(self.activity, Activity::Schedule(_)) {
            return Err(DeviceError::new(ErrorCode::Busy));
        }
        let config = &self.config;
        let received = self
            .uploaded
            .add_chunk(chunk, config.max_schedule_len, |g| check_target(config, g))?;
        Ok(Reply::ScheduleLoaded {
            schedule_id: chunk.schedule_id,
            received,
            total_len: chunk.total_len,
        })
    }

    fn start_schedule(&mut self, run: &RunSchedule) -> Result<Reply, DeviceError> {
        self.busy()?;
        self.require_drivers()?;
        self.require_homed()?;
        self.check_integration(run.integration_ms)?;
        let len = match run.source {
            ScheduleSource::Strategy1 => STRATEGY1_ORDER.len() as u16,
            ScheduleSource::Uploaded => match self.uploaded.complete(run.schedule_id) {
                Some(geometries) => geometries.len() as u16,
                None => return Err(DeviceError::new(ErrorCode::NoSchedule)),
            },
        };
        let first = self
            .schedule_geometry(run.source, 0)
            .ok_or(DeviceError::new(ErrorCode::NoSchedule))?;
        self.check_target(first)?;
        let travel = self.start_travel(first);
        self.activity = Activity::Schedule(ScheduleRun {
            schedule_id: run.schedule_id,
            source: run.source,
            len,
            index: 0,
            integration_ms: run.integration_ms,
            target: run.target,
            started_us: self.now_us,
            step: RunStep::Travel(travel),
        });
        Ok(Reply::ScheduleStarted {
            schedule_id: run.schedule_id,
            len,
        })
    }

    fn schedule_geometry(&self, source: ScheduleSource, index: u16) -> Option<Geometry> {
        match source {
            ScheduleSource::Strategy1 => STRATEGY1_ORDER.get(usize::from(index)).copied(),
            ScheduleSource::Uploaded => self.uploaded.get(index),
        }
    }

    fn poll_schedule(&mut self, mut run: ScheduleRun, send: &mut impl FnMut(&[u8])) {
        match run.step {
            RunStep::Travel(travel) => match self.advance_travel(travel) {
                Ok(Some(travel)) => run.step = RunStep::Travel(travel),
                Ok(None) => {
                    let reading = RangedReading::auto(
                        &mut self.hardware,
                        &self.config,
                        self.last_range,
                        run.integration_ms,
                        self.now_us,
                    );
                    run.step = RunStep::Measure(reading);
                }
                Err(code) => {
                    self.activity = Activity::Schedule(run);
                    return self.fail_safe_stop(code, send);
                }
            },
            RunStep::Measure(mut reading) => {
                match reading.poll(&mut self.hardware, &self.config, self.now_us) {
                    ReadingProgress::Running => run.step = RunStep::Measure(reading),
                    ReadingProgress::NoSamples => {
                        self.activity = Activity::Schedule(run);
                        return self.fail_safe_stop(ErrorCode::HardwareFault, send);
                    }
                    ReadingProgress::SamplesLost(_) => {
                        self.activity = Activity::Schedule(run);
                        return self.fail_safe_stop(ErrorCode::AdcOverrun, send);
                    }
                    ReadingProgress::Done(reading) => {
                        self.last_range = reading.range;
                        let streamed = StreamReading {
                            schedule_id: run.schedule_id,
                            index: run.index,
                            geometry: self.position(),
                            target: run.target,
                            reading,
                            device_time_us: self.now_us,
                        };
                        self.link.send(&DeviceMessage::Reading(streamed), send);
                        run.index += 1;
                        let next = self.schedule_geometry(run.source, run.index);
                        match next {
                            Some(geometry) if run.index < run.len => {
                                if let Err(error) = self.check_target(geometry) {
                                    // Checked at upload; a failure here is a firmware fault.
                                    self.activity = Activity::Schedule(run);
                                    return self.fail_safe_stop(error.code, send);
                                }
                                run.step = RunStep::Travel(self.start_travel(geometry));
                            }
                            _ => {
                                let done = ScheduleDone {
                                    schedule_id: run.schedule_id,
                                    readings: run.index,
                                    device_us: self.now_us - run.started_us,
                                    error: None,
                                };
                                self.link.send(&DeviceMessage::ScheduleDone(done), send);
                                return;
                            }
                        }
                    }
                }
            }
        }
        self.activity = Activity::Schedule(run);
    }

    /// Accept a sweep: every check before anything moves ([`crate::sweep`]), then the
    /// range selected and the move to (θi, `from`) started; the plan is the answer.
    fn start_sweep(&mut self, sweep: &Sweep) -> Result<Reply, DeviceError> {
        self.busy()?;
        self.require_drivers()?;
        self.require_homed()?;
        let bins = check_sweep(&self.config, sweep)?;
        let start = [angle_to_steps(sweep.theta_i), angle_to_steps(sweep.from)];
        let (max_speed, accel) = (
            deg_to_steps(self.config.max_speed_deg_per_s),
            deg_to_steps(self.config.accel_deg_per_s2),
        );
        let profile = sweep_profile(
            &self.config,
            start[1],
            angle_to_steps(sweep.to),
            sweep.speed_mdeg_per_s,
        );
        let duration_us =
            crate::motion::move_duration_us(self.positions(), start, max_speed, accel)
                + u64::from(self.config.settle_ms) * 1000
                + profile.duration_us();
        let mut ranging = AutoRange::new(
            &self.config,
            sweep.range.unwrap_or(self.last_range),
            sweep.range.is_some(),
        );
        if let Some(range) = ranging.take_switch() {
            self.hardware.select_range(range);
        }
        let mut travel = self.start_travel(Geometry::new(sweep.theta_i, sweep.from));
        // Settle also when already there: the range is found at rest, before any bin.
        travel.moved = true;
        self.activity = Activity::Sweep(SweepRun {
            sweep: *sweep,
            bins,
            ranging,
            phase: SweepPhase::Approach(travel),
            last_block_us: self.now_us,
        });
        let duration_ms = duration_us.div_ceil(1000).min(u64::from(u32::MAX)) as u32;
        Ok(Reply::Sweep(SweepPlan { bins, duration_ms }))
    }

    fn poll_sweep(&mut self, mut run: SweepRun, send: &mut impl FnMut(&[u8])) {
        let now = self.now_us;
        let (config, link, hardware) = (&self.config, &mut self.link, &mut self.hardware);
        let mut blocks = 0u32;
        let drained = hardware.drain_samples(&mut |sample| {
            blocks += 1;
            let class = run.ranging.block(config, sample.counts);
            if let SweepPhase::Sweeping(binner) = &mut run.phase {
                if let Some(bin) = binner.block(sample, class, run.ranging.range(), now) {
                    link.send(&DeviceMessage::SweepBin(bin), send);
                }
            }
        });
        if let Some(range) = run.ranging.take_switch() {
            hardware.select_range(range);
        }
        if blocks > 0 {
            run.last_block_us = now;
        }
        let silent = now.saturating_sub(run.last_block_us)
            > SWEEP_SILENT_BLOCKS * u64::from(config.detector_block_us);
        let fault = if drained.is_err() {
            Some(ErrorCode::AdcOverrun)
        } else if silent {
            Some(ErrorCode::HardwareFault)
        } else {
            None
        };
        if let Some(code) = fault {
            self.activity = Activity::Sweep(run);
            return self.fail_safe_stop(code, send);
        }
        match run.phase {
            SweepPhase::Approach(travel) => match self.advance_travel(travel) {
                Ok(Some(travel)) => run.phase = SweepPhase::Approach(travel),
                // Settled, but a range switch is still settling: wait for it at rest.
                Ok(None) if !run.ranging.is_found() => {
                    run.phase = SweepPhase::Approach(Travel {
                        settle_until_us: Some(now),
                        ..travel
                    });
                }
                Ok(None) => {
                    let from = angle_to_steps(run.sweep.from);
                    let profile = sweep_profile(
                        &self.config,
                        from,
                        angle_to_steps(run.sweep.to),
                        run.sweep.speed_mdeg_per_s,
                    );
                    self.motion
                        .start(&mut self.hardware, Arm::Detector, profile, now);
                    run.phase = SweepPhase::Sweeping(Binner::new(&run.sweep, run.bins));
                }
                Err(code) => {
                    self.activity = Activity::Sweep(run);
                    return self.fail_safe_stop(code, send);
                }
            },
            SweepPhase::Sweeping(binner) => {
                if binner.is_done() && !self.motion.any_moving(&self.hardware) {
                    if self.positions()
                        != [
                            angle_to_steps(run.sweep.theta_i),
                            angle_to_steps(run.sweep.to),
                        ]
                    {
                        self.activity = Activity::Sweep(run);
                        return self.fail_safe_stop(ErrorCode::HardwareFault, send);
                    }
                    if run.sweep.range.is_none() {
                        self.last_range = run.ranging.range();
                    }
                    let done = DeviceMessage::SweepDone {
                        sweep_id: run.sweep.sweep_id,
                        bins: binner.bins_sent(),
                    };
                    self.link.send(&done, send);
                    return;
                }
            }
        }
        self.activity = Activity::Sweep(run);
    }

    /// The answer to `GetStatus`.
    pub fn status(&self) -> Status {
        let state = match self.activity {
            Activity::Idle if self.safe_stopped => DeviceState::Stopped,
            Activity::Idle => DeviceState::Idle,
            Activity::Homing { .. } => DeviceState::Homing,
            Activity::Moving { .. } => DeviceState::Moving,
            Activity::Reading { .. } | Activity::Dark { .. } => DeviceState::Measuring,
            Activity::Schedule(_) => DeviceState::RunningSchedule,
            Activity::Sweep(_) => DeviceState::Sweeping,
            Activity::SelfTest { .. } => DeviceState::Measuring,
            Activity::Stopping if self.safe_stopped => DeviceState::Stopped,
            Activity::Stopping => DeviceState::Moving,
        };
        let schedule = match &self.activity {
            Activity::Schedule(run) => Some((run.schedule_id, run.index)),
            Activity::Sweep(SweepRun {
                sweep,
                phase: SweepPhase::Sweeping(binner),
                ..
            }) => Some((sweep.sweep_id, binner.bins_sent())),
            Activity::Sweep(SweepRun { sweep, .. }) => Some((sweep.sweep_id, 0)),
            _ => None,
        };
        Status {
            state,
            position: self.position(),
            homed_i: self.homed[0],
            homed_r: self.homed[1],
            lamp_on: self.lamp_on,
            fault: self.fault,
            schedule,
            uptime_us: self.now_us,
        }
    }
}

/// Refuse a target outside the working range (detail: the arm) or breaking the collision
/// guard. Every target of every command and schedule passes here before any motion.
pub fn check_target(config: &InstrumentConfig, geometry: Geometry) -> Result<(), DeviceError> {
    for (arm, angle) in [geometry.theta_i, geometry.theta_r].into_iter().enumerate() {
        if angle < config.arm_min || angle > config.arm_max {
            return Err(DeviceError::with_detail(ErrorCode::OutOfRange, arm as i32));
        }
    }
    if geometry.theta_i.ticks() + geometry.theta_r.ticks() < config.collision_min_sum.ticks() {
        return Err(DeviceError::new(ErrorCode::CollisionGuard));
    }
    Ok(())
}
