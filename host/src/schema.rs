//! The names and versions of gonio's JSON documents: every JSON object gonio prints
//! (`--json`) and every JSON file it writes carries one of these as its `schema` key, so a
//! program that reads it knows what it is reading and which version of it. Each has a
//! JSON Schema under `docs/schemas/` (`<name>-<version>.schema.json`); `docs/FORMATS.md`
//! describes them. A change to a document's fields is a new version here and a new schema
//! file; the tests validate every output against its schema, so a field cannot change
//! silently.
//!
//! Readers of gonio's own files accept the versions listed as readable next to each
//! writer's version (older session and sheet folders still verify, re-analyse and compare).
use serde_json::Value;

/// `session.json` of a session folder.
pub const SESSION: &str = "gonio-session/3";
/// `session.json` before the case recorded the sheet's orientation and side: still read
/// (both unknown).
pub const SESSION_V2: &str = "gonio-session/2";
/// `session.json` before `schema` (it was `format`), with `ci95.sigma` and the refinements
/// of `result` as bare numbers: still read, upgraded in memory ([`crate::output::folder`]).
pub const SESSION_V1: &str = "gonio-session/1";
/// `sheet.json` of a sheet folder.
pub(crate) const SHEET: &str = "gonio-sheet/3";
/// `sheet.json` before the sheet's answer (its class, confidence and the mean's intervals)
/// and with the mean as an array: still read, its result recomputed from its spots.
pub(crate) const SHEET_V2: &str = "gonio-sheet/2";
/// `sheet.json` before `schema` (it was `format`): still read.
pub(crate) const SHEET_V1: &str = "gonio-sheet/1";
/// `calibration.json` (and the `calibration` of `session.json`).
pub(crate) const CALIBRATION: &str = "gonio-calibration/1";
/// A reading's line of `points.jsonl`.
pub(crate) const POINT: &str = "gonio-point/1";
/// A line of `points.jsonl` that marks earlier readings superseded.
pub(crate) const SUPERSEDE: &str = "gonio-supersede/1";
/// The analysis of one data set: a line of `gonio fit --json`, and each `fits[].report`
/// of `session.json`.
pub const ANALYSIS: &str = "gonio-analysis/1";
/// The result of one spot: `gonio measure --json` of one spot and `result` of
/// `session.json` (the analysis and what the session adds to it).
pub const SPOT_RESULT: &str = "gonio-spot-result/1";
/// `gonio measure --json` of a sheet of several spots.
pub const SHEET_RESULT: &str = "gonio-sheet-result/2";
/// `gonio compare --json`.
pub(crate) const COMPARE: &str = "gonio-compare/5";
/// A line of `gonio verify --json`.
pub const VERIFY: &str = "gonio-verify/2";
/// A line of `gonio sessions --json`.
pub const SESSIONS_ENTRY: &str = "gonio-sessions-entry/1";
/// `gonio library list --json`.
pub const LIBRARY_LIST: &str = "gonio-library-list/1";
/// `gonio library search --json`.
pub const LIBRARY_SEARCH: &str = "gonio-library-search/4";
/// `gonio library history --json`: the audit trail.
pub const LIBRARY_HISTORY: &str = "gonio-library-history/1";
/// `gonio library history --contents-at N --json`: the contents after an entry.
pub const LIBRARY_CONTENTS_AT: &str = "gonio-library-contents-at/1";
/// A line of `gonio library export` (one measured sheet of a known stock).
pub const LIBRARY_RECORD: &str = "gonio-library/3";
/// A `gonio library export` line before the sheet's orientation and side: still imported
/// (both unknown).
pub(crate) const LIBRARY_RECORD_V2: &str = "gonio-library/2";
/// A `gonio library export` line before `schema` (it was `format`): still imported.
pub(crate) const LIBRARY_RECORD_V1: &str = "gonio-library/1";
/// A white tile's certificate (`gonio measure --tile-certificate FILE`), as the user
/// writes it; `schema` is optional there.
pub const TILE_CERTIFICATE: &str = "gonio-tile-certificate/1";

/// `signature.json` of a signed folder, and `F.sig.json` of a signed file (a library
/// export, a compare report).
pub const SIGNATURE: &str = "gonio-signature/1";
/// A public key as `gonio keys export-public` prints it and the keys folder keeps a
/// trusted one (`NAME.pub`).
pub const PUBLIC_KEY: &str = "gonio-public-key/1";
/// An own key file of the keys folder (`NAME.key`), private key included.
pub const KEY: &str = "gonio-key/1";
/// `batch.json` of a QA batch folder (`gonio batch`).
pub const BATCH: &str = "gonio-batch/3";
/// The same before the plan recorded its gloss specification and each sheet its gloss:
/// read (as a batch without gloss specification), never written.
pub(crate) const BATCH_V2: &str = "gonio-batch/2";
/// The same before the plan recorded its policy: read, never written.
pub(crate) const BATCH_V1: &str = "gonio-batch/1";

/// An instrument profile (`gonio characterize`'s `instrument.json`).
pub const INSTRUMENT_PROFILE: &str = "gonio-instrument/1";
/// `readings.shared-errors.json`: the errors a session's readings share and the settings
/// its analysis weighed `readings.csv` with ([`crate::output::shared_errors`]).
pub const SHARED_ERRORS: &str = "gonio-shared-errors/1";

/// Every schema gonio writes, for the documentation's check that each has its file.
pub const WRITTEN: [&str; 22] = [
    INSTRUMENT_PROFILE,
    SESSION,
    SHEET,
    CALIBRATION,
    POINT,
    SUPERSEDE,
    ANALYSIS,
    SPOT_RESULT,
    SHEET_RESULT,
    COMPARE,
    VERIFY,
    SESSIONS_ENTRY,
    LIBRARY_LIST,
    LIBRARY_SEARCH,
    LIBRARY_HISTORY,
    LIBRARY_CONTENTS_AT,
    LIBRARY_RECORD,
    SIGNATURE,
    PUBLIC_KEY,
    KEY,
    SHARED_ERRORS,
    BATCH,
];

/// The file name of a schema's JSON Schema under `docs/schemas/`: `gonio-session/2` →
/// `gonio-session-2.schema.json`.
pub fn file_name(schema: &str) -> String {
    format!("{}.schema.json", schema.replace('/', "-"))
}

/// `value` (an object) with `schema` set to `schema`; anything else is returned as it is.
pub fn tagged(schema: &str, mut value: Value) -> Value {
    if let Some(object) = value.as_object_mut() {
        object.insert("schema".into(), Value::from(schema));
    }
    value
}

/// The `schema` of a JSON object, if it has one that is a string.
pub fn of(value: &Value) -> Option<&str> {
    value.get("schema").and_then(Value::as_str)
}

/// Why a document is not one this gonio reads.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SchemaError {
    /// Its `schema` (or older `format`) is none of those this gonio reads.
    #[error(
        "schema '{found}' is not one this gonio reads ({}){}",
        .reads.join(", "),
        newer_hint(.newer)
    )]
    NotRead {
        /// The schema the document names.
        found: String,
        /// Those this gonio reads, newest first.
        reads: Vec<String>,
        /// Whether it is a newer version of the newest one read.
        newer: bool,
    },
    /// It names no schema and none is assumed.
    #[error("no 'schema': not a document this gonio reads ({})", .reads.join(", "))]
    Missing {
        /// Those this gonio reads, newest first.
        reads: Vec<String>,
    },
}

fn newer_hint(newer: &bool) -> &'static str {
    if *newer {
        ": written by a newer gonio; update gonio to read it"
    } else {
        ""
    }
}

/// Check that a document is of a schema this gonio reads: `reads` lists them, newest
/// first. A document without `schema` (nor the `format` that older versions wrote) is
/// accepted only when `unversioned` names what it is then taken for (a file a person
/// wrote, or one written before gonio named its documents). Returns the schema it is read
/// as; the error says what was found and what this gonio reads.
pub fn check<'a>(
    value: &'a Value,
    reads: &[&'a str],
    unversioned: Option<&'a str>,
) -> Result<&'a str, SchemaError> {
    let found = of(value).or_else(|| value.get("format").and_then(Value::as_str));
    let reads_owned = || reads.iter().map(|r| r.to_string()).collect();
    match (found, unversioned) {
        (Some(found), _) if reads.contains(&found) => Ok(found),
        (Some(found), _) => Err(SchemaError::NotRead {
            found: found.to_string(),
            reads: reads_owned(),
            newer: reads
                .first()
                .is_some_and(|newest| same_name(found, newest) && version(found) > version(newest)),
        }),
        (None, Some(taken_as)) => Ok(taken_as),
        (None, None) => Err(SchemaError::Missing {
            reads: reads_owned(),
        }),
    }
}

fn same_name(a: &str, b: &str) -> bool {
    a.split_once('/').map(|(n, _)| n) == b.split_once('/').map(|(n, _)| n)
}

fn version(schema: &str) -> Option<u32> {
    schema.split_once('/').and_then(|(_, v)| v.parse().ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_and_tags() {
        assert_eq!(file_name(SESSION), "gonio-session-3.schema.json");
        let v = tagged(ANALYSIS, serde_json::json!({"n": 1}));
        assert_eq!(of(&v), Some(ANALYSIS));
        assert_eq!(tagged(ANALYSIS, Value::from(3)), Value::from(3));
        let mut names = WRITTEN.to_vec();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), WRITTEN.len(), "a schema listed twice");
    }

    #[test]
    fn a_document_is_read_only_as_a_schema_this_gonio_reads() {
        let reads = [SESSION, SESSION_V1];
        assert_eq!(
            check(&serde_json::json!({"schema": SESSION}), &reads, None),
            Ok(SESSION)
        );
        assert_eq!(
            check(&serde_json::json!({"format": SESSION_V1}), &reads, None),
            Ok(SESSION_V1)
        );
        let newer = check(
            &serde_json::json!({"schema": "gonio-session/4"}),
            &reads,
            None,
        )
        .unwrap_err()
        .to_string();
        assert!(
            newer.contains("'gonio-session/4'") && newer.contains("update gonio"),
            "{newer}"
        );
        let other = check(&serde_json::json!({"schema": SHEET}), &reads, None)
            .unwrap_err()
            .to_string();
        assert!(
            other.contains("gonio-sheet/3") && !other.contains("update"),
            "{other}"
        );
        assert!(
            check(&serde_json::json!({}), &reads, None)
                .unwrap_err()
                .to_string()
                .contains("no 'schema'")
        );
        assert_eq!(
            check(&serde_json::json!({}), &[CALIBRATION], Some(CALIBRATION)),
            Ok(CALIBRATION)
        );
        assert!(check(&serde_json::json!({"schema": 3}), &reads, None).is_err());
    }
}
