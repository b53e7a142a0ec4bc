//! A finished session or sheet folder read into the library's [`SheetRecord`], after it is
//! checked as `gonio verify` checks it.
use super::{LibraryError, Result, SheetRecord, check_spot, now_utc};
use std::path::Path;

/// Read a finished sheet folder (`gonio measure --spots N`: its accepted spots) or session
/// folder (one spot), after checking it as `gonio verify` does (every file against the
/// manifest, the records against each other). A flagged result (`ok: false`) is refused
/// unless `allow_flagged`.
pub fn read_session_folder(
    dir: &Path,
    lot: Option<&str>,
    allow_flagged: bool,
) -> Result<SheetRecord> {
    if crate::output::folder::is_sheet_folder(dir) {
        return read_sheet_folder(dir, lot, allow_flagged);
    }
    read_spot_folder(dir, lot, allow_flagged)
}

fn read_sheet_folder(dir: &Path, lot: Option<&str>, allow_flagged: bool) -> Result<SheetRecord> {
    let bad = |what: String| LibraryError::BadSession {
        dir: dir.to_path_buf(),
        what,
    };
    let verified = crate::output::folder::verify::verify_sheet(dir, crate::output::report::draw)
        .map_err(|problems| not_verified(dir, &problems))?;
    let read = &verified.sheet;
    if !read.summary.ok() && !allow_flagged {
        let flags: Vec<&str> = read.summary.flags.iter().map(|f| f.name()).collect();
        return Err(LibraryError::Flagged {
            dir: dir.to_path_buf(),
            flags: format!("{flags:?}"),
        });
    }
    let sheet = read.sheet();
    for (k, spot) in sheet.spots.iter().enumerate() {
        check_spot(spot).map_err(|e| bad(format!("spot {k}: {e}")))?;
    }
    let first = read
        .spots
        .first()
        .ok_or_else(|| bad("a sheet without spots".into()))?;
    Ok(SheetRecord {
        lot: lot.map(str::to_string),
        measured_at: first.doc.runs.first().map(|r| r.started.clone()),
        instrument_serial: first.doc.instrument.serial_number.clone(),
        session_path: dir.display().to_string(),
        session_sha256: verified.identity.clone(),
        sample: read.doc.sample.clone(),
        // The sheet's case, else its first spot's (every spot's session.json holds it too).
        lay: read
            .doc
            .case
            .as_ref()
            .or(first.doc.case.as_ref())
            .map(crate::output::folder::CaseRecord::lay)
            .unwrap_or_default(),
        added_at: now_utc(),
        spots: sheet.spots,
    })
}

/// A folder that does not verify, with every finding on its own line.
fn not_verified(dir: &Path, problems: &[crate::output::folder::Finding]) -> LibraryError {
    let lines: Vec<String> = problems.iter().map(|p| format!("\n  {p}")).collect();
    LibraryError::BadSession {
        dir: dir.to_path_buf(),
        what: format!(
            "it does not verify (gonio verify {}):{}",
            dir.display(),
            lines.concat()
        ),
    }
}

fn read_spot_folder(dir: &Path, lot: Option<&str>, allow_flagged: bool) -> Result<SheetRecord> {
    let bad = |what: String| LibraryError::BadSession {
        dir: dir.to_path_buf(),
        what,
    };
    let verified = crate::output::folder::verify::verify(dir, crate::output::report::draw)
        .map_err(|problems| not_verified(dir, &problems))?;
    let doc = verified.doc;
    let file = dir.join(crate::output::folder::SESSION);
    let outcome = doc.outcome();
    let ok = outcome
        .ok()
        .ok_or_else(|| bad(format!("{}: no boolean 'ok'", file.display())))?;
    if !ok && !allow_flagged {
        // As the document writes them (a JSON array of their names).
        let flags = match &outcome.flags {
            None => "no flags recorded".to_string(),
            Some(Ok(flags)) => serde_json::to_string(flags).unwrap_or_default(),
            Some(Err(e)) => format!("unreadable flags ({e})"),
        };
        return Err(LibraryError::Flagged {
            dir: dir.to_path_buf(),
            flags,
        });
    }
    // The result as the comparison reads it, from the document verified.
    let value = serde_json::to_value(&doc).map_err(|e| bad(e.to_string()))?;
    let result =
        crate::analysis::compare::session_result(&file, &value).map_err(|e| bad(e.to_string()))?;
    // The library feeds the evidence alone: its spots are stored as the evidence weighs
    // them, so a library's pairs are weighed as a questioned pair is.
    let spot = result.weighed_spot();
    check_spot(&spot).map_err(|e| bad(e.to_string()))?;
    Ok(SheetRecord {
        lot: lot.map(str::to_string),
        measured_at: doc.runs.first().map(|r| r.started.clone()),
        instrument_serial: doc.instrument.serial_number,
        session_path: dir.display().to_string(),
        session_sha256: verified.identity,
        lay: doc
            .case
            .as_ref()
            .map(crate::output::folder::CaseRecord::lay)
            .unwrap_or_default(),
        sample: doc.sample,
        added_at: now_utc(),
        spots: vec![spot],
    })
}

/// The other folders that measured the same sheet as `dir`, as (identity, folder): a sheet
/// folder's spot folders, or the sheet folder a spot folder lies in. The library counts a
/// sheet once: a spot of a sheet already in it (or the sheet of a spot already in it)
/// would weigh the same paper twice as two sheets. The identity is the SHA-256 of the
/// folder's manifest, as [`read_session_folder`] gives it; folders without a manifest are
/// left out (they cannot be in the library).
pub fn same_sheet_folders(dir: &Path) -> Vec<(String, std::path::PathBuf)> {
    let identity = |folder: &Path| {
        std::fs::read(folder.join(crate::output::folder::MANIFEST))
            .ok()
            .map(|bytes| {
                (
                    crate::output::folder::manifest::sha256_hex(&bytes),
                    folder.to_path_buf(),
                )
            })
    };
    if crate::output::folder::is_sheet_folder(dir) {
        let Ok(names) = crate::output::folder::entries(dir) else {
            return Vec::new();
        };
        return names
            .iter()
            .map(|name| dir.join(name))
            .filter(|p| p.is_dir())
            .filter_map(|p| identity(&p))
            .collect();
    }
    let parent = match dir.canonicalize() {
        Ok(d) => d.parent().map(Path::to_path_buf),
        Err(_) => None,
    };
    parent
        .filter(|p| crate::output::folder::is_sheet_folder(p))
        .and_then(|p| identity(&p))
        .into_iter()
        .collect()
}
