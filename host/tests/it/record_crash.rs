//! Crash injection: a real in-process session (`host::measure::measure_with`, the
//! simulated instrument) killed at every write it makes into its folder, then resumed; and
//! real SIGKILLs of the `gonio` binary at random moments. Every resumed folder must pass
//! `gonio verify`, its `readings.csv` and `points.jsonl` agree with `session.json`, and no
//! reading is lost or recorded twice.
use crate::measure_args;
use host::measure::{Measured, measure, measure_with};
use host::output::folder::lock::FolderError;
use host::output::folder::store::{Crash, StoreOptions};
use host::session::{MeasuredPoint, SimulatedOperator};
use measure_args::parse_args;
use rand::{Rng, SeedableRng};
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gonio-crash-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Where the in-process sweeps put their folders: a RAM disk when there is one. What a
/// simulated crash leaves does not depend on the file system (it models a killed process,
/// whose writes are all in the page cache), and the sweeps' hundreds of sessions then do
/// not wait on an fsync per reading; the SIGKILLs below use the real temporary folder.
fn sweep_dir(name: &str) -> PathBuf {
    let ram = Path::new("/dev/shm");
    let base = if ram.is_dir() {
        ram.to_path_buf()
    } else {
        std::env::temp_dir()
    };
    let dir = base.join(format!("gonio-crash-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A session of one spot (these tests are about one session's folder; sheets of several
/// spots have their own crash test in `sheet.rs`).
fn run(args: &[String], crash: Option<Crash>) -> anyhow::Result<Measured> {
    let args = parse_args(one_spot(args)).expect("arguments");
    measure_with(
        &args,
        &mut SimulatedOperator,
        Arc::new(AtomicBool::new(false)),
        StoreOptions {
            crash,
            ..Default::default()
        },
    )
}

fn one_spot(args: &[String]) -> Vec<String> {
    let mut out = args.to_vec();
    if !out.iter().any(|a| a == "--spots") {
        out.splice(0..0, ["--spots".to_string(), "1".to_string()]);
    }
    out
}

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|s| s.to_string()).collect()
}

/// The whole lines of `points.jsonl` (what a crash cannot take back).
fn whole_lines(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("points.jsonl")).unwrap_or_default();
    let whole = text.rfind('\n').map_or("", |i| &text[..=i]);
    whole.lines().map(str::to_string).collect()
}

fn class(dir: &Path) -> String {
    let session: Value =
        serde_json::from_slice(&std::fs::read(dir.join("session.json")).unwrap()).unwrap();
    session["result"]["class"].as_str().unwrap().to_string()
}

/// After a crash at write `n` and a resume: the folder verifies, nothing taken before the
/// crash was lost or changed, nothing is recorded twice, and the class is the clean one.
fn check_resumed(dir: &Path, before: &[String], clean_class: &str, what: &str) {
    if let Err(problems) = host::output::folder::verify::verify(dir, host::output::report::draw) {
        panic!(
            "{what}: the resumed folder does not verify:\n{}",
            problems
                .iter()
                .map(|p| format!("  {p}\n"))
                .collect::<String>()
        );
    }
    let after = whole_lines(dir);
    assert!(
        after.len() >= before.len() && after[..before.len()] == *before,
        "{what}: a reading recorded before the crash was lost or changed"
    );
    // Readings with the marks of later lines applied (a reading superseded after lost steps
    // is measured again: its geometry then has two readings, one marked).
    let path = dir.join("points.jsonl");
    let points: Vec<MeasuredPoint> = host::output::folder::parse_points(
        &path,
        &host::output::folder::read_lines(&path).unwrap(),
    )
    .unwrap();
    let mut ids = BTreeSet::new();
    let mut geometries = BTreeSet::new();
    for p in &points {
        assert!(
            ids.insert((p.schedule_id, p.index)),
            "{what}: reading {}:{} recorded twice",
            p.schedule_id,
            p.index
        );
        if p.radiance_factor.is_some() && !p.superseded {
            assert!(
                geometries.insert((p.theta_i_deg.to_bits(), p.theta_r_deg.to_bits())),
                "{what}: geometry ({}, {}) measured twice",
                p.theta_i_deg,
                p.theta_r_deg
            );
        }
    }
    assert_eq!(class(dir), clean_class, "{what}");
}

/// Resume the crashed session in `dir` until it is finished (a folder without a session
/// is started anew with --out, as its message says).
fn resume(dir: &Path, base: &[&str], what: &str) {
    let mut args = strings(base);
    args.extend(strings(&["--resume", dir.to_str().unwrap()]));
    match run(&args, None) {
        Ok(Measured::Done { .. }) => {}
        Ok(Measured::Stopped { error, .. }) => {
            panic!("{what}: the resumed session stopped: {error}")
        }
        Ok(Measured::Sheet { .. }) => panic!("{what}: a sheet, not one spot"),
        Err(e) => match e.downcast_ref::<FolderError>() {
            // Killed while closing: the result was written, the manifest now is.
            Some(FolderError::Finished { .. }) => {}
            // Killed before its session.json: nothing was measured, and the folder is
            // free for a new session.
            Some(FolderError::NoSession(_)) => {
                assert!(
                    whole_lines(dir).is_empty(),
                    "{what}: readings in a folder without session.json"
                );
                let mut args = strings(base);
                args.extend(strings(&["--out", dir.to_str().unwrap()]));
                assert!(
                    matches!(run(&args, None), Ok(Measured::Done { .. })),
                    "{what}: a new session in the folder"
                );
            }
            Some(FolderError::NoFolder(_)) => {
                let mut args = strings(base);
                args.extend(strings(&["--out", dir.to_str().unwrap()]));
                assert!(
                    matches!(run(&args, None), Ok(Measured::Done { .. })),
                    "{what}: a new session in the folder"
                );
            }
            _ => panic!("{what}: resume refused: {e:#}"),
        },
    }
}

/// Crash the session `base` at each write in `writes` (1-based), resume, check.
fn crash_at_each(name: &str, base: &[&str], writes: impl Fn(u64) -> Vec<u64>) -> usize {
    let clean_dir = sweep_dir(&format!("{name}-clean"));
    let counting = Crash::counting();
    let mut args = strings(base);
    args.extend(strings(&["--out", clean_dir.to_str().unwrap()]));
    assert!(matches!(
        run(&args, Some(counting.clone())).unwrap(),
        Measured::Done { .. }
    ));
    let clean_class = class(&clean_dir);
    let total = counting.writes();
    assert!(total > 20, "{name}: only {total} writes counted");
    let chosen = writes(total);
    eprintln!(
        "{name}: {total} writes, crashing at {} of them",
        chosen.len()
    );
    for &n in &chosen {
        let dir = sweep_dir(&format!("{name}-{n}"));
        let what = format!("{name}, crash at write {n} of {total}");
        let crash = Crash::at(n);
        let mut args = strings(base);
        args.extend(strings(&["--out", dir.to_str().unwrap()]));
        match run(&args, Some(crash.clone())) {
            Ok(Measured::Done { .. }) => panic!("{what}: the session finished through its crash"),
            Ok(Measured::Stopped { record_error, .. }) => assert!(
                record_error.is_some(),
                "{what}: a dead folder took the status"
            ),
            Ok(Measured::Sheet { .. }) => panic!("{what}: a sheet, not one spot"),
            Err(_) => {}
        }
        assert!(crash.crashed(), "{what}: no crash");
        let before = whole_lines(&dir);
        resume(&dir, base, &what);
        check_resumed(&dir, &before, &clean_class, &what);
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&clean_dir);
    chosen.len()
}

/// The writes a crash is tried at: the first and last three, where a session is begun and
/// closed, and of the rest each with probability `share`, drawn by `seed`.
fn drawn_writes(total: u64, share: f64, seed: u64) -> Vec<u64> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ total);
    (1..=total)
        .filter(|&n| n <= 3 || n + 3 > total || rng.random_bool(share))
        .collect()
}

#[test]
fn a_session_killed_at_any_of_its_writes_resumes_to_a_verified_folder() {
    // Every write of a whole adaptive session of G, the README's sheet (calibration,
    // Strategy 1, the probe, batches, summaries, manifest); of a rough paper by the paper's
    // policy, a white check and an arm that slips, half their writes drawn anew every run
    // (the seed is printed to repeat it): every one of theirs is tried over runs, and each
    // kind of write occurs many times in a session. All of them every run took 69 s of CI's
    // CPU, crashing at about 250 writes one after the other.
    let seed: u64 = rand::rng().random();
    eprintln!("seed {seed}");
    let g = crash_at_each("G-adaptive", &["--sim", "G", "--seed", "11"], |total| {
        (1..=total).collect()
    });
    let ppc = crash_at_each(
        "PPC-paper",
        &["--sim", "PPC", "--seed", "12", "--policy", "paper"],
        |total| drawn_writes(total, 0.5, seed),
    );
    let sg = crash_at_each(
        "SG-adaptive-white-check",
        &["--sim", "SG", "--seed", "15", "--white-check"],
        |total| drawn_writes(total, 0.5, seed.rotate_left(16)),
    );
    // An arm that slips: readings superseded (a mark in points.jsonl, readings.csv rebuilt)
    // and measured again; a crash at any write of that too.
    let slipped = crash_at_each(
        "J1-lost-steps",
        &[
            "--sim",
            "J1",
            "--seed",
            "16",
            "--faults",
            "lose-steps=detector:40",
        ],
        |total| drawn_writes(total, 0.5, seed.rotate_left(32)),
    );
    assert!(
        g >= 60 && ppc + sg + slipped >= 60,
        "{g} + {ppc} + {sg} + {slipped} crash points"
    );
}

#[test]
fn a_long_session_killed_at_random_writes_resumes_to_a_verified_folder() {
    // The paper's policy on G takes a hundred readings: 30 of its writes drawn at random
    // (another draw every run: the seed is printed to repeat it).
    let seed: u64 = rand::rng().random();
    eprintln!("seed {seed}");
    let n = crash_at_each(
        "G-paper",
        &["--sim", "G", "--seed", "13", "--policy", "paper"],
        |total| {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let mut chosen: BTreeSet<u64> = BTreeSet::new();
            while chosen.len() < 30.min(total as usize) {
                chosen.insert(rng.random_range(1..=total));
            }
            chosen.into_iter().collect()
        },
    );
    assert_eq!(n, 30);
}

#[test]
fn a_full_disk_at_any_write_stops_the_session_with_whole_lines_and_it_resumes() {
    let base = ["--sim", "G", "--seed", "16"];
    let clean_dir = sweep_dir("full-clean");
    let counting = Crash::counting();
    let mut args = strings(&base);
    args.extend(strings(&["--out", clean_dir.to_str().unwrap()]));
    assert!(matches!(
        run(&args, Some(counting.clone())).unwrap(),
        Measured::Done { .. }
    ));
    let clean_class = class(&clean_dir);
    for n in 1..=counting.writes() {
        let dir = sweep_dir(&format!("full-{n}"));
        let what = format!("disk full at write {n} of {}", counting.writes());
        let mut args = strings(&base);
        args.extend(strings(&["--out", dir.to_str().unwrap()]));
        let message = match run(&args, Some(Crash::disk_full_at(n))) {
            // The last write renames the manifest into place: a full disk takes no data there.
            Ok(Measured::Done { .. }) if n == counting.writes() => {
                host::output::folder::verify::verify(&dir, host::output::report::draw).unwrap();
                let _ = std::fs::remove_dir_all(&dir);
                continue;
            }
            Ok(Measured::Done { .. }) => panic!("{what}: finished on a full disk"),
            Ok(Measured::Stopped { error, .. }) => error.to_string(),
            Ok(Measured::Sheet { .. }) => panic!("{what}: a sheet, not one spot"),
            Err(e) => format!("{e:#}"),
        };
        assert!(
            message.contains("no space left on device"),
            "{what}: {message}"
        );
        if dir.exists() {
            // What the disk took is whole: no cut line, no temporary file, a readable session.json.
            for name in ["points.jsonl", "readings.csv", "session.log"] {
                let text = std::fs::read(dir.join(name)).unwrap_or_default();
                assert!(
                    text.is_empty() || text.ends_with(b"\n"),
                    "{what}: {name} ends in a cut line"
                );
            }
            let names = host::output::folder::entries(&dir).unwrap();
            assert!(
                !names.iter().any(|n| host::output::folder::is_temp_name(n)),
                "{what}: {names:?}"
            );
            if dir.join("session.json").exists() {
                host::output::folder::read_session(&dir).unwrap_or_else(|p| panic!("{what}: {p}"));
            }
        }
        let before = whole_lines(&dir);
        resume(&dir, &base, &what);
        check_resumed(&dir, &before, &clean_class, &what);
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&clean_dir);
}

/// The model holds for a real process: `gonio measure` SIGKILLed at random moments, then
/// `gonio measure --resume`, then `gonio verify`.
#[test]
fn the_gonio_binary_killed_at_random_moments_resumes_to_a_verified_folder() {
    let gonio = env!("CARGO_BIN_EXE_gonio");
    let seed: u64 = rand::rng().random();
    eprintln!("seed {seed}");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let base = [
        "measure", "--spots", "1", "--sim", "G", "--seed", "14", "--policy", "paper", "--json",
    ];
    let clean_dir = temp_dir("kill-clean");
    let started = std::time::Instant::now();
    let out = std::process::Command::new(gonio)
        .args(base)
        .args(["--out", clean_dir.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let duration_us = started.elapsed().as_micros() as u64;
    let clean_class = class(&clean_dir);
    for k in 0..8 {
        let dir = temp_dir(&format!("kill-{k}"));
        let mut child = std::process::Command::new(gonio)
            .args(base)
            .args(["--out", dir.to_str().unwrap()])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_micros(
            rng.random_range(0..duration_us),
        ));
        let _ = child.kill(); // SIGKILL
        let status = child.wait().unwrap();
        let before = whole_lines(&dir);
        let what = format!("kill {k} (seed {seed}, {status})");
        eprintln!("{what}: {} readings on disk", before.len());
        let resumed = std::process::Command::new(gonio)
            .args(base)
            .args(["--resume", dir.to_str().unwrap()])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&resumed.stderr);
        // Exit 3 is a finished session whose result is flagged: a resume from before the
        // first reading measures the whole plane in the second run, one fixed noise draw
        // (the seed and the run number) that the lack-of-fit test flags at its own
        // false-alarm rate. The folder is finished either way, and is verified below.
        if !resumed.status.success() && resumed.status.code() != Some(3) {
            if stderr.contains("holds no session") || stderr.contains("no session folder") {
                // Killed before its session.json: start it anew, as the message says.
                let out = std::process::Command::new(gonio)
                    .args(base)
                    .args(["--out", dir.to_str().unwrap()])
                    .output()
                    .unwrap();
                assert!(
                    out.status.success(),
                    "{what}: {}",
                    String::from_utf8_lossy(&out.stderr)
                );
            } else {
                // Killed after the result: the session is finished and not measured again.
                assert!(
                    stderr.contains("holds a finished session"),
                    "{what}: {stderr}"
                );
            }
        }
        let verify = std::process::Command::new(gonio)
            .args(["verify", dir.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(
            verify.status.success(),
            "{what}: {}",
            String::from_utf8_lossy(&verify.stderr)
        );
        check_resumed(&dir, &before, &clean_class, &what);
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&clean_dir);
}

/// `measure` (no crash) is `measure_with` with a real store.
#[test]
fn measure_writes_a_folder_that_verifies() {
    let dir = temp_dir("plain");
    let args = parse_args([
        "--spots",
        "1",
        "--sim",
        "SG",
        "--out",
        dir.to_str().unwrap(),
    ])
    .unwrap();
    assert!(matches!(
        measure(
            &args,
            &mut SimulatedOperator,
            Arc::new(AtomicBool::new(false))
        )
        .unwrap(),
        Measured::Done { .. }
    ));
    host::output::folder::verify::verify(&dir, host::output::report::draw).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}
