//! The arguments of `gonio measure` and the [`MeasureOptions`] they give. Self-contained
//! (only `host::` paths), so the tests parse their argument lists as the command line does
//! (`#[path]`).
use host::instrument::sim::SimOptions;
use host::measure::MeasureOptions;
use host::session::PolicyChoice;
use std::path::PathBuf;

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
    #[arg(long, value_name = "FACTOR", default_value_t = host::instrument::calibration::DEFAULT_WHITE_RADIANCE_FACTOR, allow_negative_numbers = true)]
    pub tile_radiance_factor: f64,
    /// Standard uncertainty (k = 1) of the tile's certified radiance factor, percent; half a
    /// certificate's expanded (k = 2) uncertainty. The default is an assumption for a
    /// working-standard tile certified to ±1 % at k = 2.
    #[arg(long, value_name = "PERCENT", default_value_t = 100.0 * host::instrument::calibration::DEFAULT_TILE_RELATIVE_UNCERTAINTY, allow_negative_numbers = true)]
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
    #[arg(long, value_name = "DEG", default_value_t = host::analysis::fit::DEFAULT_ARM_ZERO_UNCERTAINTY_DEG, allow_negative_numbers = true)]
    pub arm_zero_uncertainty_deg: f64,
    /// The instrument's profile (gonio characterize): the fit models the detector's
    /// measured angular response and takes the arm zero measured on the black glass.
    /// Default: the profile installed for the instrument's serial
    /// ($XDG_DATA_HOME/gonio/instruments/SERIAL.json), if there is one; without any, the
    /// declared values are used and the result is flagged instrument-declared.
    #[arg(long, value_name = "FILE")]
    pub instrument: Option<PathBuf>,
    /// Oldest instrument profile used, days: an older one is not used (the result says so).
    #[arg(long, value_name = "DAYS", default_value_t = host::instrument::profile::DEFAULT_MAX_AGE_DAYS)]
    pub max_profile_age_days: f64,
    /// The model fitted: extended (the paper's TSL model and the extensions the readings
    /// call for, each named in the result; σ, ρs, ρd stay the main lobe's, classified by
    /// the paper's tree) or paper (the paper's model alone: a sheet it does not describe
    /// is only flagged). Recorded in session.json; a resumed session keeps its own.
    /// Default: extended (`GONIO_MODEL_EXTENSIONS=0`: paper).
    #[arg(long, value_enum, value_name = "MODEL")]
    pub model: Option<host::analysis::fit::ModelChoice>,
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
    /// The key (gonio keys list) that signs the folder's manifest (signature.json).
    /// Default: the default key, else the only key; with --sim the key 'sim', made on
    /// first use. With no key the folder is written unsigned (gonio verify says so).
    #[arg(long, value_name = "NAME")]
    pub key: Option<String>,
    /// The sheet's machine direction relative to the plane of incidence: md (machine
    /// direction in it) or cd (cross direction); recorded in session.json, sheet.json and
    /// the report, and weighed by gonio compare and the library. Asked on an instrument
    /// when not given; unknown without it.
    #[arg(long, value_name = "md|cd")]
    pub orientation: Option<host::analysis::specimen::Orientation>,
    /// The side of the sheet facing the instrument: felt or wire (as --orientation).
    #[arg(long, value_name = "felt|wire")]
    pub side: Option<host::analysis::specimen::Side>,
    /// Print one JSON object instead of the report.
    #[arg(long)]
    pub json: bool,
}

impl Args {
    /// The options the library measures with.
    pub fn options(&self) -> MeasureOptions {
        MeasureOptions {
            sim: self.sim.clone(),
            sim_options: self.sim_options.clone().with_seed(
                self.resume
                    .as_deref()
                    .and_then(host::instrument::sim::recorded_seed),
            ),
            port: self.port.clone(),
            sample: self.sample.clone(),
            out: self.out.clone(),
            resume: self.resume.clone(),
            calibration: self.calibration.clone(),
            tile_radiance_factor: self.tile_radiance_factor,
            tile_uncertainty_pct: self.tile_uncertainty_pct,
            tile_certificate: self.tile_certificate.clone(),
            arm_zero_uncertainty_deg: self.arm_zero_uncertainty_deg,
            model: self.model,
            instrument: self.instrument.clone(),
            max_profile_age_days: self.max_profile_age_days,
            max_calibration_age_h: self.max_calibration_age_h,
            integration_ms: self.integration_ms,
            policy: self.policy,
            white_check: self.white_check,
            white_drift_limit_pct: self.white_drift_limit_pct,
            spots: self.spots,
            case_id: self.case_id.clone(),
            operator: self.operator.clone(),
            note: self.note.clone(),
            orientation: self.orientation,
            side: self.side,
        }
    }
}

/// The options of a `gonio measure` argument list (`args` without the program and
/// subcommand names), as the command line parses them.
#[allow(dead_code)] // The tests' way to options; the binary parses its whole command line.
pub fn parse_args<I, S>(args: I) -> Result<MeasureOptions, clap::Error>
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
    <Measure as clap::Parser>::try_parse_from(argv).map(|m| m.args.options())
}
