//! The gonio firmware's logic, independent of the board: everything that decides
//! anything lives here, generic over small hardware traits, and is tested on the host.
//! The STM32F411 board crate (`firmware/board`) and the simulated instrument
//! (`hil-sim`) both run this same code.
//!
//! - [`link`]: bytes in, frames out; sequence numbers answered once.
//! - [`device`]: the command handler and the device's state.
//! - [`config`]: the reference instrument's limits, announced in the handshake.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod config;
pub mod device;
pub mod link;

pub use device::Device;
pub use link::Link;

/// Firmware version announced in the handshake.
pub const FIRMWARE_VERSION: &str = env!("CARGO_PKG_VERSION");
