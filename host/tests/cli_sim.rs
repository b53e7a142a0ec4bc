//! `gonio sim`: the simulated instrument on a pseudo-terminal, reached through the host's
//! serial-port code exactly as a real instrument is.

use host::instrument::link::{Client, RetryPolicy};
use host::instrument::serial::SerialTransport;
use protocol::*;
use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Command as Process, Stdio};
use std::time::Duration;

struct Sim(Child);

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start(args: &[&str]) -> (Sim, String) {
    let mut child = Process::new(env!("CARGO_BIN_EXE_gonio"))
        .arg("sim")
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start gonio sim");
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).expect("first line");
    let path = first.trim().to_owned();
    assert!(path.starts_with("/dev/pts/"), "first line is the device path: {path:?}");
    (Sim(child), path)
}

#[test]
fn a_serial_client_runs_strategy1_on_gonio_sim() {
    let (_sim, path) = start(&["G", "--seed", "4"]);
    // Garbage from another client first: the simulator must shrug it off.
    {
        let mut rogue = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        rogue.write_all(&[0x13, 0x37, 0xff, 0x00, 0x42, 0x00, 0x00, 0x99]).unwrap();
    }
    let policy = RetryPolicy { heartbeat_every: Duration::from_millis(50), ..RetryPolicy::default() };
    let mut client = Client::new(SerialTransport::open(&path).unwrap(), policy);
    assert_eq!(client.hello().unwrap().protocol_version, PROTOCOL_VERSION);
    assert!(matches!(client.request(Command::Home), Ok(Reply::Homed(_))));
    assert!(matches!(client.request(Command::SetLamp { on: true }), Ok(Reply::Ack)));
    let run = RunSchedule { schedule_id: 7, source: ScheduleSource::Strategy1, integration_ms: 100, target: Target::Sample };
    assert!(matches!(client.request(Command::RunSchedule(run)), Ok(Reply::ScheduleStarted { len: 12, .. })));
    let mut readings = 0;
    let done = loop {
        match client.next_unsolicited(Duration::from_secs(10)).unwrap() {
            Some(DeviceMessage::Reading(r)) => {
                assert_eq!((r.schedule_id, r.index), (7, readings));
                readings += 1;
            }
            Some(DeviceMessage::ScheduleDone(done)) => break done,
            other => panic!("unexpected {other:?}"),
        }
    };
    assert_eq!((readings, done.error), (12, None));
    let Ok(Reply::Status(status)) = client.request(Command::GetStatus) else { panic!("status") };
    assert_eq!(status.fault, None, "the device never thought the host was gone");
}

#[test]
fn bad_options_are_refused_before_anything_starts() {
    for args in [&["XX"][..], &["G", "--faults", "drop=3"], &["custom:1,2", "--seed", "1"], &["G", "--acceptance", "-1"]] {
        let out = Process::new(env!("CARGO_BIN_EXE_gonio")).arg("sim").args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?}");
        assert!(out.stdout.is_empty(), "{args:?}: nothing served");
        assert!(String::from_utf8_lossy(&out.stderr).contains("error"), "{args:?}");
    }
}
