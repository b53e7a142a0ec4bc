//! The wire schema cannot change silently (postcard-rpc style): one canonical instance of
//! every message, every variant and every struct on the wire is encoded and compared with
//! the committed golden file `tests/data/golden.hex` (one `name hex` line each).
//!
//! A difference means the encoding changed, so a peer of the previous version would
//! misread it: bump `PROTOCOL_VERSION` (protocol/src/lib.rs) and regenerate with
//!
//! ```text
//! GONIO_BLESS=1 cargo test -p protocol --test it golden
//! ```
//!
//! which refuses to overwrite the file while `PROTOCOL_VERSION` is still the file's
//! version (`GONIO_BLESS=force` does, for adding instances of types whose encoding did not
//! change). Every enum's instances must cover all its variants: a variant added without a
//! golden line fails here too.

use heapless::{String, Vec};
use protocol::*;
use serde::Serialize;
use serde::de::DeserializeOwned;

const GOLDEN: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/golden.hex");
/// How the messages name the file.
const GOLDEN_NAME: &str = "protocol/tests/data/golden.hex";
const BLESS: &str = "GONIO_BLESS=1 cargo test -p protocol --test it golden";

fn bytes<T: Serialize>(value: &T) -> std::vec::Vec<u8> {
    let mut buf = [0u8; 4 * MAX_FRAME_LEN];
    postcard::to_slice(value, &mut buf).expect("fits").to_vec()
}

fn hex(bytes: &[u8]) -> std::string::String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn text<const N: usize>(s: &str) -> String<N> {
    String::try_from(s).unwrap()
}

fn device_info() -> DeviceInfo {
    DeviceInfo {
        protocol_version: 4,
        firmware_version: text("0.1.0"),
        board: text("gonio STM32F411 black pill"),
        arm_min: Angle::from_whole_deg(0),
        arm_max: Angle::from_whole_deg(85),
        arm_resolution: Angle::from_ticks(1),
        collision_min_sum: Angle::from_whole_deg(10),
        max_speed_deg_per_s: 60.0,
        accel_deg_per_s2: 180.0,
        settle_ms: 100,
        detector_ranges: Vec::from_slice(&[
            DetectorRange {
                relative_gain: 1.0,
                full_scale_counts: 65_535,
                time_constant_us: 470.0,
                settle_us: 4_500,
            },
            DetectorRange {
                relative_gain: 0.1,
                full_scale_counts: 65_535,
                time_constant_us: 47.0,
                settle_us: 600,
            },
            DetectorRange {
                relative_gain: 0.01,
                full_scale_counts: 65_535,
                time_constant_us: 4.7,
                settle_us: 150,
            },
        ])
        .unwrap(),
        acceptance_deg: 1.0,
        max_schedule_len: 288,
        default_integration_ms: 100,
        max_integration_ms: 10_000,
        min_integration_ms: 10,
        heartbeat_timeout_ms: 2_000,
        longest_home_ms: 21_500,
        serial_number: text("0123456789ABCDEF01234567"),
        reset_cause: ResetCause::Fault(DeviceError::with_detail(ErrorCode::Panic, 417)),
        detector_block_us: 1_024,
    }
}

fn sweep() -> Sweep {
    Sweep {
        sweep_id: 9,
        theta_i: Angle::from_whole_deg(60),
        from: Angle::from_whole_deg(70),
        to: Angle::from_ticks(-40),
        speed_mdeg_per_s: 60_000,
        bin_ticks: 8,
        range: Some(2),
        target: Target::Sample,
    }
}

fn sweep_bin() -> SweepBin {
    SweepBin {
        sweep_id: 9,
        index: 137,
        start: Angle::from_ticks(4_504),
        end: Angle::from_ticks(4_496),
        mean_counts: 40_123.25,
        std_counts: 101.5,
        blocks: 2,
        range: 2,
        flags: SweepBin::SATURATED | SweepBin::BLANKED,
        device_time_us: 12_345_678,
    }
}

fn reset_causes() -> std::vec::Vec<ResetCause> {
    vec![
        ResetCause::PowerOn,
        ResetCause::ResetPin,
        ResetCause::Software,
        ResetCause::Watchdog,
        ResetCause::Fault(DeviceError::with_detail(
            ErrorCode::ProcessorFault,
            0x0800_1234,
        )),
    ]
}

fn reading() -> Reading {
    Reading {
        mean_counts: 26_214.5,
        std_counts: 13.25,
        samples: 100,
        range: 2,
        integration_ms: 100,
        saturated: false,
    }
}

fn status() -> Status {
    Status {
        state: DeviceState::RunningSchedule,
        position: Geometry::from_whole_deg(45, 45),
        homed_i: true,
        homed_r: true,
        lamp_on: true,
        fault: Some(ErrorCode::HeartbeatLost),
        schedule: Some((7, 3)),
        uptime_us: 123_456_789_012,
    }
}

fn chunk() -> ScheduleChunk {
    ScheduleChunk {
        schedule_id: 3,
        total_len: 40,
        offset: 16,
        geometries: Vec::from_slice(&[
            Geometry::from_whole_deg(20, 0),
            Geometry::new(Angle::from_ticks(-1), Angle::from_ticks(6800)),
        ])
        .unwrap(),
    }
}

fn run() -> RunSchedule {
    RunSchedule {
        schedule_id: 12,
        source: ScheduleSource::Uploaded,
        integration_ms: 250,
        target: Target::WhiteReference,
    }
}

fn commands() -> std::vec::Vec<(&'static str, Command)> {
    vec![
        (
            "hello",
            Command::Hello {
                protocol_version: 2,
            },
        ),
        ("heartbeat", Command::Heartbeat),
        ("get_status", Command::GetStatus),
        ("home", Command::Home),
        (
            "move_to",
            Command::MoveTo(Geometry::new(
                Angle::from_ticks(3600),
                Angle::from_ticks(-40),
            )),
        ),
        ("set_lamp", Command::SetLamp { on: true }),
        (
            "take_dark",
            Command::TakeDark {
                integration_ms: 100,
            },
        ),
        (
            "take_reading_auto",
            Command::TakeReading {
                integration_ms: 100,
                target: Target::Sample,
                range: None,
            },
        ),
        (
            "take_reading_forced",
            Command::TakeReading {
                integration_ms: 300,
                target: Target::WhiteReference,
                range: Some(1),
            },
        ),
        ("upload_schedule", Command::UploadSchedule(chunk())),
        ("run_schedule", Command::RunSchedule(run())),
        ("abort", Command::Abort),
        ("sweep", Command::Sweep(sweep())),
        ("self_test", Command::SelfTest),
    ]
}

fn replies() -> std::vec::Vec<(&'static str, Reply)> {
    vec![
        ("hello", Reply::Hello(device_info())),
        ("ack", Reply::Ack),
        ("status", Reply::Status(status())),
        (
            "homed",
            Reply::Homed(HomeReport {
                step_error_i: Some(-37),
                step_error_r: None,
            }),
        ),
        ("reading", Reply::Reading(reading())),
        (
            "dark",
            Reply::Dark(
                Vec::from_slice(&[
                    reading(),
                    Reading {
                        saturated: true,
                        range: 0,
                        ..reading()
                    },
                ])
                .unwrap(),
            ),
        ),
        (
            "schedule_loaded",
            Reply::ScheduleLoaded {
                schedule_id: 3,
                received: 32,
                total_len: 40,
            },
        ),
        (
            "schedule_started",
            Reply::ScheduleStarted {
                schedule_id: 12,
                len: 12,
            },
        ),
        (
            "sweep",
            Reply::Sweep(SweepPlan {
                bins: 1_100,
                duration_ms: 1_612,
            }),
        ),
        ("self_test", Reply::SelfTest(self_test_report())),
    ]
}

fn self_test_report() -> SelfTestReport {
    let pulses = PulseCheck {
        steps_expected: 4_000,
        steps_counted: 3_999,
        duration_expected_us: 1_166_667,
        duration_measured_us: 1_167_012,
    };
    SelfTestReport {
        hse_expected_hz: 25_000_000,
        hse_measured_hz: Some(24_998_437),
        sysclk_expected_hz: 96_000_000,
        sysclk_measured_hz: None,
        pulses_source: pulses,
        pulses_detector: PulseCheck {
            steps_counted: 4_000,
            ..pulses
        },
        blocks_expected: 1_139,
        blocks_counted: 1_140,
        sample_losses: 2,
        worst_step_late_us: 4,
        step_deadline_us: 12,
        longest_interrupts_off_us: Some(5),
        stack_used_bytes: Some(6_144),
        stack_size_bytes: 106_496,
        switch_source: true,
        switch_detector: false,
        driver_fault_source: false,
        driver_fault_detector: true,
        range_selected: 0,
        range_read_back: Some(255),
        resets_since_power_on: Some(ResetCounts {
            watchdog: 1,
            fault: 2,
            pin: 300,
            software: 0,
        }),
    }
}

fn device_messages() -> std::vec::Vec<(&'static str, DeviceMessage)> {
    let streamed = StreamReading {
        schedule_id: 12,
        index: 5,
        geometry: Geometry::from_whole_deg(45, 45),
        target: Target::Sample,
        reading: reading(),
        device_time_us: 9_876_543,
    };
    vec![
        (
            "reply_ok",
            DeviceMessage::Reply {
                seq: 300,
                result: Ok(Reply::Ack),
            },
        ),
        (
            "reply_err",
            DeviceMessage::Reply {
                seq: 70_000,
                result: Err(DeviceError::with_detail(ErrorCode::OutOfRange, 1)),
            },
        ),
        ("reading", DeviceMessage::Reading(streamed)),
        (
            "schedule_done",
            DeviceMessage::ScheduleDone(ScheduleDone {
                schedule_id: 12,
                readings: 4,
                device_us: 4_500_000,
                error: Some(ErrorCode::HeartbeatLost),
            }),
        ),
        (
            "frame_rejected",
            DeviceMessage::FrameRejected {
                code: ErrorCode::BadCrc,
            },
        ),
        (
            "stopped",
            DeviceMessage::Stopped {
                reason: ErrorCode::HardwareFault,
            },
        ),
        ("sweep_bin", DeviceMessage::SweepBin(sweep_bin())),
        (
            "sweep_done",
            DeviceMessage::SweepDone {
                sweep_id: 9,
                bins: 1_100,
            },
        ),
    ]
}

/// Every golden line: name and encoding.
fn golden_lines() -> std::vec::Vec<(std::string::String, std::vec::Vec<u8>)> {
    let mut lines = std::vec::Vec::new();
    let mut add =
        |name: std::string::String, encoded: std::vec::Vec<u8>| lines.push((name, encoded));
    for (name, command) in commands() {
        add(format!("command.{name}"), bytes(&command));
    }
    for (name, reply) in replies() {
        add(format!("reply.{name}"), bytes(&reply));
    }
    for (name, message) in device_messages() {
        add(format!("device_message.{name}"), bytes(&message));
    }
    add(
        "request".into(),
        bytes(&Request {
            seq: 1_000_000,
            command: Command::MoveTo(Geometry::from_whole_deg(20, 70)),
        }),
    );
    add(
        "request.hello_v1".into(),
        bytes(&Request {
            seq: 1,
            command: Command::Hello {
                protocol_version: 1,
            },
        }),
    );
    add(
        "device_message.version_mismatch".into(),
        bytes(&DeviceMessage::Reply {
            seq: 1,
            result: Err(DeviceError::with_detail(ErrorCode::VersionMismatch, 1)),
        }),
    );
    add("device_info".into(), bytes(&device_info()));
    add("status".into(), bytes(&status()));
    add(
        "status.idle_no_fault".into(),
        bytes(&Status {
            state: DeviceState::Idle,
            fault: None,
            schedule: None,
            ..status()
        }),
    );
    for (i, state) in device_states().into_iter().enumerate() {
        add(format!("device_state.{i}"), bytes(&state));
    }
    add(
        "home_report".into(),
        bytes(&HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(40),
        }),
    );
    add("reading".into(), bytes(&reading()));
    add(
        "detector_range".into(),
        bytes(&DetectorRange {
            relative_gain: 0.1,
            full_scale_counts: 65_535,
            time_constant_us: 47.0,
            settle_us: 600,
        }),
    );
    add("sweep".into(), bytes(&sweep()));
    add(
        "sweep.auto_range".into(),
        bytes(&Sweep {
            range: None,
            ..sweep()
        }),
    );
    add(
        "sweep_plan".into(),
        bytes(&SweepPlan {
            bins: 875,
            duration_ms: 1_600,
        }),
    );
    add("sweep_bin".into(), bytes(&sweep_bin()));
    add(
        "sweep_bin.empty".into(),
        bytes(&SweepBin {
            mean_counts: 0.0,
            std_counts: 0.0,
            blocks: 0,
            flags: SweepBin::EMPTY | SweepBin::BLANKED,
            ..sweep_bin()
        }),
    );
    add("schedule_chunk".into(), bytes(&chunk()));
    add("run_schedule".into(), bytes(&run()));
    add(
        "schedule_source.strategy1".into(),
        bytes(&ScheduleSource::Strategy1),
    );
    add(
        "schedule_source.uploaded".into(),
        bytes(&ScheduleSource::Uploaded),
    );
    add("target.sample".into(), bytes(&Target::Sample));
    add(
        "target.white_reference".into(),
        bytes(&Target::WhiteReference),
    );
    add(
        "device_error".into(),
        bytes(&DeviceError::with_detail(ErrorCode::InvalidArgument, 10)),
    );
    add(
        "error_code.not_supported".into(),
        bytes(&ErrorCode::NotSupported),
    );
    add("error_code.unknown".into(), bytes(&ErrorCode::Unknown(999)));
    add(
        "geometry".into(),
        bytes(&Geometry::new(
            Angle::from_ticks(6840),
            Angle::from_ticks(-6840),
        )),
    );
    for (i, cause) in reset_causes().into_iter().enumerate() {
        add(format!("reset_cause.{i}"), bytes(&cause));
    }
    // The shape of every message as one number (protocol::schema): a change of any type
    // shows here too, and cannot be blessed under the same version.
    add("schema_hash".into(), SCHEMA_HASH.to_le_bytes().to_vec());
    lines
}

fn device_states() -> std::vec::Vec<DeviceState> {
    vec![
        DeviceState::Idle,
        DeviceState::Homing,
        DeviceState::Moving,
        DeviceState::Measuring,
        DeviceState::RunningSchedule,
        DeviceState::Stopped,
        DeviceState::Sweeping,
    ]
}

fn render(lines: &[(std::string::String, std::vec::Vec<u8>)]) -> std::string::String {
    let mut out = format!(
        "# The gonio wire contract: postcard encoding of one canonical instance of every message.\n\
         # Written by protocol/tests/it/golden.rs; regenerate (after bumping PROTOCOL_VERSION) with\n\
         # {BLESS}\n\
         version {PROTOCOL_VERSION}\n"
    );
    for (name, encoded) in lines {
        out.push_str(&format!("{name} {}\n", hex(encoded)));
    }
    out
}

/// The file's version and lines.
fn parse(
    text: &str,
) -> (
    Option<u16>,
    std::vec::Vec<(std::string::String, std::string::String)>,
) {
    let mut version = None;
    let mut lines = std::vec::Vec::new();
    for line in text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
    {
        let (name, value) = line.split_once(' ').unwrap_or((line, ""));
        if name == "version" {
            version = value.trim().parse().ok();
        } else {
            lines.push((name.to_string(), value.trim().to_string()));
        }
    }
    (version, lines)
}

#[test]
fn the_wire_encoding_matches_the_golden_file() {
    let ours = golden_lines();
    let ours_hex: std::vec::Vec<(std::string::String, std::string::String)> =
        ours.iter().map(|(n, b)| (n.clone(), hex(b))).collect();
    let committed = std::fs::read_to_string(GOLDEN).unwrap_or_default();
    let (file_version, theirs) = parse(&committed);
    let changed = theirs != ours_hex;
    match std::env::var("GONIO_BLESS").as_deref() {
        Ok("1") if changed && file_version == Some(PROTOCOL_VERSION) => panic!(
            "the wire encoding changed but PROTOCOL_VERSION is still {PROTOCOL_VERSION}: a peer of version \
             {PROTOCOL_VERSION} would misread it. Bump PROTOCOL_VERSION in protocol/src/lib.rs (and its history), \
             then run {BLESS} again."
        ),
        Ok("1") | Ok("force") => {
            std::fs::write(GOLDEN, render(&ours)).expect("write the golden file");
            eprintln!("wrote {GOLDEN_NAME} for protocol version {PROTOCOL_VERSION}");
            return;
        }
        _ => {}
    }
    let mut differences = std::vec::Vec::new();
    for (name, value) in &ours_hex {
        match theirs.iter().find(|(n, _)| n == name) {
            None => differences.push(format!("  {name}: not in the golden file; now {value}")),
            Some((_, old)) if old != value => {
                differences.push(format!("  {name}:\n    golden {old}\n    now    {value}"))
            }
            Some(_) => {}
        }
    }
    for (name, _) in &theirs {
        if !ours_hex.iter().any(|(n, _)| n == name) {
            differences.push(format!("  {name}: in the golden file, no longer encoded"));
        }
    }
    assert!(
        differences.is_empty() && !changed,
        "the wire encoding differs from {GOLDEN_NAME}:\n{}\nA peer of protocol version {PROTOCOL_VERSION} would misread it. \
         Bump PROTOCOL_VERSION in protocol/src/lib.rs and regenerate with {BLESS}",
        differences.join("\n")
    );
    assert_eq!(
        file_version,
        Some(PROTOCOL_VERSION),
        "PROTOCOL_VERSION is {PROTOCOL_VERSION} but {GOLDEN_NAME} was written for {file_version:?}: regenerate with {BLESS}"
    );
}

/// The variant indices `instances` cover (postcard puts the index first, one byte below
/// 128), and that there is no variant beyond them: decoding the next index with an all-
/// zero body (which any variant's fields accept) fails.
fn assert_all_variants<T: DeserializeOwned>(what: &str, encodings: &[std::vec::Vec<u8>]) {
    let mut indices: std::vec::Vec<u8> = encodings.iter().map(|e| e[0]).collect();
    indices.sort();
    indices.dedup();
    let n = indices.len() as u8;
    assert_eq!(
        indices,
        (0..n).collect::<std::vec::Vec<u8>>(),
        "{what}: golden instances skip a variant"
    );
    let mut next = vec![n];
    next.extend([0u8; 64]);
    assert!(
        postcard::take_from_bytes::<T>(&next).is_err(),
        "{what} has a variant {n} with no golden instance: add one to tests/it/golden.rs, bump PROTOCOL_VERSION and run {BLESS}"
    );
}

#[test]
fn every_variant_has_a_golden_instance() {
    assert_all_variants::<Command>(
        "Command",
        &commands()
            .iter()
            .map(|(_, c)| bytes(c))
            .collect::<std::vec::Vec<_>>(),
    );
    assert_all_variants::<Reply>(
        "Reply",
        &replies()
            .iter()
            .map(|(_, r)| bytes(r))
            .collect::<std::vec::Vec<_>>(),
    );
    assert_all_variants::<DeviceMessage>(
        "DeviceMessage",
        &device_messages()
            .iter()
            .map(|(_, m)| bytes(m))
            .collect::<std::vec::Vec<_>>(),
    );
    assert_all_variants::<DeviceState>(
        "DeviceState",
        &device_states()
            .iter()
            .map(bytes)
            .collect::<std::vec::Vec<_>>(),
    );
    assert_all_variants::<ResetCause>(
        "ResetCause",
        &reset_causes()
            .iter()
            .map(bytes)
            .collect::<std::vec::Vec<_>>(),
    );
    assert_all_variants::<Target>(
        "Target",
        &[bytes(&Target::Sample), bytes(&Target::WhiteReference)],
    );
    assert_all_variants::<ScheduleSource>(
        "ScheduleSource",
        &[
            bytes(&ScheduleSource::Strategy1),
            bytes(&ScheduleSource::Uploaded),
        ],
    );
    // Result (Ok, Err) inside a reply.
    let results: std::vec::Vec<std::vec::Vec<u8>> = device_messages()
        .iter()
        .filter_map(|(_, m)| match m {
            DeviceMessage::Reply { result, .. } => Some(bytes(result)),
            _ => None,
        })
        .collect();
    assert_all_variants::<Result<Reply, DeviceError>>("Result", &results);
}

#[test]
fn hello_and_the_version_refusal_never_change() {
    // Frozen across every version (not only this one's golden file): a peer of any version
    // must be able to say hello and to read the refusal. Bless cannot move these.
    let hello = Request {
        seq: 1,
        command: Command::Hello {
            protocol_version: 1,
        },
    };
    assert_eq!(bytes(&hello), [1, 0, 1]);
    let hello = Request {
        seq: 1,
        command: Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    };
    assert_eq!(&bytes(&hello)[..2], [1, 0]);
    let refusal = DeviceMessage::Reply {
        seq: 1,
        result: Err(DeviceError::with_detail(ErrorCode::VersionMismatch, 1)),
    };
    assert_eq!(bytes(&refusal), [0, 1, 1, 5, 2]);
    // The reply to Hello starts with the device's version, whatever follows.
    let reply = DeviceMessage::Reply {
        seq: 1,
        result: Ok(Reply::Hello(device_info())),
    };
    assert_eq!(&bytes(&reply)[..4], [0, 1, 0, 0]);
    assert_eq!(
        postcard::take_from_bytes::<u16>(&bytes(&reply)[4..])
            .unwrap()
            .0,
        device_info().protocol_version
    );
}
