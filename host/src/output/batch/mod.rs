//! The folder of a QA batch (`gonio batch`): sheets of one stock measured one after the
//! other and judged against a master stock of the library.
//!
//! | file | what | written |
//! |---|---|---|
//! | `batch.json` | the plan, the master's values and the tolerances (fixed when the batch began), every sheet measured with its values and verdict, the statistics across the sheets | replaced atomically after each sheet and at the end |
//! | `sheet-01/`, `sheet-02/`, … | one sheet folder per sheet (a session folder with one spot): each verifies, reports and resumes on its own | as a sheet or session folder |
//! | `batch.csv` | one row per sheet, units in the headers: for a spreadsheet | with `batch.json` |
//! | `batch.html` | the batch report a person reads | with `batch.json` |
//!
//! The master and the tolerances are recorded when the batch begins, so a batch resumed
//! after the library changed is still judged as it began; a sheet is judged from its own
//! folder's files (read back, as `gonio compare` reads them).
mod report;

use crate::analysis::batch::{self, Master, Named, SpotValues, Statistics, Verdict};
use crate::analysis::flags::Flag;
use crate::output::folder::sheet::read_measured;
use crate::output::folder::{SESSION, Status};
use crate::output::library::{Library, OpenMode};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// `batch.json`.
pub const BATCH: &str = "batch.json";
/// `batch.csv`.
pub const BATCH_CSV: &str = "batch.csv";
/// `batch.html`.
pub const BATCH_HTML: &str = "batch.html";

/// Why a batch cannot be begun, continued or written.
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    /// The library cannot be read.
    #[error(transparent)]
    Library(#[from] crate::output::library::LibraryError),
    /// The library holds no stock of that name.
    #[error("{library}: no stock '{stock}' in the library{}", hint(known))]
    UnknownStock {
        /// The library file.
        library: PathBuf,
        /// The stock asked for.
        stock: String,
        /// The stocks it holds.
        known: Vec<String>,
    },
    /// The master's sheets determine nothing.
    #[error("{library}: {source}")]
    Master {
        /// The library file.
        library: PathBuf,
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
pub fn master_from_library(path: &Path, stock: &str) -> Result<Master, BatchError> {
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
            library: path.to_path_buf(),
            stock: stock.to_string(),
            known,
        });
    }
    Master::of_sheets(stock, &sheets).map_err(|source| BatchError::Master {
        library: path.to_path_buf(),
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
    /// The verdict against the master.
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
    let verdict = batch::judge(values, &doc.master, doc.tolerance_pct.array(), &flagged);
    Ok(BatchSheet {
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
        &[crate::schema::BATCH, crate::schema::BATCH_V1],
        None,
    )
    .map_err(|m| not(format!("{m}: not a batch folder of this gonio")))?;
    let mut doc: BatchDoc =
        serde_json::from_value(value).map_err(|e| not(format!("not a batch document: {e}")))?;
    // A gonio-batch/1 document is written back as this gonio writes (its policy null).
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

/// `batch.csv`: one row per sheet, units in the headers, comma-separated with a decimal
/// point and ASCII headers (any spreadsheet opens it as it is).
pub fn csv_bytes(doc: &BatchDoc) -> std::io::Result<Vec<u8>> {
    let mut out = csv::Writer::from_writer(Vec::new());
    out.write_record([
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
    ])?;
    let number = |v: Option<f64>| v.map_or_else(String::new, |v| format!("{v}"));
    for s in &doc.sheets {
        let failed = match &s.verdict {
            Verdict::Fail { exceeded } => exceeded
                .iter()
                .map(|e| e.parameter.as_str())
                .collect::<Vec<_>>()
                .join(" "),
            _ => String::new(),
        };
        let why = match &s.verdict {
            Verdict::Undecided { why } => why.clone(),
            _ => String::new(),
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
        out.write_record(&row)?;
    }
    out.into_inner().map_err(|e| e.into_error())
}

/// `x` to `digits` decimals (no float noise such as 0.09999999999999432 in the table).
fn round(x: f64, digits: i32) -> f64 {
    let scale = 10f64.powi(digits);
    (x * scale).round() / scale
}
