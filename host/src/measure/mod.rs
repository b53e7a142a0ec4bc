//! A whole measurement, on an instrument or the simulated one: what `gonio measure` runs.
//!
//! Every option is checked before anything moves (numbers against their limits, the
//! integration time against the instrument's announced limits); the session folder is
//! made for this session alone or, with a resume, taken only for the same sample,
//! instrument and plan ([`crate::output::folder::record`]). One spot is one [`super::Session`] in
//! its own folder ([`spot`]); a sheet of several spots is one session per spot under the
//! sheet's folder ([`spots`]).
pub mod batch;
mod check;
mod plan;
mod spot;
mod spots;
mod write;

pub use plan::{DEFAULT_WHITE_DRIFT_LIMIT_PCT, MAX_ACCEPTANCE_DEG};

use crate::instrument::calibration::Calibration;
use crate::instrument::link::{Client, LinkError, RetryPolicy, Transport};
use crate::instrument::serial::SerialTransport;
use crate::instrument::sim::SimOptions;
use crate::output::folder::store::StoreOptions;
use crate::session::{Operator, Outcome, PolicyChoice, SessionError};
use anyhow::{Context, bail};
use check::Checked;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// Spots of a sheet when none are given ([`crate::analysis::spots::DEFAULT_SPOTS`]).
pub const DEFAULT_SPOTS: u16 = crate::analysis::spots::DEFAULT_SPOTS;
/// The most spots a sheet takes.
pub(crate) const MAX_SPOTS: u16 = 20;

/// What to measure and how: the options of `gonio measure` (its `--json` aside), each
/// documented there. [`Default`] is no option given.
#[derive(Clone, Debug)]
pub struct MeasureOptions {
    /// The simulated instrument with this sample on the port, in process (else a serial port).
    pub sim: Option<String>,
    /// The simulated instrument's options.
    pub sim_options: SimOptions,
    /// Serial port of the instrument (`None`: the one attached instrument, by USB id).
    pub port: Option<String>,
    /// Name of the sample (`None`: the simulated sample, the resumed session's, or "sample").
    pub sample: Option<String>,
    /// Folder for the session's files (`None`: a new sessions/<local date-time>-<sample>).
    pub out: Option<PathBuf>,
    /// Continue the interrupted session (or sheet) in this folder.
    pub resume: Option<PathBuf>,
    /// The calibration of an earlier session (its folder, session.json or calibration.json).
    pub calibration: Option<PathBuf>,
    /// The white tile's certified radiance factor.
    pub tile_radiance_factor: f64,
    /// Standard uncertainty of the tile's radiance factor, percent.
    pub tile_uncertainty_pct: f64,
    /// The white tile's certificate (a JSON file), instead of the two numbers above.
    pub tile_certificate: Option<PathBuf>,
    /// Standard uncertainty of the detector arm's zero, degrees.
    pub arm_zero_uncertainty_deg: f64,
    /// The model fitted (`None`: the resumed session's, else
    /// [`crate::analysis::fit::ModelChoice::by_default`]).
    pub model: Option<crate::analysis::fit::ModelChoice>,
    /// The instrument profile (`None`: the one installed for the instrument, if any).
    pub instrument: Option<PathBuf>,
    /// Oldest profile used, days.
    pub max_profile_age_days: f64,
    /// Oldest calibration accepted, hours.
    pub max_calibration_age_h: f64,
    /// Integration time per reading (`None`: the resumed session's or the instrument's).
    pub integration_ms: Option<u16>,
    /// Refinement policy (`None`: the resumed session's, else adaptive).
    pub policy: Option<PolicyChoice>,
    /// Re-read the white tile at the end.
    pub white_check: bool,
    /// White drift beyond which the result is marked, percent.
    pub white_drift_limit_pct: Option<f64>,
    /// Spots of the sheet (`None`: [`DEFAULT_SPOTS`], or the resumed sheet's).
    pub spots: Option<u16>,
    /// The case or job number.
    pub case_id: Option<String>,
    /// Who measures.
    pub operator: Option<String>,
    /// A note (the item, where on it).
    pub note: Option<String>,
    /// The sheet's orientation on the port (`None`: unknown).
    pub orientation: Option<crate::analysis::specimen::Orientation>,
    /// The side of the sheet facing the instrument (`None`: unknown).
    pub side: Option<crate::analysis::specimen::Side>,
}

impl Default for MeasureOptions {
    fn default() -> Self {
        MeasureOptions {
            sim: None,
            sim_options: SimOptions::default(),
            port: None,
            sample: None,
            out: None,
            resume: None,
            calibration: None,
            tile_radiance_factor: crate::instrument::calibration::DEFAULT_WHITE_RADIANCE_FACTOR,
            tile_uncertainty_pct: 100.0
                * crate::instrument::calibration::DEFAULT_TILE_RELATIVE_UNCERTAINTY,
            tile_certificate: None,
            arm_zero_uncertainty_deg: crate::analysis::fit::DEFAULT_ARM_ZERO_UNCERTAINTY_DEG,
            model: None,
            instrument: None,
            max_profile_age_days: crate::instrument::profile::DEFAULT_MAX_AGE_DAYS,
            max_calibration_age_h: 8.0,
            integration_ms: None,
            policy: None,
            white_check: false,
            white_drift_limit_pct: None,
            spots: None,
            case_id: None,
            operator: None,
            note: None,
            orientation: None,
            side: None,
        }
    }
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
    /// A sheet of several spots was measured.
    Sheet {
        /// The sheet's folder.
        dir: PathBuf,
        /// The sheet as recorded (read back from its folder).
        sheet: Box<crate::output::folder::sheet::ReadSheet>,
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

/// The whole session on the instrument `options` name, asking `operator` to place the
/// tile; stops the instrument and returns [`Measured::Stopped`] once `interrupted` is set.
pub fn measure(
    options: &MeasureOptions,
    operator: &mut dyn Operator,
    interrupted: Arc<AtomicBool>,
) -> anyhow::Result<Measured> {
    measure_with(options, operator, interrupted, StoreOptions::default())
}

/// [`measure`], with the session folder's writes under `store` (a simulated crash, in tests).
pub fn measure_with(
    options: &MeasureOptions,
    operator: &mut dyn Operator,
    interrupted: Arc<AtomicBool>,
    store: StoreOptions,
) -> anyhow::Result<Measured> {
    // Numbers first: nothing is connected, moved or written for a bad one.
    let checked = check::check(options)?;
    let policy = RetryPolicy::default();
    let given = Given {
        options,
        checked: &checked,
        operator,
        interrupted,
        store,
    };
    // A folder that cannot be continued is said before any instrument is looked for (issue
    // 31: a finished session's --resume first said "no instrument found").
    if let Some(dir) = &options.resume {
        refuse_finished(dir, &given.store)?;
    }
    if let Some(sample) = &options.sim {
        let mut sim = options.sim_options.clone();
        // A resumed session's simulated instrument was switched on before, once per run.
        sim.power_on = options
            .resume
            .as_deref()
            .map_or(0, crate::instrument::sim::runs_recorded);
        // A simulator option (the sample's name, a fault) is the command line's.
        let instrument = sim
            .instrument(sample)
            .map_err(|e| crate::UsageError(e.to_string()))?;
        run_on(Client::new(instrument, policy), given, Some(sample.clone()))
    } else {
        let transport = open_port(options.port.as_deref())?;
        run_on(Client::new(transport, policy), given, None)
    }
}

/// The error of `--resume DIR` on a finished session or sheet, or on a folder that holds
/// none, before anything is connected; every other problem of the folder is found where
/// it is opened to continue.
fn refuse_finished(dir: &Path, store: &StoreOptions) -> anyhow::Result<()> {
    use crate::output::folder::lock::FolderError;
    let finished = if crate::output::folder::is_sheet_folder(dir) {
        crate::output::folder::sheet::SheetFolder::open(dir, store.clone()).err()
    } else {
        crate::output::folder::record::Existing::open(dir, store.clone()).err()
    };
    match finished {
        // A missing folder, or one with no session, cannot be continued either: said
        // before "no instrument found".
        Some(
            e @ (FolderError::Finished { .. }
            | FolderError::FinishedSheet { .. }
            | FolderError::NoFolder(_)
            | FolderError::NotAFolder(_)
            | FolderError::NoSession(_)),
        ) => Err(e.into()),
        _ => Ok(()),
    }
}

/// The instrument's serial port: `port`, or the one instrument found attached; checked
/// and opened, with a message that says what to do when it cannot be.
pub fn open_port(port: Option<&str>) -> anyhow::Result<SerialTransport> {
    let path = match port {
        Some(path) => path.to_string(),
        None => crate::instrument::serial::find_instrument()?.context(
            "no instrument found (gonio ports lists the serial ports); give --port PATH, or --sim SAMPLE for the simulated instrument",
        )?,
    };
    check::check_port(&path)?;
    let transport = SerialTransport::open(&path).map_err(|e| match e.to_string() {
        m if m.contains("Not a typewriter") || m.contains("Inappropriate ioctl") => {
            anyhow::anyhow!("--port {path} is not a serial port (a device, but not a terminal): give the instrument's port (gonio ports lists them)")
        }
        m => anyhow::anyhow!("cannot open --port {path}: {m}"),
    })?;
    Ok(transport)
}

/// Everything the measurement was given, checked.
struct Given<'a> {
    options: &'a MeasureOptions,
    checked: &'a Checked,
    operator: &'a mut dyn Operator,
    interrupted: Arc<AtomicBool>,
    store: StoreOptions,
}

/// The first greeting, repeated while the instrument stays silent for less than the link's
/// give-up time: a cable pulled for a moment as the session starts is ridden out as one
/// pulled mid-way is (the pty campaign of issue 30: a 1.4 s unplug at the start failed
/// the handshake, which alone gave up after its four unanswered tries, 2 s). A port
/// silent or failing for the whole give-up time (10 s) is refused as before, with the
/// handshake's error; a device heard but never understood, by the handshake's own bound.
fn greet<T: Transport>(client: &mut Client<T>) -> Result<protocol::DeviceInfo, LinkError> {
    let started = client.transport().now();
    loop {
        let within = |client: &Client<T>| {
            client.transport().now().saturating_sub(started) < client.policy().give_up_after
        };
        match client.hello() {
            Err(LinkError::NoReply { .. } | LinkError::Silent { .. }) if within(client) => {}
            // The port failed (a cable out, a USB device gone for a moment): open it again
            // after a pause, as a reconnection mid-session does.
            Err(LinkError::Io(_)) if within(client) => {
                client.transport_mut().pause(Duration::from_millis(250));
                let _ = client.transport_mut().reconnect();
            }
            other => return other,
        }
    }
}

/// Greet the instrument, then measure a sheet or one session.
fn run_on<T: Transport>(
    mut client: Client<T>,
    given: Given<'_>,
    sim_sample: Option<String>,
) -> anyhow::Result<Measured> {
    let Given {
        options,
        checked,
        operator,
        interrupted,
        store,
    } = given;
    let info = greet(&mut client).context("handshake with the instrument")?;
    let profile = profile_in_force(options, &info)?;
    let mut context = Run {
        client: &mut client,
        info,
        profile,
        options,
        checked,
        sim_sample,
        operator,
        interrupted,
        store,
    };
    let sheet = options
        .resume
        .as_deref()
        .is_some_and(crate::output::folder::is_sheet_folder)
        || (options.resume.is_none() && checked.spots > 1);
    if sheet {
        return spots::run_sheet(&mut context);
    }
    if let (Some(dir), Some(spots)) = (&options.resume, options.spots.filter(|n| *n > 1)) {
        bail!(
            "{} is a session of one spot: it is continued as it began, without --spots {spots} (or start a sheet of {spots} spots with --out)",
            dir.display()
        );
    }
    let folder = match &options.resume {
        Some(dir) => SessionFolder::Resume(dir.clone()),
        None => SessionFolder::New(options.out.clone()),
    };
    spot::run_session(&mut context, folder, None)
}

/// The instrument profile in force: `--instrument FILE` (refused when unreadable, not a
/// profile, or another instrument's), else the one installed for the instrument's serial;
/// `None` (said on the terminal) when there is none or it is older than the limit.
fn profile_in_force(
    options: &MeasureOptions,
    info: &protocol::DeviceInfo,
) -> anyhow::Result<Option<crate::instrument::profile::ProfileInUse>> {
    use crate::instrument::profile;
    anyhow::ensure!(
        options.max_profile_age_days.is_finite() && options.max_profile_age_days > 0.0,
        "--max-profile-age-days must be a positive number of days, not {}",
        options.max_profile_age_days
    );
    let path = match &options.instrument {
        Some(path) => path.clone(),
        None => match profile::default_path(&info.serial_number) {
            Some(path) if path.is_file() => path,
            _ => {
                eprintln!(
                    "note: no instrument profile for {}: the detector's response and arm zero are the declared ones (gonio characterize measures them)",
                    info.serial_number
                );
                return Ok(None);
            }
        },
    };
    let (found, sha) = profile::read(&path)?;
    if found.serial_number != info.serial_number.as_str() {
        return Err(profile::ProfileError::OtherInstrument {
            path,
            profile: found.serial_number,
            attached: info.serial_number.to_string(),
        }
        .into());
    }
    let now = crate::instrument::calibration::unix_now_s();
    let age = found.age_days(now);
    if !(age <= options.max_profile_age_days) {
        eprintln!(
            "warning: the instrument profile {} is {age:.0} days old, beyond the limit of {} days: not used; the declared values are (gonio characterize measures the instrument again)",
            path.display(),
            options.max_profile_age_days
        );
        return Ok(None);
    }
    Ok(Some(found.in_use(sha, now)))
}

/// What every session of one measurement shares.
struct Run<'a, T: Transport> {
    client: &'a mut Client<T>,
    info: protocol::DeviceInfo,
    /// The instrument profile in force.
    profile: Option<crate::instrument::profile::ProfileInUse>,
    options: &'a MeasureOptions,
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
    /// The sheet's plan: every spot's.
    plan: crate::output::folder::PlanRecord,
}

/// The command that continues a session in `dir`.
pub fn resume_command(options: &MeasureOptions, dir: &Path) -> String {
    let on = match (&options.sim, &options.port) {
        (Some(sample), _) => format!(" --sim {sample}"),
        (None, Some(port)) => format!(" --port {port}"),
        (None, None) => String::new(),
    };
    format!("gonio measure{on} --resume {}", dir.display())
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

/// The status a folder records for a session that stopped with `error`.
fn status_of(error: &SessionError) -> crate::output::folder::Status {
    use crate::output::folder::Status;
    if matches!(error, SessionError::Interrupted) {
        Status::Interrupted
    } else {
        Status::Failed
    }
}
