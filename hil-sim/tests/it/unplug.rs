//! A pulled USB cable, short and long, at random times over many seeds: the simulator
//! takes the link down for exactly the outage asked, and the firmware behind it keeps
//! running when the outage is shorter than its heartbeat timeout and takes its fail-safe
//! stop when it is longer.
//!
//! The host here is a minimal one written against the wire contract (the host crate's
//! client is not a dependency of the simulator): it heartbeats every 200 ms while it can,
//! retries every 100 ms while the cable is out, and says hello again once it is back.

use firmware::hardware::{Arm, Arms};
use hil_sim::scene::SamplePort;
use hil_sim::{SimConfig, SimInstrument, Unplug};
use protocol::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;
use std::sync::Arc;
use std::time::Duration;

/// How often the test host sends a heartbeat while it waits.
const HEARTBEAT_MS: u64 = 200;

struct Host {
    sim: SimInstrument,
    seq: u32,
    decoder: FrameDecoder,
}

#[derive(Debug)]
enum Failure {
    /// The cable is out (a write or a read saw it).
    Unplugged,
    /// No answer within the wait.
    Silent,
    /// The device answered with an error.
    Device(DeviceError),
}

impl Host {
    fn new(sim: SimInstrument) -> Host {
        Host {
            sim,
            seq: 0,
            decoder: FrameDecoder::new(),
        }
    }

    fn send(&mut self, command: Command) -> Result<u32, Failure> {
        self.seq += 1;
        let mut buf = [0u8; MAX_FRAME_LEN];
        let frame = encode_frame(
            &Request {
                seq: self.seq,
                command,
            },
            &mut buf,
        )
        .expect("frame");
        self.sim.write(frame).map_err(|_| Failure::Unplugged)?;
        Ok(self.seq)
    }

    /// Send `command` and wait up to `wait_s` of device time for its reply, heartbeating.
    fn request(&mut self, command: Command, wait_s: f64) -> Result<Reply, Failure> {
        let seq = self.send(command)?;
        let deadline = self.sim.device_time_us() + (wait_s * 1e6) as u64;
        let mut next_heartbeat = self.sim.device_time_us() + HEARTBEAT_MS * 1000;
        let mut buf = [0u8; 256];
        while self.sim.device_time_us() < deadline {
            let n = self
                .sim
                .read(&mut buf, Duration::from_millis(10))
                .map_err(|_| Failure::Unplugged)?;
            for &byte in &buf[..n] {
                if let Some(Ok(DeviceMessage::Reply { seq: got, result })) =
                    self.decoder.push::<DeviceMessage>(byte)
                {
                    if got == seq {
                        return result.map_err(Failure::Device);
                    }
                }
            }
            if self.sim.device_time_us() >= next_heartbeat {
                next_heartbeat += HEARTBEAT_MS * 1000;
                let _ = self.send(Command::Heartbeat)?;
            }
        }
        Err(Failure::Silent)
    }

    fn hello(&mut self) -> DeviceInfo {
        match self.request(
            Command::Hello {
                protocol_version: PROTOCOL_VERSION,
            },
            1.0,
        ) {
            Ok(Reply::Hello(info)) => info,
            other => panic!("hello: {other:?}"),
        }
    }

    fn status(&mut self) -> Status {
        match self.request(Command::GetStatus, 1.0) {
            Ok(Reply::Status(status)) => status,
            other => panic!("status: {other:?}"),
        }
    }

    /// Keep the link alive (a heartbeat every 200 ms, a retry every 100 ms while the cable
    /// is out) until device time `until_s` and the cable is in. Returns whether the cable
    /// was seen out meanwhile.
    fn idle_until(&mut self, until_s: f64) -> bool {
        let mut pulled = false;
        let mut next_send_us = 0;
        while (self.sim.device_time_us() as f64) < until_s * 1e6 || self.sim.is_unplugged() {
            if self.sim.device_time_us() >= next_send_us {
                let wait_ms = if self.send(Command::Heartbeat).is_ok() {
                    HEARTBEAT_MS
                } else {
                    100
                };
                next_send_us = self.sim.device_time_us() + wait_ms * 1000;
            }
            self.sim.advance_ms(1);
            pulled |= self.sim.is_unplugged();
        }
        pulled
    }
}

fn instrument(seed: u64, unplugs: Vec<Unplug>) -> SimInstrument {
    let mut config = SimConfig {
        seed,
        ..SimConfig::default()
    };
    config.faults.unplugs = unplugs;
    SimInstrument::new(SamplePort::new(Arc::new(|_: f64, _: f64| 0.5)), config)
}

/// Homed, lamp on: a device that needs its host (the heartbeat matters).
fn ready(seed: u64, unplugs: Vec<Unplug>) -> Host {
    let mut host = Host::new(instrument(seed, unplugs));
    host.hello();
    assert!(
        matches!(host.request(Command::Home, 60.0), Ok(Reply::Homed(_))),
        "home"
    );
    assert!(matches!(
        host.request(Command::SetLamp { on: true }, 1.0),
        Ok(Reply::Ack)
    ));
    host
}

/// Whole device seconds from now to `seconds` later.
fn now_s(host: &Host) -> f64 {
    host.sim.device_time_us() as f64 * 1e-6
}

#[test]
fn the_cable_is_out_exactly_as_long_as_asked() {
    let mut rng = ChaCha12Rng::seed_from_u64(0x756e_706c);
    for _ in 0..20 {
        let at_s = rng.random_range(0.5..20.0);
        let for_s = rng.random_range(0.01..30.0);
        let mut sim = instrument(1, vec![Unplug::new(at_s, for_s)]);
        let mut out_ms = 0u64;
        let mut first_out_ms = None;
        for ms in 1..=((at_s + for_s) * 1000.0) as u64 + 1000 {
            sim.advance_ms(1);
            if sim.is_unplugged() {
                out_ms += 1;
                first_out_ms.get_or_insert(ms);
            }
        }
        let first = first_out_ms.expect("the cable was pulled") as f64 * 1e-3;
        assert!(
            (first - at_s).abs() <= 0.0015,
            "pulled at {first} s, asked {at_s} s"
        );
        assert!(
            (out_ms as f64 * 1e-3 - for_s).abs() <= 0.0015,
            "out for {out_ms} ms, asked {for_s} s"
        );
    }
}

/// Device time at which `ready` is done for this seed (the simulator is deterministic,
/// so an outage scheduled after it falls on a homed instrument with the lamp on).
fn ready_at_s(seed: u64) -> f64 {
    now_s(&ready(seed, vec![]))
}

/// Heartbeat-timeout check, fault and lamp after a device that was homed with the lamp
/// on had its cable out for `for_s` from a time drawn in the few seconds after `ready`.
fn idle_outage(seed: u64, rng: &mut ChaCha12Rng, for_s: f64) -> Status {
    let at_s = ready_at_s(seed) + rng.random_range(0.05..5.0);
    let mut host = ready(seed, vec![Unplug::new(at_s, for_s)]);
    assert!(
        !host.sim.is_unplugged(),
        "seed {seed}: the outage came before the instrument was ready"
    );
    assert!(
        host.idle_until(at_s + for_s + 0.5),
        "seed {seed}: the cable was never pulled"
    );
    // Back: the device wants a new handshake (the link was reset)...
    assert!(
        matches!(host.request(Command::GetStatus, 1.0), Err(Failure::Device(e)) if e.code == ErrorCode::VersionMismatch),
        "seed {seed}: a replugged device must ask for hello"
    );
    host.hello();
    host.status()
}

#[test]
fn a_short_outage_while_idle_costs_nothing_but_the_handshake() {
    let mut rng = ChaCha12Rng::seed_from_u64(0x7368_6f72);
    for seed in 0..30 {
        // Shorter than the 2 s timeout minus the host's heartbeat period.
        let for_s = rng.random_range(0.02..1.6);
        let status = idle_outage(seed, &mut rng, for_s);
        assert_eq!(status.fault, None, "seed {seed}: out {for_s:.2} s");
        assert!(
            status.lamp_on && status.homed_i && status.homed_r,
            "seed {seed}: out {for_s:.2} s: {status:?}"
        );
    }
}

#[test]
fn a_long_outage_while_idle_takes_the_fail_safe_stop() {
    let mut rng = ChaCha12Rng::seed_from_u64(0x6c6f_6e67);
    for seed in 0..30 {
        // Well past the 2 s timeout: up to two minutes.
        let for_s = rng.random_range(2.3..120.0);
        let status = idle_outage(seed, &mut rng, for_s);
        assert_eq!(
            status.fault,
            Some(ErrorCode::HeartbeatLost),
            "seed {seed}: out {for_s:.2} s"
        );
        assert!(
            !status.lamp_on,
            "seed {seed}: the lamp stays on after a {for_s:.1} s outage"
        );
        // The arms stood still: the stop keeps their homing and leaves the device idle.
        assert_eq!(status.state, DeviceState::Idle, "seed {seed}");
        assert!(
            status.homed_i && status.homed_r,
            "seed {seed}: homing lost at rest"
        );
    }
}

/// Strategy 1 (about 10 s of moves and readings) started on a ready instrument, the
/// cable pulled at a drawn time while it runs: the host and the status once it is back.
fn outage_during_a_schedule(seed: u64, rng: &mut ChaCha12Rng, for_s: f64) -> (Host, Status) {
    let run = RunSchedule {
        schedule_id: 3,
        source: ScheduleSource::Strategy1,
        integration_ms: 100,
        target: Target::Sample,
    };
    let at_s = ready_at_s(seed) + rng.random_range(0.05..6.0);
    let mut host = ready(seed, vec![Unplug::new(at_s, for_s)]);
    assert!(matches!(
        host.request(Command::RunSchedule(run), 1.0),
        Ok(Reply::ScheduleStarted { len: 12, .. })
    ));
    assert!(
        host.idle_until(at_s + 0.01),
        "seed {seed}: the cable was never pulled"
    );
    // Where the arms are once the cable is out and for as long as it is out.
    let mut moved_while_stopped = false;
    let mut stopped_at = None;
    while host.sim.is_unplugged() {
        host.sim.advance_ms(1);
        let still = Arm::BOTH
            .iter()
            .all(|&arm| !host.sim.hardware().is_moving(arm));
        let geometry = host.sim.hardware().mechanics().true_geometry();
        match stopped_at {
            Some(at) if at != geometry => moved_while_stopped = true,
            None if still && !host.sim.hardware().mechanics().lamp_on() => {
                stopped_at = Some(geometry)
            }
            _ => {}
        }
    }
    assert!(
        !moved_while_stopped,
        "seed {seed}: the arms moved after the fail-safe stop"
    );
    host.idle_until(0.0);
    host.hello();
    let status = host.status();
    (host, status)
}

#[test]
fn a_short_outage_during_a_schedule_lets_it_run_on() {
    let mut rng = ChaCha12Rng::seed_from_u64(0x6d6f_7665);
    for seed in 0..10 {
        let for_s = rng.random_range(0.02..1.6);
        let (mut host, status) = outage_during_a_schedule(seed, &mut rng, for_s);
        assert_eq!(status.fault, None, "seed {seed}: out {for_s:.2} s");
        assert!(status.lamp_on, "seed {seed}");
        // The schedule goes on (or is done) without the host having said anything.
        assert!(
            matches!(
                status.state,
                DeviceState::RunningSchedule | DeviceState::Idle
            ),
            "seed {seed}: {status:?}"
        );
        host.idle_until(now_s(&host) + 20.0);
        let status = host.status();
        assert_eq!(
            (status.state, status.fault),
            (DeviceState::Idle, None),
            "seed {seed}"
        );
    }
}

#[test]
fn a_long_outage_during_a_schedule_ends_it_and_stops_the_arms() {
    let mut rng = ChaCha12Rng::seed_from_u64(0x7374_6f70);
    let mut kept = [0usize; 2];
    for seed in 0..10 {
        let for_s = rng.random_range(2.3..60.0);
        let (host, status) = outage_during_a_schedule(seed, &mut rng, for_s);
        assert_eq!(
            status.fault,
            Some(ErrorCode::HeartbeatLost),
            "seed {seed}: out {for_s:.2} s"
        );
        assert_eq!(status.schedule, None, "seed {seed}");
        // A stop mid-move costs the homing (Stopped until homed); one while the arms stood
        // still (integrating, settling) keeps it (Idle).
        let homed = status.homed_i && status.homed_r;
        assert_eq!(
            status.state,
            if homed {
                DeviceState::Idle
            } else {
                DeviceState::Stopped
            },
            "seed {seed}: {status:?}"
        );
        assert!(!status.lamp_on, "seed {seed}");
        assert!(
            Arm::BOTH
                .iter()
                .all(|&arm| !host.sim.hardware().is_moving(arm)),
            "seed {seed}: the arms still move"
        );
        kept[usize::from(homed)] += 1;
    }
    // The drawn moments fall both mid-move and at rest: both rules were exercised.
    assert!(
        kept[0] > 0 && kept[1] > 0,
        "stops mid-move / at rest: {kept:?}"
    );
}

#[test]
fn several_outages_in_one_run_each_come_and_go() {
    let mut rng = ChaCha12Rng::seed_from_u64(0x7477_6963);
    for seed in 0..10 {
        let first_s = ready_at_s(seed) + rng.random_range(0.05..3.0);
        let short_s = rng.random_range(0.02..1.6);
        let second_s = first_s + short_s + rng.random_range(1.0..5.0);
        let long_s = rng.random_range(2.3..30.0);
        let mut host = ready(
            seed,
            vec![Unplug::new(second_s, long_s), Unplug::new(first_s, short_s)],
        );
        assert!(host.idle_until(first_s + short_s + 0.3));
        host.hello();
        assert_eq!(
            host.status().fault,
            None,
            "seed {seed}: the short outage ({short_s:.2} s) tripped the timeout"
        );
        assert!(
            host.idle_until(second_s + long_s + 0.3),
            "seed {seed}: the second outage never came"
        );
        host.hello();
        assert_eq!(
            host.status().fault,
            Some(ErrorCode::HeartbeatLost),
            "seed {seed}: out {long_s:.2} s"
        );
    }
}

#[test]
fn overlapping_outages_are_one_until_the_last_ends() {
    let mut sim = instrument(
        3,
        vec![
            Unplug::new(1.0, 2.0),
            Unplug::new(2.5, 0.1),
            Unplug::new(2.9, 1.1),
        ],
    );
    let mut out = Vec::new();
    for _ in 0..5000 {
        sim.advance_ms(1);
        out.push(sim.is_unplugged());
    }
    let out_ms: usize = out.iter().filter(|o| **o).count();
    let first = out.iter().position(|o| *o).unwrap();
    let last = out.iter().rposition(|o| *o).unwrap();
    assert_eq!(out_ms, last - first + 1, "one outage");
    assert!(
        (first as i64 - 999).abs() <= 1 && (last as i64 - 3999).abs() <= 1,
        "{first}..{last} ms"
    );
}
