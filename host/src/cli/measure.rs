//! `gonio measure`: the whole measurement session, on an instrument or the simulated one.
//!
//! Every option is checked before anything moves (numbers against their limits, the
//! integration time against the instrument's announced limits); the session folder is
//! made for this session alone or, with `--resume`, taken only for the same sample,
//! instrument and plan ([`crate::output::record`]).
use crate::analysis::fit::Observation;
use crate::instrument::calibration::{Calibration, Tile, instrument_name, max_age_from_hours};
use crate::instrument::link::{Client, RetryPolicy, Transport};
use crate::instrument::serial::SerialTransport;
use crate::instrument::sim::SimOptions;
use crate::output::folder::{AdaptiveTargetsRecord, PlanRecord, Status};
use crate::output::record::{Existing, FileRecorder, Identity};
use crate::output::store::StoreOptions;
use crate::session::adaptive::AdaptiveTargets;
use crate::session::{
    Operator, Outcome, Plan, Policy, PolicyChoice, PromptOperator, Recorder, Session, SessionError,
    SimulatedOperator,
};
use anyhow::{Context, bail};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// The white drift limit when none is given, percent.
pub const DEFAULT_WHITE_DRIFT_LIMIT_PCT: f64 = 0.5;
/// The largest detector acceptance the fit models, degrees (full width): its acceptance
/// window is a small-angle average over the lobe, and the instrument's is about 2°.
pub const MAX_ACCEPTANCE_DEG: f64 = 10.0;

/// Arguments of `gonio measure`.
#[derive(clap::Args)]
pub struct Args {
    /// Run on the simulated instrument with this sample on the port (G, SG, PPC, MC,
    /// J1…J4, custom:SIGMA,RHO_S,RHO_D,ETA), in process.
    #[arg(long, value_name = "SAMPLE", conflicts_with = "port")]
    pub sim: Option<String>,
    #[command(flatten)]
    pub sim_options: SimOptions,
    /// Serial port of the instrument (default: the one attached instrument, by USB id).
    #[arg(long, value_name = "PATH")]
    pub port: Option<String>,
    /// Name of the sample for the report and the files (default: the simulated sample, the
    /// resumed session's, or "sample").
    #[arg(long)]
    pub sample: Option<String>,
    /// Folder for the session's files: new or empty (default: a new
    /// sessions/<local date-time>-<sample>).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Continue an interrupted session in DIR, measuring only what is missing. Options not
    /// given are the session's; options given must be the session's.
    #[arg(long, value_name = "DIR", conflicts_with = "out")]
    pub resume: Option<PathBuf>,
    /// Use the calibration of an earlier session (its folder, session.json or calibration.json).
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    /// The white tile's certified radiance factor (its certificate; recorded in
    /// calibration.json). A reused calibration keeps the tile it was taken with.
    #[arg(long, value_name = "FACTOR", default_value_t = crate::instrument::calibration::DEFAULT_WHITE_RADIANCE_FACTOR, allow_negative_numbers = true)]
    pub tile_radiance_factor: f64,
    /// Standard uncertainty (k = 1) of the tile's certified radiance factor, percent; half a
    /// certificate's expanded (k = 2) uncertainty. The default is an assumption for a
    /// working-standard tile certified to ±1 % at k = 2.
    #[arg(long, value_name = "PERCENT", default_value_t = 100.0 * crate::instrument::calibration::DEFAULT_TILE_RELATIVE_UNCERTAINTY, allow_negative_numbers = true)]
    pub tile_uncertainty_pct: f64,
    /// The white tile's certificate, transcribed into a JSON file (tile, certificate,
    /// issued, radiance_factor, expanded_uncertainty, coverage_factor; docs/FORMATS.md):
    /// its values calibrate, and it is recorded in calibration.json, the export and the
    /// report. Refused when expired. Instead of --tile-radiance-factor/--tile-uncertainty-pct.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["tile_radiance_factor", "tile_uncertainty_pct"])]
    pub tile_certificate: Option<PathBuf>,
    /// Standard uncertainty of the detector arm's zero, degrees: the fit carries an offset
    /// of this size as an error shared by every reading, wherever the data do not call for
    /// fitting one. The default is the reference instrument's alignment (about 8
    /// microsteps); 0 trusts the zero exactly.
    #[arg(long, value_name = "DEG", default_value_t = crate::analysis::fit::DEFAULT_ARM_ZERO_UNCERTAINTY_DEG, allow_negative_numbers = true)]
    pub arm_zero_uncertainty_deg: f64,
    /// Oldest calibration accepted, hours (at most 8760).
    #[arg(long, value_name = "HOURS", default_value_t = 8.0)]
    pub max_calibration_age_h: f64,
    /// Integration time per reading (default: the instrument's); within the limits the
    /// instrument announces.
    #[arg(long, value_name = "MS")]
    pub integration_ms: Option<u16>,
    /// Refinement policy (default adaptive): adaptive reaches the paper's accuracy in a
    /// fraction of its device time (docs/TRADE.md); paper follows the paper's procedure
    /// exactly; sweep reads the detector while its arm moves (θr 0…70° at θi = 20° and 60°,
    /// then sweeps across the peak where σ needs them; the whole plane if the fit lacks fit);
    /// mixed is adaptive with sweeps across the peak as candidates next to its batches.
    #[arg(long, value_enum)]
    pub policy: Option<PolicyChoice>,
    /// Re-read the white tile at the end and mark the result if it drifted.
    #[arg(long)]
    pub white_check: bool,
    /// White drift beyond which the result is marked, percent (default 0.5; above 0, at most 100).
    #[arg(long, value_name = "PERCENT")]
    pub white_drift_limit_pct: Option<f64>,
    /// Spots of the sheet to measure (1 to 20): from 2 on, the operator is asked to move
    /// the sheet between spots, the calibration is shared, a flagged spot is replaced (at
    /// most twice) or excluded with the reason, and the folder holds one session per spot
    /// and the sheet's result (its mean and its spot-to-spot variation). Forensic
    /// comparison wants several (docs/FORENSIC.md); a resumed session keeps its own.
    #[arg(long, value_name = "N")]
    pub spots: Option<u16>,
    /// The case or job number, recorded in session.json and the report.
    #[arg(long = "case", value_name = "ID")]
    pub case_id: Option<String>,
    /// Who measures, recorded in session.json and the report.
    #[arg(long, value_name = "NAME")]
    pub operator: Option<String>,
    /// A note (the item, where on it), recorded in session.json and the report.
    #[arg(long, value_name = "TEXT")]
    pub note: Option<String>,
    /// Print one JSON object instead of the report.
    #[arg(long)]
    pub json: bool,
}

/// Spots of a sheet when `--spots` is not given ([`crate::analysis::spots::DEFAULT_SPOTS`]).
pub const DEFAULT_SPOTS: u16 = crate::analysis::spots::DEFAULT_SPOTS;
/// The most spots a sheet takes.
pub const MAX_SPOTS: u16 = 20;

/// Parse `gonio measure` arguments (`args` without the program and subcommand names), as
/// the command line would.
pub fn parse_args<I, S>(args: I) -> Result<Args, clap::Error>
where
    I: IntoIterator<Item = S>,
    S: Into<std::ffi::OsString> + Clone,
{
    #[derive(clap::Parser)]
    struct Measure {
        #[command(flatten)]
        args: Args,
    }
    let argv = std::iter::once(std::ffi::OsString::from("measure"))
        .chain(args.into_iter().map(Into::into));
    <Measure as clap::Parser>::try_parse_from(argv).map(|m| m.args)
}

/// How a measurement ended.
pub enum Measured {
    /// The session completed; `summary` is the `--json` object.
    Done {
        /// The session folder.
        dir: PathBuf,
        /// Everything the session produced.
        outcome: Box<Outcome>,
        /// The result object printed by `--json`.
        summary: serde_json::Value,
    },
    /// A sheet of several spots was measured (`--spots N`).
    Sheet {
        /// The sheet's folder.
        dir: PathBuf,
        /// The sheet as recorded (read back from its folder).
        sheet: Box<crate::output::sheet_folder::ReadSheet>,
        /// The object printed by `--json`.
        json: serde_json::Value,
    },
    /// The session stopped (Ctrl-C, a dead link); the instrument was told to stop, and the
    /// readings taken are in `dir`, with `session.json` saying why and how to resume.
    Stopped {
        /// The session folder.
        dir: PathBuf,
        /// Why.
        error: SessionError,
        /// The folder could not be updated with the status either (a full disk…).
        record_error: Option<String>,
    },
}

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
    match measure(&args, operator.as_mut(), interrupted)? {
        Measured::Done {
            dir,
            outcome,
            summary,
        } => {
            print_report(&args, &dir, &outcome, &summary);
            // The exit code says what `ok` says: 0 clean, 3 flagged.
            Ok(crate::cli::exit::of_result(outcome.ok()))
        }
        Measured::Sheet { dir, sheet, json } => {
            if args.json {
                println!("{json}");
            } else {
                print_sheet(&dir, &sheet);
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
            eprintln!(
                "readings so far are in {}; continue with: {}",
                dir.display(),
                resume_command(&args, &dir)
            );
            let code = if matches!(error, SessionError::Interrupted) {
                crate::cli::exit::INTERRUPTED
            } else {
                crate::cli::exit::FAILED
            };
            Ok(ExitCode::from(code))
        }
    }
}

/// The whole session on the instrument `args` name, asking `operator` to place the tile;
/// stops the instrument and returns [`Measured::Stopped`] once `interrupted` is set.
pub fn measure(
    args: &Args,
    operator: &mut dyn Operator,
    interrupted: Arc<AtomicBool>,
) -> anyhow::Result<Measured> {
    measure_with(args, operator, interrupted, StoreOptions::default())
}

/// [`measure`], with the session folder's writes under `store` (a simulated crash, in tests).
pub fn measure_with(
    args: &Args,
    operator: &mut dyn Operator,
    interrupted: Arc<AtomicBool>,
    store: StoreOptions,
) -> anyhow::Result<Measured> {
    // Numbers first: nothing is connected, moved or written for a bad one.
    let checked = check_args(args)?;
    let policy = RetryPolicy::default();
    if let Some(sample) = &args.sim {
        let mut options = args.sim_options.clone();
        // A resumed session's simulated instrument was switched on before, once per run.
        options.power_on = args
            .resume
            .as_deref()
            .map_or(0, crate::instrument::sim::runs_recorded);
        let instrument = options.instrument(sample)?;
        run_on(
            Client::new(instrument, policy),
            args,
            &checked,
            Some(sample.clone()),
            operator,
            interrupted,
            store,
        )
    } else {
        let path = match &args.port {
            Some(path) => path.clone(),
            None => crate::instrument::serial::find_instrument()?.context(
                "no instrument found (gonio ports lists the serial ports); give --port PATH, or --sim SAMPLE for the simulated instrument",
            )?,
        };
        check_port(&path)?;
        let transport = SerialTransport::open(&path).map_err(|e| match e.to_string() {
            m if m.contains("Not a typewriter") || m.contains("Inappropriate ioctl") => {
                anyhow::anyhow!("--port {path} is not a serial port (a device, but not a terminal): give the instrument's port (gonio ports lists them)")
            }
            m => anyhow::anyhow!("cannot open --port {path}: {m}"),
        })?;
        run_on(
            Client::new(transport, policy),
            args,
            &checked,
            None,
            operator,
            interrupted,
            store,
        )
    }
}

/// Options checked before anything is connected.
struct Checked {
    max_calibration_age: Duration,
    tile: Tile,
    spots: u16,
    case: Option<crate::output::folder::CaseRecord>,
}

fn check_args(args: &Args) -> anyhow::Result<Checked> {
    let max_calibration_age = max_age_from_hours(args.max_calibration_age_h)?;
    if let Some(limit) = args.white_drift_limit_pct {
        if !(limit > 0.0 && limit <= 100.0) {
            bail!(
                "--white-drift-limit-pct must be a percentage above 0 and at most 100, not {limit:?}"
            );
        }
    }
    if let Some(sample) = &args.sample {
        if sample.trim().is_empty() || sample.chars().any(char::is_control) {
            bail!("--sample must be a name (no control characters), not {sample:?}");
        }
    }
    let tile = match &args.tile_certificate {
        Some(path) => crate::instrument::calibration::TileCertificate::read(
            path,
            chrono::Local::now().date_naive(),
        )
        .and_then(|c| c.tile())
        .context("--tile-certificate")?,
        None => Tile::new(args.tile_radiance_factor, args.tile_uncertainty_pct)
            .context("--tile-radiance-factor / --tile-uncertainty-pct")?,
    };
    let zero = args.arm_zero_uncertainty_deg;
    if !(0.0..=5.0).contains(&zero) {
        bail!("--arm-zero-uncertainty-deg must be between 0 and 5 degrees, not {zero:?}");
    }
    let spots = args.spots.unwrap_or(DEFAULT_SPOTS);
    if !(1..=MAX_SPOTS).contains(&spots) {
        bail!("--spots must be 1 to {MAX_SPOTS}, not {spots}");
    }
    for (option, value) in [
        ("--case", &args.case_id),
        ("--operator", &args.operator),
        ("--note", &args.note),
    ] {
        if let Some(v) = value {
            if v.trim().is_empty() || v.chars().any(char::is_control) || v.chars().count() > 500 {
                bail!(
                    "{option} must be text of 1 to 500 characters without control characters, not {v:?}"
                );
            }
        }
    }
    let case = crate::output::folder::CaseRecord {
        case_id: args.case_id.clone(),
        operator: args.operator.clone(),
        note: args.note.clone(),
    };
    Ok(Checked {
        max_calibration_age,
        tile,
        spots,
        case: (!case.is_empty()).then_some(case),
    })
}

/// A regular file or a folder given as `--port` is no serial port: say so before opening it.
fn check_port(path: &str) -> anyhow::Result<()> {
    let meta = match std::fs::metadata(path) {
        Ok(meta) => meta,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("--port {path}: no such port (gonio ports lists the serial ports)")
        }
        Err(e) => bail!("cannot open --port {path}: {e}"),
    };
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let kind = meta.file_type();
        if !kind.is_char_device() {
            let what = if kind.is_dir() {
                "a folder"
            } else if kind.is_file() {
                "a regular file"
            } else {
                "not a device"
            };
            bail!(
                "--port {path} is not a serial port (it is {what}): give the instrument's port, e.g. /dev/ttyACM0 (gonio ports lists them)"
            );
        }
    }
    #[cfg(not(unix))]
    let _ = meta;
    Ok(())
}

/// The command that continues a session in `dir`.
fn resume_command(args: &Args, dir: &Path) -> String {
    let on = match (&args.sim, &args.port) {
        (Some(sample), _) => format!(" --sim {sample}"),
        (None, Some(port)) => format!(" --port {port}"),
        (None, None) => String::new(),
    };
    format!("gonio measure{on} --resume {}", dir.display())
}

fn policy_name(choice: PolicyChoice) -> &'static str {
    choice.name()
}

/// What is measured: the options given, else the resumed session's, else the defaults;
/// checked against the instrument's announced limits.
fn plan_record(
    args: &Args,
    info: &protocol::DeviceInfo,
    earlier: Option<&PlanRecord>,
) -> anyhow::Result<PlanRecord> {
    let policy = match (args.policy, earlier) {
        (Some(choice), _) => choice,
        (None, Some(plan)) => <PolicyChoice as clap::ValueEnum>::from_str(&plan.policy, true)
            .map_err(|_| anyhow::anyhow!("the session's policy '{}' is not one this gonio knows (paper, adaptive, sweep, mixed)", plan.policy))?,
        (None, None) => PolicyChoice::Adaptive,
    };
    let adaptive_targets = match Policy::from(policy) {
        Policy::Adaptive(t) | Policy::Mixed(t, _) => Some(AdaptiveTargetsRecord {
            sigma_rel_half_width: t.sigma_rel_half_width,
            class_confidence: t.class_confidence,
            batch: t.batch,
            max_batches: t.max_batches,
        }),
        _ => None,
    };
    let (integration_ms, from) = match (args.integration_ms, earlier) {
        (Some(ms), _) => (ms, "--integration-ms".to_string()),
        (None, Some(plan)) => (
            plan.integration_ms,
            "the resumed session's integration time".to_string(),
        ),
        (None, None) => (
            info.default_integration_ms,
            "the instrument's default integration time".to_string(),
        ),
    };
    let (min, max) = (info.min_integration_ms.max(1), info.max_integration_ms);
    if !(min..=max).contains(&integration_ms) {
        bail!(
            "{from} {integration_ms} ms is outside what the instrument (serial {}) accepts: {min} to {max} ms",
            info.serial_number
        );
    }
    let acceptance_deg = f64::from(info.acceptance_deg);
    if !(acceptance_deg.is_finite() && (0.0..=MAX_ACCEPTANCE_DEG).contains(&acceptance_deg)) {
        bail!(
            "the instrument (serial {}) announces a detector acceptance of {acceptance_deg}°: the fit models 0 to {MAX_ACCEPTANCE_DEG}°",
            info.serial_number
        );
    }
    let sweep_targets = match Policy::from(policy) {
        Policy::Sweep(t) | Policy::Mixed(_, t) => Some(t),
        _ => None,
    };
    Ok(PlanRecord {
        policy: policy_name(policy).into(),
        adaptive_targets,
        sweep_targets,
        integration_ms,
        acceptance_deg,
        white_check: args.white_check || earlier.is_some_and(|p| p.white_check),
        white_drift_limit_pct: args
            .white_drift_limit_pct
            .or(earlier.map(|p| p.white_drift_limit_pct))
            .unwrap_or(DEFAULT_WHITE_DRIFT_LIMIT_PCT),
    })
}

fn plan_of(record: &PlanRecord, sample: &str) -> Plan {
    let adaptive = record.adaptive_targets.as_ref().map(|t| AdaptiveTargets {
        sigma_rel_half_width: t.sigma_rel_half_width,
        class_confidence: t.class_confidence,
        batch: t.batch,
        max_batches: t.max_batches,
    });
    let policy = match (record.policy.as_str(), adaptive) {
        ("sweep", _) => Policy::Sweep(record.sweep_targets.unwrap_or_default()),
        ("mixed", Some(t)) => Policy::Mixed(t, record.sweep_targets.unwrap_or_default()),
        (_, Some(t)) => Policy::Adaptive(t),
        (_, None) => Policy::Paper,
    };
    Plan {
        sample: sample.to_string(),
        integration_ms: record.integration_ms,
        policy,
        acceptance_deg: record.acceptance_deg,
        white_check: record.white_check,
        white_drift_limit: record.white_drift_limit_pct / 100.0,
    }
}

/// `--calibration`: a session folder, its `session.json` or a `calibration.json`, checked
/// for age and instrument (its serial number too, when a session document names it).
fn external_calibration(
    path: &Path,
    checked: &Checked,
    info: &protocol::DeviceInfo,
) -> anyhow::Result<Calibration> {
    let file = if path.is_dir() {
        path.join("calibration.json")
    } else {
        path.to_path_buf()
    };
    let calibration = Calibration::load(&file, checked.max_calibration_age, info)?;
    let session = if path.is_dir() {
        path.join("session.json")
    } else {
        file.with_file_name("session.json")
    };
    if let Some(serial) = std::fs::read(&session)
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .and_then(|v| {
            v["instrument"]["serial_number"]
                .as_str()
                .map(str::to_string)
        })
    {
        if serial != info.serial_number.as_str() {
            bail!(
                "calibration {} was taken on instrument serial {serial}, not on this one (serial {})",
                file.display(),
                info.serial_number
            );
        }
    }
    Ok(calibration)
}

#[allow(clippy::too_many_arguments)]
fn run_on<T: Transport>(
    mut client: Client<T>,
    args: &Args,
    checked: &Checked,
    sim_sample: Option<String>,
    operator: &mut dyn Operator,
    interrupted: Arc<AtomicBool>,
    store: StoreOptions,
) -> anyhow::Result<Measured> {
    let info = client.hello().context("handshake with the instrument")?;
    let mut context = Run {
        client: &mut client,
        info,
        args,
        checked,
        sim_sample,
        operator,
        interrupted,
        store,
    };
    let sheet = args
        .resume
        .as_deref()
        .is_some_and(crate::output::folder::is_sheet_folder)
        || (args.resume.is_none() && checked.spots > 1);
    if sheet {
        return run_sheet(&mut context);
    }
    if let (Some(dir), Some(spots)) = (&args.resume, args.spots.filter(|n| *n > 1)) {
        bail!(
            "{} is a session of one spot: it is continued as it began, without --spots {spots} (or start a sheet of {spots} spots with --out)",
            dir.display()
        );
    }
    let folder = match &args.resume {
        Some(dir) => SessionFolder::Resume(dir.clone()),
        None => SessionFolder::New(args.out.clone()),
    };
    run_session(&mut context, folder, None)
}

/// What every session of one `gonio measure` shares.
struct Run<'a, T: Transport> {
    client: &'a mut Client<T>,
    info: protocol::DeviceInfo,
    args: &'a Args,
    checked: &'a Checked,
    sim_sample: Option<String>,
    operator: &'a mut dyn Operator,
    interrupted: Arc<AtomicBool>,
    store: StoreOptions,
}

/// Where a session is recorded.
enum SessionFolder {
    /// A new folder (`None`: a new one under `sessions/`).
    New(Option<PathBuf>),
    /// An interrupted session's folder.
    Resume(PathBuf),
}

/// A spot of a multi-spot sheet.
struct SpotContext {
    number: u16,
    of: u16,
    /// The sheet's calibration, once its first spot has taken it.
    calibration: Option<Calibration>,
    /// The command that continues the sheet.
    resume_with: String,
}

/// One session (a whole measurement, or one spot of a sheet) in `folder`.
fn run_session<T: Transport>(
    cx: &mut Run<'_, T>,
    folder: SessionFolder,
    spot: Option<SpotContext>,
) -> anyhow::Result<Measured> {
    let (args, checked, info) = (cx.args, cx.checked, cx.info.clone());
    let existing = match &folder {
        SessionFolder::Resume(dir) => Some(Existing::open(dir, cx.store.clone())?),
        SessionFolder::New(_) => None,
    };
    let sample = args
        .sample
        .clone()
        .or(cx.sim_sample.clone())
        .or_else(|| existing.as_ref().map(|e| e.doc().sample.clone()))
        .unwrap_or_else(|| "sample".into());
    let plan = plan_record(args, &info, existing.as_ref().map(|e| &e.doc().plan))?;
    let mut identity = Identity::new(&sample, &info, plan.clone());
    identity.instrument.simulated_sample = cx.sim_sample.clone();
    identity.case = checked.case.clone();
    let given_calibration = match (
        spot.as_ref().and_then(|s| s.calibration.clone()),
        &args.calibration,
    ) {
        (Some(sheet), _) => Some(sheet),
        (None, Some(path)) => Some(external_calibration(path, checked, &info)?),
        (None, None) => None,
    };
    let (mut recorder, points, calibration) = match existing {
        Some(existing) => {
            existing.check_matches(&identity)?;
            if let Some(own) = existing.calibration() {
                let file = existing_path(&folder, "calibration.json");
                own.check(&file, checked.max_calibration_age, &info)?;
                if given_calibration.as_ref().is_some_and(|given| given != own) {
                    bail!(
                        "--calibration differs from the calibration the session's readings were converted with ({file}): a session keeps one calibration; resume without --calibration"
                    );
                }
            }
            let (recorder, points, own) = existing.resume(cx.store.clone())?;
            (recorder, points, own.or(given_calibration))
        }
        None => {
            let recorder = match &folder {
                SessionFolder::New(Some(dir)) => {
                    FileRecorder::create(dir, identity, cx.store.clone())?
                }
                _ => {
                    FileRecorder::create_default(Path::new("sessions"), identity, cx.store.clone())?
                }
            };
            (recorder, Vec::new(), given_calibration)
        }
    };
    let dir = recorder.dir().to_path_buf();
    cx.operator.attach_progress(&recorder.bar);
    recorder.set_resume_with(
        spot.as_ref()
            .map_or_else(|| resume_command(args, &dir), |s| s.resume_with.clone()),
    );
    let resumed = matches!(folder, SessionFolder::Resume(_));
    if let (Some(c), false) = (&calibration, dir.join("calibration.json").exists()) {
        recorder
            .calibration(c)
            .with_context(|| format!("cannot write {}", dir.join("calibration.json").display()))?;
    }
    cx.client.set_interrupt(Some(cx.interrupted.clone()));
    let mut session = Session::new(
        cx.client,
        info.clone(),
        plan_of(&plan, &sample),
        &mut recorder,
        cx.operator,
    )
    .with_calibration_limit(checked.max_calibration_age)
    .with_tile(checked.tile.clone())
    .with_arm_zero_uncertainty(args.arm_zero_uncertainty_deg);
    if let Some(spot) = &spot {
        session = session.at_spot(spot.number, spot.of);
    }
    let outcome = session.resume_from(calibration, points).run();
    recorder.bar.finish_and_clear();
    let mut outcome = match outcome {
        Ok(outcome) => outcome,
        Err(error) => {
            // Whatever happened, leave the instrument safe (arms stopped, lamp off); the
            // readings are on disk already. A second Ctrl-C must not stop this.
            cx.client.set_interrupt(None);
            let _ = cx.client.request(protocol::Command::Abort);
            let _ = cx.client.request(protocol::Command::SetLamp { on: false });
            let status = if matches!(error, SessionError::Interrupted) {
                Status::Interrupted
            } else {
                Status::Failed
            };
            let record_error = recorder
                .stop(status, &error.to_string())
                .err()
                .map(|e| e.to_string());
            return Ok(Measured::Stopped {
                dir,
                error,
                record_error,
            });
        }
    };
    // The lamp stays on between the spots of a sheet: the calibration holds for its output.
    if spot.as_ref().is_none_or(|s| s.number >= s.of) {
        let _ = cx.client.request(protocol::Command::SetLamp { on: false });
    }
    if resumed
        && !outcome
            .flags
            .contains(&crate::analysis::flags::Flag::Resumed)
    {
        outcome.flags.push(crate::analysis::flags::Flag::Resumed);
    }
    // The report names the session's folder, not the file name of its readings inside it.
    outcome.report.file = dir.display().to_string();
    match write_session(&mut recorder, &sample, &info, &outcome) {
        Ok(summary) => {
            // A spot's report is its sheet's.
            if spot.is_none() {
                draw_report(&dir);
            }
            Ok(Measured::Done {
                dir,
                outcome: Box::new(outcome),
                summary,
            })
        }
        Err(e) => {
            let why =
                format!("the session was measured but its result could not be written: {e:#}");
            let _ = recorder.stop(Status::Failed, &why);
            let how = spot.as_ref().map_or_else(
                || format!("gonio measure --resume {}", dir.display()),
                |s| s.resume_with.clone(),
            );
            bail!(
                "{why}; every reading is in {}: {how} writes the result",
                dir.display()
            )
        }
    }
}

/// The report of the finished folder `dir`; a failure is told, not fatal: the record is
/// complete and `gonio report DIR` draws the report from it.
fn draw_report(dir: &Path) {
    if let Err(e) = crate::output::report::write_into(dir) {
        eprintln!(
            "warning: the report could not be drawn ({e}); the session's files are complete: gonio report {} draws it",
            dir.display()
        );
    }
}

/// How a spot of a sheet ended, when not measured.
enum SpotStop {
    /// The session stopped (see [`Measured::Stopped`]).
    Stopped(SessionError, Option<String>),
    /// Anything else (a folder that cannot be written, a bad calibration…).
    Other(anyhow::Error),
}

/// A sheet of several spots (`--spots N`, or `--resume` of a sheet's folder): one session
/// per spot in `DIR/spot-K` ([`crate::output::sheet_folder`]), the first spot's calibration for all.
fn run_sheet<T: Transport>(cx: &mut Run<'_, T>) -> anyhow::Result<Measured> {
    use crate::analysis::spots::SpotResult;
    use crate::output::lock::FolderError;
    use crate::output::sheet_folder::{SheetFolder, SheetResult, read_sheet, read_spot};
    let args = cx.args;
    let sample = args
        .sample
        .clone()
        .or(cx.sim_sample.clone())
        .unwrap_or_else(|| "sample".into());
    let mut folder = match &args.resume {
        Some(dir) => {
            let folder = SheetFolder::open(dir, cx.store.clone())?;
            if let Some(spots) = args.spots.filter(|n| *n != folder.doc.spots_planned) {
                bail!(
                    "{} is a sheet of {} spots: it is continued as it began (without --spots, or --spots {}), not with --spots {spots}",
                    dir.display(),
                    folder.doc.spots_planned,
                    folder.doc.spots_planned
                );
            }
            if cx
                .checked
                .case
                .as_ref()
                .is_some_and(|c| Some(c) != folder.doc.case.as_ref())
            {
                bail!(
                    "{} was measured under other case fields ({:?}): a sheet is continued as it began (leave out --case, --operator and --note)",
                    dir.display(),
                    folder.doc.case
                );
            }
            if args
                .sample
                .as_ref()
                .is_some_and(|s| *s != folder.doc.sample)
            {
                bail!(
                    "{} is a sheet of '{}', not of '{sample}': a sheet is continued as it began",
                    dir.display(),
                    folder.doc.sample
                );
            }
            folder
        }
        None => match &args.out {
            Some(dir) => SheetFolder::create(
                dir,
                &sample,
                cx.checked.spots,
                crate::analysis::spots::MAX_REPLACEMENTS,
                cx.store.clone(),
            )?,
            None => SheetFolder::create_default(
                Path::new("sessions"),
                &sample,
                cx.checked.spots,
                crate::analysis::spots::MAX_REPLACEMENTS,
                cx.store.clone(),
            )?,
        },
    };
    if args.resume.is_none() {
        folder.doc.case = cx.checked.case.clone();
    }
    let dir = folder.dir().to_path_buf();
    let resume_with = resume_command(args, &dir);
    folder.start_run(resume_with.clone()).with_context(|| {
        format!(
            "cannot write {}",
            dir.join(crate::output::folder::SHEET).display()
        )
    })?;
    let plan = crate::session::sheet::SheetPlan {
        spots: folder.doc.spots_planned,
        replacements: folder.doc.replacements,
    };
    // Spots of an earlier run: finished ones count as they are, an unfinished one is resumed.
    let mut done: Vec<SpotResult> = Vec::new();
    for entry in folder.doc.spots.clone() {
        let spot_dir = dir.join(&entry.folder);
        match Existing::open(&spot_dir, cx.store.clone()) {
            Err(FolderError::Finished { .. }) => done.push(
                read_spot(&spot_dir, entry.number)
                    .map_err(|p| anyhow::anyhow!("{p}"))?
                    .result,
            ),
            Ok(_) | Err(FolderError::NoSession(_) | FolderError::NoFolder(_)) => break,
            Err(e) => return Err(e.into()),
        }
    }
    let first = dir
        .join(crate::output::folder::spot_folder(1))
        .join("calibration.json");
    let mut calibration = if first.is_file() {
        Some(Calibration::load(
            &first,
            cx.checked.max_calibration_age,
            &cx.info,
        )?)
    } else {
        None
    };
    let decisions = std::cell::RefCell::new(Vec::<String>::new());
    let measured = crate::session::sheet::measure_sheet(
        plan,
        done,
        |number, of| -> Result<SpotResult, SpotStop> {
            let spot_dir = folder.start_spot(number).map_err(|e| {
                SpotStop::Other(anyhow::anyhow!(
                    "cannot write {}: {e}",
                    dir.join(crate::output::folder::SHEET).display()
                ))
            })?;
            let kind = if spot_dir.join(crate::output::folder::SESSION).is_file() {
                SessionFolder::Resume(spot_dir.clone())
            } else {
                SessionFolder::New(Some(spot_dir.clone()))
            };
            let context = SpotContext {
                number,
                of,
                calibration: calibration.clone(),
                resume_with: resume_with.clone(),
            };
            match run_session(cx, kind, Some(context)).map_err(SpotStop::Other)? {
                Measured::Done { outcome, .. } => {
                    calibration.get_or_insert_with(|| outcome.calibration.clone());
                    read_spot(&spot_dir, number)
                        .map(|s| s.result)
                        .map_err(|p| SpotStop::Other(anyhow::anyhow!("{p}")))
                }
                Measured::Stopped {
                    error,
                    record_error,
                    ..
                } => Err(SpotStop::Stopped(error, record_error)),
                Measured::Sheet { .. } => Err(SpotStop::Other(anyhow::anyhow!(
                    "a spot measured as a sheet"
                ))),
            }
        },
        |text| decisions.borrow_mut().push(text.to_string()),
    );
    for text in decisions.into_inner() {
        folder.decision(&text);
    }
    let summary = match measured {
        Ok((_, summary)) => summary,
        Err(SpotStop::Stopped(error, record_error)) => {
            let status = if matches!(error, SessionError::Interrupted) {
                Status::Interrupted
            } else {
                Status::Failed
            };
            let sheet_error = folder
                .stop(status, &error.to_string())
                .err()
                .map(|e| e.to_string());
            return Ok(Measured::Stopped {
                dir,
                error,
                record_error: record_error.or(sheet_error),
            });
        }
        Err(SpotStop::Other(error)) => {
            let _ = folder.stop(Status::Failed, &format!("{error:#}"));
            return Err(error.context(format!(
                "the sheet in {} stopped; continue it with {resume_with}",
                dir.display()
            )));
        }
    };
    let _ = cx.client.request(protocol::Command::SetLamp { on: false });
    let spots: Vec<crate::output::sheet_folder::ReadSpot> = folder
        .doc
        .spots
        .iter()
        .map(|s| read_spot(&dir.join(&s.folder), s.number))
        .collect::<Result<_, _>>()
        .map_err(|p| anyhow::anyhow!("{p}"))?;
    let result = SheetResult {
        summary,
        device_seconds: spots.iter().map(|s| s.seconds.0).sum(),
        setup_seconds: spots.iter().map(|s| s.seconds.1).sum(),
        spot_classes: spots.iter().map(|s| s.session.class.clone()).collect(),
    };
    folder
        .finish(result)
        .with_context(|| format!("cannot write the sheet's result into {}", dir.display()))?;
    draw_report(&dir);
    let sheet = read_sheet(&dir).map_err(|p| anyhow::anyhow!("{p}"))?;
    let json = sheet_json(&sheet);
    Ok(Measured::Sheet {
        dir,
        sheet: Box::new(sheet),
        json,
    })
}

/// The `--json` object of a sheet.
fn sheet_json(sheet: &crate::output::sheet_folder::ReadSheet) -> serde_json::Value {
    let summary = &sheet.summary;
    let result = sheet.doc.result.as_ref();
    let spots: Vec<serde_json::Value> = sheet
        .spots
        .iter()
        .map(|s| {
            let verdict = summary
                .verdicts
                .iter()
                .find(|j| j.number == s.result.number)
                .map(|j| j.verdict.clone());
            json!({
                "number": s.result.number,
                "folder": s.dir.display().to_string(),
                "class": s.session.class,
                "sigma_deg": s.session.values[0],
                "rho_s": s.session.values[1],
                "rho_d": s.session.values[2],
                "flags": s.result.flags,
                "verdict": verdict,
            })
        })
        .collect();
    json!({
        "schema": crate::schema::SHEET_RESULT,
        "sample": sheet.doc.sample,
        "session_dir": sheet.dir.display().to_string(),
        "spots_planned": sheet.doc.spots_planned,
        "accepted": summary.accepted,
        "spots": spots,
        "sigma_deg": summary.mean[0],
        "rho_s": summary.mean[1],
        "rho_d": summary.mean[2],
        "within_relative_sd": summary.within_relative_sd,
        "within_log_covariance": summary.within_log_covariance,
        "notes": summary.notes,
        "device_seconds": result.map(|r| r.device_seconds),
        "setup_seconds": result.map(|r| r.setup_seconds),
        "ok": summary.ok(),
        "flags": summary.flags,
    })
}

/// A file of the resumed folder, for messages.
fn existing_path(folder: &SessionFolder, name: &str) -> String {
    match folder {
        SessionFolder::Resume(dir) => dir.join(name).display().to_string(),
        SessionFolder::New(_) => name.to_string(),
    }
}

fn print_report(args: &Args, dir: &Path, outcome: &Outcome, summary: &serde_json::Value) {
    if args.json {
        println!("{summary}");
        return;
    }
    print!("{}", crate::analysis::result::to_table(&outcome.report));
    println!(
        "  {} geometries, {:.1} device s measuring (the instrument's own seconds; +{:.1} s homing and calibration); refinements: {}",
        outcome.points.len(),
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
    if outcome.ok() {
        println!(
            "  result: ok{}",
            if outcome.flags.is_empty() {
                String::new()
            } else {
                format!(" (noted: {})", flag_names(&outcome.flags))
            }
        );
    } else {
        println!("  result: NOT CLEAN, flags: {}", flag_names(&outcome.flags));
    }
    println!(
        "  files: {} (gonio verify {} checks them; report.html is the report to read, its glossary and the README's explain the terms)",
        dir.display(),
        dir.display()
    );
}

fn print_sheet(dir: &Path, sheet: &crate::output::sheet_folder::ReadSheet) {
    use crate::analysis::spots::SpotVerdict;
    let summary = &sheet.summary;
    println!(
        "sheet of '{}': {} spots planned, {} measured, {} accepted",
        sheet.doc.sample,
        sheet.doc.spots_planned,
        sheet.spots.len(),
        summary.accepted
    );
    let value = |v: Option<f64>, digits: usize| {
        v.map_or_else(|| "—".to_string(), |v| format!("{v:.digits$}"))
    };
    for s in &sheet.spots {
        let verdict = match summary
            .verdicts
            .iter()
            .find(|j| j.number == s.result.number)
            .map(|j| &j.verdict)
        {
            Some(SpotVerdict::Accepted) => "accepted".to_string(),
            Some(SpotVerdict::Excluded { reason }) => format!("EXCLUDED: {reason}"),
            None => "?".to_string(),
        };
        // The spot's own report, as its session.json holds it.
        let result = std::fs::read(s.dir.join(crate::output::folder::SESSION))
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .map(|v| v["result"].clone())
            .unwrap_or_default();
        let interval = |key: &str, digits: usize| match result["ci95"][key]
            .as_array()
            .map(|a| (a[0].as_f64(), a[1].as_f64()))
        {
            Some((Some(lo), Some(hi))) => format!(" [{lo:.digits$}, {hi:.digits$}]"),
            _ => String::new(),
        };
        let confidence = result["class_confidence"]
            .as_f64()
            .map_or_else(String::new, |c| format!(" (confidence {c:.2})"));
        println!(
            "  spot {}: class {}{confidence}  {verdict}",
            s.result.number,
            s.session.class.as_deref().unwrap_or("undecided")
        );
        println!(
            "    σ = {}°{}   ρs = {}{}   ρd = {}{}   (95 % intervals)",
            value(s.session.values[0], 3),
            interval("sigma_deg", 3),
            value(s.session.values[1], 4),
            interval("rho_s", 4),
            value(s.session.values[2], 4),
            interval("rho_d", 4)
        );
        println!(
            "    NMAE {:.2} %, {} geometries, {:.1} device s; flags: {}; report: {}",
            100.0 * result["nmae"].as_f64().unwrap_or(f64::NAN),
            result["geometries"].as_u64().unwrap_or(0),
            result["device_seconds"].as_f64().unwrap_or(f64::NAN),
            if s.result.flags.is_empty() {
                "none".to_string()
            } else {
                flag_names(&s.result.flags)
            },
            s.dir.join(crate::output::folder::SESSION).display()
        );
    }
    let spread = |i: usize| {
        summary.within_relative_sd.map_or_else(
            || "spot-to-spot unknown".to_string(),
            |sd| format!("spot-to-spot sd {:.1} %", 100.0 * sd[i]),
        )
    };
    println!(
        "  sheet (geometric mean of the accepted spots): σ = {}° ({}), ρs = {} ({}), ρd = {} ({})",
        value(summary.mean[0], 3),
        spread(0),
        value(summary.mean[1], 4),
        spread(1),
        value(summary.mean[2], 4),
        spread(2)
    );
    for note in &summary.notes {
        println!("  note: {note}");
    }
    if let Some(result) = &sheet.doc.result {
        println!(
            "  {:.1} device s measuring the spots (+{:.1} s homing, calibration and moving the sheet)",
            result.device_seconds, result.setup_seconds
        );
    }
    if summary.ok() {
        println!(
            "  result: ok{}",
            if summary.flags.is_empty() {
                String::new()
            } else {
                format!(" (noted: {})", flag_names(&summary.flags))
            }
        );
    } else {
        println!("  result: NOT CLEAN, flags: {}", flag_names(&summary.flags));
    }
    println!(
        "  files: {} (gonio verify {} checks them)",
        dir.display(),
        dir.display()
    );
}

fn flag_names(flags: &[crate::analysis::flags::Flag]) -> String {
    flags
        .iter()
        .map(|f| f.name())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Write the result into the folder (summary files, `session.json`, the manifest) and
/// return the result object printed by `--json`.
fn write_session(
    recorder: &mut FileRecorder,
    sample: &str,
    info: &protocol::DeviceInfo,
    outcome: &Outcome,
) -> anyhow::Result<serde_json::Value> {
    let mut result = crate::analysis::result::to_json(&outcome.report);
    if let Some(object) = result.as_object_mut() {
        object.insert("sample".into(), json!(sample));
        object.insert("geometries".into(), json!(outcome.current_points().count()));
        object.insert("device_seconds".into(), json!(outcome.device_seconds));
        object.insert("setup_seconds".into(), json!(outcome.setup_seconds));
        object.insert("refinements".into(), json!(outcome.refinements));
        object.insert("covariance".into(), json!(outcome.report.fit.covariance));
        object.insert("white_drift".into(), json!(outcome.white_drift));
        object.insert(
            "white_drift_exceeded".into(),
            json!(outcome.white_drift_exceeded),
        );
        object.insert("ok".into(), json!(outcome.ok()));
        object.insert("flags".into(), json!(outcome.flags));
        object.insert(
            "session_dir".into(),
            json!(recorder.dir().display().to_string()),
        );
        // What `gonio fit DIR` needs to make this analysis again from the folder.
        object.insert("analysis_settings".into(), json!(outcome.analysis_settings));
        object.insert("analysed_unix_s".into(), json!(outcome.analysed_unix_s));
        object.remove("file");
    }
    let result = crate::schema::tagged(crate::schema::SPOT_RESULT, result);
    let mut rest = serde_json::Map::new();
    rest.insert("ok".into(), json!(outcome.ok()));
    rest.insert("flags".into(), json!(outcome.flags));
    rest.insert("calibration".into(), json!(outcome.calibration));
    rest.insert("readings".into(), json!(outcome.points));
    rest.insert("fits".into(), json!(outcome.fits));
    rest.insert("refinements".into(), json!(outcome.refinements));
    rest.insert("step_checks".into(), json!(outcome.step_checks));
    rest.insert("recoveries".into(), json!(outcome.recoveries));
    rest.insert("result".into(), result.clone());
    // Superseded readings (taken while an arm was off) stay in session.json, marked, and
    // out of the export.
    let observations: Vec<Observation> = outcome
        .current_points()
        .filter_map(|p| {
            Some(Observation {
                theta_i_deg: p.theta_i_deg,
                theta_r_deg: p.theta_r_deg,
                radiance_factor: p.radiance_factor?,
                std: p.std,
                theta_r_span_deg: 0.0,
            })
        })
        .collect();
    let meta = crate::output::export::AstmMetadata {
        sample: sample.to_string(),
        instrument: format!("{} serial {}", instrument_name(info), info.serial_number),
        measured_at: std::time::SystemTime::now(),
        acceptance_deg: outcome.analysis_settings.acceptance_deg,
        integration_ms: outcome
            .points
            .first()
            .map_or(0, |p| p.reading.integration_ms),
        white_radiance_factor: outcome.calibration.white_radiance_factor,
        white_relative_uncertainty: outcome.calibration.white_relative_uncertainty,
        white_certificate: outcome.calibration.white_certificate.clone(),
    };
    let mut files = vec![(
        crate::output::export::astm_file_name(sample),
        crate::output::export::astm(&meta, &observations).into_bytes(),
    )];
    // The plots are drawn outside the folder, then replaced into it like every summary file.
    let staging = tempfile::tempdir().context("cannot make a temporary folder for the plots")?;
    for path in crate::output::plots::write_plots(
        staging.path(),
        sample,
        &observations,
        &outcome.report.fit,
        &outcome.report.classification,
    )
    .context("cannot draw the plots")?
    {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .context("a plot without a file name")?;
        files.push((
            name,
            std::fs::read(&path)
                .with_context(|| format!("cannot read the plot {}", path.display()))?,
        ));
    }
    let dir = recorder.dir().to_path_buf();
    recorder
        .finish(rest, &files)
        .with_context(|| format!("cannot write the result into {}", dir.display()))?;
    Ok(result)
}
