//! The simulated instrument's integration tests (`cargo test -p hil-sim --test it`).
//!
//! One test binary for the crate, each file a module: a test binary links the crate and all
//! its dependencies, so one per file cost a build, a link and disk space per file. The
//! tests run as threads of one process: a test passes values in (no `set_var`, no
//! `set_current_dir`) and names its temporary folders after its own file.

mod instrument_errors;
mod sheet;
mod sweep;
mod unplug;
