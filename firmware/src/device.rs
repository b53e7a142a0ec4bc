//! The device: carries out host commands and keeps the instrument's state.
//!
//! This build answers the handshake, heartbeats and status; commands that move or
//! measure are refused with [`ErrorCode::NotSupported`] until the motion and detector
//! layers exist (firmware issue).

use crate::config::InstrumentConfig;
use crate::link::{Incoming, Link};
use protocol::{
    Command, DeviceError, DeviceState, ErrorCode, Geometry, PROTOCOL_VERSION, Reply, Status,
};

/// The firmware's state machine.
pub struct Device {
    config: InstrumentConfig,
    link: Link,
    /// Set by a `Hello` with our protocol version; until then only `Hello` is served.
    handshake_done: bool,
    /// Protocol version of the last refused `Hello`, for the board's log.
    refused_version: Option<u16>,
    lamp_on: bool,
    now_us: u64,
}

impl Device {
    /// A device just out of reset.
    pub fn new(config: InstrumentConfig) -> Device {
        Device { config, link: Link::new(), handshake_done: false, refused_version: None, lamp_on: false, now_us: 0 }
    }

    /// The instrument's configuration.
    pub fn config(&self) -> &InstrumentConfig {
        &self.config
    }

    /// Whether a host with our protocol version has said hello.
    pub fn handshake_done(&self) -> bool {
        self.handshake_done
    }

    /// Take (and clear) the version of a host refused since the last call, for logging.
    pub fn take_refused_version(&mut self) -> Option<u16> {
        self.refused_version.take()
    }

    /// The host went away (USB reset, cable pulled): partial frames are dropped and a new
    /// session must say hello again.
    pub fn disconnected(&mut self) {
        self.link.reset();
        self.handshake_done = false;
    }

    /// Feed bytes received from the host at device time `now_us`; frames to send back go
    /// to `send`, in order.
    pub fn receive(&mut self, bytes: &[u8], now_us: u64, send: &mut impl FnMut(&[u8])) {
        self.now_us = now_us;
        for &byte in bytes {
            if let Some(Incoming::Fresh(request)) = self.link.push(byte, send) {
                let result = self.execute(&request.command);
                self.link.reply(request.seq, result, send);
            }
        }
    }

    fn execute(&mut self, command: &Command) -> Result<Reply, DeviceError> {
        if let Command::Hello { protocol_version } = *command {
            return if protocol_version == PROTOCOL_VERSION {
                self.handshake_done = true;
                Ok(Reply::Hello(self.config.device_info()))
            } else {
                self.handshake_done = false;
                self.refused_version = Some(protocol_version);
                Err(DeviceError::with_detail(ErrorCode::VersionMismatch, i32::from(PROTOCOL_VERSION)))
            };
        }
        if !self.handshake_done {
            return Err(DeviceError::with_detail(ErrorCode::VersionMismatch, i32::from(PROTOCOL_VERSION)));
        }
        match command {
            Command::Heartbeat => Ok(Reply::Ack),
            Command::GetStatus => Ok(Reply::Status(self.status())),
            Command::Abort => Ok(Reply::Ack),
            Command::SetLamp { on: false } => {
                self.lamp_on = false;
                Ok(Reply::Ack)
            }
            _ => Err(DeviceError::new(ErrorCode::NotSupported)),
        }
    }

    fn status(&self) -> Status {
        Status {
            state: DeviceState::Idle,
            position: Geometry::default(),
            homed_i: false,
            homed_r: false,
            lamp_on: self.lamp_on,
            fault: None,
            schedule: None,
            uptime_us: self.now_us,
        }
    }
}
