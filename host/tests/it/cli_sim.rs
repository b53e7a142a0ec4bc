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
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .expect("first line");
    let path = first.trim().to_owned();
    assert!(
        path.starts_with("/dev/pts/"),
        "first line is the device path: {path:?}"
    );
    (Sim(child), path)
}

#[test]
fn a_serial_client_runs_strategy1_on_gonio_sim() {
    let (_sim, path) = start(&["G", "--seed", "4"]);
    // Garbage from another client first: the simulator must shrug it off.
    {
        let mut rogue = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        rogue
            .write_all(&[0x13, 0x37, 0xff, 0x00, 0x42, 0x00, 0x00, 0x99])
            .unwrap();
    }
    let policy = RetryPolicy {
        heartbeat_every: Duration::from_millis(50),
        ..RetryPolicy::default()
    };
    let mut client = Client::new(SerialTransport::open(&path).unwrap(), policy);
    assert_eq!(client.hello().unwrap().protocol_version, PROTOCOL_VERSION);
    assert!(matches!(client.request(Command::Home), Ok(Reply::Homed(_))));
    assert!(matches!(
        client.request(Command::SetLamp { on: true }),
        Ok(Reply::Ack)
    ));
    let run = RunSchedule {
        schedule_id: 7,
        source: ScheduleSource::Strategy1,
        integration_ms: 100,
        target: Target::Sample,
    };
    assert!(matches!(
        client.request(Command::RunSchedule(run)),
        Ok(Reply::ScheduleStarted { len: 12, .. })
    ));
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
    let Ok(Reply::Status(status)) = client.request(Command::GetStatus) else {
        panic!("status")
    };
    assert_eq!(
        status.fault, None,
        "the device never thought the host was gone"
    );
}

#[test]
fn bad_options_are_refused_before_anything_starts() {
    for args in [
        &["XX"][..],
        &["G", "--faults", "drop=3"],
        &["custom:1,2", "--seed", "1"],
        &["G", "--acceptance", "-1"],
    ] {
        let out = Process::new(env!("CARGO_BIN_EXE_gonio"))
            .arg("sim")
            .args(args)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?}");
        assert!(out.stdout.is_empty(), "{args:?}: nothing served");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("error"),
            "{args:?}"
        );
    }
}

/// `gonio ARGS…` run to the end: exit code and stderr.
fn run_gonio(args: &[&str]) -> (Option<i32>, String, String) {
    let out = Process::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn bad_physics_options_name_the_option_and_the_value_and_exit_non_zero() {
    let dir = std::env::temp_dir().join(format!("gonio-cli-sim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad_table = dir.join("bad.csv");
    std::fs::write(
        &bad_table,
        "theta_i,theta_r,radiance_factor\n20,0,0.5\n20,10,x\n",
    )
    .unwrap();
    let bad_table_arg = bad_table.to_str().unwrap().to_owned();
    let bad_table_message =
        format!("--scene-file {bad_table_arg}:3: radiance_factor 'x' is not a number");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["sim", "G", "--gain-error", "50"],
            "--gain-error must be a percentage in [0, 20], got 50",
        ),
        (
            vec!["sim", "G", "--tile-error", "-1"],
            "--tile-error must be a percentage in [0, 20], got -1",
        ),
        (
            vec!["sim", "SG", "--arm-offset", "nan"],
            "--arm-offset must be between -5 and 5 degrees, got NaN",
        ),
        (
            vec!["sim", "J1", "--sheet-variation", "80"],
            "--sheet-variation must be a percentage in [0, 50], got 80",
        ),
        (
            vec!["sim", "G", "--lobe", "lorentz"],
            "invalid value 'lorentz' for '--lobe",
        ),
        (
            vec!["sim", "MC", "--lobe", "beckmann"],
            "--lobe beckmann does not fit sample 'MC': sigma of a beckmann lobe must be at most 39 degrees",
        ),
        (
            vec!["sim", "G", "--departure", "haze:0.03"],
            "bad --departure 'haze:0.03': haze takes 2 values: haze:FRACTION:SIGMA_DEG",
        ),
        (
            vec!["sim", "G", "--faults", "unplug-at=5:0"],
            "bad fault 'unplug-at=5:0' in --faults",
        ),
        (
            vec!["sim", "replay", "--scene-file", &bad_table_arg],
            &bad_table_message,
        ),
        (
            vec!["sim", "replay", "--scene-file", "/nonexistent/scene.csv"],
            "--scene-file /nonexistent/scene.csv: cannot read",
        ),
        (
            vec!["sim", "G", "--lobe", "ggx", "--scene-file", &bad_table_arg],
            "--lobe does not apply with --scene-file",
        ),
        (
            vec![
                "measure",
                "--spots",
                "1",
                "--sim",
                "G",
                "--forward-lobe",
                "-2",
            ],
            "--forward-lobe must be a radiance factor in [0, 100], got -2",
        ),
        (
            vec![
                "measure",
                "--spots",
                "1",
                "--sim",
                "PPC",
                "--lamp-drift-pct-per-h",
                "1e6",
            ],
            "--lamp-drift-pct-per-h must be a percentage per hour in [0, 100], got 1000000",
        ),
    ];
    for (args, expected) in cases {
        let (code, stdout, stderr) = run_gonio(&args);
        assert!(matches!(code, Some(c) if c != 0), "{args:?}: exit {code:?}");
        assert!(
            stdout.is_empty(),
            "{args:?}: nothing served or measured: {stdout}"
        );
        assert!(
            stderr.contains(expected),
            "{args:?}: {stderr:?} should say {expected:?}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn gonio_sim_serves_a_realistic_sheet() {
    let (_sim, path) = start(&[
        "J2",
        "--seed",
        "8",
        "--physics",
        "real",
        "--lobe",
        "cauchy",
        "--specular-bump",
        "0.1",
        "--sheet-variation",
        "5",
    ]);
    let policy = RetryPolicy {
        heartbeat_every: Duration::from_millis(50),
        ..RetryPolicy::default()
    };
    let mut client = Client::new(SerialTransport::open(&path).unwrap(), policy);
    client.hello().unwrap();
    assert!(matches!(client.request(Command::Home), Ok(Reply::Homed(_))));
    assert!(matches!(
        client.request(Command::SetLamp { on: true }),
        Ok(Reply::Ack)
    ));
    let Ok(Reply::Reading(r)) = client.request(Command::TakeReading {
        integration_ms: 100,
        target: Target::Sample,
        range: None,
    }) else {
        panic!("reading")
    };
    assert!(r.mean_counts > 0.0 && !r.saturated, "{r:?}");
}

#[test]
fn a_lost_heartbeat_does_not_stop_the_instrument_over_the_pseudo_terminal() {
    // Issue 30: the simulator's clock ran up to 1.5 s of device time ahead of the last bytes
    // from the host, so heartbeats sent 200 ms apart reached the firmware 1.5 s apart and a
    // single dropped one made its 2 s heartbeat timeout: fail-safe stops over the
    // pseudo-terminal on links that cost none in process. Now the clock leads the last
    // frame the firmware heard, as its timeout does.
    let (_sim, path) = start(&["G", "--seed", "5", "--faults", "drop=0.25"]);
    let mut client = Client::new(
        SerialTransport::open(&path).unwrap(),
        RetryPolicy::default(),
    );
    client.hello().expect("handshake");
    assert!(matches!(
        client.request(Command::SetLamp { on: true }),
        Ok(Reply::Ack)
    ));
    // Six seconds of heartbeats alone, some dropped; the lamp on, so the firmware needs them.
    let mut stops = 0;
    let until = std::time::Instant::now() + Duration::from_secs(6);
    while std::time::Instant::now() < until {
        if let Some(DeviceMessage::Stopped { reason }) = client
            .next_unsolicited(Duration::from_millis(500))
            .expect("link")
        {
            assert_eq!(reason, ErrorCode::HeartbeatLost);
            stops += 1;
        }
    }
    let status = loop {
        match client.request(Command::GetStatus) {
            Ok(Reply::Status(status)) => break status,
            Ok(other) => panic!("{other:?}"),
            Err(host::instrument::link::LinkError::NoReply { .. }) => continue,
            Err(other) => panic!("{other}"),
        }
    };
    assert_eq!(stops, 0, "fail-safe stops for lost heartbeats");
    assert!(status.lamp_on && status.fault.is_none(), "{status:?}");
}

/// Issue 31: the help printed `[`REAL_PHYSICS`]`, a doc comment's link to the code. No
/// subcommand's help shows rustdoc's link syntax.
#[test]
fn the_help_text_shows_no_rustdoc_links() {
    for subcommand in ["measure", "sim", "selftest", "characterize", "trade", "fit"] {
        let out = crate::cli_support::gonio(&[subcommand, "--help"]);
        let help = String::from_utf8_lossy(&out.stdout);
        assert!(
            !help.contains("[`") && !help.contains("`]"),
            "gonio {subcommand} --help:\n{help}"
        );
    }
}
