//! The pseudo-terminal campaign (issue 30): the real binary against the simulated
//! instrument on a pty, on a bad link with the cable pulled once.
//!
//! Each session spawns `gonio sim SAMPLE --faults unplug-at=T:D,corrupt=P,drop=P` (the
//! simulated instrument served on a pseudo-terminal) and `gonio measure --port PTY` on it,
//! the operator's prompts answered at once through standard input, as a person who is
//! ready. Drawn from the session's index and the campaign's seed: the paper, the policy
//! (sweep, adaptive, paper), the spots of the sheet (1–3), the byte corruption in
//! [0, 0.01], the frame loss in [0, 0.02], the unplug's moment (uniform over the simulator's
//! clock of the same session fault-free on a pty: that clock runs ahead of wall time while
//! the host talks) and its length (0.2–8 s).
//!
//! A session **ends within its bounds** when `gonio measure` exits by itself, within
//! [`wall_limit_s`] of wall time, saying how it ended: finished, given up with a stated
//! reason (in the folder's record, or the error it printed when it could not begin), or
//! stopped at a bound of the run (rounds, device time, folder size) with the bound named;
//! and no spot spent more device time, as the host counts it (on a serial port, the wall
//! clock, as on a real instrument), than [`device_limit_s`]. A session still running at
//! its wall limit is killed and is a failure of the campaign, as is an exit without a
//! stated reason.
use crate::session::PolicyChoice;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;
use serde_json::Value;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The papers: two glossy ones that the policies refine at length, two rough ones.
pub const SAMPLES: [&str; 4] = ["G", "SG", "PPC", "J1"];

/// The policies, in turn.
pub const POLICIES: [PolicyChoice; 3] = [
    PolicyChoice::Sweep,
    PolicyChoice::Adaptive,
    PolicyChoice::Paper,
];

/// The most byte corruption drawn (per byte, either way).
pub const MAX_CORRUPT: f64 = 0.01;
/// The most frame loss drawn (per frame, either way).
pub const MAX_DROP: f64 = 0.02;

/// The bound on one spot's device time: the session's own bound
/// ([`crate::session::bounds::MAX_DEVICE_SECONDS`], measuring) plus its setup (homing, the
/// calibration's white and dark readings, the spot's prompts), which that bound leaves out,
/// and the 10 s a give-up waits.
pub fn device_limit_s() -> f64 {
    crate::session::bounds::MAX_DEVICE_SECONDS + SETUP_ALLOWANCE_S
}

/// Device time outside the session's measuring bound that one spot may spend: its
/// homing and calibration (about 12 s fault-free), recoveries there on a bad link, the
/// unplug, the give-up's 10 s.
pub const SETUP_ALLOWANCE_S: f64 = 60.0;

/// The wall-time bound of a session of `spots` spots: every spot at its device bound,
/// with the simulator's device time never behind wall time by more than its own
/// heartbeat-driven pace allows (it runs ahead of wall time while the host talks, and
/// with it when the host is silent), plus 30 s per spot for the processes' start, the
/// folder's documents and a loaded machine.
pub fn wall_limit_s(spots: u16) -> f64 {
    f64::from(spots) * (device_limit_s() + 30.0)
}

/// One session of the campaign, as drawn.
#[derive(Clone, Debug)]
pub struct Spec {
    /// Its index in the campaign.
    pub index: usize,
    /// The paper.
    pub sample: &'static str,
    /// The policy.
    pub policy: PolicyChoice,
    /// Spots of the sheet (1: a session of one spot).
    pub spots: u16,
    /// The simulator's seed.
    pub seed: u64,
    /// Probability that a byte is corrupted, either way.
    pub corrupt: f64,
    /// Probability that a frame is lost, either way.
    pub drop: f64,
    /// Where the unplug falls in the session's fault-free device time (0–1).
    pub unplug_share: f64,
    /// How long the cable stays out, seconds.
    pub outage_s: f64,
}

/// Draw session `index` of the campaign of `seed`.
pub fn draw(index: usize, seed: u64) -> Spec {
    let mut rng = ChaCha12Rng::seed_from_u64(
        seed.wrapping_mul(0xD1B5_4A32_D192_ED03)
            ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
    );
    Spec {
        index,
        sample: SAMPLES[rng.random_range(0..SAMPLES.len())],
        policy: POLICIES[index % POLICIES.len()],
        spots: rng.random_range(1..=3),
        seed: rng.random_range(1..1_000_000),
        corrupt: rng.random_range(0.0..=MAX_CORRUPT),
        drop: rng.random_range(0.0..=MAX_DROP),
        unplug_share: rng.random_range(0.0..1.0),
        outage_s: rng.random_range(0.2..8.0),
    }
}

impl Spec {
    /// The unplug's device time, seconds, in a session whose fault-free twin takes
    /// `clean_s`.
    pub fn unplug_at_s(&self, clean_s: f64) -> f64 {
        self.unplug_share * clean_s
    }

    /// `gonio sim`'s `--faults`.
    pub fn faults(&self, clean_s: f64) -> String {
        format!(
            "unplug-at={:.3}:{:.3},corrupt={:.5},drop={:.5}",
            self.unplug_at_s(clean_s),
            self.outage_s,
            self.corrupt,
            self.drop
        )
    }
}

/// How a session ended.
#[derive(Clone, Debug, PartialEq)]
pub enum Ended {
    /// Every spot measured.
    Finished,
    /// The session gave up, saying why (the record's reason).
    GaveUp(String),
    /// A bound of the run stopped it, named (the record's reason).
    Bound(String),
    /// It did not end by itself within the wall bound: killed.
    Overran,
    /// It ended without a stated reason, or could not be run (what happened).
    Unexplained(String),
}

impl Ended {
    /// Its name in the campaign's files.
    pub fn name(&self) -> &'static str {
        match self {
            Ended::Finished => "finished",
            Ended::GaveUp(_) => "gave-up",
            Ended::Bound(_) => "bound",
            Ended::Overran => "overran",
            Ended::Unexplained(_) => "unexplained",
        }
    }

    /// The stated reason, if any.
    pub fn reason(&self) -> &str {
        match self {
            Ended::GaveUp(r) | Ended::Bound(r) | Ended::Unexplained(r) => r,
            _ => "",
        }
    }
}

/// What became of one session.
#[derive(Clone, Debug)]
pub struct Row {
    /// What was drawn.
    pub spec: Spec,
    /// The unplug's device time, seconds.
    pub unplug_at_s: f64,
    /// How it ended.
    pub ended: Ended,
    /// `gonio measure`'s exit status (`None`: killed).
    pub exit_code: Option<i32>,
    /// Wall time of `gonio measure`, seconds.
    pub wall_s: f64,
    /// Device time of the whole session (every spot, setup included), seconds.
    pub device_s: f64,
    /// The most device time one spot spent, seconds.
    pub max_spot_device_s: f64,
    /// The simulator's clock at the last reading, seconds (informational: it runs ahead of
    /// wall time while the host talks).
    pub sim_clock_s: f64,
    /// Spots the folder holds.
    pub spots_measured: usize,
    /// Re-measure rounds over every spot (the record's "measuring again" decisions).
    pub rounds: usize,
    /// Fail-safe stops the instrument made, over every spot.
    pub stops: u64,
    /// Reconnections, over every spot.
    pub reconnections: u64,
    /// Why the session is a failure of the campaign (`None`: it ended within its bounds).
    pub failure: Option<String>,
}

/// The simulator on a pty, killed when dropped.
struct Simulator {
    child: Child,
    path: String,
}

impl Simulator {
    fn spawn(gonio: &Path, sample: &str, seed: u64, faults: &str) -> Result<Simulator, String> {
        let mut child = Command::new(gonio)
            .args(["sim", sample, "--seed", &seed.to_string()])
            .arg(format!("--faults={faults}"))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("cannot start {} sim: {e}", gonio.display()))?;
        let mut line = String::new();
        let read = child
            .stdout
            .take()
            .map(|out| BufReader::new(out).read_line(&mut line));
        let path = line.trim().to_string();
        let simulator = Simulator { child, path };
        match read {
            Some(Ok(n)) if n > 0 && !simulator.path.is_empty() => Ok(simulator),
            _ => Err("gonio sim printed no device path".into()),
        }
    }
}

impl Drop for Simulator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Read a child's pipe to its end on a thread (so that it never blocks on a full pipe).
fn drain(pipe: Option<impl Read + Send + 'static>) -> std::thread::JoinHandle<String> {
    std::thread::spawn(move || {
        let mut text = String::new();
        if let Some(mut pipe) = pipe {
            let mut bytes = Vec::new();
            let _ = pipe.read_to_end(&mut bytes);
            text = String::from_utf8_lossy(&bytes).into_owned();
        }
        text
    })
}

fn json(path: &Path) -> Option<Value> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

/// What the record says of a folder: per-spot figures and how the last run ended.
#[derive(Default)]
struct Record {
    /// Per spot, the host's device time (on a serial port the host's clock is wall time,
    /// as a real instrument's is): the result's measuring and setup seconds, or for a spot
    /// that stopped its last run's span.
    device_s: Vec<f64>,
    /// The simulator's clock at the last reading (it runs ahead of wall time while the
    /// host talks: informational only).
    sim_clock_s: f64,
    rounds: usize,
    stops: u64,
    reconnections: u64,
    /// The status and stated reason of a spot that did not finish.
    stopped: Option<(String, String)>,
    finished: bool,
}

/// A session document's decisions: its own list (a finished session's), else every run's.
fn decisions(doc: &Value) -> Vec<String> {
    let own = doc["decisions"].as_array().map(|d| {
        d.iter()
            .filter_map(Value::as_str)
            .map(str::to_string)
            .collect::<Vec<_>>()
    });
    own.unwrap_or_else(|| {
        doc["runs"]
            .as_array()
            .into_iter()
            .flatten()
            .flat_map(|run| run["decisions"].as_array().cloned().unwrap_or_default())
            .filter_map(|d| d.as_str().map(str::to_string))
            .collect()
    })
}

/// The device clock of the last reading in a spot's `points.jsonl`, seconds (the
/// simulator's clock runs on from spot to spot of a sheet).
fn last_reading_s(dir: &Path) -> f64 {
    let text = std::fs::read_to_string(dir.join("points.jsonl")).unwrap_or_default();
    text.lines()
        .filter_map(|line| serde_json::from_str::<Value>(line).ok())
        .filter_map(|p| p["device_time_us"].as_f64())
        .fold(0.0, f64::max)
        * 1e-6
}

/// A spot's device time as the host reckons it: its result's measuring and setup seconds
/// (waiting for the operator left out, as the session's bound counts), or, for a spot that
/// stopped (no result), the wall span of its runs.
fn host_device_s(doc: &Value) -> f64 {
    let result = &doc["result"];
    let seconds = |v: &Value| v.as_f64().unwrap_or(0.0);
    let from_result = seconds(&result["device_seconds"]) + seconds(&result["setup_seconds"]);
    if from_result > 0.0 {
        return from_result;
    }
    let time = |v: &Value| {
        v.as_str()
            .and_then(|t| chrono::DateTime::parse_from_rfc3339(t).ok())
    };
    doc["runs"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|run| {
            let (start, end) = (time(&run["started"])?, time(&run["ended"])?);
            Some((end - start).num_milliseconds() as f64 * 1e-3)
        })
        .sum()
}

fn read_record(dir: &Path) -> Record {
    let mut record = Record::default();
    let mut folders = vec![dir.to_path_buf()];
    if !dir.join("session.json").exists() {
        let mut spots: Vec<std::path::PathBuf> = std::fs::read_dir(dir)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.join("session.json").exists())
            .collect();
        // spot-2 before spot-10.
        spots.sort_by_key(|p| {
            let name = p.file_name().map(|n| n.to_string_lossy().into_owned());
            let number = name
                .as_deref()
                .and_then(|n| n.rsplit('-').next())
                .and_then(|n| n.parse::<u32>().ok());
            (number, p.clone())
        });
        folders = spots;
    }
    let sheet = json(&dir.join("sheet.json"));
    for folder in &folders {
        let Some(doc) = json(&folder.join("session.json")) else {
            continue;
        };
        record.device_s.push(host_device_s(&doc));
        record.sim_clock_s = record.sim_clock_s.max(last_reading_s(folder));
        let decisions = decisions(&doc);
        let count = |what: &dyn Fn(&str) -> bool| decisions.iter().filter(|d| what(d)).count();
        record.rounds += count(&|d| d.starts_with("measuring again") && d.contains("(round "));
        // Announced by its message, or found in the status at a reconnection.
        record.stops += count(&|d| {
            d.contains("took its fail-safe stop") || d.starts_with("the instrument reports")
        }) as u64;
        record.reconnections += count(&|d| d.starts_with("link back")) as u64;
        let status = doc["status"].as_str().unwrap_or_default();
        if status != "finished" && record.stopped.is_none() {
            let reason = doc["why"].as_str().unwrap_or_default().to_string();
            record.stopped = Some((status.to_string(), reason));
        }
    }
    record.finished = match &sheet {
        Some(sheet) => sheet["status"].as_str() == Some("finished") && record.stopped.is_none(),
        None => !folders.is_empty() && record.stopped.is_none(),
    };
    record
}

/// How one `gonio measure` on a pty ended: its exit status (`None`: killed at the wall
/// limit), its standard error, its wall seconds.
struct Run {
    status: Option<std::process::ExitStatus>,
    stderr: String,
    wall_s: f64,
}

/// Serve `sample` (simulator `seed`, `faults`) on a pty with `gonio sim` and measure it with
/// `gonio measure --port` under `policy`, `spots`, into `dir`, killed past `wall_limit_s`.
#[allow(clippy::too_many_arguments)]
fn measure_on_pty(
    gonio: &Path,
    sample: &str,
    seed: u64,
    faults: &str,
    policy: PolicyChoice,
    spots: u16,
    dir: &Path,
    wall_limit_s: f64,
) -> Result<Run, String> {
    let simulator = Simulator::spawn(gonio, sample, seed, faults)?;
    let started = Instant::now();
    let mut child = Command::new(gonio)
        .args(["measure", "--port", &simulator.path, "--sample", sample])
        .args(["--policy", policy.name()])
        .args(["--spots", &spots.to_string()])
        .arg("--out")
        .arg(dir)
        .arg("--json")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot start {} measure: {e}", gonio.display()))?;
    // A person who is ready at every prompt: an answer waiting for each (the pipe stays
    // open until the session ends, so no prompt meets an end of input).
    let mut stdin = child.stdin.take();
    if let Some(input) = stdin.as_mut() {
        let _ = input.write_all(&[b'\n'; 512]);
    }
    let stdout = drain(child.stdout.take());
    let stderr = drain(child.stderr.take());
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break Some(status),
            Ok(None) if started.elapsed().as_secs_f64() > wall_limit_s => {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(100)),
            Err(_) => break None,
        }
    };
    let wall_s = started.elapsed().as_secs_f64();
    drop(stdin);
    drop(simulator);
    let _ = stdout.join();
    Ok(Run {
        status,
        stderr: stderr.join().unwrap_or_default(),
        wall_s,
    })
}

/// The simulator's clock at the last reading of a fault-free session of `sample`,
/// `policy`, `spots` on a pty, in `dir` (removed after): the span over which the unplug's
/// moment is drawn (the pty simulator's clock runs ahead of wall time while the host
/// talks, so the session's length in it is its own, not the in-process one's).
pub fn clean_sim_clock_s(
    gonio: &Path,
    sample: &str,
    policy: PolicyChoice,
    spots: u16,
    dir: &Path,
) -> Result<f64, String> {
    let _ = std::fs::remove_dir_all(dir);
    let run = measure_on_pty(
        gonio,
        sample,
        1,
        "",
        policy,
        spots,
        dir,
        wall_limit_s(spots),
    )?;
    let record = read_record(dir);
    let _ = std::fs::remove_dir_all(dir);
    match run.status {
        Some(status) if status.success() || status.code() == Some(3) => Ok(record.sim_clock_s),
        _ => Err(format!(
            "the fault-free session did not finish: {}",
            run.stderr
                .lines()
                .rev()
                .take(3)
                .collect::<Vec<_>>()
                .join(" | ")
        )),
    }
}

/// Run session `spec` with the `gonio` binary at `gonio`, its folder under `base`, against
/// its fault-free twin's simulator clock `clean_s`.
pub fn run_one(spec: &Spec, gonio: &Path, base: &Path, clean_s: f64) -> Row {
    let dir = base.join(format!("pty-{}", spec.index));
    let _ = std::fs::remove_dir_all(&dir);
    let unplug_at_s = spec.unplug_at_s(clean_s);
    let mut row = Row {
        spec: spec.clone(),
        unplug_at_s,
        ended: Ended::Unexplained(String::new()),
        exit_code: None,
        wall_s: 0.0,
        device_s: 0.0,
        max_spot_device_s: 0.0,
        sim_clock_s: 0.0,
        spots_measured: 0,
        rounds: 0,
        stops: 0,
        reconnections: 0,
        failure: None,
    };
    let wall_limit = wall_limit_s(spec.spots);
    let run = match measure_on_pty(
        gonio,
        spec.sample,
        spec.seed,
        &spec.faults(clean_s),
        spec.policy,
        spec.spots,
        &dir,
        wall_limit,
    ) {
        Ok(run) => run,
        Err(why) => {
            row.ended = Ended::Unexplained(why.clone());
            row.failure = Some(why);
            return row;
        }
    };
    let (status, stderr) = (run.status, run.stderr);
    row.wall_s = run.wall_s;
    row.exit_code = status.and_then(|s| s.code());
    let record = read_record(&dir);
    row.device_s = record.device_s.iter().sum();
    row.max_spot_device_s = record.device_s.iter().copied().fold(0.0, f64::max);
    row.spots_measured = record.device_s.len();
    row.sim_clock_s = record.sim_clock_s;
    row.rounds = record.rounds;
    row.stops = record.stops;
    row.reconnections = record.reconnections;
    let said = stderr
        .lines()
        .find_map(|l| l.strip_prefix("session stopped: "))
        .map(str::to_string);
    row.ended = if status.is_none() {
        Ended::Overran
    } else if record.finished && row.exit_code.is_some_and(|c| c == 0 || c == 3) {
        Ended::Finished
    } else {
        let reason = record
            .stopped
            .as_ref()
            .map(|(_, r)| r.clone())
            .filter(|r| !r.is_empty())
            .or(said)
            .unwrap_or_default();
        // Refused before the session began (no folder): the error it printed.
        let reason = if reason.is_empty() {
            stderr
                .lines()
                .find_map(|l| l.strip_prefix("error: "))
                .map(str::to_string)
                .unwrap_or_default()
        } else {
            reason
        };
        if reason.contains("stopped at the bound") {
            Ended::Bound(reason)
        } else if !reason.is_empty() {
            Ended::GaveUp(reason)
        } else {
            let tail: String = stderr.lines().rev().take(3).collect::<Vec<_>>().join(" | ");
            Ended::Unexplained(format!("exit {:?}: {tail}", row.exit_code))
        }
    };
    row.failure = match &row.ended {
        Ended::Overran => Some(format!(
            "still running after {wall_limit:.0} s of wall time: killed"
        )),
        Ended::Unexplained(why) => Some(format!("ended without a stated reason: {why}")),
        _ if row.max_spot_device_s > device_limit_s() => Some(format!(
            "a spot spent {:.0} s of device time, past the bound of {:.0} s",
            row.max_spot_device_s,
            device_limit_s()
        )),
        _ => None,
    };
    if row.failure.is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    } else if let Some(why) = row.failure.as_mut() {
        let _ = write!(why, " (folder kept: {})", dir.display());
    }
    row
}

/// Run `sessions` sessions of the campaign of `seed` with the binary `gonio`, `threads` at
/// a time, in folders under `base`; `progress` after each.
pub fn run_all(
    sessions: usize,
    seed: u64,
    gonio: &Path,
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
        clean_sim_clock_s(gonio, sample, policy, spots, &dir)
            .map(|s| ((sample, policy.name(), spots), s))
            .map_err(|e| format!("fault-free {sample} {} {spots} spots: {e}", policy.name()))
    });
    let cleans: BTreeMap<_, _> = cleans.into_iter().collect::<Result<_, _>>()?;
    Ok(super::parallel(&specs, threads, progress, |spec| {
        run_one(
            spec,
            gonio,
            base,
            cleans[&(spec.sample, spec.policy.name(), spec.spots)],
        )
    }))
}

/// The campaign's rows as CSV (through the csv crate: a reason's commas and quotes are
/// quoted by construction).
pub fn to_csv(rows: &[Row]) -> String {
    let mut csv = csv::Writer::from_writer(Vec::new());
    // Writing to memory fails only on a record of the wrong length, which these are not.
    let _ = csv.write_record([
        "index",
        "sample",
        "policy",
        "spots",
        "seed",
        "corrupt",
        "drop",
        "unplug_at_s",
        "outage_s",
        "ended",
        "reason",
        "exit_code",
        "wall_s",
        "device_s",
        "max_spot_device_s",
        "sim_clock_s",
        "spots_measured",
        "rounds",
        "stops",
        "reconnections",
        "within_bounds",
        "failure",
    ]);
    for r in rows {
        let _ = csv.write_record([
            r.spec.index.to_string(),
            r.spec.sample.to_string(),
            r.spec.policy.name().to_string(),
            r.spec.spots.to_string(),
            r.spec.seed.to_string(),
            format!("{:.5}", r.spec.corrupt),
            format!("{:.5}", r.spec.drop),
            format!("{:.3}", r.unplug_at_s),
            format!("{:.3}", r.spec.outage_s),
            r.ended.name().to_string(),
            r.ended.reason().to_string(),
            r.exit_code
                .map_or_else(|| "killed".into(), |c| c.to_string()),
            format!("{:.2}", r.wall_s),
            format!("{:.2}", r.device_s),
            format!("{:.2}", r.max_spot_device_s),
            format!("{:.2}", r.sim_clock_s),
            r.spots_measured.to_string(),
            r.rounds.to_string(),
            r.stops.to_string(),
            r.reconnections.to_string(),
            r.failure.is_none().to_string(),
            r.failure.clone().unwrap_or_default(),
        ]);
    }
    csv.into_inner()
        .map(|bytes| String::from_utf8_lossy(&bytes).into_owned())
        .unwrap_or_default()
}

fn quantile(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * q).round() as usize]
}

/// The campaign's tables, in Markdown.
pub fn summary_markdown(rows: &[Row], seed: u64, wall_total_s: f64) -> String {
    let mut out = String::new();
    let within = rows.iter().filter(|r| r.failure.is_none()).count();
    let _ = writeln!(
        out,
        "{} sessions (campaign seed {seed}), **{within} ended within their bounds** (device time of a spot ≤ {:.0} s; wall time ≤ {:.0} s per spot of the sheet); the campaign took {:.0} s of wall time.\n",
        rows.len(),
        device_limit_s(),
        wall_limit_s(1),
        wall_total_s
    );
    let _ = writeln!(
        out,
        "| policy | sessions | finished | gave up | bound hit | failed | wall s median | max | device s median | max | rounds max | stops max |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    let mut cells: Vec<(String, Vec<&Row>)> = POLICIES
        .iter()
        .map(|p| {
            (
                p.name().to_string(),
                rows.iter().filter(|r| r.spec.policy == *p).collect(),
            )
        })
        .collect();
    cells.push(("all".into(), rows.iter().collect()));
    for (name, cell) in cells {
        if cell.is_empty() {
            continue;
        }
        let count = |f: &dyn Fn(&Ended) -> bool| cell.iter().filter(|r| f(&r.ended)).count();
        let mut wall: Vec<f64> = cell.iter().map(|r| r.wall_s).collect();
        let mut device: Vec<f64> = cell.iter().map(|r| r.device_s).collect();
        let _ = writeln!(
            out,
            "| {name} | {} | {} | {} | {} | {} | {:.0} | {:.0} | {:.0} | {:.0} | {} | {} |",
            cell.len(),
            count(&|e| *e == Ended::Finished),
            count(&|e| matches!(e, Ended::GaveUp(_))),
            count(&|e| matches!(e, Ended::Bound(_))),
            cell.iter().filter(|r| r.failure.is_some()).count(),
            quantile(&mut wall, 0.5),
            quantile(&mut wall, 1.0),
            quantile(&mut device, 0.5),
            quantile(&mut device, 1.0),
            cell.iter().map(|r| r.rounds).max().unwrap_or(0),
            cell.iter().map(|r| r.stops).max().unwrap_or(0),
        );
    }
    let mut reasons: BTreeMap<String, usize> = BTreeMap::new();
    for r in rows {
        if let Ended::GaveUp(reason) | Ended::Bound(reason) = &r.ended {
            let short: String = reason
                .split(':')
                .next()
                .unwrap_or_default()
                .chars()
                .take(90)
                .collect();
            *reasons.entry(short).or_default() += 1;
        }
    }
    if !reasons.is_empty() {
        let _ = writeln!(
            out,
            "\nReasons stated by the sessions that did not finish:\n"
        );
        for (reason, n) in &reasons {
            let _ = writeln!(out, "- {n} × \"{reason}…\"");
        }
    }
    let failed: Vec<&Row> = rows.iter().filter(|r| r.failure.is_some()).collect();
    if !failed.is_empty() {
        let _ = writeln!(out, "\nFailures:\n");
        for r in failed {
            let _ = writeln!(
                out,
                "- {} {} {} {} spots, seed {}, corrupt {:.4}, drop {:.4}, unplug at {:.1} s for {:.1} s: {}",
                r.spec.index,
                r.spec.sample,
                r.spec.policy.name(),
                r.spec.spots,
                r.spec.seed,
                r.spec.corrupt,
                r.spec.drop,
                r.unplug_at_s,
                r.spec.outage_s,
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
    fn draws_stay_within_the_issues_faults_and_cover_the_policies_and_sheets() {
        for seed in [1, 2, 77] {
            let specs: Vec<Spec> = (0..60).map(|k| draw(k, seed)).collect();
            for s in &specs {
                assert!((0.0..=MAX_CORRUPT).contains(&s.corrupt));
                assert!((0.0..=MAX_DROP).contains(&s.drop));
                assert!((0.0..1.0).contains(&s.unplug_share));
                assert!((1..=3).contains(&s.spots));
            }
            for p in POLICIES {
                assert!(specs.iter().any(|s| s.policy == p));
            }
            assert!(
                specs
                    .iter()
                    .any(|s| s.spots > 1 && s.policy == PolicyChoice::Sweep)
            );
        }
    }
}
