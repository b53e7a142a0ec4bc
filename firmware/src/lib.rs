//! The gonio firmware's logic, independent of the board: everything that decides
//! anything lives here, generic over small hardware traits, and is tested on the host.
//! The STM32F411 board crate (`firmware/board`) and the simulated instrument
//! (`hil-sim`) both run this same code.
//!
//! - [`link`]: bytes in, frames out; sequence numbers answered once.
//! - [`device`]: the command handler and the device's state (how a board drives it is
//!   described there).
//! - [`hardware`]: the traits a board implements (arms, detector, lamp).
//! - [`motion`]: angle ↔ microsteps, velocity profiles, both arms arriving together.
//! - [`homing`]: one arm's homing state machine.
//! - [`switches`]: the home switches, debounced.
//! - [`stepgen`]: step pulses from a hardware timer (segments, runt-free replacement,
//!   late-interrupt detection), behind [`stepgen::StepTimer`].
//! - [`detector`]: reading statistics and auto-ranging.
//! - [`sampling`]: ADC decimation and the sample ring, with the overrun rule.
//! - [`schedule`]: Strategy 1's visiting order and uploaded schedules.
//! - [`selftest`]: the self-test's pulse checks and read-backs.
//! - [`sweep`]: sweeps: the checks, the profile, auto-ranging while moving, the bins.
//! - [`clock`]: the PLL settings' derived clocks, the crystal checked against HSI, the
//!   error blink code.
//! - [`config`]: the reference instrument's limits, announced in the handshake.
//! - [`fault`]: the fault handlers' safe stop, their record across the reset, the reset cause.
//! - [`txqueue`]: frames for the host, queued whole or dropped whole.
//! - [`testing`]: hardware models on virtual time, for the tests and the simulator.
//! - [`scenarios`]: whole-device scenarios on those models, `no_std`, run on the host and
//!   on the Cortex-M4 under QEMU (`firmware/target-tests`).
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod clock;
pub mod config;
pub mod detector;
pub mod device;
pub mod fault;
pub mod hardware;
pub mod homing;
pub mod link;
pub mod motion;
pub mod sampling;
pub mod scenarios;
pub mod schedule;
pub mod selftest;
pub mod stepgen;
pub mod sweep;
pub mod switches;
pub mod testing;
pub mod txqueue;

pub use device::Device;
pub use hardware::{
    Arm, Arms, Detector, Diagnostics, Hardware, Lamp, MeasuredClocks, ResetCause, Sample, StackUse,
};
pub use link::Link;

/// Firmware version announced in the handshake.
pub const FIRMWARE_VERSION: &str = env!("CARGO_PKG_VERSION");
