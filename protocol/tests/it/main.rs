//! The protocol crate's integration tests (`cargo test -p protocol --test it`).
//!
//! One test binary for the crate, each file a module: a test binary links the crate and all
//! its dependencies, so one per file cost a build, a link and disk space per file. The
//! tests run as threads of one process: a test passes values in (no `set_var`, no
//! `set_current_dir`) and names its temporary folders after its own file.
// Some tests state the wire budget's arithmetic as assertions on constants: the numbers
// are the documentation, checked.
#![allow(clippy::assertions_on_constants, clippy::nonminimal_bool)]

// Helpers shared by the test files.
mod arbitrary;

mod framing;
mod golden;
mod schedule_vectors;
mod schema;
