//! `gonio accuracy`: the accuracy campaign on the simulated instrument (docs/ACCURACY.md),
//! or with `--instruments N` the campaign of drawn instruments characterized on the black
//! glass (docs/ACCURACY.md, "The instrument as measured"), or with `--shapes SEEDS` the
//! campaign of sheets that are not TSL (issue 28, `host/src/study/shapes.rs`).
use anyhow::{Context, bail};
use host::session::PolicyChoice;
use host::study::{accuracy, instruments, shapes};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio accuracy`.
#[derive(clap::Args)]
pub struct Args {
    /// Folder for accuracy.csv and summary.md (with --instruments: instruments.csv,
    /// sessions.csv and summary.md; with --shapes: sessions.csv and summary.md).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Sessions per coverage case (G, SG, PPC, J1 × ideal and real physics) and policy.
    #[arg(long, default_value_t = 200)]
    pub coverage_sessions: usize,
    /// Sessions per robustness case (non-Gaussian lobes, bump, forward lobe, arm offset)
    /// and policy.
    #[arg(long, default_value_t = 100)]
    pub robust_sessions: usize,
    /// Instead of the campaign above: N simulated instruments drawn unlike the declared
    /// one (--physics drawn), each characterized on the black glass, then the eight papers
    /// measured on it under each policy with its profile and without.
    #[arg(long, value_name = "N", conflicts_with_all = ["coverage_sessions", "robust_sessions"])]
    pub instruments: Option<usize>,
    /// Instead of the campaigns above: sheets that are not TSL (issue 28), every departure
    /// the simulator has at two strengths and the exact-TSL control, on the eight papers,
    /// SEEDS sessions each per policy, ideal physics.
    #[arg(long, value_name = "SEEDS", conflicts_with_all = ["coverage_sessions", "robust_sessions", "instruments"])]
    pub shapes: Option<usize>,
    /// With --shapes: only these departures (haze, peak-shift, ggx, cauchy, beckmann,
    /// blinn-phong, asymmetry, fresnel-flat, sigma-slope, oren-nayar, grazing, retro; tsl:
    /// the control alone, which always runs).
    #[arg(long, value_name = "LIST", value_delimiter = ',', requires = "shapes")]
    pub departures: Vec<String>,
    /// With --shapes: only these papers (G, SG, PPC, MC, J1, J2, J3, J4).
    #[arg(long, value_name = "LIST", value_delimiter = ',', requires = "shapes")]
    pub papers: Vec<String>,
    /// With --shapes: the sessions' indices start here (seeds 0…SEEDS−1 by default), so a
    /// figure can be measured on seeds a change was not tuned on.
    #[arg(long, value_name = "INDEX", requires = "shapes", default_value_t = 0)]
    pub first_seed: usize,
    /// Seed the instruments of --instruments are drawn from.
    #[arg(long, value_name = "SEED", requires = "instruments", default_value_t = instruments::DEFAULT_BASE_SEED)]
    pub instruments_seed: u64,
    /// Policies to run every case under [default: adaptive,paper; with --instruments or
    /// --shapes: sweep,adaptive].
    #[arg(long, value_enum, value_delimiter = ',')]
    pub policies: Vec<PolicyChoice>,
    /// Worker threads (default: one per core).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// A progress bar of `len` items.
fn bar(len: usize, what: &str, message: &'static str) -> ProgressBar {
    let bar = ProgressBar::new(len as u64);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{msg}} [{{bar:30}}] {{pos}}/{{len}} {what}, {{elapsed}} ({{eta}} left)"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message(message);
    bar
}

/// Run `gonio accuracy`: exit 0 when every claim held, 3 when any did not.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if threads == 0 {
        bail!("--threads must be at least 1");
    }
    if let Some(n) = args.instruments {
        return run_instruments(&args, n, threads);
    }
    if let Some(seeds) = args.shapes {
        return run_shapes(&args, seeds, threads);
    }
    if args.coverage_sessions == 0 && args.robust_sessions == 0 {
        bail!("--coverage-sessions and --robust-sessions cannot both be 0");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let cases = accuracy::cases();
    let policies = if args.policies.is_empty() {
        accuracy::DEFAULT_POLICIES.to_vec()
    } else {
        args.policies.clone()
    };
    let specs = accuracy::plan_policies(
        &cases,
        args.coverage_sessions,
        args.robust_sessions,
        &policies,
    );
    let bar = bar(
        specs.len(),
        "sessions",
        "simulated sessions against the truth",
    );
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
    Ok(exit(held))
}

fn exit(held: bool) -> ExitCode {
    if held {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(crate::cli::exit::FLAGGED)
    }
}

/// `gonio accuracy --instruments N`.
fn run_instruments(args: &Args, n: usize, threads: usize) -> anyhow::Result<ExitCode> {
    if n == 0 {
        bail!("--instruments must be at least 1");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let policies = if args.policies.is_empty() {
        instruments::DEFAULT_POLICIES.to_vec()
    } else {
        args.policies.clone()
    };
    let design = instruments::Design::new(n, args.instruments_seed, &policies);
    let bar = bar(
        design.work(),
        "characterizations and sessions",
        "drawn instruments, characterized and measured",
    );
    let campaign = instruments::run(&design, threads, &|| bar.inc(1))?;
    bar.finish_and_clear();
    let written = [
        ("instruments.csv", instruments::instruments_csv(&campaign)),
        ("sessions.csv", instruments::sessions_csv(&campaign)),
        ("summary.md", instruments::summary_markdown(&campaign)),
    ];
    for (name, text) in &written {
        let path = args.out.join(name);
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    print!("{}", written[2].1);
    eprintln!(
        "wrote instruments.csv, sessions.csv and summary.md in {}",
        args.out.display()
    );
    let held = instruments::verdicts(&campaign).iter().all(|(_, h)| *h);
    Ok(exit(held))
}

/// `gonio accuracy --shapes SEEDS`.
fn run_shapes(args: &Args, seeds: usize, threads: usize) -> anyhow::Result<ExitCode> {
    if seeds == 0 {
        bail!("--shapes must be at least 1");
    }
    let mut kinds = Vec::new();
    for name in &args.departures {
        if name.eq_ignore_ascii_case("tsl") {
            continue;
        }
        let Some(kind) = shapes::Kind::named(name) else {
            bail!(
                "--departures: no departure '{name}': use {} or tsl",
                shapes::KINDS.map(shapes::Kind::name).join(", ")
            );
        };
        if !kinds.contains(&kind) {
            kinds.push(kind);
        }
    }
    if args.departures.is_empty() {
        kinds = shapes::KINDS.to_vec();
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let policies = if args.policies.is_empty() {
        shapes::DEFAULT_POLICIES.to_vec()
    } else {
        args.policies.clone()
    };
    let mut papers = Vec::new();
    for name in &args.papers {
        let Some(paper) = shapes::PAPERS.iter().find(|p| p.eq_ignore_ascii_case(name)) else {
            bail!(
                "--papers: no paper '{name}': use {}",
                shapes::PAPERS.join(", ")
            );
        };
        if !papers.contains(paper) {
            papers.push(*paper);
        }
    }
    if papers.is_empty() {
        papers = shapes::PAPERS.to_vec();
    }
    let design = shapes::Design {
        shapes: shapes::Shape::all(&kinds),
        papers,
        first_index: args.first_seed,
        ..shapes::Design::new(seeds, &policies)
    };
    let bar = bar(
        shapes::work(&design),
        "sessions",
        "sheets that are not TSL, measured",
    );
    let campaign = shapes::run(&design, threads, &|| bar.inc(1))?;
    bar.finish_and_clear();
    let summary = shapes::summary_markdown(&campaign);
    let written = [
        ("sessions.csv", shapes::to_csv(&campaign)),
        ("members.csv", shapes::members_csv(&campaign)),
        ("summary.md", summary.clone()),
    ];
    for (name, text) in &written {
        let path = args.out.join(name);
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    print!("{summary}");
    eprintln!(
        "wrote sessions.csv, members.csv and summary.md in {}",
        args.out.display()
    );
    let held = shapes::verdicts(&campaign).iter().all(|(_, h)| *h);
    Ok(exit(held))
}
