//! `gonio measure` end to end through the pseudo-terminal: the host's serial-port code
//! against the simulated instrument served on a pty, as a real instrument would be reached.
//! Every session here asks its operator to place the white tile, as on any port.

use host::cli::measure::{Measured, measure, parse_args};
use host::session::{Operator, Placement, SessionError};
use host::instrument::sim::SimOptions;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

/// The simulated instrument on a pty, served from a thread until dropped or [`Served::stop`].
struct Served {
    path: String,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<hil_sim::SimInstrument>>,
}

impl Served {
    fn new(sample: &str, seed: u64, faults: &str) -> Served {
        let options = SimOptions { seed, faults: faults.into(), ..SimOptions::default() };
        let mut instrument = options.instrument(sample).expect("simulated instrument");
        let server = hil_sim::pty::PtyServer::open().expect("pseudo-terminal");
        let path = server.path().to_string_lossy().into_owned();
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            server.serve(&mut instrument, &flag).expect("serve");
            instrument
        });
        Served { path, stop, thread: Some(thread) }
    }

    /// Stop serving and hand back the instrument, to look at its state.
    fn stop(mut self) -> hil_sim::SimInstrument {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.take().unwrap().join().expect("server thread")
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// The person at the instrument: does as asked at once, and remembers what.
#[derive(Default)]
struct Person {
    asked: Vec<Placement>,
}

impl Operator for Person {
    fn place(&mut self, placement: Placement) -> std::io::Result<()> {
        self.asked.push(placement);
        Ok(())
    }
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gonio-e2e-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn run(args: &[&str], person: &mut Person, interrupted: Arc<AtomicBool>) -> anyhow::Result<Measured> {
    measure(&parse_args(args).expect("arguments"), person, interrupted)
}

/// A completed session's `--json` object.
fn completed(served: &Served, sample: &str, dir: &Path, extra: &[&str]) -> Value {
    let mut args = vec!["--port", &served.path, "--sample", sample];
    if !extra.contains(&"--resume") {
        args.extend(["--out", dir.to_str().unwrap()]);
    }
    args.extend_from_slice(extra);
    let mut person = Person::default();
    match run(&args, &mut person, Arc::new(AtomicBool::new(false))).expect("session") {
        Measured::Done { summary, .. } => summary,
        Measured::Stopped { error, .. } => panic!("{sample}: stopped: {error}"),
    }
}

fn geometries(dir: &Path) -> Vec<(f64, f64)> {
    let session: Value = serde_json::from_slice(&std::fs::read(dir.join("session.json")).unwrap()).unwrap();
    session["readings"].as_array().unwrap().iter().map(|p| (p["theta_i_deg"].as_f64().unwrap(), p["theta_r_deg"].as_f64().unwrap())).collect()
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
    let mut person = Person::default();
    let args = ["--port", &served.path, "--sample", sample, "--policy", "paper", "--out", dir.to_str().unwrap()];
    let Measured::Done { summary: r, .. } = run(&args, &mut person, Arc::new(AtomicBool::new(false))).expect("session") else {
        panic!("{sample}: the session stopped");
    };
    assert_eq!(person.asked, [Placement::WhiteTile, Placement::Sample], "{sample}: the operator places the tile, then the sample");
    assert_eq!(r["class"], class, "{sample}: {r}");
    assert_eq!(r["sigma_ok"], true, "{sample}: {r}");
    for key in ["group", "sigma_deg", "rho_s", "rho_d", "eta", "nmae", "geometries", "device_seconds", "refinements", "class_confidence"] {
        assert!(r.get(key).is_some(), "{sample}: no {key}");
    }
    let refinements = r["refinements"].as_array().unwrap();
    if class.starts_with("rough") {
        assert!(refinements.is_empty(), "{sample}: rough papers need no refinement: {r}");
        assert_eq!(r["geometries"], 12);
    } else {
        // The paper: G passes σ_l at δ ≤ 3°, SG at δ ≤ 8°.
        let last = refinements.last().and_then(Value::as_u64).unwrap();
        assert!(if sample == "G" { last <= 3 } else { last <= 8 }, "{sample}: {r}");
    }
    let mut files = vec!["session.json", "readings.csv", "points.jsonl", "calibration.json", "astm-e1392.csv", "fig4-radiance-factor.svg", "fig5-sigma-rho_s.svg"];
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
    let faulty = completed(&Served::new("G", 1, "corrupt=0.001,drop=0.001,unplug-at=5"), "G", &faulty_dir, &[]);
    assert_eq!(faulty["class"], clean["class"]);
    let g = geometries(&faulty_dir);
    assert_each_once(&g);
    assert_eq!(g.len(), geometries(&clean_dir).len());
    let session: Value = serde_json::from_slice(&std::fs::read(faulty_dir.join("session.json")).unwrap()).unwrap();
    let decisions = session["decisions"].to_string();
    assert!(decisions.contains("link lost"), "the unplug was noticed and recovered: {decisions}");
    let _ = std::fs::remove_dir_all(&clean_dir);
    let _ = std::fs::remove_dir_all(&faulty_dir);
}

fn resume(policy: &str) {
    let dir = temp_dir(&format!("resume-{policy}"));
    let full = completed(&Served::new("SG", 8, ""), "SG", &dir, &["--policy", policy]);
    let all = geometries(&dir);
    // As if it had crashed after 20 readings, the last line cut short.
    let points = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    let mut kept: String = points.lines().take(20).map(|l| format!("{l}\n")).collect();
    kept.push_str(&points.lines().nth(20).unwrap()[..30]);
    std::fs::write(dir.join("points.jsonl"), kept).unwrap();
    std::fs::remove_file(dir.join("session.json")).unwrap();
    let served = Served::new("SG", 8, "");
    let mut person = Person::default();
    let args = ["--port", served.path.as_str(), "--sample", "SG", "--policy", policy, "--resume", dir.to_str().unwrap()];
    let Measured::Done { summary: resumed, .. } = run(&args, &mut person, Arc::new(AtomicBool::new(false))).unwrap() else { panic!("stopped") };
    assert!(person.asked.is_empty(), "the session's own calibration is reused: no tile");
    assert_eq!(resumed["class"], full["class"]);
    let g = geometries(&dir);
    assert_each_once(&g);
    assert!(g[..20] == all[..20], "the readings taken before the crash are kept as they were");
    if policy == "paper" {
        // A fixed procedure: exactly what the uninterrupted session measured.
        assert_eq!(g.len(), all.len());
    } else {
        // The adaptive policy plans again from what it has: it may choose other geometries,
        // never one already measured.
        assert!(g.len() >= 21 && resumed["sigma_ok"] == true, "{resumed}");
    }
    let _ = std::fs::remove_dir_all(&dir);
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
    let mut person = Person::default();
    let args = ["--port", served.path.as_str(), "--sample", "G", "--out", dir.to_str().unwrap()];
    let outcome = run(&args, &mut person, interrupted).expect("no failure but the interruption");
    watcher.join().unwrap();
    let Measured::Stopped { error, .. } = outcome else { panic!("the session went on after Ctrl-C") };
    assert!(matches!(error, SessionError::Interrupted), "{error}");
    let instrument = served.stop();
    assert!(!instrument.hardware().mechanics().lamp_on(), "lamp left on");
    assert!(instrument.is_idle(), "arms still moving");
    let kept = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    let taken = kept.lines().count();
    assert!((6..12).contains(&taken), "{taken} readings kept");
    // And the session can be finished later, measuring only what is missing.
    let resumed = completed(&Served::new("G", 5, ""), "G", &dir, &["--resume", dir.to_str().unwrap()]);
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
    let args = ["--port", served.path.as_str(), "--sample", "G", "--out", dir.to_str().unwrap()];
    let outcome = run(&args, &mut Person::default(), interrupted).expect("no failure but the interruption");
    watcher.join().unwrap();
    let Measured::Stopped { error, .. } = outcome else { panic!("the session went on after Ctrl-C") };
    assert!(matches!(error, SessionError::Interrupted), "{error}");
    // Ask the instrument, as any host would.
    let mut client = host::instrument::link::Client::new(host::instrument::serial::SerialTransport::open(&served.path).unwrap(), host::instrument::link::RetryPolicy::default());
    client.hello().unwrap();
    let Ok(protocol::Reply::Status(status)) = client.request(protocol::Command::GetStatus) else { panic!("no status") };
    assert!(!(status.homed_i && status.homed_r), "homing ran to its end: the Ctrl-C was not heard during it");
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
    calibration["taken_unix_s"] = Value::from(calibration["taken_unix_s"].as_u64().unwrap() - 9 * 3600);
    std::fs::write(&path, calibration.to_string()).unwrap();
    let served = Served::new("MC", 2, "");
    let out = temp_dir("stale2");
    let args = ["--port", served.path.as_str(), "--calibration", path.to_str().unwrap(), "--out", out.to_str().unwrap()];
    let error = match run(&args, &mut Person::default(), Arc::new(AtomicBool::new(false))) {
        Err(error) => format!("{error:#}"),
        Ok(_) => panic!("a 9 h old calibration was used"),
    };
    assert!(error.contains("9.0 h old") && error.contains("limit is 8.0 h"), "{error}");
    assert!(!out.join("points.jsonl").exists(), "nothing measured with a refused calibration");
    // A fresh enough one is used as is: no white tile.
    let mut person = Person::default();
    let out = temp_dir("stale3");
    let args = ["--port", served.path.as_str(), "--calibration", dir.to_str().unwrap(), "--max-calibration-age-h", "24", "--out", out.to_str().unwrap()];
    let Measured::Done { summary, .. } = run(&args, &mut person, Arc::new(AtomicBool::new(false))).unwrap() else { panic!("stopped") };
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
    let path = nix::unistd::ttyname(&pty.slave).unwrap().to_string_lossy().into_owned();
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
            let Ok(n) = nix::unistd::read(&pty.master, &mut buf) else { continue };
            let mut requests = Vec::new();
            decoder.feed(&buf[..n], |r: Result<Request, FrameError>| requests.push(r));
            for request in requests.into_iter().flatten() {
                let error = DeviceError::with_detail(ErrorCode::VersionMismatch, i32::from(version));
                let reply = DeviceMessage::Reply { seq: request.seq, result: Err(error) };
                let mut frame = [0u8; MAX_FRAME_LEN];
                let _ = nix::unistd::write(&pty.master, encode_frame(&reply, &mut frame).unwrap());
            }
        }
    });
    (path, stop, thread)
}

#[test]
fn an_instrument_of_another_protocol_version_is_refused_saying_which_side_to_update() {
    for (version, advice) in [(protocol::PROTOCOL_VERSION + 1, "update the host software"), (protocol::PROTOCOL_VERSION - 1, "update the instrument's firmware")] {
        let (path, stop, thread) = serve_device_of_version(version);
        let dir = temp_dir(&format!("version-{version}"));
        let result = run(&["--port", path.as_str(), "--out", dir.to_str().unwrap()], &mut Person::default(), Arc::new(AtomicBool::new(false)));
        stop.store(true, Ordering::Relaxed);
        thread.join().unwrap();
        let error = match result {
            Err(error) => format!("{error:#}"),
            Ok(_) => panic!("a device of version {version} was accepted"),
        };
        assert!(error.contains("protocol version mismatch") && error.contains(advice), "{error}");
        assert!(!dir.exists(), "no session folder for a refused instrument");
    }
}
