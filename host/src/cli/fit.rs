//! `gonio fit` (being written: see issue 3).
use std::process::ExitCode;

/// Arguments of `gonio fit`.
#[derive(clap::Args)]
pub struct Args {
    /// CSV files.
    pub files: Vec<std::path::PathBuf>,
}

/// Run `gonio fit`.
pub fn run(_args: Args) -> anyhow::Result<ExitCode> {
    anyhow::bail!("gonio fit is not built yet")
}
