//! Property tests of the framing: every message round-trips; no byte sequence panics
//! the decoder; after garbage, corruption, truncation or an over-long frame the decoder
//! is back in step at the next delimiter; a frame with a good CRC that holds no message
//! of this version still gives the sequence number it names, exactly when it names one.

use crate::arbitrary;

use arbitrary::{device_message, request};
use proptest::prelude::*;
use protocol::*;

fn encode<T: serde::Serialize>(message: &T) -> std::vec::Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    encode_frame(message, &mut buf)
        .expect("every message fits in a frame")
        .to_vec()
}

/// The postcard encoding (no CRC, no COBS) of `value`.
fn to_bytes<T: serde::Serialize>(value: &T) -> std::vec::Vec<u8> {
    let mut buf = [0u8; 2 * MAX_FRAME_LEN];
    postcard::to_slice(value, &mut buf).expect("fits").to_vec()
}

fn decode_all<T: Sequenced>(bytes: &[u8]) -> std::vec::Vec<Result<T, FrameError>> {
    let mut decoder: FrameDecoder = FrameDecoder::new();
    let mut out = std::vec::Vec::new();
    decoder.feed(bytes, |r| out.push(r));
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn every_request_round_trips(message in request()) {
        let frame = encode(&message);
        prop_assert!(frame.len() <= MAX_FRAME_LEN);
        prop_assert_eq!(frame.iter().filter(|&&b| b == 0).count(), 1, "only the delimiter is zero");
        prop_assert_eq!(decode_all::<Request>(&frame), vec![Ok(message)]);
    }

    #[test]
    fn every_device_message_round_trips(message in device_message()) {
        let frame = encode(&message);
        prop_assert!(frame.len() <= MAX_FRAME_LEN);
        prop_assert_eq!(decode_all::<DeviceMessage>(&frame), vec![Ok(message)]);
    }

    #[test]
    fn arbitrary_bytes_never_panic_and_resync(garbage in proptest::collection::vec(any::<u8>(), 0..2000), message in request()) {
        // Whatever came before, a delimiter followed by a valid frame yields that frame.
        let mut stream = garbage.clone();
        stream.push(0);
        stream.extend(encode(&message));
        let results = decode_all::<Request>(&stream);
        prop_assert_eq!(results.last(), Some(&Ok(message)));
        // Garbage alone: at most one result per delimiter, never a panic.
        let delimiters = garbage.iter().filter(|&&b| b == 0).count();
        prop_assert!(decode_all::<DeviceMessage>(&garbage).len() <= delimiters);
    }

    #[test]
    fn corruption_costs_at_most_the_corrupted_frames(
        messages in proptest::collection::vec(device_message(), 1..8),
        flips in proptest::collection::vec((any::<prop::sample::Index>(), 1u8..=255), 1..4),
    ) {
        let frames: std::vec::Vec<std::vec::Vec<u8>> = messages.iter().map(encode).collect();
        let mut stream: std::vec::Vec<u8> = frames.concat();
        let mut hit = std::collections::BTreeSet::new();
        for (index, mask) in &flips {
            let at = index.index(stream.len());
            stream[at] ^= mask;
            // Which frame the flipped byte belonged to (a flipped delimiter merges two).
            let mut end = 0;
            for (i, f) in frames.iter().enumerate() {
                end += f.len();
                if at < end { hit.insert(i); if at == end - 1 { hit.insert(i + 1); } break; }
            }
        }
        let results = decode_all::<DeviceMessage>(&stream);
        // Every intact frame still arrives, in order; a corrupted frame never decodes
        // into a different message (CRC-32 misses a random corruption with odds 2^-32).
        let intact: std::vec::Vec<&DeviceMessage> = messages.iter().enumerate().filter(|(i, _)| !hit.contains(i)).map(|(_, m)| m).collect();
        let decoded: std::vec::Vec<&DeviceMessage> = results.iter().filter_map(|r| r.as_ref().ok()).collect();
        for m in &decoded {
            prop_assert!(messages.contains(m), "a corrupted frame decoded into a message that was never sent");
        }
        let mut it = decoded.iter();
        for m in intact {
            prop_assert!(it.any(|d| *d == m), "intact frame lost: {:?}", m);
        }
    }

    #[test]
    fn truncated_frame_costs_only_itself(message in device_message(), next in device_message(), cut in any::<prop::sample::Index>()) {
        let frame = encode(&message);
        let keep = cut.index(frame.len() - 1); // drop at least the delimiter
        let mut stream = frame[..keep].to_vec();
        stream.push(0); // the link resumes with a delimiter (the sender's next frame start)
        stream.extend(encode(&next));
        let results = decode_all::<DeviceMessage>(&stream);
        prop_assert_eq!(results.last(), Some(&Ok(next.clone())));
        prop_assert!(results.len() <= 2);
        if results.len() == 2 {
            prop_assert!(results[0].is_err(), "a truncated frame decoded: {:?}", results[0]);
        }
    }

    #[test]
    fn unknown_command_keeps_its_seq(
        seq in any::<u32>(),
        variant in 12u32..100_000,
        body in proptest::collection::vec(any::<u8>(), 0..200),
        next in request(),
    ) {
        // A newer host's command: this version's variants end at 11 (Sweep).
        let mut payload = to_bytes(&seq);
        payload.extend(to_bytes(&variant));
        payload.extend(&body);
        let mut stream = crc_frame(&payload);
        stream.extend(encode(&next));
        let results = decode_all::<Request>(&stream);
        prop_assert_eq!(results, vec![Err(FrameError::UnknownMessage { seq: Some(seq) }), Ok(next)]);
    }

    #[test]
    fn a_known_message_with_bytes_appended_keeps_its_seq(
        message in request(),
        extra in proptest::collection::vec(any::<u8>(), 1..64),
    ) {
        // A newer version that appended a field: readable seq, unreadable message.
        let mut payload = to_bytes(&message);
        payload.extend(&extra);
        let results = decode_all::<Request>(&crc_frame(&payload));
        prop_assert_eq!(results, vec![Err(FrameError::UnknownMessage { seq: Some(message.seq) })]);
    }

    #[test]
    fn any_payload_with_a_good_crc_decodes_or_names_its_leading_seq(
        payload in proptest::collection::vec(any::<u8>(), 0..(MAX_PAYLOAD_LEN - 8)),
        next in request(),
    ) {
        // Whatever the payload, the decoder never panics and never guesses: either the
        // whole payload is one request, or it is unknown with exactly the leading varint
        // (when there is one), and the next frame still decodes.
        let mut stream = crc_frame(&payload);
        stream.extend(encode(&next));
        let results = decode_all::<Request>(&stream);
        prop_assert_eq!(results.len(), 2);
        prop_assert_eq!(&results[1], &Ok(next));
        match &results[0] {
            Ok(request) => prop_assert_eq!(&to_bytes(request), &payload),
            Err(FrameError::UnknownMessage { seq }) => {
                let leading = postcard::take_from_bytes::<u32>(&payload).ok().map(|(s, _)| s);
                prop_assert_eq!(*seq, leading);
            }
            Err(other) => prop_assert!(false, "a good CRC gave {:?}", other),
        }
        // The host side: a device message payload names a seq only as a reply.
        let results = decode_all::<DeviceMessage>(&crc_frame(&payload));
        match &results[..] {
            [Ok(message)] => prop_assert_eq!(&to_bytes(message), &payload),
            [Err(FrameError::UnknownMessage { seq: Some(seq) })] => {
                // Only a reply (variant 0, however its varint is spelt) names a seq.
                let (variant, rest) = postcard::take_from_bytes::<u32>(&payload).unwrap();
                prop_assert_eq!(variant, 0, "only a reply names a seq");
                prop_assert_eq!(postcard::take_from_bytes::<u32>(rest).unwrap().0, *seq);
            }
            [Err(FrameError::UnknownMessage { seq: None })] => {}
            other => prop_assert!(false, "a good CRC gave {:?}", other),
        }
    }

    #[test]
    fn an_unreadable_reply_names_its_request(seq in any::<u32>(), variant in 9u32..1000, body in proptest::collection::vec(any::<u8>(), 0..100)) {
        // A newer device's reply (Ok with a Reply variant this version lacks: they end at 8, Sweep).
        let mut payload = vec![0u8]; // DeviceMessage::Reply
        payload.extend(to_bytes(&seq));
        payload.push(0); // Result::Ok
        payload.extend(to_bytes(&variant));
        payload.extend(&body);
        let results = decode_all::<DeviceMessage>(&crc_frame(&payload));
        prop_assert_eq!(results, vec![Err(FrameError::UnknownMessage { seq: Some(seq) })]);
    }

    #[test]
    fn overlong_frame_gives_exactly_one_error(len in MAX_FRAME_LEN..4 * MAX_FRAME_LEN, fill in 1u8..=255, next in request()) {
        let mut stream = vec![fill; len];
        stream.push(0);
        stream.extend(encode(&next));
        let results = decode_all::<Request>(&stream);
        prop_assert_eq!(results, vec![Err(FrameError::TooLong), Ok(next)]);
    }
}

#[test]
fn longest_frame_that_fits_is_accepted() {
    // MAX_FRAME_LEN - 1 non-zero bytes then the delimiter is not "too long".
    let mut stream = vec![1u8; MAX_FRAME_LEN - 1];
    stream.push(0);
    let results = decode_all::<Request>(&stream);
    assert_eq!(results.len(), 1);
    assert_ne!(results[0], Err(FrameError::TooLong));
}

/// Hand-made frame content (payload and CRC as given), COBS-encoded and delimited with
/// the cobs crate postcard uses.
fn cobs_frame(raw: &[u8]) -> std::vec::Vec<u8> {
    let mut stream = vec![0u8; cobs::max_encoding_length(raw.len())];
    let len = cobs::encode(raw, &mut stream);
    stream.truncate(len);
    stream.push(0);
    stream
}

#[test]
fn bad_crc_is_reported_as_such() {
    let message = Request {
        seq: 7,
        command: Command::GetStatus,
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
    let frame = encode_frame(&message, &mut buf).unwrap();
    let n = frame.len();
    // COBS-decode, flip a CRC bit, re-encode.
    let mut raw = frame[..n - 1].to_vec();
    let len = cobs::decode_in_place(&mut raw).unwrap();
    raw.truncate(len);
    raw[len - 1] ^= 0x01;
    assert_eq!(
        decode_all::<Request>(&cobs_frame(&raw)),
        vec![Err(FrameError::BadCrc)]
    );
}

/// A frame around a hand-made payload, with its correct CRC.
fn crc_frame(payload: &[u8]) -> std::vec::Vec<u8> {
    let mut raw = payload.to_vec();
    raw.extend(framing::CRC.checksum(payload).to_le_bytes());
    cobs_frame(&raw)
}

#[test]
fn valid_crc_over_junk_is_unknown_message() {
    // A future message variant: a correct frame this version cannot read, whose seq can.
    assert_eq!(
        decode_all::<Request>(&crc_frame(&[1, 99])),
        vec![Err(FrameError::UnknownMessage { seq: Some(1) })]
    );
    // A multi-byte varint seq (300 = 0xac 0x02).
    assert_eq!(
        decode_all::<Request>(&crc_frame(&[0xac, 0x02, 99])),
        vec![Err(FrameError::UnknownMessage { seq: Some(300) })]
    );
    // No readable seq: an empty payload, a varint cut short, one beyond u32.
    for payload in [&[][..], &[0x80], &[0xff, 0xff, 0xff, 0xff, 0x7f]] {
        assert_eq!(
            decode_all::<Request>(&crc_frame(payload)),
            vec![Err(FrameError::UnknownMessage { seq: None })],
            "{payload:?}"
        );
    }
    // Host side: a stream reading (variant 1) of junk answers no request.
    assert_eq!(
        decode_all::<DeviceMessage>(&crc_frame(&[1, 2])),
        vec![Err(FrameError::UnknownMessage { seq: None })]
    );
}

#[test]
fn error_codes_are_stable() {
    // These numbers are on the wire and in users' logs: changing one breaks both.
    let expected: &[(ErrorCode, u16)] = &[
        (ErrorCode::BadFrame, 1),
        (ErrorCode::BadCrc, 2),
        (ErrorCode::UnknownMessage, 3),
        (ErrorCode::FrameTooLong, 4),
        (ErrorCode::VersionMismatch, 5),
        (ErrorCode::NotHomed, 6),
        (ErrorCode::OutOfRange, 7),
        (ErrorCode::CollisionGuard, 8),
        (ErrorCode::Busy, 9),
        (ErrorCode::ScheduleTooLong, 10),
        (ErrorCode::Aborted, 11),
        (ErrorCode::HardwareFault, 12),
        (ErrorCode::HomeSwitchNotFound, 13),
        (ErrorCode::HomeSwitchStuck, 14),
        (ErrorCode::HeartbeatLost, 15),
        (ErrorCode::NoSchedule, 16),
        (ErrorCode::BadSchedule, 17),
        (ErrorCode::InvalidArgument, 18),
        (ErrorCode::WatchdogReset, 19),
        (ErrorCode::NotSupported, 20),
        (ErrorCode::Panic, 21),
        (ErrorCode::ProcessorFault, 22),
        (ErrorCode::StackOverflow, 23),
        (ErrorCode::StepLate, 24),
        (ErrorCode::AdcOverrun, 25),
    ];
    assert_eq!(ErrorCode::ALL.len(), expected.len());
    for &(code, number) in expected {
        assert_eq!(code.code(), number);
        assert_eq!(ErrorCode::from(number), code);
        let mut buf = [0u8; 8];
        assert_eq!(
            postcard::to_slice(&code, &mut buf).unwrap(),
            postcard::to_slice(&number, &mut [0u8; 8]).unwrap()
        );
    }
    assert_eq!(ErrorCode::from(999), ErrorCode::Unknown(999));
}

#[test]
fn version_mismatch_refusal_keeps_its_encoding() {
    // A peer of any protocol version must be able to read this refusal: its bytes are frozen.
    let message = DeviceMessage::Reply {
        seq: 1,
        result: Err(DeviceError::with_detail(ErrorCode::VersionMismatch, 1)),
    };
    let mut buf = [0u8; 32];
    let bytes = postcard::to_slice(&message, &mut buf).unwrap();
    assert_eq!(bytes, &[0, 1, 1, 5, 2]);
    let hello = Request {
        seq: 1,
        command: Command::Hello {
            protocol_version: 1,
        },
    };
    assert_eq!(
        postcard::to_slice(&hello, &mut [0u8; 32]).unwrap(),
        &[1, 0, 1]
    );
}

#[test]
fn a_sweep_bin_fits_the_link_budget() {
    // What the protocol's SweepBin doc promises (the bin rate against USB full speed).
    let frame_len = |bin: SweepBin| encode(&DeviceMessage::SweepBin(bin)).len();
    let worst = SweepBin {
        sweep_id: u16::MAX,
        index: u16::MAX,
        start: Angle::from_ticks(i32::MIN),
        end: Angle::from_ticks(i32::MAX),
        mean_counts: f32::MAX,
        std_counts: f32::MAX,
        blocks: u16::MAX,
        range: u8::MAX,
        flags: u8::MAX,
        device_time_us: u64::MAX,
    };
    assert_eq!(frame_len(worst), 46);
    let session = SweepBin {
        sweep_id: 16_383,
        index: MAX_SWEEP_BINS - 1,
        start: Angle::from_ticks(-6800),
        end: Angle::from_ticks(6800),
        blocks: 127,
        range: 3,
        flags: 7,
        device_time_us: (1 << 35) - 1,
        ..worst
    };
    assert!((1u64 << 35) as f64 / 3.6e9 > 9.5, "9.5 hours of µs");
    assert!(frame_len(session) <= 31, "{}", frame_len(session));
    // 1000 bins/s against one 64-byte packet per 1 ms USB frame.
    assert!(1000 * 31 < 64_000 / 2 && 1000 * 46 < 64_000);
    // The board's 1 KiB TX queue holds 33 of them.
    assert_eq!(1024 / 31, 33);
}
