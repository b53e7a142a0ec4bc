//! The host end of the link: requests with sequence numbers, replies matched to them,
//! timeouts and retries, heartbeats, and the handshake.
//!
//! The host never trusts that the device heard a request until it has the answer: a
//! request whose reply does not arrive in time is sent again with the same sequence
//! number, which the firmware answers without acting twice.
//!
//! One deadline bounds every wait: [`RetryPolicy::give_up_after`] of silence (nothing at
//! all heard from the device, on the transport's clock). A live device is never silent
//! that long, because every heartbeat (sent every [`RetryPolicy::heartbeat_every`] while
//! the host waits) is answered; a wait that reaches the deadline ends with
//! [`LinkError::Silent`], whatever it was waiting for. Reconnecting is the session's job
//! (`crate::session`), under the same deadline: [`Client::silent_for`].

use protocol::{
    Command, DeviceError, DeviceInfo, DeviceMessage, ErrorCode, FrameDecoder, MAX_FRAME_LEN,
    PROTOCOL_VERSION, Reply, Request,
};
use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// A byte pipe to an instrument: a serial port, a pseudo-terminal, or the simulator in
/// process.
pub trait Transport {
    /// Write all of `bytes`.
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()>;
    /// Read what is available into `buf`, waiting at most `timeout`; `Ok(0)` on timeout.
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize>;
    /// Let `duration` pass on the transport's clock (a sleep; the simulator runs on).
    fn pause(&mut self, duration: Duration) {
        std::thread::sleep(duration);
    }
    /// Re-open the link after a failure (a serial port that went away); no-op by default.
    fn reconnect(&mut self) -> std::io::Result<()> {
        Ok(())
    }
    /// The operator moved the sample so that another spot lies on the port (a multi-spot
    /// session asked them to). A real instrument cannot tell; the simulator in process moves
    /// its sheet. No-op by default.
    fn sample_moved(&mut self) {}
    /// What the link is, for messages (a port's path).
    fn name(&self) -> String {
        "the instrument's link".to_string()
    }
    /// The clock timeouts are measured on: wall time for a real link, device time for the
    /// simulator in process (whose waits take no wall time). Monotonic, from any origin.
    fn now(&self) -> Duration {
        static ORIGIN: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
        ORIGIN.get_or_init(std::time::Instant::now).elapsed()
    }
    /// Whether [`Transport::now`] is the instrument's own clock (the simulator in
    /// process). Otherwise the session reads the device's clock (its uptime in
    /// `GetStatus`) for device time: over a serial port the host's wall clock is not the
    /// device's (the simulator on a pseudo-terminal runs ahead of wall time, a host busy
    /// fitting is not the device working).
    fn now_is_device_time(&self) -> bool {
        false
    }
    /// The first sequence number a new [`Client`] uses, chosen so that it cannot collide
    /// with the numbers of an earlier host process on the same instrument (whose
    /// requests the firmware may still be carrying out or have cached).
    ///
    /// By default the wall clock in milliseconds since 1970 (as u32, so it wraps every
    /// 49.7 days). It grows faster than any host process uses numbers: a host sends one
    /// request and waits for its reply (a USB full-speed device answers in a later 1 ms
    /// frame, so at most one request per millisecond), plus one heartbeat per 200 ms;
    /// an earlier process that started at t₀ ms has therefore used numbers below
    /// t₀ + (its lifetime in ms) ≤ now. A later process starting at `now` is above all
    /// of them (unless one process outlived a wrap of the 49.7-day cycle).
    fn first_seq(&self) -> u32 {
        let ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis());
        (ms as u32).max(1)
    }
}

/// Why a request failed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The byte pipe failed.
    #[error("link I/O error: {0}")]
    Io(#[from] std::io::Error),
    /// The user interrupted the wait (see [`Client::set_interrupt`]).
    #[error("interrupted by the user")]
    Interrupted,
    /// Nothing at all heard from the device for [`RetryPolicy::give_up_after`].
    #[error("nothing heard from the instrument for {:.1} s", silent_for.as_secs_f64())]
    Silent {
        /// How long since the last byte from the device.
        silent_for: Duration,
    },
    /// No reply after every retry (while the device answered other frames). Said in
    /// the user's words: the request's number is the link's bookkeeping (kept here, in the
    /// `Debug` form), not something a user can act on (issue 31).
    #[error("{}", no_reply_text(command, *attempts))]
    NoReply {
        /// The request's sequence number.
        seq: u32,
        /// What it was.
        command: &'static str,
        /// How often it was sent.
        attempts: u32,
    },
    /// The handshake got no intelligible answer in [`HANDSHAKE_ROUNDS`] rounds of
    /// retries, while the device was heard (a link too noisy to start on).
    #[error(
        "no intelligible answer to the handshake after {attempts} attempts over {:.1} s ({garbled} frames arrived garbled): the link is too noisy to start a session on; check the cable and its connectors",
        seconds
    )]
    NoHandshake {
        /// Hellos sent.
        attempts: u32,
        /// How long it was tried, on the transport's clock.
        seconds: f64,
        /// Frames from the device that could not be read meanwhile.
        garbled: u32,
    },
    /// The device refused or failed the request.
    #[error("the instrument refused {command}: {error}")]
    Device {
        /// What it was.
        command: &'static str,
        /// The device's reason.
        error: DeviceError,
    },
    /// The peers speak different protocol versions.
    #[error(
        "protocol version mismatch: this host speaks version {host}, the instrument version {device}; {}",
        version_advice(*host, *device)
    )]
    VersionMismatch {
        /// Our version.
        host: u16,
        /// The device's version.
        device: u16,
    },
    /// A reply of the wrong kind for the request.
    #[error("unexpected reply to {command}: {reply:?}")]
    UnexpectedReply {
        /// What it was.
        command: &'static str,
        /// What came back.
        reply: Box<Reply>,
    },
}

/// What [`LinkError::NoReply`] says: which exchange got no answer, in words.
fn no_reply_text(command: &str, attempts: u32) -> String {
    if command == "Hello" {
        format!(
            "the greeting that opens the link was sent {attempts} times and nothing came back: check that this is the instrument's port (gonio ports lists them), that the instrument is switched on and running its firmware, and that no other program has the port"
        )
    } else {
        format!("the instrument did not answer the {command} command (sent {attempts} times)")
    }
}

fn version_advice(host: u16, device: u16) -> String {
    if device > host {
        "update the host software (gonio) to a release that speaks the instrument's version"
            .to_string()
    } else {
        // The field user has the gonio binary and a debug probe, not the source: say the
        // command that fixes it.
        format!(
            "the instrument's firmware is older than this host: update the instrument's firmware with `gonio flash` (the image of this gonio release, or `gonio flash IMAGE` with a firmware of protocol version {host}; a debug probe on the board's SWD pins)"
        )
    }
}

/// How long the device's commands may take, from what it announced in the handshake
/// (the reference instrument's until then): its motion limits through the firmware's own
/// planner ([`firmware::motion::move_duration_us`]), its homing bound and its heartbeat
/// timeout. Nothing of the device's timing is restated here.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeviceTiming {
    /// The longest move (both arms over the whole working range) and its settling.
    pub longest_move: Duration,
    /// `DeviceInfo::longest_home_ms`.
    pub longest_home: Duration,
    /// `DeviceInfo::heartbeat_timeout_ms`.
    pub heartbeat_timeout: Duration,
    /// The self-test's pulse check ([`protocol::SELF_TEST_PULSE_STEPS`] at the limits).
    pub self_test: Duration,
}

/// The self-test's pulse profile at these limits, µs (0 for limits that make no motion).
fn pulse_check_us(max_speed_deg_per_s: f32, accel_deg_per_s2: f32) -> u64 {
    use firmware::motion::{deg_to_steps, move_duration_us};
    let steps = i32::try_from(protocol::SELF_TEST_PULSE_STEPS).unwrap_or(i32::MAX);
    move_duration_us(
        [0, 0],
        [steps, steps],
        deg_to_steps(max_speed_deg_per_s),
        deg_to_steps(accel_deg_per_s2),
    )
}

impl DeviceTiming {
    /// From the device's handshake. Limits that make no motion (a device that announced a
    /// zero or a non-finite speed) leave the reference instrument's move time.
    pub fn from_info(info: &DeviceInfo) -> DeviceTiming {
        use firmware::motion::{angle_to_steps, deg_to_steps, move_duration_us};
        let (low, high) = (angle_to_steps(info.arm_min), angle_to_steps(info.arm_max));
        let move_us = move_duration_us(
            [low, low],
            [high, high],
            deg_to_steps(info.max_speed_deg_per_s),
            deg_to_steps(info.accel_deg_per_s2),
        );
        let reference = Self::reference();
        let longest_move = if move_us == 0 && high != low {
            reference.longest_move
        } else {
            Duration::from_micros(move_us) + Duration::from_millis(u64::from(info.settle_ms))
        };
        let pulse_us = pulse_check_us(info.max_speed_deg_per_s, info.accel_deg_per_s2);
        DeviceTiming {
            longest_move,
            longest_home: Duration::from_millis(u64::from(info.longest_home_ms)),
            heartbeat_timeout: Duration::from_millis(u64::from(info.heartbeat_timeout_ms)),
            self_test: if pulse_us == 0 {
                reference.self_test
            } else {
                Duration::from_micros(pulse_us)
            },
        }
    }

    /// The reference instrument's (before the handshake).
    pub fn reference() -> DeviceTiming {
        let info = firmware::config::InstrumentConfig::REFERENCE.device_info("");
        let (low, high) = (
            firmware::motion::angle_to_steps(info.arm_min),
            firmware::motion::angle_to_steps(info.arm_max),
        );
        let move_us = firmware::motion::move_duration_us(
            [low, low],
            [high, high],
            firmware::motion::deg_to_steps(info.max_speed_deg_per_s),
            firmware::motion::deg_to_steps(info.accel_deg_per_s2),
        );
        DeviceTiming {
            longest_move: Duration::from_micros(move_us)
                + Duration::from_millis(u64::from(info.settle_ms)),
            longest_home: Duration::from_millis(u64::from(info.longest_home_ms)),
            heartbeat_timeout: Duration::from_millis(u64::from(info.heartbeat_timeout_ms)),
            self_test: Duration::from_micros(pulse_check_us(
                info.max_speed_deg_per_s,
                info.accel_deg_per_s2,
            )),
        }
    }

    /// How long `command` may take on the device beyond a quick answer.
    pub fn expected_duration(&self, command: &Command) -> Duration {
        let ms = |ms: u64| Duration::from_millis(ms);
        match command {
            Command::Home => self.longest_home,
            Command::MoveTo(_) => self.longest_move,
            // Up to one re-take per range.
            Command::TakeReading { integration_ms, .. } => ms(4 * u64::from(*integration_ms)),
            Command::TakeDark { integration_ms } => ms(3 * u64::from(*integration_ms) + 500),
            // Both pulse checks at once, at the limits; twice over for margin.
            Command::SelfTest => 2 * self.self_test + ms(500),
            _ => Duration::ZERO,
        }
    }
}

/// Timing of requests.
#[derive(Clone, Copy, Debug)]
pub struct RetryPolicy {
    /// How long to wait for a reply before sending the request again.
    pub reply_timeout: Duration,
    /// While waiting, a heartbeat goes out when the host has sent nothing for this long,
    /// or for a fifth of the device's heartbeat timeout (`DeviceInfo::heartbeat_timeout_ms`)
    /// if that is shorter.
    pub heartbeat_every: Duration,
    /// How many times a request is sent at most.
    pub attempts: u32,
    /// A device silent this long (not one byte) is given up: every wait ends there.
    pub give_up_after: Duration,
}

/// The bound: a frozen or vanished instrument is given up within 10 s of silence.
/// Five times the firmware's 2 s heartbeat timeout: an outage of a few seconds (a cable
/// pulled and pushed back) is ridden out, a dead instrument is not waited for.
pub(crate) const GIVE_UP_AFTER: Duration = Duration::from_secs(10);

/// Rounds of [`Client::request`]'s retries the handshake makes while the device is heard:
/// at most 16 × 4 sends, 32 s with the default policy. At corrupt 0.01 a round fails with
/// probability ~0.4 (four garbled answers in a row, 0.8⁴; measured: 10 of 30 starts in
/// process, 12 of 30 in issue 30), so 16 fail together with ~4·10⁻⁷; a link worse than that
/// is better refused than measured on (issue 30 D9).
pub const HANDSHAKE_ROUNDS: u32 = 16;

impl Default for RetryPolicy {
    fn default() -> Self {
        RetryPolicy {
            reply_timeout: Duration::from_millis(500),
            heartbeat_every: Duration::from_millis(200),
            attempts: 4,
            give_up_after: GIVE_UP_AFTER,
        }
    }
}

/// Counters of what went wrong on the link, for the session report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Frames from the device that could not be read.
    pub bad_frames: u32,
    /// Requests sent again after a timeout.
    pub retries: u32,
    /// Frames the device reported it could not read.
    pub(crate) rejected_by_device: u32,
}

/// A request/reply client over a [`Transport`].
pub struct Client<T: Transport> {
    transport: T,
    decoder: FrameDecoder,
    next_seq: u32,
    policy: RetryPolicy,
    /// Messages that arrived while waiting for a reply (streamed readings, stops).
    unsolicited: VecDeque<DeviceMessage>,
    stats: LinkStats,
    /// Bytes read from the transport; `rx[rx_pos..rx_len]` are not decoded yet.
    rx: [u8; MAX_FRAME_LEN],
    rx_pos: usize,
    rx_len: usize,
    /// When the host last sent a frame, on the transport's clock.
    last_sent: Duration,
    /// When the last byte from the device arrived, on the transport's clock.
    last_heard: Duration,
    /// Set by a Ctrl-C handler: waiting stops with [`LinkError::Interrupted`].
    interrupt: Option<Arc<AtomicBool>>,
    /// The device's timing, from its last handshake.
    timing: DeviceTiming,
}

pub(crate) fn command_name(command: &Command) -> &'static str {
    match command {
        Command::Hello { .. } => "Hello",
        Command::Heartbeat => "Heartbeat",
        Command::GetStatus => "GetStatus",
        Command::Home => "Home",
        Command::MoveTo(_) => "MoveTo",
        Command::SetLamp { .. } => "SetLamp",
        Command::TakeDark { .. } => "TakeDark",
        Command::TakeReading { .. } => "TakeReading",
        Command::UploadSchedule(_) => "UploadSchedule",
        Command::RunSchedule(_) => "RunSchedule",
        Command::Abort => "Abort",
        Command::Sweep(_) => "Sweep",
        Command::SelfTest => "SelfTest",
    }
}

impl<T: Transport> Client<T> {
    /// A client over `transport`.
    pub fn new(transport: T, policy: RetryPolicy) -> Client<T> {
        let (next_seq, now) = (transport.first_seq(), transport.now());
        Client {
            transport,
            decoder: FrameDecoder::new(),
            next_seq,
            policy,
            unsolicited: VecDeque::new(),
            stats: LinkStats::default(),
            rx: [0; MAX_FRAME_LEN],
            rx_pos: 0,
            rx_len: 0,
            last_sent: Duration::ZERO,
            last_heard: now,
            interrupt: None,
            timing: DeviceTiming::reference(),
        }
    }

    /// The retry policy.
    pub fn policy(&self) -> RetryPolicy {
        self.policy
    }

    /// How long since the device was last heard (any byte), on the transport's clock.
    pub fn silent_for(&self) -> Duration {
        self.transport.now().saturating_sub(self.last_heard)
    }

    /// When the silence reaches [`RetryPolicy::give_up_after`].
    fn give_up_at(&self) -> Duration {
        self.last_heard + self.policy.give_up_after
    }

    /// Forget the messages queued while waiting (after a reconnection or a recovery:
    /// the state they told of has been read afresh).
    pub(crate) fn clear_unsolicited(&mut self) {
        self.unsolicited.clear();
    }

    /// Let `duration` pass on the transport's clock while keeping the instrument alive:
    /// heartbeats go out, and whatever the device sends meanwhile is queued for
    /// [`Client::next_unsolicited`]. Ends early with an error when the link fails, the
    /// device has been silent for [`RetryPolicy::give_up_after`], or on a Ctrl-C.
    pub fn keep_alive(&mut self, duration: Duration) -> Result<(), LinkError> {
        let deadline = self.transport.now() + duration;
        while let Some(message) = self.next_message(deadline)? {
            if !matches!(message, DeviceMessage::Reply { .. }) {
                self.unsolicited.push_back(message);
            }
        }
        Ok(())
    }

    /// The transport, e.g. to inspect a simulator.
    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.transport
    }

    /// The transport.
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// The transport, the client done with.
    pub fn into_transport(self) -> T {
        self.transport
    }

    /// What went wrong on the link so far.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// The device's timing, as its last handshake gave it.
    pub fn timing(&self) -> DeviceTiming {
        self.timing
    }

    /// The interval of heartbeats while waiting: the policy's, or a fifth of the device's
    /// heartbeat timeout if that is shorter (but not under 20 ms, whatever a device says:
    /// a zero would send heartbeats without end).
    fn heartbeat_every(&self) -> Duration {
        self.policy
            .heartbeat_every
            .min(self.timing.heartbeat_timeout / 5)
            .max(Duration::from_millis(20))
    }

    /// Handshake: our protocol version for the device's description (whose timing the
    /// client then waits by).
    ///
    /// The device's answer is the longest frame of the protocol, so a noisy link garbles
    /// it far more often than any other (at 1 % of bytes corrupted, four times in five).
    /// Retried like any request ([`Client::request`]), and then, while the device is heard
    /// at all, for up to [`HANDSHAKE_ROUNDS`] such requests; a device never heard fails as
    /// fast as before ([`LinkError::NoReply`], or [`LinkError::Silent`]).
    pub fn hello(&mut self) -> Result<DeviceInfo, LinkError> {
        let started = self.transport.now();
        let garbled_before = self.stats.bad_frames;
        let mut attempts = 0;
        for _ in 0..HANDSHAKE_ROUNDS {
            match self.hello_once() {
                Err(LinkError::NoReply { attempts: sent, .. }) if self.last_heard > started => {
                    attempts += sent;
                }
                other => return other,
            }
        }
        Err(LinkError::NoHandshake {
            attempts,
            seconds: self.transport.now().saturating_sub(started).as_secs_f64(),
            garbled: self.stats.bad_frames - garbled_before,
        })
    }

    /// One handshake request, with [`Client::request`]'s retries.
    fn hello_once(&mut self) -> Result<DeviceInfo, LinkError> {
        let version_error = |device: u16| LinkError::VersionMismatch {
            host: PROTOCOL_VERSION,
            device,
        };
        match self.request(Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        }) {
            Ok(Reply::Hello(info)) if info.protocol_version == PROTOCOL_VERSION => {
                self.timing = DeviceTiming::from_info(&info);
                Ok(info)
            }
            Ok(Reply::Hello(info)) => Err(version_error(info.protocol_version)),
            Ok(reply) => Err(LinkError::UnexpectedReply {
                command: "Hello",
                reply: Box::new(reply),
            }),
            Err(LinkError::Device { error, .. }) if error.code == ErrorCode::VersionMismatch => {
                Err(version_error(
                    u16::try_from(error.detail).unwrap_or(u16::MAX),
                ))
            }
            Err(other) => Err(other),
        }
    }

    /// Once `flag` is set (`None`: never), send nothing more and stop any wait with
    /// [`LinkError::Interrupted`], so that a Ctrl-C is heard during a long command (homing
    /// takes up to 20 s) and the caller can stop the instrument at once (after clearing it).
    pub(crate) fn set_interrupt(&mut self, flag: Option<Arc<AtomicBool>>) {
        self.interrupt = flag;
    }

    /// Whether the operator interrupted (the flag of [`Client::set_interrupt`] is set).
    pub(crate) fn interrupted(&self) -> bool {
        self.check_interrupt().is_err()
    }

    fn check_interrupt(&self) -> Result<(), LinkError> {
        match &self.interrupt {
            Some(flag) if flag.load(Ordering::Relaxed) => Err(LinkError::Interrupted),
            _ => Ok(()),
        }
    }

    /// Send `command` and wait for its reply, retrying with the same sequence number.
    ///
    /// The request is sent again every [`RetryPolicy::reply_timeout`] until the reply comes,
    /// also while a long command (a homing, a move, a reading) is still being carried
    /// out: the firmware ignores a repeat of the request in progress and answers a repeat
    /// of one already done from its reply cache, so a lost request starts late by one
    /// timeout, and a lost reply is had again as soon as the command is done, instead of
    /// after the longest the command could take. [`RetryPolicy::attempts`] counts the
    /// sends after that longest time: then the request is given up ([`LinkError::NoReply`]).
    pub fn request(&mut self, command: Command) -> Result<Reply, LinkError> {
        let seq = self.take_seq();
        let name = command_name(&command);
        let longest = self.timing.expected_duration(&command);
        let started = self.transport.now();
        let request = Request { seq, command };
        let mut attempts = 0;
        let mut sends = 0u32;
        while attempts < self.policy.attempts {
            if sends > 0 {
                self.stats.retries += 1;
            }
            // Nothing new is started after a Ctrl-C.
            self.check_interrupt()?;
            if self.transport.now() >= started + longest {
                attempts += 1;
            }
            self.send(&request)?;
            sends += 1;
            if let Some(result) = self.wait_for_reply(seq, self.policy.reply_timeout)? {
                return result.map_err(|error| LinkError::Device {
                    command: name,
                    error,
                });
            }
        }
        Err(LinkError::NoReply {
            seq,
            command: name,
            attempts: sends,
        })
    }

    fn take_seq(&mut self) -> u32 {
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1).max(1);
        seq
    }

    fn send(&mut self, request: &Request) -> Result<(), LinkError> {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let frame = protocol::encode_frame(request, &mut buf)
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e.to_string()))?;
        loop {
            match self.transport.write_all(frame) {
                Ok(()) => break,
                // A signal (Ctrl-C's SIGINT among them) cut the system call short: the port
                // is fine. Sent again whole (the firmware drops a repeated request); after a
                // Ctrl-C nothing is sent.
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => self.check_interrupt()?,
                Err(e) => return Err(e.into()),
            }
        }
        self.last_sent = self.transport.now();
        Ok(())
    }

    /// Wait up to `timeout` for the reply to `seq`; other messages are queued.
    fn wait_for_reply(
        &mut self,
        seq: u32,
        timeout: Duration,
    ) -> Result<Option<Result<Reply, DeviceError>>, LinkError> {
        let deadline = self.transport.now() + timeout;
        while let Some(message) = self.next_message(deadline)? {
            match message {
                DeviceMessage::Reply {
                    seq: answered,
                    result,
                } if answered == seq => return Ok(Some(result)),
                // A late duplicate answer to an earlier request: already handled.
                DeviceMessage::Reply { .. } => {}
                other => self.unsolicited.push_back(other),
            }
        }
        Ok(None)
    }

    /// The next message that is not a reply (a streamed reading, a schedule end, a stop),
    /// waiting at most `timeout`.
    pub fn next_unsolicited(
        &mut self,
        timeout: Duration,
    ) -> Result<Option<DeviceMessage>, LinkError> {
        if let Some(message) = self.unsolicited.pop_front() {
            return Ok(Some(message));
        }
        let deadline = self.transport.now() + timeout;
        while let Some(message) = self.next_message(deadline)? {
            if !matches!(message, DeviceMessage::Reply { .. }) {
                return Ok(Some(message));
            }
        }
        Ok(None)
    }

    /// Read until one message is decoded or `deadline` passes. Frames the device reports
    /// it could not read are counted here and not returned. Past the silence deadline
    /// ([`RetryPolicy::give_up_after`] without a byte from the device) the wait ends with
    /// [`LinkError::Silent`].
    fn next_message(&mut self, deadline: Duration) -> Result<Option<DeviceMessage>, LinkError> {
        loop {
            while self.rx_pos < self.rx_len {
                let byte = self.rx[self.rx_pos];
                self.rx_pos += 1;
                match self.decoder.push::<DeviceMessage>(byte) {
                    Some(Ok(DeviceMessage::FrameRejected { .. })) => {
                        self.stats.rejected_by_device += 1
                    }
                    Some(Ok(message)) => return Ok(Some(message)),
                    Some(Err(_)) => self.stats.bad_frames += 1,
                    None => {}
                }
            }
            self.check_interrupt()?;
            let now = self.transport.now();
            let give_up_at = self.give_up_at();
            if now >= give_up_at {
                return Err(LinkError::Silent {
                    silent_for: now - self.last_heard,
                });
            }
            if now >= deadline {
                return Ok(None);
            }
            let heartbeat_due = self.last_sent + self.heartbeat_every();
            if now >= heartbeat_due {
                // Its reply is read and dropped like any answer to an earlier request.
                let seq = self.take_seq();
                self.send(&Request {
                    seq,
                    command: Command::Heartbeat,
                })?;
                continue;
            }
            // Read in chunks (one system call per chunk on a serial port); bytes after a
            // complete frame stay in `rx` for the next call.
            self.rx_len = match self.transport.read(
                &mut self.rx,
                deadline.min(heartbeat_due).min(give_up_at) - now,
            ) {
                Ok(n) => n,
                // A signal cut the wait short (EINTR: a Ctrl-C's SIGINT lands in the poll
                // of a serial read): nothing was read and the link is not lost. The loop's
                // check of the interrupt flag turns a Ctrl-C into `Interrupted`; before,
                // the session took it for a dead port (issue 30 D3).
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => 0,
                Err(e) => return Err(e.into()),
            };
            self.rx_pos = 0;
            if self.rx_len > 0 {
                self.last_heard = self.transport.now();
            }
        }
    }
}
