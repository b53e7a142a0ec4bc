//! Every check of a finished folder, as `gonio verify` runs them: of a session folder, the
//! manifest and the agreement of `points.jsonl` (the primary record), `readings.csv`,
//! `calibration.json` and `session.json`; of a sheet folder, its manifest, every spot's
//! folder and the result its spots give; of either, that `report.html` is the report its
//! files give; of either, that its signature (`signature.json`), when it has one, holds
//! over its manifest (who signed, and whether that key is trusted, is for the caller to
//! judge: [`Verified::signed`]). Read-only: it changes nothing.
//!
//! Rendering sits above verification (the report is drawn from what is checked here), so
//! the check of `report.html` is handed the drawing: [`DrawReport`], in use
//! `output::report::draw`, above the folder. A folder is read once: what the checks read is what
//! the drawing is given, and what [`Verified`] hands on (the library adds it from there).
use crate::instrument::calibration::Calibration;
use crate::output::folder::documents::Part;
use crate::output::folder::sheet::{
    ReadFolder, ReadSheet, assemble, manifest_text, read_doc, require_finished_sheet, spot_from,
};
use crate::output::folder::signature::{SIGNATURE, Signed, check_folder, check_folder_over};
use crate::output::folder::{
    self, CALIBRATION, CsvAgreement, Finding, Inspection, LOG, MANIFEST, POINTS, READINGS, REPORT,
    RunOutcome, SESSION, SHEET, SessionDoc, Status,
};
use crate::session::MeasuredPoint;
use std::path::{Path, PathBuf};

/// Draws the report of a finished folder (session or sheet), already read, for the check
/// that its `report.html` is the one its files give.
pub(crate) type DrawReport<E> = fn(&ReadFolder) -> Result<String, E>;

/// A folder that passed every check, with what was read of it.
#[derive(Clone, Debug, PartialEq)]
pub struct Verified {
    /// The folder.
    pub dir: PathBuf,
    /// Files the manifest lists (all of them but itself).
    pub files: usize,
    /// The folder's identity: the SHA-256 (hex) of its manifest.
    pub identity: String,
    /// Readings in `points.jsonl`.
    pub readings: usize,
    /// Its `session.json`.
    pub doc: SessionDoc,
    /// Its `calibration.json`.
    pub calibration: Option<Calibration>,
    /// Who signed its manifest (`signature.json`), when it is signed; a signature that does
    /// not hold is a problem found.
    pub signed: Option<Signed>,
}

/// Check the finished session folder `dir`; every problem found, each at `file:line` where
/// a line is known. In order: the damage reading finds, the status, the manifest, the
/// report (when nothing else is wrong so far), cut lines, `readings.csv`, and what a
/// finished `session.json` must hold.
pub fn verify<E: std::fmt::Display>(
    dir: &Path,
    draw: DrawReport<E>,
) -> Result<Verified, Vec<Finding>> {
    let inspection = folder::inspect(dir).map_err(|p| vec![p])?;
    let Some(doc) = &inspection.session else {
        return Err(vec![at(
            dir,
            SESSION,
            None,
            "missing: not a session folder, or no session was started in it".into(),
        )]);
    };
    let mut problems = inspection.damage.clone();
    problems.extend(unfinished(dir, doc));
    let matched = match crate::output::folder::manifest::check_read(dir, &inspection.read) {
        Ok(matched) => Some(matched),
        Err(found) => {
            problems.extend(found);
            None
        }
    };
    if problems.is_empty() {
        let read = ReadFolder::Session {
            dir,
            doc,
            calibration: Ok(inspection.calibration.as_ref()),
        };
        problems.extend(check_report(dir, &read, draw));
    }
    problems.extend(cut_lines(dir, &inspection));
    problems.extend(csv_behind(dir, &inspection.csv));
    if doc.status == Status::Finished {
        // Each part read once (the readings are most of the document).
        let record = doc.record();
        problems.extend(finished_readings(
            dir,
            doc,
            record.readings,
            &inspection.points,
        ));
        problems.extend(finished_record(dir, doc, record.calibration, &inspection));
    }
    // Over the manifest as the check above read it, when it could.
    let signature = match &matched {
        Some(matched) => check_folder_over(dir, matched.text.as_bytes()),
        None => check_folder(dir),
    };
    let signed = match signature {
        Ok(signed) => signed,
        Err(problem) => {
            problems.push(problem);
            None
        }
    };
    match matched {
        Some(matched) if problems.is_empty() => Ok(Verified {
            dir: dir.to_path_buf(),
            files: matched.files,
            identity: matched.identity,
            readings: inspection.points.len(),
            doc: doc.clone(),
            calibration: inspection.calibration,
            signed,
        }),
        _ => Err(problems),
    }
}

/// A finding about the file `file` of the folder `dir`.
fn at(dir: &Path, file: &str, line: Option<usize>, message: String) -> Finding {
    Finding {
        file: dir.join(file),
        line,
        message,
    }
}

/// A session that is not finished, and how to continue it.
fn unfinished(dir: &Path, doc: &SessionDoc) -> Option<Finding> {
    if doc.status == Status::Finished {
        return None;
    }
    let how = doc
        .resume_with
        .clone()
        .unwrap_or_else(|| format!("gonio measure --resume {}", dir.display()));
    Some(at(
        dir,
        SESSION,
        None,
        format!(
            "status is {}: the session is not finished (continue it with {how})",
            doc.status
        ),
    ))
}

/// A last line cut short in `points.jsonl` or `session.log`.
fn cut_lines(dir: &Path, inspection: &Inspection) -> Vec<Finding> {
    [(POINTS, &inspection.points_file), (LOG, &inspection.log)]
        .into_iter()
        .filter_map(|(name, file)| {
            let tail = file.cut_tail.as_ref()?;
            Some(at(
                dir,
                name,
                Some(file.lines.len() + 1),
                format!("last line cut short ({} bytes, no newline)", tail.len()),
            ))
        })
        .collect()
}

/// `readings.csv` behind `points.jsonl` or stale (a disagreement is among the damage).
fn csv_behind(dir: &Path, csv: &CsvAgreement) -> Option<Finding> {
    match csv {
        CsvAgreement::Agrees | CsvAgreement::Differs(_) => None,
        CsvAgreement::Behind { missing, cut } => Some(at(
            dir,
            READINGS,
            None,
            format!(
                "{missing} rows of {POINTS} missing{}",
                if *cut { ", the last one cut short" } else { "" }
            ),
        )),
        CsvAgreement::Stale { .. } => Some(at(
            dir,
            READINGS,
            None,
            format!("holds rows from before readings were superseded or {CALIBRATION} changed"),
        )),
    }
}

/// A finished `session.json`'s readings: as many as `points.jsonl` holds, and the same.
fn finished_readings(
    dir: &Path,
    doc: &SessionDoc,
    recorded: Part<Vec<MeasuredPoint>>,
    points: &[MeasuredPoint],
) -> Vec<Finding> {
    let mut problems = Vec::new();
    if doc.readings_recorded < points.len() {
        problems.push(at(
            dir,
            SESSION,
            None,
            format!(
                "readings_recorded is {}, but {POINTS} holds {}",
                doc.readings_recorded,
                points.len()
            ),
        ));
    }
    match recorded {
        None => problems.push(at(dir, SESSION, None, "no 'readings'".into())),
        Some(Err(e)) => problems.push(at(
            dir,
            SESSION,
            None,
            format!("'readings' are not readings: {e}"),
        )),
        Some(Ok(readings)) => {
            if readings.len() != points.len() {
                problems.push(at(
                    dir,
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
                problems.push(at(
                    dir,
                    POINTS,
                    Some(k + 1),
                    format!("differs from reading {} of {SESSION}", k + 1),
                ));
            }
        }
    }
    problems
}

/// The rest of a finished `session.json`: its calibration as `calibration.json` holds it,
/// its result, and runs that all ended, the last one finishing the session.
fn finished_record(
    dir: &Path,
    doc: &SessionDoc,
    calibration: Part<Calibration>,
    inspection: &Inspection,
) -> Vec<Finding> {
    let mut problems = Vec::new();
    let problem = |file: &str, message: String| at(dir, file, None, message);
    let outcome = doc.outcome();
    match (calibration, &inspection.calibration) {
        (Some(Ok(in_session)), Some(file)) if in_session == *file => {}
        (Some(Ok(_)), Some(_)) => problems.push(problem(
            CALIBRATION,
            format!("differs from the calibration in {SESSION}"),
        )),
        (_, None) => problems.push(problem(CALIBRATION, "missing".into())),
        (None, _) => problems.push(problem(SESSION, "no 'calibration'".into())),
        (Some(Err(e)), _) => problems.push(problem(
            SESSION,
            format!("'calibration' is not a calibration: {e}"),
        )),
    }
    let present = [
        ("result", outcome.result.is_some()),
        ("ok", outcome.ok.is_some()),
        ("flags", outcome.flags.is_some()),
    ];
    for (key, _) in present.iter().filter(|(_, present)| !present) {
        problems.push(problem(SESSION, format!("no '{key}'")));
    }
    match doc.runs.last() {
        Some(run) if run.outcome == RunOutcome::Finished => {}
        _ => problems.push(problem(
            SESSION,
            "its last run did not finish the session".into(),
        )),
    }
    if let Some(run) = doc.runs.iter().find(|r| r.outcome == RunOutcome::Running) {
        problems.push(problem(
            SESSION,
            format!("run {} is still marked running", run.run),
        ));
    }
    problems
}

/// A sheet folder that passed every check.
#[derive(Clone, Debug, PartialEq)]
pub struct VerifiedSheet {
    /// The sheet, as its verified spots give it.
    pub sheet: ReadSheet,
    /// Each spot's check.
    pub spots: Vec<Verified>,
    /// The sheet folder's identity: the SHA-256 (hex) of its manifest.
    pub identity: String,
    /// Who signed the sheet's manifest, when it is signed (each spot's signer is in
    /// `spots`).
    pub signed: Option<Signed>,
}

/// Check the finished sheet folder `dir`: its manifest, every spot folder as `gonio verify`
/// checks a session, and the recorded result against the one its spots give.
pub fn verify_sheet<E: std::fmt::Display>(
    dir: &Path,
    draw: DrawReport<E>,
) -> Result<VerifiedSheet, Vec<Finding>> {
    let doc = read_doc(dir).map_err(|p| vec![p])?;
    let mut problems = Vec::new();
    let manifest = dir.join(MANIFEST);
    let mut identity = String::new();
    let read = std::fs::read_to_string(&manifest);
    match (&read, manifest_text(dir, &doc)) {
        (Ok(recorded), Ok(now)) if *recorded == now => {
            identity = crate::output::folder::manifest::sha256_hex(recorded.as_bytes());
        }
        (Ok(_), Ok(_)) => problems.push(Finding { file: manifest.clone(), line: None, message: format!("does not match {SHEET} and the spots' manifests: a file changed since the sheet finished") }),
        (Err(e), _) => problems.push(Finding { file: manifest.clone(), line: None, message: format!("cannot read ({e}): the sheet never finished") }),
        (_, Err(e)) => problems.push(Finding { file: dir.to_path_buf(), line: None, message: format!("a file the manifest covers cannot be read: {e}") }),
    }
    // Over the manifest as read above, when it could be.
    let signature = match &read {
        Ok(recorded) => check_folder_over(dir, recorded.as_bytes()),
        Err(_) => check_folder(dir),
    };
    let signed = match signature {
        Ok(signed) => signed,
        Err(problem) => {
            problems.push(problem);
            None
        }
    };
    let expected: Vec<String> = [SHEET, MANIFEST, REPORT, SIGNATURE]
        .iter()
        .map(|s| s.to_string())
        .chain(std::iter::once(folder::temp_name(SIGNATURE)))
        .chain(doc.spots.iter().map(|s| s.folder.clone()))
        .collect();
    if let Ok(names) = folder::entries(dir) {
        for name in names.into_iter().filter(|n| !expected.contains(n)) {
            problems.push(Finding {
                file: dir.join(&name),
                line: None,
                message: format!("not part of the sheet ({SHEET} lists no such spot)"),
            });
        }
    }
    let mut verified = Vec::new();
    let mut spots = Vec::new();
    for entry in &doc.spots {
        let spot_dir = dir.join(&entry.folder);
        match verify(&spot_dir, draw) {
            Ok(v) => {
                // The spot as the sheet reads it, from the documents just verified.
                let calibration = Ok(v.calibration.clone());
                match spot_from(&spot_dir, entry.number, v.doc.clone(), calibration) {
                    Ok(spot) => spots.push(spot),
                    Err(problem) => problems.push(problem),
                }
                verified.push(v);
            }
            Err(found) => problems.extend(found),
        }
    }
    if !problems.is_empty() {
        return Err(problems);
    }
    require_finished_sheet(dir, &doc).map_err(|p| vec![p])?;
    let sheet = assemble(dir, doc, spots);
    let recorded = sheet.doc.result.as_ref().map(|r| &r.summary);
    // A sheet written before the answer was recorded is checked on what it recorded.
    let mut computed = sheet.summary.clone();
    if !sheet.doc.records_answer() {
        computed.answer = None;
    }
    if recorded != Some(&computed) {
        return Err(vec![Finding {
            file: dir.join(SHEET),
            line: None,
            message: "its result is not the one its spots give".into(),
        }]);
    }
    if let Some(problem) = check_report(dir, &ReadFolder::Sheet(&sheet), draw) {
        return Err(vec![problem]);
    }
    Ok(VerifiedSheet {
        sheet,
        spots: verified,
        identity,
        signed,
    })
}

/// Whether the folder's `report.html`, if it has one, is the report its files give
/// (`read`: the folder as read).
pub(crate) fn check_report<E: std::fmt::Display>(
    dir: &Path,
    read: &ReadFolder,
    draw: DrawReport<E>,
) -> Option<Finding> {
    let path = dir.join(REPORT);
    let recorded = std::fs::read(&path).ok()?;
    let problem = |message: String| Finding {
        file: path.clone(),
        line: None,
        message,
    };
    match draw(read) {
        Ok(drawn) if drawn.as_bytes() == recorded.as_slice() => None,
        Ok(_) => Some(problem(format!(
            "is not the report of this folder's files (changed, or drawn by another gonio version): redraw it with gonio report {}",
            dir.display()
        ))),
        Err(e) => Some(problem(format!("cannot be checked: {e}"))),
    }
}
