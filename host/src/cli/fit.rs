//! `gonio fit`: fit the TSL model to measured data sets, check σ against σ_l and classify.
//!
//! Each file is read and each data set fitted on its own: a bad file or data set is
//! reported on stderr as `file:line: message` and the others still get their results;
//! the exit status is non-zero if anything failed.
use crate::classify::{self, Classification};
use crate::dataset::{self, DataSet};
use crate::fit::{self, FitOptions, FitResult};
use crate::model::{self, PARAM_NAMES};
use crate::sampling::{self, Delta, SigmaCheck};
use serde_json::{Value, json};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `gonio fit`.
#[derive(clap::Args)]
pub struct Args {
    /// Print one JSON object per data set (JSON Lines) instead of tables.
    #[arg(long)]
    pub json: bool,
    /// Sampling interval δ around the specular direction, degrees, for the σ_l check
    /// (default: the schedule's nominal δ, else measured from the geometries).
    #[arg(long, value_name = "DEG")]
    pub delta: Option<f64>,
    /// Full width of the detector's angular acceptance, degrees (0 leaves it out).
    #[arg(long, value_name = "DEG", default_value_t = model::DEFAULT_ACCEPTANCE_DEG)]
    pub acceptance: f64,
    /// CSV files: header with theta_i, theta_r, radiance_factor; optional std, sample.
    #[arg(required = true, value_name = "FILE")]
    pub files: Vec<PathBuf>,
}

/// Everything reported about one data set.
pub struct Report {
    /// File it came from.
    pub file: PathBuf,
    /// Sample name.
    pub sample: String,
    /// The fit.
    pub fit: FitResult,
    /// δ used for the σ_l check, if one could be found.
    pub delta: Option<Delta>,
    /// The σ_l check.
    pub check: Option<SigmaCheck>,
    /// The classification.
    pub classification: Classification,
}

/// Fit, check and classify one data set; errors are `line: message`.
pub fn analyse(file: &Path, set: &DataSet, options: &FitOptions, delta_deg: Option<f64>) -> Result<Report, String> {
    let result = fit::fit(&set.observations, options).map_err(|e| {
        let line = e.reading_index().and_then(|i| set.lines.get(i)).or(set.lines.first()).copied().unwrap_or(1);
        format!("{line}: sample '{}': {e}", set.sample)
    })?;
    let delta = sampling::delta(&set.geometries(), delta_deg);
    let check = delta.map(|d| sampling::check_sigma(result.sigma_deg(), d.deg));
    let classification = classify::classify(&result);
    Ok(Report { file: file.to_path_buf(), sample: set.sample.clone(), fit: result, delta, check, classification })
}

fn finite_or_null(x: Option<f64>) -> Value {
    x.filter(|v| v.is_finite()).map_or(Value::Null, |v| json!(v))
}

/// The JSON object of a report (one line of `--json`).
pub fn to_json(r: &Report) -> Value {
    let f = &r.fit;
    let mut ci = serde_json::Map::new();
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        ci.insert(name.to_string(), f.ci95[i].map_or(Value::Null, |(lo, hi)| json!([lo, hi])));
    }
    json!({
        "file": r.file.display().to_string(),
        "sample": r.sample,
        "n": f.n,
        "sigma_deg": finite_or_null(f.sigma_deg()),
        "sigma_upper_deg": finite_or_null(f.sigma_upper_deg()),
        "rho_s": finite_or_null(f.reported(model::RHO_S)),
        "rho_d": finite_or_null(f.reported(model::RHO_D)),
        "eta": finite_or_null(f.reported(model::ETA)),
        "nmae": f.nmae,
        "rms": f.rms,
        "cost": f.cost,
        "delta_deg": finite_or_null(r.delta.map(|d| d.deg)),
        "delta_source": r.delta.map(|d| d.source),
        "sigma_l_deg": finite_or_null(r.check.map(|c| c.sigma_l_deg)),
        "sigma_ok": r.check.is_some_and(|c| c.sigma_ok),
        "group": r.classification.group.name(),
        "class": r.classification.class.name(),
        "class_confidence": r.classification.confidence,
        "nearest_reference": r.classification.nearest_reference,
        "nearest_reference_distance": finite_or_null(Some(r.classification.nearest_distance)),
        "ci95": ci,
        "model": f.model.names(),
        "active_bounds": f.active_bounds,
        "notes": f.notes,
        "acceptance_deg": f.acceptance_deg,
        "iterations": f.iterations,
        "status": f.status,
        "weighted": f.weighted,
    })
}

fn fmt_value(x: Option<f64>) -> String {
    x.map_or_else(|| "—".to_string(), |v| format!("{v:.4}"))
}

/// The human table of a report.
pub fn to_table(r: &Report) -> String {
    let f = &r.fit;
    let c = &r.classification;
    let mut s = format!("{}  sample {}  (n = {}, fitted: {})\n", r.file.display(), r.sample, f.n, f.model.names().join(" "));
    s += "  parameter        value       95 % interval\n";
    let values = [f.sigma_deg(), f.reported(model::RHO_S), f.reported(model::RHO_D), f.reported(model::ETA)];
    for (i, name) in ["sigma [deg]", "rho_s", "rho_d", "eta"].iter().enumerate() {
        let ci = f.ci95[i].map_or_else(String::new, |(lo, hi)| format!("[{lo:.4}, {hi:.4}]"));
        let value = match (i, f.sigma_upper_deg()) {
            (model::SIGMA, Some(up)) => format!("≤ {up:.4}"),
            _ => fmt_value(values[i]),
        };
        s += &format!("  {name:<14} {value:>10}   {ci}\n");
    }
    s += &format!("  NMAE {:.2} %   RMS {:.4}   {} iterations, {:?}\n", 100.0 * f.nmae, f.rms, f.iterations, f.status);
    match (r.delta, r.check) {
        (Some(d), Some(chk)) => {
            s += &format!(
                "  δ {:.3}°   σ_l {:.3}°   σ > σ_l: {}\n",
                d.deg,
                chk.sigma_l_deg,
                if chk.sigma_ok { "yes" } else { "NO (measure closer to the specular direction)" }
            )
        }
        _ => s += "  δ unknown (no neighbours of the specular direction): σ_l check not made\n",
    }
    s += &format!(
        "  class {} ({}), confidence {:.0} %, nearest reference {} (distance {:.2})\n",
        c.class.name(),
        c.group.name(),
        100.0 * c.confidence,
        c.nearest_reference,
        c.nearest_distance
    );
    for note in &f.notes {
        s += &format!("  note: {note}\n");
    }
    s
}

/// Run `gonio fit`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if let Some(d) = args.delta {
        anyhow::ensure!(d.is_finite() && d > 0.0, "--delta must be a positive number of degrees, not {d}");
    }
    anyhow::ensure!(args.acceptance.is_finite() && args.acceptance >= 0.0, "--acceptance must be ≥ 0 degrees, not {}", args.acceptance);
    let options = FitOptions { acceptance_deg: (args.acceptance > 0.0).then_some(args.acceptance), ..FitOptions::default() };

    let mut failed = false;
    // Read everything first (cheap), then fit the data sets on all cores, in input order.
    let mut jobs: Vec<(usize, &Path, DataSet)> = Vec::new();
    let mut file_errors: Vec<(usize, String)> = Vec::new();
    for (k, path) in args.files.iter().enumerate() {
        match dataset::read_file(path) {
            Ok(sets) => jobs.extend(sets.into_iter().map(|s| (k, path.as_path(), s))),
            Err(e) => {
                failed = true;
                let location = e.line().map_or_else(|| path.display().to_string(), |l| format!("{}:{l}", path.display()));
                let message = match e {
                    dataset::DatasetError::Io(io) => io.to_string(),
                    // The line is in the location already; drop the "line N: " prefix.
                    other => other.to_string().split_once(": ").map_or_else(|| other.to_string(), |(_, m)| m.to_string()),
                };
                file_errors.push((k, format!("{location}: {message}")));
            }
        }
    }
    let results = analyse_all(&jobs, &options, args.delta);

    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let mut file_errors = file_errors.into_iter().peekable();
    for ((k, path, _), result) in jobs.iter().zip(results) {
        // Keep errors of unreadable files in file order relative to the results.
        while let Some((_, message)) = file_errors.next_if(|(ek, _)| ek < k) {
            out.flush()?;
            eprintln!("error: {message}");
        }
        match result {
            Ok(report) => {
                if args.json {
                    writeln!(out, "{}", to_json(&report))?;
                } else {
                    writeln!(out, "{}", to_table(&report))?;
                }
            }
            Err(message) => {
                failed = true;
                out.flush()?;
                eprintln!("error: {}:{message}", path.display());
            }
        }
    }
    out.flush()?;
    for (_, message) in file_errors {
        eprintln!("error: {message}");
    }
    Ok(if failed { ExitCode::FAILURE } else { ExitCode::SUCCESS })
}

/// Fit every data set, in parallel over the available cores; results in input order.
fn analyse_all(jobs: &[(usize, &Path, DataSet)], options: &FitOptions, delta: Option<f64>) -> Vec<Result<Report, String>> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(jobs.len().max(1));
    if threads <= 1 || jobs.len() < 8 {
        return jobs.iter().map(|(_, path, set)| analyse(path, set, options, delta)).collect();
    }
    let chunk = jobs.len().div_ceil(threads);
    std::thread::scope(|scope| {
        let handles: Vec<_> = jobs
            .chunks(chunk)
            .map(|part| {
                let handle = scope.spawn(move || part.iter().map(|(_, path, set)| analyse(path, set, options, delta)).collect::<Vec<_>>());
                (part.len(), handle)
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|(len, h)| {
                // Keep one result per data set even if a thread died, so that results stay aligned.
                h.join().unwrap_or_else(|_| (0..len).map(|_| Err("1: internal error: the fit panicked".to_string())).collect())
            })
            .collect()
    })
}
