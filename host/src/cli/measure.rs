//! `gonio measure`: the whole measurement session, on an instrument or the simulated one.
use crate::instrument::calibration::{Calibration, Tile, instrument_name};
use crate::analysis::fit::Observation;
use crate::instrument::link::{Client, RetryPolicy, Transport};
use crate::instrument::serial::SerialTransport;
use crate::output::record::{FileRecorder, read_points};
use crate::session::{Operator, Outcome, Plan, PolicyChoice, PromptOperator, Recorder, Session, SessionError, SimulatedOperator};
use crate::instrument::sim::SimOptions;
use anyhow::Context;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

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
    /// Name of the sample for the report and the files (default: the simulated sample, or "sample").
    #[arg(long)]
    pub sample: Option<String>,
    /// Folder for the session's files (default: sessions/<time>-<sample>).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Continue an interrupted session in DIR, measuring only what is missing.
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
    /// Oldest calibration accepted, hours.
    #[arg(long, value_name = "HOURS", default_value_t = 8.0)]
    pub max_calibration_age_h: f64,
    /// Integration time per reading (default: the instrument's).
    #[arg(long, value_name = "MS")]
    pub integration_ms: Option<u16>,
    /// Refinement policy: adaptive reaches the paper's accuracy in a fraction of its
    /// device time (docs/TRADE.md); paper follows the paper's procedure exactly.
    #[arg(long, value_enum, default_value_t = PolicyChoice::Adaptive)]
    pub policy: PolicyChoice,
    /// Re-read the white tile at the end and mark the result if it drifted.
    #[arg(long)]
    pub white_check: bool,
    /// White drift beyond which the result is marked, percent.
    #[arg(long, value_name = "PERCENT", default_value_t = 0.5)]
    pub white_drift_limit_pct: f64,
    /// Print one JSON object instead of the report.
    #[arg(long)]
    pub json: bool,
}

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
    let argv = std::iter::once(std::ffi::OsString::from("measure")).chain(args.into_iter().map(Into::into));
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
    /// The session stopped (Ctrl-C, a dead link); the instrument was told to stop, and the
    /// readings taken are in `dir`.
    Stopped {
        /// The session folder.
        dir: PathBuf,
        /// Why.
        error: SessionError,
    },
}

/// Run `gonio measure`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let interrupted = Arc::new(AtomicBool::new(false));
    let flag = interrupted.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed)).context("cannot install the Ctrl-C handler")?;
    // In process the simulated operator swaps the tile; on any port a person is asked.
    let mut operator: Box<dyn Operator> = if args.sim.is_some() { Box::new(SimulatedOperator) } else { Box::new(PromptOperator) };
    match measure(&args, operator.as_mut(), interrupted)? {
        Measured::Done { dir, outcome, summary } => {
            print_report(&args, &dir, &outcome, &summary);
            Ok(ExitCode::SUCCESS)
        }
        Measured::Stopped { dir, error } => {
            eprintln!("session stopped: {error}");
            eprintln!("readings so far are in {}; continue with: gonio measure --resume {} ...", dir.display(), dir.display());
            Ok(ExitCode::FAILURE)
        }
    }
}

/// The whole session on the instrument `args` name, asking `operator` to place the tile;
/// stops the instrument and returns [`Measured::Stopped`] once `interrupted` is set.
pub fn measure(args: &Args, operator: &mut dyn Operator, interrupted: Arc<AtomicBool>) -> anyhow::Result<Measured> {
    let policy = RetryPolicy::default();
    if let Some(sample) = &args.sim {
        let instrument = args.sim_options.instrument(sample)?;
        run_on(Client::new(instrument, policy), args, sample.clone(), operator, interrupted)
    } else {
        let path = match &args.port {
            Some(path) => path.clone(),
            None => crate::instrument::serial::find_instrument()?.context(
                "no instrument found (gonio ports lists the serial ports); give --port PATH, or --sim SAMPLE for the simulated instrument",
            )?,
        };
        let transport = SerialTransport::open(&path).with_context(|| format!("cannot open {path}"))?;
        run_on(Client::new(transport, policy), args, "sample".into(), operator, interrupted)
    }
}

fn run_on<T: Transport>(mut client: Client<T>, args: &Args, sample: String, operator: &mut dyn Operator, interrupted: Arc<AtomicBool>) -> anyhow::Result<Measured> {
    let sample = args.sample.clone().unwrap_or(sample);
    let tile = Tile::new(args.tile_radiance_factor, args.tile_uncertainty_pct).context("--tile-radiance-factor / --tile-uncertainty-pct")?;
    let info = client.hello().context("handshake with the instrument")?;
    let dir = match (&args.resume, &args.out) {
        (Some(dir), _) | (None, Some(dir)) => dir.clone(),
        (None, None) => {
            let stamp = crate::instrument::calibration::unix_now_s();
            PathBuf::from("sessions").join(format!("{stamp}-{}", sample.replace(['/', ':', ','], "_")))
        }
    };
    let max_age = Duration::from_secs_f64(args.max_calibration_age_h.max(0.0) * 3600.0);
    let mut calibration = match &args.calibration {
        Some(path) => {
            let path = if path.is_dir() { path.join("calibration.json") } else { path.clone() };
            Some(Calibration::load(&path, max_age, &info)?)
        }
        None => None,
    };
    let mut points = Vec::new();
    if let Some(dir) = &args.resume {
        points = read_points(dir)?;
        if calibration.is_none() && dir.join("calibration.json").exists() {
            calibration = Some(Calibration::load(&dir.join("calibration.json"), max_age, &info)?);
        }
        eprintln!("resuming {}: {} readings already taken", dir.display(), points.len());
    }
    let mut recorder = FileRecorder::open(&dir).with_context(|| format!("cannot write to {}", dir.display()))?;
    if let Some(c) = &calibration {
        recorder.calibration(c)?;
    }
    let plan = Plan {
        sample: sample.clone(),
        integration_ms: args.integration_ms.unwrap_or(info.default_integration_ms),
        policy: args.policy.into(),
        acceptance_deg: f64::from(info.acceptance_deg),
        white_check: args.white_check,
        white_drift_limit: args.white_drift_limit_pct / 100.0,
    };
    client.set_interrupt(Some(interrupted));
    let session = Session::new(&mut client, info.clone(), plan, &mut recorder, operator).with_tile(tile).resume_from(calibration, points);
    let outcome = session.run();
    recorder.bar.finish_and_clear();
    let outcome = match outcome {
        Ok(outcome) => outcome,
        Err(error) => {
            // Whatever happened, leave the instrument safe (arms stopped, lamp off); the
            // readings are on disk already. A second Ctrl-C must not stop this.
            client.set_interrupt(None);
            let _ = client.request(protocol::Command::Abort);
            let _ = client.request(protocol::Command::SetLamp { on: false });
            return Ok(Measured::Stopped { dir, error });
        }
    };
    let _ = client.request(protocol::Command::SetLamp { on: false });
    let summary = write_session(&dir, &sample, &info, &outcome, &recorder.decisions)?;
    Ok(Measured::Done { dir, outcome: Box::new(outcome), summary })
}

fn print_report(args: &Args, dir: &Path, outcome: &Outcome, summary: &serde_json::Value) {
    if args.json {
        println!("{summary}");
        return;
    }
    print!("{}", crate::analysis::report::to_table(&outcome.report));
    println!(
        "  {} geometries, {:.1} device s measuring (+{:.1} s homing and calibration); refinements: {}",
        outcome.points.len(),
        outcome.device_seconds,
        outcome.setup_seconds,
        if outcome.refinements.is_empty() { "none".to_string() } else { outcome.refinements.iter().map(|r| match r.delta_deg { Some(d) => format!("δ = {d}° (+{}: {})", r.added, r.reason), None => format!("+{} ({})", r.added, r.reason) }).collect::<Vec<_>>().join("; ") }
    );
    if let Some(drift) = outcome.white_drift {
        println!("  white check: drift {:.2} %{}", 100.0 * drift, if outcome.white_drift_exceeded { " — BEYOND THE LIMIT, result marked" } else { "" });
    }
    println!("  files: {}", dir.display());
}

/// Write `session.json` and return the result object printed by `--json`.
fn write_session(dir: &Path, sample: &str, info: &protocol::DeviceInfo, outcome: &Outcome, decisions: &[String]) -> anyhow::Result<serde_json::Value> {
    let mut result = crate::analysis::report::to_json(&outcome.report);
    if let Some(object) = result.as_object_mut() {
        object.insert("sample".into(), json!(sample));
        object.insert("geometries".into(), json!(outcome.points.len()));
        object.insert("device_seconds".into(), json!(outcome.device_seconds));
        object.insert("setup_seconds".into(), json!(outcome.setup_seconds));
        // The paper's refinements by their δ, adaptive batches by the geometries they added.
        object.insert("refinements".into(), json!(outcome.refinements.iter().map(|r| r.delta_deg.map_or(r.added as u64, u64::from)).collect::<Vec<_>>()));
        object.insert("covariance".into(), json!(outcome.report.fit.covariance));
        object.insert("white_drift".into(), json!(outcome.white_drift));
        object.insert("white_drift_exceeded".into(), json!(outcome.white_drift_exceeded));
        object.remove("file");
    }
    let session = json!({
        "sample": sample,
        "device": info,
        "calibration": outcome.calibration,
        "readings": outcome.points,
        "fits": outcome.fits,
        "refinements": outcome.refinements,
        "decisions": decisions,
        "result": result,
    });
    let path = dir.join("session.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&session)?).with_context(|| format!("cannot write {}", path.display()))?;
    let observations: Vec<Observation> = outcome
        .points
        .iter()
        .filter_map(|p| Some(Observation { theta_i_deg: p.theta_i_deg, theta_r_deg: p.theta_r_deg, radiance_factor: p.radiance_factor?, std: p.std }))
        .collect();
    let export = dir.join("astm-e1392.csv");
    crate::output::export::write_astm_e1392_csv(&export, sample, &instrument_name(info), &observations)
        .with_context(|| format!("cannot write {}", export.display()))?;
    crate::output::plots::write_plots(dir, sample, &observations, &outcome.report.fit, &outcome.report.classification)
        .with_context(|| format!("cannot write the plots into {}", dir.display()))?;
    Ok(result)
}
