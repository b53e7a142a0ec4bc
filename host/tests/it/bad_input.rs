//! Bad input through the `gonio` binary: each gets an error that names the value and where
//! it came from, exits non-zero, and loses nothing already measured (a resumed folder is
//! left exactly as it was).
use crate::cli_support;
use crate::measure_args;
use cli_support::gonio;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn temp_dir(name: &str) -> PathBuf {
    cli_support::temp_dir("bad", name)
}

fn contents(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap())
        .map(|e| {
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect()
}

/// Refused: exit code 1 (a file, a folder) or 2 (a value on the command line), never a
/// panic's 101; every needle in the message, no panic text. Which of 1 and 2 each kind of
/// refusal gets is `cli_exit::every_subcommand_exits_with_the_readmes_codes`'s to check.
fn rejected(args: &[&str], needles: &[&str]) -> String {
    let out = gonio(args);
    let message = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        matches!(out.status.code(), Some(1 | 2)),
        "{args:?}: exit {:?}: {message}",
        out.status.code()
    );
    assert!(!message.contains("panicked"), "{args:?}: {message}");
    for needle in needles {
        assert!(
            message.contains(needle),
            "{args:?}: no '{needle}' in: {message}"
        );
    }
    message
}

/// `gonio measure --sim G` with `bad`, into a new folder: refused before any folder is made.
fn measure_rejected(bad: &[&str], needles: &[&str]) {
    let dir = temp_dir("never");
    let mut args = vec![
        "measure",
        "--spots",
        "1",
        "--sim",
        "G",
        "--out",
        dir.to_str().unwrap(),
    ];
    args.extend_from_slice(bad);
    rejected(&args, needles);
    assert!(
        !dir.exists(),
        "{bad:?}: a folder was made for a refused session"
    );
}

/// An interrupted session to resume with bad options (it must be left as it was).
fn interrupted_session(name: &str) -> PathBuf {
    let dir = temp_dir(name);
    let crash = host::output::folder::store::Crash::at(30);
    let args =
        measure_args::parse_args(["--spots", "1", "--sim", "G", "--out", dir.to_str().unwrap()])
            .unwrap();
    let _ = host::measure::measure_with(
        &args,
        &mut host::session::SimulatedOperator,
        std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false)),
        host::output::folder::store::StoreOptions {
            crash: Some(crash),
            ..Default::default()
        },
    );
    assert!(dir.join("points.jsonl").exists());
    dir
}

#[test]
fn a_maximum_calibration_age_that_is_no_number_of_hours_is_refused() {
    for bad in ["inf", "NaN", "-1", "0", "1e300", "9000"] {
        let shown = format!("{:?}", bad.parse::<f64>().unwrap());
        // `=`: clap takes "-1" after a space for an option of its own.
        let option = format!("--max-calibration-age-h={bad}");
        measure_rejected(
            &[&option],
            &[
                "--max-calibration-age-h must be a number of hours above 0 and at most 8760",
                &format!("not {shown}"),
            ],
        );
    }
    // On a resume, nothing measured is touched.
    let dir = interrupted_session("age");
    let before = contents(&dir);
    rejected(
        &[
            "measure",
            "--spots",
            "1",
            "--sim",
            "G",
            "--resume",
            dir.to_str().unwrap(),
            "--max-calibration-age-h",
            "inf",
        ],
        &["--max-calibration-age-h", "not inf"],
    );
    assert!(contents(&dir) == before);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_white_drift_limit_that_is_no_percentage_is_refused() {
    for (bad, shown) in [
        ("nan", "NaN"),
        ("inf", "inf"),
        ("0", "0.0"),
        ("-0.5", "-0.5"),
        ("101", "101.0"),
    ] {
        let option = format!("--white-drift-limit-pct={bad}");
        measure_rejected(
            &["--white-check", &option],
            &[
                "--white-drift-limit-pct must be a percentage above 0 and at most 100",
                &format!("not {shown}"),
            ],
        );
    }
}

#[test]
fn an_integration_time_outside_the_instruments_limits_is_refused_before_anything_moves() {
    for bad in ["0", "1", "60000"] {
        measure_rejected(
            &["--integration-ms", bad],
            &[
                &format!(
                    "--integration-ms {bad} ms is outside what the instrument (serial SIM-0001) accepts:"
                ),
                " to ",
                " ms",
            ],
        );
    }
    // The limits are the instrument's, from its handshake.
    let out = gonio(&[
        "measure",
        "--spots",
        "1",
        "--sim",
        "G",
        "--integration-ms",
        "0",
        "--out",
        temp_dir("limits").to_str().unwrap(),
    ]);
    let message = String::from_utf8_lossy(&out.stderr);
    // The simulator's defaults, as the command line gives them.
    let options = measure_args::parse_args(["--spots", "1", "--sim", "G"])
        .unwrap()
        .sim_options;
    let mut client = host::instrument::link::Client::new(
        options.instrument("G").unwrap(),
        host::instrument::link::RetryPolicy::default(),
    );
    let info = client.hello().unwrap();
    assert!(
        message.contains(&format!(
            "accepts: {} to {} ms",
            info.min_integration_ms.max(1),
            info.max_integration_ms
        )),
        "{message}"
    );
    // The instrument's own shortest time is taken.
    let dir = temp_dir("shortest");
    let min = info.min_integration_ms.max(1).to_string();
    let out = gonio(&[
        "measure",
        "--spots",
        "1",
        "--sim",
        "PPC",
        "--integration-ms",
        &min,
        "--json",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_detector_acceptance_beyond_what_the_fit_models_is_refused() {
    measure_rejected(
        &["--acceptance", "1e308"],
        &["--acceptance must be between 0 and 10 degrees"],
    );
    let dir = temp_dir("fit-acceptance");
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("a.csv");
    std::fs::write(
        &csv,
        "theta_i,theta_r,radiance_factor\n20,0,0.8\n20,20,5\n20,25,1\n45,45,6\n45,50,1\n",
    )
    .unwrap();
    for (bad, shown) in [
        ("1e308", "1e308"),
        ("inf", "inf"),
        ("11", "11.0"),
        ("-1", "-1.0"),
    ] {
        let option = format!("--acceptance={bad}");
        rejected(
            &["fit", &option, csv.to_str().unwrap()],
            &[
                "--acceptance must be between 0 and 10 degrees",
                &format!("not {shown}"),
            ],
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn csv_numbers_the_fit_cannot_represent_are_refused_at_their_line_and_a_bom_is_accepted() {
    let dir = temp_dir("csv");
    std::fs::create_dir_all(&dir).unwrap();
    // A real session's readings as the base.
    let session = temp_dir("csv-session");
    cli_support::assert_finished(&gonio(&[
        "measure",
        "--spots",
        "1",
        "--sim",
        "G",
        "--out",
        session.to_str().unwrap(),
    ]));
    let readings = std::fs::read_to_string(session.join("readings.csv")).unwrap();
    let rows: Vec<&str> = readings.lines().collect();
    let with_row = |line: usize, row: String| {
        let mut rows: Vec<String> = rows.iter().map(|r| r.to_string()).collect();
        rows[line - 1] = row;
        rows.join("\n") + "\n"
    };
    let fields = |line: usize| {
        rows[line - 1]
            .split(',')
            .map(str::to_string)
            .collect::<Vec<_>>()
    };
    let f = fields(5);
    let cases = [
        (
            "radiance-1e308",
            with_row(5, format!("{},{},1e308,{}", f[0], f[1], f[3])),
            "radiance_factor 1e308 is beyond ±1e6, what the fit can represent",
        ),
        (
            "std-1e-300",
            with_row(5, format!("{},{},{},1e-300", f[0], f[1], f[2])),
            "std 1e-300 is outside 1e-9 … 1e6, what the fit can weigh",
        ),
        (
            "radiance-nan",
            with_row(5, format!("{},{},NaN,{}", f[0], f[1], f[3])),
            "radiance_factor NaN is not a finite number",
        ),
        (
            "std-far-apart",
            with_row(5, format!("{},{},{},1e-8", f[0], f[1], f[2])),
            "times the std 1e-8 of line 5 (sample 'std-far-apart'): weights that far apart cannot be fitted together",
        ),
    ];
    for (name, text, needle) in cases {
        let path = dir.join(format!("{name}.csv"));
        std::fs::write(&path, text).unwrap();
        // The far-apart uncertainties are named at the largest one's line, with line 5's.
        let location = if name == "std-far-apart" {
            format!("{}:", path.display())
        } else {
            format!("{}:5:", path.display())
        };
        rejected(&["fit", path.to_str().unwrap()], &[&location, needle]);
    }
    // A UTF-8 byte-order mark, as spreadsheets write it: read as if absent.
    let plain = dir.join("plain.csv");
    std::fs::write(&plain, &readings).unwrap();
    let bom = dir.join("bom.csv");
    std::fs::write(&bom, format!("\u{feff}{readings}")).unwrap();
    let (a, b) = (
        gonio(&["fit", "--json", plain.to_str().unwrap()]),
        gonio(&["fit", "--json", bom.to_str().unwrap()]),
    );
    // Read alike: the same exit (0, or 3 when the bare CSV's fit is flagged — readings.csv
    // carries each reading's own noise, not the calibration's shared errors).
    assert!(
        matches!(b.status.code(), Some(0 | 3)),
        "{}",
        String::from_utf8_lossy(&b.stderr)
    );
    assert_eq!(a.status.code(), b.status.code());
    let (a, b): (serde_json::Value, serde_json::Value) = (
        serde_json::from_slice(&a.stdout).unwrap(),
        serde_json::from_slice(&b.stdout).unwrap(),
    );
    assert_eq!(a["sigma_deg"], b["sigma_deg"]);
    assert_eq!(b["class"], "G");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&session);
}

#[test]
fn a_port_that_is_no_serial_port_is_refused_saying_what_it_is() {
    let dir = temp_dir("port");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("not-a-port");
    std::fs::write(&file, "").unwrap();
    let out = dir.join("never");
    let args = |port: &str| {
        vec![
            "measure".to_string(),
            "--port".into(),
            port.into(),
            "--out".into(),
            out.to_str().unwrap().into(),
        ]
    };
    let run = |port: &str, needles: &[&str]| {
        let a = args(port);
        rejected(&a.iter().map(String::as_str).collect::<Vec<_>>(), needles);
        assert!(!out.exists());
    };
    run(
        file.to_str().unwrap(),
        &[&format!(
            "--port {} is not a serial port (it is a regular file)",
            file.display()
        )],
    );
    run(
        dir.to_str().unwrap(),
        &["is not a serial port (it is a folder)"],
    );
    run(
        dir.join("none").to_str().unwrap(),
        &["no such port", "gonio ports"],
    );
    run(
        "/dev/null",
        &["--port /dev/null is not a serial port (a device, but not a terminal)"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_options_on_a_resume_leave_the_folder_as_it_was() {
    let dir = temp_dir("resume-bad");
    let dir = {
        let _ = std::fs::remove_dir_all(&dir);
        interrupted_session("resume-bad")
    };
    let d = dir.to_str().unwrap();
    let before = contents(&dir);
    for (bad, needle) in [
        (
            vec!["--white-drift-limit-pct", "nan"],
            "--white-drift-limit-pct must be a percentage",
        ),
        (
            vec!["--integration-ms", "1"],
            "--integration-ms 1 ms is outside",
        ),
        (vec!["--sample", ""], "--sample must be a name"),
    ] {
        let mut args = vec!["measure", "--spots", "1", "--sim", "G", "--resume", d];
        args.extend_from_slice(&bad);
        rejected(&args, &[needle]);
        assert!(contents(&dir) == before, "{bad:?} changed the folder");
    }
    // And with good ones it finishes, every reading kept.
    let out = gonio(&["measure", "--spots", "1", "--sim", "G", "--resume", d]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let points = String::from_utf8(before["points.jsonl"].clone()).unwrap();
    let whole = &points[..points.rfind('\n').map_or(0, |i| i + 1)];
    assert!(
        std::fs::read_to_string(dir.join("points.jsonl"))
            .unwrap()
            .starts_with(whole)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_bad_or_expired_tile_certificate_is_refused_before_anything_is_measured() {
    let dir = temp_dir("certificates");
    std::fs::create_dir_all(&dir).unwrap();
    let write = |name: &str, text: &str| {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path.display().to_string()
    };
    let expired = write(
        "expired.json",
        r#"{"tile": "T", "certificate": "C", "issued": "2020-01-01", "valid_until": "2021-01-01", "radiance_factor": 0.98, "expanded_uncertainty": 0.01}"#,
    );
    measure_rejected(
        &["--tile-certificate", &expired],
        &[
            "--tile-certificate",
            "expired.json",
            "expired on 2021-01-01",
        ],
    );
    // Implausible dates (issue 30): issued in 1900, or valid until before its issue.
    let ancient = write(
        "ancient.json",
        r#"{"tile": "T", "certificate": "C", "issued": "1900-01-01", "radiance_factor": 0.98, "expanded_uncertainty": 0.01}"#,
    );
    measure_rejected(
        &["--tile-certificate", &ancient],
        &["ancient.json", "issued 1900-01-01, before 2000-01-01"],
    );
    let backwards = write(
        "backwards.json",
        r#"{"tile": "T", "certificate": "C", "issued": "2026-01-01", "valid_until": "2025-06-01", "radiance_factor": 0.98, "expanded_uncertainty": 0.01}"#,
    );
    measure_rejected(
        &["--tile-certificate", &backwards],
        &[
            "backwards.json",
            "valid until 2025-06-01, before it was issued (2026-01-01)",
        ],
    );
    let broken = write("broken.json", r#"{"tile": "T", "certificate": "C", "#);
    measure_rejected(&["--tile-certificate", &broken], &["broken.json", "line 1"]);
    let missing = dir.join("missing.json").display().to_string();
    measure_rejected(
        &["--tile-certificate", &missing],
        &["missing.json", "cannot read"],
    );
    // Values and a certificate at once: which to believe is not guessed.
    let out = gonio(&[
        "measure",
        "--sim",
        "G",
        "--tile-certificate",
        &expired,
        "--tile-radiance-factor",
        "0.9",
    ]);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot be used with"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_trade_study_policy_that_is_not_one_is_refused_naming_the_known_ones() {
    let out = temp_dir("trade-policies");
    rejected(
        &[
            "trade",
            "--quick",
            "--policies",
            "sweep,sweeps",
            "--out",
            out.to_str().unwrap(),
        ],
        &[
            "--policies",
            "'sweeps'",
            "strategy1, strategy2, paper, adaptive, sweep",
        ],
    );
    assert!(!out.join("trade.csv").exists(), "nothing run");
}

#[test]
fn a_symbolic_link_inside_a_session_folder_is_never_written_through() {
    // Issue 30: a session.log linked to a file elsewhere was appended to by the resume.
    let dir = interrupted_session("symlink");
    let outside = temp_dir("symlink-outside");
    std::fs::create_dir_all(&outside).unwrap();
    let target = outside.join("elsewhere.log");
    std::fs::write(&target, "not gonio's\n").unwrap();
    let log = dir.join("session.log");
    let _ = std::fs::remove_file(&log);
    std::os::unix::fs::symlink(&target, &log).unwrap();
    let d = dir.to_str().unwrap();
    rejected(
        &["measure", "--spots", "1", "--sim", "G", "--resume", d],
        &["session.log", "symbolic link", "nothing was changed"],
    );
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "not gonio's\n");
    // The writer itself opens no link: the report's temporary file linked outside.
    std::fs::remove_file(&log).unwrap();
    let out = gonio(&["measure", "--spots", "1", "--sim", "G", "--resume", d]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let temp = dir.join(".report.html.gonio-tmp");
    std::os::unix::fs::symlink(&target, &temp).unwrap();
    let out = gonio(&["report", "--unverified", d]);
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{message}");
    assert!(message.contains("symbolic link"), "{message}");
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "not gonio's\n");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&outside);
}

#[test]
fn a_folder_another_gonio_is_making_is_in_use_and_left_alone() {
    // Issue 30: of two `gonio measure --out same` started together, one removed the other's
    // first sheet.json (its temporary file) before finding the folder locked: that one
    // failed with "cannot write … No such file or directory". The lock comes first now.
    for (spots, first) in [
        ("3", ".sheet.json.gonio-tmp"),
        ("1", ".session.json.gonio-tmp"),
    ] {
        let dir = temp_dir(&format!("in-use-{spots}"));
        std::fs::create_dir_all(&dir).unwrap();
        // The other gonio made the folder a moment ago, holds it, writes its first file.
        let lock = host::output::folder::lock::FolderLock::take(&dir).unwrap();
        std::fs::write(dir.join(first), "{").unwrap();
        rejected(
            &[
                "measure",
                "--spots",
                spots,
                "--sim",
                "G",
                "--out",
                dir.to_str().unwrap(),
            ],
            &["is in use by another gonio process"],
        );
        assert!(
            dir.join(first).exists(),
            "--spots {spots}: the other gonio's temporary file was removed"
        );
        drop(lock);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
