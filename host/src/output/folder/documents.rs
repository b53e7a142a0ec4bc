//! The typed parts of a finished `session.json` beyond its head ([`SessionDoc`]): the
//! spot's result ([`SpotResultDocument`], written by the measurement and read back by the
//! report, the catalogue, the re-analysis and the sheet), the rest of what the session
//! writes when it finishes ([`FinishedSession`]), and that read back ([`SessionOutcome`]).
//! `docs/FORMATS.md` describes the keys.
//!
//! Like [`crate::analysis::result::ResultDocument`], each is written through
//! [`serde_json::Value`], whose keys serde_json keeps sorted: the bytes do not depend on
//! the order of the fields here (kept alphabetical, as the JSON reads).
use crate::analysis::flags::Flag;
use crate::analysis::result::ResultDocument;
use crate::instrument::calibration::Calibration;
use crate::output::folder::SessionDoc;
use crate::session::{AnalysisSettings, FitStep, MeasuredPoint, Recoveries, Refinement, StepCheck};
use serde::{Deserialize, Deserializer, Serialize};

/// The result of one spot (`gonio-spot-result/1`): `result` of `session.json` and the
/// `--json` of `gonio measure` of one spot, the analysis and what the session adds to it.
/// Fields that sessions of older versions did not write read as `None`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SpotResultDocument {
    /// The analysis; its `flags` and `ok` are the session's, its `schema` this document's.
    #[serde(flatten)]
    pub(crate) analysis: ResultDocument,
    /// When the final analysis was made, Unix seconds (a re-analysis makes it as of then).
    pub(crate) analysed_unix_s: Option<u64>,
    /// What the final analysis was made with besides the readings and the calibration.
    pub(crate) analysis_settings: Option<AnalysisSettings>,
    /// Covariance of (σ [deg], ρs, ρd, η) (`null`: not finite).
    pub(crate) covariance: Option<[[Option<f64>; 4]; 4]>,
    /// Device time measuring, seconds.
    pub device_seconds: Option<f64>,
    /// Geometries the result rests on.
    pub geometries: Option<u64>,
    /// Without an instrument profile: σ, ρs, ρd and the class through the bound on the
    /// unmeasured response (their honest range; the intervals hold for the declared one).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub instrument_bound: Option<crate::session::InstrumentBound>,
    /// Specular gloss at the gloss meters' geometries the arms reach, from the fitted
    /// model through each standard's apertures (only with an instrument profile in force).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gloss: Option<Vec<GlossValue>>,
    /// Every refinement taken.
    pub(crate) refinements: Vec<Refinement>,
    /// The session folder.
    pub(crate) session_dir: Option<String>,
    /// Device time of homing and calibration, seconds.
    pub setup_seconds: Option<f64>,
    /// White drift at the end, fraction (`null`: not checked).
    pub(crate) white_drift: Option<f64>,
    /// The drift exceeded its limit.
    pub(crate) white_drift_exceeded: bool,
}

/// Specular gloss at one gloss meter geometry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GlossValue {
    /// The standard and geometry, e.g. "ISO 2813 60°".
    pub geometry: String,
    /// Its angle, degrees.
    pub angle_deg: f64,
    /// Gloss units (100: the standard's primary black glass).
    pub gloss_units: f64,
    /// Standard uncertainty from the fit's covariance, gloss units.
    pub u_gloss_units: f64,
}

/// The gloss of fitted parameters `params` (covariance in the fit's order) at every gloss
/// geometry whose receptor the arms reach (`max_theta_deg`).
pub fn gloss_values(
    params: &crate::analysis::model::Params,
    covariance: &[[f64; 4]; 4],
    max_theta_deg: f64,
) -> Vec<GlossValue> {
    use crate::analysis::gloss;
    gloss::GLOSS_GEOMETRIES
        .iter()
        .filter(|g| gloss::arms_reach(g, max_theta_deg))
        .map(|g| {
            let (value, u) = gloss::gloss_interval(params, covariance, g);
            GlossValue {
                geometry: format!("{} {}", g.standard, g.name),
                angle_deg: g.angle_deg,
                gloss_units: value,
                u_gloss_units: u,
            }
        })
        .filter(|v| v.gloss_units.is_finite() && v.u_gloss_units.is_finite())
        .collect()
}

impl SpotResultDocument {
    /// The 95 % interval of the parameter named `name` ([`crate::analysis::model::PARAM_NAMES`]).
    pub fn interval(&self, name: &str) -> Option<[Option<f64>; 2]> {
        self.analysis.ci95.of(name)
    }

    /// The share of the parameters' uncertainty region in the class.
    pub fn class_confidence(&self) -> Option<f64> {
        self.analysis.class_confidence
    }

    /// Normalised mean absolute error of the fit (NaN when not finite).
    pub fn nmae(&self) -> f64 {
        self.analysis.nmae
    }

    /// The class, when decided.
    pub(crate) fn class(&self) -> Option<&str> {
        self.analysis.class.as_deref()
    }

    /// The document as a JSON value: its keys sorted, non-finite numbers `null`.
    pub(crate) fn to_value(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("a spot result serialises to JSON")
    }
}

/// What a finished session adds to `session.json` (besides its decisions, which the
/// recorder adds from its runs): the record of the session and the spot's result.
#[derive(Debug, Serialize)]
pub(crate) struct FinishedSession<'a> {
    /// The calibration the readings were converted with.
    pub calibration: &'a Calibration,
    /// Every fit.
    pub fits: &'a [FitStep],
    /// The session's flags (the analysis's and its own).
    pub flags: &'a [Flag],
    /// No flag but the informational ones.
    pub ok: bool,
    /// Every reading, superseded ones included (marked).
    pub readings: &'a [MeasuredPoint],
    /// What was recovered.
    pub recoveries: &'a Recoveries,
    /// Every refinement.
    pub refinements: &'a [Refinement],
    /// The spot's result.
    pub result: &'a SpotResultDocument,
    /// Every Home of the session and the step errors it found.
    pub step_checks: &'a [StepCheck],
}

/// A part of a document read on its own: `None` when absent, the error when it is not
/// what it must be (so one bad part leaves the others readable, as each reader needs).
pub(crate) type Part<T> = Option<Result<T, serde_json::Error>>;

/// What a finished `session.json` says of its outcome besides its head: the session's
/// verdict (`ok`, `flags`) and the spot's result, each read on its own.
#[derive(Debug, Default, Deserialize)]
#[serde(default)]
pub(crate) struct SessionOutcome {
    /// No flag but the informational ones.
    #[serde(deserialize_with = "part")]
    pub ok: Part<bool>,
    /// The session's flags (the analysis's and its own).
    #[serde(deserialize_with = "part")]
    pub flags: Part<Vec<Flag>>,
    /// The spot's result.
    #[serde(deserialize_with = "part")]
    pub result: Part<SpotResultDocument>,
}

impl SessionOutcome {
    /// `ok`, when present and a boolean.
    pub fn ok(&self) -> Option<bool> {
        self.ok.as_ref().and_then(|r| r.as_ref().ok()).copied()
    }

    /// `flags`, when present and flags.
    pub fn flags(&self) -> Option<&[Flag]> {
        self.flags
            .as_ref()
            .and_then(|r| r.as_ref().ok())
            .map(Vec::as_slice)
    }

    /// `result`, when present and a spot result.
    pub fn result(&self) -> Option<&SpotResultDocument> {
        self.result.as_ref().and_then(|r| r.as_ref().ok())
    }
}

/// What a finished `session.json` records besides its outcome, as `gonio verify` checks it
/// against the folder's other files; each part read on its own.
#[derive(Debug, Default, Deserialize)]
#[serde(default)]
pub(crate) struct SessionRecord {
    /// Every reading, superseded ones included (marked).
    #[serde(deserialize_with = "part")]
    pub readings: Part<Vec<MeasuredPoint>>,
    /// The calibration the readings were converted with.
    #[serde(deserialize_with = "part")]
    pub calibration: Part<Calibration>,
}

impl SessionDoc {
    /// The outcome parts of the document (all `None` before it is finished).
    pub(crate) fn outcome(&self) -> SessionOutcome {
        // Every field is read on its own and the others ignored: this cannot fail.
        SessionOutcome::deserialize(&self.rest).unwrap_or_default()
    }

    /// The record parts of the document (all `None` before it is finished); apart from
    /// [`SessionDoc::outcome`] because only the verification needs every reading.
    pub(crate) fn record(&self) -> SessionRecord {
        // As the outcome: every field on its own, so this cannot fail.
        SessionRecord::deserialize(&self.rest).unwrap_or_default()
    }
}

/// A present field read as `T`, its error kept rather than failing the whole document.
fn part<'de, D: Deserializer<'de>, T: serde::de::DeserializeOwned>(
    deserializer: D,
) -> Result<Part<T>, D::Error> {
    let value = serde_json::Value::deserialize(deserializer)?;
    Ok(Some(T::deserialize(value)))
}
