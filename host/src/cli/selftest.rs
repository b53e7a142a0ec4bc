//! `gonio selftest`: the instrument's self-test, judged: what a builder runs before a first
//! motion and a lab before a case (docs/HARDWARE.md's first-power-on checklist).
use super::exit;
use anyhow::Context;
use host::instrument::link::{Client, RetryPolicy, Transport};
use host::instrument::selftest::{self, SelfTest, Verdict};
use host::instrument::sim::SimOptions;
use std::process::ExitCode;

/// Arguments of `gonio selftest`.
#[derive(clap::Args)]
pub struct Args {
    /// The instrument's serial port (default: the one instrument attached).
    #[arg(long, value_name = "PATH", conflicts_with = "sim")]
    pub port: Option<String>,
    /// Test the simulated instrument (its faults with --faults, e.g. diag-stuck=source).
    #[arg(long)]
    pub sim: bool,
    /// Print the checks as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub sim_options: SimOptions,
}

/// Run `gonio selftest`: exit 0 when every check passed, 3 when one failed.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let result = if args.sim {
        // The self-test keeps seed 1 unless given: its figures are not a measurement.
        let instrument = args
            .sim_options
            .clone()
            .with_seed(Some(1))
            .instrument("G")?;
        test(Client::new(instrument, RetryPolicy::default()))?
    } else {
        let transport = host::measure::open_port(args.port.as_deref())?;
        test(Client::new(transport, RetryPolicy::default()))?
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&result)?);
    } else {
        print_table(&result);
    }
    Ok(exit::of_result(result.passed()))
}

fn test<T: Transport>(mut client: Client<T>) -> anyhow::Result<SelfTest> {
    let info = client.hello().context("no handshake with the instrument")?;
    eprintln!(
        "self-test of {} (firmware {}): drivers off, the arms do not move; they are not homed afterwards",
        info.serial_number, info.firmware_version
    );
    selftest::run(&mut client, &info).context("the self-test did not finish")
}

fn print_table(result: &SelfTest) {
    println!(
        "instrument {} firmware {}",
        result.serial_number, result.firmware_version
    );
    for check in &result.checks {
        let verdict = match check.verdict {
            Verdict::Pass => "pass",
            Verdict::Fail => "FAIL",
            Verdict::NotMeasured => "n/a",
        };
        println!(
            "{verdict:<5} {:<20} {:<42} limit {}",
            check.name, check.measured, check.limit
        );
        if let Some(advice) = &check.advice {
            println!("      └ {advice}");
        }
    }
    let failed = result
        .checks
        .iter()
        .filter(|c| c.verdict == Verdict::Fail)
        .count();
    let unmeasured = result
        .checks
        .iter()
        .filter(|c| c.verdict == Verdict::NotMeasured)
        .count();
    println!(
        "{}: {failed} failed, {unmeasured} not measured",
        if failed == 0 { "PASSED" } else { "FAILED" }
    );
}
