//! `gonio measure`: parses, hands the measurement to [`host::measure`], prints
//! what it gave and exits with what the result says.
mod args;

pub use args::Args;

use anyhow::Context;
use host::measure::{Measured, measure_with, resume_command};
use host::output::folder::signature::{Keys, SIM_KEY, Signer, fingerprint};
use host::output::folder::store::SignManifest;
use host::session::{Operator, Outcome, PromptOperator, SessionError, SimulatedOperator};
use std::path::Path;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Run `gonio measure`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let interrupted = Arc::new(AtomicBool::new(false));
    let flag = interrupted.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed))
        .context("cannot install the Ctrl-C handler")?;
    // In process the simulated operator swaps the tile; on any port a person is asked.
    let mut operator: Box<dyn Operator> = if args.sim.is_some() {
        Box::new(SimulatedOperator)
    } else {
        Box::new(PromptOperator::new())
    };
    let mut options = args.options();
    // On an instrument a person is there: asked how the sheet lies when the command line
    // does not say (a resumed session or sheet keeps what it began with).
    if args.sim.is_none()
        && args.resume.is_none()
        && (options.orientation.is_none() || options.side.is_none())
        && std::io::IsTerminal::is_terminal(&std::io::stdin())
    {
        let lay = host::session::ask_lay(
            host::analysis::specimen::SheetLay {
                orientation: options.orientation,
                side: options.side,
            },
            &mut std::io::stdin().lock(),
            &mut std::io::stderr(),
        )
        .context("cannot ask how the sheet lies on the port")?;
        options.orientation = lay.orientation;
        options.side = lay.side;
    }
    if let Some(sample) = &options.sim {
        eprintln!(
            "simulated instrument, sample {sample}, seed {} (--seed {} repeats this run; recorded in session.json)",
            options.sim_options.seed, options.sim_options.seed
        );
    }
    // Chosen before anything is measured: a wrong --key stops here, not at the end.
    let store = host::output::folder::store::StoreOptions {
        signer: signer(&args)?.map(|s| Arc::new(s) as Arc<dyn SignManifest>),
        ..Default::default()
    };
    match measure_with(&options, operator.as_mut(), interrupted, store)? {
        Measured::Done {
            dir,
            outcome,
            summary,
        } => {
            print_report(&args, &dir, &outcome, &summary);
            if !args.json {
                print_lay(options.orientation, options.side);
            }
            // The exit code says what `ok` says: 0 clean, 3 flagged.
            Ok(crate::cli::exit::of_result(outcome.ok()))
        }
        Measured::Sheet { dir, sheet, json } => {
            if args.json {
                println!("{json}");
            } else {
                print_sheet(&dir, &sheet);
                let case = sheet.doc.case.clone().unwrap_or_default();
                print_lay(case.orientation, case.side);
            }
            Ok(crate::cli::exit::of_result(sheet.summary.ok()))
        }
        Measured::Stopped {
            dir,
            error,
            record_error,
        } => {
            eprintln!("session stopped: {error}");
            if let Some(record_error) = record_error {
                eprintln!("and its folder could not be updated: {record_error}");
            }
            if matches!(error, SessionError::Saturated(_)) {
                // Resuming would read the same light: the folder keeps what was measured.
                eprintln!(
                    "the readings are kept in {} (points.jsonl: each raw reading, marked saturated)",
                    dir.display()
                );
            } else {
                eprintln!(
                    "readings so far are in {}; continue with: {}",
                    dir.display(),
                    resume_command(&options, &dir)
                );
            }
            let code = if matches!(error, SessionError::Interrupted) {
                crate::cli::exit::INTERRUPTED
            } else {
                crate::cli::exit::FAILED
            };
            Ok(ExitCode::from(code))
        }
    }
}

fn print_report(args: &Args, dir: &Path, outcome: &Outcome, summary: &serde_json::Value) {
    if args.json {
        println!("{summary}");
        return;
    }
    print!("{}", host::analysis::result::to_table(&outcome.report));
    println!(
        "  {}, {:.1} device s measuring (the instrument's own seconds; +{:.1} s homing and calibration); refinements: {}",
        geometries_read(outcome.usable_readings(), outcome.points.len()),
        outcome.device_seconds,
        outcome.setup_seconds,
        if outcome.refinements.is_empty() {
            "none".to_string()
        } else {
            outcome
                .refinements
                .iter()
                .map(|r| match r.delta_deg {
                    Some(d) => format!("δ = {d}° (+{}: {})", r.added, r.reason),
                    None => format!("+{} ({})", r.added, r.reason),
                })
                .collect::<Vec<_>>()
                .join("; ")
        }
    );
    if let Some(drift) = outcome.white_drift {
        println!(
            "  white check: drift {:.2} %{}",
            100.0 * drift,
            if outcome.white_drift_exceeded {
                " — BEYOND THE LIMIT, result marked"
            } else {
                ""
            }
        );
    }
    print_result(outcome.ok(), &outcome.flags);
    println!(
        "  files: {} (gonio verify {} checks them; report.html is the report to read, its glossary and the README's explain the terms)",
        dir.display(),
        dir.display()
    );
}

/// The key that signs the session's folder: `--key`, else with `--sim` the key `sim` (made
/// on first use: a simulated instrument's key, which proves nothing about hardware), else
/// the default or only key. `None` (said on stderr) when there is none, or no keys folder.
fn signer(args: &Args) -> anyhow::Result<Option<Signer>> {
    let keys = match (Keys::from_env(), &args.key) {
        (Ok(keys), _) => keys,
        (Err(e), Some(_)) => return Err(e.into()),
        (Err(e), None) => {
            eprintln!("note: the folder is written unsigned ({e})");
            return Ok(None);
        }
    };
    if args.key.is_none() && args.sim.is_some() {
        let (signer, made) = keys.load_or_create(SIM_KEY).with_context(|| {
            format!("cannot make or read the simulated instrument's key (give --key NAME, or set {} to a writable folder)", host::output::folder::signature::KEYS_DIR_ENV)
        })?;
        if made {
            eprintln!(
                "made the key '{SIM_KEY}' ({}) in {}: it signs the folders of the simulated instrument",
                fingerprint(&signer.public_key()),
                keys.dir().display()
            );
        }
        return Ok(Some(signer));
    }
    let signer = keys.choose(args.key.as_deref())?;
    if signer.is_none() {
        eprintln!(
            "note: no signing key in {}: the folder is written unsigned (gonio keys new NAME makes one)",
            keys.dir().display()
        );
    }
    Ok(signer)
}

fn print_sheet(dir: &Path, sheet: &host::output::folder::sheet::ReadSheet) {
    use host::analysis::spots::SpotCounts;
    let summary = &sheet.summary;
    println!(
        "sheet of '{}': {}",
        sheet.doc.sample,
        sheet.counts().sentence()
    );
    println!("  (σ, ρs, ρd below are sigma_deg, rho_s, rho_d in --json and the folder's files)");
    let value = |v: Option<f64>, digits: usize| {
        v.map_or_else(|| "—".to_string(), |v| format!("{v:.digits$}"))
    };
    for s in &sheet.spots {
        let verdict = SpotCounts::verdict_words(
            summary
                .verdicts
                .iter()
                .find(|j| j.number == s.result.number)
                .map(|j| &j.verdict),
            &s.result.flags,
        );
        // The spot's own report, as its session.json holds it.
        let result = &s.document;
        // To two significant digits of the uncertainty where an interval exists.
        let shown = |v: Option<f64>, key: &str, digits: usize| match (v, result.interval(key)) {
            (Some(v), Some([Some(lo), Some(hi)])) => {
                let (v, ci) = host::analysis::result::value_with_interval(v, lo, hi);
                format!("{v} {ci}")
            }
            (v, _) => value(v, digits),
        };
        let confidence = result
            .class_confidence()
            .map_or_else(String::new, |c| format!(" (confidence {c:.2})"));
        println!(
            "  spot {}: class {}{confidence}  {verdict}",
            s.result.number,
            s.session.class.as_deref().unwrap_or("undecided")
        );
        println!(
            "    σ = {}°   ρs = {}   ρd = {}   (95 % intervals)",
            shown(s.session.values[0], "sigma_deg", 3),
            shown(s.session.values[1], "rho_s", 4),
            shown(s.session.values[2], "rho_d", 4)
        );
        println!(
            "    NMAE {:.2} %, {}, {:.1} device s; flags: {}; report: {}",
            100.0 * result.nmae(),
            geometries_read(
                result.geometries.unwrap_or(0) as usize,
                s.doc.readings_recorded
            ),
            result.device_seconds.unwrap_or(f64::NAN),
            if s.result.flags.is_empty() {
                "none".to_string()
            } else {
                flag_names(&s.result.flags)
            },
            s.dir.join(host::output::folder::SESSION).display()
        );
    }
    let spread = |i: usize| {
        summary.within_relative_sd.map_or_else(
            || "spot-to-spot unknown".to_string(),
            |sd| format!("spot-to-spot sd {:.1} %", 100.0 * sd[i]),
        )
    };
    // The mean to the precision of its own interval, when the answer has one.
    let mean = |i: usize, digits: usize| {
        let ci = summary.answer.as_ref().and_then(|a| {
            [a.ci95.sigma_deg, a.ci95.rho_s, a.ci95.rho_d][i]
                .and_then(|[lo, hi]| host::analysis::result::interval_decimals(lo, hi))
        });
        value(summary.mean[i], ci.unwrap_or(digits))
    };
    println!(
        "  sheet (geometric mean of the spots in it): σ = {}° ({}), ρs = {} ({}), ρd = {} ({})",
        mean(0, 3),
        spread(0),
        mean(1, 4),
        spread(1),
        mean(2, 4),
        spread(2)
    );
    if let Some(answer) = &summary.answer {
        print_answer(answer);
    }
    for note in &summary.notes {
        println!("  note: {note}");
    }
    if let Some(result) = &sheet.doc.result {
        println!(
            "  {:.1} device s measuring the spots (+{:.1} s homing, calibration and moving the sheet)",
            result.device_seconds, result.setup_seconds
        );
    }
    print_result(summary.ok(), &summary.flags);
    println!(
        "  files: {} (gonio verify {} checks them)",
        dir.display(),
        dir.display()
    );
}

/// How the sheet lay on the port, as recorded.
fn print_lay(
    orientation: Option<host::analysis::specimen::Orientation>,
    side: Option<host::analysis::specimen::Side>,
) {
    println!(
        "  laid on the port: orientation {}, side {} (recorded; gonio compare weighs them)",
        host::analysis::specimen::orientation_text(orientation),
        host::analysis::specimen::side_text(side)
    );
}

/// The sheet's answer: its class and confidence, the mean's 95 % intervals, the spots left
/// out, and a warning when its spots disagree in class.
fn print_answer(answer: &host::analysis::spots::SheetAnswer) {
    let interval = |i: Option<[f64; 2]>, digits: usize| {
        i.map_or_else(
            || "—".to_string(),
            |[lo, hi]| {
                let digits = host::analysis::result::interval_decimals(lo, hi).unwrap_or(digits);
                format!("[{lo:.digits$}, {hi:.digits$}]")
            },
        )
    };
    println!(
        "  sheet's class: {}{}{}",
        answer.class.as_deref().unwrap_or("undecided"),
        answer
            .class_confidence
            .map_or_else(String::new, |c| format!(" (confidence {c:.2})")),
        answer
            .undecided
            .as_ref()
            .map_or_else(String::new, |why| format!(" ({why})"))
    );
    println!(
        "  sheet's mean, 95 % intervals (spot-to-spot variation included): σ {}°, ρs {}, ρd {}{}",
        interval(answer.ci95.sigma_deg, 3),
        interval(answer.ci95.rho_s, 4),
        interval(answer.ci95.rho_d, 4),
        if answer.excluded > 0 {
            format!("; {} flagged spot(s) left out", answer.excluded)
        } else {
            String::new()
        }
    );
    if let Some(disagree) = &answer.spots_disagree {
        println!("  WARNING (spots-disagree): {disagree}");
    }
}

/// "result: ok" (with the informational flags noted) or "result: NOT CLEAN" with the flags.
fn print_result(ok: bool, flags: &[host::analysis::flags::Flag]) {
    if ok {
        println!(
            "  result: ok{}",
            if flags.is_empty() {
                String::new()
            } else {
                format!(" (noted: {})", flag_names(flags))
            }
        );
    } else {
        println!("  result: NOT CLEAN, flags: {}", flag_names(flags));
    }
}

fn flag_names(flags: &[host::analysis::flags::Flag]) -> String {
    flags
        .iter()
        .map(|f| f.name())
        .collect::<Vec<_>>()
        .join(", ")
}

/// "N geometries", and how many readings were taken when that is more (a sweep's blanked
/// bins, readings superseded after lost steps): the count is the fit's and readings.csv's.
fn geometries_read(usable: usize, read: usize) -> String {
    if read > usable {
        format!(
            "{usable} geometries ({read} readings taken, {} not usable: see points.jsonl)",
            read - usable
        )
    } else {
        format!("{usable} geometries")
    }
}
