//! The simulated instrument as a [`Transport`], for `--sim` sessions in process.

use crate::link::Transport;
use hil_sim::SimInstrument;
use std::time::Duration;

impl Transport for SimInstrument {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.write(bytes)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        SimInstrument::read(self, buf, timeout)
    }

    /// Device time: waiting on the simulator runs it forward instead of sleeping.
    fn now(&self) -> Duration {
        Duration::from_micros(self.device_time_us())
    }
}
