//! Real instruments over a serial port (USB CDC-ACM), or anything that looks like one
//! (the simulator's pseudo-terminal).

use crate::instrument::link::Transport;
use serialport::{SerialPort, SerialPortType};
use std::io::{Read, Write};
use std::time::Duration;

/// A serial port as a [`Transport`].
pub struct SerialTransport {
    port: Box<dyn SerialPort>,
    path: String,
}

impl SerialTransport {
    /// Open `path`. CDC-ACM ignores the baud rate; it is set for UART bridges.
    pub fn open(path: &str) -> Result<SerialTransport, serialport::Error> {
        let port = serialport::new(path, 115_200)
            .timeout(Duration::from_millis(50))
            .open()?;
        Ok(SerialTransport {
            port,
            path: path.to_owned(),
        })
    }

    /// The device path.
    pub fn path(&self) -> &str {
        &self.path
    }
}

impl Transport for SerialTransport {
    fn reconnect(&mut self) -> std::io::Result<()> {
        // A CDC-ACM port that was unplugged comes back under the same path (or not yet).
        // serialport says "not found" for a path that is gone: keep the OS's words.
        self.port = serialport::new(&self.path, 115_200)
            .timeout(Duration::from_millis(50))
            .open()
            .map_err(std::io::Error::from)?;
        Ok(())
    }

    fn name(&self) -> String {
        self.path.clone()
    }

    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.port.write_all(bytes)?;
        self.port.flush()
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        self.port
            .set_timeout(timeout.max(Duration::from_millis(1)))?;
        match self.port.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Ok(0),
            Err(e) => Err(e),
        }
    }
}

/// A serial port that may be an instrument.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PortCandidate {
    /// Device path.
    pub path: String,
    /// USB vendor and product id, if it is a USB port.
    pub usb_id: Option<(u16, u16)>,
    /// USB product string, if known.
    pub product: Option<String>,
    /// VID/PID match the instrument's.
    pub is_instrument: bool,
}

/// Whether a USB port with this identity is a gonio instrument.
pub fn is_instrument(vid: u16, pid: u16) -> bool {
    (vid, pid) == (protocol::USB_VID, protocol::USB_PID)
}

/// Every serial port of the machine, instruments first.
pub fn list_ports() -> Result<Vec<PortCandidate>, serialport::Error> {
    let mut ports: Vec<PortCandidate> = serialport::available_ports()?
        .into_iter()
        .map(|info| match info.port_type {
            SerialPortType::UsbPort(usb) => PortCandidate {
                path: info.port_name,
                usb_id: Some((usb.vid, usb.pid)),
                is_instrument: is_instrument(usb.vid, usb.pid),
                product: usb.product,
            },
            _ => PortCandidate {
                path: info.port_name,
                usb_id: None,
                product: None,
                is_instrument: false,
            },
        })
        .collect();
    ports.sort_by_key(|p| (!p.is_instrument, p.path.clone()));
    Ok(ports)
}

/// The one attached instrument, if exactly one is attached.
pub fn find_instrument() -> Result<Option<String>, FindError> {
    let found: Vec<String> = list_ports()?
        .into_iter()
        .filter(|p| p.is_instrument)
        .map(|p| p.path)
        .collect();
    match found.as_slice() {
        [] => Ok(None),
        [one] => Ok(Some(one.clone())),
        _ => Err(FindError::Several(found)),
    }
}

/// Why auto-detection failed.
#[derive(Debug, thiserror::Error)]
pub enum FindError {
    /// The ports could not be listed.
    #[error("cannot list serial ports: {0}")]
    List(#[from] serialport::Error),
    /// More than one instrument: the user must choose.
    #[error("several instruments are attached ({}); choose one with --port", .0.join(", "))]
    Several(Vec<String>),
}
