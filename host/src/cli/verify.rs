//! `gonio verify DIR…`: is each session folder whole and as its session left it?
//!
//! Checks every file against `MANIFEST.sha256` (no file missing, changed or added), and
//! that `points.jsonl`, `readings.csv`, `calibration.json` and `session.json` agree. Prints
//! one line per folder that passes and every problem as `file:line: message` on stderr.
//!
//! Exit codes: 0 when every folder passes; 1 when any does not (damaged, changed, or a
//! session that never finished); 2 for a wrong command line.
use host::output::verify::verify;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio verify`.
#[derive(clap::Args)]
#[command(
    after_help = "Exit codes: 0 every folder passes; 1 any does not (a file missing, changed or added since the session finished, records that disagree, a session not finished); 2 a wrong command line."
)]
pub struct Args {
    /// Print one JSON object per folder instead of text.
    #[arg(long)]
    pub json: bool,
    /// Session folders.
    #[arg(required = true, value_name = "DIR")]
    pub dirs: Vec<PathBuf>,
}

/// Run `gonio verify`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut failed = false;
    for dir in &args.dirs {
        if host::output::folder::is_sheet_folder(dir) {
            failed |= !verify_sheet(dir, args.json);
            continue;
        }
        match verify(dir, host::output::report::draw) {
            Ok(v) => {
                if args.json {
                    println!(
                        "{}",
                        serde_json::json!({"schema": host::schema::VERIFY, "kind": "session", "dir": dir.display().to_string(), "ok": true, "files": v.files, "readings": v.readings, "sample": v.doc.sample, "serial_number": v.doc.instrument.serial_number, "runs": v.doc.runs.len(), "problems": []})
                    );
                } else {
                    println!(
                        "{}: verified: {} files match MANIFEST.sha256; {} readings agree in points.jsonl, readings.csv and session.json; sample '{}' on instrument {}, {} run{}",
                        dir.display(),
                        v.files,
                        v.readings,
                        v.doc.sample,
                        v.doc.instrument.serial_number,
                        v.doc.runs.len(),
                        if v.doc.runs.len() == 1 { "" } else { "s" }
                    );
                }
            }
            Err(problems) => {
                failed = true;
                for p in &problems {
                    eprintln!("error: {p}");
                }
                if args.json {
                    println!(
                        "{}",
                        serde_json::json!({"schema": host::schema::VERIFY, "kind": "session", "dir": dir.display().to_string(), "ok": false, "problems": problems.iter().map(ToString::to_string).collect::<Vec<_>>()})
                    );
                } else {
                    eprintln!(
                        "{}: NOT verified ({} problem{})",
                        dir.display(),
                        problems.len(),
                        if problems.len() == 1 { "" } else { "s" }
                    );
                }
            }
        }
    }
    Ok(ExitCode::from(if failed {
        crate::cli::exit::FAILED
    } else {
        crate::cli::exit::OK
    }))
}

/// Check a sheet folder and print the result; whether it verified.
fn verify_sheet(dir: &std::path::Path, json: bool) -> bool {
    match host::output::verify::verify_sheet(dir, host::output::report::draw) {
        Ok(v) => {
            let readings: usize = v.spots.iter().map(|s| s.readings).sum();
            if json {
                println!(
                    "{}",
                    serde_json::json!({"schema": host::schema::VERIFY, "kind": "sheet", "dir": dir.display().to_string(), "ok": true, "spots": v.spots.len(), "readings": readings, "sample": v.sheet.doc.sample, "problems": []})
                );
            } else {
                println!(
                    "{}: verified: a sheet of {} spots of '{}'; MANIFEST.sha256 matches sheet.json and every spot's manifest; every spot folder verifies ({readings} readings); the sheet's result is the one its spots give",
                    dir.display(),
                    v.spots.len(),
                    v.sheet.doc.sample
                );
            }
            true
        }
        Err(problems) => {
            for p in &problems {
                eprintln!("error: {p}");
            }
            if json {
                println!(
                    "{}",
                    serde_json::json!({"schema": host::schema::VERIFY, "kind": "sheet", "dir": dir.display().to_string(), "ok": false, "problems": problems.iter().map(ToString::to_string).collect::<Vec<_>>()})
                );
            } else {
                eprintln!(
                    "{}: NOT verified ({} problem{})",
                    dir.display(),
                    problems.len(),
                    if problems.len() == 1 { "" } else { "s" }
                );
            }
            false
        }
    }
}
