//! `gonio`: the host command line. One module per subcommand in `host::cli`, each with
//! its own clap struct and `run()`.
use clap::{CommandFactory, Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "gonio",
    version,
    about = "Gonio-reflectometer host: measure, fit and classify white papers"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Measure a sheet: home, calibrate, Strategy 1, fit, refine until σ > σ_l, classify.
    Measure(host::cli::measure::Args),
    /// Fit the TSL model to measured radiance factors and classify each data set.
    Fit(host::cli::fit::Args),
    /// Put firmware on the instrument through a debug probe (probe-rs): check the image, program, verify, reset, handshake.
    Flash(host::cli::flash::Args),
    /// List serial ports; instruments (by USB VID/PID) are marked.
    Ports(host::cli::ports::Args),
    /// Serve the simulated instrument on a pseudo-terminal (prints its path first).
    Sim(host::cli::sim::Args),
    /// Compare two measured sheets: the likelihood ratio of "same paper stock" against "different stocks".
    Compare(host::cli::compare::Args),
    /// Speed against accuracy: whole simulated sessions over papers, seeds and policies.
    Trade(host::cli::trade::Args),
    /// Reliability under bench faults: simulated sessions with pulled cables, a noisy link and slow operators.
    Reliability(host::cli::reliability::Args),
    /// Accuracy on sheets and instruments that are not the model: coverage of the intervals, never confidently wrong.
    Accuracy(host::cli::accuracy::Args),
    /// Forensic validation: a simulated population of stocks, likelihood ratios of held-out pairs, Cllr and a Tippett plot.
    Forensic(host::cli::forensic::Args),
    /// Check session folders: every file against MANIFEST.sha256, the records against each other.
    Verify(host::cli::verify::Args),
    /// Print the completion script of a shell (bash, zsh, fish, elvish, powershell).
    Completions(host::cli::completions::Args),
    /// List the session and sheet folders under a folder (default sessions/): date, sample, class, state, device time.
    Sessions(host::cli::sessions::Args),
    /// Draw the report a person reads (report.html) of finished session or sheet folders.
    Report(host::cli::report::Args),
    /// The reference library of paper stocks: add measured sheets, list, remove, export, import, search.
    Library(host::cli::library::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Measure(args) => host::cli::measure::run(args),
        Command::Fit(args) => host::cli::fit::run(args),
        Command::Flash(args) => host::cli::flash::run(args),
        Command::Ports(args) => host::cli::ports::run(args),
        Command::Sim(args) => host::cli::sim::run(args),
        Command::Compare(args) => host::cli::compare::run(args),
        Command::Trade(args) => host::cli::trade::run(args),
        Command::Reliability(args) => host::cli::reliability::run(args),
        Command::Accuracy(args) => host::cli::accuracy::run(args),
        Command::Forensic(args) => host::cli::forensic::run(args),
        Command::Verify(args) => host::cli::verify::run(args),
        Command::Library(args) => host::cli::library::run(args),
        Command::Report(args) => host::cli::report::run(args),
        Command::Sessions(args) => host::cli::sessions::run(args),
        Command::Completions(args) => host::cli::completions::run(args, &mut Cli::command()),
    };
    match result {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
