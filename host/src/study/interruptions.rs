//! The interruption campaign (issue 30): whole sheets (`gonio measure --spots N` on the
//! simulated instrument, in process, into real folders) interrupted one, two or three
//! times in a row, each interruption followed by a resume, then resumed to the end.
//!
//! An interruption is drawn among what can be injected in process:
//! - **kill**: the process killed at a write drawn at random ([`Crash::at`]: a prefix of
//!   that write reaches the file, then nothing more);
//! - **Ctrl-C**: the operator's interruption at a write drawn at random
//!   ([`Crash::interrupt_at`]: the flag the binary's SIGINT handler sets);
//! - **give-up**: the cable pulled for good at a device time drawn at random
//!   (`--faults unplug-at=T:60`): the session gives up after its 10 s without a word.
//!
//! Each run is aimed at a share of the sheet's work (a draw over the writes or the device
//! time of an uninterrupted sheet, divided by the interruptions planned), so that the
//! interruptions fall anywhere in the sheet; a run that finishes before its draw ends the
//! sequence (the interruptions that happened are counted, not those drawn).
//!
//! A session **holds** when its final folder verifies (`gonio verify`, the signatures of
//! the sheet and every spot by the campaign's key included), every spot's plan
//! is the sheet's (and the sheet's the policy drawn), and nothing measured was lost: the
//! whole lines of every spot's `points.jsonl` after each interruption are the first lines
//! of the final one. Every draw comes from the session's index and the campaign's seed.
use crate::measure::{MeasureOptions, Measured, measure_with};
use crate::output::folder::lock::FolderError;
use crate::output::folder::store::{Crash, StoreOptions};
use crate::session::{PolicyChoice, SessionError, SimulatedOperator};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

/// The papers: a glossy one refined at length under every policy, a semi-gloss, a rough one.
pub const SAMPLES: [&str; 3] = ["G", "SG", "PPC"];

/// The policies of a sheet.
pub const POLICIES: [PolicyChoice; 3] = [
    PolicyChoice::Sweep,
    PolicyChoice::Adaptive,
    PolicyChoice::Paper,
];

/// One session in this many is the README's main job: `gonio measure --sim G --policy
/// sweep`, the sheet of the default number of spots (no `--spots`).
pub const MAIN_JOB_EVERY: usize = 6;

/// One interruption.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interruption {
    /// The process killed at a write.
    Kill,
    /// Ctrl-C at a write.
    CtrlC,
    /// The cable pulled for good: the session gives up.
    GiveUp,
}

impl Interruption {
    /// Its name in the campaign's files.
    pub fn name(self) -> &'static str {
        match self {
            Interruption::Kill => "kill",
            Interruption::CtrlC => "ctrl-c",
            Interruption::GiveUp => "give-up",
        }
    }
}

/// One session of the campaign, as drawn.
#[derive(Clone, Debug)]
pub struct Spec {
    /// Its index in the campaign.
    pub index: usize,
    /// The paper.
    pub sample: &'static str,
    /// The sheet's policy.
    pub policy: PolicyChoice,
    /// Spots of the sheet (2 or 3; the default's for the main job).
    pub spots: u16,
    /// The README's main job (`--sim G --policy sweep`, no `--spots`).
    pub main_job: bool,
    /// The simulator's seed of the first run (each run adds its number).
    pub seed: u64,
    /// The interruptions drawn, with where each falls in its run's share (0–1).
    pub interruptions: Vec<(Interruption, f64)>,
}

/// Draw session `index` of the campaign of `seed`.
pub fn draw(index: usize, seed: u64) -> Spec {
    let mut rng =
        ChaCha12Rng::seed_from_u64(seed ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let main_job = index % MAIN_JOB_EVERY == MAIN_JOB_EVERY - 1;
    let sample = SAMPLES[rng.random_range(0..SAMPLES.len())];
    let policy = POLICIES[index % POLICIES.len()];
    let spots = rng.random_range(2..=3);
    let (sample, policy, spots) = if main_job {
        ("G", PolicyChoice::Sweep, crate::measure::DEFAULT_SPOTS)
    } else {
        (sample, policy, spots)
    };
    let count = 1 + (index / POLICIES.len()) % 3;
    let kinds = [
        Interruption::Kill,
        Interruption::CtrlC,
        Interruption::GiveUp,
    ];
    let interruptions = (0..count)
        .map(|_| {
            (
                kinds[rng.random_range(0..kinds.len())],
                rng.random_range(0.0..1.0),
            )
        })
        .collect();
    Spec {
        index,
        sample,
        policy,
        spots,
        main_job,
        seed: rng.random_range(1..1_000_000),
        interruptions,
    }
}

/// An uninterrupted sheet of a paper, policy and spot count: its writes and device time.
#[derive(Clone, Copy, Debug)]
pub struct Clean {
    /// Writes into its folders.
    pub writes: u64,
    /// Device time of its spots (setup included), seconds.
    pub device_s: f64,
}

/// What became of one session.
#[derive(Clone, Debug)]
pub struct Row {
    /// What was drawn.
    pub spec: Spec,
    /// The interruptions that happened, in order ("kill@W", "ctrl-c@W", "give-up@T s").
    pub happened: Vec<String>,
    /// Runs made (the interrupted ones and the last).
    pub runs: usize,
    /// Why it did not hold (`None`: it held).
    pub failure: Option<String>,
}

fn options(spec: &Spec, run: usize, dir: &Path, fresh: bool) -> MeasureOptions {
    let mut options = MeasureOptions {
        sim: Some(spec.sample.to_string()),
        ..MeasureOptions::default()
    };
    options.sim_options.seed = spec.seed + run as u64;
    if fresh {
        options.out = Some(dir.to_path_buf());
        options.policy = Some(spec.policy);
        // The main job as the README gives it: the sheet's spots by default.
        options.spots = (!spec.main_job).then_some(spec.spots);
    } else {
        // The sheet's plan is its own: a resume gives no option of it.
        options.resume = Some(dir.to_path_buf());
    }
    options
}

/// Run an uninterrupted sheet of `sample`, `policy`, `spots` in `dir` (removed after).
pub fn clean(
    sample: &'static str,
    policy: PolicyChoice,
    spots: u16,
    dir: &Path,
) -> Result<Clean, String> {
    let spec = Spec {
        index: 0,
        sample,
        policy,
        spots,
        main_job: false,
        seed: 1,
        interruptions: Vec::new(),
    };
    let _ = std::fs::remove_dir_all(dir);
    let counting = Crash::counting();
    let measured = measure_with(
        &options(&spec, 0, dir, true),
        &mut SimulatedOperator,
        Arc::new(AtomicBool::new(false)),
        // Signed as every interrupted run is, so the writes counted (where kills are drawn)
        // include the signatures'.
        store_options(&spec, Some(counting.clone())),
    );
    let clean = match measured {
        Ok(Measured::Sheet { sheet, .. }) => Ok(Clean {
            writes: counting.writes(),
            device_s: sheet
                .doc
                .result
                .as_ref()
                .map_or(0.0, |r| r.device_seconds + r.setup_seconds),
        }),
        Ok(_) => Err("not a sheet".to_string()),
        Err(e) => Err(format!("{e:#}")),
    };
    let _ = std::fs::remove_dir_all(dir);
    clean
}

/// How a run ended.
enum Ended {
    /// The sheet is finished.
    Finished,
    /// It stopped or was killed.
    Interrupted,
}

fn ended(measured: anyhow::Result<Measured>) -> Result<Ended, String> {
    match measured {
        Ok(Measured::Sheet { .. }) => Ok(Ended::Finished),
        Ok(Measured::Done { .. }) => Err("measured one spot, not a sheet".into()),
        Ok(Measured::Stopped { .. }) => Ok(Ended::Interrupted),
        Err(e) if e.to_string().contains("finished sheet") => Ok(Ended::Finished),
        Err(e) => match e.downcast_ref::<FolderError>() {
            Some(FolderError::Finished { .. }) => Ok(Ended::Finished),
            _ => Err(format!("{e:#}")),
        },
    }
}

/// The whole lines of every spot's `points.jsonl` in the sheet `dir`, by spot folder.
fn spot_lines(dir: &Path) -> BTreeMap<String, Vec<String>> {
    let mut out = BTreeMap::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return out;
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if !entry.path().is_dir() {
            continue;
        }
        let text = std::fs::read_to_string(entry.path().join("points.jsonl")).unwrap_or_default();
        let whole = text.rfind('\n').map_or("", |i| &text[..=i]);
        out.insert(name, whole.lines().map(str::to_string).collect());
    }
    out
}

fn json(path: &Path) -> Result<serde_json::Value, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// The campaign's signing key, as a lab's would sign: every run of a sheet (the first, each
/// resume) signs with it, and the final folder must verify under it, the sheet and every
/// spot. Derived from the sheet's seed so a row repeats; a key, not a secret.
fn campaign_signer(seed: u64) -> crate::output::folder::signature::Signer {
    let mut bytes = [0u8; 32];
    ChaCha12Rng::seed_from_u64(seed ^ 0x5157_4e45_4452_3235).fill(&mut bytes[..]);
    crate::output::folder::signature::Signer::new(
        "interruption-campaign",
        ed25519_dalek::SigningKey::from_bytes(&bytes),
    )
}

/// Store options of every run of the sheet `spec`: signed with the campaign's key.
fn store_options(spec: &Spec, crash: Option<Crash>) -> StoreOptions {
    StoreOptions {
        crash,
        signer: Some(Arc::new(campaign_signer(spec.seed))),
    }
}

/// The final checks: the folder verifies, its signatures (the sheet's and every spot's) are
/// the campaign key's, every spot under the sheet's plan, nothing lost.
fn check(
    spec: &Spec,
    dir: &Path,
    snapshots: &[BTreeMap<String, Vec<String>>],
) -> Result<(), String> {
    let verified = crate::output::folder::verify::verify_sheet(dir, crate::output::report::draw)
        .map_err(|problems| {
            format!(
                "does not verify: {}",
                problems
                    .iter()
                    .map(ToString::to_string)
                    .collect::<Vec<_>>()
                    .join("; ")
            )
        })?;
    let key =
        crate::output::folder::signature::hex(campaign_signer(spec.seed).public_key().as_bytes());
    let signed_by_campaign = |signed: &Option<crate::output::folder::signature::Signed>| {
        signed.as_ref().is_some_and(|s| s.public_key == key)
    };
    if !signed_by_campaign(&verified.signed) {
        return Err(format!(
            "the sheet is not signed by the campaign's key: {:?}",
            verified.signed
        ));
    }
    if let Some(spot) = verified
        .spots
        .iter()
        .find(|v| !signed_by_campaign(&v.signed))
    {
        return Err(format!(
            "{} is not signed by the campaign's key: {:?}",
            spot.dir.display(),
            spot.signed
        ));
    }
    let sheet = json(&dir.join("sheet.json"))?;
    let plan = &sheet["plan"];
    if plan["policy"] != spec.policy.name() {
        return Err(format!(
            "the sheet's plan is not the policy drawn ({}): {plan}",
            spec.policy.name()
        ));
    }
    let spots = sheet["spots"].as_array().cloned().unwrap_or_default();
    if spots.is_empty() {
        return Err("no spot in sheet.json".into());
    }
    for spot in &spots {
        let folder = spot["folder"].as_str().unwrap_or_default();
        let session = json(&dir.join(folder).join("session.json"))?;
        if session["plan"] != *plan {
            return Err(format!(
                "{folder} was measured under another plan than the sheet's: {} against {plan}",
                session["plan"]
            ));
        }
    }
    let now = spot_lines(dir);
    for (k, snapshot) in snapshots.iter().enumerate() {
        for (folder, before) in snapshot {
            let after = now.get(folder).map_or(&[][..], Vec::as_slice);
            if after.len() < before.len() || after[..before.len()] != before[..] {
                return Err(format!(
                    "{folder}/points.jsonl lost or changed readings recorded before interruption {}",
                    k + 1
                ));
            }
        }
    }
    Ok(())
}

/// Run session `spec` in `base` against its uninterrupted twin `clean`.
pub fn run_one(spec: &Spec, base: &Path, clean: Clean) -> Row {
    let dir = base.join(format!("interruptions-{}", spec.index));
    let _ = std::fs::remove_dir_all(&dir);
    let mut row = Row {
        spec: spec.clone(),
        happened: Vec::new(),
        runs: 0,
        failure: None,
    };
    let share = 1.0 / spec.interruptions.len().max(1) as f64;
    let mut snapshots = Vec::new();
    let mut finished = false;
    let result = (|| -> Result<(), String> {
        for &(kind, at) in &spec.interruptions {
            let fresh = !dir.join("sheet.json").exists();
            let mut options = options(spec, row.runs, &dir, fresh);
            if fresh {
                // Killed before the sheet's first document: nothing was measured, and the
                // folder is started again.
                let _ = std::fs::remove_dir_all(&dir);
            }
            let interrupt = Arc::new(AtomicBool::new(false));
            let write = 1 + (at * share * clean.writes as f64) as u64;
            let unplug_s = 0.5 + at * share * clean.device_s;
            let crash = match kind {
                Interruption::Kill => Some(Crash::at(write)),
                Interruption::CtrlC => Some(Crash::interrupt_at(write, interrupt.clone())),
                Interruption::GiveUp => {
                    options.sim_options.faults = format!("unplug-at={unplug_s:.3}:60");
                    None
                }
            };
            let measured = measure_with(
                &options,
                &mut SimulatedOperator,
                interrupt,
                store_options(spec, crash.clone()),
            );
            row.runs += 1;
            let gave_up = matches!(
                &measured,
                Ok(Measured::Stopped {
                    error: SessionError::Lost { .. },
                    ..
                })
            );
            let killed = kind == Interruption::Kill && crash.as_ref().is_some_and(Crash::crashed);
            match (ended(measured), killed) {
                (Ok(Ended::Finished), true) => {
                    return Err(format!(
                        "the sheet finished through its kill at write {write}"
                    ));
                }
                (Ok(Ended::Finished), false) => {
                    finished = true;
                    break;
                }
                // A killed process ends however its last write left it.
                (Ok(Ended::Interrupted), _) | (Err(_), true) => {}
                (Err(e), false) => return Err(e),
            }
            row.happened.push(match kind {
                Interruption::GiveUp if gave_up => format!("give-up@{unplug_s:.1}s"),
                Interruption::GiveUp => format!("stopped@{unplug_s:.1}s"),
                _ => format!("{}@{write}", kind.name()),
            });
            snapshots.push(spot_lines(&dir));
        }
        if !finished {
            let fresh = !dir.join("sheet.json").exists();
            if fresh {
                let _ = std::fs::remove_dir_all(&dir);
            }
            let measured = measure_with(
                &options(spec, row.runs, &dir, fresh),
                &mut SimulatedOperator,
                Arc::new(AtomicBool::new(false)),
                store_options(spec, None),
            );
            row.runs += 1;
            match ended(measured)? {
                Ended::Finished => {}
                Ended::Interrupted => return Err("the last resume stopped".into()),
            }
        }
        check(spec, &dir, &snapshots)
    })();
    match result {
        Ok(()) => {
            let _ = std::fs::remove_dir_all(&dir);
        }
        Err(why) => row.failure = Some(format!("{why} (folder kept: {})", dir.display())),
    }
    row
}

/// Run `sessions` sessions of the campaign of `seed` on `threads` threads, in folders
/// under `base`; `progress` after each.
pub fn run_all(
    sessions: usize,
    seed: u64,
    base: &Path,
    threads: usize,
    progress: &(dyn Fn() + Sync),
) -> Result<Vec<Row>, String> {
    let specs: Vec<Spec> = (0..sessions).map(|k| draw(k, seed)).collect();
    let mut combos: Vec<(&'static str, PolicyChoice, u16)> = specs
        .iter()
        .map(|s| (s.sample, s.policy, s.spots))
        .collect();
    combos.sort_by_key(|(s, p, n)| (*s, p.name(), *n));
    combos.dedup();
    let cleans = super::parallel(&combos, threads, &|| {}, |&(sample, policy, spots)| {
        let dir = base.join(format!("clean-{sample}-{}-{spots}", policy.name()));
        clean(sample, policy, spots, &dir).map(|c| ((sample, policy.name(), spots), c))
    });
    let cleans: BTreeMap<_, _> = cleans.into_iter().collect::<Result<_, _>>()?;
    Ok(super::parallel(&specs, threads, progress, |spec| {
        run_one(
            spec,
            base,
            cleans[&(spec.sample, spec.policy.name(), spec.spots)],
        )
    }))
}

/// The campaign's rows as CSV, through the csv crate: a failure's text (quotes, commas,
/// line breaks) is quoted by construction.
pub fn to_csv(rows: &[Row]) -> String {
    let mut csv = csv::Writer::from_writer(Vec::new());
    let header = [
        "index", "sample", "policy", "spots", "main_job", "seed", "drawn", "happened", "runs",
        "held", "failure",
    ];
    // Writing to memory fails only on a record of the wrong length, which these are not.
    let _ = csv.write_record(header);
    for r in rows {
        let drawn: Vec<String> = r
            .spec
            .interruptions
            .iter()
            .map(|(k, at)| format!("{}:{at:.3}", k.name()))
            .collect();
        let _ = csv.write_record([
            r.spec.index.to_string(),
            r.spec.sample.to_string(),
            r.spec.policy.name().to_string(),
            r.spec.spots.to_string(),
            r.spec.main_job.to_string(),
            r.spec.seed.to_string(),
            drawn.join(" "),
            r.happened.join(" "),
            r.runs.to_string(),
            r.failure.is_none().to_string(),
            r.failure.clone().unwrap_or_default(),
        ]);
    }
    csv.into_inner()
        .map(|bytes| String::from_utf8_lossy(&bytes).into_owned())
        .unwrap_or_default()
}

/// The campaign's tables, in Markdown.
pub fn summary_markdown(rows: &[Row], seed: u64) -> String {
    let mut out = String::new();
    let held = rows.iter().filter(|r| r.failure.is_none()).count();
    let _ = writeln!(
        out,
        "{} sheets (campaign seed {seed}), **{held} held**: the final folder verifies, signed by the campaign's key (the sheet and every spot), every spot under the sheet's plan, nothing measured lost.\n",
        rows.len()
    );
    let _ = writeln!(
        out,
        "| policy | interruptions that happened | sheets | held |\n|---|---:|---:|---:|"
    );
    // A policy's sheets, then the README's main job (`None`).
    let kinds: Vec<(String, Option<PolicyChoice>)> = POLICIES
        .iter()
        .map(|&policy| (policy.name().to_string(), Some(policy)))
        .chain(std::iter::once((
            format!(
                "the README's main job (G, sweep, {} spots)",
                crate::measure::DEFAULT_SPOTS
            ),
            None,
        )))
        .collect();
    let of_kind = |spec: &Spec, kind: Option<PolicyChoice>| match kind {
        Some(policy) => spec.policy == policy && !spec.main_job,
        None => spec.main_job,
    };
    for (name, kind) in &kinds {
        for n in 0..=3 {
            let cell: Vec<&Row> = rows
                .iter()
                .filter(|r| of_kind(&r.spec, *kind) && r.happened.len() == n)
                .collect();
            if cell.is_empty() {
                continue;
            }
            let ok = cell.iter().filter(|r| r.failure.is_none()).count();
            let _ = writeln!(out, "| {name} | {n} | {} | {ok} |", cell.len());
        }
    }
    let mut kinds: BTreeMap<String, usize> = BTreeMap::new();
    for r in rows {
        for h in &r.happened {
            let kind = h.split('@').next().unwrap_or_default().to_string();
            *kinds.entry(kind).or_default() += 1;
        }
    }
    let total: usize = kinds.values().sum();
    let _ = writeln!(
        out,
        "\n{total} interruptions happened: {}.",
        kinds
            .iter()
            .map(|(k, n)| format!("{n} {k}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let failed: Vec<&Row> = rows.iter().filter(|r| r.failure.is_some()).collect();
    if !failed.is_empty() {
        let _ = writeln!(out, "\nFailures:\n");
        for r in failed {
            let _ = writeln!(
                out,
                "- {} {} {} spots, seed {}, {}: {}",
                r.spec.index,
                r.spec.sample,
                r.spec.policy.name(),
                r.spec.spots,
                r.happened.join(", "),
                r.failure.as_deref().unwrap_or_default()
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failure_with_quotes_commas_and_lines_is_one_csv_field() {
        let failure = "folder \"x\" failed, then:\nline two";
        let row = Row {
            spec: draw(3, 1),
            happened: vec!["kill@12".into()],
            runs: 2,
            failure: Some(failure.into()),
        };
        let text = to_csv(&[row]);
        let mut reader = csv::Reader::from_reader(text.as_bytes());
        let records: Vec<csv::StringRecord> =
            reader.records().map(|r| r.expect("a record")).collect();
        assert_eq!(records.len(), 1);
        assert_eq!(&records[0][10], failure);
        assert_eq!(&records[0][9], "false");
    }
}
