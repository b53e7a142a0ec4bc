//! The host crate's integration tests (`cargo test -p host --test it`).
//!
//! One test binary for the crate, each file a module: a test binary links the crate and all
//! its dependencies, so one per file cost a build, a link and disk space per file. The
//! tests run as threads of one process: a test passes values in (no `set_var`, no
//! `set_current_dir`) and names its temporary folders after its own file.
// Tests index vectors as the formulas they check write them, and spell out the shapes of
// the tables they compare against.
#![allow(clippy::needless_range_loop, clippy::type_complexity)]

// Helpers shared by the test files.
mod characterize;
mod cli_support;
mod common;
mod firmware_support;
// The binary's own `gonio measure` arguments, parsed as the command line parses them.
#[allow(dead_code)]
#[path = "../../src/cli/measure/args.rs"]
mod measure_args;

mod acceptance;
mod accuracy;
mod adaptive_lack_of_fit;
mod arm_offset_rate;
mod bad_input;
mod batch;
mod bounds;
mod budget;
mod budget_cli;
mod budget_session;
mod cli_exit;
mod cli_fit;
mod cli_measure;
mod cli_messages;
mod cli_sim;
mod compare;
mod completions;
mod device_timing;
mod docs;
mod evidence;
mod export;
mod extension;
mod file_readers;
mod firmware_image;
mod fit;
mod flash_session;
mod forensic;
mod handshake;
mod house;
mod instruments_study;
mod interruptions;
mod lay;
mod library;
mod library_postgres;
mod model;
mod noise_device;
mod order;
mod plots;
mod progress;
mod pty_campaign;
mod reanalysis;
mod record_crash;
mod record_folder;
mod reliability;
mod report;
mod saturation;
mod schemas;
mod selftest;
mod shapes_study;
mod sheet;
mod sheet_answer;
mod sheet_resume;
mod signature;
mod sim_instrument;
mod start_unplug;
mod sweep_bad_link;
mod table6;
mod trade;
