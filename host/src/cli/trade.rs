//! `gonio trade`: the speed–accuracy trade study on the simulated instrument.
use anyhow::{Context, bail};
use host::study::trade;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio trade`.
#[derive(clap::Args)]
pub struct Args {
    /// Folder for trade.csv, summary.md and pareto.svg.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Seeds per paper and configuration [default: 20, or 3 with --quick].
    #[arg(long)]
    pub seeds: Option<u64>,
    /// Quick look: 3 seeds (unless --seeds is given) and the fixed schedules at 100 ms only.
    #[arg(long)]
    pub quick: bool,
    /// Worker threads (default: one per core).
    #[arg(long)]
    pub threads: Option<usize>,
    /// The simulated instrument's errors: ideal, or the accuracy study's realistic set
    /// (range-gain, tile and arm-zero errors, docs/ACCURACY.md).
    #[arg(long, value_enum, default_value = "ideal")]
    pub physics: host::instrument::sim::Physics,
    /// Only these policies (comma-separated: strategy1, strategy2, paper, adaptive, sweep);
    /// all by default. `--policies sweep,adaptive` is the sweep settings' front with the
    /// adaptive policy to compare against, in a fraction of the whole study's time.
    #[arg(long, value_delimiter = ',', value_name = "LIST")]
    pub policies: Vec<String>,
}

/// Run `gonio trade`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let seeds = args.seeds.unwrap_or(if args.quick { 3 } else { 20 });
    if seeds == 0 {
        bail!("--seeds must be at least 1");
    }
    let mut runs = trade::plan_runs(seeds, args.quick);
    if let Some(unknown) = args
        .policies
        .iter()
        .find(|p| !trade::POLICIES.contains(&p.as_str()))
    {
        bail!(
            "--policies: unknown policy '{unknown}' (known: {})",
            trade::POLICIES.join(", ")
        );
    }
    if !args.policies.is_empty() {
        runs.retain(|r| args.policies.iter().any(|p| p == r.policy));
    }
    for run in &mut runs {
        run.physics = args.physics;
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let bar = ProgressBar::new(runs.len() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{bar:30}] {pos}/{len} sessions, {elapsed} ({eta} left)",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message("simulated sessions");
    let rows = trade::run_all(&runs, threads, &|| bar.inc(1))?;
    bar.finish_and_clear();
    let csv = args.out.join("trade.csv");
    std::fs::write(&csv, trade::to_csv(&rows))
        .with_context(|| format!("cannot write {}", csv.display()))?;
    let motion = host::session::order::Motion::reference();
    let order_table = host::session::order::study_markdown(&host::session::order::study(
        &motion,
        u32::from(trade::TARGET_INTEGRATION_MS),
    ));
    let summary = trade::summary_markdown(&rows, seeds, &order_table);
    let md = args.out.join("summary.md");
    std::fs::write(&md, &summary).with_context(|| format!("cannot write {}", md.display()))?;
    let svg = args.out.join(host::study::trade_plot::PARETO_FILE);
    host::study::trade_plot::write_pareto(&svg, &trade::pareto(&rows))
        .with_context(|| format!("cannot write {}", svg.display()))?;
    print!("{summary}");
    eprintln!(
        "wrote {}, {} and {}",
        csv.display(),
        md.display(),
        svg.display()
    );
    Ok(ExitCode::SUCCESS)
}
