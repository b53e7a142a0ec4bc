//! `gonio fit`: fit the TSL model to measured data sets, check σ against σ_l and classify.
//!
//! Each file is read and each data set fitted on its own: a bad file or data set is
//! reported on stderr as `file:line: message` and the others still get their results;
//! the exit status is 1 if anything failed, else 3 if any result is flagged (not `ok`).
use host::analysis::dataset::DataSet;
use host::analysis::fit::FitOptions;
use host::analysis::model;
use host::analysis::result::{Readings, Report, analyse, to_json, to_table};
use host::output::dataset;
use host::output::shared_errors::{self, SharedErrorsError, SharedErrorsFile};
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
    /// An instrument profile (gonio characterize) to analyse with: for CSV files the
    /// detector's measured response instead of --acceptance, and the arm zero it measured;
    /// for session folders in place of the profile the session recorded (the result then
    /// differs from the session's where the instrument does).
    #[arg(long, value_name = "FILE", conflicts_with = "acceptance")]
    pub instrument: Option<PathBuf>,
    /// The model fitted to CSV and `.astm` tables: extended (the paper's TSL model and the
    /// extensions the readings call for, each named in the result) or paper (the paper's
    /// model alone). Session folders and tables with their shared errors are analysed with
    /// the model their session used. Default: extended (`GONIO_MODEL_EXTENSIONS=0`: paper).
    #[arg(long, value_enum, value_name = "MODEL")]
    pub model: Option<host::analysis::fit::ModelChoice>,
    /// CSV files (header with theta_i, theta_r, radiance_factor; optional std, sample;
    /// comma-, semicolon- or tab-separated, decimal commas with the latter two), gonio's
    /// `.astm` exports, or finished session or sheet folders: analysed again from their own
    /// readings, calibration and settings, and compared with the result they reported
    /// (--delta and --acceptance do not apply to them). A CSV file with a
    /// `<stem>.shared-errors.json` beside it (a session's readings.csv) is analysed as its
    /// session analysed it: with the errors its readings share and the session's settings.
    #[arg(required = true, value_name = "FILE|DIR")]
    pub files: Vec<PathBuf>,
}

/// Run `gonio fit`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let profile = match &args.instrument {
        Some(path) => {
            let (found, sha) = host::instrument::profile::read(path)?;
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs());
            Some(found.in_use(sha, now))
        }
        None => None,
    };
    let options = fit_options(&args, profile.as_ref())?;
    // Read everything first (cheap), then fit the data sets on all cores, in input order.
    let mut inputs = read_inputs(&args.files);
    // The profile's arm zero: the θr of a data set are the firmware's (a data set with
    // its shared errors takes the profile in place of its session's: `analyse_set`).
    if let Some(profile) = &profile {
        for Job { set, .. } in inputs.jobs.iter_mut().filter(|j| j.shared.is_none()) {
            for o in &mut set.observations {
                o.theta_r_deg = profile.corrected_theta_r(o.theta_i_deg, o.theta_r_deg);
            }
        }
    }
    let results = analyse_all(&inputs.jobs, &options, args.delta, profile.as_ref());
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let mut told = Told {
        failed: inputs.failed,
        flagged: false,
    };
    // Folders first, in the order given: each its session's analysis made again.
    print_folders(
        &mut out,
        &inputs.folders,
        args.json,
        profile.as_ref(),
        &mut told,
    )?;
    let mut file_errors = inputs.file_errors.into_iter().peekable();
    for (Job { k, path, .. }, result) in inputs.jobs.iter().zip(results) {
        // Keep errors of unreadable files in file order relative to the results.
        while let Some((_, message)) = file_errors.next_if(|(ek, _)| ek < k) {
            out.flush()?;
            eprintln!("error: {message}");
        }
        match result {
            Ok(report) => {
                told.flagged |= !report.ok();
                if args.json {
                    writeln!(out, "{}", to_json(&report))?;
                } else {
                    writeln!(out, "{}", to_table(&report))?;
                }
            }
            Err(message) => {
                told.failed = true;
                out.flush()?;
                eprintln!("error: {}:{message}", path.display());
            }
        }
    }
    out.flush()?;
    for (_, message) in file_errors {
        eprintln!("error: {message}");
    }
    Ok(if told.failed {
        ExitCode::from(crate::cli::exit::FAILED)
    } else {
        crate::cli::exit::of_result(!told.flagged)
    })
}

/// The fit's options from `--delta` and `--acceptance` (or the profile's response and arm
/// zero uncertainty), checked.
fn fit_options(
    args: &Args,
    profile: Option<&host::instrument::profile::ProfileInUse>,
) -> anyhow::Result<FitOptions> {
    if let Some(d) = args.delta {
        anyhow::ensure!(
            d.is_finite() && d > 0.0 && d <= 90.0,
            "--delta must be a number of degrees above 0 and at most 90, not {d:?}"
        );
    }
    let max_acceptance = host::measure::MAX_ACCEPTANCE_DEG;
    anyhow::ensure!(
        args.acceptance.is_finite() && (0.0..=max_acceptance).contains(&args.acceptance),
        "--acceptance must be between 0 and {max_acceptance} degrees (the detector's full width, which the fit models as a small window), not {:?}",
        args.acceptance
    );
    let response = profile.map(|p| p.response()).transpose()?;
    Ok(FitOptions {
        acceptance_deg: (args.acceptance > 0.0).then_some(args.acceptance),
        response,
        arm_zero_uncertainty_deg: profile.map_or(0.0, |p| p.arm_zero_u_deg),
        extensions: args
            .model
            .unwrap_or_else(host::analysis::fit::ModelChoice::by_default)
            .extensions(),
        ..FitOptions::default()
    })
}

/// What was said so far: anything failed, any result flagged.
struct Told {
    failed: bool,
    flagged: bool,
}

/// One data set to fit: the file's index and path, the data set, and the errors its
/// readings share when the file has its shared-errors file beside it.
struct Job<'a> {
    k: usize,
    path: &'a Path,
    set: DataSet,
    shared: Option<std::sync::Arc<SharedErrorsFile>>,
}

/// The inputs read: the data sets of the files (with the file's index), the files that
/// could not be read (with the message), the session folders found.
struct Inputs<'a> {
    jobs: Vec<Job<'a>>,
    file_errors: Vec<(usize, String)>,
    folders: Vec<(usize, PathBuf)>,
    failed: bool,
}

/// Read every file and find every session folder, in the order given.
fn read_inputs(files: &[PathBuf]) -> Inputs<'_> {
    let mut inputs = Inputs {
        jobs: Vec::new(),
        file_errors: Vec::new(),
        folders: Vec::new(),
        failed: false,
    };
    for (k, path) in files.iter().enumerate() {
        if path.is_dir() {
            match host::output::reanalysis::session_folders(path) {
                Ok(dirs) => inputs.folders.extend(dirs.into_iter().map(|d| (k, d))),
                Err(e) => {
                    inputs.failed = true;
                    inputs.file_errors.push((k, e.to_string()));
                }
            }
            continue;
        }
        match read_with_shared_errors(path) {
            Ok((sets, shared)) => inputs.jobs.extend(sets.into_iter().map(|set| Job {
                k,
                path: path.as_path(),
                set,
                shared: shared.clone(),
            })),
            Err(ReadError::Shared(e)) => {
                inputs.failed = true;
                inputs.file_errors.push((k, e.to_string()));
            }
            Err(ReadError::Dataset(e)) => {
                inputs.failed = true;
                let location = e.line().map_or_else(
                    || path.display().to_string(),
                    |l| format!("{}:{l}", path.display()),
                );
                let message = match e {
                    dataset::DatasetError::Io(io) => io.to_string(),
                    // The line is in the location already; drop the "line N: " prefix.
                    other => other
                        .to_string()
                        .split_once(": ")
                        .map_or_else(|| other.to_string(), |(_, m)| m.to_string()),
                };
                inputs
                    .file_errors
                    .push((k, format!("{location}: {message}")));
            }
        }
    }
    inputs
}

/// Each session folder's analysis made again from its files, compared with its own.
fn print_folders(
    out: &mut impl Write,
    folders: &[(usize, PathBuf)],
    json: bool,
    profile: Option<&host::instrument::profile::ProfileInUse>,
    told: &mut Told,
) -> anyhow::Result<()> {
    for (_, dir) in folders {
        match host::output::reanalysis::reanalyse_with(dir, profile) {
            Ok(again) => {
                told.flagged |= !again.report.ok();
                let same = again.differences.is_empty();
                if json {
                    let mut v = to_json(&again.report);
                    v["session_dir"] = serde_json::json!(dir.display().to_string());
                    v["same_as_session"] = serde_json::json!(same);
                    v["differs_from_session_in"] = serde_json::json!(again.differences);
                    writeln!(out, "{v}")?;
                } else {
                    writeln!(out, "{}", to_table(&again.report))?;
                    if same {
                        writeln!(
                            out,
                            "  re-analysed from the folder's readings and calibration: the same result as the session reported\n"
                        )?;
                    } else {
                        writeln!(
                            out,
                            "  re-analysed from the folder's readings and calibration: DIFFERS from the session's result in {}\n",
                            again.differences.join(", ")
                        )?;
                    }
                }
            }
            Err(message) => {
                told.failed = true;
                out.flush()?;
                eprintln!("error: {message}");
            }
        }
    }
    Ok(())
}

/// Why a file cannot be read.
enum ReadError {
    Dataset(dataset::DatasetError),
    Shared(SharedErrorsError),
}

/// A file's data sets and, for a CSV file with its shared-errors file beside it, that
/// file (one data set only: the shared errors are the session's, of one sample). A
/// session's `readings.csv` without one is analysed on its readings' own noise, and said
/// so: the result then need not be the session's.
fn read_with_shared_errors(
    path: &Path,
) -> Result<(Vec<DataSet>, Option<std::sync::Arc<SharedErrorsFile>>), ReadError> {
    let bytes = std::fs::read(path).map_err(|e| ReadError::Dataset(e.into()))?;
    let sets = dataset::read_bytes(path, &bytes).map_err(ReadError::Dataset)?;
    let shared = shared_errors::find(path, &bytes).map_err(ReadError::Shared)?;
    match shared {
        Some(shared) if sets.len() == 1 => Ok((sets, Some(std::sync::Arc::new(shared)))),
        Some(shared) => Err(ReadError::Shared(SharedErrorsError::Unreadable {
            path: shared.path().to_path_buf(),
            why: format!(
                "{} holds {} data sets; the shared errors are those of one session's readings",
                path.display(),
                sets.len()
            ),
        })),
        None => {
            // A session's readings.csv (its other exports carry no uncertainties at all).
            let in_session_folder = path.file_name().is_some_and(|n| n == "readings.csv")
                && path
                    .parent()
                    .is_some_and(|d| d.join(host::output::folder::SESSION).is_file());
            if in_session_folder {
                eprintln!(
                    "note: {} has no {} beside it: analysed on its readings' own noise, without the errors the calibration shares among them (the session's result may differ; `gonio fit {}` re-analyses the folder)",
                    path.display(),
                    shared_errors::sidecar_path(path)
                        .file_name()
                        .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
                    path.parent()
                        .map_or_else(String::new, |d| d.display().to_string())
                );
            }
            Ok((sets, None))
        }
    }
}

/// Analyse one data set of the file `path`; errors are `line: message`.
fn analyse_set(
    job: &Job<'_>,
    options: &FitOptions,
    delta: Option<f64>,
    profile: Option<&host::instrument::profile::ProfileInUse>,
) -> anyhow::Result<Report> {
    let Job {
        path, set, shared, ..
    } = job;
    if let Some(shared) = shared {
        // Errors of the shared-errors file name it, not a line of the CSV.
        return shared_errors::analyse(&path.display().to_string(), set, shared, profile).map_err(
            |e| match e {
                // The fit's own error starts with its line: `file:line: …`.
                SharedErrorsError::Analysis(a @ host::session::PointsAnalysisError::Fit(_)) => {
                    anyhow::anyhow!("{a}")
                }
                other => anyhow::anyhow!(" {other}"),
            },
        );
    }
    let readings = Readings {
        source: &path.display().to_string(),
        sample: &set.sample,
        observations: &set.observations,
        lines: &set.lines,
    };
    Ok(analyse(&readings, options, delta)?)
}

/// Fit every data set, in parallel over the available cores; results in input order.
fn analyse_all(
    jobs: &[Job<'_>],
    options: &FitOptions,
    delta: Option<f64>,
    profile: Option<&host::instrument::profile::ProfileInUse>,
) -> Vec<anyhow::Result<Report>> {
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(jobs.len().max(1));
    if threads <= 1 || jobs.len() < 8 {
        return jobs
            .iter()
            .map(|job| analyse_set(job, options, delta, profile))
            .collect();
    }
    let chunk = jobs.len().div_ceil(threads);
    std::thread::scope(|scope| {
        let handles: Vec<_> = jobs
            .chunks(chunk)
            .map(|part| {
                let handle = scope.spawn(move || {
                    part.iter()
                        .map(|job| analyse_set(job, options, delta, profile))
                        .collect::<Vec<_>>()
                });
                (part.len(), handle)
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|(len, h)| {
                // Keep one result per data set even if a thread died, so that results stay aligned.
                h.join().unwrap_or_else(|_| {
                    (0..len)
                        .map(|_| Err(anyhow::anyhow!("1: internal error: the fit panicked")))
                        .collect()
                })
            })
            .collect()
    })
}
