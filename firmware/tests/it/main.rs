//! The firmware library's tests on the host (`cargo test -p firmware --test it`).
//!
//! One test binary for the crate, each file a module: a test binary links the crate and all
//! its dependencies, so one per file cost a build, a link and disk space per file. The
//! tests run as threads of one process: a test passes values in (no `set_var`, no
//! `set_current_dir`) and names its temporary folders after its own file.

// Helpers shared by the test files.
mod common;

mod clock;
mod device;
mod failsafe;
mod faults;
mod guard;
mod handshake;
mod homing;
mod link;
mod motion;
mod sampling;
mod scenarios;
mod schedules;
mod selftest;
mod stepgen;
mod sweep;
mod switches;
mod txqueue;
