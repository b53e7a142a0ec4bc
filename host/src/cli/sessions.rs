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
    println!(
        "{:<19} {:<12} {:<7} {:<24} {:<32} {:>9}  folder",
        "started", "sample", "kind", "class", "state", "device s"
    );
    for e in &entries {
        let classes: Vec<&str> = e
            .classes
            .iter()
            .map(|c| c.as_deref().unwrap_or("undecided"))
            .collect();
        let class = if classes.is_empty() {
            "—".to_string()
        } else {
            classes.join(",")
        };
        let state = match (&e.problem, e.ok) {
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
        };
        println!(
            "{:<19} {:<12} {:<7} {:<24} {:<32} {:>9}  {}",
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
