//! The simulated instrument as a [`Transport`], for `--sim` sessions in process.

use crate::link::Transport;
use hil_sim::SimInstrument;
use std::time::Duration;

impl Transport for SimInstrument {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.write(bytes);
        Ok(())
    }

    fn read(&mut self, buf: &mut [u8], _timeout: Duration) -> std::io::Result<usize> {
        // In process the device answers during `write`: nothing more will come by waiting.
        Ok(SimInstrument::read(self, buf))
    }
}
