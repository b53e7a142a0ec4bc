//! `gonio accuracy`: the accuracy campaign on the simulated instrument (docs/ACCURACY.md).
use anyhow::{Context, bail};
use host::study::accuracy;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio accuracy`.
#[derive(clap::Args)]
pub struct Args {
    /// Folder for accuracy.csv and summary.md.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Sessions per coverage case (G, SG, PPC, J1 × ideal and real physics) and policy.
    #[arg(long, default_value_t = 200)]
    pub coverage_sessions: usize,
    /// Sessions per robustness case (non-Gaussian lobes, bump, forward lobe, arm offset)
    /// and policy.
    #[arg(long, default_value_t = 100)]
    pub robust_sessions: usize,
    /// Policies to run every case under.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = accuracy::DEFAULT_POLICIES)]
    pub policies: Vec<host::session::PolicyChoice>,
    /// Worker threads (default: one per core).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Run `gonio accuracy`: exit 0 when every claim held, 3 when any did not.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.coverage_sessions == 0 && args.robust_sessions == 0 {
        bail!("--coverage-sessions and --robust-sessions cannot both be 0");
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if threads == 0 {
        bail!("--threads must be at least 1");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let cases = accuracy::cases();
    if args.policies.is_empty() {
        bail!("--policies needs at least one policy");
    }
    let specs = accuracy::plan_policies(
        &cases,
        args.coverage_sessions,
        args.robust_sessions,
        &args.policies,
    );
    let bar = ProgressBar::new(specs.len() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{bar:30}] {pos}/{len} sessions, {elapsed} ({eta} left)",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message("simulated sessions against the truth");
    let rows = accuracy::run_all(&cases, &specs, threads, &|| bar.inc(1));
    bar.finish_and_clear();
    if rows.len() != specs.len() {
        bail!(
            "{} of {} sessions did not run (a worker panicked)",
            specs.len() - rows.len(),
            specs.len()
        );
    }
    let csv = args.out.join("accuracy.csv");
    std::fs::write(&csv, accuracy::to_csv(&cases, &rows))
        .with_context(|| format!("cannot write {}", csv.display()))?;
    let summary = accuracy::summary_markdown(&cases, &rows);
    let md = args.out.join("summary.md");
    std::fs::write(&md, &summary).with_context(|| format!("cannot write {}", md.display()))?;
    print!("{summary}");
    eprintln!("wrote {} and {}", csv.display(), md.display());
    let held = accuracy::verdicts(&cases, &rows)
        .iter()
        .all(|(_, held)| *held);
    Ok(if held {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(crate::cli::exit::FLAGGED)
    })
}
