//! Fuzz the frame decoder with arbitrary bytes, as the device and the host both see them.
//!
//! Checks beyond "no panic": at most one result per delimiter, and a valid frame sent
//! after the junk (behind a delimiter) always decodes: the decoder is back in step.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::{Command, DeviceMessage, FrameDecoder, MAX_FRAME_LEN, Request, encode_frame};

fuzz_target!(|data: &[u8]| {
    let delimiters = data.iter().filter(|&&b| b == 0).count();

    let mut device_side: FrameDecoder = FrameDecoder::new();
    let mut results = 0;
    device_side.feed(data, |_: Result<Request, _>| results += 1);
    assert!(results <= delimiters);

    let mut host_side: FrameDecoder = FrameDecoder::new();
    let mut results = 0;
    host_side.feed(data, |_: Result<DeviceMessage, _>| results += 1);
    assert!(results <= delimiters);

    let probe = Request {
        seq: 42,
        command: Command::GetStatus,
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
    let frame = encode_frame(&probe, &mut buf).expect("probe fits");
    let mut last = None;
    device_side.feed(&[0], |r: Result<Request, _>| last = Some(r));
    device_side.feed(frame, |r: Result<Request, _>| last = Some(r));
    assert_eq!(last, Some(Ok(probe)));
});
