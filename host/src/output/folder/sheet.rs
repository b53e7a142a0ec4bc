//! The folder of a sheet measured at several spots (`gonio measure --spots N`, N ≥ 2):
//!
//! | file | what | written |
//! |---|---|---|
//! | `sheet.json` | sample, the spots planned, every spot started (its folder), the decisions, and at the end the sheet's result | replaced atomically, before each spot and at the end |
//! | `spot-1/`, `spot-2/`, … | one whole session folder per spot ([`crate::output::folder`]): each verifies on its own | as a session folder |
//! | `MANIFEST.sha256` | the SHA-256 of `sheet.json` and of every spot's `MANIFEST.sha256` (`sha256sum -c` checks it) | last, atomically |
//!
//! Spot 1's folder holds the calibration taken; every later spot's holds the same one
//! (it was reused), so each spot folder stands alone. A kill at any write leaves a folder
//! `gonio measure --resume` continues: finished spots are kept, an unfinished spot is
//! resumed as any session is, and the spots still missing are measured.
use crate::analysis::compare::{SessionResult, session_result};
use crate::analysis::evidence::Sheet;
use crate::analysis::flags::Flag;
use crate::analysis::spots::{self, SheetSummary, SpotResult};
use crate::instrument::calibration::Calibration;
use crate::output::folder::documents::{GlossValue, SpotResultDocument};
use crate::output::folder::lock::{FolderError, FolderLock, io_error};
use crate::output::folder::store::{Store, StoreOptions};
use crate::output::folder::{
    self, Finding, MANIFEST, SESSION, SHEET, SessionDoc, Status, dated_folder_name,
    is_sheet_folder, json_bytes, spot_folder,
};
use serde::{Deserialize, Serialize};
use std::io;
use std::path::{Path, PathBuf};

/// One spot started.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpotEntry {
    /// Its number, from 1, in the order measured.
    pub number: u16,
    /// Its session folder, relative to the sheet's.
    pub folder: String,
}

/// The sheet's result, once its spots are measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SheetResult {
    /// Which spots count, the sheet's mean parameters and their spot-to-spot variation.
    #[serde(flatten)]
    pub summary: SheetSummary,
    /// Device time measuring the spots (their sessions' `device_seconds`), seconds.
    pub device_seconds: f64,
    /// Device time of homing and calibration, and of waiting for the operator to move
    /// the sheet, seconds.
    pub setup_seconds: f64,
    /// Each spot's class, in the order measured (`null`: undecided).
    pub(crate) spot_classes: Vec<Option<String>>,
}

/// `sheet.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SheetDoc {
    /// [`crate::schema::SHEET`] (an older document is read as this version: the two differ
    /// only in this key's name, which was `format`).
    #[serde(alias = "format")]
    pub schema: String,
    /// Where the sheet stands.
    pub status: Status,
    /// Why it stopped, when failed or interrupted.
    pub why: Option<String>,
    /// How to go on, when not finished.
    pub resume_with: Option<String>,
    /// The sample.
    pub sample: String,
    /// Clean spots wanted.
    pub spots_planned: u16,
    /// More spots measured, at most, in place of flagged ones.
    pub(crate) replacements: u16,
    /// Every spot started, in order.
    pub spots: Vec<SpotEntry>,
    /// The sheet's decisions, in order (each spot's own are in its folder).
    pub decisions: Vec<String>,
    /// The result, once finished.
    pub result: Option<SheetResult>,
    /// The case, when given (every spot's `session.json` holds it too).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub case: Option<folder::CaseRecord>,
    /// The sheet's plan, recorded once when it began: every spot, resumed or not, is
    /// measured under it (issue 30 D2: a resume without `--policy` measured the spots still
    /// missing under the default policy). `None` in a sheet written before it was recorded:
    /// spot 1's plan is the sheet's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plan: Option<folder::PlanRecord>,
    /// The version the file was written in (`schema` is the current one once read): a
    /// sheet of `gonio-sheet/2` or before recorded no answer, and its recorded result is
    /// checked without one. Empty for a document made here.
    #[serde(skip)]
    pub(crate) read_as: &'static str,
}

impl SheetDoc {
    /// Whether the file recorded the sheet's answer (written as `gonio-sheet/3` or later,
    /// or made here).
    pub(crate) fn records_answer(&self) -> bool {
        ![crate::schema::SHEET_V1, crate::schema::SHEET_V2].contains(&self.read_as)
    }
}

/// Read `sheet.json` of `dir`.
pub(crate) fn read_doc(dir: &Path) -> Result<SheetDoc, Finding> {
    let file = dir.join(SHEET);
    let problem = |message: String| Finding {
        file: file.clone(),
        line: None,
        message,
    };
    let text = std::fs::read_to_string(&file).map_err(|e| problem(format!("cannot read: {e}")))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| problem(format!("not JSON: {e}")))?;
    const READS: [&str; 3] = [
        crate::schema::SHEET,
        crate::schema::SHEET_V2,
        crate::schema::SHEET_V1,
    ];
    let found = crate::schema::check(&value, &READS, None)
        .map_err(|m| problem(format!("{m}: not a sheet folder of this gonio")))?;
    let version = READS.into_iter().find(|v| *v == found).unwrap_or("");
    let mut doc: SheetDoc =
        serde_json::from_value(value).map_err(|e| problem(format!("not a sheet document: {e}")))?;
    doc.schema = crate::schema::SHEET.into();
    doc.read_as = version;
    for (k, entry) in doc.spots.iter().enumerate() {
        if entry.number as usize != k + 1 || entry.folder != spot_folder(entry.number) {
            return Err(problem(format!(
                "spot entry {} is not spot {} in {}",
                k + 1,
                k + 1,
                spot_folder(k as u16 + 1)
            )));
        }
    }
    Ok(doc)
}

/// Writes a sheet's folder: its `sheet.json` and, at the end, its manifest. The spots'
/// folders are written by their sessions' own recorders.
pub(crate) struct SheetFolder {
    store: Store,
    _lock: FolderLock,
    /// The document as last written.
    pub doc: SheetDoc,
}

/// What a new sheet's first `sheet.json` holds besides its sample and spots.
#[derive(Clone, Debug, Default)]
pub struct SheetStart {
    /// The case fields, when given.
    pub case: Option<folder::CaseRecord>,
    /// The sheet's plan.
    pub plan: Option<folder::PlanRecord>,
}

impl SheetFolder {
    /// Make `dir` (new, or empty) for a new sheet of `sample`, its first `sheet.json`
    /// holding the sheet's case fields and plan (`first`): a sheet killed before its first
    /// spot is resumed under the plan it began with (issue 30).
    pub fn create(
        dir: &Path,
        sample: &str,
        spots_planned: u16,
        replacements: u16,
        first: SheetStart,
        options: StoreOptions,
    ) -> Result<SheetFolder, FolderError> {
        if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(io_error(parent))?;
        }
        // The lock is taken before anything in the folder is looked at or removed: a
        // `gonio measure --out` started at the same moment may have made the folder and be
        // writing its first sheet.json, whose temporary file is not ours to remove (issue
        // 30: removing it made that gonio fail with "No such file or directory").
        let lock = match Store::create_dir(dir, options.clone()) {
            Ok(_) => FolderLock::take(dir)?,
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                if !dir.is_dir() {
                    return Err(FolderError::NotAFolder(dir.to_path_buf()));
                }
                let lock = FolderLock::take(dir)?;
                // A temporary file alone is a first sheet.json a killed gonio left: the
                // folder is as empty as before it.
                let names = folder::entries(dir).map_err(io_error(dir))?;
                let (temp, names): (Vec<String>, Vec<String>) =
                    names.into_iter().partition(|n| folder::is_temp_name(n));
                if names.is_empty() {
                    let mut store = Store::open_dir(dir, options.clone());
                    for name in temp {
                        store.remove(&name).map_err(io_error(dir))?;
                    }
                } else {
                    let shown: Vec<&str> = names.iter().take(3).map(String::as_str).collect();
                    return Err(FolderError::NotEmpty {
                        dir: dir.to_path_buf(),
                        entries: shown.join(", "),
                    });
                }
                lock
            }
            Err(e) => {
                return Err(FolderError::Io {
                    dir: dir.to_path_buf(),
                    source: e,
                });
            }
        };
        let doc = SheetDoc {
            schema: crate::schema::SHEET.into(),
            status: Status::Running,
            why: None,
            resume_with: None,
            sample: sample.to_string(),
            spots_planned,
            replacements,
            spots: Vec::new(),
            decisions: Vec::new(),
            result: None,
            case: first.case,
            plan: first.plan,
            read_as: "",
        };
        let mut folder = SheetFolder {
            store: Store::open_dir(dir, options),
            _lock: lock,
            doc,
        };
        folder.write().map_err(io_error(dir))?;
        Ok(folder)
    }

    /// A new folder `PARENT/<local date-time>-<sample>` (a suffix when taken).
    pub fn create_default(
        parent: &Path,
        sample: &str,
        spots_planned: u16,
        replacements: u16,
        first: SheetStart,
        options: StoreOptions,
    ) -> Result<SheetFolder, FolderError> {
        std::fs::create_dir_all(parent).map_err(io_error(parent))?;
        let base = dated_folder_name(sample);
        for k in 1..10_000 {
            let dir = parent.join(if k == 1 {
                base.clone()
            } else {
                format!("{base}-{k}")
            });
            if !dir.exists() {
                match SheetFolder::create(
                    &dir,
                    sample,
                    spots_planned,
                    replacements,
                    first.clone(),
                    options.clone(),
                ) {
                    // Another gonio made this folder since: take the next name.
                    Err(FolderError::InUse(_) | FolderError::NotEmpty { .. }) => continue,
                    other => return other,
                }
            }
        }
        Err(FolderError::Io {
            dir: parent.join(base),
            source: io::Error::other("10 000 sheets of this sample in one second"),
        })
    }

    /// Open the sheet folder `dir` to continue it: refuses a missing folder, one in use, a
    /// damaged `sheet.json`, or a finished sheet (whose manifest is written first when a
    /// crash kept it from being written).
    pub fn open(dir: &Path, options: StoreOptions) -> Result<SheetFolder, FolderError> {
        if !dir.exists() {
            return Err(FolderError::NoFolder(dir.to_path_buf()));
        }
        let lock = FolderLock::take(dir)?;
        folder::refuse_links(dir).map_err(FolderError::Damaged)?;
        let mut store = Store::open_dir(dir, options);
        // A temporary file is a replacement of sheet.json that a kill cut short.
        for name in folder::entries(dir).map_err(io_error(dir))? {
            if folder::is_temp_name(&name) {
                store.remove(&name).map_err(io_error(dir))?;
            }
        }
        let doc = read_doc(dir).map_err(FolderError::Damaged)?;
        let mut folder = SheetFolder {
            store,
            _lock: lock,
            doc,
        };
        if folder.doc.status == Status::Finished {
            if !dir.join(MANIFEST).exists() {
                folder.write_manifest().map_err(io_error(dir))?;
            } else {
                // Killed between the manifest and its signature.
                let whole = manifest_text(dir, &folder.doc).is_ok_and(|now| {
                    std::fs::read_to_string(dir.join(MANIFEST)).is_ok_and(|m| m == now)
                });
                crate::output::folder::signature::sign_if_unsigned(&mut folder.store, whole)
                    .map_err(io_error(dir))?;
            }
            return Err(FolderError::FinishedSheet {
                dir: dir.to_path_buf(),
                sample: folder.doc.sample.clone(),
                spots: folder.doc.spots.len(),
            });
        }
        Ok(folder)
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        self.store.dir()
    }

    fn write(&mut self) -> io::Result<()> {
        let bytes = json_bytes(&self.doc)?;
        self.store.replace(SHEET, &bytes)
    }

    /// Status running, and how to go on if this run stops.
    pub(crate) fn start_run(&mut self, resume_with: String) -> io::Result<()> {
        self.doc.status = Status::Running;
        self.doc.why = None;
        self.doc.resume_with = Some(resume_with);
        self.write()
    }

    /// Spot `number` begins: recorded before its folder is made, so a resume finds it.
    pub(crate) fn start_spot(&mut self, number: u16) -> io::Result<PathBuf> {
        if !self.doc.spots.iter().any(|s| s.number == number) {
            self.doc.spots.push(SpotEntry {
                number,
                folder: spot_folder(number),
            });
            self.write()?;
        }
        Ok(self.dir().join(spot_folder(number)))
    }

    /// A decision of the sheet (kept in `sheet.json` at the next write).
    pub fn decision(&mut self, text: &str) {
        self.doc.decisions.push(text.to_string());
    }

    /// The sheet is measured: its result, then the manifest.
    pub fn finish(&mut self, result: SheetResult) -> io::Result<()> {
        self.doc.result = Some(result);
        self.doc.status = Status::Finished;
        self.doc.why = None;
        self.doc.resume_with = None;
        self.write()?;
        self.write_manifest()
    }

    /// The sheet stopped (`status` failed or interrupted), and why.
    pub fn stop(&mut self, status: Status, why: &str) -> io::Result<()> {
        self.doc.status = status;
        self.doc.why = Some(why.to_string());
        self.write()
    }

    fn write_manifest(&mut self) -> io::Result<()> {
        let text = manifest_text(self.store.dir(), &self.doc)?;
        self.store.replace(MANIFEST, text.as_bytes())?;
        crate::output::folder::signature::sign_manifest(&mut self.store, text.as_bytes())
    }
}

/// The sheet's manifest: `sheet.json` and every spot's manifest, in `sha256sum` format.
pub fn manifest_text(dir: &Path, doc: &SheetDoc) -> io::Result<String> {
    let mut names = vec![SHEET.to_string()];
    names.extend(doc.spots.iter().map(|s| format!("{}/{MANIFEST}", s.folder)));
    let mut text = String::new();
    for name in names {
        text += &format!(
            "{}  {name}\n",
            crate::output::folder::manifest::sha256_hex(&std::fs::read(dir.join(&name))?)
        );
    }
    Ok(text)
}

/// A finished spot of a sheet, read back from its folder.
#[derive(Clone, Debug, PartialEq)]
pub struct ReadSpot {
    /// Its folder.
    pub dir: PathBuf,
    /// Its `session.json` as the comparison reads it.
    pub session: SessionResult,
    /// What it contributes to the sheet.
    pub result: SpotResult,
    /// Its session's device seconds measuring, and homing-and-calibration seconds.
    pub seconds: (f64, f64),
    /// Its session's `result` (all absent when it cannot be read as one).
    pub document: SpotResultDocument,
    /// Its `session.json`, as read (the report is drawn from it).
    pub doc: SessionDoc,
    /// Its `calibration.json` as read: the report says when it cannot be read.
    pub calibration: Result<Option<Calibration>, Finding>,
}

/// Read a finished spot folder's result.
pub(crate) fn read_spot(dir: &Path, number: u16) -> Result<ReadSpot, Finding> {
    let doc = folder::require_finished(dir)?;
    spot_from(dir, number, doc, folder::read_calibration(dir))
}

/// The spot `number` of a sheet from its folder's documents, already read (by
/// [`read_spot`], or by the verification that checked them).
pub(crate) fn spot_from(
    dir: &Path,
    number: u16,
    doc: SessionDoc,
    calibration: Result<Option<Calibration>, Finding>,
) -> Result<ReadSpot, Finding> {
    let file = dir.join(SESSION);
    let problem = |message: String| Finding {
        file: file.clone(),
        line: None,
        message,
    };
    let session = serde_json::to_value(&doc)
        .map_err(|e| problem(e.to_string()))
        .and_then(|v| session_result(&file, &v).map_err(|e| problem(e.to_string())))?;
    let outcome = doc.outcome();
    let flags: Vec<Flag> = outcome
        .flags
        .transpose()
        .map_err(|e| problem(format!("flags: {e}")))?
        .unwrap_or_default();
    // Seconds a session did not record (or not as numbers) count as none.
    let result = outcome.result.and_then(Result::ok).unwrap_or_default();
    let seconds = (
        result.device_seconds.unwrap_or(0.0),
        result.setup_seconds.unwrap_or(0.0),
    );
    Ok(ReadSpot {
        dir: dir.to_path_buf(),
        seconds,
        document: result,
        result: SpotResult {
            number,
            flags,
            spot: session.spot(),
            shape_widening: session.shape_widening,
            class: session.class.clone(),
        },
        session,
        doc,
        calibration,
    })
}

/// A finished sheet folder, read back.
#[derive(Clone, Debug, PartialEq)]
pub struct ReadSheet {
    /// Its folder.
    pub dir: PathBuf,
    /// `sheet.json`.
    pub doc: SheetDoc,
    /// Every spot measured, in order.
    pub spots: Vec<ReadSpot>,
    /// The result recomputed from the spots (it must be the recorded one).
    pub summary: SheetSummary,
}

impl ReadSheet {
    /// The accepted spots, as the evidence weighs the sheet.
    pub fn sheet(&self) -> Sheet {
        self.summary.sheet(&self.results())
    }

    /// The accepted spots as their sessions reported them.
    pub fn reported(&self) -> Sheet {
        self.summary.reported(&self.results())
    }

    /// Every spot's result.
    fn results(&self) -> Vec<SpotResult> {
        self.spots.iter().map(|s| s.result.clone()).collect()
    }

    /// Its spots counted: planned, measured, accepted, flagged.
    pub fn counts(&self) -> crate::analysis::spots::SpotCounts {
        crate::analysis::spots::SpotCounts::of(self.doc.spots_planned, &self.summary, |n| {
            self.spots
                .iter()
                .find(|s| s.result.number == n)
                .map(|s| s.result.flags.clone())
                .unwrap_or_default()
        })
    }
}

/// Read the finished sheet folder `dir`: `sheet.json` and every spot's result.
pub(crate) fn read_sheet(dir: &Path) -> Result<ReadSheet, Finding> {
    let doc = read_doc(dir)?;
    require_finished_sheet(dir, &doc)?;
    let spots = doc
        .spots
        .iter()
        .map(|s| read_spot(&dir.join(&s.folder), s.number))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(assemble(dir, doc, spots))
}

/// The sheet of `dir` from its `sheet.json` and its spots, already read: its result
/// computed from the spots.
pub(crate) fn assemble(dir: &Path, doc: SheetDoc, spots: Vec<ReadSpot>) -> ReadSheet {
    let results: Vec<SpotResult> = spots.iter().map(|s| s.result.clone()).collect();
    let summary = spots::assess(doc.spots_planned, &results);
    ReadSheet {
        dir: dir.to_path_buf(),
        doc,
        spots,
        summary,
    }
}

/// A sheet that must be finished (to report, verify or weigh it), and how to continue it
/// when it is not.
pub(crate) fn require_finished_sheet(dir: &Path, doc: &SheetDoc) -> Result<(), Finding> {
    if doc.status != Status::Finished {
        let how = doc
            .resume_with
            .clone()
            .unwrap_or_else(|| format!("gonio measure --resume {}", dir.display()));
        return Err(Finding {
            file: dir.join(SHEET),
            line: None,
            message: format!(
                "status is {}: the sheet is not finished (continue it with {how})",
                doc.status
            ),
        });
    }
    Ok(())
}

/// A finished folder as read once, handed to what draws its report (verification reads
/// a folder to check it, then hands what it read to the drawing of `report.html`).
pub enum ReadFolder<'a> {
    /// A session folder (one spot).
    Session {
        /// The folder.
        dir: &'a Path,
        /// Its `session.json`.
        doc: &'a SessionDoc,
        /// Its `calibration.json` (`None`: there is none; the error: it cannot be read).
        calibration: Result<Option<&'a Calibration>, &'a Finding>,
    },
    /// A sheet folder.
    Sheet(&'a ReadSheet),
}

/// A measured sheet as `gonio compare` and `gonio library` read it: a sheet folder (its
/// accepted spots), or a session of one spot (its folder or `session.json`).
#[derive(Clone, Debug, PartialEq)]
pub struct MeasuredSheet {
    /// What was read (the folder, or the `session.json`).
    pub path: PathBuf,
    /// The sample.
    pub sample: String,
    /// Each accepted spot's class (`None`: undecided).
    pub classes: Vec<Option<String>>,
    /// The accepted spots, as the evidence weighs them ([`crate::analysis::evidence::Spot::weighed`]).
    pub sheet: Sheet,
    /// The accepted spots as their sessions reported them: the sheet's own intervals.
    pub reported: Sheet,
    /// The sheet's result when it is a sheet folder; `None` for a session of one spot.
    pub summary: Option<SheetSummary>,
    /// Its result's flags (empty: clean).
    pub flags: Vec<String>,
    /// Its folder's identity: the SHA-256 of its `MANIFEST.sha256`, when it has one.
    pub identity: Option<String>,
    /// The instrument's serial number.
    pub instrument: Option<String>,
    /// The case, when given.
    pub case: Option<folder::CaseRecord>,
    /// Each accepted spot's gloss (`None`: none computed, no instrument profile being in
    /// force).
    pub gloss: Vec<Option<Vec<GlossValue>>>,
}

/// What a measured folder says of where it came from: its identity (its manifest's
/// SHA-256), its instrument and its case; each `None` when the file does not say.
fn provenance(dir: &Path) -> (Option<String>, Option<String>, Option<folder::CaseRecord>) {
    let identity = std::fs::read(dir.join(folder::MANIFEST))
        .ok()
        .map(|bytes| crate::output::folder::manifest::sha256_hex(&bytes));
    #[derive(serde::Deserialize)]
    struct Head {
        instrument: Option<folder::InstrumentRecord>,
        case: Option<folder::CaseRecord>,
    }
    let head: Option<Head> = std::fs::read_to_string(dir.join(SESSION))
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok());
    let (instrument, case) = head.map_or((None, None), |h| {
        (h.instrument.map(|i| i.serial_number), h.case)
    });
    (identity, instrument, case)
}

impl MeasuredSheet {
    /// The sheet as the evidence weighs it, with its flags, folder identity and instrument
    /// (what the warnings need).
    pub fn questioned(&self) -> crate::analysis::evidence::Questioned {
        crate::analysis::evidence::Questioned {
            sheet: self.sheet.clone(),
            flags: self.flags.clone(),
            identity: self.identity.clone(),
            instrument: self.instrument.clone(),
        }
    }

    /// The classes of its spots in words ("G", "G, G, SG", "undecided").
    pub fn class_text(&self) -> String {
        let names: Vec<&str> = self
            .classes
            .iter()
            .map(|c| c.as_deref().unwrap_or("undecided"))
            .collect();
        if names.is_empty() {
            "undecided".to_string()
        } else {
            names.join(", ")
        }
    }
}

/// Why a measured sheet cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum MeasuredError {
    /// A sheet folder that cannot be read (or is not finished).
    #[error("{0}")]
    Sheet(#[from] Finding),
    /// A session folder or `session.json` that cannot be read as a result.
    #[error("{0}")]
    Session(#[from] crate::analysis::compare::CompareError),
}

/// Read a sheet folder, a session folder or a `session.json`. A sheet folder must be
/// finished; its result is recomputed from its spots' files.
pub fn read_measured(path: &Path) -> Result<MeasuredSheet, MeasuredError> {
    if is_sheet_folder(path) {
        let read = read_sheet(path)?;
        let (sheet, reported) = (read.sheet(), read.reported());
        let accepted = |n: u16| {
            read.summary
                .verdicts
                .iter()
                .any(|j| j.number == n && j.verdict == spots::SpotVerdict::Accepted)
        };
        let classes = read
            .spots
            .iter()
            .filter(|s| accepted(s.result.number))
            .map(|s| s.session.class.clone())
            .collect();
        let (identity, _, case) = provenance(path);
        let instrument = read
            .spots
            .first()
            .map(|s| s.doc.instrument.serial_number.clone());
        let flags = read.summary.flags.iter().map(|f| f.to_string()).collect();
        let gloss = read
            .spots
            .iter()
            .filter(|s| accepted(s.result.number))
            .map(|s| s.document.gloss.clone())
            .collect();
        return Ok(MeasuredSheet {
            gloss,
            path: path.to_path_buf(),
            sample: read.doc.sample.clone(),
            classes,
            sheet,
            reported,
            summary: Some(read.summary),
            flags,
            identity,
            instrument,
            case: read.doc.case.clone().or(case),
        });
    }
    let session = crate::analysis::compare::read_session(path)?;
    let dir = session.file.parent().unwrap_or(Path::new("."));
    let (identity, instrument, case) = provenance(dir);
    // The spot's gloss, read on its own: a session whose result has none (or none readable)
    // has none.
    let gloss = std::fs::read_to_string(&session.file)
        .ok()
        .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
        .and_then(|mut v| serde_json::from_value(v["result"]["gloss"].take()).ok())
        .flatten();
    Ok(MeasuredSheet {
        gloss: vec![gloss],
        path: session.file.clone(),
        sample: session.sample.clone(),
        classes: vec![session.class.clone()],
        sheet: session.sheet(),
        reported: Sheet {
            spots: vec![session.spot()],
        },
        summary: None,
        flags: session.flags.clone(),
        identity,
        instrument,
        case,
    })
}
