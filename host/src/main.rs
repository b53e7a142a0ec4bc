//! `gonio`: the host command line. One module per subcommand in [`cli`], each with its
//! own clap struct and `run()`, handing the work to the `host` library.
mod cli;

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

// Parsed once per run: the size of the largest subcommand's arguments costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum Command {
    /// Measure a sheet: home, calibrate, Strategy 1, fit, refine until σ > σ_l, classify.
    Measure(cli::measure::Args),
    /// A QA batch: many sheets measured against a master stock of the library, pass/fail per sheet, statistics and control limits, an HTML report and a CSV.
    Batch(cli::batch::Args),
    /// Fit the TSL model to measured radiance factors and classify each data set.
    Fit(cli::fit::Args),
    /// Put firmware on the instrument through a debug probe (probe-rs): check the image, program, verify, reset, handshake.
    Flash(cli::flash::Args),
    /// List serial ports; instruments (by USB VID/PID) are marked.
    Ports(cli::ports::Args),
    /// Serve the simulated instrument on a pseudo-terminal (prints its path first).
    Sim(cli::sim::Args),
    /// Compare two measured sheets: the likelihood ratio of "same paper stock" against "different stocks".
    Compare(cli::compare::Args),
    /// Speed against accuracy: whole simulated sessions over papers, seeds and policies.
    Trade(cli::trade::Args),
    /// Reliability under bench faults: simulated sessions with pulled cables, a noisy link and slow operators.
    Reliability(cli::reliability::Args),
    /// Accuracy on sheets and instruments that are not the model: coverage of the intervals, never confidently wrong.
    Accuracy(cli::accuracy::Args),
    /// Forensic validation: a simulated population of stocks, likelihood ratios of held-out pairs, Cllr and a Tippett plot.
    Forensic(cli::forensic::Args),
    /// Check session folders: every file against MANIFEST.sha256, the records against each other, the signature and its signer.
    Verify(cli::verify::Args),
    /// The keys that sign folders, exports and reports, and the public keys of others you trust.
    Keys(cli::keys::Args),
    /// Print the completion script of a shell (bash, zsh, fish, elvish, powershell).
    Completions(cli::completions::Args),
    /// List the session and sheet folders under a folder (default sessions/): date, sample, class, state, device time.
    Sessions(cli::sessions::Args),
    /// Draw the report a person reads (report.html) of finished session or sheet folders.
    Report(cli::report::Args),
    /// The reference library of paper stocks: add measured sheets, list, remove, export, import, search.
    Library(cli::library::Args),
    /// The instrument's self-test: clocks, step pulses, interrupts, stack, switches, drivers and detector, judged against their limits.
    Selftest(cli::selftest::Args),
    /// Measure the instrument with a black glass and the white tile: angular response, arm zero, gains, noise, lamp; writes its profile.
    Characterize(cli::characterize::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Measure(args) => cli::measure::run(args),
        Command::Batch(args) => cli::batch::run(args),
        Command::Fit(args) => cli::fit::run(args),
        Command::Flash(args) => cli::flash::run(args),
        Command::Ports(args) => cli::ports::run(args),
        Command::Sim(args) => cli::sim::run(args),
        Command::Compare(args) => cli::compare::run(args),
        Command::Trade(args) => cli::trade::run(args),
        Command::Reliability(args) => cli::reliability::run(args),
        Command::Accuracy(args) => cli::accuracy::run(args),
        Command::Forensic(args) => cli::forensic::run(args),
        Command::Verify(args) => cli::verify::run(args),
        Command::Keys(args) => cli::keys::run(args),
        Command::Library(args) => cli::library::run(args),
        Command::Selftest(args) => cli::selftest::run(args),
        Command::Characterize(args) => cli::characterize::run(args),
        Command::Report(args) => cli::report::run(args),
        Command::Sessions(args) => cli::sessions::run(args),
        Command::Completions(args) => cli::completions::run(args, &mut Cli::command()),
    };
    match result {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {}", host::text::error_chain(&err));
            // A value on the command line refused after clap parsed it exits as clap's own
            // refusals do.
            if err
                .chain()
                .any(|c| c.downcast_ref::<host::UsageError>().is_some())
            {
                ExitCode::from(cli::exit::USAGE)
            } else {
                ExitCode::from(cli::exit::FAILED)
            }
        }
    }
}
