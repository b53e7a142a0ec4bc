//! The session folder as it is on disk: its files, the `session.json` document, and the
//! read-only checks that `gonio verify` reports and that a `--resume` repairs or refuses.
//!
//! | file | what | written |
//! |---|---|---|
//! | `points.jsonl` | the primary record: every reading as it arrived, one JSON object a line | appended, synced per line |
//! | `readings.csv` | the convertible readings of `points.jsonl`, in its order (`gonio fit` reads it) | appended; rebuilt from `points.jsonl` by a resume |
//! | `session.json` | sample, instrument, plan, status, every run, and at the end the result | replaced atomically |
//! | `calibration.json` | the calibration the readings were converted with | replaced atomically |
//! | `session.log` | every decision, time-stamped, tagged with its run | appended |
//! | `<sample>.astm`, `fig*.svg` | summaries of the result (the ASTM E1392/E2387 exchange format, plots) | replaced atomically at the end |
//! | `MANIFEST.sha256` | the SHA-256 of every other file, in `sha256sum` format | last, atomically |
//! | `signature.json` | the signature of the manifest, when a key signed it | right after it |
//!
//! # One module for the folder, in layers
//!
//! Reading, writing, verifying and signing a session or sheet folder are this module's.
//! Each part imports only those below it (paths `crate::output::folder::…`), so there is
//! no circle among them; nothing here imports anything else of `output` (the report is
//! above: its check is handed the drawing, `verify::DrawReport`):
//!
//! | layer | modules | imports from `folder` |
//! |---|---|---|
//! | verification | [`verify`]: every check of a finished session or sheet folder, on what [`sheet`] read | all below |
//! | writers and the sheet's reader | [`record`] (a session folder), [`sheet`] (a sheet's: written, and read once into [`sheet::ReadSheet`] / [`sheet::ReadFolder`]) | all below |
//! | signatures | [`signature`]: the manifest's signature, a file's, the keys | `store`, `manifest`, this page |
//! | store, manifest, lock and documents | [`store`], [`manifest`], [`lock`], [`documents`] (the typed result and outcome of a finished `session.json`) | this page |
//! | names and reading | this page: file names, `session.json`, findings, reading a file | none |
use crate::instrument::calibration::Calibration;
use crate::schema;
use crate::session::MeasuredPoint;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};

pub mod documents;
pub mod lock;
pub mod manifest;
pub mod record;
pub mod sheet;
pub mod signature;
pub mod store;
pub mod verify;

/// The primary record.
pub(crate) const POINTS: &str = "points.jsonl";
/// The convertible readings as CSV, derived from [`POINTS`].
pub(crate) const READINGS: &str = "readings.csv";
/// The session document.
pub const SESSION: &str = "session.json";
/// The calibration.
pub(crate) const CALIBRATION: &str = "calibration.json";
/// The decision log.
pub(crate) const LOG: &str = "session.log";
/// The manifest.
pub const MANIFEST: &str = "MANIFEST.sha256";
/// The report drawn from a finished session or sheet folder's files (not in its manifest:
/// `gonio verify` checks it against them instead).
pub(crate) const REPORT: &str = "report.html";
/// The signature of a finished folder's manifest ([`signature`]): not in
/// the manifest, which it signs.
pub const SIGNATURE: &str = "signature.json";
/// The sheet document of a folder of several spots.
pub(crate) const SHEET: &str = "sheet.json";
/// The header of [`READINGS`]: the angles in degrees, named with their unit.
pub(crate) const READINGS_HEADER: &str = "theta_i_deg,theta_r_deg,radiance_factor,std";
/// The header of [`READINGS`] once a reading was taken while the detector moved (a sweep's
/// bin): its travel in θr, degrees, in a fifth column.
pub(crate) const READINGS_HEADER_WITH_SPAN: &str =
    "theta_i_deg,theta_r_deg,radiance_factor,std,theta_r_span_deg";
/// The header of [`READINGS`] in folders written before it named the angles' unit; their
/// rows hold the angles unrounded. Such folders still verify and resume (a resume
/// rewrites the file in the current form).
pub(crate) const LEGACY_READINGS_HEADER: &str = "theta_i,theta_r,radiance_factor,std";
/// [`LEGACY_READINGS_HEADER`] with the span column.
pub(crate) const LEGACY_READINGS_HEADER_WITH_SPAN: &str =
    "theta_i,theta_r,radiance_factor,std,theta_r_span";
/// An angle as [`READINGS`] writes it: as it is recorded
/// ([`crate::session::recorded_angle`]), so that a still reading's schedule arithmetic
/// shows no float noise either.
pub(crate) fn rounded_angle(deg: f64) -> f64 {
    crate::session::recorded_angle(deg)
}

/// The two headers (without, with the span column) of the form `header` belongs to.
fn header_form(header: &str) -> Option<(&'static str, &'static str)> {
    [
        (READINGS_HEADER, READINGS_HEADER_WITH_SPAN),
        (LEGACY_READINGS_HEADER, LEGACY_READINGS_HEADER_WITH_SPAN),
    ]
    .into_iter()
    .find(|(still, moving)| header == *still || header == *moving)
}

/// Whether `header` is one of the legacy headers (unitless names, angles unrounded).
pub(crate) fn is_legacy_header(header: &str) -> bool {
    header == LEGACY_READINGS_HEADER || header == LEGACY_READINGS_HEADER_WITH_SPAN
}

/// The suffix of a file being replaced ([`store::Store::replace`]).
const TEMP_SUFFIX: &str = ".gonio-tmp";

/// Whether `name` is a temporary file that [`store::Store::replace`] writes
/// (and a kill can leave).
pub fn is_temp_name(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(TEMP_SUFFIX)
}

/// The temporary name [`store::Store::replace`] writes `name` under.
pub(crate) fn temp_name(name: &str) -> String {
    format!(".{name}{TEMP_SUFFIX}")
}

/// The folder name of spot `number` in a sheet's folder.
pub(crate) fn spot_folder(number: u16) -> String {
    format!("spot-{number}")
}

/// Whether `dir` is the folder of a multi-spot sheet.
pub fn is_sheet_folder(dir: &Path) -> bool {
    dir.join(SHEET).is_file()
}

/// A sample's name as a file name: letters, digits, `.`, `_` and `-` kept, the rest `_`.
pub(crate) fn file_name_of(sample: &str) -> String {
    let name: String = sample
        .chars()
        .take(48)
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if name.is_empty() || name.starts_with('.') {
        format!("_{name}")
    } else {
        name
    }
}

/// The name of a new folder for `sample` under `sessions/`: `<local date-time>-<sample>`
/// (a session's and a sheet's alike; the caller adds `-2`, `-3`… when it is taken).
pub(crate) fn dated_folder_name(sample: &str) -> String {
    format!(
        "{}-{}",
        chrono::Local::now().format("%Y-%m-%d_%H-%M-%S"),
        file_name_of(sample)
    )
}

/// A document's bytes as gonio writes its JSON files: pretty, with a last newline.
pub(crate) fn json_bytes(value: &impl serde::Serialize) -> std::io::Result<Vec<u8>> {
    let mut bytes = serde_json::to_vec_pretty(value)?;
    bytes.push(b'\n');
    Ok(bytes)
}

/// The header `readings.csv` has for `points`: the span column once any was taken moving.
pub(crate) fn readings_header(points: &[MeasuredPoint]) -> &'static str {
    if points.iter().any(|p| p.theta_r_span_deg > 0.0) {
        READINGS_HEADER_WITH_SPAN
    } else {
        READINGS_HEADER
    }
}

/// Where a session stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Status {
    /// Measuring (or the process was killed while it was: its run has no end).
    Running,
    /// Done: the result is in `session.json`; it is not measured again.
    Finished,
    /// Stopped by a failure; can be resumed.
    Failed,
    /// Stopped by the user; can be resumed.
    Interrupted,
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Status::Running => "running",
            Status::Finished => "finished",
            Status::Failed => "failed",
            Status::Interrupted => "interrupted",
        })
    }
}

/// How one run (one `gonio measure` process on the folder) ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RunOutcome {
    /// Still measuring.
    Running,
    /// Finished the session.
    Finished,
    /// Stopped by a failure.
    Failed,
    /// Stopped by the user.
    Interrupted,
    /// Ended without closing its run (killed, a power loss): found by the next resume.
    Killed,
}

/// The instrument a session is measured on, as the handshake named it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct InstrumentRecord {
    /// Its unique serial number (the chain of custody rests on it).
    pub serial_number: String,
    /// Board name.
    pub board: String,
    /// Firmware version.
    pub firmware_version: String,
    /// On the simulated instrument: the sample its scene holds (`--sim`), whatever the
    /// sample is named.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) simulated_sample: Option<String>,
    /// On the simulated instrument: the seed of its noise and faults (`--seed` repeats the
    /// run; `--resume` continues with it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) simulated_seed: Option<u64>,
}

/// The case a session belongs to (`gonio measure --case --operator --note`), as the
/// examiner states it; every field optional.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CaseRecord {
    /// The case or job number.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub case_id: Option<String>,
    /// Who measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub operator: Option<String>,
    /// A free note (the item, where on it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The sheet's machine direction relative to the plane of incidence (`--orientation`,
    /// or the operator's answer on an instrument); absent: unknown.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation: Option<crate::analysis::specimen::Orientation>,
    /// The side of the sheet facing the instrument (`--side`, or the operator's answer);
    /// absent: unknown.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub side: Option<crate::analysis::specimen::Side>,
}

impl CaseRecord {
    /// Whether no field is given.
    pub fn is_empty(&self) -> bool {
        self.case_id.is_none()
            && self.operator.is_none()
            && self.note.is_none()
            && self.orientation.is_none()
            && self.side.is_none()
    }

    /// How the sheet lay, as stated (each `None`: unknown).
    pub fn lay(&self) -> crate::analysis::specimen::SheetLay {
        crate::analysis::specimen::SheetLay {
            orientation: self.orientation,
            side: self.side,
        }
    }
}

/// What the session was asked to measure: a resume must ask for the same.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlanRecord {
    /// `paper`, `adaptive` or `sweep`.
    pub policy: String,
    /// The adaptive policy's targets (its stopping rule), when adaptive.
    pub adaptive_targets: Option<AdaptiveTargetsRecord>,
    /// The sweep policy's pass and targets, when `sweep`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sweep_targets: Option<crate::session::sweep_policy::SweepTargets>,
    /// Integration time of every reading, ms.
    pub integration_ms: u16,
    /// Detector acceptance modelled in the fit, degrees.
    pub acceptance_deg: f64,
    /// The white tile is re-read at the end.
    pub white_check: bool,
    /// Drift beyond which the result is marked, percent.
    pub white_drift_limit_pct: f64,
    /// The model fitted: `extended` or `paper` ([`crate::analysis::fit::ModelChoice`]).
    /// Absent in sessions begun before it was recorded, whose default was the paper's
    /// model: a resume of one fits that.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
}

impl PlanRecord {
    /// The model the plan fits: its record, else the paper's (see [`PlanRecord::model`]).
    pub(crate) fn model_choice(&self) -> anyhow::Result<crate::analysis::fit::ModelChoice> {
        use crate::analysis::fit::ModelChoice;
        match self.model.as_deref() {
            None => Ok(ModelChoice::Paper),
            Some(name) => <ModelChoice as clap::ValueEnum>::from_str(name, true).map_err(|_| {
                anyhow::anyhow!(
                    "the session's model '{name}' is not one this gonio knows (extended, paper)"
                )
            }),
        }
    }
}

/// [`crate::session::adaptive::AdaptiveTargets`] as recorded.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdaptiveTargetsRecord {
    /// σ's 95 % half-width relative to σ.
    pub(crate) sigma_rel_half_width: f64,
    /// Class confidence.
    pub class_confidence: f64,
    /// Geometries per batch.
    pub batch: usize,
    /// Batches at most.
    pub max_batches: usize,
}

/// One run of `gonio measure` on the folder.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Run {
    /// 1, 2, … in order.
    pub run: u32,
    /// Local date-time it started (RFC 3339).
    pub started: String,
    /// Local date-time it ended; `None` while running or when it was killed.
    pub ended: Option<String>,
    /// The `gonio` version that ran it.
    pub host_version: String,
    /// How it ended.
    pub outcome: RunOutcome,
    /// Why it stopped (failed, interrupted, killed).
    pub why: Option<String>,
    /// Readings in `points.jsonl` when it started.
    pub readings_before: usize,
    /// Readings in `points.jsonl` when it ended (unknown when killed).
    pub readings_after: Option<usize>,
    /// Its decisions, in order (for a killed run: as its `session.log` lines kept them).
    pub decisions: Vec<String>,
}

/// `session.json`: the typed head of the document; the result's parts (readings, fits,
/// refinements, result, ok, flags…) are kept as they are in `rest`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionDoc {
    /// [`crate::schema::SESSION`] (an older document is upgraded as it is read).
    pub schema: String,
    /// Where the session stands.
    pub status: Status,
    /// Why it stopped, when failed or interrupted.
    pub why: Option<String>,
    /// How to go on, when not finished.
    pub resume_with: Option<String>,
    /// The sample.
    pub sample: String,
    /// The instrument.
    pub instrument: InstrumentRecord,
    /// The handshake's `DeviceInfo`, whole.
    pub device: serde_json::Value,
    /// What was asked.
    pub plan: PlanRecord,
    /// Every run, in order.
    pub runs: Vec<Run>,
    /// Lines of `points.jsonl` when this document was written.
    pub readings_recorded: usize,
    /// The case, when given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub case: Option<CaseRecord>,
    /// The rest: `calibration`, `readings`, `fits`, `refinements`, `decisions`, `result`,
    /// `ok`, `flags` once finished.
    #[serde(flatten)]
    pub rest: serde_json::Map<String, serde_json::Value>,
}

/// Something found wrong in a session or sheet folder (by reading it, by `gonio verify`,
/// or by a resume's check), at `file:line` when a line is known.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Finding {
    /// The file (or folder) concerned.
    pub file: PathBuf,
    /// Its 1-based line.
    pub line: Option<usize>,
    /// What is wrong.
    pub message: String,
}

impl Finding {
    fn new(file: &Path, line: Option<usize>, message: impl Into<String>) -> Finding {
        Finding {
            file: file.to_path_buf(),
            line,
            message: message.into(),
        }
    }
}

impl std::error::Error for Finding {}

impl fmt::Display for Finding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(line) => write!(f, "{}:{line}: {}", self.file.display(), self.message),
            None => write!(f, "{}: {}", self.file.display(), self.message),
        }
    }
}

/// A file of lines as a crash can leave it: whole lines, and maybe a last one cut short
/// (no newline at its end).
#[derive(Clone, Debug, Default)]
pub struct LinesFile {
    /// The whole lines (without their newline), with their 1-based line number.
    pub lines: Vec<(usize, String)>,
    /// Bytes up to and with the last newline.
    pub(crate) whole_len: u64,
    /// The last line's bytes when it has no newline.
    pub(crate) cut_tail: Option<Vec<u8>>,
    /// The file exists.
    pub exists: bool,
}

/// Read a file of lines; a missing file is empty. Invalid UTF-8 in a whole line is a problem.
pub fn read_lines(path: &Path) -> Result<LinesFile, Finding> {
    lines_read(path, std::fs::read(path))
}

/// [`read_lines`] of what reading the file `path` gave.
fn lines_read(path: &Path, read: std::io::Result<Vec<u8>>) -> Result<LinesFile, Finding> {
    match read {
        Ok(bytes) => lines_of(path, &bytes),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(LinesFile::default()),
        Err(e) => Err(Finding::new(path, None, format!("cannot read: {e}"))),
    }
}

/// The lines of a file's bytes, as [`read_lines`] reads them (`path` names the file in
/// messages): the reader without the file system, for the fuzz targets (host/fuzz).
pub fn lines_of(path: &Path, bytes: &[u8]) -> Result<LinesFile, Finding> {
    let whole_len = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    let cut_tail = (whole_len < bytes.len()).then(|| bytes[whole_len..].to_vec());
    let mut lines = Vec::new();
    for (k, line) in bytes[..whole_len]
        .split_inclusive(|&b| b == b'\n')
        .enumerate()
    {
        let text = std::str::from_utf8(&line[..line.len() - 1])
            .map_err(|_| Finding::new(path, Some(k + 1), "not UTF-8 text"))?;
        lines.push((k + 1, text.to_string()));
    }
    Ok(LinesFile {
        lines,
        whole_len: whole_len as u64,
        cut_tail,
        exists: true,
    })
}

/// A line of `points.jsonl` that is no reading: readings recorded earlier (by their
/// 0-based position among the file's readings) are superseded, for `why`. The file stays
/// append-only: a reading is never rewritten, a later line marks it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SupersedeMark {
    /// Positions of the readings superseded.
    pub superseded: Vec<usize>,
    /// Why, in words.
    pub why: String,
}

/// The `points.jsonl` line of a mark (with its newline), tagged [`schema::SUPERSEDE`].
pub fn mark_line(mark: &SupersedeMark) -> std::io::Result<String> {
    Ok(serde_json::to_string(&schema::tagged(
        schema::SUPERSEDE,
        serde_json::to_value(mark)?,
    ))? + "\n")
}

/// A line of `points.jsonl`.
enum PointsLine {
    Reading(Box<MeasuredPoint>),
    Mark(SupersedeMark),
}

/// Why a line of `points.jsonl` is neither a reading nor a mark.
#[derive(Debug, thiserror::Error)]
enum PointsLineError {
    /// Not JSON at all.
    #[error("not a reading (not JSON): {0}")]
    NotJson(serde_json::Error),
    /// JSON, but not a reading.
    #[error("not a reading: {0}")]
    NotReading(serde_json::Error),
    /// A reading whose numbers cannot be an instrument's (issue 30 D4: a reading of 1e308
    /// made every resume measure again, then fail).
    #[error("not a reading the instrument can have taken: {0}")]
    Implausible(String),
    /// Tagged as a mark, but not one.
    #[error("not a mark of superseded readings: {0}")]
    NotMark(serde_json::Error),
    /// Tagged with a schema read elsewhere.
    #[error("schema '{0}' is not one this gonio reads here ({POINT}, {SUPERSEDE})", POINT = schema::POINT, SUPERSEDE = schema::SUPERSEDE)]
    OtherSchema(String),
}

/// Parse one line of `points.jsonl`: by its `schema`; a line without one was written
/// before gonio named its documents (a mark then has exactly its two fields, a reading
/// many more).
fn parse_points_line(text: &str) -> Result<PointsLine, PointsLineError> {
    let mut value: serde_json::Value =
        serde_json::from_str(text).map_err(PointsLineError::NotJson)?;
    let found = schema::of(&value).map(str::to_string);
    if let Some(object) = value.as_object_mut() {
        object.remove("schema");
    }
    let reading = |value: serde_json::Value| {
        let point =
            serde_json::from_value::<MeasuredPoint>(value).map_err(PointsLineError::NotReading)?;
        point
            .implausible()
            .map_or(Ok(PointsLine::Reading(Box::new(point))), |why| {
                Err(PointsLineError::Implausible(why))
            })
    };
    let mark = |value: serde_json::Value| {
        serde_json::from_value::<SupersedeMark>(value).map(PointsLine::Mark)
    };
    match found.as_deref() {
        Some(schema::POINT) => reading(value),
        Some(schema::SUPERSEDE) => mark(value).map_err(PointsLineError::NotMark),
        Some(other) => Err(PointsLineError::OtherSchema(other.to_string())),
        None => mark(value.clone()).or_else(|_| reading(value)),
    }
}

/// Parse the whole lines of `points.jsonl`: its readings in order, with the marks of later
/// lines applied (`superseded` set).
pub fn parse_points(path: &Path, file: &LinesFile) -> Result<Vec<MeasuredPoint>, Finding> {
    let mut points: Vec<MeasuredPoint> = Vec::new();
    for (line, text) in &file.lines {
        match parse_points_line(text).map_err(|e| Finding::new(path, Some(*line), e.to_string()))? {
            PointsLine::Mark(mark) => {
                for &k in &mark.superseded {
                    match points.get_mut(k) {
                        Some(point) => point.superseded = true,
                        None => {
                            return Err(Finding::new(
                                path,
                                Some(*line),
                                format!(
                                    "marks reading {k} superseded, but only {} come before it",
                                    points.len()
                                ),
                            ));
                        }
                    }
                }
            }
            PointsLine::Reading(point) => points.push(*point),
        }
    }
    Ok(points)
}

/// The `points.jsonl` line of a reading (with its newline), tagged [`schema::POINT`],
/// checked to read back as the same reading: a record that cannot be read back is no record.
pub(crate) fn point_line(point: &MeasuredPoint) -> std::io::Result<String> {
    let text = serde_json::to_string(&schema::tagged(schema::POINT, serde_json::to_value(point)?))?;
    match parse_points_line(&text) {
        Ok(PointsLine::Reading(back)) if *back == *point => Ok(text + "\n"),
        _ => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "the reading at θi {}°, θr {}° holds a number JSON cannot keep (NaN or infinite): {text}",
                point.theta_i_deg, point.theta_r_deg
            ),
        )),
    }
}

/// The `readings.csv` row of a reading (with its newline), if it was converted and is not
/// superseded (`readings.csv` holds what the result rests on, for `gonio fit`), under the
/// header `header` (with or without the span column). Numbers in Rust's shortest
/// round-trip form: parsing them gives the recorded f64 exactly.
pub fn csv_row(point: &MeasuredPoint, header: &str) -> Option<String> {
    if point.superseded {
        return None;
    }
    let (r, u) = (point.radiance_factor?, point.std?);
    // The current form rounds the angles; a legacy file's rows are as they were written.
    let angle = |deg: f64| {
        if is_legacy_header(header) {
            deg
        } else {
            rounded_angle(deg)
        }
    };
    let (ti, tr) = (angle(point.theta_i_deg), angle(point.theta_r_deg));
    Some(
        if header == READINGS_HEADER_WITH_SPAN || header == LEGACY_READINGS_HEADER_WITH_SPAN {
            format!("{ti},{tr},{r},{u},{}\n", angle(point.theta_r_span_deg))
        } else {
            format!("{ti},{tr},{r},{u}\n")
        },
    )
}

/// `readings.csv` as `points.jsonl` says it must be.
pub fn readings_csv(points: &[MeasuredPoint]) -> String {
    let header = readings_header(points);
    let mut text = format!("{header}\n");
    text.extend(points.iter().filter_map(|p| csv_row(p, header)));
    text
}

/// How `readings.csv` stands against `points.jsonl`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum CsvAgreement {
    /// Exactly the rows `points.jsonl` gives.
    Agrees,
    /// A prefix of them, perhaps with a last row cut short (what a crash between the two
    /// appends, or during the second, leaves): a resume rebuilds it.
    Behind {
        /// Rows missing.
        missing: usize,
        /// The last row was cut short.
        cut: bool,
    },
    /// It still holds rows as they were before readings were superseded or the
    /// calibration changed (what a crash between the record and the rewrite of
    /// `readings.csv` leaves): a resume rebuilds it.
    Stale {
        /// Rows of superseded readings still in it.
        superseded: usize,
    },
    /// Something else: damage.
    Differs(Finding),
}

/// The readings with their conversion by `calibration` (`calibration.json`): a reading's
/// record is its raw reading; its radiance factor follows from the calibration now in the
/// folder, which a gain calibration may have changed since the reading was appended.
pub fn converted(
    points: &[MeasuredPoint],
    calibration: Option<&Calibration>,
) -> Vec<MeasuredPoint> {
    let mut out = points.to_vec();
    if let Some(calibration) = calibration {
        out.iter_mut().for_each(|p| p.convert_with(calibration));
    }
    out
}

/// Compare `readings.csv` with what `points.jsonl` gives (`points` converted with the
/// folder's calibration; `recorded` as appended).
pub(crate) fn csv_agreement(
    path: &Path,
    file: &LinesFile,
    points: &[MeasuredPoint],
    recorded: &[MeasuredPoint],
) -> CsvAgreement {
    let agreement = csv_agreement_with(path, file, points);
    if !matches!(agreement, CsvAgreement::Differs(_)) {
        return agreement;
    }
    // Only stale if the file agrees with the rows as they stood before a mark or before a
    // new calibration (a crash between the record and the rewrite of readings.csv).
    let unmarked = |points: &[MeasuredPoint]| {
        points
            .iter()
            .map(|p| MeasuredPoint {
                superseded: false,
                ..p.clone()
            })
            .collect::<Vec<_>>()
    };
    let superseded = points.iter().filter(|p| p.superseded).count();
    for before in [unmarked(points), recorded.to_vec(), unmarked(recorded)] {
        if !matches!(
            csv_agreement_with(path, file, &before),
            CsvAgreement::Differs(_)
        ) {
            return CsvAgreement::Stale { superseded };
        }
    }
    agreement
}

fn csv_agreement_with(path: &Path, file: &LinesFile, points: &[MeasuredPoint]) -> CsvAgreement {
    let wanted = readings_header(points);
    if !file.exists {
        return CsvAgreement::Behind {
            missing: expected_rows(points, wanted).len(),
            cut: false,
        };
    }
    match csv_header(path, file, points, wanted) {
        Ok(header) => csv_rows_agreement(path, file, &expected_rows(points, header)),
        Err(verdict) => verdict,
    }
}

/// The rows `readings.csv` must hold under `header`, without their newlines.
fn expected_rows(points: &[MeasuredPoint], header: &str) -> Vec<String> {
    points
        .iter()
        .filter_map(|p| csv_row(p, header))
        .map(|r| r.trim_end().to_string())
        .collect()
}

/// The file's header: the one its readings need (`wanted`), or the one without the span
/// column while no reading was taken moving yet (the file is rewritten with the span
/// column when the first bin arrives); else the file's agreement as the header decides it.
fn csv_header(
    path: &Path,
    file: &LinesFile,
    points: &[MeasuredPoint],
    wanted: &'static str,
) -> Result<&'static str, CsvAgreement> {
    // The file's form (current or legacy) decides how its rows are written.
    let form = file.lines.first().and_then(|(_, h)| header_form(h));
    let wanted = match form {
        Some((_, moving)) if wanted == READINGS_HEADER_WITH_SPAN => moving,
        Some((still, _)) => still,
        None => wanted,
    };
    match file.lines.first() {
        Some((_, header)) if header == wanted => Ok(wanted),
        Some((line, header)) if form.is_some_and(|(still, _)| header == still) => {
            // What a crash between the first bin's record and the rewrite leaves: the rows
            // of the readings before it, under the old header; a resume rebuilds the file.
            let first_moving = points
                .iter()
                .position(|p| p.theta_r_span_deg > 0.0)
                .unwrap_or(points.len());
            Err(
                match csv_agreement_with(path, file, &points[..first_moving]) {
                    CsvAgreement::Differs(_) => CsvAgreement::Differs(Finding::new(
                        path,
                        Some(*line),
                        format!(
                            "header is '{header}', without the theta_r_span column the readings taken while moving need"
                        ),
                    )),
                    _ => CsvAgreement::Stale { superseded: 0 },
                },
            )
        }
        Some((line, header)) => Err(CsvAgreement::Differs(Finding::new(
            path,
            Some(*line),
            format!("header is '{header}', not '{wanted}'"),
        ))),
        // Only the header, cut short (or nothing): a crash right after the file was made.
        None => Err(match &file.cut_tail {
            Some(tail)
                if ![
                    READINGS_HEADER,
                    READINGS_HEADER_WITH_SPAN,
                    LEGACY_READINGS_HEADER,
                    LEGACY_READINGS_HEADER_WITH_SPAN,
                ]
                .iter()
                .any(|h| h.as_bytes().starts_with(tail)) =>
            {
                CsvAgreement::Differs(Finding::new(
                    path,
                    Some(1),
                    format!(
                        "'{}' is not the header '{wanted}'",
                        String::from_utf8_lossy(tail)
                    ),
                ))
            }
            tail => CsvAgreement::Behind {
                missing: expected_rows(points, wanted).len(),
                cut: tail.is_some(),
            },
        }),
    }
}

/// The rows after the header against `expected`: the same, or a prefix of them (perhaps
/// with a last row cut short).
fn csv_rows_agreement(path: &Path, file: &LinesFile, expected: &[String]) -> CsvAgreement {
    let rows: Vec<&(usize, String)> = file.lines.iter().skip(1).collect();
    if rows.len() > expected.len() {
        let (line, text) = rows[expected.len()];
        return CsvAgreement::Differs(Finding::new(
            path,
            Some(*line),
            format!("row '{text}' has no reading in {POINTS}"),
        ));
    }
    for ((line, text), want) in rows.iter().map(|r| (&r.0, &r.1)).zip(expected) {
        if !same_row(text, want) {
            return CsvAgreement::Differs(Finding::new(
                path,
                Some(*line),
                format!("row '{text}' differs from its reading in {POINTS} ('{want}')"),
            ));
        }
    }
    let missing = expected.len() - rows.len();
    if let Some(tail) = &file.cut_tail {
        // A cut row must be the start of the next expected one.
        let next = expected
            .get(rows.len())
            .map(String::as_bytes)
            .unwrap_or_default();
        if !next.starts_with(tail) {
            let line = rows.last().map_or(2, |r| r.0 + 1);
            return CsvAgreement::Differs(Finding::new(
                path,
                Some(line),
                format!(
                    "last line '{}' is no reading of {POINTS}",
                    String::from_utf8_lossy(tail)
                ),
            ));
        }
        return CsvAgreement::Behind { missing, cut: true };
    }
    if missing == 0 {
        CsvAgreement::Agrees
    } else {
        CsvAgreement::Behind {
            missing,
            cut: false,
        }
    }
}

/// Two CSV rows of the same numbers (compared as the f64 they parse to).
fn same_row(row: &str, want: &str) -> bool {
    let parse = |s: &str| {
        s.split(',')
            .map(|f| f.trim().parse::<f64>().ok())
            .collect::<Option<Vec<f64>>>()
    };
    match (parse(row), parse(want)) {
        (Some(a), Some(b)) => {
            a.len() == b.len() && a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits())
        }
        _ => false,
    }
}

/// Read `session.json`; `None` when there is none. A document of an older version
/// ([`crate::schema::SESSION_V1`]) is upgraded in memory (the file stays as it is: its
/// manifest vouches for its bytes).
pub fn read_session(dir: &Path) -> Result<Option<SessionDoc>, Finding> {
    session_read(dir, std::fs::read(dir.join(SESSION)))
}

/// [`read_session`] of what reading `dir`'s `session.json` gave.
fn session_read(dir: &Path, read: std::io::Result<Vec<u8>>) -> Result<Option<SessionDoc>, Finding> {
    let path = dir.join(SESSION);
    match text_of(read) {
        Ok(text) => parse_session(&path, &text).map(Some),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(Finding::new(&path, None, format!("cannot read: {e}"))),
    }
}

/// The text of a `session.json` as [`read_session`] reads it (`path` names the file in
/// messages): the reader without the file system, for the fuzz targets (host/fuzz).
pub fn parse_session(path: &Path, text: &str) -> Result<SessionDoc, Finding> {
    let mut value: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| Finding::new(path, Some(e.line()), format!("not JSON: {e}")))?;
    let schema = schema::check(
        &value,
        &[schema::SESSION, schema::SESSION_V2, schema::SESSION_V1],
        None,
    )
    .map_err(|m| {
        Finding::new(
            path,
            None,
            format!("{m}: not a session folder of this gonio"),
        )
    })?;
    if schema == schema::SESSION_V1 {
        upgrade_session_v1(&mut value);
    }
    serde_json::from_value(value)
        .map_err(|e| Finding::new(path, None, format!("not a session document: {e}")))
}

/// [`read_session`] of a folder that must hold a session.
pub(crate) fn require_session(dir: &Path) -> Result<SessionDoc, Finding> {
    read_session(dir)?
        .ok_or_else(|| Finding::new(&dir.join(SESSION), None, "missing: not a session folder"))
}

/// [`require_session`] of a session that must be finished (to report, re-analyse or
/// weigh its result).
pub(crate) fn require_finished(dir: &Path) -> Result<SessionDoc, Finding> {
    let doc = require_session(dir)?;
    if doc.status != Status::Finished {
        return Err(Finding::new(
            &dir.join(SESSION),
            None,
            format!(
                "the session is not finished (status {}): it has no result yet; its readings so far are in {}",
                doc.status,
                dir.join(READINGS).display()
            ),
        ));
    }
    Ok(doc)
}

/// A `gonio-session/1` document as `gonio-session/2`: `format` was `schema`; σ's key in
/// the analyses' `ci95`, `model`, `not_identified` and `active_bounds` was `sigma` (now
/// `sigma_deg` everywhere, as its value's key); the result's `refinements` were bare numbers
/// (δ or geometries added), now the objects the document's own `refinements` holds.
fn upgrade_session_v1(doc: &mut serde_json::Value) {
    use serde_json::Value;
    let Some(object) = doc.as_object_mut() else {
        return;
    };
    object.remove("format");
    object.insert("schema".into(), Value::from(schema::SESSION));
    let sigma = crate::analysis::model::PARAM_NAMES[crate::analysis::model::SIGMA];
    let upgrade_analysis = |analysis: &mut Value| {
        if let Some(ci) = analysis.get_mut("ci95").and_then(Value::as_object_mut)
            && let Some(v) = ci.remove("sigma")
        {
            ci.insert(sigma.into(), v);
        }
        if let Some(names) = analysis.get_mut("model").and_then(Value::as_array_mut) {
            names
                .iter_mut()
                .filter(|n| n.as_str() == Some("sigma"))
                .for_each(|n| *n = Value::from(sigma));
        }
        for key in ["not_identified", "active_bounds"] {
            if let Some(items) = analysis.get_mut(key).and_then(Value::as_array_mut) {
                items
                    .iter_mut()
                    .filter_map(|i| i.get_mut("param"))
                    .filter(|p| p.as_str() == Some("sigma"))
                    .for_each(|p| *p = Value::from(sigma));
            }
        }
    };
    let refinements = object.get("refinements").cloned();
    if let Some(result) = object.get_mut("result") {
        upgrade_analysis(result);
        if let (Some(r), Some(refinements)) = (result.as_object_mut(), refinements) {
            r.insert("refinements".into(), refinements);
            r.insert("schema".into(), Value::from(schema::SPOT_RESULT));
        }
    }
    if let Some(fits) = object.get_mut("fits").and_then(Value::as_array_mut) {
        for report in fits.iter_mut().filter_map(|f| f.get_mut("report")) {
            upgrade_analysis(report);
            if let Some(r) = report.as_object_mut() {
                r.insert("schema".into(), Value::from(schema::ANALYSIS));
            }
        }
    }
}

/// Read `calibration.json`; `None` when there is none.
pub(crate) fn read_calibration(dir: &Path) -> Result<Option<Calibration>, Finding> {
    calibration_read(dir, std::fs::read(dir.join(CALIBRATION)))
}

/// [`read_calibration`] of what reading `dir`'s `calibration.json` gave.
fn calibration_read(
    dir: &Path,
    read: std::io::Result<Vec<u8>>,
) -> Result<Option<Calibration>, Finding> {
    let path = dir.join(CALIBRATION);
    match text_of(read) {
        Ok(text) => parse_calibration(&path, &text).map(Some),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(Finding::new(&path, None, format!("cannot read: {e}"))),
    }
}

/// A file's bytes as its text, refused as [`std::fs::read_to_string`] refuses invalid
/// UTF-8 (with its words: the messages are the same whichever read the file).
fn text_of(read: std::io::Result<Vec<u8>>) -> std::io::Result<String> {
    String::from_utf8(read?).map_err(|_| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "stream did not contain valid UTF-8",
        )
    })
}

/// The text of a `calibration.json` as [`read_calibration`] reads it (`path` names the
/// file in messages): the reader without the file system, for the fuzz targets (host/fuzz).
pub fn parse_calibration(path: &Path, text: &str) -> Result<Calibration, Finding> {
    let calibration =
        Calibration::from_json(text).map_err(|e| Finding::new(path, e.line(), e.to_string()))?;
    // Values that cannot be a calibration are refused here, at their line: a resume would
    // convert nothing with them and measure the same readings again for ever (issue 30 D4).
    calibration
        .validate_field()
        .map_err(|(key, e)| Finding::new(path, line_of_key(text, key), format!("{key}: {e}")))?;
    Ok(calibration)
}

/// The 1-based line of the first `"key":` in a JSON text.
fn line_of_key(text: &str, key: &str) -> Option<usize> {
    let quoted = format!("\"{key}\"");
    text.lines()
        .position(|l| l.contains(&quoted))
        .map(|k| k + 1)
}

/// The names in a folder (files and folders), sorted.
pub fn entries(dir: &Path) -> std::io::Result<Vec<String>> {
    let mut names: Vec<String> = std::fs::read_dir(dir)?
        .map(|e| e.map(|e| e.file_name().to_string_lossy().into_owned()))
        .collect::<Result<_, _>>()?;
    names.sort();
    Ok(names)
}

/// Refuse a folder to write into that holds a symbolic link: gonio never leaves one, and a
/// write through it (an appended `session.log`, a replaced file, a sheet's spot folder)
/// could land anywhere outside the folder (issue 30). The store refuses to open a link for
/// writing as well ([`store::open_in_folder`]); this says so before anything
/// is changed.
pub(crate) fn refuse_links(dir: &Path) -> Result<(), Finding> {
    let cannot_list = |e: std::io::Error| Finding::new(dir, None, format!("cannot list: {e}"));
    for name in entries(dir).map_err(cannot_list)? {
        let path = dir.join(&name);
        if std::fs::symlink_metadata(&path).is_ok_and(|m| m.file_type().is_symlink()) {
            return Err(Finding::new(
                &path,
                None,
                "a symbolic link: gonio writes nothing through a link inside a session folder (it could lead outside the folder); put the file itself in its place, or remove the link",
            ));
        }
    }
    Ok(())
}

/// Temporary files a killed `gonio` left in `dir`.
pub(crate) fn temp_files(dir: &Path) -> std::io::Result<Vec<String>> {
    Ok(entries(dir)?
        .into_iter()
        .filter(|n| is_temp_name(n))
        .collect())
}

/// The decisions of run `run` in `session.log` (a killed run's record of what it did).
pub(crate) fn logged_decisions(log: &LinesFile, run: u32) -> Vec<String> {
    let tag = format!(" [run {run}] ");
    log.lines
        .iter()
        .filter_map(|(_, l)| l.split_once(&tag).map(|(_, text)| text.to_string()))
        .collect()
}

/// The bytes of each file [`inspect`] read, by name, as it read them: the manifest is
/// checked on these ([`manifest::check_read`]), so the files parsed are the files hashed
/// and each is read once.
pub(crate) type FilesRead = std::collections::BTreeMap<String, Vec<u8>>;

/// Everything a folder holds, read and cross-checked without changing it.
pub(crate) struct Inspection {
    /// The folder.
    pub dir: PathBuf,
    /// `session.json`.
    pub session: Option<SessionDoc>,
    /// `points.jsonl` as read.
    pub(crate) points_file: LinesFile,
    /// Its readings.
    pub points: Vec<MeasuredPoint>,
    /// `readings.csv` against them.
    pub csv: CsvAgreement,
    /// `session.log` as read.
    pub log: LinesFile,
    /// `calibration.json`.
    pub calibration: Option<Calibration>,
    /// Temporary files left by a kill.
    pub(crate) temp_files: Vec<String>,
    /// The bytes of the files read.
    pub(crate) read: FilesRead,
    /// Damage that a resume does not repair, found by cross-checking the files: anything
    /// but a cut-off last line, `readings.csv` behind `points.jsonl`, temporary files, and
    /// a run that ended without closing.
    pub damage: Vec<Finding>,
}

/// Read and cross-check a session folder. A file that cannot be read as what it must be
/// is an error at `file:line`; disagreements between the files are in
/// [`Inspection::damage`].
pub(crate) fn inspect(dir: &Path) -> Result<Inspection, Finding> {
    if !dir.is_dir() {
        return Err(Finding::new(
            dir,
            None,
            if dir.exists() {
                "not a folder"
            } else {
                "no such folder"
            },
        ));
    }
    let mut read = FilesRead::new();
    let mut keep = |name: &str| {
        let bytes = std::fs::read(dir.join(name))?;
        read.insert(name.to_string(), bytes.clone());
        Ok(bytes)
    };
    let session = session_read(dir, keep(SESSION))?;
    let points_path = dir.join(POINTS);
    let points_file = lines_read(&points_path, keep(POINTS))?;
    let recorded = parse_points(&points_path, &points_file)?;
    let csv_path = dir.join(READINGS);
    let csv_file = lines_read(&csv_path, keep(READINGS))?;
    let log = lines_read(&dir.join(LOG), keep(LOG))?;
    let calibration = calibration_read(dir, keep(CALIBRATION))?;
    let points = converted(&recorded, calibration.as_ref());
    let temp_files =
        temp_files(dir).map_err(|e| Finding::new(dir, None, format!("cannot list: {e}")))?;
    let session_path = dir.join(SESSION);
    let mut damage = Vec::new();
    match &session {
        None if points_file.exists || calibration.is_some() => {
            damage.push(Finding::new(&session_path, None, "missing, but the folder holds readings or a calibration: not a folder gonio left, or damaged"));
        }
        Some(doc) => {
            if points.len() < doc.readings_recorded {
                damage.push(Finding::new(
                    &points_path,
                    Some(points_file.lines.len() + 1),
                    format!(
                        "{} readings, but {SESSION} says {} were recorded: readings are missing",
                        points.len(),
                        doc.readings_recorded
                    ),
                ));
            }
            if points.iter().any(|p| p.radiance_factor.is_some()) && calibration.is_none() {
                damage.push(Finding::new(
                    &dir.join(CALIBRATION),
                    None,
                    "missing, but readings were converted with it",
                ));
            }
            if doc.runs.is_empty() {
                damage.push(Finding::new(&session_path, None, "no runs recorded"));
            }
        }
        None => {}
    }
    let csv = csv_agreement(&csv_path, &csv_file, &points, &recorded);
    if let CsvAgreement::Differs(problem) = &csv {
        damage.push(problem.clone());
    }
    Ok(Inspection {
        dir: dir.to_path_buf(),
        session,
        points_file,
        points,
        csv,
        log,
        calibration,
        temp_files,
        read,
        damage,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(theta_r_deg: f64, theta_r_span_deg: f64, index: u16) -> MeasuredPoint {
        MeasuredPoint {
            theta_i_deg: 60.0,
            theta_r_deg,
            theta_r_span_deg,
            radiance_factor: Some(1.0 + theta_r_deg / 100.0),
            std: Some(0.01),
            reading: protocol::Reading {
                mean_counts: 1000.0,
                std_counts: 5.0,
                samples: 100,
                range: 0,
                integration_ms: 100,
                saturated: false,
            },
            schedule_id: 1,
            index,
            device_time_us: u64::from(index) * 1000,
            note: None,
            superseded: false,
            unusable: None,
        }
    }

    /// readings.csv gains its span column with the first bin; a file a crash left under
    /// the old header, with the rows of the readings before the bin, is stale (a resume
    /// rebuilds it); one whose rows are not those readings is damage.
    #[test]
    fn readings_csv_takes_the_span_column_with_the_first_bin() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(READINGS);
        let still = vec![point(50.0, 0.0, 0), point(55.0, 0.0, 1)];
        let mut moving = still.clone();
        moving.push(point(59.5, 0.25, 2));
        assert!(readings_csv(&still).starts_with(&format!("{READINGS_HEADER}\n")));
        let text = readings_csv(&moving);
        assert!(
            text.starts_with(&format!("{READINGS_HEADER_WITH_SPAN}\n"))
                && text.contains("55,1.55,0.01,0\n")
                && text.ends_with(",0.25\n"),
            "{text}"
        );
        let agree = |content: &str| {
            std::fs::write(&path, content).unwrap();
            csv_agreement(&path, &read_lines(&path).unwrap(), &moving, &moving)
        };
        assert_eq!(agree(&text), CsvAgreement::Agrees);
        assert_eq!(
            agree(&readings_csv(&still)),
            CsvAgreement::Stale { superseded: 0 }
        );
        assert_eq!(
            agree(&readings_csv(&still[..1])),
            CsvAgreement::Stale { superseded: 0 }
        );
        assert!(matches!(
            agree(&readings_csv(&still).replace("1.55", "9.55")),
            CsvAgreement::Differs(_)
        ));
    }

    #[test]
    fn lines_and_a_cut_tail() {
        let dir = std::env::temp_dir().join(format!("gonio-folder-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("x");
        std::fs::write(&path, "a\nb\nc").unwrap();
        let file = read_lines(&path).unwrap();
        assert_eq!(file.lines, [(1, "a".to_string()), (2, "b".to_string())]);
        assert_eq!(
            (file.whole_len, file.cut_tail.as_deref()),
            (4, Some(&b"c"[..]))
        );
        std::fs::write(&path, "a\n").unwrap();
        let file = read_lines(&path).unwrap();
        assert_eq!((file.lines.len(), file.cut_tail), (1, None));
        assert!(!read_lines(&dir.join("none")).unwrap().exists);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
