//! A QA batch (`gonio batch`): sheets of one stock measured one after the other, each a
//! whole `gonio measure` into its own folder under the batch's, each judged against a
//! master stock of the library as soon as it is measured ([`crate::output::batch`]).
//!
//! Resumable at every step: `batch.json` is written after each sheet, a sheet folder
//! that is finished is read and never measured again, one that was begun is resumed as
//! `gonio measure --resume` resumes it, and the batch goes on at the next sheet.
//!
//! On the simulator every sheet is a sheet of its own: sheet k has its own seed (the
//! batch's + k − 1: its noise and, with `--physics real` or `drawn`, its own draw of the
//! instrument's errors) and its own σ, ρs and ρd, drawn log-normally about the paper's
//! with the relative sd `--sheet-to-sheet-pct` (what sheets of one lot differ by; the
//! forensic study's `sheets-3pct` scenario uses 3 %), so that a batch shows the
//! sheet-to-sheet variation a real one does, not the same sheet N times.
use super::{MeasureOptions, Measured, measure};
use crate::analysis::batch::GlossSpec;
use crate::instrument::sim::sample_params;
use crate::output::batch::{self as folder, BatchDoc, BatchLock, BatchPlan};
use crate::output::folder::Status;
use crate::session::{Operator, PolicyChoice, SessionError};
use anyhow::{Context, bail, ensure};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// The most sheets a batch takes.
pub const MAX_SHEETS: u16 = 999;
/// Default spread of the simulated sheets about their paper, percent.
pub const DEFAULT_SHEET_TO_SHEET_PCT: f64 = 1.0;
/// The largest spread of the simulated sheets accepted, percent.
const MAX_SHEET_TO_SHEET_PCT: f64 = 30.0;
/// The largest tolerance accepted, percent.
const MAX_TOLERANCE_PCT: f64 = 1000.0;

/// What `gonio batch` was given.
#[derive(Clone, Debug)]
pub struct BatchOptions {
    /// The master stock's name in the library (a new batch).
    pub master: Option<String>,
    /// The library (a file or a PostgreSQL URL).
    pub library: crate::output::library::Location,
    /// Sheets to measure (a new batch).
    pub sheets: Option<u16>,
    /// The batch folder (a new batch): new or empty.
    pub out: Option<PathBuf>,
    /// An interrupted batch's folder to continue.
    pub resume: Option<PathBuf>,
    /// Tolerances on σ, ρs, ρd, percent (`None`: the default from the master's spread).
    pub tolerance_pct: [Option<f64>; 3],
    /// Spread of the simulated sheets about their paper, percent.
    pub sheet_to_sheet_pct: f64,
    /// Gloss specifications (`--gloss-spec`): a new batch's; a resume's must be the
    /// batch's (empty: the batch's).
    pub gloss_spec: Vec<GlossSpec>,
    /// How each sheet is measured: the instrument or simulator, the spots, the policy….
    /// Its `out`, `resume` and, on the simulator, seed and sample are the batch's own.
    pub measure: MeasureOptions,
}

/// How a batch ended.
pub enum BatchEnd {
    /// Every sheet measured.
    Finished {
        /// The batch folder.
        dir: PathBuf,
        /// `batch.json` as written.
        doc: Box<BatchDoc>,
    },
    /// A sheet's session stopped; the batch is recorded as stopped and can be resumed.
    Stopped {
        /// The batch folder.
        dir: PathBuf,
        /// `batch.json` as written.
        doc: Box<BatchDoc>,
        /// Why the sheet stopped.
        error: SessionError,
    },
}

/// Begin or continue the batch, measuring every sheet still missing.
pub fn run_batch(
    options: &BatchOptions,
    operator: &mut dyn Operator,
    interrupted: Arc<AtomicBool>,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<BatchEnd> {
    // The batch folder is held until the batch ends, however it ends (the lock is dropped
    // with it): a second gonio batch in it is refused, naming this one.
    let (dir, mut doc, _lock) = match &options.resume {
        Some(dir) => {
            let lock = if dir.is_dir() {
                let mut lock = BatchLock::take(dir)?;
                lock.announce()?;
                Some(lock)
            } else {
                None
            };
            (dir.clone(), continued(options, dir)?, lock)
        }
        None => {
            let (dir, doc, lock) = begin(options)?;
            (dir, doc, Some(lock))
        }
    };
    let resume_with = resume_command(&options.measure, &dir);
    let first = doc.sheets.len() as u16 + 1;
    for number in first..=doc.plan.sheets {
        if interrupted.load(Ordering::Relaxed) {
            let error = SessionError::Interrupted;
            stop(&dir, &mut doc, &error, &resume_with)?;
            return Ok(BatchEnd::Stopped {
                dir,
                doc: Box::new(doc),
                error,
            });
        }
        let sheet_dir = dir.join(BatchDoc::sheet_folder(number));
        let simulated = simulated_sample(&doc.plan, options, number)?;
        let sheet_options = sheet_options(options, &doc.plan, &sheet_dir, number, &simulated);
        if !folder::is_finished(&sheet_dir) {
            progress(&format!(
                "sheet {number} of {}: {} (folder {})",
                doc.plan.sheets,
                if options.measure.sim.is_some() {
                    "drawn on the simulator"
                } else {
                    "put the next sheet on the sample port when asked"
                },
                sheet_dir.display()
            ));
            let measured = measure(&sheet_options, operator, interrupted.clone());
            match measured {
                Ok(Measured::Done { .. } | Measured::Sheet { .. }) => {}
                Ok(Measured::Stopped { error, .. }) => {
                    stop(&dir, &mut doc, &error, &resume_with)?;
                    return Ok(BatchEnd::Stopped {
                        dir,
                        doc: Box::new(doc),
                        error,
                    });
                }
                Err(e) => {
                    let why = format!("sheet {number}: {}", crate::text::error_chain(&e));
                    doc.status = Status::Failed;
                    doc.why = Some(why);
                    doc.resume_with = Some(resume_with.clone());
                    folder::write(&dir, &doc)?;
                    return Err(e.context(format!(
                        "sheet {number} of the batch in {} (the sheets before it are kept; continue with: {resume_with})",
                        dir.display()
                    )));
                }
            }
        }
        let entry = folder::judge_sheet(&doc, number, &sheet_dir, simulated)?;
        progress(&format!("sheet {number}: {}", entry.verdict.text()));
        doc.push(entry);
        doc.status = Status::Running;
        doc.why = None;
        doc.resume_with = Some(resume_with.clone());
        folder::write(&dir, &doc)?;
    }
    doc.status = Status::Finished;
    doc.why = None;
    doc.resume_with = None;
    folder::write(&dir, &doc)?;
    Ok(BatchEnd::Finished {
        dir,
        doc: Box::new(doc),
    })
}

/// Record the batch as stopped by `error`.
fn stop(
    dir: &Path,
    doc: &mut BatchDoc,
    error: &SessionError,
    resume_with: &str,
) -> anyhow::Result<()> {
    doc.status = if matches!(error, SessionError::Interrupted) {
        Status::Interrupted
    } else {
        Status::Failed
    };
    doc.why = Some(format!("sheet {}: {error}", doc.sheets.len() + 1));
    doc.resume_with = Some(resume_with.to_string());
    folder::write(dir, doc)?;
    Ok(())
}

/// The command that continues the batch in `dir`.
pub fn resume_command(options: &MeasureOptions, dir: &Path) -> String {
    let on = match (&options.sim, &options.port) {
        (Some(sample), _) => format!(" --sim {sample}"),
        (None, Some(port)) => format!(" --port {port}"),
        (None, None) => String::new(),
    };
    format!("gonio batch{on} --resume {}", dir.display())
}

/// Check a new batch's options and read its master, before anything is written; then
/// make its folder, take it and write its first `batch.json`.
fn begin(options: &BatchOptions) -> anyhow::Result<(PathBuf, BatchDoc, BatchLock)> {
    let Some(stock) = &options.master else {
        crate::usage_bail!(
            "a new batch needs --master STOCK: the stock of the library its sheets are judged against"
        );
    };
    let Some(sheets) = options.sheets else {
        crate::usage_bail!("a new batch needs --sheets N: how many sheets to measure");
    };
    if !(1..=MAX_SHEETS).contains(&sheets) {
        crate::usage_bail!("--sheets must be 1 to {MAX_SHEETS}, not {sheets}");
    }
    let Some(dir) = options.out.clone() else {
        crate::usage_bail!(
            "a new batch needs --out DIR: the folder its sheets and reports go into"
        );
    };
    let spots = options.measure.spots.unwrap_or(super::DEFAULT_SPOTS);
    if !(1..=super::MAX_SPOTS).contains(&spots) {
        crate::usage_bail!("--spots must be 1 to {}, not {spots}", super::MAX_SPOTS);
    }
    for (i, t) in options.tolerance_pct.iter().enumerate() {
        if let Some(t) = t
            && !(t.is_finite() && *t > 0.0 && *t <= MAX_TOLERANCE_PCT)
        {
            crate::usage_bail!(
                "--tolerance-{}-pct must be above 0 and at most {MAX_TOLERANCE_PCT} percent, not {t}",
                ["sigma", "rho-s", "rho-d"][i]
            );
        }
    }
    if !(options.sheet_to_sheet_pct.is_finite()
        && (0.0..=MAX_SHEET_TO_SHEET_PCT).contains(&options.sheet_to_sheet_pct))
    {
        crate::usage_bail!(
            "--sheet-to-sheet-pct must be 0 to {MAX_SHEET_TO_SHEET_PCT} percent, not {}",
            options.sheet_to_sheet_pct
        );
    }
    if let Some(paper) = &options.measure.sim
        && options.measure.sim_options.scene_file.is_none()
    {
        // An unknown name on the command line: exit 2, as `gonio measure --sim GG`.
        sample_params(paper).map_err(|e| crate::UsageError(format!("--sim {paper}: {e:#}")))?;
    }
    for (k, spec) in options.gloss_spec.iter().enumerate() {
        if let Some(twice) = options.gloss_spec[..k]
            .iter()
            .find(|s| s.angle_deg == spec.angle_deg)
        {
            crate::usage_bail!(
                "--gloss-spec {} and --gloss-spec {}: {} specified twice (one specification a geometry)",
                twice.text(),
                spec.text(),
                spec.label()
            );
        }
    }
    let master = folder::master_from_library(&options.library, stock)?;
    let tolerance = std::array::from_fn(|i| match options.tolerance_pct[i] {
        Some(t) => (
            t,
            format!("given (--tolerance-{}-pct)", ["sigma", "rho-s", "rho-d"][i]),
        ),
        None => master.default_tolerance(i),
    });
    let plan = BatchPlan {
        sheets,
        spots,
        sample: options
            .measure
            .sample
            .clone()
            .or_else(|| options.measure.sim.clone())
            .unwrap_or_else(|| "sample".to_string()),
        sim: options.measure.sim.clone(),
        sim_seed: options
            .measure
            .sim
            .as_ref()
            .map(|_| options.measure.sim_options.seed),
        sheet_to_sheet_pct: options
            .measure
            .sim
            .as_ref()
            .map(|_| options.sheet_to_sheet_pct),
        library: options.library.to_string(),
        policy: Some(
            options
                .measure
                .policy
                .unwrap_or(PolicyChoice::Adaptive)
                .name()
                .to_string(),
        ),
        gloss_spec: options.gloss_spec.clone(),
        instrument_profile: options
            .measure
            .instrument
            .as_ref()
            .map(|p| p.display().to_string()),
    };
    let lock = make_folder(&dir)?;
    let doc = BatchDoc::new(plan, master, tolerance);
    folder::write(&dir, &doc)?;
    Ok((dir, doc, lock))
}

/// A new batch folder: made, or an empty one taken; held by this process.
fn make_folder(dir: &Path) -> anyhow::Result<BatchLock> {
    if !dir.exists() {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--out {}: cannot make the folder", dir.display()))?;
    }
    // Taken before the folder is looked at: a gonio batch running in it has written its
    // batch.json and sheets, and is named rather than told to resume.
    let mut lock = if dir.is_dir() {
        BatchLock::take(dir)?
    } else {
        bail!("--out {}: not a folder", dir.display());
    };
    // A batch.lock alone is one a killed gonio batch left before its first batch.json.
    match std::fs::read_dir(dir) {
        Ok(entries) => {
            let mut entries = entries
                .filter_map(Result::ok)
                .filter(|e| e.file_name() != folder::BATCH_LOCK);
            if entries.next().is_some() {
                if dir.join(folder::BATCH).is_file() {
                    bail!(
                        "--out {}: a batch is already there (continue it with gonio batch --resume {})",
                        dir.display(),
                        dir.display()
                    );
                }
                bail!(
                    "--out {}: the folder is not empty; a batch takes a new or empty folder",
                    dir.display()
                );
            }
            lock.announce()?;
            Ok(lock)
        }
        Err(e) => Err(anyhow::anyhow!("--out {}: {e}", dir.display())),
    }
}

/// The interrupted batch in `dir`, its plan checked against the options given.
fn continued(options: &BatchOptions, dir: &Path) -> anyhow::Result<BatchDoc> {
    let doc = folder::read(dir)?;
    ensure!(
        doc.status != Status::Finished,
        "{}: the batch is finished ({} sheets measured); gonio report and batch.html show it",
        dir.display(),
        doc.sheets.len()
    );
    ensure!(
        doc.plan.sim == options.measure.sim,
        "{}: the batch was measured {}, not {}: resume it as it began",
        dir.display(),
        on(doc.plan.sim.as_deref()),
        on(options.measure.sim.as_deref())
    );
    if let Some(planned) = &doc.plan.policy {
        ensure!(
            <PolicyChoice as clap::ValueEnum>::from_str(planned, true).is_ok(),
            "{}: the batch's policy '{}' is not one this gonio knows (paper, adaptive, sweep, mixed)",
            dir.join(folder::BATCH).display(),
            crate::text::shown(planned)
        );
    }
    if let (Some(given), Some(planned)) = (options.measure.policy, &doc.plan.policy) {
        ensure!(
            given.name() == planned,
            "{}: --policy {} differs from the batch's plan (policy {planned}): a batch is measured under one procedure (resume without --policy)",
            dir.display(),
            given.name()
        );
    }
    let given: Vec<String> = options.gloss_spec.iter().map(GlossSpec::text).collect();
    let planned: Vec<String> = doc.plan.gloss_spec.iter().map(GlossSpec::text).collect();
    ensure!(
        given.is_empty() || given == planned,
        "{}: --gloss-spec {} differs from the batch's plan ({}): a batch is judged against one specification (resume without --gloss-spec)",
        dir.display(),
        given.join(" --gloss-spec "),
        if planned.is_empty() {
            "no gloss specification".to_string()
        } else {
            format!("gloss spec {}", planned.join(", "))
        }
    );
    Ok(doc)
}

fn on(sim: Option<&str>) -> String {
    sim.map_or_else(
        || "on an instrument".to_string(),
        |s| format!("on the simulator (--sim {s})"),
    )
}

/// The simulated sheet `number`'s own sample: the paper's σ, ρs, ρd drawn log-normally
/// about it (`None` on an instrument; the paper itself when there is no spread or the
/// simulator replays a table).
fn simulated_sample(
    plan: &BatchPlan,
    options: &BatchOptions,
    number: u16,
) -> anyhow::Result<Option<String>> {
    let (Some(paper), Some(seed)) = (&plan.sim, plan.sim_seed) else {
        return Ok(None);
    };
    let pct = plan.sheet_to_sheet_pct.unwrap_or(0.0);
    if pct == 0.0 || options.measure.sim_options.scene_file.is_some() {
        return Ok(Some(paper.clone()));
    }
    let p = sample_params(paper).with_context(|| format!("--sim {paper}"))?;
    let mut rng =
        rand_chacha::ChaCha12Rng::seed_from_u64(sheet_seed(seed, number) ^ 0xba7c_5ee7_0000_0000);
    let s2 = (1.0 + (pct / 100.0).powi(2)).ln();
    let [sigma, rho_s, rho_d] = [p.sigma_deg, p.rho_s, p.rho_d].map(|v| {
        let z: f64 = StandardNormal.sample(&mut rng);
        v * (s2.sqrt() * z - 0.5 * s2).exp()
    });
    Ok(Some(format!(
        "custom:{sigma:.6},{rho_s:.6},{rho_d:.6},{}",
        p.eta
    )))
}

/// The simulator's seed of sheet `number`.
fn sheet_seed(first: u64, number: u16) -> u64 {
    first.wrapping_add(u64::from(number) - 1)
}

/// The options sheet `number` is measured with.
fn sheet_options(
    options: &BatchOptions,
    plan: &BatchPlan,
    sheet_dir: &Path,
    number: u16,
    simulated: &Option<String>,
) -> MeasureOptions {
    let mut sheet = options.measure.clone();
    sheet.sample = Some(plan.sample.clone());
    // The batch's policy, not the resume's default: a sheet begun after a resume is
    // measured as the sheets before it were.
    if let Some(policy) = plan.policy.as_deref()
        && let Ok(choice) = <PolicyChoice as clap::ValueEnum>::from_str(policy, true)
    {
        sheet.policy = Some(choice);
    }
    // The batch's profile when the resume gives none: its sheets are analysed alike.
    if sheet.instrument.is_none() {
        sheet.instrument = plan.instrument_profile.as_ref().map(PathBuf::from);
    }
    if let (Some(sample), Some(seed)) = (simulated, plan.sim_seed) {
        sheet.sim = Some(sample.clone());
        sheet.sim_options.seed = sheet_seed(seed, number);
    }
    if folder::is_started(sheet_dir) {
        // A sheet begun keeps its own plan (its spots among it).
        sheet.resume = Some(sheet_dir.to_path_buf());
        sheet.out = None;
        sheet.spots = None;
    } else {
        sheet.resume = None;
        sheet.out = Some(sheet_dir.to_path_buf());
        sheet.spots = Some(plan.spots);
    }
    sheet
}
