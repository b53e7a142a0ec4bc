//! One module per `gonio` subcommand, each with its clap `Args` and `run()`.
pub mod accuracy;
pub mod compare;
pub mod completions;
pub mod exit;
pub mod fit;
pub mod flash;
pub mod forensic;
pub mod library;
pub mod measure;
pub mod population;
pub mod ports;
pub mod reliability;
pub mod report;
pub mod sessions;
pub mod sim;
pub mod trade;
pub mod verify;
