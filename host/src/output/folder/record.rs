//! The session folder as the record of one session: created for it alone, every reading
//! appended as it arrives, every decision logged, resumed only by the same sample,
//! instrument and plan, closed with a manifest. The files are described in
//! [`crate::output::folder`]; every write goes through [`crate::output::folder::store::Store`]
//! (whose documentation says what is synced when).
//!
//! A folder's life: [`FileRecorder::create`] (or [`FileRecorder::create_default`]) makes it
//! and writes `session.json` with status `running` before anything is measured;
//! [`Existing::open`] reads a folder to resume without changing it, refusing damage,
//! another sample, instrument or plan ([`Existing::check_matches`]) and a finished session;
//! [`Existing::resume`] repairs what a crash leaves (a cut-off last line, `readings.csv`
//! behind `points.jsonl`, temporary files, a run without an end) and logs each repair;
//! [`FileRecorder::finish`] writes the result and the manifest, [`FileRecorder::stop`] the
//! status of a failed or interrupted session and how to resume it.
use crate::instrument::calibration::Calibration;
use crate::output::folder::documents::FinishedSession;
use crate::output::folder::lock::{FolderError, FolderLock, io_error};
use crate::output::folder::store::{Store, StoreOptions, Sync};
use crate::output::folder::{
    self, CALIBRATION, CsvAgreement, Finding, Inspection, InstrumentRecord, LOG, MANIFEST, POINTS,
    PlanRecord, READINGS, READINGS_HEADER, Run, RunOutcome, SESSION, SessionDoc, Status,
    dated_folder_name, json_bytes,
};
use crate::session::{MeasuredPoint, Progress, Recorder};
use indicatif::{ProgressBar, ProgressStyle};
use std::io;
use std::path::Path;

/// This host's version, recorded with every run.
pub(crate) const HOST_VERSION: &str = env!("CARGO_PKG_VERSION");

/// Local date-time now, RFC 3339 with milliseconds (what `session.log` and the runs record).
pub(crate) fn local_now() -> String {
    chrono::Local::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, false)
}

/// What a session is: it is resumed only as the same.
#[derive(Clone, Debug, PartialEq)]
pub struct Identity {
    /// The sample's name.
    pub sample: String,
    /// The instrument.
    pub instrument: InstrumentRecord,
    /// The handshake's `DeviceInfo`, whole.
    pub device: serde_json::Value,
    /// What is measured.
    pub plan: PlanRecord,
    /// The case, when given.
    pub case: Option<crate::output::folder::CaseRecord>,
}

impl Identity {
    /// The identity of a session of `sample` on the instrument `info` describes.
    pub fn new(sample: &str, info: &protocol::DeviceInfo, plan: PlanRecord) -> Identity {
        Identity {
            sample: sample.to_string(),
            instrument: InstrumentRecord {
                serial_number: info.serial_number.to_string(),
                board: info.board.to_string(),
                firmware_version: info.firmware_version.to_string(),
                simulated_sample: None,
                simulated_seed: None,
            },
            device: serde_json::to_value(info).unwrap_or_default(),
            plan,
            case: None,
        }
    }
}

/// Records a session into its folder and shows its progress.
pub struct FileRecorder {
    store: Store,
    _lock: FolderLock,
    doc: SessionDoc,
    /// The progress bar (hidden when stderr is not a terminal).
    pub bar: ProgressBar,
    /// This run's decisions, in order.
    pub decisions: Vec<String>,
    /// Readings in `points.jsonl`, in order (marks applied): a mark names positions in it,
    /// and `readings.csv` is rebuilt from it.
    points: Vec<MeasuredPoint>,
    /// The first write that failed outside `point` and `calibration` (a log line): the
    /// next of those reports it, so that the session stops rather than go on unrecorded.
    failed: Option<io::Error>,
    /// The folder's size as far as this recorder knows (its files when it was opened,
    /// and every line appended since), against [`crate::session::bounds::MAX_FOLDER_BYTES`].
    folder_bytes: u64,
}

/// The bytes of the files in `dir` (0 for what cannot be read: the bound is a backstop).
fn folder_size(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .filter_map(|e| e.metadata().ok())
                .filter(std::fs::Metadata::is_file)
                .map(|m| m.len())
                .sum()
        })
        .unwrap_or(0)
}

/// The bar of a stage of geometries.
fn geometries_style() -> ProgressStyle {
    ProgressStyle::with_template(
        "{msg:40} [{bar:30}] {pos}/{len} geometries, {prefix} device s left",
    )
    .unwrap_or_else(|_| ProgressStyle::default_bar())
    .progress_chars("=> ")
}

/// Before the first stage of geometries (connecting, homing, the dark and white
/// readings) a phase line, not a bar of "0/0 geometries".
fn progress_bar() -> ProgressBar {
    progress_bar_to(indicatif::ProgressDrawTarget::stderr())
}

/// A session's progress bar drawn to `target` (the terminal's standard error in use).
pub fn progress_bar_to(target: indicatif::ProgressDrawTarget) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(0), target);
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.set_message("getting ready: homing, calibration, the operator (no geometry measured yet)");
    bar
}

impl FileRecorder {
    /// Make the folder `dir` for a new session (`--out`): a new folder, or an empty one.
    /// Refuses a folder that holds anything (another session or not).
    pub fn create(
        dir: &Path,
        identity: Identity,
        options: StoreOptions,
    ) -> Result<FileRecorder, FolderError> {
        if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(io_error(parent))?;
        }
        let (store, lock, cleaned) = match Store::create_dir(dir, options.clone()) {
            Ok(store) => (store, FolderLock::take(dir)?, Vec::new()),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                if !dir.is_dir() {
                    return Err(FolderError::NotAFolder(dir.to_path_buf()));
                }
                let lock = FolderLock::take(dir)?;
                let mut store = Store::open_dir(dir, options);
                let cleaned = take_empty(&mut store, dir)?;
                (store, lock, cleaned)
            }
            Err(e) => {
                return Err(FolderError::Io {
                    dir: dir.to_path_buf(),
                    source: e,
                });
            }
        };
        let mut recorder = FileRecorder::start(store, lock, identity)?;
        for name in cleaned {
            recorder.decision(&format!(
                "removed {name}, a temporary file a killed gonio left before its session began"
            ));
        }
        Ok(recorder)
    }

    /// Make a new folder `PARENT/<local date-time>-<sample>` (a suffix `-2`, `-3`… when a
    /// session of the same second has it: the folder is made atomically, so two sessions
    /// never get the same one).
    pub fn create_default(
        parent: &Path,
        identity: Identity,
        options: StoreOptions,
    ) -> Result<FileRecorder, FolderError> {
        std::fs::create_dir_all(parent).map_err(io_error(parent))?;
        let base = dated_folder_name(&identity.sample);
        for k in 1..10_000 {
            let dir = parent.join(if k == 1 {
                base.clone()
            } else {
                format!("{base}-{k}")
            });
            match Store::create_dir(&dir, options.clone()) {
                Ok(store) => {
                    let lock = FolderLock::take(&dir)?;
                    return FileRecorder::start(store, lock, identity);
                }
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(FolderError::Io { dir, source: e }),
            }
        }
        Err(FolderError::Io {
            dir: parent.join(base),
            source: io::Error::other("10 000 sessions of this sample in one second"),
        })
    }

    /// The first `session.json` (status running, run 1) and the `readings.csv` header.
    fn start(
        mut store: Store,
        lock: FolderLock,
        identity: Identity,
    ) -> Result<FileRecorder, FolderError> {
        let dir = store.dir().to_path_buf();
        let doc = SessionDoc {
            schema: crate::schema::SESSION.into(),
            status: Status::Running,
            why: None,
            resume_with: None,
            sample: identity.sample,
            instrument: identity.instrument,
            device: identity.device,
            plan: identity.plan,
            runs: vec![new_run(1, 0)],
            readings_recorded: 0,
            case: identity.case,
            rest: serde_json::Map::new(),
        };
        store
            .replace(SESSION, &json_bytes(&doc).map_err(io_error(&dir))?)
            .map_err(io_error(&dir))?;
        store
            .append(
                READINGS,
                format!("{READINGS_HEADER}\n").as_bytes(),
                Sync::Never,
            )
            .map_err(io_error(&dir))?;
        let mut recorder = FileRecorder {
            store,
            _lock: lock,
            doc,
            bar: progress_bar(),
            decisions: Vec::new(),
            points: Vec::new(),
            failed: None,
            folder_bytes: folder_size(&dir),
        };
        recorder.decision(&format!(
            "session of '{}' on instrument {} in {}",
            recorder.doc.sample,
            recorder.doc.instrument.serial_number,
            dir.display()
        ));
        Ok(recorder)
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        self.store.dir()
    }

    /// The session document as last written (or about to be).
    pub fn doc(&self) -> &SessionDoc {
        &self.doc
    }

    /// Readings recorded in `points.jsonl`, earlier runs included.
    pub fn readings(&self) -> usize {
        self.points.len()
    }

    /// The command that continues this session, for `session.json` and the messages.
    pub(crate) fn set_resume_with(&mut self, command: String) {
        self.doc.resume_with = Some(command);
    }

    fn close_run(&mut self, outcome: RunOutcome, why: Option<String>) {
        let readings = self.points.len();
        let decisions = self.decisions.clone();
        if let Some(run) = self.doc.runs.last_mut() {
            run.ended = Some(local_now());
            run.outcome = outcome;
            run.why = why;
            run.readings_after = Some(readings);
            run.decisions = decisions;
        }
        self.doc.readings_recorded = readings;
    }

    /// The session finished: the summary files (`files`: name and bytes), then
    /// `session.json` with status finished, what `finished` holds (the readings, fits,
    /// result, ok, flags…) and every run's decisions, then the manifest. Nothing is written
    /// into the folder after it.
    pub(crate) fn finish(
        &mut self,
        finished: &FinishedSession<'_>,
        files: &[(String, Vec<u8>)],
    ) -> io::Result<()> {
        self.check_failed()?;
        self.decision("session finished: result in session.json, checksums in MANIFEST.sha256");
        self.check_failed()?;
        for (name, bytes) in files {
            self.store.replace(name, bytes)?;
        }
        self.close_run(RunOutcome::Finished, None);
        self.doc.status = Status::Finished;
        self.doc.why = None;
        self.doc.resume_with = None;
        let closing = Closing {
            finished,
            decisions: self
                .doc
                .runs
                .iter()
                .flat_map(|r| r.decisions.iter().map(String::as_str))
                .collect(),
        };
        self.doc.rest = serde_json::from_value(serde_json::to_value(&closing)?)?;
        self.store.replace(SESSION, &json_bytes(&self.doc)?)?;
        self.store.sync_all()?;
        write_manifest(&mut self.store)
    }

    /// The session stopped (`status` failed or interrupted) for `why`: the decision log,
    /// then `session.json` with the status, why and how to resume.
    pub fn stop(&mut self, status: Status, why: &str) -> io::Result<()> {
        self.decision(&format!("session stopped ({status}): {why}"));
        self.close_run(
            if status == Status::Interrupted {
                RunOutcome::Interrupted
            } else {
                RunOutcome::Failed
            },
            Some(why.to_string()),
        );
        self.doc.status = status;
        self.doc.why = Some(why.to_string());
        self.store.replace(SESSION, &json_bytes(&self.doc)?)?;
        self.store.sync_all()?;
        self.check_failed()
    }

    fn check_failed(&mut self) -> io::Result<()> {
        match self.failed.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    fn log(&mut self, text: &str) {
        let run = self.doc.runs.last().map_or(0, |r| r.run);
        let line = format!(
            "{} [run {run}] {}\n",
            local_now(),
            text.replace(['\n', '\r'], " / ")
        );
        self.folder_bytes += line.len() as u64;
        if let Err(e) = self.store.append(LOG, line.as_bytes(), Sync::Never) {
            self.failed.get_or_insert(e);
        }
    }
}

/// The parts a finished session adds to `session.json`: the caller's, and the decisions of
/// every run.
#[derive(serde::Serialize)]
struct Closing<'a> {
    #[serde(flatten)]
    finished: &'a FinishedSession<'a>,
    decisions: Vec<&'a str>,
}

fn new_run(run: u32, readings_before: usize) -> Run {
    Run {
        run,
        started: local_now(),
        ended: None,
        host_version: HOST_VERSION.into(),
        outcome: RunOutcome::Running,
        why: None,
        readings_before,
        readings_after: None,
        decisions: Vec::new(),
    }
}

/// Write `MANIFEST.sha256` for everything in the folder, then its signature (when the
/// store has a key).
fn write_manifest(store: &mut Store) -> io::Result<()> {
    let text = crate::output::folder::manifest::manifest_text(store.dir())?;
    store.replace(MANIFEST, text.as_bytes())?;
    crate::output::folder::signature::sign_manifest(store, text.as_bytes())
}

/// An existing folder taken for `--out`: it must be empty, but for temporary files a
/// killed gonio left before its session began (removed; their names returned).
fn take_empty(store: &mut Store, dir: &Path) -> Result<Vec<String>, FolderError> {
    let names = folder::entries(dir).map_err(io_error(dir))?;
    if names.iter().any(|n| n == SESSION) {
        // A session.json that cannot be read is still not an empty folder (below).
        if let Ok(Some(doc)) = folder::read_session(dir) {
            return Err(FolderError::OtherSession {
                dir: dir.to_path_buf(),
                sample: doc.sample,
                serial: doc.instrument.serial_number,
                started: doc
                    .runs
                    .first()
                    .map_or_else(|| "?".into(), |r| r.started.clone()),
                status: doc.status,
            });
        }
    }
    let others: Vec<&String> = names.iter().filter(|n| !folder::is_temp_name(n)).collect();
    if !others.is_empty() {
        let mut listed = others
            .iter()
            .take(3)
            .map(|s| s.as_str())
            .collect::<Vec<_>>()
            .join(", ");
        if others.len() > 3 {
            listed += &format!(" and {} more", others.len() - 3);
        }
        return Err(FolderError::NotEmpty {
            dir: dir.to_path_buf(),
            entries: listed,
        });
    }
    for name in &names {
        store.remove(name).map_err(io_error(dir))?;
    }
    Ok(names)
}

/// A folder to resume, read and checked, not yet changed.
pub struct Existing {
    inspection: Inspection,
    doc: SessionDoc,
    lock: FolderLock,
}

impl Existing {
    /// Read `dir` for `--resume`: refuses a folder that is missing, holds no session, is in
    /// use, is damaged beyond what a crash leaves, or holds a finished session (whose
    /// manifest is written first if a crash kept it from being written).
    pub fn open(dir: &Path, options: StoreOptions) -> Result<Existing, FolderError> {
        if !dir.exists() {
            return Err(FolderError::NoFolder(dir.to_path_buf()));
        }
        if !dir.is_dir() {
            return Err(FolderError::NotAFolder(dir.to_path_buf()));
        }
        let lock = FolderLock::take(dir)?;
        folder::refuse_links(dir).map_err(FolderError::Damaged)?;
        let inspection = folder::inspect(dir).map_err(FolderError::Damaged)?;
        if let Some(problem) = inspection.damage.first() {
            return Err(FolderError::Damaged(problem.clone()));
        }
        let Some(doc) = inspection.session.clone() else {
            return Err(FolderError::NoSession(dir.to_path_buf()));
        };
        if doc.status == Status::Finished {
            if !dir.join(MANIFEST).exists() {
                // Killed between the result and its manifest: finish the closing.
                let mut store = Store::open_dir(dir, options);
                for name in &inspection.temp_files {
                    store.remove(name).map_err(io_error(dir))?;
                }
                write_manifest(&mut store).map_err(io_error(dir))?;
            } else {
                // Killed between the manifest and its signature: sign the folder as its
                // manifest holds it (never a folder changed since).
                let mut store = Store::open_dir(dir, options);
                let whole = crate::output::folder::manifest::check(dir).is_ok();
                crate::output::folder::signature::sign_if_unsigned(&mut store, whole)
                    .map_err(io_error(dir))?;
            }
            return Err(FolderError::Finished {
                dir: dir.to_path_buf(),
                sample: doc.sample.clone(),
                class: doc
                    .outcome()
                    .result()
                    .and_then(|r| r.class())
                    .map(str::to_string),
                ended: doc
                    .runs
                    .last()
                    .and_then(|r| r.ended.clone())
                    .unwrap_or_else(|| "?".into()),
            });
        }
        Ok(Existing {
            inspection,
            doc,
            lock,
        })
    }

    /// The session document.
    pub fn doc(&self) -> &SessionDoc {
        &self.doc
    }

    /// The calibration the session's readings were converted with, if it has one.
    pub fn calibration(&self) -> Option<&Calibration> {
        self.inspection.calibration.as_ref()
    }

    /// The readings recorded (whole lines of `points.jsonl`).
    pub fn points(&self) -> &[MeasuredPoint] {
        &self.inspection.points
    }

    /// Refuse to go on with another sample, instrument or plan, naming each difference.
    pub(crate) fn check_matches(&self, identity: &Identity) -> Result<(), FolderError> {
        let differences = differences(&self.doc, identity);
        if differences.is_empty() {
            Ok(())
        } else {
            Err(FolderError::Mismatch {
                dir: self.inspection.dir.clone(),
                differences,
            })
        }
    }

    /// Repair what a crash left and open the folder for a new run: temporary files removed,
    /// a cut-off last line of `points.jsonl` or `session.log` dropped, `readings.csv`
    /// rebuilt from `points.jsonl` when behind it, runs that never ended marked killed; each
    /// repair is a decision of the new run. Returns the recorder and the readings taken.
    pub fn resume(
        self,
        options: StoreOptions,
    ) -> Result<(FileRecorder, Vec<MeasuredPoint>, Option<Calibration>), FolderError> {
        let Existing {
            inspection,
            mut doc,
            lock,
        } = self;
        let dir = inspection.dir.clone();
        let mut store = Store::open_dir(&dir, options);
        let mut repairs = Vec::new();
        for name in &inspection.temp_files {
            store.remove(name).map_err(io_error(&dir))?;
            repairs.push(format!(
                "removed {name}, a temporary file left by a run that was killed while replacing {}",
                name.trim_start_matches('.').trim_end_matches(".gonio-tmp")
            ));
        }
        for (name, file) in [(POINTS, &inspection.points_file), (LOG, &inspection.log)] {
            if let Some(tail) = &file.cut_tail {
                store
                    .truncate(name, file.whole_len)
                    .map_err(io_error(&dir))?;
                let shown: String = String::from_utf8_lossy(tail).chars().take(60).collect();
                let what = if name == POINTS {
                    "; its reading is measured again"
                } else {
                    ""
                };
                repairs.push(format!("{name}: removed its last line, cut short by a crash after {} bytes ('{shown}…'){what}", tail.len()));
            }
        }
        match inspection.csv {
            CsvAgreement::Agrees => {}
            CsvAgreement::Behind { missing, cut } => {
                store
                    .replace(
                        READINGS,
                        folder::readings_csv(&inspection.points).as_bytes(),
                    )
                    .map_err(io_error(&dir))?;
                repairs.push(format!(
                    "{READINGS}: rebuilt from {POINTS} ({missing} rows were missing{})",
                    if cut { ", the last one cut short" } else { "" }
                ));
            }
            CsvAgreement::Stale { superseded } => {
                store
                    .replace(
                        READINGS,
                        folder::readings_csv(&inspection.points).as_bytes(),
                    )
                    .map_err(io_error(&dir))?;
                repairs.push(format!("{READINGS}: rebuilt from {POINTS} and {CALIBRATION} (it held rows from before {superseded} readings were superseded or the calibration changed)"));
            }
            CsvAgreement::Differs(problem) => return Err(FolderError::Damaged(problem)),
        }
        // A folder written before readings.csv named the angles' unit: rows appended now
        // are in the current form, so the file is rewritten in it first.
        let legacy = std::fs::read_to_string(dir.join(READINGS))
            .ok()
            .and_then(|text| text.lines().next().map(folder::is_legacy_header))
            .unwrap_or(false);
        if legacy {
            store
                .replace(
                    READINGS,
                    folder::readings_csv(&inspection.points).as_bytes(),
                )
                .map_err(io_error(&dir))?;
            repairs.push(format!(
                "{READINGS}: rewritten with the angles' unit in its header and the angles rounded to 0.0001°"
            ));
        }
        for run in doc
            .runs
            .iter_mut()
            .filter(|r| r.outcome == RunOutcome::Running)
        {
            run.outcome = RunOutcome::Killed;
            run.why = Some(
                "the process ended without closing its run (killed, or the machine lost power)"
                    .into(),
            );
            run.decisions = folder::logged_decisions(&inspection.log, run.run);
            repairs.push(format!(
                "run {} ended without closing (killed, or power lost): marked killed",
                run.run
            ));
        }
        let readings = inspection.points.len();
        let number = doc.runs.last().map_or(1, |r| r.run + 1);
        doc.runs.push(new_run(number, readings));
        doc.status = Status::Running;
        doc.why = None;
        doc.readings_recorded = readings;
        store
            .replace(SESSION, &json_bytes(&doc).map_err(io_error(&dir))?)
            .map_err(io_error(&dir))?;
        let mut recorder = FileRecorder {
            store,
            _lock: lock,
            doc,
            bar: progress_bar(),
            decisions: Vec::new(),
            points: inspection.points.clone(),
            failed: None,
            folder_bytes: folder_size(&dir),
        };
        recorder.decision(&format!(
            "resuming {} (run {number}): {readings} readings already taken",
            dir.display()
        ));
        for repair in repairs {
            recorder.decision(&format!("repaired: {repair}"));
        }
        Ok((recorder, inspection.points, inspection.calibration))
    }
}

/// What differs between a session and the one asked for, in words.
pub fn differences(doc: &SessionDoc, wanted: &Identity) -> Vec<String> {
    let mut out = Vec::new();
    let mut differ = |what: &str, was: String, now: String| {
        if was != now {
            out.push(format!(
                "the {what} differs (the session: {was}; now: {now})"
            ));
        }
    };
    differ(
        "sample",
        format!("'{}'", doc.sample),
        format!("'{}'", wanted.sample),
    );
    differ(
        "instrument",
        format!("serial {}", doc.instrument.serial_number),
        format!("serial {}", wanted.instrument.serial_number),
    );
    let simulated = |s: &Option<String>| {
        s.as_ref()
            .map_or_else(|| "none".to_string(), |s| format!("'{s}'"))
    };
    differ(
        "simulated sample",
        simulated(&doc.instrument.simulated_sample),
        simulated(&wanted.instrument.simulated_sample),
    );
    let (a, b) = (&doc.plan, &wanted.plan);
    differ("policy", a.policy.clone(), b.policy.clone());
    differ(
        "adaptive policy's targets",
        format!("{:?}", a.adaptive_targets),
        format!("{:?}", b.adaptive_targets),
    );
    differ(
        "integration time",
        format!("{} ms", a.integration_ms),
        format!("{} ms", b.integration_ms),
    );
    differ(
        "detector acceptance",
        format!("{}°", a.acceptance_deg),
        format!("{}°", b.acceptance_deg),
    );
    differ(
        "white check",
        (if a.white_check { "on" } else { "off" }).into(),
        (if b.white_check { "on" } else { "off" }).into(),
    );
    differ(
        "white drift limit",
        format!("{} %", a.white_drift_limit_pct),
        format!("{} %", b.white_drift_limit_pct),
    );
    // A plan recorded before the model was is the paper's model's (`PlanRecord::model`).
    let model = |p: &PlanRecord| {
        p.model_choice()
            .map_or_else(|_| format!("{:?}", p.model), |m| m.name().to_string())
    };
    differ("model", model(a), model(b));
    // Case fields given again must be the session's; left out, the session's stand.
    if let Some(case) = wanted.case.as_ref().filter(|c| !c.is_empty()) {
        let theirs = doc.case.clone().unwrap_or_default();
        let text = |v: &Option<String>| {
            v.as_ref()
                .map_or_else(|| "none".to_string(), |s| format!("'{s}'"))
        };
        for (what, now, was) in [
            ("case", &case.case_id, &theirs.case_id),
            ("operator", &case.operator, &theirs.operator),
            ("note", &case.note, &theirs.note),
        ] {
            if now.is_some() {
                differ(what, text(was), text(now));
            }
        }
    }
    out
}

impl Recorder for FileRecorder {
    fn calibration(&mut self, calibration: &Calibration) -> io::Result<()> {
        self.check_failed()?;
        self.store
            .replace(CALIBRATION, &json_bytes(&calibration.to_document()?)?)?;
        // A new calibration (gain ratios calibrated on the sample) converts the readings
        // taken anew: readings.csv follows (a crash before leaves it stale, which a resume
        // rebuilds).
        if !self.points.is_empty() {
            self.points = folder::converted(&self.points, Some(calibration));
            self.store
                .replace(READINGS, folder::readings_csv(&self.points).as_bytes())?;
        }
        Ok(())
    }

    fn sweep_done(&mut self) -> io::Result<()> {
        self.check_failed()?;
        self.store.sync_file(POINTS)
    }

    fn point(&mut self, point: &MeasuredPoint) -> io::Result<()> {
        self.check_failed()?;
        // The primary record first, synced (a sweep's bins at its end: `sweep_done`); the
        // CSV row after it is derived from it.
        let sync = if point.theta_r_span_deg > 0.0 {
            Sync::Never
        } else {
            Sync::Data
        };
        if self.folder_bytes > crate::session::bounds::MAX_FOLDER_BYTES {
            return Err(io::Error::other(crate::session::bounds::FolderFull {
                bytes: self.folder_bytes,
            }));
        }
        let line = folder::point_line(point)?;
        self.store.append(POINTS, line.as_bytes(), sync)?;
        self.folder_bytes += line.len() as u64;
        let header_before = folder::readings_header(&self.points);
        self.points.push(point.clone());
        let header = folder::readings_header(&self.points);
        if header != header_before {
            // The first reading taken while moving: readings.csv gains its span column
            // (rewritten whole; a crash before leaves it stale, which a resume rebuilds).
            return self
                .store
                .replace(READINGS, folder::readings_csv(&self.points).as_bytes());
        }
        if let Some(row) = folder::csv_row(point, header) {
            self.folder_bytes += row.len() as u64;
            self.store.append(READINGS, row.as_bytes(), Sync::Never)?;
        }
        Ok(())
    }

    fn superseded(&mut self, points: &[MeasuredPoint], why: &str) -> io::Result<()> {
        self.check_failed()?;
        // A reading is known by where and when it streamed: schedule, index, device time.
        let key = |p: &MeasuredPoint| (p.schedule_id, p.index, p.device_time_us);
        let mut positions = Vec::new();
        for point in points {
            let found = self
                .points
                .iter()
                .position(|p| key(p) == key(point))
                .ok_or_else(|| {
                    io::Error::new(
                        io::ErrorKind::InvalidInput,
                        format!(
                            "superseding a reading that was never recorded (θi {}°, θr {}°)",
                            point.theta_i_deg, point.theta_r_deg
                        ),
                    )
                })?;
            positions.push(found);
        }
        positions.sort_unstable();
        positions.dedup();
        let mark = folder::SupersedeMark {
            superseded: positions,
            why: why.to_string(),
        };
        // The primary record first (synced), then readings.csv rebuilt without those rows: a
        // crash between the two leaves it stale, which a resume rebuilds.
        self.store
            .append(POINTS, folder::mark_line(&mark)?.as_bytes(), Sync::Data)?;
        for &k in &mark.superseded {
            self.points[k].superseded = true;
        }
        self.store
            .replace(READINGS, folder::readings_csv(&self.points).as_bytes())
    }

    fn stage(&mut self, what: &str, planned: usize) {
        self.bar.set_style(geometries_style());
        self.bar.set_message(what.to_string());
        self.bar.set_length(planned as u64);
        self.bar.set_position(0);
        self.bar.set_prefix("?");
    }

    fn progress(&mut self, progress: Progress) {
        self.bar.set_position(progress.done as u64);
        self.bar
            .set_prefix(format!("{:.1}", progress.remaining.as_secs_f64()));
    }

    fn decision(&mut self, text: &str) {
        // A hidden bar (stderr not a terminal) prints nothing: say it plainly then.
        if self.bar.is_hidden() {
            eprintln!("  {text}");
        } else {
            self.bar.println(format!("  {text}"));
        }
        self.decisions.push(text.to_string());
        self.log(text);
    }
}

/// Every reading recorded in `dir/points.jsonl`, refusing any damage (a cut-off last line
/// included: [`Existing::resume`] is what repairs it).
pub(crate) fn read_points(dir: &Path) -> Result<Vec<MeasuredPoint>, Finding> {
    let path = dir.join(POINTS);
    let file = folder::read_lines(&path)?;
    if file.cut_tail.is_some() {
        return Err(Finding {
            file: path,
            line: Some(file.lines.len() + 1),
            message:
                "last line cut short (a crash while writing it): gonio measure --resume repairs it"
                    .into(),
        });
    }
    folder::parse_points(&path, &file)
}
