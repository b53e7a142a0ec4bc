//! The simulated instrument on a pseudo-terminal, so that the host reaches it through
//! exactly the serial-port code it uses for a real instrument, and any serial client can
//! talk to it.

use crate::SimInstrument;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::openpty;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// A pseudo-terminal whose far end is the simulated instrument.
pub struct PtyServer {
    master: OwnedFd,
    /// Held open so that the master keeps working while no client is attached (Linux
    /// answers EIO on the master when every slave descriptor is closed).
    _slave: OwnedFd,
    path: PathBuf,
}

impl PtyServer {
    /// Open a new pseudo-terminal in raw mode (no echo, no line editing, no CR/LF
    /// translation: frames are binary).
    pub fn open() -> std::io::Result<PtyServer> {
        let pty = openpty(None, None)?;
        let mut termios = tcgetattr(&pty.slave)?;
        cfmakeraw(&mut termios);
        tcsetattr(&pty.slave, SetArg::TCSANOW, &termios)?;
        let path = nix::unistd::ttyname(&pty.slave)?;
        Ok(PtyServer {
            master: pty.master,
            _slave: pty.slave,
            path,
        })
    }

    /// The device path clients open (`/dev/pts/N`).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Serve `instrument` until `stop` is set. Whatever a client sends, garbage included,
    /// goes to the firmware's decoder, which answers bad frames and carries on.
    ///
    /// Virtual time runs ahead of wall time while the firmware has work under way (a move,
    /// a reading, a schedule, a sweep), but never more than three quarters of the
    /// firmware's heartbeat timeout past the last frame from the host the firmware heard:
    /// a host that keeps talking (as a host must while the arms move) is never taken for
    /// lost, however fast the simulation runs. A host unheard for the heartbeat timeout in
    /// wall time is gone, and virtual time then follows wall time, so the firmware's safe
    /// stop happens.
    ///
    /// The lead runs from the last frame *heard*, not from the last bytes read: bytes of a
    /// frame the link dropped show nothing to the firmware, and a lead from them let the
    /// clock run 1.5 s of device time per 200 ms heartbeat, so one lost heartbeat made the
    /// firmware's 2 s timeout and a fail-safe stop the same link costs nothing in process
    /// (issue 30). Now, as in process, it takes about the timeout without a frame heard.
    pub fn serve(&self, instrument: &mut SimInstrument, stop: &AtomicBool) -> std::io::Result<()> {
        let timeout = instrument.heartbeat_timeout();
        let lead_us = timeout.as_micros() as u64 * 3 / 4;
        let mut buf = [0u8; 4096];
        let mut last_host_wall = Instant::now();
        let mut last_host_virtual_us = instrument.device_time_us();
        let mut last_loop_wall = Instant::now();
        while !stop.load(Ordering::Relaxed) {
            let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLIN)];
            let ready = match poll(&mut fds, PollTimeout::from(1u8)) {
                Ok(n) => n,
                Err(nix::errno::Errno::EINTR) => continue,
                Err(e) => return Err(e.into()),
            };
            if ready > 0 {
                match nix::unistd::read(&self.master, &mut buf) {
                    Ok(n) => {
                        // With the simulated cable out the bytes are lost, as on a real link.
                        let _ = instrument.write(&buf[..n]);
                        let heard_us = instrument.last_heard_us();
                        if heard_us > last_host_virtual_us {
                            last_host_wall = Instant::now();
                            last_host_virtual_us = heard_us;
                        }
                    }
                    // A client closing its end is not our failure.
                    Err(
                        nix::errno::Errno::EIO
                        | nix::errno::Errno::EAGAIN
                        | nix::errno::Errno::EINTR,
                    ) => {}
                    Err(e) => return Err(e.into()),
                }
            }
            let now_wall = Instant::now();
            let wall_step_us = (now_wall - last_loop_wall).as_micros() as u64;
            last_loop_wall = now_wall;
            let now_us = instrument.device_time_us();
            // Idle, the firmware waits for the host, which is computing (or gone): device
            // time follows wall time, as on a real instrument. Running ahead there made
            // the idle instrument's clock gain up to the lead on every pause of the host.
            let limit_us = if now_wall - last_host_wall >= timeout || instrument.is_idle() {
                now_us + wall_step_us
            } else {
                // At most 50 ms of device time per turn keeps the loop responsive.
                (last_host_virtual_us + lead_us).clamp(now_us, now_us + 50_000)
            };
            self.run_until(instrument, limit_us, &mut buf)?;
        }
        Ok(())
    }

    /// Run the instrument up to device time `limit_us`, passing its output to the client.
    fn run_until(
        &self,
        instrument: &mut SimInstrument,
        limit_us: u64,
        buf: &mut [u8],
    ) -> std::io::Result<()> {
        loop {
            let wait = Duration::from_micros(limit_us.saturating_sub(instrument.device_time_us()));
            match instrument.read(buf, wait) {
                Ok(0) => return Ok(()),
                Ok(n) => write_all(&self.master, &buf[..n])?,
                Err(e) if e.kind() == std::io::ErrorKind::NotConnected => {
                    if instrument.device_time_us() >= limit_us {
                        return Ok(());
                    }
                }
                Err(e) => return Err(e),
            }
        }
    }
}

fn write_all(fd: &OwnedFd, mut bytes: &[u8]) -> std::io::Result<()> {
    while !bytes.is_empty() {
        match nix::unistd::write(fd, bytes) {
            Ok(n) => bytes = &bytes[n..],
            Err(nix::errno::Errno::EINTR | nix::errno::Errno::EAGAIN) => {}
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}
