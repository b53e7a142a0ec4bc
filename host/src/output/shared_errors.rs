//! `readings.shared-errors.json` (schema `gonio-shared-errors/1`): what a session's
//! analysis weighs `readings.csv` with besides each reading's own noise, so that the
//! folder's data alone re-analyse to the session's result (`gonio fit readings.csv` finds
//! it beside the CSV: `<stem>.shared-errors.json`).
//!
//! A reading's own noise is independent from reading to reading; the calibration's errors
//! are not: the white tile's certificate, the white read at each θi, the darks, the range
//! gain ratios and the lamp's drift each move many readings together, and the arm zero
//! moves every θr. A fit that weighs only the readings' own noise takes those shared
//! errors for lack of fit (a clean session's `readings.csv` alone gave χ²/ν ≈ 3 and exit
//! 3). The file holds, for the readings the result rests on (by their line in the CSV):
//! the standard uncertainty the analysis weighed each by (a sweep's bins scaled to their
//! own scatter), every shared error as its effect on each reading per standard deviation,
//! the analysis's settings (acceptance, arm zero, the instrument profile, the model's
//! extensions) and the sample's name. The SHA-256 of the CSV it goes with ties the two:
//! a CSV edited since is refused rather than analysed with errors that are not its own.
use crate::analysis::dataset::DataSet;
use crate::analysis::fit::SharedError;
use crate::analysis::result::Report;
use crate::instrument::calibration::Calibration;
use crate::instrument::profile::ProfileInUse;
use crate::output::folder::{self, READINGS};
use crate::session::{AnalysisSettings, MeasuredPoint, PointsAnalysisError};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The file beside `readings.csv`.
pub(crate) const SHARED_ERRORS: &str = "readings.shared-errors.json";
/// What names a CSV file's shared-errors file: `<stem>` + this.
const SUFFIX: &str = ".shared-errors.json";

/// The shared-errors file that goes with the CSV file `csv`: `<stem>.shared-errors.json`
/// in its folder.
pub fn sidecar_path(csv: &Path) -> PathBuf {
    let stem = csv
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    csv.with_file_name(format!("{stem}{SUFFIX}"))
}

/// One reading the result rests on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ReadingEntry {
    /// Its 1-based line in the CSV.
    line: usize,
    /// The standard uncertainty the analysis weighed it by (the CSV's `std`, or a sweep's
    /// bin's scaled to the bins' own scatter); null: none stated.
    std: Option<f64>,
}

/// One shared error: reading k is off by `(sensitivity[k] + additive[k]) · ε`, one
/// ε ~ N(0, 1) for all of them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SharedEntry {
    name: String,
    sensitivity: Vec<f64>,
    #[serde(default)]
    additive: Vec<f64>,
}

/// The document.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Document {
    schema: String,
    /// The sample, as the session named it.
    sample: String,
    /// The CSV file it goes with (its name in the folder) and that file's SHA-256.
    readings_file: String,
    readings_sha256: String,
    /// When the session's analysis was made (the lamp drift's share is as of it).
    analysed_unix_s: u64,
    analysis_settings: AnalysisSettings,
    /// The variance of the log of the bins' noise scale (0: none scaled).
    noise_scale_log_variance: f64,
    readings: Vec<ReadingEntry>,
    shared_errors: Vec<SharedEntry>,
}

/// The shared-errors file of a session's readings: its bytes, written beside
/// `readings.csv` (whose text is `readings_csv`) by a finished session.
pub(crate) fn document_bytes(
    sample: &str,
    points: &[MeasuredPoint],
    calibration: &Calibration,
    settings: &AnalysisSettings,
    analysed_unix_s: u64,
    readings_csv: &[u8],
) -> std::io::Result<Vec<u8>> {
    let inputs = crate::session::analysis_inputs(points, Some(calibration), analysed_unix_s)
        .map_err(|e| std::io::Error::other(format!("the shared errors: {e}")))?;
    // The CSV's line of each point that has a row there.
    let header = folder::readings_header(points);
    let mut line_of = vec![None; points.len()];
    let mut line = 1;
    for (k, p) in points.iter().enumerate() {
        if folder::csv_row(p, header).is_some() {
            line += 1;
            line_of[k] = Some(line);
        }
    }
    let readings = inputs
        .indices
        .iter()
        .zip(&inputs.observations)
        .map(|(&k, o)| {
            let line = line_of.get(k).copied().flatten().ok_or_else(|| {
                std::io::Error::other(format!(
                    "the reading at θi {}°, θr {}° the result rests on has no row in {READINGS}",
                    o.theta_i_deg, o.theta_r_deg
                ))
            })?;
            Ok(ReadingEntry { line, std: o.std })
        })
        .collect::<std::io::Result<Vec<_>>>()?;
    let doc = Document {
        schema: crate::schema::SHARED_ERRORS.to_string(),
        sample: sample.to_string(),
        readings_file: READINGS.to_string(),
        readings_sha256: crate::output::folder::manifest::sha256_hex(readings_csv),
        analysed_unix_s,
        analysis_settings: settings.clone(),
        noise_scale_log_variance: inputs.noise_scale_log_variance,
        readings,
        shared_errors: inputs
            .shared
            .into_iter()
            .map(|s| SharedEntry {
                name: s.name,
                sensitivity: s.sensitivity,
                additive: s.additive,
            })
            .collect(),
    };
    folder::json_bytes(&doc)
}

/// Why a CSV file cannot be analysed with its shared-errors file.
#[derive(Debug, thiserror::Error)]
pub enum SharedErrorsError {
    /// The file cannot be read or is not the document.
    #[error("{}: {why}", .path.display())]
    Unreadable {
        /// The shared-errors file.
        path: PathBuf,
        /// What is wrong.
        why: String,
    },
    /// The analysis failed.
    #[error("{0}")]
    Analysis(PointsAnalysisError),
}

/// A shared-errors file, read and checked against the CSV it goes with.
#[derive(Clone, Debug)]
pub struct SharedErrorsFile {
    path: PathBuf,
    doc: Document,
}

impl SharedErrorsFile {
    /// The sample's name the session gave.
    pub fn sample(&self) -> &str {
        &self.doc.sample
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// The shared-errors file beside `csv`, if there is one, read and checked against the
/// CSV's bytes `csv_bytes`.
pub fn find(csv: &Path, csv_bytes: &[u8]) -> Result<Option<SharedErrorsFile>, SharedErrorsError> {
    let path = sidecar_path(csv);
    let unreadable = |why: String| SharedErrorsError::Unreadable {
        path: path.clone(),
        why,
    };
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(unreadable(format!("cannot read: {e}"))),
    };
    let value: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| unreadable(format!("line {}: not JSON: {e}", e.line())))?;
    crate::schema::check(&value, &[crate::schema::SHARED_ERRORS], None)
        .map_err(|e| unreadable(e.to_string()))?;
    let doc = Document::deserialize(&value).map_err(|e| unreadable(e.to_string()))?;
    let sha = crate::output::folder::manifest::sha256_hex(csv_bytes);
    if sha != doc.readings_sha256 {
        return Err(unreadable(format!(
            "written for another {} (SHA-256 {}, this file's is {sha}): the CSV was edited or replaced since; remove the shared-errors file to analyse the CSV on its own readings' noise",
            doc.readings_file, doc.readings_sha256
        )));
    }
    let n = doc.readings.len();
    if n == 0 {
        return Err(unreadable("no readings".into()));
    }
    for s in &doc.shared_errors {
        let lengths_fit =
            s.sensitivity.len() == n && (s.additive.is_empty() || s.additive.len() == n);
        if !lengths_fit {
            return Err(unreadable(format!(
                "shared error '{}' has {} sensitivities and {} additive terms for {n} readings",
                crate::text::shown(&s.name),
                s.sensitivity.len(),
                s.additive.len()
            )));
        }
        if s.sensitivity
            .iter()
            .chain(&s.additive)
            .any(|x| !x.is_finite())
        {
            return Err(unreadable(format!(
                "shared error '{}' holds a number that is not finite",
                crate::text::shown(&s.name)
            )));
        }
    }
    if !(doc.noise_scale_log_variance.is_finite() && doc.noise_scale_log_variance >= 0.0) {
        return Err(unreadable(format!(
            "noise_scale_log_variance {} is not a variance",
            doc.noise_scale_log_variance
        )));
    }
    Ok(Some(SharedErrorsFile { path, doc }))
}

/// The session's analysis of the CSV data set `set` (read from `source`) with its
/// shared-errors file: the readings it names, weighed as it says, with its shared errors
/// and settings (`profile`, when given, in place of the instrument profile it recorded).
pub fn analyse(
    source: &str,
    set: &DataSet,
    sidecar: &SharedErrorsFile,
    profile: Option<&ProfileInUse>,
) -> Result<Report, SharedErrorsError> {
    let doc = &sidecar.doc;
    let unreadable = |why: String| SharedErrorsError::Unreadable {
        path: sidecar.path.clone(),
        why,
    };
    let mut observations = Vec::with_capacity(doc.readings.len());
    let mut lines = Vec::with_capacity(doc.readings.len());
    for (k, entry) in doc.readings.iter().enumerate() {
        let at = set.lines.binary_search(&entry.line).map_err(|_| {
            unreadable(format!(
                "reading {} names line {} of {source}, which holds no reading of sample '{}'",
                k + 1,
                entry.line,
                crate::text::shown(&set.sample)
            ))
        })?;
        let mut o = set.observations[at];
        if let Some(std) = entry.std {
            crate::analysis::dataset::check_std(std)
                .ok()
                .filter(|s| *s > 0.0)
                .ok_or_else(|| {
                    unreadable(format!("reading {}: std {std} cannot be weighed", k + 1))
                })?;
            o.std = Some(std);
        }
        observations.push(o);
        lines.push(entry.line);
    }
    let shared: Vec<SharedError> = doc
        .shared_errors
        .iter()
        .map(|s| SharedError {
            name: s.name.clone(),
            sensitivity: s.sensitivity.clone(),
            additive: s.additive.clone(),
        })
        .collect();
    let mut settings = doc.analysis_settings.clone();
    if let Some(profile) = profile {
        settings.instrument_profile = Some(profile.clone());
    }
    crate::session::analyse_inputs(
        source,
        &doc.sample,
        observations,
        &lines,
        &shared,
        doc.noise_scale_log_variance,
        &settings,
    )
    .map_err(SharedErrorsError::Analysis)
}
