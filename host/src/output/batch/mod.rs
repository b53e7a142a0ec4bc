//! The folder of a QA batch (`gonio batch`): sheets of one stock measured one after the
//! other and judged against a master stock of the library.
//!
//! | file | what | written |
//! |---|---|---|
//! | `batch.json` | the plan, the master's values and the tolerances (fixed when the batch began), every sheet measured with its values and verdict, the statistics across the sheets | replaced atomically after each sheet and at the end |
//! | `sheet-01/`, `sheet-02/`, … | one sheet folder per sheet (a session folder with one spot): each verifies, reports and resumes on its own | as a sheet or session folder |
//! | `batch.csv` | one row per sheet, units in the headers: for a spreadsheet | with `batch.json` |
//! | `batch.html` | the batch report a person reads | with `batch.json` |
//! | `batch.lock` | who holds the batch (process, command, since when) while a `gonio batch` runs in it | when it takes the folder; removed when it lets go |
//!
//! The master and the tolerances are recorded when the batch begins, so a batch resumed
//! after the library changed is still judged as it began; a sheet is judged from its own
//! folder's files (read back, as `gonio compare` reads them).
//!
//! One `gonio batch` at a time in a folder: [`BatchLock`] (an advisory lock on the folder,
//! as a session folder's) refuses a second, naming the folder and the one that holds it.
mod report;

use crate::analysis::batch::{
    self, GlossJudgement, GlossSpec, Master, Named, SheetGloss, SpotGloss, SpotValues, Statistics,
    Verdict,
};
use crate::analysis::flags::Flag;
use crate::output::folder::lock::{FolderError, FolderLock};
use crate::output::folder::sheet::read_measured;
use crate::output::folder::{SESSION, Status};
use crate::output::library::{Library, Location, OpenMode};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// `batch.json`.
pub const BATCH: &str = "batch.json";
/// `batch.csv`.
pub const BATCH_CSV: &str = "batch.csv";
/// `batch.html`.
pub const BATCH_HTML: &str = "batch.html";
/// `batch.lock`: who holds the folder.
pub const BATCH_LOCK: &str = "batch.lock";

/// Why a batch cannot be begun, continued or written.
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    /// The library cannot be read.
    #[error(transparent)]
    Library(#[from] crate::output::library::LibraryError),
    /// The library holds no stock of that name.
    #[error("{library}: no stock '{stock}' in the library{}", hint(known))]
    UnknownStock {
        /// The library.
        library: Location,
        /// The stock asked for.
        stock: String,
        /// The stocks it holds.
        known: Vec<String>,
    },
    /// The master's sheets determine nothing.
    #[error("{library}: {source}")]
    Master {
        /// The library.
        library: Location,
        /// What is wrong.
        source: batch::MasterError,
    },
    /// A file of the batch folder cannot be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// `batch.json` is not a batch document of this gonio.
    #[error("{}: {why}", path.display())]
    NotABatch {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        why: String,
    },
    /// Another process runs a batch in the folder.
    #[error(
        "{} is in use by another gonio batch ({holder}): one batch, one process; nothing in the folder was changed (when that one has ended, gonio batch --resume {} continues the batch)",
        .dir.display(), .dir.display()
    )]
    InUse {
        /// The batch folder.
        dir: PathBuf,
        /// Who holds it, as its `batch.lock` says.
        holder: String,
    },
    /// A measured sheet's folder cannot be read back.
    #[error("{}: {why}", path.display())]
    Sheet {
        /// Its folder.
        path: PathBuf,
        /// What is wrong.
        why: String,
    },
}

fn hint(known: &[String]) -> String {
    if known.is_empty() {
        " (the library has no stock: gonio library add --stock NAME SHEET… adds the master's sheets)"
            .to_string()
    } else {
        format!(
            " (it holds: {}; gonio library list shows them)",
            known
                .iter()
                .map(|k| crate::text::shown_at_most(k, 60))
                .collect::<Vec<_>>()
                .join(", ")
        )
    }
}

/// The master stock `stock` of the library at `path`: its sheets' values and spread.
pub fn master_from_library(path: &Location, stock: &str) -> Result<Master, BatchError> {
    let library = Library::open(path, OpenMode::Existing)?;
    let sheets: Vec<Vec<SpotValues>> = library
        .sheets()?
        .into_iter()
        .filter(|(_, s)| s.stock == stock)
        .map(|(_, s)| {
            s.sheet
                .spots
                .iter()
                .map(|spot| SpotValues {
                    values: spot.values,
                    uncertainties: std::array::from_fn(|i| {
                        let v = spot.covariance[i][i];
                        (v.is_finite() && v >= 0.0).then(|| v.sqrt())
                    }),
                })
                .collect()
        })
        .collect();
    if sheets.is_empty() {
        let mut known: Vec<String> = library.stocks()?.into_iter().map(|s| s.name).collect();
        known.truncate(20);
        return Err(BatchError::UnknownStock {
            library: path.clone(),
            stock: stock.to_string(),
            known,
        });
    }
    Master::of_sheets(stock, &sheets).map_err(|source| BatchError::Master {
        library: path.clone(),
        source,
    })
}

/// What the batch measures, as it began.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BatchPlan {
    /// Sheets to measure.
    pub sheets: u16,
    /// Clean spots per sheet.
    pub spots: u16,
    /// The sample's name (every sheet's).
    pub sample: String,
    /// The simulated paper, when on the simulator.
    pub sim: Option<String>,
    /// The simulator's seed of sheet 1 (sheet k's is this + k − 1), when on the simulator.
    pub sim_seed: Option<u64>,
    /// The simulated sheets' spread about the paper (log-normal, relative sd, percent),
    /// when on the simulator.
    pub sheet_to_sheet_pct: Option<f64>,
    /// The library the master was read from.
    pub library: String,
    /// Every sheet's refinement policy (`paper`, `adaptive`, `sweep`, `mixed`): a batch is
    /// measured under one procedure, so a resume that would change it is refused. `null`
    /// in a batch written before it was recorded (its sheets' own plans say).
    #[serde(default)]
    pub policy: Option<String>,
    /// The gloss specifications every sheet is judged against besides the master
    /// (`--gloss-spec`; empty: gloss is not judged; a `gonio-batch/2` batch has none).
    #[serde(default)]
    pub gloss_spec: Vec<GlossSpec>,
    /// The instrument profile given (`--instrument`), used again by a resume that gives
    /// none (`null`: the one installed for the instrument, if any).
    #[serde(default)]
    pub instrument_profile: Option<String>,
}

/// One sheet of the batch, measured and judged.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BatchSheet {
    /// Its number, from 1.
    pub number: u16,
    /// Its folder, relative to the batch's.
    pub folder: String,
    /// The simulated sheet's own parameters, as the simulator was given them (`null` on an
    /// instrument).
    pub simulated: Option<String>,
    /// Spots accepted.
    pub accepted_spots: usize,
    /// σ (degrees), ρs, ρd: the geometric mean of its accepted spots.
    pub values: Named<Option<f64>>,
    /// Spot-to-spot relative sd (`null`: fewer than two spots).
    pub spot_to_spot_relative_sd: Option<Named<f64>>,
    /// Relative deviation from the master, percent.
    pub deviation_pct: Named<Option<f64>>,
    /// The result's flags, informational ones included (empty: clean).
    pub flags: Vec<String>,
    /// Its gloss at each geometry its accepted spots have it (empty: none, no instrument
    /// profile in force).
    #[serde(default)]
    pub gloss: Vec<SheetGloss>,
    /// Its gloss against each of the plan's gloss specifications.
    #[serde(default)]
    pub gloss_judgements: Vec<GlossJudgement>,
    /// The verdict against the master and the gloss specifications.
    #[serde(flatten)]
    pub verdict: Verdict,
}

/// Sheets by verdict.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counts {
    /// Passed.
    pub pass: usize,
    /// Failed.
    pub fail: usize,
    /// Undecided.
    pub undecided: usize,
}

/// `batch.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BatchDoc {
    /// [`crate::schema::BATCH`].
    pub schema: String,
    /// Where the batch stands.
    pub status: Status,
    /// Why it stopped, when failed or interrupted.
    pub why: Option<String>,
    /// How to go on, when not finished.
    pub resume_with: Option<String>,
    /// What it measures.
    pub plan: BatchPlan,
    /// The master stock, as read when the batch began.
    pub master: Master,
    /// The tolerances, percent of the master's value.
    pub tolerance_pct: Named<f64>,
    /// What each tolerance rests on.
    pub tolerance_basis: Named<String>,
    /// Every sheet measured, in order.
    pub sheets: Vec<BatchSheet>,
    /// Sheets by verdict.
    pub counts: Counts,
    /// Across the clean sheets: how the statistics and control limits are made.
    pub chart: String,
    /// Across the clean sheets, one per parameter determined.
    pub statistics: Vec<Statistics>,
}

/// What [`BatchDoc::chart`] says.
pub const CHART: &str = "individuals and moving range (I-MR) over the clean sheets in the order measured: limits mean ± 3·MR̄/1.128, moving range up to 3.267·MR̄";

impl BatchDoc {
    /// A new batch, nothing measured.
    pub fn new(plan: BatchPlan, master: Master, tolerance: [(f64, String); 3]) -> BatchDoc {
        let [a, b, c] = tolerance;
        BatchDoc {
            schema: crate::schema::BATCH.to_string(),
            status: Status::Running,
            why: None,
            resume_with: None,
            plan,
            master,
            tolerance_pct: Named::of([a.0, b.0, c.0]),
            tolerance_basis: Named {
                sigma_deg: a.1,
                rho_s: b.1,
                rho_d: c.1,
            },
            sheets: Vec::new(),
            counts: Counts::default(),
            chart: CHART.to_string(),
            statistics: Vec::new(),
        }
    }

    /// The folder of sheet `number`.
    pub fn sheet_folder(number: u16) -> String {
        format!("sheet-{number:02}")
    }

    /// Add sheet `entry` and compute the counts and statistics again.
    pub fn push(&mut self, entry: BatchSheet) {
        self.sheets.push(entry);
        self.counts = Counts::default();
        for s in &self.sheets {
            match s.verdict {
                Verdict::Pass => self.counts.pass += 1,
                Verdict::Fail { .. } => self.counts.fail += 1,
                Verdict::Undecided { .. } => self.counts.undecided += 1,
            }
        }
        self.statistics = (0..3)
            .filter_map(|i| {
                let points: Vec<(u16, f64)> = self
                    .sheets
                    .iter()
                    .filter(|s| clean(&s.flags))
                    .filter_map(|s| s.values[i].map(|v| (s.number, v)))
                    .collect();
                batch::statistics(batch::PARAMETERS[i], &points)
            })
            .collect();
        let mut angles: Vec<f64> = self
            .sheets
            .iter()
            .flat_map(|s| s.gloss.iter().map(|g| g.angle_deg))
            .collect();
        angles.sort_by(f64::total_cmp);
        angles.dedup();
        for angle in angles {
            let points: Vec<(u16, f64)> = self
                .sheets
                .iter()
                .filter(|s| clean(&s.flags))
                .filter_map(|s| {
                    let g = s.gloss.iter().find(|g| g.angle_deg == angle)?;
                    Some((s.number, g.gloss_units))
                })
                .collect();
            self.statistics
                .extend(batch::statistics(&batch::gloss_label(angle), &points));
        }
    }

    /// Every sheet passed.
    pub fn all_pass(&self) -> bool {
        self.counts.fail == 0 && self.counts.undecided == 0
    }
}

/// Flags (as strings) that are informational only; an unknown string counts as not.
fn clean(flags: &[String]) -> bool {
    flags.iter().all(|f| {
        Flag::ALL
            .iter()
            .any(|k| k.name() == f && k.is_informational())
    })
}

/// Sheet `number` of the batch `doc`, read back from its finished folder `dir` and judged.
pub fn judge_sheet(
    doc: &BatchDoc,
    number: u16,
    dir: &Path,
    simulated: Option<String>,
) -> Result<BatchSheet, BatchError> {
    let measured = read_measured(dir).map_err(|e| BatchError::Sheet {
        path: dir.to_path_buf(),
        why: e.to_string(),
    })?;
    let (values, within, accepted) = match &measured.summary {
        Some(summary) => (
            summary.mean,
            summary.within_relative_sd.map(Named::of),
            summary.accepted,
        ),
        None => (
            measured.sheet.spots.first().map_or([None; 3], |s| s.values),
            None,
            measured.sheet.spots.len(),
        ),
    };
    let flagged: Vec<String> = measured
        .flags
        .iter()
        .filter(|f| !clean(std::slice::from_ref(f)))
        .cloned()
        .collect();
    let spots_gloss: Vec<Option<Vec<SpotGloss>>> = measured
        .gloss
        .iter()
        .map(|spot| {
            spot.as_ref().map(|values| {
                values
                    .iter()
                    .map(|g| SpotGloss {
                        geometry: g.geometry.clone(),
                        angle_deg: g.angle_deg,
                        gloss_units: g.gloss_units,
                        u_gloss_units: g.u_gloss_units,
                    })
                    .collect()
            })
        })
        .collect();
    let gloss = batch::sheet_gloss(&spots_gloss);
    let any_gloss = spots_gloss.iter().any(Option::is_some);
    let gloss_judgements: Vec<GlossJudgement> = doc
        .plan
        .gloss_spec
        .iter()
        .map(|spec| {
            if !flagged.is_empty() {
                return GlossJudgement::of(spec, None, || {
                    "the sheet's result is flagged".to_string()
                });
            }
            let at = gloss.iter().find(|g| g.angle_deg == spec.angle_deg);
            GlossJudgement::of(spec, at.map(|g| g.gloss_units), || {
                batch::no_gloss_why(any_gloss, spec)
            })
        })
        .collect();
    let verdict = batch::judge(
        values,
        &doc.master,
        doc.tolerance_pct.array(),
        &flagged,
        &gloss_judgements,
    );
    Ok(BatchSheet {
        gloss,
        gloss_judgements,
        number,
        folder: BatchDoc::sheet_folder(number),
        simulated,
        accepted_spots: accepted,
        values: Named::of(values),
        spot_to_spot_relative_sd: within,
        deviation_pct: Named::of(std::array::from_fn(|i| {
            batch::deviation_pct(values[i], doc.master.values[i])
        })),
        flags: measured.flags.clone(),
        verdict,
    })
}

/// Keeps a second `gonio batch` out of a batch folder while this one runs in it: the
/// folder's lock ([`FolderLock`], which the kernel drops however the process ends) and
/// `batch.lock`, which says who holds it (a lock that a killed process left is not held,
/// and its `batch.lock` is written anew by the next).
pub struct BatchLock {
    _lock: FolderLock,
    holder_file: PathBuf,
    announced: bool,
}

impl BatchLock {
    /// Take the batch folder `dir` (it must exist), or say who holds it. Nothing is
    /// written in the folder until [`BatchLock::announce`].
    pub fn take(dir: &Path) -> Result<BatchLock, BatchError> {
        let holder_file = dir.join(BATCH_LOCK);
        let lock = FolderLock::take(dir).map_err(|e| match e {
            FolderError::InUse(_) => BatchError::InUse {
                dir: dir.to_path_buf(),
                holder: std::fs::read_to_string(&holder_file)
                    .ok()
                    .map(|h| crate::text::shown_at_most(h.trim(), 300))
                    .filter(|h| !h.is_empty())
                    .unwrap_or_else(|| "a process that has not said who it is yet".into()),
            },
            other => BatchError::Io {
                path: dir.to_path_buf(),
                source: std::io::Error::other(other.to_string()),
            },
        })?;
        Ok(BatchLock {
            _lock: lock,
            holder_file,
            announced: false,
        })
    }

    /// Write `batch.lock`: this process, its command and since when.
    pub fn announce(&mut self) -> Result<(), BatchError> {
        let command: Vec<String> = std::env::args().collect();
        let holder = format!(
            "process {}, `{}`, since {}",
            std::process::id(),
            command.join(" "),
            chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Secs, true)
        );
        std::fs::write(&self.holder_file, format!("{holder}\n")).map_err(|source| {
            BatchError::Io {
                path: self.holder_file.clone(),
                source,
            }
        })?;
        self.announced = true;
        Ok(())
    }
}

impl Drop for BatchLock {
    fn drop(&mut self) {
        // While the lock is still held: no other batch can have written it.
        if self.announced {
            let _ = std::fs::remove_file(&self.holder_file);
        }
    }
}

/// Whether sheet folder `dir` is finished (its `sheet.json` or `session.json` says so).
pub fn is_finished(dir: &Path) -> bool {
    read_measured(dir).is_ok()
}

/// Whether `dir` holds anything of a sheet (an unfinished one is resumed).
pub fn is_started(dir: &Path) -> bool {
    crate::output::folder::is_sheet_folder(dir) || dir.join(SESSION).is_file()
}

/// Read `batch.json` of `dir`.
pub fn read(dir: &Path) -> Result<BatchDoc, BatchError> {
    let path = dir.join(BATCH);
    let text = std::fs::read_to_string(&path).map_err(|source| BatchError::Io {
        path: path.clone(),
        source,
    })?;
    let not = |why: String| BatchError::NotABatch {
        path: path.clone(),
        why,
    };
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| not(format!("not JSON: {e}")))?;
    crate::schema::check(
        &value,
        &[
            crate::schema::BATCH,
            crate::schema::BATCH_V2,
            crate::schema::BATCH_V1,
        ],
        None,
    )
    .map_err(|m| not(format!("{m}: not a batch folder of this gonio")))?;
    let mut doc: BatchDoc =
        serde_json::from_value(value).map_err(|e| not(format!("not a batch document: {e}")))?;
    // A gonio-batch/1 or /2 document is written back as this gonio writes (its policy null
    // in /1; no gloss specification, no sheet's gloss in either).
    doc.schema = crate::schema::BATCH.to_string();
    for (k, s) in doc.sheets.iter().enumerate() {
        if s.number as usize != k + 1 || s.folder != BatchDoc::sheet_folder(s.number) {
            return Err(not(format!(
                "sheet entry {} is not sheet {} in {}",
                k + 1,
                k + 1,
                BatchDoc::sheet_folder(k as u16 + 1)
            )));
        }
    }
    Ok(doc)
}

/// Write `batch.json`, `batch.csv` and `batch.html` into `dir`, each replaced atomically.
pub fn write(dir: &Path, doc: &BatchDoc) -> Result<(), BatchError> {
    let json = serde_json::to_vec_pretty(doc).map_err(|e| BatchError::Io {
        path: dir.join(BATCH),
        source: std::io::Error::other(e),
    })?;
    replace(
        &dir.join(BATCH_CSV),
        &csv_bytes(doc).map_err(|source| BatchError::Io {
            path: dir.join(BATCH_CSV),
            source,
        })?,
    )?;
    replace(&dir.join(BATCH_HTML), report::html(doc).as_bytes())?;
    // batch.json last: it is what a resume reads.
    replace(&dir.join(BATCH), &json)
}

/// Write `bytes` to `path` through a temporary file and a rename: a reader sees the old
/// file or the new one, never half of one.
fn replace(path: &Path, bytes: &[u8]) -> Result<(), BatchError> {
    let io = |source| BatchError::Io {
        path: path.to_path_buf(),
        source,
    };
    let temporary = path.with_extension("new");
    std::fs::write(&temporary, bytes).map_err(io)?;
    std::fs::rename(&temporary, path).map_err(io)
}

/// The gloss geometries `batch.csv` has a column for: those specified and those any sheet
/// has gloss at, by angle.
fn gloss_angles(doc: &BatchDoc) -> Vec<f64> {
    let mut angles: Vec<f64> = doc
        .plan
        .gloss_spec
        .iter()
        .map(|g| g.angle_deg)
        .chain(
            doc.sheets
                .iter()
                .flat_map(|s| s.gloss.iter().map(|g| g.angle_deg)),
        )
        .collect();
    angles.sort_by(f64::total_cmp);
    angles.dedup();
    angles
}

/// `batch.csv`: one row per sheet, units in the headers, comma-separated with a decimal
/// point and ASCII headers (any spreadsheet opens it as it is). The gloss columns follow
/// the others: the sheet's gloss at each geometry specified or measured, then each
/// specification's target, tolerance, verdict and why it is undecided.
pub fn csv_bytes(doc: &BatchDoc) -> std::io::Result<Vec<u8>> {
    let mut out = csv::Writer::from_writer(Vec::new());
    let angles = gloss_angles(doc);
    let mut header: Vec<String> = [
        "sheet",
        "folder",
        "verdict",
        "failed parameters",
        "sigma (deg)",
        "rho_s (1)",
        "rho_d (1)",
        "sigma deviation (%)",
        "rho_s deviation (%)",
        "rho_d deviation (%)",
        "sigma tolerance (%)",
        "rho_s tolerance (%)",
        "rho_d tolerance (%)",
        "accepted spots",
        "sigma spot-to-spot sd (%)",
        "rho_s spot-to-spot sd (%)",
        "rho_d spot-to-spot sd (%)",
        "flags",
        "why undecided",
    ]
    .map(String::from)
    .to_vec();
    header.extend(angles.iter().map(|a| format!("gloss {a} deg (GU)")));
    for spec in &doc.plan.gloss_spec {
        let a = spec.angle_deg;
        header.extend([
            format!("gloss {a} deg spec (GU)"),
            format!("gloss {a} deg tolerance (GU)"),
            format!("gloss {a} deg verdict"),
            format!("gloss {a} deg why undecided"),
        ]);
    }
    out.write_record(&header)?;
    let number = |v: Option<f64>| v.map_or_else(String::new, |v| format!("{v}"));
    for s in &doc.sheets {
        let failed = match &s.verdict {
            Verdict::Fail {
                exceeded,
                gloss_exceeded,
                ..
            } => exceeded
                .iter()
                .map(|e| e.parameter.clone())
                .chain(
                    gloss_exceeded
                        .iter()
                        .map(|g| format!("gloss_{}deg", g.angle_deg)),
                )
                .collect::<Vec<_>>()
                .join(" "),
            _ => String::new(),
        };
        let why = match &s.verdict {
            Verdict::Undecided { why } => why.clone(),
            Verdict::Fail { undecided, .. } => undecided.join("; "),
            Verdict::Pass => String::new(),
        };
        let mut row = vec![
            s.number.to_string(),
            s.folder.clone(),
            s.verdict.name().to_string(),
            failed,
        ];
        row.extend((0..3).map(|i| number(s.values[i].map(|v| round(v, 6)))));
        row.extend((0..3).map(|i| number(s.deviation_pct[i].map(|d| round(d, 4)))));
        row.extend((0..3).map(|i| number(Some(doc.tolerance_pct[i]))));
        row.push(s.accepted_spots.to_string());
        row.extend(
            (0..3).map(|i| number(s.spot_to_spot_relative_sd.map(|w| round(100.0 * w[i], 4)))),
        );
        row.push(s.flags.join(" "));
        row.push(why);
        row.extend(angles.iter().map(|a| {
            number(
                s.gloss
                    .iter()
                    .find(|g| g.angle_deg == *a)
                    .map(|g| round(g.gloss_units, 2)),
            )
        }));
        for spec in &doc.plan.gloss_spec {
            let judged = s
                .gloss_judgements
                .iter()
                .find(|j| j.angle_deg == spec.angle_deg);
            row.extend([
                number(Some(spec.target_gloss_units)),
                number(Some(spec.tolerance_gloss_units)),
                judged.map_or_else(String::new, |j| j.verdict.clone()),
                judged.and_then(|j| j.why.clone()).unwrap_or_default(),
            ]);
        }
        out.write_record(&row)?;
    }
    out.into_inner().map_err(|e| e.into_error())
}

/// `x` to `digits` decimals (no float noise such as 0.09999999999999432 in the table).
fn round(x: f64, digits: i32) -> f64 {
    let scale = 10f64.powi(digits);
    (x * scale).round() / scale
}
