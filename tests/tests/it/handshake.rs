//! The handshake end to end: the host's link client against the firmware library
//! (in the simulated instrument), through the real framing.

use host::instrument::link::{Client, LinkError, RetryPolicy, Transport};
use protocol::*;
use std::time::Duration;

/// A simulated instrument with a matte grey sample on the port.
fn simulator() -> hil_sim::SimInstrument {
    let port = hil_sim::scene::SamplePort::new(std::sync::Arc::new(|_: f64, _: f64| 0.5));
    hil_sim::SimInstrument::new(port, hil_sim::SimConfig::default())
}

#[test]
fn host_and_firmware_agree_on_the_handshake() {
    let mut client = Client::new(simulator(), RetryPolicy::default());
    let info = client.hello().expect("handshake");
    assert_eq!(info.protocol_version, PROTOCOL_VERSION);
    assert_eq!(
        info.board.as_str(),
        firmware::config::InstrumentConfig::REFERENCE.board
    );
    assert!(matches!(
        client.request(Command::GetStatus),
        Ok(Reply::Status(_))
    ));
    assert_eq!(client.stats().retries, 0);
}

/// A device of another protocol version: it refuses our hello the way every version must.
struct DeviceOfVersion {
    version: u16,
    decoder: FrameDecoder,
    out: Vec<u8>,
}

impl DeviceOfVersion {
    fn new(version: u16) -> DeviceOfVersion {
        DeviceOfVersion {
            version,
            decoder: FrameDecoder::new(),
            out: Vec::new(),
        }
    }
}

impl Transport for DeviceOfVersion {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let mut requests = Vec::new();
        self.decoder
            .feed(bytes, |r: Result<Request, FrameError>| requests.push(r));
        for request in requests.into_iter().flatten() {
            let reply = DeviceMessage::Reply {
                seq: request.seq,
                result: Err(DeviceError::with_detail(
                    ErrorCode::VersionMismatch,
                    i32::from(self.version),
                )),
            };
            let mut buf = [0u8; MAX_FRAME_LEN];
            self.out
                .extend_from_slice(encode_frame(&reply, &mut buf).unwrap());
        }
        Ok(())
    }

    fn read(&mut self, buf: &mut [u8], _timeout: Duration) -> std::io::Result<usize> {
        let n = buf.len().min(self.out.len());
        buf[..n].copy_from_slice(&self.out[..n]);
        self.out.drain(..n);
        Ok(n)
    }
}

#[test]
fn host_refuses_a_newer_device_and_says_which_side_to_update() {
    let mut client = Client::new(
        DeviceOfVersion::new(PROTOCOL_VERSION + 1),
        RetryPolicy::default(),
    );
    let error = client.hello().unwrap_err();
    assert!(
        matches!(error, LinkError::VersionMismatch { host, device } if host == PROTOCOL_VERSION && device == PROTOCOL_VERSION + 1)
    );
    let text = error.to_string();
    assert!(text.contains("update the host software"), "{text}");
    assert!(!text.contains("gonio flash"), "{text}");
}

#[test]
fn host_finding_older_firmware_tells_the_user_to_run_gonio_flash() {
    for older in [0, 1, PROTOCOL_VERSION - 1] {
        let mut client = Client::new(DeviceOfVersion::new(older), RetryPolicy::default());
        let error = client.hello().unwrap_err();
        assert!(
            matches!(error, LinkError::VersionMismatch { host, device } if host == PROTOCOL_VERSION && device == older)
        );
        let text = error.to_string();
        for needle in [
            &format!("this host speaks version {PROTOCOL_VERSION}, the instrument version {older}"),
            "firmware is older than this host",
            "`gonio flash`",
            &format!("protocol version {PROTOCOL_VERSION}"),
        ] {
            assert!(text.contains(needle), "no {needle:?} in: {text}");
        }
    }
}

#[test]
fn lost_reply_is_recovered_by_retrying_the_same_sequence() {
    /// Drops the device's first reply, as a corrupted USB transfer would.
    struct DropFirstReply {
        sim: hil_sim::SimInstrument,
        dropped: bool,
    }
    impl Transport for DropFirstReply {
        fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
            self.sim.write(bytes)?;
            if !self.dropped {
                self.dropped = true;
                let mut sink = [0u8; 4 * MAX_FRAME_LEN];
                self.sim.read(&mut sink, Duration::ZERO)?;
            }
            Ok(())
        }
        fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
            self.sim.read(buf, timeout)
        }
        fn now(&self) -> Duration {
            Duration::from_micros(self.sim.device_time_us())
        }
    }
    let policy = RetryPolicy {
        reply_timeout: Duration::from_millis(20),
        attempts: 3,
        ..RetryPolicy::default()
    };
    let mut client = Client::new(
        DropFirstReply {
            sim: simulator(),
            dropped: false,
        },
        policy,
    );
    let info = client.hello().expect("handshake after a retry");
    assert_eq!(info.protocol_version, PROTOCOL_VERSION);
    assert_eq!(client.stats().retries, 1);
}
