//! The link across host processes: `Hello` starts a fresh link (the reply cache of an
//! earlier host never answers a new one), a USB reset forgets the cache, and a command
//! this version cannot read is answered `NotSupported` under its own sequence number.

use crate::common;

use common::{Bench, frame};
use firmware::link::{Incoming, Link};
use protocol::*;

fn hello() -> Command {
    Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    }
}

/// A frame holding `payload` with its correct CRC (a message of some other version).
fn crc_frame(payload: &[u8]) -> Vec<u8> {
    let mut raw = payload.to_vec();
    raw.extend(framing::CRC.checksum(payload).to_le_bytes());
    let mut out = vec![0u8; raw.len() + raw.len() / 254 + 2];
    let n = cobs_encode(&raw, &mut out);
    out.truncate(n);
    out.push(0);
    out
}

/// COBS encoding, written out (the test must not lean on the decoder it checks).
fn cobs_encode(raw: &[u8], out: &mut [u8]) -> usize {
    let mut code_at = 0;
    let mut code = 1u8;
    let mut n = 1;
    for &byte in raw {
        if byte == 0 {
            out[code_at] = code;
            code_at = n;
            n += 1;
            code = 1;
        } else {
            out[n] = byte;
            n += 1;
            code += 1;
            if code == 0xff {
                out[code_at] = code;
                code_at = n;
                n += 1;
                code = 1;
            }
        }
    }
    out[code_at] = code;
    n
}

#[test]
fn a_new_host_starting_again_at_seq_1_is_not_answered_from_the_old_hosts_cache() {
    // Host process A: Hello at seq 1 (the bench's), Home at seq 2; then A exits and the
    // cached reply to its seq 2 (Homed) stays in the device. No USB reset (a pty, a hub).
    let mut bench = Bench::new();
    assert!(matches!(
        bench.ask_as(2, Command::Home),
        Ok(Reply::Homed(_))
    ));
    // Host process B starts again at seq 1.
    assert!(
        matches!(bench.ask_as(1, hello()), Ok(Reply::Hello(_))),
        "a real Hello reply"
    );
    let target = Geometry::from_whole_deg(40, 20);
    assert_eq!(
        bench.ask_as(2, Command::MoveTo(target)),
        Ok(Reply::Ack),
        "B's seq 2 is carried out, not A's reply"
    );
    bench.wait_at_rest();
    assert_eq!(bench.hw().true_geometry(), target);
}

#[test]
fn a_hello_refused_to_an_old_host_is_not_replayed_to_a_new_one() {
    // Host A speaks an older version: its Hello at seq 1 is refused. Host B (this version)
    // starts again at seq 1 on the same port: its Hello must be carried out, not answered
    // with A's refusal, and B's next command served.
    let mut bench = Bench::new();
    assert!(matches!(
        bench.ask_as(9, Command::Home),
        Ok(Reply::Homed(_))
    ));
    let old = Command::Hello {
        protocol_version: PROTOCOL_VERSION - 1,
    };
    assert_eq!(
        bench.ask_as(1, old).unwrap_err().code,
        ErrorCode::VersionMismatch
    );
    let Ok(Reply::Hello(info)) = bench.ask_as(1, hello()) else {
        panic!("B was refused with A's answer")
    };
    assert_eq!(info.protocol_version, PROTOCOL_VERSION);
    assert!(matches!(
        bench.ask_as(2, Command::GetStatus),
        Ok(Reply::Status(_))
    ));
}

#[test]
fn hello_after_a_usb_reset_starts_the_session() {
    // A's Hello (seq 1) may sit in the cache; the cable is pulled and B says Hello at seq 1:
    // it must be carried out (handshake done), so that B's next command is served.
    let mut bench = Bench::new();
    bench.device.disconnected();
    assert_eq!(
        bench.ask_as(2, Command::GetStatus).unwrap_err().code,
        ErrorCode::VersionMismatch
    );
    assert!(matches!(bench.ask_as(1, hello()), Ok(Reply::Hello(_))));
    assert!(bench.device.handshake_done());
    assert!(matches!(
        bench.ask_as(2, Command::GetStatus),
        Ok(Reply::Status(_))
    ));
}

#[test]
fn hello_while_an_earlier_hosts_command_runs() {
    // A's Home (seq 2) is under way when B says Hello: B is answered at once, B's own
    // seq 2 is a new request (not "the one in progress"), and A's Home reply, when it comes,
    // does not land in the cache where it would answer B's next seq 2.
    let mut bench = Bench::new();
    bench.send_bytes(&frame(&Request {
        seq: 2,
        command: Command::Home,
    }));
    bench.run_ms(200);
    assert!(matches!(bench.ask_as(1, hello()), Ok(Reply::Hello(_))));
    let Ok(Reply::Status(status)) = bench.ask_as(2, Command::GetStatus) else {
        panic!("B's status")
    };
    assert_eq!(status.state, DeviceState::Homing);
    assert_eq!(
        bench.ask_as(3, Command::MoveTo(Geometry::from_whole_deg(40, 40))),
        Err(DeviceError::new(ErrorCode::Busy))
    );
    bench.wait_idle();
    assert!(
        bench
            .replies(2)
            .iter()
            .any(|r| matches!(r, Ok(Reply::Homed(_)))),
        "A's reply is still sent"
    );
    let target = Geometry::from_whole_deg(30, 50);
    assert_eq!(bench.ask_as(2, Command::MoveTo(target)), Ok(Reply::Ack));
    bench.wait_at_rest();
    assert_eq!(bench.hw().true_geometry(), target);
}

#[test]
fn a_repeated_hello_is_carried_out_again() {
    let mut bench = Bench::new();
    bench.home();
    // The host lost the reply to its Hello and retries with the same seq: carried out
    // again (a Hello changes nothing twice), and it does not disturb what came before.
    for _ in 0..2 {
        assert!(matches!(bench.ask_as(50, hello()), Ok(Reply::Hello(_))));
    }
    assert!(bench.status().homed_i);
}

/// Feed a whole frame to the link; what it made of it.
fn push_frame(link: &mut Link, bytes: &[u8]) -> Option<Incoming> {
    let mut last = None;
    for &b in bytes {
        if let Some(incoming) = link.push(b, &mut |_: &[u8]| {}) {
            last = Some(incoming);
        }
    }
    last
}

#[test]
fn a_link_reset_forgets_the_cached_reply() {
    let mut link = Link::new();
    let home = frame(&Request {
        seq: 5,
        command: Command::Home,
    });
    assert!(matches!(
        push_frame(&mut link, &home),
        Some(Incoming::Fresh(_))
    ));
    link.reply(5, Ok(Reply::Ack), &mut |_: &[u8]| {});
    assert_eq!(push_frame(&mut link, &home), Some(Incoming::Repeat));
    link.reset();
    assert!(
        matches!(push_frame(&mut link, &home), Some(Incoming::Fresh(_))),
        "the cache outlived the reset"
    );
}

#[test]
fn an_unknown_command_is_answered_not_supported_under_its_seq() {
    let mut bench = Bench::new();
    bench.home();
    // A newer host's command (variant 99) at seq 300 (a two-byte varint), with a body.
    let from = bench.messages.len();
    bench.send_bytes(&crc_frame(&[0xac, 0x02, 99, 1, 2, 3]));
    assert_eq!(
        bench.messages_since(from),
        [DeviceMessage::Reply {
            seq: 300,
            result: Err(DeviceError::new(ErrorCode::NotSupported))
        }]
    );
    // A known command with a field appended (another version's TakeReading): the same.
    let mut payload = vec![0xad, 0x02]; // seq 301
    payload.extend([7, 100, 0, 0, 42]); // TakeReading 100 ms, Sample, None, then one byte more
    let from = bench.messages.len();
    bench.send_bytes(&crc_frame(&payload));
    assert_eq!(
        bench.messages_since(from),
        [DeviceMessage::Reply {
            seq: 301,
            result: Err(DeviceError::new(ErrorCode::NotSupported))
        }]
    );
    // Without a readable seq (or with a bad CRC) the device can only say it dropped a frame.
    let from = bench.messages.len();
    bench.send_bytes(&crc_frame(&[0xff, 0xff, 0xff, 0xff, 0xff]));
    let mut corrupted = frame(&Request {
        seq: 9,
        command: Command::GetStatus,
    });
    corrupted[1] ^= 0x10;
    bench.send_bytes(&corrupted);
    assert!(
        bench
            .messages_since(from)
            .iter()
            .all(|m| matches!(m, DeviceMessage::FrameRejected { .. }))
    );
    assert_eq!(bench.messages_since(from).len(), 2);
}

#[test]
fn an_unknown_command_does_not_disturb_the_cache_or_a_command_in_progress() {
    let mut bench = Bench::new();
    bench.home();
    let target = Geometry::from_whole_deg(50, 50);
    bench.send_bytes(&frame(&Request {
        seq: 400,
        command: Command::MoveTo(target),
    }));
    bench.run_ms(50);
    // An unreadable frame, even under the seq in progress, starts nothing and ends nothing.
    bench.send_bytes(&crc_frame(&[0x90, 0x03, 99]));
    assert_eq!(
        bench.reply(400),
        Some(Err(DeviceError::new(ErrorCode::NotSupported)))
    );
    bench.wait_idle();
    assert_eq!(bench.replies(400).last(), Some(&Ok(Reply::Ack)));
    assert_eq!(bench.hw().true_geometry(), target);
    // The move's reply is still the cached answer to a retry of seq 400.
    bench.send_bytes(&frame(&Request {
        seq: 400,
        command: Command::MoveTo(target),
    }));
    assert_eq!(bench.replies(400).last(), Some(&Ok(Reply::Ack)));
    assert_eq!(bench.replies(400).len(), 3);
}

#[test]
fn an_unknown_command_before_the_handshake_is_answered_too() {
    let mut bench = Bench::new();
    bench.device.disconnected();
    let from = bench.messages.len();
    bench.send_bytes(&crc_frame(&[7, 99]));
    assert_eq!(
        bench.messages_since(from),
        [DeviceMessage::Reply {
            seq: 7,
            result: Err(DeviceError::new(ErrorCode::NotSupported))
        }]
    );
}

mod random {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(500))]

        /// Any frame with a good CRC that is no request of this version gets exactly one
        /// answer: `NotSupported` under its leading seq when it has one, else
        /// `FrameRejected`; and the device goes on serving the next request.
        #[test]
        fn every_unreadable_frame_gets_one_answer(payload in proptest::collection::vec(any::<u8>(), 0..120)) {
            let readable = postcard::take_from_bytes::<Request>(&payload).map(|(_, rest)| rest.is_empty()).unwrap_or(false);
            prop_assume!(!readable);
            let mut bench = Bench::new();
            let from = bench.messages.len();
            bench.send_bytes(&crc_frame(&payload));
            let expected = match postcard::take_from_bytes::<u32>(&payload) {
                Ok((seq, _)) => DeviceMessage::Reply { seq, result: Err(DeviceError::new(ErrorCode::NotSupported)) },
                Err(_) => DeviceMessage::FrameRejected { code: ErrorCode::UnknownMessage },
            };
            prop_assert_eq!(bench.messages_since(from), &[expected][..]);
            let served = matches!(bench.ask_as(u32::MAX, Command::GetStatus), Ok(Reply::Status(_)));
            prop_assert!(served);
        }
    }
}
