//! `gonio reliability`: the fault campaign on the simulated instrument (docs/RELIABILITY.md).
use anyhow::{Context, bail};
use host::study::reliability::{self, FaultKind};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio reliability`.
#[derive(clap::Args)]
pub struct Args {
    /// Folder for reliability.csv and summary.md.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Sessions in the campaign (each with a clean twin), drawn over the fault kinds.
    #[arg(long, default_value_t = 3000)]
    pub sessions: usize,
    /// Sessions whose cable never comes back (how the host gives up).
    #[arg(long, default_value_t = 200)]
    pub give_ups: usize,
    /// Worker threads (default: one per core).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Instead of the fault campaign: this many sheets interrupted one, two or three times
    /// in a row (kills and Ctrl-C at random writes, give-ups), each interruption resumed
    /// (interruptions.csv, interruptions.md).
    #[arg(long, value_name = "N")]
    pub interruptions: Option<usize>,
    /// Instead of the fault campaign: this many sessions of this binary's `gonio measure`
    /// against `gonio sim` on a pseudo-terminal, with corrupt ≤ 0.01, drop ≤ 0.02 and an
    /// unplug at a drawn moment, each checked to end within its bounds (pty.csv, pty.md).
    #[arg(long, value_name = "N", conflicts_with = "interruptions")]
    pub pty: Option<usize>,
    /// The interruption or pty campaign's seed (its draws repeat with it).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// The pty campaign of `gonio reliability --pty N`.
fn pty(args: &Args, sessions: usize, threads: usize) -> anyhow::Result<ExitCode> {
    use host::study::pty as campaign;
    let gonio = std::env::current_exe().context("cannot find this gonio binary")?;
    let base = args.out.join("folders");
    std::fs::create_dir_all(&base).with_context(|| format!("cannot create {}", base.display()))?;
    let bar = ProgressBar::new(sessions as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{bar:30}] {pos}/{len} sessions, {elapsed} ({eta} left)",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message("pty sessions");
    let started = std::time::Instant::now();
    let rows = campaign::run_all(sessions, args.seed, &gonio, &base, threads, &|| bar.inc(1))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    bar.finish_and_clear();
    let summary = campaign::summary_markdown(&rows, args.seed, started.elapsed().as_secs_f64());
    let held = rows.len() == sessions && rows.iter().all(|r| r.failure.is_none());
    write_campaign(
        &args.out,
        "pty",
        &campaign::to_csv(&rows),
        &summary,
        &base,
        held,
    )
}

/// The interruption campaign of `gonio reliability --interruptions N`.
fn interruptions(args: &Args, sessions: usize, threads: usize) -> anyhow::Result<ExitCode> {
    use host::study::interruptions as campaign;
    // Its folders on a RAM disk when there is one: every reading is synced.
    let ram = std::path::Path::new("/dev/shm");
    let base = if ram.is_dir() {
        ram.join(format!("gonio-interruptions-{}", std::process::id()))
    } else {
        args.out.join("folders")
    };
    std::fs::create_dir_all(&base).with_context(|| format!("cannot create {}", base.display()))?;
    let bar = ProgressBar::new(sessions as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} sheets, {elapsed} ({eta} left)")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message("interrupted sheets");
    let rows = campaign::run_all(sessions, args.seed, &base, threads, &|| bar.inc(1))
        .map_err(|e| anyhow::anyhow!("an uninterrupted sheet failed: {e}"))?;
    bar.finish_and_clear();
    let summary = campaign::summary_markdown(&rows, args.seed);
    let held = rows.len() == sessions && rows.iter().all(|r| r.failure.is_none());
    write_campaign(
        &args.out,
        "interruptions",
        &campaign::to_csv(&rows),
        &summary,
        &base,
        held,
    )
}

/// A campaign's end, the same for the pty and the interruption campaigns: `NAME.csv` and
/// `NAME.md` written in `out`, the summary printed, the (emptied) folders' `base` removed,
/// and the exit status: success only when every session held.
fn write_campaign(
    out: &std::path::Path,
    name: &str,
    csv_text: &str,
    summary: &str,
    base: &std::path::Path,
    held: bool,
) -> anyhow::Result<ExitCode> {
    let csv = out.join(format!("{name}.csv"));
    std::fs::write(&csv, csv_text).with_context(|| format!("cannot write {}", csv.display()))?;
    let md = out.join(format!("{name}.md"));
    std::fs::write(&md, summary).with_context(|| format!("cannot write {}", md.display()))?;
    print!("{summary}");
    eprintln!("wrote {} and {}", csv.display(), md.display());
    let _ = std::fs::remove_dir(base);
    Ok(if held {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// Run `gonio reliability`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.sessions == 0 {
        bail!("--sessions must be at least 1");
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if threads == 0 {
        bail!("--threads must be at least 1");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    if let Some(sessions) = args.interruptions {
        if sessions == 0 {
            bail!("--interruptions must be at least 1");
        }
        return interruptions(&args, sessions, threads);
    }
    if let Some(sessions) = args.pty {
        if sessions == 0 {
            bail!("--pty must be at least 1");
        }
        return pty(&args, sessions, threads);
    }
    let durations = reliability::session_durations()?;
    let specs: Vec<_> = (0..args.sessions)
        .map(|k| reliability::draw(k, &FaultKind::ALL, &durations))
        .collect();
    let bar = ProgressBar::new(specs.len() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{bar:30}] {pos}/{len} sessions, {elapsed} ({eta} left)",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message("faulty sessions and their clean twins");
    let rows = reliability::run_all(&specs, true, threads, &|| bar.inc(1));
    bar.finish_and_clear();
    let give_ups = reliability::give_ups(args.give_ups, &durations, threads);
    let csv = args.out.join("reliability.csv");
    std::fs::write(&csv, reliability::to_csv(&rows))
        .with_context(|| format!("cannot write {}", csv.display()))?;
    let summary = reliability::summary_markdown(&rows, &give_ups);
    let md = args.out.join("summary.md");
    std::fs::write(&md, &summary).with_context(|| format!("cannot write {}", md.display()))?;
    print!("{summary}");
    eprintln!("wrote {} and {}", csv.display(), md.display());
    Ok(ExitCode::SUCCESS)
}
