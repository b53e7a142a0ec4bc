//! The session folder belongs to one session: every refusal (`--out` onto another session
//! or any non-empty folder, `--resume` with another sample, instrument or plan, of a
//! finished session, of damage), the default names, the repairs a resume makes and the
//! chain of custody across resumes (folder, sample, instrument serial, runs, manifest);
//! `gonio verify` and its exit codes. Through the `gonio` binary where it is a command line.
use crate::cli_support;
use crate::measure_args;
use cli_support::gonio;
use cli_support::stderr;
use host::measure::{Measured, measure_with};
use host::output::folder::lock::{FolderError, FolderLock};
use host::output::folder::record::{FileRecorder, Identity};
use host::output::folder::store::{Crash, StoreOptions};
use host::session::{Operator, Placement, SimulatedOperator};
use measure_args::parse_args;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

fn temp_dir(name: &str) -> PathBuf {
    cli_support::temp_dir("folder", name)
}

fn session(dir: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(dir.join("session.json")).unwrap()).unwrap()
}

/// Every file of a folder and its bytes: to show a refusal changed nothing.
fn contents(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap())
        .map(|e| {
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap_or_default(),
            )
        })
        .collect()
}

/// A refusal: exit code 1, the message holds every `needle`, the folder is as it was.
fn refused(args: &[&str], dir: &Path, needles: &[&str]) -> String {
    let before = dir.is_dir().then(|| contents(dir));
    let out = gonio(args);
    let message = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {message}");
    for needle in needles {
        assert!(
            message.contains(needle),
            "{args:?}: no '{needle}' in: {message}"
        );
    }
    if let Some(before) = before {
        assert!(
            contents(dir) == before,
            "{args:?}: the folder was changed by a refusal"
        );
    }
    message
}

fn finished(sample: &str, dir: &Path, extra: &[&str]) {
    let mut args = vec![
        "measure",
        "--spots",
        "1",
        "--sim",
        sample,
        "--json",
        "--out",
        dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = gonio(&args);
    // A finished session exits 0, or 3 where its result is flagged (a PPC's lack-of-fit
    // false alarm on run seed 521884 made this fail): either is the finished session
    // these tests need.
    cli_support::assert_finished(&out);
    assert!(dir.join("session.json").is_file(), "{}", stderr(&out));
}

/// A session of one spot (these tests are about one session's folder).
fn run_in_process(
    args: &[&str],
    crash: Option<Crash>,
    operator: &mut dyn Operator,
    interrupted: Arc<AtomicBool>,
) -> anyhow::Result<Measured> {
    let one_spot: Vec<&str> = if args.contains(&"--spots") {
        args.to_vec()
    } else {
        [&["--spots", "1"], args].concat()
    };
    measure_with(
        &parse_args(one_spot).unwrap(),
        operator,
        interrupted,
        StoreOptions {
            crash,
            ..Default::default()
        },
    )
}

/// A G session killed at its `n`-th write (readings taken, no end recorded).
fn killed(dir: &Path, n: u64, extra: &[&str]) {
    let mut args = vec!["--sim", "G", "--seed", "21", "--out", dir.to_str().unwrap()];
    args.extend_from_slice(extra);
    let crash = Crash::at(n);
    let _ = run_in_process(
        &args,
        Some(crash.clone()),
        &mut SimulatedOperator,
        Arc::new(AtomicBool::new(false)),
    );
    assert!(crash.crashed());
}

/// `gonio measure` resuming the G session of seed 21 in `dir` (the one [`killed`] leaves).
fn resumed(dir: &Path) -> std::process::Output {
    gonio(&[
        "measure",
        "--spots",
        "1",
        "--sim",
        "G",
        "--seed",
        "21",
        "--resume",
        dir.to_str().unwrap(),
    ])
}

#[test]
fn out_onto_another_sessions_folder_or_any_non_empty_folder_is_refused() {
    let dir = temp_dir("another");
    finished("G", &dir, &[]);
    let d = dir.to_str().unwrap();
    refused(
        &["measure", "--spots", "1", "--sim", "G", "--out", d],
        &dir,
        &[
            "holds another session (sample 'G', instrument SIM-0001",
            "finished",
            "--resume",
        ],
    );
    refused(
        &["measure", "--spots", "1", "--sim", "PPC", "--out", d],
        &dir,
        &["holds another session"],
    );
    // An interrupted one too: it is continued with --resume, never appended to.
    let stopped = temp_dir("another-killed");
    killed(&stopped, 30, &[]);
    refused(
        &[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--out",
            stopped.to_str().unwrap(),
        ],
        &stopped,
        &["holds another session", "running", "--resume"],
    );
    // Any other non-empty folder.
    let other = temp_dir("not-empty");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("notes.txt"), "mine").unwrap();
    refused(
        &[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--out",
            other.to_str().unwrap(),
        ],
        &other,
        &["is not empty (it holds notes.txt)", "new or empty folder"],
    );
    // A file.
    let file = other.join("notes.txt");
    refused(
        &[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--out",
            file.to_str().unwrap(),
        ],
        &other,
        &["is not a folder"],
    );
    // An empty folder is taken.
    let empty = temp_dir("empty");
    std::fs::create_dir_all(&empty).unwrap();
    finished("PPC", &empty, &[]);
    for d in [dir, stopped, other, empty] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn a_folder_left_by_a_kill_before_its_session_began_is_taken_by_a_new_session() {
    // Killed while writing the first session.json: only its temporary file is there.
    let dir = temp_dir("pre-session");
    for n in 2..=3 {
        let _ = std::fs::remove_dir_all(&dir);
        killed(&dir, n, &[]);
        assert!(!dir.join("session.json").exists());
        let out = gonio(&[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--resume",
            dir.to_str().unwrap(),
        ]);
        assert_eq!(out.status.code(), Some(1));
        assert!(
            stderr(&out).contains("holds no session") && stderr(&out).contains("--out"),
            "{}",
            stderr(&out)
        );
        finished("G", &dir, &[]);
        let log = std::fs::read_to_string(dir.join("session.log")).unwrap();
        if n == 2 {
            assert!(log.contains("removed .session.json.gonio-tmp"), "{log}");
        }
        assert!(gonio(&["verify", dir.to_str().unwrap()]).status.success());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn default_folder_names_are_readable_and_two_sessions_in_one_second_get_two() {
    let cwd = temp_dir("default-names");
    std::fs::create_dir_all(&cwd).unwrap();
    let spawn = || {
        Command::new(env!("CARGO_BIN_EXE_gonio"))
            .args(["measure", "--spots", "1", "--sim", "PPC", "--json"])
            .current_dir(&cwd)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (spawn(), spawn());
    for child in [a, b] {
        // Two seeds drawn: either session may be flagged (CI failed on a PPC's lack-of-fit
        // false alarm here); the folders' names are the subject.
        cli_support::assert_finished(&child.wait_with_output().unwrap());
    }
    let names: Vec<String> = std::fs::read_dir(cwd.join("sessions"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
    for name in &names {
        // sessions/<YYYY-MM-DD_HH-MM-SS>-PPC, with -2, -3… on collision.
        let (stamp, rest) = name.split_at(19);
        assert!(
            stamp
                .chars()
                .enumerate()
                .all(|(k, c)| if [4, 7, 13, 16].contains(&k) {
                    c == '-'
                } else if k == 10 {
                    c == '_'
                } else {
                    c.is_ascii_digit()
                }),
            "{name}"
        );
        assert!(
            rest == "-PPC"
                || rest
                    .strip_prefix("-PPC-")
                    .is_some_and(|k| k.parse::<u32>().is_ok_and(|k| k >= 2)),
            "{name}"
        );
        assert!(
            gonio(&["verify", cwd.join("sessions").join(name).to_str().unwrap()])
                .status
                .success()
        );
    }
    // Eight at once in one process: eight folders (made with create_dir, never shared).
    let info = hil_sim_info();
    let plan = host::output::folder::PlanRecord {
        policy: "paper".into(),
        adaptive_targets: None,
        sweep_targets: None,
        integration_ms: 100,
        acceptance_deg: 1.0,
        white_check: false,
        white_drift_limit_pct: 0.5,
        model: Some("extended".into()),
    };
    let parent = cwd.join("many");
    let dirs: Vec<PathBuf> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..8)
            .map(|_| {
                let identity = Identity::new("custom:1,2,0.5,1.5", &info, plan.clone());
                let parent = parent.clone();
                s.spawn(move || {
                    FileRecorder::create_default(&parent, identity, StoreOptions::default())
                        .unwrap()
                        .dir()
                        .to_path_buf()
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let unique: std::collections::BTreeSet<&PathBuf> = dirs.iter().collect();
    assert_eq!(unique.len(), 8, "{dirs:?}");
    assert!(
        dirs.iter().all(|d| d
            .file_name()
            .unwrap()
            .to_string_lossy()
            .contains("-custom_1_2_0.5_1.5")),
        "{dirs:?}"
    );
    let _ = std::fs::remove_dir_all(&cwd);
}

/// The simulated instrument's DeviceInfo, from a handshake.
fn hil_sim_info() -> protocol::DeviceInfo {
    // The simulator's defaults, as the command line gives them.
    let options = parse_args(["--spots", "1", "--sim", "G"])
        .unwrap()
        .sim_options;
    let instrument = options.instrument("G").unwrap();
    let mut client = host::instrument::link::Client::new(
        instrument,
        host::instrument::link::RetryPolicy::default(),
    );
    client.hello().unwrap()
}

#[test]
fn resume_with_another_sample_instrument_or_plan_is_refused_naming_what_differs() {
    let dir = temp_dir("mismatch");
    killed(&dir, 30, &[]);
    let d = dir.to_str().unwrap();
    refused(
        &["measure", "--spots", "1", "--sim", "PPC", "--resume", d],
        &dir,
        &[
            "cannot resume",
            "the sample differs (the session: 'G'; now: 'PPC')",
        ],
    );
    refused(
        &[
            "measure", "--spots", "1", "--sim", "G", "--sample", "G2", "--resume", d,
        ],
        &dir,
        &["the sample differs (the session: 'G'; now: 'G2')"],
    );
    // Another paper under the same name is another sample still.
    refused(
        &[
            "measure", "--spots", "1", "--sim", "PPC", "--sample", "G", "--resume", d,
        ],
        &dir,
        &["the simulated sample differs (the session: 'G'; now: 'PPC')"],
    );
    refused(
        &[
            "measure", "--spots", "1", "--sim", "G", "--policy", "paper", "--resume", d,
        ],
        &dir,
        &["the policy differs (the session: adaptive; now: paper)"],
    );
    refused(
        &[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--integration-ms",
            "50",
            "--resume",
            d,
        ],
        &dir,
        &["the integration time differs (the session: 100 ms; now: 50 ms)"],
    );
    refused(
        &[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--white-check",
            "--resume",
            d,
        ],
        &dir,
        &["the white check differs (the session: off; now: on)"],
    );
    refused(
        &[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--white-drift-limit-pct",
            "2",
            "--resume",
            d,
        ],
        &dir,
        &["the white drift limit differs (the session: 0.5 %; now: 2 %)"],
    );
    refused(
        &[
            "measure", "--spots", "1", "--sim", "G", "--model", "paper", "--resume", d,
        ],
        &dir,
        &["the model differs (the session: extended; now: paper)"],
    );
    // Several at once, all named.
    refused(
        &[
            "measure", "--spots", "1", "--sim", "SG", "--policy", "paper", "--resume", d,
        ],
        &dir,
        &["the sample differs", "the policy differs"],
    );
    // Another instrument: the folder of one whose serial is not the simulator's.
    let mut doc = session(&dir);
    doc["instrument"]["serial_number"] = "GONIO-0042".into();
    std::fs::write(
        dir.join("session.json"),
        serde_json::to_vec_pretty(&doc).unwrap(),
    )
    .unwrap();
    refused(
        &["measure", "--spots", "1", "--sim", "G", "--resume", d],
        &dir,
        &["the instrument differs (the session: serial GONIO-0042; now: serial SIM-0001)"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_finished_session_is_not_measured_again_and_says_where_its_result_is() {
    let dir = temp_dir("finished");
    finished("SG", &dir, &[]);
    let d = dir.to_str().unwrap();
    // The class its result has (on a seed drawn for the run, one flagged may have another).
    let class = format!(
        "class {}",
        session(&dir)["result"]["class"].as_str().unwrap()
    );
    let message = refused(
        &["measure", "--spots", "1", "--sim", "SG", "--resume", d],
        &dir,
        &[
            "holds a finished session of 'SG'",
            &class,
            "it is not measured again",
            "its result is in",
        ],
    );
    assert!(
        message.contains(&dir.join("session.json").display().to_string()),
        "{message}"
    );
    assert!(gonio(&["verify", d]).status.success());
    // Killed between its result and its manifest: the resume writes the manifest, and
    // measures nothing.
    let dir2 = temp_dir("finished-no-manifest");
    let counting = Crash::counting();
    let args = [
        "--sim",
        "SG",
        "--seed",
        "21",
        "--out",
        dir2.to_str().unwrap(),
    ];
    run_in_process(
        &args,
        Some(counting.clone()),
        &mut SimulatedOperator,
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    let _ = std::fs::remove_dir_all(&dir2);
    // The last two writes are the manifest's temporary file and its rename.
    let crash = Crash::at(counting.writes() - 1);
    let _ = run_in_process(
        &args,
        Some(crash),
        &mut SimulatedOperator,
        Arc::new(AtomicBool::new(false)),
    );
    assert_eq!(session(&dir2)["status"], "finished");
    assert!(!dir2.join("MANIFEST.sha256").exists());
    let points = std::fs::read(dir2.join("points.jsonl")).unwrap();
    let out = gonio(&[
        "measure",
        "--spots",
        "1",
        "--sim",
        "SG",
        "--resume",
        dir2.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("holds a finished session"),
        "{}",
        stderr(&out)
    );
    assert_eq!(
        std::fs::read(dir2.join("points.jsonl")).unwrap(),
        points,
        "nothing measured"
    );
    assert!(gonio(&["verify", dir2.to_str().unwrap()]).status.success());
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&dir2);
}

#[test]
fn resume_of_no_session_or_of_damage_is_refused_at_file_and_line() {
    let missing = temp_dir("missing");
    refused(
        &[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--resume",
            missing.to_str().unwrap(),
        ],
        &missing,
        &["no session folder"],
    );
    let empty = temp_dir("empty-resume");
    std::fs::create_dir_all(&empty).unwrap();
    refused(
        &[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--resume",
            empty.to_str().unwrap(),
        ],
        &empty,
        &["holds no session", "nothing was measured there"],
    );

    let dir = temp_dir("damaged");
    killed(&dir, 40, &[]);
    let d = dir.to_str().unwrap();
    let pristine = contents(&dir);
    let restore = || {
        for (name, bytes) in &pristine {
            std::fs::write(dir.join(name), bytes).unwrap();
        }
    };
    // A merged line inside points.jsonl (not its last): refused, never repaired.
    let points = String::from_utf8(pristine["points.jsonl"].clone()).unwrap();
    let mut lines: Vec<&str> = points.lines().collect();
    assert!(lines.len() >= 4, "{} readings", lines.len());
    let merged = format!("{}{}", &lines[1][..40], lines[2]);
    lines[1] = &merged;
    std::fs::write(dir.join("points.jsonl"), lines.join("\n") + "\n").unwrap();
    refused(
        &["measure", "--spots", "1", "--sim", "G", "--resume", d],
        &dir,
        &["points.jsonl:2: not a reading", "nothing was changed"],
    );
    restore();
    // readings.csv contradicting points.jsonl.
    let csv = String::from_utf8(pristine["readings.csv"].clone())
        .unwrap()
        .replacen(",0.", ",9.", 2);
    std::fs::write(dir.join("readings.csv"), csv).unwrap();
    refused(
        &["measure", "--spots", "1", "--sim", "G", "--resume", d],
        &dir,
        &[
            "readings.csv:2: row",
            "differs from its reading in points.jsonl",
        ],
    );
    restore();
    // A session.json that is not JSON.
    std::fs::write(
        dir.join("session.json"),
        "{\n \"format\": \"gonio-session/1\",\n  oops\n}",
    )
    .unwrap();
    refused(
        &["measure", "--spots", "1", "--sim", "G", "--resume", d],
        &dir,
        &["session.json:3: not JSON"],
    );
    restore();
    // Readings that session.json says were recorded, gone.
    std::fs::write(dir.join("points.jsonl"), lines[..1].join("\n") + "\n").unwrap();
    let mut doc = session(&dir);
    doc["readings_recorded"] = 3.into();
    std::fs::write(
        dir.join("session.json"),
        serde_json::to_vec_pretty(&doc).unwrap(),
    )
    .unwrap();
    refused(
        &["measure", "--spots", "1", "--sim", "G", "--resume", d],
        &dir,
        &["points.jsonl:2: 1 readings, but session.json says 3 were recorded"],
    );
    restore();
    // Restored, it resumes.
    assert!(
        gonio(&[
            "measure", "--spots", "1", "--sim", "G", "--seed", "21", "--resume", d
        ])
        .status
        .success()
    );
    assert!(gonio(&["verify", d]).status.success());
    for d in [missing, empty, dir] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// The first write index at which a crash leaves `points.jsonl` with a cut-off last line.
fn a_crash_that_cuts_a_reading(dir: &Path) -> u64 {
    for n in 20..200 {
        let _ = std::fs::remove_dir_all(dir);
        killed(dir, n, &[]);
        let text = std::fs::read(dir.join("points.jsonl")).unwrap_or_default();
        if text.len() > 200 && !text.ends_with(b"\n") {
            return n;
        }
    }
    panic!("no crash cut a reading");
}

#[test]
fn a_cut_off_last_line_is_repaired_and_the_repair_logged() {
    let dir = temp_dir("cut");
    a_crash_that_cuts_a_reading(&dir);
    let text = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    let whole = text.rfind('\n').unwrap() + 1;
    let cut = text.len() - whole;
    // gonio verify says what is wrong, at file:line.
    let out = gonio(&["verify", dir.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    let lines = text[..whole].lines().count();
    assert!(
        stderr(&out).contains(&format!(
            "points.jsonl:{}: last line cut short ({cut} bytes",
            lines + 1
        )),
        "{}",
        stderr(&out)
    );
    assert!(
        stderr(&out).contains("status is running: the session is not finished"),
        "{}",
        stderr(&out)
    );
    let out = resumed(&dir);
    assert!(out.status.success(), "{}", stderr(&out));
    let after = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    assert!(
        after.starts_with(&text[..whole]),
        "the whole lines kept as they were"
    );
    assert!(
        after
            .lines()
            .all(|l| serde_json::from_str::<Value>(l).is_ok()),
        "never appended onto the cut line"
    );
    let log = std::fs::read_to_string(dir.join("session.log")).unwrap();
    assert!(log.contains(&format!("[run 2] repaired: points.jsonl: removed its last line, cut short by a crash after {cut} bytes")), "{log}");
    assert!(
        log.contains("[run 2] repaired: run 1 ended without closing"),
        "{log}"
    );
    let doc = session(&dir);
    assert!(
        doc["runs"][1]["decisions"]
            .to_string()
            .contains("repaired: points.jsonl"),
        "{}",
        doc["runs"][1]
    );
    assert!(gonio(&["verify", dir.to_str().unwrap()]).status.success());
    let _ = std::fs::remove_dir_all(&dir);
}

/// The model a session fits is its plan's: begun with `--model paper` and killed, it is
/// resumed without the option under the paper's model, and its result and session.json
/// say so; a session whose plan predates the record (no `model`) is the paper's, as the
/// default was when it was begun.
#[test]
fn a_resumed_session_fits_the_model_it_was_begun_with() {
    let model_of = |dir: &Path| {
        let doc = session(dir);
        (
            doc["plan"]["model"].clone(),
            doc["result"]["analysis_settings"]["model_extensions"].clone(),
        )
    };
    let resume = |dir: &Path| {
        let out = resumed(dir);
        assert!(
            out.status.code() == Some(0) || out.status.code() == Some(3),
            "{}",
            stderr(&out)
        );
    };
    let paper = temp_dir("model-paper");
    killed(&paper, 30, &["--model", "paper"]);
    assert_eq!(session(&paper)["plan"]["model"], "paper");
    resume(&paper);
    assert_eq!(model_of(&paper), (Value::from("paper"), Value::from(false)));
    // A plan written before the model was recorded: the paper's model.
    let older = temp_dir("model-older");
    killed(&older, 30, &[]);
    let mut doc = session(&older);
    assert_eq!(
        doc["plan"]["model"],
        host::analysis::fit::ModelChoice::by_default().name(),
        "the default"
    );
    doc["plan"].as_object_mut().unwrap().remove("model");
    std::fs::write(
        older.join("session.json"),
        serde_json::to_vec_pretty(&doc).unwrap(),
    )
    .unwrap();
    resume(&older);
    assert_eq!(model_of(&older).1, Value::from(false));
    let _ = std::fs::remove_dir_all(&paper);
    let _ = std::fs::remove_dir_all(&older);
}

/// An operator who presses Ctrl-C once the tile is back and the sample is on.
struct CtrlCAfterCalibration(Arc<AtomicBool>);

impl Operator for CtrlCAfterCalibration {
    fn ask(&mut self, placement: Placement, _now: std::time::Duration) -> std::io::Result<()> {
        if placement == Placement::Sample {
            self.0.store(true, Ordering::Relaxed);
        }
        Ok(())
    }

    fn answered(&mut self, _now: std::time::Duration) -> std::io::Result<bool> {
        Ok(true)
    }
}

#[test]
fn the_chain_of_custody_holds_across_a_kill_an_interruption_and_the_end() {
    let dir = temp_dir("custody");
    // Run 1: interrupted (Ctrl-C) once calibrated.
    let interrupted = Arc::new(AtomicBool::new(false));
    let args = ["--sim", "G", "--seed", "22", "--out", dir.to_str().unwrap()];
    let Measured::Stopped {
        error,
        record_error: None,
        ..
    } = run_in_process(
        &args,
        None,
        &mut CtrlCAfterCalibration(interrupted.clone()),
        interrupted,
    )
    .unwrap()
    else {
        panic!("not stopped by the Ctrl-C");
    };
    assert!(matches!(error, host::session::SessionError::Interrupted));
    let doc = session(&dir);
    assert_eq!(doc["status"], "interrupted");
    assert_eq!(doc["why"], "interrupted by the user");
    assert_eq!(
        doc["resume_with"],
        format!("gonio measure --sim G --resume {}", dir.display())
    );
    assert_eq!(doc["runs"][0]["outcome"], "interrupted");
    assert!(
        std::fs::read_to_string(dir.join("session.log"))
            .unwrap()
            .contains("[run 1] session stopped (interrupted): interrupted by the user")
    );
    // Run 2: killed at its 12th write, after some readings.
    let resume = [
        "--sim",
        "G",
        "--seed",
        "22",
        "--resume",
        dir.to_str().unwrap(),
    ];
    let crash = Crash::at(12);
    let _ = run_in_process(
        &resume,
        Some(crash.clone()),
        &mut SimulatedOperator,
        Arc::new(AtomicBool::new(false)),
    );
    assert!(crash.crashed());
    // Whole lines only: the crash may have cut the last one short (the resume drops it).
    let text = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    let readings_before_3 = text.rfind('\n').map_or(0, |i| text[..=i].lines().count());
    assert!(readings_before_3 > 0);
    // Run 3, the binary: finishes.
    let out = gonio(&[
        "measure",
        "--spots",
        "1",
        "--sim",
        "G",
        "--seed",
        "22",
        "--json",
        "--resume",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let result: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(result["ok"], true, "{result}");
    assert_eq!(
        result["flags"],
        serde_json::json!(["resumed", "instrument-declared"]),
        "{result}"
    );
    assert_eq!(result["class"], "G");
    let doc = session(&dir);
    assert_eq!(doc["status"], "finished");
    assert_eq!(doc["sample"], "G");
    assert_eq!(doc["instrument"]["serial_number"], "SIM-0001");
    assert_eq!(
        doc["flags"],
        serde_json::json!(["resumed", "instrument-declared"])
    );
    let runs = doc["runs"].as_array().unwrap();
    let outcomes: Vec<&str> = runs
        .iter()
        .map(|r| r["outcome"].as_str().unwrap())
        .collect();
    assert_eq!(outcomes, ["interrupted", "killed", "finished"]);
    for (k, run) in runs.iter().enumerate() {
        assert_eq!(run["run"], k as u64 + 1);
        assert_eq!(run["host_version"], env!("CARGO_PKG_VERSION"));
        assert!(
            run["started"].as_str().is_some_and(|s| s.len() >= 23),
            "{run}"
        );
        assert!(
            !run["decisions"].as_array().unwrap().is_empty(),
            "run {}: no decisions kept: {run}",
            k + 1
        );
    }
    assert_eq!(runs[0]["readings_after"], 0);
    assert_eq!(runs[2]["readings_before"], readings_before_3);
    assert!(runs[1]["ended"].is_null() && runs[1]["why"].as_str().unwrap().contains("killed"));
    // The killed run's decisions come back from session.log.
    assert!(
        runs[1]["decisions"].to_string().contains("resuming"),
        "{}",
        runs[1]
    );
    let all = doc["decisions"].as_array().unwrap().len();
    assert_eq!(
        all,
        runs.iter()
            .map(|r| r["decisions"].as_array().unwrap().len())
            .sum::<usize>()
    );
    let verified = gonio(&["verify", dir.to_str().unwrap()]);
    assert!(verified.status.success(), "{}", stderr(&verified));
    let line = String::from_utf8_lossy(&verified.stdout);
    assert!(
        line.contains("sample 'G' on instrument SIM-0001, 3 runs"),
        "{line}"
    );
    // sha256sum checks the same manifest, where there is one.
    if let Ok(out) = Command::new("sha256sum")
        .arg("-c")
        .arg("--quiet")
        .arg("MANIFEST.sha256")
        .current_dir(&dir)
        .output()
    {
        assert!(
            out.status.success(),
            "sha256sum -c: {}{}",
            String::from_utf8_lossy(&out.stdout),
            stderr(&out)
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_failed_session_writes_its_status_and_log_and_decisions_reach_stderr_when_it_is_not_a_terminal()
{
    let dir = temp_dir("failed");
    let out = gonio(&[
        "measure",
        "--spots",
        "1",
        "--sim",
        "G",
        "--faults",
        "no-switch=source",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    let doc = session(&dir);
    assert_eq!(doc["status"], "failed");
    assert!(
        doc["why"]
            .as_str()
            .unwrap()
            .contains("home switch not found"),
        "{doc}"
    );
    assert_eq!(doc["runs"][0]["outcome"], "failed");
    assert!(doc["resume_with"].as_str().unwrap().contains("--resume"));
    let log = std::fs::read_to_string(dir.join("session.log")).unwrap();
    assert!(
        log.contains(
            "[run 1] session stopped (failed): the instrument refused Home: home switch not found"
        ),
        "{log}"
    );
    // Every line: a local date-time, the run, the decision.
    for line in log.lines() {
        let (stamp, rest) = line.split_once(' ').unwrap();
        assert!(
            chrono::DateTime::parse_from_rfc3339(stamp).is_ok() && rest.starts_with("[run 1] "),
            "{line}"
        );
    }
    assert!(
        stderr(&out).contains("session stopped (failed)"),
        "{}",
        stderr(&out)
    );
    // A session that goes through refinements prints them on a non-terminal stderr, as
    // session.log has them.
    let dir2 = temp_dir("decisions");
    let out = gonio(&[
        "measure",
        "--spots",
        "1",
        "--sim",
        "G",
        "--out",
        dir2.to_str().unwrap(),
    ]);
    cli_support::assert_finished(&out);
    let log = std::fs::read_to_string(dir2.join("session.log")).unwrap();
    let batch = log
        .lines()
        .find(|l| l.contains("adaptive batch 1"))
        .expect("a batch in the log");
    let decision = batch.split_once("] ").unwrap().1;
    assert!(stderr(&out).contains(decision), "{}", stderr(&out));
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&dir2);
}

#[test]
fn a_folder_in_use_by_another_process_is_refused() {
    let dir = temp_dir("in-use");
    killed(&dir, 30, &[]);
    let lock = FolderLock::take(&dir).unwrap();
    let error = run_in_process(
        &["--sim", "G", "--resume", dir.to_str().unwrap()],
        None,
        &mut SimulatedOperator,
        Arc::new(AtomicBool::new(false)),
    )
    .err()
    .expect("refused");
    assert!(
        matches!(
            error.downcast_ref::<FolderError>(),
            Some(FolderError::InUse(_))
        ),
        "{error:#}"
    );
    assert!(
        error
            .to_string()
            .contains("in use by another gonio process")
    );
    drop(lock);
    assert!(resumed(&dir).status.success());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn verify_names_every_file_changed_added_or_missing_and_exits_1() {
    let dir = temp_dir("verify");
    finished("PPC", &dir, &[]);
    let d = dir.to_str().unwrap();
    // Strategy 1's 12 readings, or more where the seed drawn for the run called for
    // refinements: 19 on seeds 96 and 176 (clean), 26 on seed 226467 (lack of fit measured
    // again twice, flagged).
    let readings = session(&dir)["readings_recorded"].as_u64().unwrap();
    assert!(readings >= 12, "{readings} readings");
    let out = gonio(&["verify", d]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(
        String::from_utf8_lossy(&out.stdout).contains(&format!(
            "verified: 10 files match MANIFEST.sha256; {readings} readings agree"
        )),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let pristine = contents(&dir);
    let check = |needles: &[&str]| {
        let out = gonio(&["verify", d]);
        assert_eq!(out.status.code(), Some(1));
        for needle in needles {
            assert!(
                stderr(&out).contains(needle),
                "no '{needle}' in {}",
                stderr(&out)
            );
        }
        for (name, bytes) in &pristine {
            std::fs::write(dir.join(name), bytes).unwrap();
        }
    };
    // A changed radiance factor: the manifest and the agreement both say so.
    let csv = String::from_utf8(pristine["readings.csv"].clone()).unwrap();
    std::fs::write(dir.join("readings.csv"), csv.replacen(",0.", ",0.1", 1)).unwrap();
    check(&[
        "readings.csv: changed since the session finished",
        "readings.csv:2: row",
    ]);
    std::fs::write(dir.join("extra.txt"), "x").unwrap();
    check(&["extra.txt: not in MANIFEST.sha256"]);
    std::fs::remove_file(dir.join("extra.txt")).unwrap();
    std::fs::remove_file(dir.join("calibration.json")).unwrap();
    check(&["calibration.json: missing (listed in MANIFEST.sha256:"]);
    std::fs::write(dir.join("MANIFEST.sha256"), "not a manifest\n").unwrap();
    check(&["MANIFEST.sha256:1: 'not a manifest' is not 'SHA256  NAME'"]);
    // A raw reading edited in points.jsonl and readings.csv rebuilt to match (a reading's
    // record is its raw reading; its radiance factor follows from calibration.json), the
    // manifest recomputed by hand: the records still disagree with session.json.
    let points = String::from_utf8(pristine["points.jsonl"].clone()).unwrap();
    let mut doc: Value = serde_json::from_str(points.lines().next().unwrap()).unwrap();
    doc["reading"]["mean_counts"] = (doc["reading"]["mean_counts"].as_f64().unwrap() * 1.01).into();
    let edited = points.replacen(points.lines().next().unwrap(), &doc.to_string(), 1);
    std::fs::write(dir.join("points.jsonl"), &edited).unwrap();
    let calibration: host::instrument::calibration::Calibration =
        serde_json::from_slice(&pristine["calibration.json"]).unwrap();
    let recorded: Vec<host::session::MeasuredPoint> = edited
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let rows = host::output::folder::readings_csv(&host::output::folder::converted(
        &recorded,
        Some(&calibration),
    ));
    std::fs::write(dir.join("readings.csv"), rows).unwrap();
    std::fs::write(
        dir.join("MANIFEST.sha256"),
        host::output::folder::manifest::manifest_text(&dir).unwrap(),
    )
    .unwrap();
    check(&["points.jsonl:1: differs from reading 1 of session.json"]);
    // Only the radiance factor recorded with it edited (and readings.csv with it): the
    // conversion by calibration.json does not give it, so readings.csv is not what the
    // record says.
    let mut doc: Value = serde_json::from_str(points.lines().next().unwrap()).unwrap();
    doc["radiance_factor"] = 0.5.into();
    let edited = points.replacen(points.lines().next().unwrap(), &doc.to_string(), 1);
    std::fs::write(dir.join("points.jsonl"), &edited).unwrap();
    let rows = host::output::folder::readings_csv(
        &edited
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect::<Vec<_>>(),
    );
    std::fs::write(dir.join("readings.csv"), rows).unwrap();
    std::fs::write(
        dir.join("MANIFEST.sha256"),
        host::output::folder::manifest::manifest_text(&dir).unwrap(),
    )
    .unwrap();
    check(&["readings.csv: holds rows from before"]);
    // --json for scripts.
    let out = gonio(&["verify", "--json", d]);
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (v["ok"].clone(), v["readings"].clone()),
        (Value::from(true), Value::from(readings))
    );
    // Not a session folder at all; and the usage error.
    let out = gonio(&["verify", temp_dir("nothing").to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("no such folder"), "{}", stderr(&out));
    assert_eq!(gonio(&["verify"]).status.code(), Some(2));
    let _ = std::fs::remove_dir_all(&dir);
}
