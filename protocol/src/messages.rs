//! Every message of the wire contract.
//!
//! The host sends [`Request`]s, each with a sequence number. The device sends
//! [`DeviceMessage`]s: a [`DeviceMessage::Reply`] names the sequence it answers and
//! carries either a [`Reply`] or a domain [`DeviceError`]; streamed readings carry the
//! schedule id and geometry index so the host can detect loss and duplication.
//! Transport failures (bad frames) are [`crate::FrameError`]s and stay out of these types,
//! except for the device telling the host that it dropped a frame
//! ([`DeviceMessage::FrameRejected`]), which has no sequence number to answer.
//!
//! A frame with a good CRC that holds no command of this version (a newer host's, or a
//! field this version cannot read) still names its request: the `seq` leads every
//! [`Request`] ([`crate::framing::Sequenced`]). The device answers it
//! `Reply { seq, result: Err(NotSupported) }`, so the host stops retrying at once;
//! only a frame whose `seq` cannot be read is answered `FrameRejected`.
//!
//! Compatibility rule: `Request::seq` (first), `Command::Hello` (variant 0),
//! `DeviceMessage::Reply` (variant 0) and its `seq`, `Result::Err` and [`DeviceError`]
//! never change encoding, so a peer of any version can read a version-mismatch refusal
//! and tie an unreadable message to its request. Every other encoding is pinned by the
//! golden file `tests/data/golden.hex` (see `tests/it/golden.rs`): a change there is a new
//! [`crate::PROTOCOL_VERSION`].

use crate::framing::Sequenced;
use crate::geometry::Geometry;
use core::fmt;
use heapless::{String, Vec};
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Geometries per [`ScheduleChunk`]; a longer schedule is uploaded in several chunks.
pub const SCHEDULE_CHUNK_LEN: usize = 16;
/// Most detector ranges a device can announce.
pub const MAX_RANGES: usize = 4;
/// Longest [`DeviceInfo::firmware_version`], bytes.
pub const FIRMWARE_VERSION_LEN: usize = 16;
/// Longest [`DeviceInfo::board`], bytes.
pub const BOARD_NAME_LEN: usize = 32;
/// Longest [`DeviceInfo::serial_number`], bytes.
pub const SERIAL_NUMBER_LEN: usize = 24;

/// A host request: a sequence number and a command.
///
/// The device answers every request exactly once per sequence number: a request repeated
/// with the same `seq` (a retry after a lost reply) is answered again, not executed again.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Request {
    /// Chosen by the host, increasing; echoed in the reply.
    pub seq: u32,
    /// What to do.
    pub command: Command,
}

impl Sequenced for Request {
    /// The leading `seq`, which every version keeps first.
    fn seq_of_unreadable(payload: &[u8]) -> Option<u32> {
        postcard::take_from_bytes::<u32>(payload)
            .ok()
            .map(|(seq, _)| seq)
    }
}

impl Sequenced for DeviceMessage {
    /// The `seq` of a reply (variant 0, `seq` first, in every version) whose result this
    /// version cannot read; other device messages answer no request.
    fn seq_of_unreadable(payload: &[u8]) -> Option<u32> {
        match postcard::take_from_bytes::<u32>(payload) {
            Ok((0, rest)) => postcard::take_from_bytes::<u32>(rest)
                .ok()
                .map(|(seq, _)| seq),
            _ => None,
        }
    }
}

/// What the host asks of the device.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// Handshake: the host's protocol version. Answered with [`Reply::Hello`], or with
    /// [`ErrorCode::VersionMismatch`] (detail: the device's version). Until a matching
    /// `Hello`, every other command is refused with `VersionMismatch`.
    ///
    /// `Hello` starts a fresh link: it is always carried out (never answered from the
    /// reply cache, never taken for a repeat of a request in progress) and it empties the
    /// cache, so a new host process may start again at any sequence number. What runs
    /// goes on (the new host reads the state with `GetStatus`); the reply of a command
    /// accepted before the `Hello` is still sent but is no longer cached.
    Hello {
        /// [`crate::PROTOCOL_VERSION`] of the host.
        protocol_version: u16,
    },
    /// Keeps the session alive while the arms move or the lamp is on; answered with `Ack`.
    Heartbeat,
    /// Answered with [`Reply::Status`].
    GetStatus,
    /// Home both arms; answered with [`Reply::Homed`] when done.
    Home,
    /// Move both arms to a geometry; answered with `Ack` once there and settled.
    MoveTo(Geometry),
    /// Switch the lamp; answered with `Ack`.
    SetLamp {
        /// On or off.
        on: bool,
    },
    /// Dark readings, lamp off, one per detector range; answered with [`Reply::Dark`].
    TakeDark {
        /// Integration time per range, `min_integration_ms ..= max_integration_ms` of
        /// [`DeviceInfo`]; outside, [`ErrorCode::InvalidArgument`] with the violated limit
        /// as detail.
        integration_ms: u16,
    },
    /// One reading at the current position; answered with [`Reply::Reading`].
    TakeReading {
        /// Integration time, limited like `TakeDark`'s.
        integration_ms: u16,
        /// What is on the sample port.
        target: Target,
        /// `None`: auto-ranged. `Some(r)`: one integration on range `r` (after the range's
        /// settle time), never re-taken on another (a saturated reading comes back flagged),
        /// so that the host can read one scene on two adjacent ranges and calibrate their
        /// gain ratio. An index beyond the device's ranges is refused with
        /// [`ErrorCode::InvalidArgument`] (detail: the number of ranges).
        range: Option<u8>,
    },
    /// Part of a host-made schedule; answered with [`Reply::ScheduleLoaded`].
    UploadSchedule(ScheduleChunk),
    /// Run a schedule; answered with [`Reply::ScheduleStarted`], then one
    /// [`DeviceMessage::Reading`] per geometry and a [`DeviceMessage::ScheduleDone`].
    RunSchedule(RunSchedule),
    /// Stop motion (ramped) and any schedule or sweep now; answered with `Ack`. Accepted in
    /// any state.
    Abort,
    /// Sweep the detector arm across `from ..= to` at a constant speed, the source arm held,
    /// streaming the detector's blocks as bins; answered with [`Reply::Sweep`] once accepted
    /// (before the arms move), then one [`DeviceMessage::SweepBin`] per bin, in order, and a
    /// [`DeviceMessage::SweepDone`] once the detector arm has stopped at `to`. See [`Sweep`]
    /// for what is refused.
    Sweep(Sweep),
    /// The self-test: what a builder runs before a first motion and a lab before a case.
    /// Answered with [`Reply::SelfTest`] once done (about a second): both drivers are
    /// disabled (EN high: no torque, the arms do not move) and each arm's step generator
    /// runs [`SELF_TEST_PULSE_STEPS`] steps at the speed and acceleration limits, counted
    /// against the profile and timed by the device clock, while the detector's blocks are
    /// counted against the block period; the rest is read back (clocks measured at boot,
    /// the worst step-interrupt lateness and the longest interrupt-off section since boot,
    /// the stack's high-water mark, switches, driver faults, the range lines). The lamp is
    /// switched off. The drivers stay disabled afterwards and the arms count as not homed
    /// (an arm without torque may have moved), so a `Home` follows.
    ///
    /// Refused with `Busy` while anything runs. The device judges nothing: the host holds
    /// the limits (`gonio selftest`).
    SelfTest,
}

/// Steps each arm's step generator issues in the self-test's pulse check, drivers disabled:
/// 50° of steps, which at the reference limits (60°/s, 180°/s²) take about 1.2 s, long
/// enough that the device's 1 ms poll resolves the duration to a tenth of a percent.
pub const SELF_TEST_PULSE_STEPS: u32 = 4_000;

impl Command {
    /// Whether carrying the command out changes nothing (heartbeat, status). The device
    /// may carry such a command out again when it is repeated, so its replies need no
    /// place in the reply cache that protects the commands that do act.
    pub fn is_read_only(&self) -> bool {
        matches!(self, Command::Heartbeat | Command::GetStatus)
    }
}

/// What is on the sample port while a reading is taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Target {
    /// The sample under test.
    Sample,
    /// The white reference tile (white calibration or white check).
    WhiteReference,
}

/// One chunk of a host-made schedule. Chunks arrive in order: `offset` is the number of
/// geometries already received for this `schedule_id`; a chunk with `offset` 0 starts over.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScheduleChunk {
    /// Host-chosen id, echoed by every streamed reading of the schedule.
    pub schedule_id: u16,
    /// Length of the whole schedule.
    pub total_len: u16,
    /// Index of this chunk's first geometry in the schedule.
    pub offset: u16,
    /// The geometries, in the order the host wants them visited.
    pub geometries: Vec<Geometry, SCHEDULE_CHUNK_LEN>,
}

/// Which schedule to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScheduleSource {
    /// The built-in 12 geometries of Strategy 1, in the device's fixed fast order.
    Strategy1,
    /// The last fully uploaded schedule with this run's `schedule_id`, in its given order.
    Uploaded,
}

/// Run a schedule.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RunSchedule {
    /// Labels the streamed readings (for `Uploaded`, selects the schedule).
    pub schedule_id: u16,
    /// Built-in or uploaded.
    pub source: ScheduleSource,
    /// Integration time of every reading.
    pub integration_ms: u16,
    /// What is on the sample port.
    pub target: Target,
}

/// Most bins one sweep may have; a sweep of more is refused ([`ErrorCode::InvalidArgument`],
/// detail: this number).
pub const MAX_SWEEP_BINS: u16 = 4096;

/// Sweep the detector arm at a constant speed across `[from, to]` with the source arm held
/// at `theta_i`, streaming one [`SweepBin`] per bin.
///
/// The device moves both arms to (`theta_i`, `from`) and settles there (also when it is
/// already there: auto-ranging finds the range at rest), then runs one profile of the
/// detector arm from `from` to `to`: it accelerates from rest at
/// [`DeviceInfo::accel_deg_per_s2`] up to `speed_mdeg_per_s` and decelerates to rest on
/// `to` (a short sweep never reaches the speed: a triangular profile). The ramps are kept:
/// every bin has its true interval from the step counts, ramps included.
///
/// A bin is whole detector blocks ([`DeviceInfo::detector_block_us`] each, stamped with
/// the detector arm's step count at the block's end): bin `k` closes with the first block
/// whose end reaches its nominal end `from + (k + 1)·bin_ticks` (towards `to`; the last
/// bin's is `to`), so its `start` is the previous bin's `end`, the first starts at `from`,
/// the last ends at `to`, and the bins are `⌈|to − from| / bin_ticks⌉`.
///
/// Refused before anything moves, in this order (so that a host can tell which limit an
/// `InvalidArgument` detail names): `Busy` while anything runs; `HardwareFault` (detail:
/// the arm) while a driver reports a fault; `NotHomed`; `InvalidArgument` for `sweep_id`
/// 0 (detail 0) and for a forced `range` beyond the detector's (detail: the number of
/// ranges); `OutOfRange` (detail: the arm) for `theta_i`, `from` or `to` outside the arms'
/// range; `CollisionGuard` when θi + θr on the path falls below the collision minimum;
/// `InvalidArgument` for a speed outside `100 ..=` the maximum (detail: the limit broken,
/// mdeg/s), a bin shorter than the travel of one detector block at the sweep's speed
/// (detail: the shortest bin accepted, ticks), a bin longer than the sweep (detail:
/// `|to − from|`, ticks; a sweep of no travel is refused so), more than [`MAX_SWEEP_BINS`]
/// bins (detail: that number).
///
/// Heartbeats as for a schedule: the host must be heard every
/// [`DeviceInfo::heartbeat_timeout_ms`]. `Abort` or a fail-safe stop ends the sweep with the
/// arm ramped down; no `SweepDone` follows then (the host has the bins it got, each named).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sweep {
    /// Chosen by the host; names every bin (like a schedule id). 0 is refused.
    pub sweep_id: u16,
    /// The source arm's angle, held through the sweep.
    pub theta_i: crate::Angle,
    /// θr where the detector arm starts (at rest) and the first bin starts.
    pub from: crate::Angle,
    /// θr where it stops and the last bin ends (`to < from` sweeps backwards).
    pub to: crate::Angle,
    /// The profile's top speed, millidegrees per second: `100 ..=` 1000 × the
    /// [`DeviceInfo::max_speed_deg_per_s`].
    pub speed_mdeg_per_s: u32,
    /// Bin length, ticks of [`crate::Angle`] (0.0125°): at least the travel of one detector
    /// block at the top speed (rounded up to whole ticks, and one more tick for the step
    /// count's quantisation: one bin per block at most), at most `|to − from|`.
    pub bin_ticks: u16,
    /// `None`: auto-ranged while moving (thresholds on each block, blanking for the new
    /// range's settling time after each switch). `Some(r)`: held on range `r` (a saturated
    /// bin is flagged).
    pub range: Option<u8>,
    /// What is on the sample port (as for a schedule): the device does not act on it; it
    /// tells a simulated instrument, or a bench with a sample changer, what to place.
    pub target: Target,
}

/// The answer to [`Command::Sweep`]: accepted, before the arms move.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SweepPlan {
    /// Bins that will stream: `⌈|to − from| / bin_ticks⌉`.
    pub bins: u16,
    /// Device time planned, ms: the move to (θi, `from`), its settle, and the sweep's
    /// profile (rounded up). A range switch found at rest may add its settling time.
    pub duration_ms: u32,
}

/// One bin of a running sweep, sent after its last block.
///
/// `start` and `end` are the detector arm's step counts at the start of the bin's first
/// block and at the end of its last: the bins tile the sweep exactly. `mean_counts` is the
/// mean of the blocks kept (`blocks` of them), dark offset included; while the arm moves at
/// v the amplifier makes the reading trail the angle by v·τ (the range's
/// [`DetectorRange::time_constant_us`]).
///
/// THE LINK. At most one bin is sent per detector block (the shortest bin is longer than a
/// block's travel), so at most 1,000 bins/s (976.6 on the board's 1.024 ms blocks). A bin is
/// at most 46 bytes as a frame, and at most 31 with angles in the arms' range, a sweep id
/// below 16,384, fewer than 128 blocks and under 9.5 hours of uptime (`tests/it/framing.rs`):
/// at most 31 kB/s (46 kB/s whatever the values). USB full speed carries up to 19 bulk
/// packets of 64 bytes per 1 ms frame (1.2 MB/s) and the host's CDC-ACM driver keeps reads
/// pending on the IN endpoint, so that is under 3 % of the link, and under half of even one
/// packet per frame (64 kB/s). The board's TX queue holds 1 KiB, 33 such bins: 33 ms of a
/// host that does not read; past that, bins are dropped whole (never half a frame), which
/// the host sees as a gap in `index` and measures again with a short sweep over the gap.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SweepBin {
    /// The sweep.
    pub sweep_id: u16,
    /// `0 ..= bins − 1`, in order.
    pub index: u16,
    /// θr at the start of the bin's first block (the step count).
    pub start: crate::Angle,
    /// θr at the end of its last block.
    pub end: crate::Angle,
    /// Mean of the blocks kept, ADC counts (dark offset included, like [`Reading`]); 0 when
    /// none was kept ([`SweepBin::EMPTY`]).
    pub mean_counts: f32,
    /// Standard deviation of the kept blocks' values (n − 1; 0 for one block), counts.
    pub std_counts: f32,
    /// Detector blocks averaged (0: none usable, see `flags`).
    pub blocks: u16,
    /// The range the kept blocks were taken on (a bin never mixes ranges).
    pub range: u8,
    /// [`SweepBin::SATURATED`], [`SweepBin::BLANKED`], [`SweepBin::EMPTY`], or'ed.
    pub flags: u8,
    /// Device time at the bin's end (when its last block was read), µs since boot.
    pub device_time_us: u64,
}

impl SweepBin {
    /// A kept block saturated on the least sensitive range (auto-ranged) or on the forced
    /// range: the mean is a lower bound, not a value (never clipped by the firmware).
    pub const SATURATED: u8 = 1;
    /// Blocks of the bin were dropped: the settling after a range switch, or a block that
    /// saturated a more sensitive range (its switch follows). The mean is of the `blocks`
    /// kept, which cover only part of `start ..= end` (a host that needs the interval's
    /// mean measures it again with a short sweep over it).
    pub const BLANKED: u8 = 2;
    /// No usable block: `mean_counts` and `std_counts` are 0 and mean nothing.
    pub const EMPTY: u8 = 4;

    /// Whether [`SweepBin::SATURATED`] is set.
    pub const fn is_saturated(&self) -> bool {
        self.flags & SweepBin::SATURATED != 0
    }

    /// Whether [`SweepBin::BLANKED`] is set.
    pub const fn is_blanked(&self) -> bool {
        self.flags & SweepBin::BLANKED != 0
    }

    /// Whether [`SweepBin::EMPTY`] is set.
    pub const fn is_empty(&self) -> bool {
        self.flags & SweepBin::EMPTY != 0
    }
}

/// Everything the device may send.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DeviceMessage {
    /// The answer to the request with sequence number `seq`.
    Reply {
        /// The request's sequence number.
        seq: u32,
        /// The outcome.
        result: Result<Reply, DeviceError>,
    },
    /// One reading of a running schedule, sent as soon as it is taken.
    Reading(StreamReading),
    /// A schedule ended (completed, aborted or failed).
    ScheduleDone(ScheduleDone),
    /// A frame arrived that the device could not read and whose sequence number it could
    /// not read either (bad COBS, bad CRC, too long). A frame with a good CRC and a readable
    /// `seq` is answered `Reply { seq, result: Err(NotSupported) }` instead.
    FrameRejected {
        /// [`ErrorCode::BadFrame`], [`ErrorCode::BadCrc`] or [`ErrorCode::UnknownMessage`].
        code: ErrorCode,
    },
    /// The device took its fail-safe stop on its own (arms ramped down, lamp off, what
    /// ran ended with `reason`), and why. Whether the arms are still homed is in
    /// [`Status`]: a stop with both arms at rest and no driver fault keeps the homing
    /// (state `Idle`), one mid-move or on a driver fault loses it (state `Stopped`).
    Stopped {
        /// The reason, e.g. [`ErrorCode::HeartbeatLost`] or [`ErrorCode::HardwareFault`].
        reason: ErrorCode,
    },
    /// One bin of a running sweep ([`Command::Sweep`]), sent after its last block.
    SweepBin(SweepBin),
    /// A sweep ended: every bin was sent and the detector arm stopped at `to`. Not sent
    /// after an `Abort` or a fail-safe stop.
    SweepDone {
        /// The sweep.
        sweep_id: u16,
        /// Bins sent (the plan's count).
        bins: u16,
    },
}

/// A successful answer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reply {
    /// Answer to `Hello`.
    Hello(DeviceInfo),
    /// Done (heartbeat, move, lamp, abort).
    Ack,
    /// Answer to `GetStatus`.
    Status(Status),
    /// Answer to `Home`.
    Homed(HomeReport),
    /// Answer to `TakeReading`.
    Reading(Reading),
    /// Answer to `TakeDark`: one reading per range, most sensitive first.
    Dark(Vec<Reading, MAX_RANGES>),
    /// Answer to `UploadSchedule`.
    ScheduleLoaded {
        /// The schedule.
        schedule_id: u16,
        /// Geometries received so far.
        received: u16,
        /// Announced length.
        total_len: u16,
    },
    /// Answer to `RunSchedule`: accepted and started.
    ScheduleStarted {
        /// The schedule.
        schedule_id: u16,
        /// Number of readings that will stream.
        len: u16,
    },
    /// Answer to `Sweep`: accepted; the arms start moving.
    Sweep(SweepPlan),
    /// Answer to `SelfTest`.
    SelfTest(SelfTestReport),
}

/// One arm's pulse check in the self-test: its step generator ran a profile of
/// [`SELF_TEST_PULSE_STEPS`] with the driver disabled.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PulseCheck {
    /// Steps the profile has.
    pub steps_expected: u32,
    /// Steps the step generator counted (one per pulse its interrupt saw issued).
    pub steps_counted: u32,
    /// The profile's duration, µs.
    pub duration_expected_us: u32,
    /// From the profile's start until the generator was at rest, by the device clock, µs:
    /// the step timer's rate against the clock, to within one poll of the device loop.
    pub duration_measured_us: u32,
}

/// What the self-test measured ([`Command::SelfTest`]). Each figure is a measurement or
/// `None` where this hardware cannot make it (the simulator has no clocks to measure);
/// the host holds the pass/fail limits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SelfTestReport {
    /// The crystal this firmware was built for, Hz.
    pub hse_expected_hz: u32,
    /// The crystal measured against the internal RC oscillator (HSI, ±1 %) at boot, Hz.
    pub hse_measured_hz: Option<u32>,
    /// The core clock the firmware set up, Hz.
    pub sysclk_expected_hz: u32,
    /// The core clock measured against the crystal at boot, Hz.
    pub sysclk_measured_hz: Option<u32>,
    /// The pulse check of the source arm.
    pub pulses_source: PulseCheck,
    /// The pulse check of the detector arm.
    pub pulses_detector: PulseCheck,
    /// Detector blocks expected over the pulse check (its duration / the block period).
    pub blocks_expected: u32,
    /// Detector blocks that arrived meanwhile: the ADC's pace against the device clock.
    pub blocks_counted: u32,
    /// Times samples were lost during the test (an ADC or DMA overrun, a full ring).
    pub sample_losses: u16,
    /// The latest a step interrupt ran after its segment began, since boot, µs.
    pub worst_step_late_us: u32,
    /// The step interrupt's deadline in the shortest segment the generator makes, µs: a
    /// lateness reaching it stops the arm ([`ErrorCode::StepLate`]).
    pub step_deadline_us: u32,
    /// The longest section with interrupts off since boot, µs (the board times its
    /// critical sections by the cycle counter).
    pub longest_interrupts_off_us: Option<u32>,
    /// The stack's high-water mark since boot (a painted stack), bytes.
    pub stack_used_bytes: Option<u32>,
    /// The stack's size, bytes (0 where not measured).
    pub stack_size_bytes: u32,
    /// Source arm's home switch pressed (the arms stand where they were).
    pub switch_source: bool,
    /// Detector arm's home switch pressed.
    pub switch_detector: bool,
    /// Source arm's driver reports a fault (read with the driver disabled).
    pub driver_fault_source: bool,
    /// Detector arm's driver reports a fault.
    pub driver_fault_detector: bool,
    /// The range the amplifier was told to use.
    pub range_selected: u8,
    /// The range the amplifier's select lines read back (one-hot decoded); `None` where
    /// the lines cannot be read back, 255 when they are not one-hot.
    pub range_read_back: Option<u8>,
    /// The resets since the supply came on (or since RAM last lost its content), by
    /// cause; `None` where not kept.
    pub resets_since_power_on: Option<ResetCounts>,
}

/// Resets of each kind since power-on ([`SelfTestReport::resets_since_power_on`]): the
/// board counts them in RAM that survives a reset. The power-on itself is not counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ResetCounts {
    /// By the watchdog (a hung firmware).
    pub watchdog: u16,
    /// By the firmware's own fail-safe reset after a panic, a processor fault or a stack
    /// overflow.
    pub fault: u16,
    /// By the reset pin (the board's button, a probe).
    pub pin: u16,
    /// By software without a fault (a debugger's reset request).
    pub software: u16,
}

/// A refused or failed request: a stable code and a code-specific detail.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceError {
    /// What went wrong.
    pub code: ErrorCode,
    /// Code-specific: the device's version for `VersionMismatch`, the arm (0 = source,
    /// 1 = detector) for `OutOfRange` and homing faults, the limit for `ScheduleTooLong`,
    /// the expected offset for `BadSchedule`; for `InvalidArgument`, the violated limit
    /// (the shortest or the longest integration time, ms; the number of detector ranges
    /// for a forced range); for the firmware's own faults, as each [`ErrorCode`] says;
    /// otherwise 0.
    pub detail: i32,
}

impl DeviceError {
    /// An error with no detail.
    pub const fn new(code: ErrorCode) -> DeviceError {
        DeviceError { code, detail: 0 }
    }

    /// An error with a detail.
    pub const fn with_detail(code: ErrorCode, detail: i32) -> DeviceError {
        DeviceError { code, detail }
    }
}

impl fmt::Display for DeviceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (code {}", self.code.description(), self.code.code())?;
        if self.detail != 0 {
            write!(f, ", detail {}", self.detail)?;
        }
        f.write_str(")")
    }
}

macro_rules! error_codes {
    ($($(#[doc = $doc:literal])* $name:ident = $code:literal, $text:literal;)*) => {
        /// Domain error codes. The numbers are stable across protocol versions: they are
        /// what goes on the wire, and what logs and users quote.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
        #[serde(from = "u16", into = "u16")]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub enum ErrorCode {
            $($(#[doc = $doc])* $name,)*
            /// A code this side does not know (sent by a newer peer).
            Unknown(u16),
        }

        impl ErrorCode {
            /// Every known code, in numeric order.
            pub const ALL: &'static [ErrorCode] = &[$(ErrorCode::$name,)*];

            /// The stable number.
            pub const fn code(self) -> u16 {
                match self {
                    $(ErrorCode::$name => $code,)*
                    ErrorCode::Unknown(code) => code,
                }
            }

            /// A short sentence for people.
            pub const fn description(self) -> &'static str {
                match self {
                    $(ErrorCode::$name => $text,)*
                    ErrorCode::Unknown(_) => "unknown error code (peer is newer)",
                }
            }
        }

        impl From<u16> for ErrorCode {
            fn from(code: u16) -> ErrorCode {
                match code {
                    $($code => ErrorCode::$name,)*
                    other => ErrorCode::Unknown(other),
                }
            }
        }
    };
}

error_codes! {
    /// A frame could not be COBS-decoded or had bytes after its CRC.
    BadFrame = 1, "bad frame";
    /// A frame's CRC-32 did not match its payload.
    BadCrc = 2, "bad CRC";
    /// A well-formed frame that is no message of this protocol version.
    UnknownMessage = 3, "unknown message";
    /// A frame longer than the maximum frame length.
    FrameTooLong = 4, "frame too long";
    /// The peers speak different protocol versions.
    VersionMismatch = 5, "protocol version mismatch";
    /// Motion or measurement before both arms are homed.
    NotHomed = 6, "arms not homed";
    /// A target outside an arm's working range.
    OutOfRange = 7, "target out of range";
    /// A target breaking the collision guard θi + θr ≥ 10°.
    CollisionGuard = 8, "target breaks the collision guard";
    /// Another operation is running.
    Busy = 9, "busy";
    /// A schedule longer than the device holds.
    ScheduleTooLong = 10, "schedule too long";
    /// The operation was aborted.
    Aborted = 11, "aborted";
    /// A hardware fault (driver, ADC, lamp).
    HardwareFault = 12, "hardware fault";
    /// Homing did not find the switch within the search range.
    HomeSwitchNotFound = 13, "home switch not found";
    /// The home switch did not release when backing off.
    HomeSwitchStuck = 14, "home switch does not release";
    /// No frame from the host for too long while moving or lit: safe stop.
    HeartbeatLost = 15, "host heartbeat lost";
    /// Running an uploaded schedule that is missing or incomplete.
    NoSchedule = 16, "no complete schedule with that id";
    /// A schedule chunk out of order or inconsistent with its announced length.
    BadSchedule = 17, "bad schedule chunk";
    /// A parameter out of its allowed range (e.g. integration time).
    InvalidArgument = 18, "invalid argument";
    /// The MCU was reset by its watchdog; arms count as not homed.
    WatchdogReset = 19, "reset by watchdog";
    /// A command this firmware build does not carry out.
    NotSupported = 20, "not supported by this firmware";
    /// The firmware panicked (a broken invariant); it stopped every output and reset.
    /// Detail: the source line of the panic.
    Panic = 21, "firmware panic";
    /// The processor faulted (a bad memory access, an undefined instruction); the
    /// firmware stopped every output and reset. Detail: the faulting instruction's address.
    ProcessorFault = 22, "processor fault";
    /// The stack ran into the end of RAM (it is placed there so that an overflow faults
    /// instead of overwriting data); the firmware stopped every output and reset.
    StackOverflow = 23, "stack overflow";
    /// A step timer's interrupt ran too late to load the next segment, so the timer may
    /// have issued a step nobody counted: fail-safe stop, arms not homed. Detail: the arm.
    StepLate = 24, "step interrupt late";
    /// Detector samples were lost or could have been mixed (the ADC or its DMA overran,
    /// or nobody drained the decoded samples in time): fail-safe stop. Detail: 1 ADC
    /// overrun, 2 DMA lapped the decimation, 3 decoded samples lost.
    AdcOverrun = 25, "detector samples lost";
}

/// On the wire an error code is its number (a `u16`), whatever the variant: a code this
/// version does not know still decodes, as [`ErrorCode::Unknown`].
impl Schema for ErrorCode {
    const SCHEMA: &'static postcard_schema::schema::NamedType =
        &postcard_schema::schema::NamedType {
            name: "ErrorCode",
            ty: <u16 as Schema>::SCHEMA.ty,
        };
}

impl From<ErrorCode> for u16 {
    fn from(code: ErrorCode) -> u16 {
        code.code()
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (code {})", self.description(), self.code())
    }
}

/// What the device is and can do: the answer to `Hello`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceInfo {
    /// The device's [`crate::PROTOCOL_VERSION`]; first, so it is readable by any version.
    pub protocol_version: u16,
    /// Firmware version (semver).
    pub firmware_version: String<FIRMWARE_VERSION_LEN>,
    /// Board name.
    pub board: String<BOARD_NAME_LEN>,
    /// Working range of both arms: lowest angle.
    pub arm_min: crate::Angle,
    /// Working range of both arms: highest angle.
    pub arm_max: crate::Angle,
    /// Arm resolution (one microstep).
    pub arm_resolution: crate::Angle,
    /// Collision guard: every target keeps θi + θr at or above this.
    pub collision_min_sum: crate::Angle,
    /// Arm speed limit.
    pub max_speed_deg_per_s: f32,
    /// Arm acceleration limit.
    pub accel_deg_per_s2: f32,
    /// Settling time after every move.
    pub settle_ms: u16,
    /// Detector ranges, most sensitive first.
    pub detector_ranges: Vec<DetectorRange, MAX_RANGES>,
    /// Detector angular acceptance, full width.
    pub acceptance_deg: f32,
    /// Longest schedule the device holds.
    pub max_schedule_len: u16,
    /// Default integration time.
    pub default_integration_ms: u16,
    /// Longest integration time accepted.
    pub max_integration_ms: u16,
    /// Shortest integration time accepted (a reading needs samples after the amplifier
    /// settles); shorter ones are refused with [`ErrorCode::InvalidArgument`].
    pub min_integration_ms: u16,
    /// The host must send a frame at least this often while an arm moves or the lamp is
    /// on, or the device takes its fail-safe stop ([`ErrorCode::HeartbeatLost`]).
    pub heartbeat_timeout_ms: u32,
    /// The longest a `Home` can take on this instrument, from anywhere, failures
    /// included: how long a host waits for its answer.
    pub longest_home_ms: u32,
    /// This instrument's unique serial number (the MCU's unique ID, or the simulator's):
    /// what a session folder and a calibration record as the instrument they came from.
    pub serial_number: String<SERIAL_NUMBER_LEN>,
    /// Why the MCU last came out of reset: after a fault of the firmware's own (a panic,
    /// a processor fault, a stack overflow) or a watchdog reset the arms are not homed
    /// and [`Status::fault`] holds the reason until the next homing.
    pub reset_cause: ResetCause,
    /// The detector's block period, µs: one ADC sample (a block of oversampled
    /// conversions) per period, the unit a sweep's bins are made of. While the arm moves at
    /// v a block covers v × this.
    pub detector_block_us: u32,
}

/// Why the device last came out of reset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// Power-up or a brown-out.
    PowerOn,
    /// The reset pin: the board's button or a debug probe.
    ResetPin,
    /// A software reset without a recorded fault (a debugger's reset request).
    Software,
    /// The independent watchdog reset a hung MCU ([`ErrorCode::WatchdogReset`]).
    Watchdog,
    /// The firmware's own fail-safe reset after a fault: every output was made safe first,
    /// and this is why ([`ErrorCode::Panic`], [`ErrorCode::ProcessorFault`],
    /// [`ErrorCode::StackOverflow`], with their detail).
    Fault(DeviceError),
}

impl ResetCause {
    /// The fault a device reports after this reset (in [`Status::fault`]), if any.
    pub const fn fault(self) -> Option<ErrorCode> {
        match self {
            ResetCause::PowerOn | ResetCause::ResetPin | ResetCause::Software => None,
            ResetCause::Watchdog => Some(ErrorCode::WatchdogReset),
            ResetCause::Fault(error) => Some(error.code),
        }
    }
}

impl fmt::Display for ResetCause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ResetCause::PowerOn => f.write_str("power-on"),
            ResetCause::ResetPin => f.write_str("reset pin"),
            ResetCause::Software => f.write_str("software reset"),
            ResetCause::Watchdog => f.write_str("watchdog reset (the firmware hung)"),
            ResetCause::Fault(error) => write!(f, "fail-safe reset after {error}"),
        }
    }
}

/// One detector range.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DetectorRange {
    /// Gain relative to the most sensitive range (1, 0.1, 0.01 for decade steps).
    pub relative_gain: f32,
    /// ADC counts at full scale.
    pub full_scale_counts: u32,
    /// The amplifier's time constant on this range, µs (its feedback R·C): a first-order
    /// response, so while the arm moves at v a reading trails the angle by v·τ (the mean
    /// of the exponential kernel; its spread (v·τ)² is second order).
    pub time_constant_us: f32,
    /// How long the amplifier takes to settle after a switch to this range, µs: the blocks
    /// of a sweep within it are dropped, and a reading waits it out.
    pub settle_us: u32,
}

/// One detector reading: statistics of the samples taken over the integration time.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Reading {
    /// Mean of the samples, in ADC counts (dark offset included).
    pub mean_counts: f32,
    /// Standard deviation of the samples, in counts.
    pub std_counts: f32,
    /// Number of samples.
    pub samples: u32,
    /// Index of the range it was taken on (into `DeviceInfo::detector_ranges`).
    pub range: u8,
    /// Integration time.
    pub integration_ms: u16,
    /// Saturated on the least sensitive range (auto-ranged) or on the forced range: the
    /// mean is a lower bound, not a value.
    pub saturated: bool,
}

/// One reading of a running schedule.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StreamReading {
    /// The schedule.
    pub schedule_id: u16,
    /// Index of the geometry in the schedule.
    pub index: u16,
    /// The geometry actually reached.
    pub geometry: Geometry,
    /// What was on the sample port.
    pub target: Target,
    /// The reading.
    pub reading: Reading,
    /// Device time at the end of the integration, µs since boot.
    pub device_time_us: u64,
}

/// The end of a schedule.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScheduleDone {
    /// The schedule.
    pub schedule_id: u16,
    /// Readings streamed.
    pub readings: u16,
    /// Device time the schedule took, µs.
    pub device_us: u64,
    /// `None` when completed; otherwise why it stopped early.
    pub error: Option<ErrorCode>,
}

/// What the device is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DeviceState {
    /// Waiting for a command.
    Idle,
    /// Homing the arms.
    Homing,
    /// Moving the arms.
    Moving,
    /// Taking a reading.
    Measuring,
    /// Running a schedule.
    RunningSchedule,
    /// In the safe state after a fault that cost the homing (a stop mid-move, a driver
    /// fault, a watchdog reset); cleared by the next `Home`. A fail-safe stop with both
    /// arms at rest keeps the homing and leaves the device `Idle` (its reason in
    /// `Status::fault`).
    Stopped,
    /// Running a sweep ([`Command::Sweep`]); [`Status::schedule`] holds its id and the
    /// bins sent so far.
    Sweeping,
}

/// The answer to `GetStatus`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// What the device is doing.
    pub state: DeviceState,
    /// Where the arms are (meaningful only where homed).
    pub position: Geometry,
    /// Source arm homed.
    pub homed_i: bool,
    /// Detector arm homed.
    pub homed_r: bool,
    /// Lamp on.
    pub lamp_on: bool,
    /// The last fault (a fail-safe stop's reason, a homing failure, a watchdog reset),
    /// until cleared by homing; set also when the stop kept the homing.
    pub fault: Option<ErrorCode>,
    /// The running schedule or sweep: its id and the readings or bins sent so far.
    pub schedule: Option<(u16, u16)>,
    /// µs since boot.
    pub uptime_us: u64,
}

/// The answer to `Home`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HomeReport {
    /// Source arm: where the switch was found minus where the arm believed it was, in
    /// ticks (exact: the switch is located by the slow approach); `None` on the first
    /// homing after power-up (nothing to compare). Non-zero means lost steps. A re-home
    /// is quick (full speed to just short of the switch, then the slow approach), so a
    /// session can afford one at its end to check for lost steps.
    pub step_error_i: Option<i32>,
    /// Detector arm: likewise.
    pub step_error_r: Option<i32>,
}
