//! The simulated instrument: the firmware library ([`firmware::Device`]) running on the
//! host, reached through the same byte-level protocol as the real board.
//!
//! This is the in-process link only: bytes written by the host go through the real
//! framing into the firmware's command handler, and its frames come back to be read.
//! Simulated arms, detector and scene follow with the firmware's motion and detector
//! layers (hil-sim issue).

use firmware::Device;
use firmware::config::InstrumentConfig;
use std::collections::VecDeque;

/// The firmware logic behind a byte pipe, on virtual time.
pub struct SimInstrument {
    device: Device,
    /// Bytes the device sent that the host has not read yet.
    to_host: VecDeque<u8>,
    /// Virtual device time.
    now_us: u64,
}

impl SimInstrument {
    /// A simulated reference instrument, just powered up.
    pub fn new() -> SimInstrument {
        SimInstrument::with_config(InstrumentConfig::REFERENCE)
    }

    /// A simulated instrument with other limits.
    pub fn with_config(config: InstrumentConfig) -> SimInstrument {
        SimInstrument { device: Device::new(config), to_host: VecDeque::new(), now_us: 0 }
    }

    /// Bytes from the host arrive at the device.
    pub fn write(&mut self, bytes: &[u8]) {
        let to_host = &mut self.to_host;
        self.device.receive(bytes, self.now_us, &mut |frame: &[u8]| to_host.extend(frame));
    }

    /// Bytes from the device to the host; returns how many were copied into `buf`.
    pub fn read(&mut self, buf: &mut [u8]) -> usize {
        let n = buf.len().min(self.to_host.len());
        for (slot, byte) in buf.iter_mut().zip(self.to_host.drain(..n)) {
            *slot = byte;
        }
        n
    }

    /// Virtual device time since power-up, µs.
    pub fn device_time_us(&self) -> u64 {
        self.now_us
    }
}

impl Default for SimInstrument {
    fn default() -> Self {
        Self::new()
    }
}

pub mod detector;
pub mod scene;
pub mod pty;
