//! A measured sheet as `gonio compare` and the library read it: the result of a session
//! (`session.json` of a session folder), its parameters and their covariance, every key
//! checked and named when it is missing or wrong. The comparison itself is the likelihood
//! ratio of [`crate::analysis::evidence`]; a parameter the session reported as null stays
//! undetermined and is left out there, and the class is carried for information only.
use serde::{Deserialize, Deserializer};
use serde_json::Value;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Why a session result cannot be read. Every variant names the file; key errors name the key.
#[derive(Debug, Error)]
pub enum CompareError {
    /// The file cannot be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not JSON.
    #[error("{path}: not valid JSON: {message}")]
    Json {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// A key the comparison needs is absent.
    #[error("{path}: missing key `{key}`")]
    MissingKey {
        /// The file.
        path: PathBuf,
        /// Dotted path of the key, e.g. `result.covariance`.
        key: String,
    },
    /// A key holds the wrong kind of value.
    #[error("{path}: key `{key}` must be {expected}")]
    BadValue {
        /// The file.
        path: PathBuf,
        /// Dotted path of the key.
        key: String,
        /// What it should hold.
        expected: &'static str,
    },
}

/// What the comparison reads from one `session.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionResult {
    /// The file read.
    pub file: PathBuf,
    /// Sample name.
    pub sample: String,
    /// Class as the session spelled it (G, SG, rough-I…); `None` when the session could not
    /// decide it (null in the file).
    pub class: Option<String>,
    /// σ [deg], ρs, ρd, η; `None` where the session reported null (not determined).
    pub values: [Option<f64>; 4],
    /// Covariance of (σ [deg], ρs, ρd, η); rows/columns of parameters not fitted are 0.
    pub covariance: [[f64; 4]; 4],
    /// The result's flags (`flags` beside `result`, or the result's own); empty: clean.
    pub flags: Vec<String>,
    /// The fit's `model form` widening and how far its terms moved the estimates from the
    /// paper's model's, which the evidence weighs in its place
    /// ([`crate::analysis::evidence::Spot::weighed`]).
    pub shape_widening: crate::analysis::evidence::ShapeWidening,
}

impl SessionResult {
    /// The sheet it measured, as the evidence weighs it: one spot (σ, ρs, ρd and their
    /// covariance; a parameter the session left null stays undetermined).
    pub fn sheet(&self) -> crate::analysis::evidence::Sheet {
        crate::analysis::evidence::Sheet {
            spots: vec![self.weighed_spot()],
        }
    }

    /// The spot it measured: σ, ρs, ρd and their covariance as the session reported them
    /// (η is not weighed).
    pub fn spot(&self) -> crate::analysis::evidence::Spot {
        let values = std::array::from_fn(|i| self.values[i]);
        let covariance = std::array::from_fn(|r| std::array::from_fn(|c| self.covariance[r][c]));
        crate::analysis::evidence::Spot { values, covariance }
    }

    /// The spot as the evidence weighs it ([`crate::analysis::evidence::Spot::weighed`]).
    pub fn weighed_spot(&self) -> crate::analysis::evidence::Spot {
        self.spot().weighed(self.shape_widening)
    }
}

/// The `session.json` of a session folder, or the path itself when it is a file.
pub(crate) fn session_file(path: &Path) -> PathBuf {
    if path.is_dir() {
        path.join("session.json")
    } else {
        path.to_path_buf()
    }
}

/// Read a session result from a session folder or its `session.json`.
pub fn read_session(path: &Path) -> Result<SessionResult, CompareError> {
    let file = session_file(path);
    let text = std::fs::read_to_string(&file).map_err(|source| CompareError::Io {
        path: file.clone(),
        source,
    })?;
    parse_session(&file, &text)
}

/// Parse the text of a `session.json` (`file` is only for messages).
pub fn parse_session(file: &Path, text: &str) -> Result<SessionResult, CompareError> {
    let root: Value = serde_json::from_str(text).map_err(|e| CompareError::Json {
        path: file.to_path_buf(),
        message: e.to_string(),
    })?;
    session_result(file, &root)
}

/// The result of a `session.json` document (`file` is only for messages). A document that
/// names its schema must be one whose result this gonio reads (the result's keys are the
/// same in both versions); one without (written by hand) is read by its keys alone.
pub(crate) fn session_result(file: &Path, root: &Value) -> Result<SessionResult, CompareError> {
    use crate::schema;
    if schema::of(root).is_some() || root.get("format").is_some() {
        schema::check(
            root,
            &[schema::SESSION, schema::SESSION_V2, schema::SESSION_V1],
            None,
        )
        .map_err(|error| CompareError::Json {
            path: file.to_path_buf(),
            message: error.to_string(),
        })?;
    }
    let missing = |key: &str| CompareError::MissingKey {
        path: file.to_path_buf(),
        key: key.to_string(),
    };
    let bad = |key: &str, expected: &'static str| CompareError::BadValue {
        path: file.to_path_buf(),
        key: key.to_string(),
        expected,
    };
    let fail = |found: Found, key: &str, expected: &'static str| match found {
        Found::Missing => missing(key),
        Found::Bad => bad(key, expected),
    };
    if !root.is_object() {
        return Err(bad("(top level)", "an object"));
    }
    let document = SessionFile::deserialize(root).unwrap_or_default();
    let sample = document
        .sample
        .get()
        .map_err(|found| fail(found, "sample", "a string"))?;
    let result = match document.result.get() {
        Ok(Value::Object(result)) => ResultFile::deserialize(result).unwrap_or_default(),
        Ok(_) | Err(Found::Bad) => return Err(bad("result", "an object")),
        Err(Found::Missing) => return Err(missing("result")),
    };

    let mut values = [None; 4];
    for (i, name) in crate::analysis::model::PARAM_NAMES.iter().enumerate() {
        let key = format!("result.{name}");
        values[i] = result
            .parameter(name)
            .get()
            .map_err(|found| fail(found, &key, "a number or null"))?;
    }
    let class = result
        .class
        .get()
        .map_err(|found| fail(found, "result.class", "a string or null"))?;
    // serde_json writes a non-finite covariance as null: treat it as not determined.
    let covariance = result
        .covariance
        .get()
        .map_err(|found| fail(found, "result.covariance", "a 4×4 array of numbers"))?
        .map(|row| row.map(|v| v.unwrap_or(0.0)));
    let shape_widening = result.shape_widening();
    // Flags as they are written (strings), beside the result or in it; none: clean.
    let flags = match document.flags {
        Slot::Is(flags) => flags,
        _ => match result.flags {
            Slot::Is(flags) => flags,
            _ => Vec::new(),
        },
    };
    Ok(SessionResult {
        file: file.to_path_buf(),
        sample,
        class,
        values,
        covariance,
        flags,
        shape_widening,
    })
}

/// What the comparison reads of a `session.json`, each key kept apart as [`Slot`] so that a
/// missing or wrong one is named.
#[derive(Default, Deserialize)]
#[serde(default)]
struct SessionFile {
    sample: Slot<String>,
    result: Slot<Value>,
    flags: Slot<Vec<String>>,
}

/// What the comparison reads of a session's `result`.
#[derive(Default, Deserialize)]
#[serde(default)]
struct ResultFile {
    sigma_deg: Slot<Option<f64>>,
    rho_s: Slot<Option<f64>>,
    rho_d: Slot<Option<f64>>,
    eta: Slot<Option<f64>>,
    class: Slot<Option<String>>,
    covariance: Slot<[[Option<f64>; 4]; 4]>,
    flags: Slot<Vec<String>>,
    budget: Slot<BudgetFile>,
    model_extension: Slot<Option<ExtensionFile>>,
}

/// What the comparison reads of a result's `budget`: its terms' names and variances.
#[derive(Default, Deserialize)]
#[serde(default)]
struct BudgetFile {
    terms: Vec<BudgetTermFile>,
}

/// One term of a result's budget: its name and its variance per parameter.
#[derive(Default, Deserialize)]
#[serde(default)]
struct BudgetTermFile {
    name: String,
    variance: std::collections::BTreeMap<String, Option<f64>>,
}

/// What the comparison reads of a result's `model_extension`: the terms added, and how far
/// they moved σ, ρs, ρd from the paper's model (absent before that was recorded).
#[derive(Default, Deserialize)]
#[serde(default)]
struct ExtensionFile {
    terms: Vec<Value>,
    shift_from_paper_model: Option<ShiftFile>,
}

/// A result's `model_extension.shift_from_paper_model`.
#[derive(Default, Deserialize)]
#[serde(default)]
struct ShiftFile {
    sigma_deg: Option<f64>,
    rho_s: Option<f64>,
    rho_d: Option<f64>,
}

impl ResultFile {
    /// The fit's `model form` widening (its budget's terms of that kind), and how far its
    /// extension step moved σ, ρs, ρd from the paper's model: as recorded; 0 where a
    /// record from before the shift was written added no term; not known (the widening is
    /// then weighed whole) where it added one, where the step did not run, and where
    /// `model_extension` cannot be read.
    fn shape_widening(&self) -> crate::analysis::evidence::ShapeWidening {
        let shift_from_paper_model = match &self.model_extension {
            Slot::Is(Some(extension)) => match &extension.shift_from_paper_model {
                Some(shift) => [shift.sigma_deg, shift.rho_s, shift.rho_d],
                None if extension.terms.is_empty() => [Some(0.0); 3],
                None => [None; 3],
            },
            Slot::Missing | Slot::Is(None) | Slot::Bad => [None; 3],
        };
        let mut variance = [0.0; 3];
        if let Slot::Is(budget) = &self.budget {
            for term in budget
                .terms
                .iter()
                .filter(|t| crate::analysis::evidence::is_model_form(&t.name))
            {
                for (k, name) in crate::analysis::evidence::PARAMS.iter().enumerate() {
                    variance[k] += term.variance.get(*name).copied().flatten().unwrap_or(0.0);
                }
            }
        }
        crate::analysis::evidence::ShapeWidening {
            variance,
            shift_from_paper_model,
        }
    }

    /// The parameter named `name` ([`crate::analysis::model::PARAM_NAMES`]).
    fn parameter(&self, name: &str) -> &Slot<Option<f64>> {
        match name {
            "sigma_deg" => &self.sigma_deg,
            "rho_s" => &self.rho_s,
            "rho_d" => &self.rho_d,
            "eta" => &self.eta,
            _ => &Slot::Missing,
        }
    }
}

/// A key of a document: absent, present but not a `T`, or a `T`.
#[derive(Default)]
enum Slot<T> {
    /// The key is absent.
    #[default]
    Missing,
    /// The key holds something else.
    Bad,
    /// The key's value.
    Is(T),
}

impl<'de, T: serde::de::DeserializeOwned> Deserialize<'de> for Slot<T> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let value = Value::deserialize(deserializer)?;
        Ok(T::deserialize(value).map_or(Slot::Bad, Slot::Is))
    }
}

impl<T: Clone> Slot<T> {
    /// The value, or why there is none.
    fn get(&self) -> Result<T, Found> {
        match self {
            Slot::Missing => Err(Found::Missing),
            Slot::Bad => Err(Found::Bad),
            Slot::Is(value) => Ok(value.clone()),
        }
    }
}

/// Why a [`Slot`] holds no value.
enum Found {
    /// The key is absent.
    Missing,
    /// The key holds something else.
    Bad,
}
