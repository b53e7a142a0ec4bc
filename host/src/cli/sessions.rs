//! `gonio sessions [ROOT]`: the session and sheet folders under ROOT (default `sessions/`,
//! where `gonio measure` makes them), one line each: date, sample, kind, class, state and
//! device time ([`host::output::catalogue`]).
use host::output::catalogue;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio sessions`.
#[derive(clap::Args)]
pub struct Args {
    /// The folder holding session folders.
    #[arg(default_value = "sessions", value_name = "ROOT")]
    pub root: PathBuf,
    /// One JSON object per folder (JSON Lines).
    #[arg(long)]
    pub json: bool,
}

/// Run `gonio sessions`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if !args.root.is_dir() {
        anyhow::bail!(
            "no folder {} (gonio measure makes its session folders in sessions/ of the current folder; give the folder that holds them)",
            args.root.display()
        );
    }
    let entries = catalogue::list(&args.root).map_err(anyhow::Error::msg)?;
    if args.json {
        for e in &entries {
            println!(
                "{}",
                host::schema::tagged(host::schema::SESSIONS_ENTRY, serde_json::to_value(e)?)
            );
        }
        return Ok(ExitCode::SUCCESS);
    }
    if entries.is_empty() {
        println!("no session or sheet folders in {}", args.root.display());
        return Ok(ExitCode::SUCCESS);
    }
    let states: Vec<String> = entries.iter().map(state_column).collect();
    // The sample's and the state's columns are as wide as their widest cell: a flagged
    // spot's state ("FLAGGED: lack-of-fit, instrument-declared") pushed the columns after
    // it out of line.
    let sample_width = entries
        .iter()
        .map(|e| e.sample.chars().count())
        .fold(12, usize::max);
    let state_width = states
        .iter()
        .map(|s| s.chars().count())
        .fold(32, usize::max);
    println!(
        "{:<19} {:<sample_width$} {:<7} {:<CLASS_WIDTH$} {:<state_width$} {:>9}  folder",
        "started", "sample", "kind", "class", "state", "device s"
    );
    for (e, state) in entries.iter().zip(&states) {
        let class = class_column(&e.classes);
        println!(
            "{:<19} {:<sample_width$} {:<7} {:<CLASS_WIDTH$} {:<state_width$} {:>9}  {}",
            e.started.as_deref().map_or_else(
                || "?".to_string(),
                |t| t.chars().take(19).collect::<String>().replace('T', " ")
            ),
            e.sample,
            e.kind,
            class,
            state,
            e.device_seconds
                .map_or("—".to_string(), |s| format!("{s:.1}")),
            e.dir.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The state column: ok (with its informational flags), flagged (with its flags), the
/// status of a session not finished, or why the folder could not be read.
fn state_column(e: &catalogue::Entry) -> String {
    match (&e.problem, e.ok) {
        (Some(problem), _) => format!("UNREADABLE: {problem}"),
        (None, Some(true)) => {
            if e.flags.is_empty() {
                "ok".to_string()
            } else {
                format!("ok ({})", e.flags.join(", "))
            }
        }
        (None, Some(false)) => format!("FLAGGED: {}", e.flags.join(", ")),
        (None, None) => e.status.clone(),
    }
}

/// Width of the class column.
const CLASS_WIDTH: usize = 24;

/// The class column: a session's class, a sheet's spots counted by class ("rough-II ×5",
/// "SG ×3, G ×1"), or, when that does not fit the column, how many spots and classes: a
/// sheet of many spots keeps the table's columns aligned (issue 31: it printed
/// `rough-II,rough-II,…` across the table). `--json` keeps every spot's class.
fn class_column(classes: &[Option<String>]) -> String {
    let names: Vec<&str> = classes
        .iter()
        .map(|c| c.as_deref().unwrap_or("undecided"))
        .collect();
    match names.as_slice() {
        [] => return "—".to_string(),
        [one] => return one.to_string(),
        _ => {}
    }
    // In the order first measured.
    let mut counts: Vec<(&str, usize)> = Vec::new();
    for name in &names {
        match counts.iter_mut().find(|(n, _)| n == name) {
            Some((_, count)) => *count += 1,
            None => counts.push((name, 1)),
        }
    }
    let summary = counts
        .iter()
        .map(|(name, count)| format!("{name} ×{count}"))
        .collect::<Vec<_>>()
        .join(", ");
    if summary.chars().count() <= CLASS_WIDTH {
        summary
    } else {
        format!("{} spots, {} classes", names.len(), counts.len())
    }
}
