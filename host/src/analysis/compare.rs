//! A measured sheet as `gonio compare` and the library read it: the result of a session
//! (`session.json` of a session folder), its parameters and their covariance, every key
//! checked and named when it is missing or wrong. The comparison itself is the likelihood
//! ratio of [`crate::analysis::evidence`]; a parameter the session reported as null stays
//! undetermined and is left out there, and the class is carried for information only.
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
}

impl SessionResult {
    /// The sheet it measured, as the evidence weighs it: one spot (σ, ρs, ρd and their
    /// covariance; a parameter the session left null stays undetermined).
    pub fn sheet(&self) -> crate::analysis::evidence::Sheet {
        let values = std::array::from_fn(|i| self.values[i]);
        let covariance = std::array::from_fn(|r| std::array::from_fn(|c| self.covariance[r][c]));
        crate::analysis::evidence::Sheet {
            spots: vec![crate::analysis::evidence::Spot { values, covariance }],
        }
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
        schema::check(root, &[schema::SESSION, schema::SESSION_V1], None).map_err(|error| {
            CompareError::Json {
                path: file.to_path_buf(),
                message: error.to_string(),
            }
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
    let object = root
        .as_object()
        .ok_or_else(|| bad("(top level)", "an object"))?;

    let sample = object
        .get("sample")
        .ok_or_else(|| missing("sample"))?
        .as_str()
        .ok_or_else(|| bad("sample", "a string"))?
        .to_string();
    let result = object.get("result").ok_or_else(|| missing("result"))?;
    let result = result
        .as_object()
        .ok_or_else(|| bad("result", "an object"))?;

    let mut values = [None; 4];
    for (i, name) in crate::analysis::model::PARAM_NAMES.iter().enumerate() {
        let key = format!("result.{name}");
        values[i] = match result.get(*name).ok_or_else(|| missing(&key))? {
            Value::Null => None,
            v => Some(
                v.as_f64()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| bad(&key, "a number or null"))?,
            ),
        };
    }
    let class = match result.get("class").ok_or_else(|| missing("result.class"))? {
        Value::Null => None,
        v => Some(
            v.as_str()
                .ok_or_else(|| bad("result.class", "a string or null"))?
                .to_string(),
        ),
    };

    let rows = result
        .get("covariance")
        .ok_or_else(|| missing("result.covariance"))?;
    let shape = "a 4×4 array of numbers";
    let rows = rows
        .as_array()
        .filter(|r| r.len() == 4)
        .ok_or_else(|| bad("result.covariance", shape))?;
    let mut covariance = [[0.0; 4]; 4];
    for (i, row) in rows.iter().enumerate() {
        let row = row
            .as_array()
            .filter(|r| r.len() == 4)
            .ok_or_else(|| bad("result.covariance", shape))?;
        for (j, v) in row.iter().enumerate() {
            // serde_json writes a non-finite covariance as null: treat it as not determined.
            covariance[i][j] = match v {
                Value::Null => 0.0,
                v => v.as_f64().ok_or_else(|| bad("result.covariance", shape))?,
            };
        }
    }
    // Flags are read as they are written (strings); a document without them is clean.
    let flags = object
        .get("flags")
        .or_else(|| result.get("flags"))
        .and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .map(|f| f.as_str().map_or_else(|| f.to_string(), str::to_string))
                .collect()
        })
        .unwrap_or_default();
    Ok(SessionResult {
        file: file.to_path_buf(),
        sample,
        class,
        values,
        covariance,
        flags,
    })
}
