//! A bench for the firmware library: the device on fake hardware and a virtual clock,
//! talked to through the real framing, polled every millisecond like the board does.
#![allow(dead_code)]

use firmware::Device;
use firmware::config::InstrumentConfig;
use firmware::hardware::ResetCause;
use firmware::testing::{FakeHardware, Scene};
use protocol::*;

/// A scene as a plain function: signal counts on the most sensitive range at (θi, θr)°.
pub type SceneFn = fn(f32, f32) -> f32;
pub type Hw = FakeHardware<SceneFn>;

/// The white tile at θi = 20° reads 40 % of full scale on the most sensitive range.
pub fn counts_for_radiance_factor(radiance_factor: f32, theta_i_deg: f32) -> f32 {
    let cos = |deg: f32| (deg * core::f32::consts::PI / 180.0).cos();
    0.4 * 65_535.0 * radiance_factor / 0.99 * cos(theta_i_deg) / cos(20.0)
}

/// Like the glossy paper G: diffuse 0.855 plus a specular peak of radiance factor 58 with
/// σ = 0.8°, so the specular readings need the least sensitive range.
pub fn glossy_scene(theta_i_deg: f32, theta_r_deg: f32) -> f32 {
    let half = (theta_i_deg - theta_r_deg) / 2.0;
    let radiance_factor = 0.855 + 58.0 * (-(half * half) / (2.0 * 0.8 * 0.8)).exp();
    counts_for_radiance_factor(radiance_factor, theta_i_deg)
}

/// The bench, over fake hardware seeing the scene `S` (a plain function by default).
pub struct Bench<S: Scene = SceneFn> {
    pub device: Device<FakeHardware<S>>,
    pub now_us: u64,
    next_seq: u32,
    /// Everything the device sent, in order.
    pub messages: Vec<DeviceMessage>,
    decoder: FrameDecoder,
    /// Send a heartbeat every this many ms while waiting (None: stay silent).
    pub heartbeat_every_ms: Option<u64>,
}

pub fn frame(request: &Request) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    encode_frame(request, &mut buf).unwrap().to_vec()
}

impl Bench<SceneFn> {
    /// The reference device on fake hardware, arms at (30°, 30°), handshake done.
    pub fn new() -> Bench {
        Bench::with_scene(glossy_scene)
    }

    pub fn with_scene(scene: SceneFn) -> Bench {
        Bench::seeing(scene)
    }
}

impl<S: Scene> Bench<S> {
    /// The reference device on fake hardware seeing `scene`, arms at (30°, 30°), handshake
    /// done.
    pub fn seeing(scene: S) -> Bench<S> {
        let config = InstrumentConfig::REFERENCE;
        let hardware = FakeHardware::new(&config, scene, Geometry::from_whole_deg(30, 30));
        Bench::with_hardware(hardware, ResetCause::PowerOn)
    }

    pub fn with_hardware(hardware: FakeHardware<S>, reset_cause: ResetCause) -> Bench<S> {
        let device = Device::new(InstrumentConfig::REFERENCE, hardware, reset_cause);
        let mut bench = Bench {
            device,
            now_us: 0,
            next_seq: 1,
            messages: Vec::new(),
            decoder: FrameDecoder::new(),
            heartbeat_every_ms: Some(500),
        };
        let hello = bench.ask(Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        });
        assert!(matches!(hello, Ok(Reply::Hello(_))));
        bench
    }

    pub fn hw(&self) -> &FakeHardware<S> {
        self.device.hardware()
    }

    pub fn hw_mut(&mut self) -> &mut FakeHardware<S> {
        self.device.hardware_mut()
    }

    fn collect(&mut self, bytes: &[u8]) {
        let messages = &mut self.messages;
        self.decoder
            .feed(bytes, |r: Result<DeviceMessage, FrameError>| {
                messages.push(r.expect("valid frame"))
            });
    }

    /// Send raw bytes now.
    pub fn send_bytes(&mut self, bytes: &[u8]) {
        let mut out = Vec::new();
        self.device
            .receive(bytes, self.now_us, &mut |f: &[u8]| out.extend_from_slice(f));
        self.collect(&out);
    }

    /// Send a request with a fresh sequence number; returns it.
    pub fn send(&mut self, command: Command) -> u32 {
        let seq = self.next_seq;
        self.next_seq += 1;
        self.send_bytes(&frame(&Request { seq, command }));
        seq
    }

    /// One millisecond of virtual time.
    pub fn tick(&mut self) {
        self.now_us += 1000;
        if let Some(every) = self.heartbeat_every_ms {
            if self.now_us.is_multiple_of(every * 1000) {
                self.send(Command::Heartbeat);
            }
        }
        let now = self.now_us;
        self.device.hardware_mut().advance_to(now);
        let mut out = Vec::new();
        self.device
            .poll(now, &mut |f: &[u8]| out.extend_from_slice(f));
        self.collect(&out);
    }

    pub fn run_ms(&mut self, ms: u64) {
        for _ in 0..ms {
            self.tick();
        }
    }

    /// The reply to `seq`, if it came.
    pub fn reply(&self, seq: u32) -> Option<Result<Reply, DeviceError>> {
        self.replies(seq).into_iter().next()
    }

    /// Every reply to `seq`.
    pub fn replies(&self, seq: u32) -> Vec<Result<Reply, DeviceError>> {
        self.messages
            .iter()
            .filter_map(|m| match m {
                DeviceMessage::Reply { seq: s, result } if *s == seq => Some(result.clone()),
                _ => None,
            })
            .collect()
    }

    /// Run until the reply to `seq` (at most a minute of virtual time).
    pub fn wait_reply(&mut self, seq: u32) -> Result<Reply, DeviceError> {
        for _ in 0..60_000 {
            if let Some(reply) = self.reply(seq) {
                return reply;
            }
            self.tick();
        }
        panic!("no reply to {seq}")
    }

    /// Send a command with a sequence number of the caller's choice (another host
    /// process, a retry) and wait for a reply to it that arrives after it was sent.
    pub fn ask_as(&mut self, seq: u32, command: Command) -> Result<Reply, DeviceError> {
        let from = self.messages.len();
        self.send_bytes(&frame(&Request { seq, command }));
        for _ in 0..60_000 {
            let answered = self.messages[from..].iter().find_map(|m| match m {
                DeviceMessage::Reply { seq: s, result } if *s == seq => Some(result.clone()),
                _ => None,
            });
            if let Some(result) = answered {
                return result;
            }
            self.tick();
        }
        panic!("no reply to {seq}")
    }

    /// Messages from index `from` on.
    pub fn messages_since(&self, from: usize) -> &[DeviceMessage] {
        &self.messages[from..]
    }

    /// Run until the arms have stopped and the device is idle or stopped (at most a minute).
    pub fn wait_at_rest(&mut self) {
        for _ in 0..60_000 {
            let moving = firmware::Arms::is_moving(self.hw(), firmware::Arm::Source)
                || firmware::Arms::is_moving(self.hw(), firmware::Arm::Detector);
            if !moving && self.device.is_idle() {
                return;
            }
            self.tick();
        }
        panic!("arms never at rest")
    }

    /// Send a command and wait for its reply.
    pub fn ask(&mut self, command: Command) -> Result<Reply, DeviceError> {
        let seq = self.send(command);
        self.wait_reply(seq)
    }

    /// Run until the device is idle (at most a minute).
    pub fn wait_idle(&mut self) {
        for _ in 0..60_000 {
            if self.device.is_idle() {
                return;
            }
            self.tick();
        }
        panic!("device never idle")
    }

    pub fn status(&mut self) -> Status {
        match self.ask(Command::GetStatus) {
            Ok(Reply::Status(status)) => status,
            other => panic!("no status: {other:?}"),
        }
    }

    pub fn home(&mut self) -> HomeReport {
        match self.ask(Command::Home) {
            Ok(Reply::Homed(report)) => report,
            other => panic!("homing failed: {other:?}"),
        }
    }

    /// Streamed readings of a schedule, in order.
    pub fn streamed(&self, schedule_id: u16) -> Vec<StreamReading> {
        self.messages
            .iter()
            .filter_map(|m| match m {
                DeviceMessage::Reading(r) if r.schedule_id == schedule_id => Some(*r),
                _ => None,
            })
            .collect()
    }

    pub fn schedule_done(&self, schedule_id: u16) -> Option<ScheduleDone> {
        self.messages.iter().find_map(|m| match m {
            DeviceMessage::ScheduleDone(d) if d.schedule_id == schedule_id => Some(*d),
            _ => None,
        })
    }

    /// Run until the schedule is done (at most two minutes).
    pub fn wait_schedule(&mut self, schedule_id: u16) -> ScheduleDone {
        for _ in 0..120_000 {
            if let Some(done) = self.schedule_done(schedule_id) {
                return done;
            }
            self.tick();
        }
        panic!("schedule {schedule_id} never done")
    }

    pub fn stopped_reasons(&self) -> Vec<ErrorCode> {
        self.messages
            .iter()
            .filter_map(|m| match m {
                DeviceMessage::Stopped { reason } => Some(*reason),
                _ => None,
            })
            .collect()
    }
}
