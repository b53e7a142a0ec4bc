//! The host's serial-port code against the simulated instrument on a pseudo-terminal:
//! the path a real instrument takes, minus the USB cable.

use host::instrument::link::{Client, RetryPolicy};
use host::instrument::serial::SerialTransport;
use protocol::{Command, PROTOCOL_VERSION, Reply};
use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

struct Served {
    path: String,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<std::io::Result<()>>>,
}

impl Drop for Served {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn serve() -> Served {
    let server = hil_sim::pty::PtyServer::open().expect("pseudo-terminal");
    let path = server.path().to_string_lossy().into_owned();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let port = hil_sim::scene::SamplePort::new(Arc::new(|_: f64, _: f64| 0.5));
    let mut instrument = hil_sim::SimInstrument::new(port, hil_sim::SimConfig::default());
    let thread = std::thread::spawn(move || server.serve(&mut instrument, &flag));
    Served {
        path,
        stop,
        thread: Some(thread),
    }
}

#[test]
fn handshake_through_the_serial_port_code() {
    let served = serve();
    let mut client = Client::new(
        SerialTransport::open(&served.path).expect("open pty"),
        RetryPolicy::default(),
    );
    let info = client.hello().expect("handshake over the pty");
    assert_eq!(info.protocol_version, PROTOCOL_VERSION);
    assert!(matches!(
        client.request(Command::GetStatus),
        Ok(Reply::Status(_))
    ));
}

#[test]
fn garbage_from_a_client_does_not_bring_the_simulator_down() {
    let served = serve();
    {
        let mut rogue = std::fs::OpenOptions::new()
            .write(true)
            .open(&served.path)
            .expect("open pty");
        let garbage: Vec<u8> = (0..3000u32)
            .map(|i| (i.wrapping_mul(2654435761) >> 13) as u8)
            .collect();
        rogue.write_all(&garbage).unwrap();
        rogue.write_all(&[0]).unwrap();
    }
    let mut client = Client::new(
        SerialTransport::open(&served.path).expect("open pty"),
        RetryPolicy::default(),
    );
    assert!(client.hello().is_ok());
}

#[test]
fn a_host_that_goes_quiet_on_the_pty_is_taken_for_lost() {
    let served = serve();
    let policy = RetryPolicy {
        heartbeat_every: std::time::Duration::from_millis(50),
        ..RetryPolicy::default()
    };
    let mut client = Client::new(
        SerialTransport::open(&served.path).expect("open pty"),
        policy,
    );
    client.hello().unwrap();
    assert!(matches!(client.request(Command::Home), Ok(Reply::Homed(_))));
    assert!(matches!(
        client.request(Command::SetLamp { on: true }),
        Ok(Reply::Ack)
    ));
    // The host stops talking for longer than the heartbeat timeout, in wall time.
    std::thread::sleep(std::time::Duration::from_millis(2_600));
    let Ok(Reply::Status(status)) = client.request(Command::GetStatus) else {
        panic!("status")
    };
    assert_eq!(status.fault, Some(protocol::ErrorCode::HeartbeatLost));
    assert!(!status.lamp_on);
}
