//! `gonio verify`'s check of a session folder: the manifest, and the agreement of
//! `points.jsonl` (the primary record), `readings.csv`, `calibration.json` and
//! `session.json`. Read-only: it changes nothing.
use crate::output::folder::{
    self, CALIBRATION, CsvAgreement, LOG, POINTS, Problem, READINGS, RunOutcome, SESSION, Status,
};
use crate::session::MeasuredPoint;
use std::path::{Path, PathBuf};

/// A folder that passed every check.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Verified {
    /// The folder.
    pub dir: PathBuf,
    /// Files the manifest lists (all of them but itself).
    pub files: usize,
    /// Readings in `points.jsonl`.
    pub readings: usize,
    /// The sample.
    pub sample: String,
    /// The instrument's serial number.
    pub serial_number: String,
    /// Runs that made the session.
    pub runs: usize,
}

/// Check the finished session folder `dir`; every problem found, each at `file:line` where
/// a line is known.
pub fn verify(dir: &Path) -> Result<Verified, Vec<Problem>> {
    let inspection = folder::inspect(dir).map_err(|p| vec![p])?;
    let problem = |file: &str, line: Option<usize>, message: String| Problem {
        file: dir.join(file),
        line,
        message,
    };
    let Some(doc) = &inspection.session else {
        return Err(vec![problem(
            SESSION,
            None,
            "missing: not a session folder, or no session was started in it".into(),
        )]);
    };
    let mut problems = inspection.damage.clone();
    if doc.status != Status::Finished {
        let how = doc
            .resume_with
            .clone()
            .unwrap_or_else(|| format!("gonio measure --resume {}", dir.display()));
        problems.push(problem(
            SESSION,
            None,
            format!(
                "status is {}: the session is not finished (continue it with {how})",
                doc.status
            ),
        ));
    }
    let files = match crate::output::manifest::check(dir) {
        Ok(files) => files,
        Err(found) => {
            problems.extend(found);
            0
        }
    };
    if problems.is_empty() {
        problems.extend(crate::output::report::check_report(dir));
    }
    for (name, file) in [(POINTS, &inspection.points_file), (LOG, &inspection.log)] {
        if let Some(tail) = &file.cut_tail {
            problems.push(problem(
                name,
                Some(file.lines.len() + 1),
                format!("last line cut short ({} bytes, no newline)", tail.len()),
            ));
        }
    }
    match &inspection.csv {
        CsvAgreement::Agrees => {}
        CsvAgreement::Behind { missing, cut } => problems.push(problem(
            READINGS,
            None,
            format!(
                "{missing} rows of {POINTS} missing{}",
                if *cut { ", the last one cut short" } else { "" }
            ),
        )),
        CsvAgreement::Stale { .. } => problems.push(problem(
            READINGS,
            None,
            format!("holds rows from before readings were superseded or {CALIBRATION} changed"),
        )),
        // Among the damage already.
        CsvAgreement::Differs(_) => {}
    }
    let points = &inspection.points;
    if doc.status == Status::Finished && doc.readings_recorded < points.len() {
        problems.push(problem(
            SESSION,
            None,
            format!(
                "readings_recorded is {}, but {POINTS} holds {}",
                doc.readings_recorded,
                points.len()
            ),
        ));
    }
    if doc.status == Status::Finished {
        match doc
            .rest
            .get("readings")
            .map(|r| serde_json::from_value::<Vec<MeasuredPoint>>(r.clone()))
        {
            None => problems.push(problem(SESSION, None, "no 'readings'".into())),
            Some(Err(e)) => problems.push(problem(
                SESSION,
                None,
                format!("'readings' are not readings: {e}"),
            )),
            Some(Ok(readings)) => {
                if readings.len() != points.len() {
                    problems.push(problem(
                        SESSION,
                        None,
                        format!(
                            "{} readings, but {POINTS} holds {}",
                            readings.len(),
                            points.len()
                        ),
                    ));
                }
                if let Some(k) = readings.iter().zip(points).position(|(a, b)| a != b) {
                    problems.push(problem(
                        POINTS,
                        Some(k + 1),
                        format!("differs from reading {} of {SESSION}", k + 1),
                    ));
                }
            }
        }
        match (
            doc.rest.get("calibration").map(|c| {
                serde_json::from_value::<crate::instrument::calibration::Calibration>(c.clone())
            }),
            &inspection.calibration,
        ) {
            (Some(Ok(in_session)), Some(file)) if in_session == *file => {}
            (Some(Ok(_)), Some(_)) => problems.push(problem(
                CALIBRATION,
                None,
                format!("differs from the calibration in {SESSION}"),
            )),
            (_, None) => problems.push(problem(CALIBRATION, None, "missing".into())),
            (None, _) => problems.push(problem(SESSION, None, "no 'calibration'".into())),
            (Some(Err(e)), _) => problems.push(problem(
                SESSION,
                None,
                format!("'calibration' is not a calibration: {e}"),
            )),
        }
        for key in ["result", "ok", "flags"] {
            if !doc.rest.contains_key(key) {
                problems.push(problem(SESSION, None, format!("no '{key}'")));
            }
        }
        match doc.runs.last() {
            Some(run) if run.outcome == RunOutcome::Finished => {}
            _ => problems.push(problem(
                SESSION,
                None,
                "its last run did not finish the session".into(),
            )),
        }
        if let Some(run) = doc.runs.iter().find(|r| r.outcome == RunOutcome::Running) {
            problems.push(problem(
                SESSION,
                None,
                format!("run {} is still marked running", run.run),
            ));
        }
    }
    if problems.is_empty() {
        Ok(Verified {
            dir: dir.to_path_buf(),
            files,
            readings: points.len(),
            sample: doc.sample.clone(),
            serial_number: doc.instrument.serial_number.clone(),
            runs: doc.runs.len(),
        })
    } else {
        Err(problems)
    }
}
