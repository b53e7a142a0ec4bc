//! The gonio host library: the science (model, fit, schedules' use, classification), the
//! link to the instrument, the session, and the command-line subcommands.
pub mod cli;
pub mod link;
pub mod sim;
pub mod serial;
pub mod model;
pub mod fit;
pub mod sampling;
pub mod classify;
pub mod dataset;
pub mod adaptive;
pub mod calibration;
pub mod plots;
pub mod session;
pub mod export;
pub mod compare;
pub mod order;
pub mod trade;
