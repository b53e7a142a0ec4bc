//! The simulated instrument: the firmware library ([`firmware::Device`]) running on the
//! host, reached through the same byte-level protocol as the real board.
//!
//! Bytes written by the host go through the real framing into the firmware's command
//! handler, and its frames come back to be read. The hardware is the library's own model
//! ([`firmware::testing::FakeHardware`]): arms that follow the planned profiles on virtual
//! time, home switches, a lamp, and a detector that sees a CONSTANT signal (set with
//! [`SimInstrument::with_scene`]). The physics of a real scene (TSL samples, the white
//! tile, acceptance, drift) is the hil-sim issue's; it will implement
//! [`firmware::testing::Scene`] or the hardware traits with it.
//!
//! Virtual time does not pass on its own: [`SimInstrument::advance_ms`] runs the firmware
//! forward (polling it every millisecond, as the board's loop does).

use firmware::Device;
use firmware::config::InstrumentConfig;
use firmware::hardware::ResetCause;
use firmware::testing::{ConstantScene, FakeHardware};
use protocol::Geometry;
use std::collections::VecDeque;

/// Hardware of the simulated instrument.
pub type SimHardware = FakeHardware<ConstantScene>;

/// Signal of the default constant scene on the most sensitive range, counts: about the
/// white tile at θi = 20° (40 % of full scale, INSTRUMENT.md).
pub const DEFAULT_SIGNAL_COUNTS: f32 = 0.4 * 65_535.0;

/// The firmware logic behind a byte pipe, on virtual time.
pub struct SimInstrument {
    device: Device<SimHardware>,
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
        SimInstrument::with_scene(config, ConstantScene(DEFAULT_SIGNAL_COUNTS))
    }

    /// A simulated instrument whose detector sees `scene`; the arms power up at
    /// (30°, 30°), which the firmware does not know until it homes.
    pub fn with_scene(config: InstrumentConfig, scene: ConstantScene) -> SimInstrument {
        let hardware = FakeHardware::new(&config, scene, Geometry::from_whole_deg(30, 30));
        SimInstrument { device: Device::new(config, hardware, ResetCause::PowerOn), to_host: VecDeque::new(), now_us: 0 }
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

    /// Run the firmware forward by `ms` of virtual time, polling it every millisecond.
    pub fn advance_ms(&mut self, ms: u64) {
        for _ in 0..ms {
            self.now_us += 1000;
            self.device.hardware_mut().advance_to(self.now_us);
            let to_host = &mut self.to_host;
            self.device.poll(self.now_us, &mut |frame: &[u8]| to_host.extend(frame));
        }
    }

    /// Whether the firmware has nothing under way.
    pub fn is_idle(&self) -> bool {
        self.device.is_idle()
    }

    /// The simulated hardware (true arm angles, lamp, injected faults).
    pub fn hardware(&self) -> &SimHardware {
        self.device.hardware()
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
