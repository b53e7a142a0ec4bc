//! The host waits by the device's own timing (issue 15): move times from the firmware's
//! planner, the homing bound and the heartbeat timeout from the handshake, never restated.

use firmware::config::InstrumentConfig;
use firmware::motion::{angle_to_steps, deg_to_steps, move_duration_us};
use host::instrument::link::{Client, DeviceTiming, RetryPolicy, Transport};
use protocol::*;
use std::time::Duration;

#[test]
fn the_timing_is_the_firmwares() {
    let config = InstrumentConfig::REFERENCE;
    let info = config.device_info("");
    let timing = DeviceTiming::from_info(&info);
    assert_eq!(timing, DeviceTiming::reference());
    let (low, high) = (
        angle_to_steps(config.arm_min),
        angle_to_steps(config.arm_max),
    );
    let planned = move_duration_us(
        [low, low],
        [high, high],
        deg_to_steps(config.max_speed_deg_per_s),
        deg_to_steps(config.accel_deg_per_s2),
    );
    assert_eq!(
        timing.longest_move,
        Duration::from_micros(planned) + Duration::from_millis(u64::from(config.settle_ms))
    );
    assert_eq!(
        timing.longest_home.as_millis() as u64,
        firmware::homing::longest_homing_us(&config).div_ceil(1000)
    );
    assert_eq!(timing.heartbeat_timeout, Duration::from_millis(2000));
    assert_eq!(
        timing.expected_duration(&Command::Home),
        timing.longest_home
    );
    assert_eq!(
        timing.expected_duration(&Command::MoveTo(Geometry::from_whole_deg(20, 20))),
        timing.longest_move
    );
    // A slower device is waited for longer; one that announced no motion keeps the reference.
    let slow = DeviceTiming::from_info(&DeviceInfo {
        max_speed_deg_per_s: 6.0,
        ..info.clone()
    });
    assert!(slow.longest_move > 5 * timing.longest_move);
    let broken = DeviceTiming::from_info(&DeviceInfo {
        max_speed_deg_per_s: f32::NAN,
        accel_deg_per_s2: 0.0,
        ..info
    });
    assert_eq!(broken.longest_move, timing.longest_move);
}

/// A device on a virtual clock that announces `heartbeat_timeout_ms` and records when each
/// heartbeat arrives.
struct Device {
    now: Duration,
    heartbeat_timeout_ms: u32,
    decoder: FrameDecoder,
    out: Vec<u8>,
    heartbeats: Vec<Duration>,
}

impl Transport for Device {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let mut requests = Vec::new();
        self.decoder.feed(bytes, |r: Result<Request, FrameError>| {
            requests.push(r.expect("a valid request"))
        });
        for request in requests {
            let result = match request.command {
                Command::Hello { .. } => {
                    let info = InstrumentConfig::REFERENCE.device_info("T");
                    Ok(Reply::Hello(DeviceInfo {
                        heartbeat_timeout_ms: self.heartbeat_timeout_ms,
                        ..info
                    }))
                }
                Command::Heartbeat => {
                    self.heartbeats.push(self.now);
                    Ok(Reply::Ack)
                }
                _ => Ok(Reply::Ack),
            };
            let mut buf = [0u8; MAX_FRAME_LEN];
            self.out.extend_from_slice(
                encode_frame(
                    &DeviceMessage::Reply {
                        seq: request.seq,
                        result,
                    },
                    &mut buf,
                )
                .unwrap(),
            );
        }
        Ok(())
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        if self.out.is_empty() {
            self.now += timeout;
            return Ok(0);
        }
        let n = buf.len().min(self.out.len());
        buf[..n].copy_from_slice(&self.out[..n]);
        self.out.drain(..n);
        Ok(n)
    }

    fn pause(&mut self, duration: Duration) {
        self.now += duration;
    }

    fn now(&self) -> Duration {
        self.now
    }
}

fn longest_heartbeat_gap(heartbeat_timeout_ms: u32) -> Duration {
    let device = Device {
        now: Duration::ZERO,
        heartbeat_timeout_ms,
        decoder: FrameDecoder::new(),
        out: Vec::new(),
        heartbeats: Vec::new(),
    };
    let mut client = Client::new(device, RetryPolicy::default());
    client.hello().expect("hello");
    client
        .keep_alive(Duration::from_secs(3))
        .expect("kept alive");
    let beats = &client.transport().heartbeats;
    assert!(beats.len() > 5, "{} heartbeats", beats.len());
    beats.windows(2).map(|w| w[1] - w[0]).max().unwrap()
}

#[test]
fn heartbeats_keep_within_the_devices_timeout() {
    // The reference's 2 s: the policy's 200 ms.
    assert!(longest_heartbeat_gap(2000) <= Duration::from_millis(200));
    // A device that stops after 300 ms of silence hears from the host every 60 ms.
    assert!(longest_heartbeat_gap(300) <= Duration::from_millis(60));
    // A device that says 0 does not get a flood (at most one per 20 ms).
    let gap = longest_heartbeat_gap(0);
    assert!(
        gap >= Duration::from_millis(20) && gap <= Duration::from_millis(25),
        "{gap:?}"
    );
}
