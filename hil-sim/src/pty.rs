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
        Ok(PtyServer { master: pty.master, _slave: pty.slave, path })
    }

    /// The device path clients open (`/dev/pts/N`).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Serve `instrument` until `stop` is set. Whatever a client sends, garbage included,
    /// goes to the firmware's decoder, which answers bad frames and carries on.
    pub fn serve(&self, instrument: &mut SimInstrument, stop: &AtomicBool) -> std::io::Result<()> {
        let mut buf = [0u8; 4096];
        while !stop.load(Ordering::Relaxed) {
            let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLIN)];
            let ready = match poll(&mut fds, PollTimeout::from(20u8)) {
                Ok(n) => n,
                Err(nix::errno::Errno::EINTR) => continue,
                Err(e) => return Err(e.into()),
            };
            if ready > 0 {
                match nix::unistd::read(&self.master, &mut buf) {
                    Ok(n) => instrument.write(&buf[..n]),
                    // A client closing its end is not our failure.
                    Err(nix::errno::Errno::EIO | nix::errno::Errno::EAGAIN | nix::errno::Errno::EINTR) => {}
                    Err(e) => return Err(e.into()),
                }
            }
            loop {
                let n = instrument.read(&mut buf);
                if n == 0 {
                    break;
                }
                write_all(&self.master, &buf[..n])?;
            }
        }
        Ok(())
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
