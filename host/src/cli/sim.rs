//! `gonio sim`: the simulated instrument on a pseudo-terminal, for any serial client.
use anyhow::Context;
use host::instrument::sim::SimOptions;
use std::io::Write;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Arguments of `gonio sim`.
#[derive(clap::Args)]
pub struct Args {
    /// The sample on the port: G, SG, PPC, MC, J1, J2, J3, J4, or custom:SIGMA,RHO_S,RHO_D,ETA.
    pub sample: String,
    #[command(flatten)]
    pub options: SimOptions,
}

/// Run `gonio sim`: print the device path on the first line, serve until Ctrl-C.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let options = args.options.with_seed(None);
    // A simulator option (the sample's name, a fault) is the command line's: exit 2.
    let mut instrument = options
        .instrument(&args.sample)
        .map_err(|e| host::UsageError(e.to_string()))?;
    let server = hil_sim::pty::PtyServer::open().context("cannot open a pseudo-terminal")?;
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed))
        .context("cannot install the Ctrl-C handler")?;
    let mut stdout = std::io::stdout().lock();
    writeln!(stdout, "{}", server.path().display())?;
    stdout.flush()?;
    eprintln!(
        "simulated instrument with sample {}, seed {} (--seed {} repeats it), on {}; Ctrl-C stops it",
        args.sample,
        options.seed,
        options.seed,
        server.path().display()
    );
    server
        .serve(&mut instrument, &stop)
        .context("simulated instrument stopped")?;
    Ok(ExitCode::SUCCESS)
}
