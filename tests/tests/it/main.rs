//! The end-to-end tests across host, simulator and firmware logic (`cargo test -p gonio-tests --test it`).
//!
//! One test binary for the crate, each file a module: a test binary links the crate and all
//! its dependencies, so one per file cost a build, a link and disk space per file. The
//! tests run as threads of one process: a test passes values in (no `set_var`, no
//! `set_current_dir`) and names its temporary folders after its own file.
// The bench's tables are spelled out as the shapes they are.
#![allow(clippy::type_complexity)]

mod bench;
mod handshake;
mod measure;
mod pty_link;
mod reliability;
mod simulator;

// The host's tests' run seed, the same file: one GONIO_TEST_SEED runs both crates again.
#[path = "../../../host/tests/it/common/seed.rs"]
mod seed;
