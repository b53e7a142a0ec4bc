//! The handshake and the link rules, through the firmware library's byte interface:
//! exactly what the board and the simulator run.

use firmware::config::InstrumentConfig;
use firmware::hardware::ResetCause;
use firmware::testing::{ConstantScene, FakeHardware};
use protocol::*;

type Device = firmware::Device<FakeHardware<ConstantScene>>;

fn new_device() -> Device {
    let config = InstrumentConfig::REFERENCE;
    let hardware = FakeHardware::new(
        &config,
        ConstantScene(0.0),
        Geometry::from_whole_deg(30, 30),
    );
    firmware::Device::new(config, hardware, ResetCause::PowerOn)
}

fn frame(request: &Request) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    encode_frame(request, &mut buf).unwrap().to_vec()
}

/// Send bytes to the device and decode everything it sends back.
fn exchange(device: &mut Device, bytes: &[u8]) -> Vec<DeviceMessage> {
    let mut out = Vec::new();
    device.receive(bytes, 0, &mut |f: &[u8]| out.extend_from_slice(f));
    let mut decoder: FrameDecoder = FrameDecoder::new();
    let mut messages = Vec::new();
    decoder.feed(&out, |r: Result<DeviceMessage, FrameError>| {
        messages.push(r.expect("device frames are valid"))
    });
    messages
}

fn ask(device: &mut Device, seq: u32, command: Command) -> Result<Reply, DeviceError> {
    match exchange(device, &frame(&Request { seq, command })).as_slice() {
        [
            DeviceMessage::Reply {
                seq: answered,
                result,
            },
        ] => {
            assert_eq!(*answered, seq);
            result.clone()
        }
        other => panic!("expected one reply, got {other:?}"),
    }
}

#[test]
fn hello_answers_device_info() {
    let mut device = new_device();
    let Ok(Reply::Hello(info)) = ask(
        &mut device,
        1,
        Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    ) else {
        panic!("no device info")
    };
    assert_eq!(info.protocol_version, PROTOCOL_VERSION);
    assert_eq!(info.firmware_version.as_str(), firmware::FIRMWARE_VERSION);
    assert_eq!(info.arm_min, Angle::from_whole_deg(0));
    assert_eq!(info.arm_max, Angle::from_whole_deg(85));
    assert_eq!(info.arm_resolution.deg(), 0.0125);
    assert_eq!(info.collision_min_sum, Angle::from_whole_deg(10));
    assert_eq!(info.detector_ranges.len(), 3);
    assert_eq!(info.acceptance_deg, 1.0);
    assert!(usize::from(info.max_schedule_len) >= 284);
    assert!(device.handshake_done());
}

#[test]
fn version_mismatch_is_refused_and_blocks_the_session() {
    let mut device = new_device();
    let refused = ask(
        &mut device,
        1,
        Command::Hello {
            protocol_version: PROTOCOL_VERSION + 1,
        },
    );
    assert_eq!(
        refused,
        Err(DeviceError::with_detail(
            ErrorCode::VersionMismatch,
            i32::from(PROTOCOL_VERSION)
        ))
    );
    assert_eq!(device.take_refused_version(), Some(PROTOCOL_VERSION + 1));
    // Nothing else is served until a matching hello.
    assert_eq!(
        ask(&mut device, 2, Command::GetStatus).unwrap_err().code,
        ErrorCode::VersionMismatch
    );
    assert!(matches!(
        ask(
            &mut device,
            3,
            Command::Hello {
                protocol_version: PROTOCOL_VERSION
            }
        ),
        Ok(Reply::Hello(_))
    ));
    assert!(matches!(
        ask(&mut device, 4, Command::GetStatus),
        Ok(Reply::Status(_))
    ));
}

#[test]
fn repeated_sequence_number_is_answered_from_the_cache() {
    let mut device = new_device();
    ask(
        &mut device,
        1,
        Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    )
    .unwrap();
    let first = exchange(
        &mut device,
        &frame(&Request {
            seq: 2,
            command: Command::GetStatus,
        }),
    );
    // The retry carries a different command body only if the host is broken; the device
    // must answer the sequence it already answered, identically, without acting again.
    let again = exchange(
        &mut device,
        &frame(&Request {
            seq: 2,
            command: Command::GetStatus,
        }),
    );
    assert_eq!(first, again);
    let next = exchange(
        &mut device,
        &frame(&Request {
            seq: 3,
            command: Command::GetStatus,
        }),
    );
    assert_eq!(next.len(), 1);
}

#[test]
fn bad_frames_are_reported_and_the_link_recovers() {
    let mut device = new_device();
    let mut corrupted = frame(&Request {
        seq: 1,
        command: Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    });
    corrupted[2] ^= 0x40;
    let messages = exchange(&mut device, &corrupted);
    assert_eq!(messages.len(), 1);
    assert!(matches!(
        messages[0],
        DeviceMessage::FrameRejected {
            code: ErrorCode::BadCrc | ErrorCode::BadFrame
        }
    ));
    let over_long = vec![0x55u8; 3 * MAX_FRAME_LEN];
    let mut stream = over_long;
    stream.push(0);
    stream.extend(frame(&Request {
        seq: 2,
        command: Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    }));
    let messages = exchange(&mut device, &stream);
    assert_eq!(
        messages[0],
        DeviceMessage::FrameRejected {
            code: ErrorCode::FrameTooLong
        }
    );
    assert!(matches!(
        &messages[1],
        DeviceMessage::Reply {
            seq: 2,
            result: Ok(Reply::Hello(_))
        }
    ));
    assert_eq!(messages.len(), 2);
}

#[test]
fn reconnect_requires_a_new_hello() {
    let mut device = new_device();
    ask(
        &mut device,
        1,
        Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    )
    .unwrap();
    device.disconnected();
    assert_eq!(
        ask(&mut device, 2, Command::GetStatus).unwrap_err().code,
        ErrorCode::VersionMismatch
    );
}

#[test]
fn every_reply_of_the_reference_device_fits_a_frame() {
    let info = InstrumentConfig::REFERENCE.device_info("");
    let mut buf = [0u8; MAX_FRAME_LEN];
    let message = DeviceMessage::Reply {
        seq: u32::MAX,
        result: Ok(Reply::Hello(info)),
    };
    assert!(encode_frame(&message, &mut buf).is_ok());
}
