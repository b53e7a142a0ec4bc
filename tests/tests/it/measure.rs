//! `gonio measure` end to end through the pseudo-terminal: the host's serial-port code
//! against the simulated instrument served on a pty, as a real instrument would be reached.
//! Every session here asks its operator to place the white tile, as on any port.

#[allow(dead_code)] // The binary's own arguments, parsed as `gonio measure` parses them.
#[path = "../../../host/src/cli/measure/args.rs"]
mod measure_args;
use host::instrument::sim::SimOptions;
use host::measure::{Measured, measure};
use host::session::{Placement, SessionError, WallClockOperator};
use measure_args::parse_args;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

/// The simulated instrument on a pty, served from a thread until dropped or [`Served::stop`].
struct Served {
    path: String,
    stop: Arc<AtomicBool>,
    /// After the serving stops: keep the pty open (a frozen instrument) until dropped.
    keep_open: Arc<AtomicBool>,
    released: Arc<AtomicBool>,
    thread: Option<JoinHandle<hil_sim::SimInstrument>>,
}

/// How an instrument on a pty stops answering.
#[derive(Clone, Copy, PartialEq)]
enum Cut {
    /// The port goes away (the pty is closed, as a USB device that vanished).
    Vanish,
    /// The port stays but nothing answers (the simulator stops serving).
    Freeze,
}

impl Served {
    fn new(sample: &str, seed: u64, faults: &str) -> Served {
        let options = SimOptions {
            seed,
            faults: faults.into(),
            ..SimOptions::default()
        };
        let mut instrument = options.instrument(sample).expect("simulated instrument");
        let server = hil_sim::pty::PtyServer::open().expect("pseudo-terminal");
        let path = server.path().to_string_lossy().into_owned();
        let stop = Arc::new(AtomicBool::new(false));
        let keep_open = Arc::new(AtomicBool::new(false));
        let released = Arc::new(AtomicBool::new(false));
        let (flag, keep, release) = (stop.clone(), keep_open.clone(), released.clone());
        let thread = std::thread::spawn(move || {
            server.serve(&mut instrument, &flag).expect("serve");
            while keep.load(Ordering::Relaxed) && !release.load(Ordering::Relaxed) {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            drop(server);
            instrument
        });
        Served {
            path,
            stop,
            keep_open,
            released,
            thread: Some(thread),
        }
    }

    /// Stop answering, the `how` way.
    fn cut(&self, how: Cut) {
        self.keep_open.store(how == Cut::Freeze, Ordering::Relaxed);
        self.stop.store(true, Ordering::Relaxed);
    }

    /// Stop serving and hand back the instrument, to look at its state.
    fn stop(mut self) -> hil_sim::SimInstrument {
        self.stop.store(true, Ordering::Relaxed);
        self.released.store(true, Ordering::Relaxed);
        self.thread.take().unwrap().join().expect("server thread")
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.released.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// The person at the instrument: does as asked (at once unless given delays, in real
/// time), and remembers what.
type Person = WallClockOperator;

fn person() -> Person {
    WallClockOperator::new(Vec::new())
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gonio-e2e-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn run(
    args: &[&str],
    person: &mut Person,
    interrupted: Arc<AtomicBool>,
) -> anyhow::Result<Measured> {
    // Sessions of one spot: the simulator behind a pseudo-terminal cannot see the sheet
    // move, so sheets of several spots are tested in process (host/tests/it/sheet.rs).
    let one_spot: Vec<&str> = if args.contains(&"--spots") {
        args.to_vec()
    } else {
        [&["--spots", "1"], args].concat()
    };
    measure(
        &parse_args(one_spot).expect("arguments"),
        person,
        interrupted,
    )
}

/// A completed session's `--json` object.
fn completed(served: &Served, sample: &str, dir: &Path, extra: &[&str]) -> Value {
    let mut args = vec!["--port", &served.path, "--sample", sample];
    if !extra.contains(&"--resume") {
        args.extend(["--out", dir.to_str().unwrap()]);
    }
    args.extend_from_slice(extra);
    let mut person = person();
    match run(&args, &mut person, Arc::new(AtomicBool::new(false))).expect("session") {
        Measured::Done { summary, .. } => summary,
        Measured::Stopped { error, .. } => panic!("{sample}: stopped: {error}"),
        Measured::Sheet { .. } => panic!("{sample}: measured a sheet of several spots"),
    }
}

/// The geometries of the session's current readings. A reading superseded (taken while an
/// arm may have been off, or while the lamp was off after the instrument's fail-safe stop)
/// stays in the record, marked, and its geometry is measured again: it is not a geometry
/// recorded twice. (A fresh-clone CI run under load lost the host's heartbeat in
/// `paper_g_is_classified_g`: the stop put the lamp out, 8 readings were superseded and
/// measured again, and 111 readings held 103 geometries.)
fn geometries(dir: &Path) -> Vec<(f64, f64)> {
    let session: Value =
        serde_json::from_slice(&std::fs::read(dir.join("session.json")).unwrap()).unwrap();
    session["readings"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["superseded"] != true)
        .map(|p| {
            (
                p["theta_i_deg"].as_f64().unwrap(),
                p["theta_r_deg"].as_f64().unwrap(),
            )
        })
        .collect()
}

fn assert_each_once(g: &[(f64, f64)]) {
    let mut sorted = g.to_vec();
    sorted.sort_by(|a, b| a.partial_cmp(b).unwrap());
    sorted.dedup();
    assert_eq!(sorted.len(), g.len(), "a geometry was recorded twice");
}

fn paper(sample: &str, class: &str) {
    let served = Served::new(sample, 3, "");
    let dir = temp_dir(sample);
    let mut person = person();
    let args = [
        "--port",
        &served.path,
        "--sample",
        sample,
        "--policy",
        "paper",
        "--out",
        dir.to_str().unwrap(),
    ];
    let Measured::Done {
        summary: r,
        outcome,
        ..
    } = run(&args, &mut person, Arc::new(AtomicBool::new(false))).expect("session")
    else {
        panic!("{sample}: the session stopped");
    };
    assert_eq!(
        person.asked[..2.min(person.asked.len())],
        [Placement::WhiteTile, Placement::Sample],
        "{sample}: the operator places the tile, then the sample"
    );
    // On a loaded machine the host can miss the instrument's heartbeat (a fresh-clone CI
    // run did, on J1): its fail-safe stop turns the lamp off, and once it is lit again the
    // tile is read again to see that its output came back. That, and only that, asks for
    // the tile once more: one placement per relighting.
    let again = &person.asked[2..];
    assert!(
        again.iter().all(|p| *p == Placement::WhiteTile)
            && again.len() <= outcome.recoveries.lamp_relit as usize,
        "{sample}: asked {:?} with the lamp relit {} times",
        person.asked,
        outcome.recoveries.lamp_relit
    );
    assert_eq!(r["class"], class, "{sample}: {r}");
    assert_eq!(r["sigma_ok"], true, "{sample}: {r}");
    for key in [
        "group",
        "sigma_deg",
        "rho_s",
        "rho_d",
        "eta",
        "nmae",
        "geometries",
        "device_seconds",
        "refinements",
        "class_confidence",
    ] {
        assert!(r.get(key).is_some(), "{sample}: no {key}");
    }
    let refinements = r["refinements"].as_array().unwrap();
    if class.starts_with("rough") {
        assert!(
            refinements.is_empty(),
            "{sample}: rough papers need no refinement: {r}"
        );
        assert_eq!(r["geometries"], 12);
    } else {
        // The paper: G passes σ_l at δ ≤ 3°, SG at δ ≤ 8°.
        let last = refinements
            .last()
            .and_then(|r| r["delta_deg"].as_u64())
            .unwrap();
        assert!(
            if sample == "G" { last <= 3 } else { last <= 8 },
            "{sample}: {r}"
        );
    }
    let astm = format!("{sample}.astm");
    let mut files = vec![
        "session.json",
        "readings.csv",
        "points.jsonl",
        "calibration.json",
        astm.as_str(),
        "fig4-radiance-factor.svg",
        "fig5-sigma-rho_s.svg",
    ];
    if class.starts_with("rough") {
        files.push("fig7-rho_s-rho_d.svg");
    }
    for file in files {
        assert!(dir.join(file).exists(), "{sample}: no {file}");
    }
    assert_each_once(&geometries(&dir));
    let _ = std::fs::remove_dir_all(&dir);
}

macro_rules! papers {
    ($($name:ident: $sample:literal => $class:literal,)*) => {$(
        #[test]
        fn $name() {
            paper($sample, $class);
        }
    )*};
}

papers! {
    paper_g_is_classified_g: "G" => "G",
    paper_sg_is_classified_sg: "SG" => "SG",
    paper_ppc_is_classified_rough_ii: "PPC" => "rough-II",
    paper_mc_is_classified_rough_iii: "MC" => "rough-III",
    paper_j1_is_classified_rough_i: "J1" => "rough-I",
    paper_j2_is_classified_rough_i: "J2" => "rough-I",
    paper_j3_is_classified_rough_ii: "J3" => "rough-II",
    paper_j4_is_classified_rough_ii: "J4" => "rough-II",
}

#[test]
fn a_faulty_link_still_gives_the_same_class_and_every_geometry_once() {
    let clean_dir = temp_dir("clean");
    let faulty_dir = temp_dir("faulty");
    let clean = completed(&Served::new("G", 1, ""), "G", &clean_dir, &[]);
    let faulty = completed(
        &Served::new("G", 1, "corrupt=0.001,drop=0.001,unplug-at=20:3"),
        "G",
        &faulty_dir,
        &[],
    );
    assert_eq!(faulty["class"], clean["class"]);
    let g = geometries(&faulty_dir);
    assert_each_once(&g);
    let session: Value =
        serde_json::from_slice(&std::fs::read(faulty_dir.join("session.json")).unwrap()).unwrap();
    let decisions = session["decisions"].to_string();
    // Not necessarily the same geometries: the simulated detector keeps sampling while the
    // cable is out, so the readings after it carry other noise draws and the adaptive
    // batches may be placed otherwise (a first batch that did not resolve σ: 26 against
    // 20). Each geometry once, Strategy 1's at least, and the same class.
    assert!(g.len() >= 12, "faulty: {decisions}");
    assert!(
        decisions.contains("link back"),
        "the unplug was noticed and recovered: {decisions}"
    );
    let _ = std::fs::remove_dir_all(&clean_dir);
    let _ = std::fs::remove_dir_all(&faulty_dir);
}

fn resume(policy: &str) {
    let full_dir = temp_dir(&format!("resume-{policy}-full"));
    let full = completed(
        &Served::new("SG", 8, ""),
        "SG",
        &full_dir,
        &["--policy", policy],
    );
    let all = geometries(&full_dir);
    // The same session stopped once 20 readings are on disk (the paper's policy: 49 on
    // SG), or 14 (adaptive: into its first batch after Strategy 1's 12; over the pty the
    // adaptive SG of seed 8 took 18 to 31 with the model's extensions, for its device
    // time, hence its lamp's drift, follows the host's pace), then the next line cut short
    // as a crash while writing it leaves it.
    let stop_at = if policy == "paper" { 20 } else { 14 };
    let dir = temp_dir(&format!("resume-{policy}"));
    let interrupted = Arc::new(AtomicBool::new(false));
    let ended = Arc::new(AtomicBool::new(false));
    let watcher = {
        let (flag, points) = (interrupted.clone(), dir.join("points.jsonl"));
        let ended = ended.clone();
        std::thread::spawn(move || {
            while std::fs::read_to_string(&points).map_or(0, |t| t.lines().count()) < stop_at {
                if ended.load(Ordering::Relaxed) {
                    return;
                }
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
            flag.store(true, Ordering::Relaxed);
        })
    };
    let served = Served::new("SG", 8, "");
    let args = [
        "--port",
        served.path.as_str(),
        "--sample",
        "SG",
        "--policy",
        policy,
        "--out",
        dir.to_str().unwrap(),
    ];
    let outcome = run(&args, &mut person(), interrupted).unwrap();
    ended.store(true, Ordering::Relaxed);
    watcher.join().unwrap();
    let Measured::Stopped { .. } = outcome else {
        panic!("not stopped after {stop_at} readings of {}", all.len())
    };
    drop(served);
    let before = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    let taken = before.lines().count();
    let mut points = std::fs::OpenOptions::new()
        .append(true)
        .open(dir.join("points.jsonl"))
        .unwrap();
    // (The start of a reading's line, as a crash in the middle of its write leaves it.)
    std::io::Write::write_all(
        &mut points,
        &before.lines().last().unwrap().as_bytes()[..30],
    )
    .unwrap();
    let served = Served::new("SG", 8, "");
    let mut person = person();
    let args = [
        "--port",
        served.path.as_str(),
        "--sample",
        "SG",
        "--policy",
        policy,
        "--resume",
        dir.to_str().unwrap(),
    ];
    let Measured::Done {
        summary: resumed, ..
    } = run(&args, &mut person, Arc::new(AtomicBool::new(false))).unwrap()
    else {
        panic!("stopped")
    };
    assert!(
        person.asked.is_empty(),
        "the session's own calibration is reused: no tile"
    );
    assert_eq!(resumed["class"], full["class"]);
    let g = geometries(&dir);
    assert_each_once(&g);
    let after = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    assert!(
        after.starts_with(&before),
        "the readings taken before the crash are kept as they were"
    );
    if policy == "paper" {
        // A fixed procedure: exactly what the uninterrupted session measured.
        assert_eq!(g.len(), all.len());
    } else {
        // The adaptive policy plans again from what it has: it may choose other geometries,
        // never one already measured, or none where what it has meets its targets (the
        // extended fit of SG can at 15 readings).
        assert!(g.len() >= taken && resumed["sigma_ok"] == true, "{resumed}");
    }
    let log = std::fs::read_to_string(dir.join("session.log")).unwrap();
    assert!(
        log.contains("points.jsonl: removed its last line, cut short by a crash"),
        "{log}"
    );
    host::output::folder::verify::verify(&dir, host::output::report::draw).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&full_dir);
}

#[test]
fn an_interrupted_session_resumes_measuring_only_what_is_missing() {
    resume("paper");
}

#[test]
fn an_interrupted_adaptive_session_resumes_without_measuring_anything_twice() {
    resume("adaptive");
}

#[test]
fn ctrl_c_stops_the_instrument_and_keeps_every_reading() {
    let dir = temp_dir("ctrl-c");
    let served = Served::new("G", 5, "");
    let interrupted = Arc::new(AtomicBool::new(false));
    // Ctrl-C once the sixth reading is on disk, from another thread as a signal handler would.
    let watcher = {
        let (flag, points) = (interrupted.clone(), dir.join("points.jsonl"));
        std::thread::spawn(move || {
            while std::fs::read_to_string(&points).map_or(0, |t| t.lines().count()) < 6 {
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
            flag.store(true, Ordering::Relaxed);
        })
    };
    let mut person = person();
    let args = [
        "--port",
        served.path.as_str(),
        "--sample",
        "G",
        "--out",
        dir.to_str().unwrap(),
    ];
    let outcome = run(&args, &mut person, interrupted).expect("no failure but the interruption");
    watcher.join().unwrap();
    let Measured::Stopped { error, .. } = outcome else {
        panic!("the session went on after Ctrl-C")
    };
    assert!(matches!(error, SessionError::Interrupted), "{error}");
    let instrument = served.stop();
    assert!(!instrument.hardware().mechanics().lamp_on(), "lamp left on");
    assert!(instrument.is_idle(), "arms still moving");
    let kept = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    let taken = kept.lines().count();
    assert!((6..12).contains(&taken), "{taken} readings kept");
    // And the session can be finished later, measuring only what is missing.
    let resumed = completed(
        &Served::new("G", 5, ""),
        "G",
        &dir,
        &["--resume", dir.to_str().unwrap()],
    );
    assert_eq!(resumed["class"], "G");
    assert_each_once(&geometries(&dir));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ctrl_c_during_homing_stops_the_arms_there() {
    let dir = temp_dir("ctrl-c-homing");
    let served = Served::new("G", 6, "");
    let interrupted = Arc::new(AtomicBool::new(false));
    // Homing the reference instrument takes seconds of device time; the pty lets device
    // time lead by at most 1.5 s past the host's last frame, so 20 ms in it is still going.
    let watcher = {
        let flag = interrupted.clone();
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(20));
            flag.store(true, Ordering::Relaxed);
        })
    };
    let args = [
        "--port",
        served.path.as_str(),
        "--sample",
        "G",
        "--out",
        dir.to_str().unwrap(),
    ];
    let outcome = run(&args, &mut person(), interrupted).expect("no failure but the interruption");
    watcher.join().unwrap();
    let Measured::Stopped { error, .. } = outcome else {
        panic!("the session went on after Ctrl-C")
    };
    assert!(matches!(error, SessionError::Interrupted), "{error}");
    // Ask the instrument, as any host would.
    let mut client = host::instrument::link::Client::new(
        host::instrument::serial::SerialTransport::open(&served.path).unwrap(),
        host::instrument::link::RetryPolicy::default(),
    );
    client.hello().unwrap();
    let Ok(protocol::Reply::Status(status)) = client.request(protocol::Command::GetStatus) else {
        panic!("no status")
    };
    assert!(
        !(status.homed_i && status.homed_r),
        "homing ran to its end: the Ctrl-C was not heard during it"
    );
    assert!(!status.lamp_on, "lamp left on");
    drop(client);
    let instrument = served.stop();
    assert!(instrument.is_idle(), "arms still moving");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_stale_calibration_is_refused_with_its_age() {
    let dir = temp_dir("stale");
    completed(&Served::new("MC", 2, ""), "MC", &dir, &[]);
    let path = dir.join("calibration.json");
    let mut calibration: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    calibration["taken_unix_s"] =
        Value::from(calibration["taken_unix_s"].as_u64().unwrap() - 9 * 3600);
    std::fs::write(&path, calibration.to_string()).unwrap();
    let served = Served::new("MC", 2, "");
    let out = temp_dir("stale2");
    let args = [
        "--port",
        served.path.as_str(),
        "--calibration",
        path.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    let error = match run(&args, &mut person(), Arc::new(AtomicBool::new(false))) {
        Err(error) => format!("{error:#}"),
        Ok(_) => panic!("a 9 h old calibration was used"),
    };
    assert!(
        error.contains("9.0 h old") && error.contains("limit is 8.0 h"),
        "{error}"
    );
    assert!(
        !out.join("points.jsonl").exists(),
        "nothing measured with a refused calibration"
    );
    // A fresh enough one is used as is: no white tile.
    let mut person = person();
    let out = temp_dir("stale3");
    let args = [
        "--port",
        served.path.as_str(),
        "--calibration",
        dir.to_str().unwrap(),
        "--max-calibration-age-h",
        "24",
        "--out",
        out.to_str().unwrap(),
    ];
    let Measured::Done { summary, .. } =
        run(&args, &mut person, Arc::new(AtomicBool::new(false))).unwrap()
    else {
        panic!("stopped")
    };
    assert_eq!(summary["class"], "rough-III");
    assert!(person.asked.is_empty());
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&out);
}

/// A device of another protocol version on a pseudo-terminal: it answers every request
/// with the frozen refusal, naming its version.
fn serve_device_of_version(version: u16) -> (String, Arc<AtomicBool>, JoinHandle<()>) {
    use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
    use protocol::*;
    use std::os::fd::AsFd;
    let pty = nix::pty::openpty(None, None).unwrap();
    let mut termios = nix::sys::termios::tcgetattr(&pty.slave).unwrap();
    nix::sys::termios::cfmakeraw(&mut termios);
    nix::sys::termios::tcsetattr(&pty.slave, nix::sys::termios::SetArg::TCSANOW, &termios).unwrap();
    let path = nix::unistd::ttyname(&pty.slave)
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let thread = std::thread::spawn(move || {
        let _slave = pty.slave;
        let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
        let mut buf = [0u8; 1024];
        while !flag.load(Ordering::Relaxed) {
            let mut fds = [PollFd::new(pty.master.as_fd(), PollFlags::POLLIN)];
            if poll(&mut fds, PollTimeout::from(10u8)).unwrap_or(0) == 0 {
                continue;
            }
            let Ok(n) = nix::unistd::read(&pty.master, &mut buf) else {
                continue;
            };
            let mut requests = Vec::new();
            decoder.feed(&buf[..n], |r: Result<Request, FrameError>| requests.push(r));
            for request in requests.into_iter().flatten() {
                let error =
                    DeviceError::with_detail(ErrorCode::VersionMismatch, i32::from(version));
                let reply = DeviceMessage::Reply {
                    seq: request.seq,
                    result: Err(error),
                };
                let mut frame = [0u8; MAX_FRAME_LEN];
                let _ = nix::unistd::write(&pty.master, encode_frame(&reply, &mut frame).unwrap());
            }
        }
    });
    (path, stop, thread)
}

#[test]
fn an_instrument_of_another_protocol_version_is_refused_saying_which_side_to_update() {
    for (version, advice) in [
        (protocol::PROTOCOL_VERSION + 1, "update the host software"),
        (
            protocol::PROTOCOL_VERSION - 1,
            "update the instrument's firmware with `gonio flash`",
        ),
    ] {
        let (path, stop, thread) = serve_device_of_version(version);
        let dir = temp_dir(&format!("version-{version}"));
        let result = run(
            &["--port", path.as_str(), "--out", dir.to_str().unwrap()],
            &mut person(),
            Arc::new(AtomicBool::new(false)),
        );
        stop.store(true, Ordering::Relaxed);
        thread.join().unwrap();
        let error = match result {
            Err(error) => format!("{error:#}"),
            Ok(_) => panic!("a device of version {version} was accepted"),
        };
        assert!(
            error.contains("protocol version mismatch") && error.contains(advice),
            "{error}"
        );
        assert!(!dir.exists(), "no session folder for a refused instrument");
    }
}

/// `points.jsonl` of `dir` has at least `n` lines (read by a watcher while a session runs).
fn wait_for_readings(dir: &Path, n: usize) {
    let points = dir.join("points.jsonl");
    let started = std::time::Instant::now();
    while std::fs::read_to_string(&points).map_or(0, |t| t.lines().count()) < n {
        assert!(
            started.elapsed() < std::time::Duration::from_secs(120),
            "no {n} readings in {}",
            points.display()
        );
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
}

/// A session on a pty whose instrument stops answering after `after` readings: how it ends.
fn cut_off(
    how: Cut,
    sample: &str,
    seed: u64,
    after: usize,
) -> (SessionError, PathBuf, std::time::Duration) {
    let dir = temp_dir(&format!(
        "cut-{sample}-{seed}-{}",
        if how == Cut::Vanish {
            "vanish"
        } else {
            "freeze"
        }
    ));
    let served = Arc::new(Served::new(sample, seed, ""));
    let cut_at = Arc::new(std::sync::Mutex::new(None));
    let watcher = {
        let (served, dir, cut_at) = (served.clone(), dir.clone(), cut_at.clone());
        std::thread::spawn(move || {
            wait_for_readings(&dir, after);
            *cut_at.lock().unwrap() = Some(std::time::Instant::now());
            served.cut(how);
        })
    };
    let args = [
        "--port",
        served.path.as_str(),
        "--sample",
        sample,
        "--out",
        dir.to_str().unwrap(),
    ];
    let outcome = run(&args, &mut person(), Arc::new(AtomicBool::new(false)))
        .expect("no failure but the lost instrument");
    let ended = std::time::Instant::now();
    watcher.join().unwrap();
    let cut_at = cut_at.lock().unwrap().expect("cut");
    let Measured::Stopped { error, .. } = outcome else {
        panic!("{sample}: finished without its instrument")
    };
    (error, dir, ended - cut_at)
}

fn assert_given_up(how: Cut, sample: &str, seed: u64) {
    let (error, dir, took) = cut_off(how, sample, seed, 5);
    let text = error.to_string();
    let SessionError::Lost {
        loss, silent_for, ..
    } = &error
    else {
        panic!("{sample}: {text}")
    };
    // Silence on the host's clock (wall time on a port): the 10 s bound, give or take a
    // loaded machine's scheduling; and the session did end (no hang), in about that time.
    assert!(
        *silent_for <= std::time::Duration::from_secs(11),
        "{sample}: {silent_for:?}"
    );
    assert!(
        took < std::time::Duration::from_secs(30),
        "{sample}: {took:?} after the cut"
    );
    match how {
        Cut::Vanish => {
            assert!(
                matches!(loss, host::session::LinkLoss::PortGone(_)),
                "{sample}: {loss:?}"
            );
            assert!(
                text.contains("port is gone") && text.contains("reconnect the cable"),
                "{text}"
            );
        }
        Cut::Freeze => {
            assert_eq!(*loss, host::session::LinkLoss::NoAnswer, "{sample}: {text}");
            assert!(
                text.contains("the port is there")
                    && text.contains("has not answered")
                    && text.contains("power-cycle"),
                "{text}"
            );
        }
    }
    assert!(
        text.contains("decisions so far") && text.contains("link lost"),
        "{text}"
    );
    // Everything measured is kept, and the folder says how to resume.
    let kept = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    assert!(
        kept.lines().count() >= 5
            && kept
                .lines()
                .all(|l| serde_json::from_str::<Value>(l).is_ok())
    );
    let session: Value =
        serde_json::from_slice(&std::fs::read(dir.join("session.json")).unwrap()).unwrap();
    assert!(session.to_string().contains("--resume"), "{session}");
    let log = std::fs::read_to_string(dir.join("session.log")).unwrap();
    assert!(log.contains("giving up"), "{log}");
    eprintln!(
        "{sample}: given up {:.2} s after the cut, {:.2} s of silence: {}",
        took.as_secs_f64(),
        silent_for.as_secs_f64(),
        text.lines().next().unwrap_or("")
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_vanished_port_is_given_up_within_10_s_saying_the_port_is_gone() {
    assert_given_up(Cut::Vanish, "G", 11);
}

#[test]
fn a_frozen_instrument_is_given_up_within_10_s_saying_nothing_answers() {
    assert_given_up(Cut::Freeze, "SG", 12);
}

#[test]
fn a_person_who_takes_a_real_10_s_at_the_white_tile_finds_the_instrument_homed_and_lit() {
    let served = Served::new("PPC", 13, "");
    let dir = temp_dir("slow-person");
    let mut person = WallClockOperator::new(vec![
        std::time::Duration::from_secs(10),
        std::time::Duration::ZERO,
    ]);
    let args = [
        "--port",
        served.path.as_str(),
        "--sample",
        "PPC",
        "--out",
        dir.to_str().unwrap(),
    ];
    let Measured::Done {
        summary, outcome, ..
    } = run(&args, &mut person, Arc::new(AtomicBool::new(false))).expect("session")
    else {
        panic!("stopped")
    };
    assert_eq!(person.asked, [Placement::WhiteTile, Placement::Sample]);
    assert_eq!(summary["class"], "rough-II", "{summary}");
    assert_eq!(summary["ok"], true, "{summary}");
    let waited = outcome
        .decisions
        .iter()
        .find(|d| d.contains("answered after"))
        .expect("the wait");
    assert!(
        waited.contains("after 10.") || waited.contains("after 11."),
        "{waited}"
    );
    let r = &outcome.recoveries;
    assert_eq!(
        (r.stops, r.rehomings, r.lamp_relit, r.reconnections),
        (0, 0, 0, 0),
        "{r:?}: {:#?}",
        outcome.decisions
    );
    assert_each_once(&geometries(&dir));
    let instrument = served.stop();
    assert!(instrument.is_idle());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn thirty_sessions_on_the_pty_with_a_pulled_cable_and_a_bad_link_all_finish_clean() {
    use host::study::reliability::{self, FaultKind};
    let durations = reliability::session_durations().expect("fault-free sessions");
    let specs: Vec<_> = (0..30)
        .map(|k| reliability::draw(5000 + k, &[FaultKind::Mixed], &durations))
        .collect();
    let failures = std::sync::Mutex::new(Vec::new());
    let next = std::sync::atomic::AtomicUsize::new(0);
    let flagged = std::sync::atomic::AtomicUsize::new(0);
    let named = std::sync::atomic::AtomicUsize::new(0);
    // A pty session mostly waits (the simulator keeps device time within reach of the
    // host's heartbeats): eight at a time. The thirty took 112 s of wall clock and 15 s of
    // CPU four at a time, the longest pole of the end-to-end tests in CI.
    std::thread::scope(|scope| {
        for _ in 0..8 {
            scope.spawn(|| {
                while let Some(spec) = specs.get(next.fetch_add(1, Ordering::Relaxed)) {
                    let what = format!(
                        "#{} {} {:?} seed {} faults {}",
                        spec.index,
                        spec.sample,
                        spec.policy,
                        spec.seed,
                        spec.faults()
                    );
                    let served = Served::new(spec.sample, spec.seed, &spec.faults());
                    let dir = temp_dir(&format!("pty-campaign-{}", spec.index));
                    let policy = if spec.policy == host::session::PolicyChoice::Paper {
                        "paper"
                    } else {
                        "adaptive"
                    };
                    let args = [
                        "--port",
                        served.path.as_str(),
                        "--sample",
                        spec.sample,
                        "--policy",
                        policy,
                        "--out",
                        dir.to_str().unwrap(),
                    ];
                    let verdict = match run(&args, &mut person(), Arc::new(AtomicBool::new(false)))
                    {
                        Ok(Measured::Done { outcome, .. }) => {
                            let row = reliability::judge(spec, &Ok(*outcome));
                            if row.lack_of_fit() {
                                flagged.fetch_add(1, Ordering::Relaxed);
                            }
                            if row.outlier() {
                                named.fetch_add(1, Ordering::Relaxed);
                            }
                            row.failure.map(|why| format!("{what}: {why}"))
                        }
                        Ok(Measured::Stopped { error, .. }) => {
                            Some(format!("{what}: stopped: {error}"))
                        }
                        Ok(Measured::Sheet { .. }) => {
                            Some(format!("{what}: measured a sheet, not one spot"))
                        }
                        Err(error) => Some(format!("{what}: {error:#}")),
                    };
                    if let Some(why) = verdict {
                        failures.lock().unwrap().push(why);
                    }
                    let _ = std::fs::remove_dir_all(&dir);
                }
            });
        }
    });
    let failures = failures.into_inner().unwrap();
    assert!(
        failures.is_empty(),
        "{} of {} pty sessions did not finish clean:\n{}",
        failures.len(),
        specs.len(),
        failures.join("\n")
    );
    // lack-of-fit: the goodness-of-fit test's false alarm, at its stated rate (the class
    // of a flagged session is right all the same).
    let flagged = flagged.into_inner();
    assert!(
        flagged <= reliability::lack_of_fit_allowed(specs.len()),
        "lack-of-fit in {flagged} of {} pty sessions",
        specs.len()
    );
    // outlier: the outlier test's false alarm, likewise. Session #5026 (J1, seed 286171)
    // draws two readings about 3.5 and −3.2 standard deviations off the noiseless truth on
    // the pty, faults or none, and its fit may name one; a reading the link corrupted and
    // the session kept would be named too, and more than the rate allows fails.
    let named = named.into_inner();
    assert!(
        named <= reliability::outliers_allowed(specs.len()),
        "outlier in {named} of {} pty sessions",
        specs.len()
    );
}

/// The stretches of θr in `0 ..= 70°` at `theta_i_deg` that `readings` (session.json's,
/// sweeps' bins only) leave uncovered by more than `tolerance_deg`.
fn sweep_gaps(
    readings: &[Value],
    theta_i_deg: f64,
    usable_only: bool,
    tolerance_deg: f64,
) -> Vec<(f64, f64)> {
    let mut intervals: Vec<(f64, f64)> = readings
        .iter()
        .filter(|p| {
            p["theta_i_deg"].as_f64() == Some(theta_i_deg)
                && p["theta_r_span_deg"].as_f64().unwrap_or(0.0) > 0.0
        })
        .filter(|p| p["superseded"] != true)
        .filter(|p| {
            !usable_only
                || (p.get("unusable").is_none_or(Value::is_null)
                    && (p["radiance_factor"].is_number() || p["reading"]["saturated"] == true))
        })
        .map(|p| {
            let (middle, span) = (
                p["theta_r_deg"].as_f64().unwrap(),
                p["theta_r_span_deg"].as_f64().unwrap(),
            );
            (middle - 0.5 * span, middle + 0.5 * span)
        })
        .collect();
    intervals.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut at, mut gaps) = (0.0_f64, Vec::new());
    for (a, b) in intervals {
        if a > at + tolerance_deg {
            gaps.push((at, a));
        }
        at = at.max(b);
    }
    if 70.0 > at + tolerance_deg {
        gaps.push((at, 70.0));
    }
    gaps
}

/// Sweep sessions through the pty with a corrupting, dropping link and the cable pulled at
/// a random moment of the first pass (a different one for every seed): each finishes
/// with the clean session's class, every bin it received recorded once (a duplicate on
/// the link is not a second bin), and θr 0–70° covered on every whole line it swept (the
/// first pass's 20° and 60°, 30° and 45° too where the fit lacked fit) — the
/// bins lost on the link or cut off by the unplug measured again, only a range switch's
/// blanking (≤ 0.5°) left as it is.
#[test]
fn sweep_sessions_with_a_bad_link_and_a_pulled_cable_finish_with_every_bin_once() {
    // (sample, class, seed), the seeds (and so the unplug's moments) drawn for this run and
    // named in every message: the first pass runs from about 12 s of device time (homing
    // and the calibration before it) to about 17 s.
    let drawn = 1 + crate::seed::run_seed();
    let cases = [
        ("G", "G", drawn),
        ("G", "G", drawn + 1),
        ("SG", "SG", drawn + 2),
        ("J1", "rough-I", drawn + 3),
    ];
    std::thread::scope(|scope| {
        for &(sample, class, seed) in &cases {
            scope.spawn(move || {
                // The unplug's moment from the seed (splitmix64), anywhere in the pass.
                let mut z = seed.wrapping_add(0x9e37_79b9_7f4a_7c15);
                z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
                let unplug_at_s = 12.3 + 4.6 * ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64;
                let faults = format!("corrupt=0.001,drop=0.001,unplug-at={unplug_at_s:.3}:2");
                let what = format!("{sample} seed {seed} faults {faults}");
                let dir = temp_dir(&format!("sweep-faulty-{sample}-{seed}"));
                let served = Served::new(sample, seed, &faults);
                let summary = completed(&served, sample, &dir, &["--policy", "sweep"]);
                assert_eq!(summary["class"], class, "{what}: {summary}");
                let session: Value = serde_json::from_slice(&std::fs::read(dir.join("session.json")).unwrap()).unwrap();
                let decisions = session["decisions"].to_string();
                assert!(decisions.contains("link back"), "{what}: the unplug was noticed and recovered: {decisions}");
                let readings = session["readings"].as_array().unwrap();
                let mut bins: Vec<(u64, u64)> = readings
                    .iter()
                    .filter(|p| p["theta_r_span_deg"].as_f64().unwrap_or(0.0) > 0.0)
                    .map(|p| (p["schedule_id"].as_u64().unwrap(), p["index"].as_u64().unwrap()))
                    .collect();
                let received = bins.len();
                assert!(received > 1300, "{what}: {received} bins");
                bins.sort_unstable();
                bins.dedup();
                assert_eq!(bins.len(), received, "{what}: a bin was recorded twice");
                // Whole lines: the first pass's, and the rest of the full plane's where the
                // fit lacked fit (sweeps across the peak cover only its neighbourhood).
                let whole_plane = decisions.contains("the rest of the full plane");
                let lines: &[f64] = if whole_plane { &[20.0, 30.0, 45.0, 60.0] } else { &[20.0, 60.0] };
                for &theta_i in lines {
                    let lost = sweep_gaps(readings, theta_i, false, 0.05);
                    assert!(lost.is_empty(), "{what}: θi = {theta_i}°: stretches never received: {lost:?}");
                    let unusable = sweep_gaps(readings, theta_i, true, 0.5);
                    assert!(unusable.is_empty(), "{what}: θi = {theta_i}°: stretches without a usable bin over 0.5°: {unusable:?}");
                }
                let _ = std::fs::remove_dir_all(&dir);
            });
        }
    });
}
