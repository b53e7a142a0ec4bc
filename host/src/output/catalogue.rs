//! The sessions under a folder (`gonio sessions [ROOT]`): each session or sheet folder
//! with its date, sample, class, state and device time, read from its own documents.
use crate::output::folder::{SESSION, SessionDoc, Status};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// The folder to list cannot be listed.
#[derive(Debug, thiserror::Error)]
#[error("{}: {source}", .root.display())]
pub struct CatalogueError {
    /// The folder.
    pub root: PathBuf,
    /// Why.
    pub source: std::io::Error,
}

/// One session or sheet folder.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Entry {
    /// The folder.
    pub dir: PathBuf,
    /// `session` (one spot) or `sheet` (several).
    pub kind: &'static str,
    /// When its first run started (local RFC 3339).
    pub started: Option<String>,
    /// The sample.
    pub sample: String,
    /// Where it stands (`finished`, `interrupted`, …).
    pub status: String,
    /// The class of each spot (one for a session); `None`: undecided or not finished.
    pub classes: Vec<Option<String>>,
    /// Clean, when finished.
    pub ok: Option<bool>,
    /// Its flags, when finished.
    pub flags: Vec<String>,
    /// Device seconds measuring, when finished.
    pub device_seconds: Option<f64>,
    /// What could not be read, when something could not.
    pub problem: Option<String>,
}

fn session_doc(dir: &Path) -> Result<SessionDoc, crate::output::folder::Finding> {
    crate::output::folder::require_session(dir)
}

fn session_entry(dir: &Path) -> Entry {
    let mut entry = Entry {
        dir: dir.to_path_buf(),
        kind: "session",
        started: None,
        sample: String::new(),
        status: "unreadable".into(),
        classes: Vec::new(),
        ok: None,
        flags: Vec::new(),
        device_seconds: None,
        problem: None,
    };
    match session_doc(dir) {
        Ok(doc) => {
            entry.started = doc.runs.first().map(|r| r.started.clone());
            entry.sample = doc.sample.clone();
            entry.status = doc.status.to_string();
            if doc.status == Status::Finished {
                let outcome = doc.outcome();
                let result = outcome.result();
                entry.classes = vec![result.and_then(|r| r.class()).map(str::to_string)];
                entry.ok = outcome.ok();
                entry.flags = outcome
                    .flags()
                    .unwrap_or_default()
                    .iter()
                    .map(|f| f.name().to_string())
                    .collect();
                entry.device_seconds = result.and_then(|r| r.device_seconds);
            }
        }
        Err(e) => entry.problem = Some(e.to_string()),
    }
    entry
}

fn sheet_entry(dir: &Path) -> Entry {
    let mut entry = Entry {
        dir: dir.to_path_buf(),
        kind: "sheet",
        started: None,
        sample: String::new(),
        status: "unreadable".into(),
        classes: Vec::new(),
        ok: None,
        flags: Vec::new(),
        device_seconds: None,
        problem: None,
    };
    match crate::output::folder::sheet::read_doc(dir) {
        Ok(doc) => {
            entry.sample = doc.sample.clone();
            entry.status = doc.status.to_string();
            entry.started = doc
                .spots
                .first()
                .and_then(|s| session_doc(&dir.join(&s.folder)).ok())
                .and_then(|d| d.runs.first().map(|r| r.started.clone()));
            if let Some(result) = &doc.result {
                entry.classes = result.spot_classes.clone();
                entry.ok = Some(result.summary.ok());
                entry.flags = result
                    .summary
                    .flags
                    .iter()
                    .map(|f| f.name().to_string())
                    .collect();
                entry.device_seconds = Some(result.device_seconds);
            }
        }
        Err(p) => entry.problem = Some(p.to_string()),
    }
    entry
}

/// The session and sheet folders directly under `root`, oldest first (by their first
/// run's start, then name); a folder that is neither is left out. When `root` is itself a
/// session folder, it is the list; a sheet folder comes first, then its spots (issue 31:
/// `gonio sessions SHEET` said "no session or sheet folders" of a folder that is one).
pub fn list(root: &Path) -> Result<Vec<Entry>, CatalogueError> {
    let itself = if crate::output::folder::is_sheet_folder(root) {
        Some(sheet_entry(root))
    } else if root.join(SESSION).is_file() {
        return Ok(vec![session_entry(root)]);
    } else {
        None
    };
    let mut out = under(root)?;
    if let Some(sheet) = itself {
        out.insert(0, sheet);
    }
    Ok(out)
}

/// The session and sheet folders directly under `root`, oldest first.
fn under(root: &Path) -> Result<Vec<Entry>, CatalogueError> {
    let names = crate::output::folder::entries(root).map_err(|source| CatalogueError {
        root: root.to_path_buf(),
        source,
    })?;
    let mut out: Vec<Entry> = names
        .iter()
        .map(|n| root.join(n))
        .filter_map(|dir| {
            if crate::output::folder::is_sheet_folder(&dir) {
                Some(sheet_entry(&dir))
            } else if dir.join(SESSION).is_file() {
                Some(session_entry(&dir))
            } else {
                None
            }
        })
        .collect();
    out.sort_by(|a, b| (&a.started, &a.dir).cmp(&(&b.started, &b.dir)));
    Ok(out)
}
