//! A finished session folder analysed again from its own record (`gonio fit DIR`): the
//! readings of `points.jsonl` (marks applied) converted with `calibration.json`, the
//! analysis settings and time the session recorded in its result, through the session's
//! own analysis ([`crate::session::analyse_points`]), and compared with the result the
//! session reported.
use crate::analysis::flags::Flag;
use crate::analysis::result::{Report, to_json};
use crate::instrument::profile::ProfileInUse;
use crate::output::folder::{self, Finding, SESSION};
use crate::session::{AnalysisSettings, analyse_points};
use serde::Deserialize;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// Why a folder cannot be analysed again.
#[derive(Debug, thiserror::Error)]
pub enum ReanalysisError {
    /// A file of the folder cannot be read as what it must be (or the session is not
    /// finished).
    #[error("{0}")]
    Folder(#[from] Finding),
    /// A finished `session.json` without a result.
    #[error("{}: no result", .0.display())]
    NoResult(PathBuf),
    /// The analysis itself failed.
    #[error("{0}")]
    Analysis(crate::session::PointsAnalysisError),
}

/// The session folders of `path`: a sheet's spots, or the session itself.
pub fn session_folders(path: &Path) -> Result<Vec<PathBuf>, Finding> {
    if folder::is_sheet_folder(path) {
        let doc = crate::output::folder::sheet::read_doc(path)?;
        return Ok(doc.spots.iter().map(|s| path.join(&s.folder)).collect());
    }
    Ok(vec![path.to_path_buf()])
}

/// The `result` of a `session.json` as written: the comparison goes key by key over what
/// the session wrote (a key an older session did not write differs, whatever the typed
/// document would read it as).
#[derive(Deserialize)]
struct RecordedResult {
    result: Option<Value>,
}

/// A re-analysis and how it compares with the session's own result.
pub struct Reanalysis {
    /// The analysis made again.
    pub report: Report,
    /// Keys of the result whose value differs from the session's (empty: the same result).
    pub differences: Vec<String>,
}

/// Analyse the finished session folder `dir` again from its record.
pub fn reanalyse(dir: &Path) -> Result<Reanalysis, ReanalysisError> {
    reanalyse_with(dir, None)
}

/// [`reanalyse`], with `profile` (when given) in place of the instrument profile the
/// session recorded (or of none): the analysis as it would be on the instrument as that
/// profile measured it.
pub fn reanalyse_with(
    dir: &Path,
    profile: Option<&ProfileInUse>,
) -> Result<Reanalysis, ReanalysisError> {
    let doc = folder::require_finished(dir)?;
    let recorded = RecordedResult::deserialize(&doc.rest)
        .ok()
        .and_then(|r| r.result)
        .ok_or_else(|| ReanalysisError::NoResult(dir.join(SESSION)))?;
    let outcome = doc.outcome();
    let document = outcome.result();
    let calibration = folder::read_calibration(dir)?;
    let mut points = crate::output::folder::record::read_points(dir)?;
    if let Some(c) = &calibration {
        for p in &mut points {
            p.convert_with(c);
        }
    }
    // Sessions before these were recorded: the plan's acceptance, the default arm zero, the
    // session's end as the time of the analysis (the result then differs in the drift's share).
    let settings = document
        .and_then(|d| d.analysis_settings.clone())
        .unwrap_or(AnalysisSettings {
            acceptance_deg: doc.plan.acceptance_deg,
            arm_zero_uncertainty_deg: crate::analysis::fit::DEFAULT_ARM_ZERO_UNCERTAINTY_DEG,
            instrument_profile: None,
            model_extensions: false,
        });
    let recorded_profile = settings.instrument_profile.is_some();
    let mut settings = settings;
    if let Some(profile) = profile {
        settings.instrument_profile = Some(profile.clone());
    }
    let ended = doc
        .runs
        .last()
        .and_then(|r| r.ended.as_deref())
        .and_then(|t| chrono::DateTime::parse_from_rfc3339(t).ok())
        .map_or(0, |t| t.timestamp().max(0) as u64);
    let now = document.and_then(|d| d.analysed_unix_s).unwrap_or(ended);
    let mut report = analyse_points(&doc.sample, &points, calibration.as_ref(), &settings, now)
        .map_err(ReanalysisError::Analysis)?;
    report.file = dir.display().to_string();
    let again = to_json(&report);
    // The session's `flags` and `ok` are the session's (lost steps, a resume, …) over the
    // analysis's own: those must be among them.
    // Its `schema` is the analysis's, the recorded one the spot result's.
    let session_level = ["schema", "file", "flags", "ok"];
    let mut differences: Vec<String> = again
        .as_object()
        .map(|o| {
            o.iter()
                .filter(|(k, v)| {
                    // A key the recorded document predates reads as null (as
                    // `model_extension` of a folder analysed before extensions).
                    !session_level.contains(&k.as_str())
                        && recorded.get(k.as_str()).unwrap_or(&serde_json::Value::Null) != *v
                })
                .map(|(k, _)| k.clone())
                .collect()
        })
        .unwrap_or_default();
    let recorded_flags = document
        .map(|d| d.analysis.flags.as_slice())
        .unwrap_or_default();
    // A session recorded before instrument profiles had none: the flag that says so now
    // is no difference in its analysis.
    let new_flag = |f: &&Flag| {
        !recorded_flags.contains(f) && !(**f == Flag::InstrumentDeclared && !recorded_profile)
    };
    if report.flags.iter().any(|f| new_flag(&f)) {
        differences.push("flags".to_string());
    }
    Ok(Reanalysis {
        report,
        differences,
    })
}
