//! `gonio characterize` on simulated instruments that are not the one they declare
//! (`--physics drawn`: a top-hat, Gaussian or trapezoid response of 0.3–3° FWHM, an arm
//! zero within ±0.5°, noise half to twice the reference's): the response width and the arm
//! zero it measures against the drawn truth, which the procedure is never told.
use host::instrument::link::{Client, RetryPolicy};
use host::instrument::profile::{BlackGlass, Standards, WhiteTile};
use host::instrument::sim::{Physics, SimOptions};
use host::session::characterize::{self, Characterization, Options};
use host::session::operator::SimulatedOperator;

pub(crate) fn options() -> Options {
    Options {
        standards: Standards {
            black_glass: BlackGlass {
                id: "BG-1".into(),
                refractive_index: 1.567,
                certified_gu: vec![(20.0, 100.0), (60.0, 100.0)],
            },
            white_tile: WhiteTile {
                id: "W-1".into(),
                radiance_factor: 0.99,
            },
        },
        rehomes: 2,
        lamp_s: 5.0,
    }
}

/// The characterization of the drawn instrument of `seed`.
pub(crate) fn characterize_drawn(seed: u64) -> (SimOptions, Characterization) {
    let sim = SimOptions {
        seed,
        physics: Physics::Drawn,
        ..SimOptions::default()
    };
    let instrument = sim.instrument("black-glass").expect("the black glass");
    let mut client = Client::new(instrument, RetryPolicy::default());
    let info = client.hello().expect("handshake");
    let result = characterize::run(&mut client, &info, &mut SimulatedOperator, &options())
        .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
    (sim, result)
}

#[test]
fn the_response_width_and_arm_zero_are_recovered_on_drawn_instruments() {
    let mut worst = (0.0f64, 0.0f64);
    for seed in 1..=10 {
        let (sim, result) = characterize_drawn(seed);
        let truth = sim.instrument_truth().unwrap();
        let p = &result.profile;
        let fwhm_error = p.response.fwhm_deg.value / truth.response.fwhm_deg() - 1.0;
        let equivalent_truth = (12.0 * truth.response.variance_deg2()).sqrt();
        let width_error = p.response.equivalent_width_deg.value / equivalent_truth - 1.0;
        eprintln!(
            "seed {seed}: {:?} fwhm {:.4} (truth {:.4}, {:+.2} %), equivalent {:+.2} %, zero {:?} truth {:.4}, {} s",
            truth.response,
            p.response.fwhm_deg.value,
            truth.response.fwhm_deg(),
            100.0 * fwhm_error,
            100.0 * width_error,
            p.incidences
                .iter()
                .map(|i| i.arm_zero_deg.value)
                .collect::<Vec<_>>(),
            truth.arm_zero_deg,
            p.device_seconds
        );
        assert!(
            fwhm_error.abs() < 0.05,
            "seed {seed}: FWHM off by {fwhm_error}"
        );
        for i in &p.incidences {
            let e = i.arm_zero_deg.value - truth.arm_zero_deg;
            worst.1 = worst.1.max(e.abs());
            assert!(
                e.abs() < 0.02,
                "seed {seed}, θi {}: zero off by {e}°",
                i.theta_i_deg
            );
        }
        // Each gain ratio measured against the drawn one (nominal 0.1 × (1 + error), drawn
        // with a 1 % sd): within 2 %. The ratios come out 0.1–1.3 % off, more than their
        // stated scatter (0.03–0.26 %): a systematic error not yet found (the darks taken
        // just after a range switch are part of it), so the profile's ratios are a record
        // only, and sessions calibrate their own.
        for g in &p.gain_ratios {
            let truth_ratio = g.nominal * (1.0 + truth.gain_ratio_errors[usize::from(g.range)]);
            let e = g.ratio.value / truth_ratio - 1.0;
            assert!(
                e.abs() < 0.02,
                "seed {seed}: gain ratio {}/{} off by {:.3} % (± {:.3} %)",
                g.range,
                g.range + 1,
                100.0 * e,
                100.0 * g.ratio.u / truth_ratio
            );
        }
        assert!(
            !p.gain_ratios.is_empty(),
            "seed {seed}: no gain ratio measured"
        );
        worst.0 = worst.0.max(fwhm_error.abs());
        assert!(
            p.device_seconds < 120.0,
            "seed {seed}: {} s",
            p.device_seconds
        );
    }
    eprintln!(
        "worst FWHM error {:.2} %, worst zero error {:.4}°",
        100.0 * worst.0,
        worst.1
    );
}

/// The confidently wrong session: a G sheet (σ 1.25°) on a detector of 3° full
/// width, which the host takes for the declared 1°. Without a profile the class must not
/// stand unflagged; with the instrument's own profile it is G and σ's interval covers the
/// truth. `gonio characterize` and `gonio measure --instrument` as a user runs them.
#[test]
fn a_wide_detector_is_flagged_without_a_profile_and_measured_right_with_one() {
    use crate::cli_support::{gonio, stderr, temp_dir};
    let dir = temp_dir("characterize", "wide-detector");
    std::fs::create_dir_all(&dir).unwrap();
    let profile = dir.join("instrument.json");
    let out = gonio(&[
        "characterize",
        "--sim",
        "--acceptance",
        "3",
        "--seed",
        "2",
        "--rehomes",
        "1",
        "--lamp-s",
        "5",
        "--out",
        profile.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(dir.join("instrument.html").is_file());
    let (found, _) = host::instrument::profile::read(&profile).expect("a valid profile");
    assert!(
        (found.response.fwhm_deg.value - 3.0).abs() < 0.05,
        "{:?}",
        found.response
    );
    let sheet = "custom:1.25,57.8,0.855,1.19";
    let measure = |name: &str, extra: &[&str]| -> serde_json::Value {
        let folder = dir.join(name);
        let mut args = vec![
            "measure",
            "--sim",
            sheet,
            "--acceptance",
            "3",
            "--policy",
            "sweep",
            "--spots",
            "1",
            "--seed",
            "2",
            "--json",
            "--out",
            folder.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let out = gonio(&args);
        serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {}", stderr(&out)))
    };
    let declared = measure("declared", &[]);
    let flags: Vec<&str> = declared["flags"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|f| f.as_str())
        .collect();
    assert!(flags.contains(&"instrument-declared"), "{flags:?}");
    let wrong = declared["class"] != "G";
    assert!(
        !wrong || flags.contains(&"instrument-sensitive"),
        "a wrong class without a flag: {declared}"
    );
    let bound = &declared["instrument_bound"]["sigma_deg"];
    assert!(
        bound[0].as_f64().unwrap() <= 1.25 && bound[1].as_f64().unwrap() >= 1.25,
        "the bound does not hold the truth: {bound}"
    );
    let measured = measure("measured", &["--instrument", profile.to_str().unwrap()]);
    assert_eq!(measured["class"], "G", "{measured}");
    assert_eq!(measured["ok"], true, "{measured}");
    let ci = &measured["ci95"]["sigma_deg"];
    assert!(
        ci[0].as_f64().unwrap() <= 1.25 && ci[1].as_f64().unwrap() >= 1.25,
        "σ's interval {ci} misses 1.25"
    );
    assert!(
        measured["analysis_settings"]["instrument_profile"]["sha256"]
            .as_str()
            .is_some_and(|s| s.len() == 64)
    );
    assert!(measured["gloss"].as_array().is_some_and(|g| g.len() >= 2));
    // Another instrument's profile is refused, naming both serials.
    let mut other = found.clone();
    other.serial_number = "OTHER-7".into();
    let other_path = dir.join("other.json");
    std::fs::write(&other_path, serde_json::to_vec(&other).unwrap()).unwrap();
    let out = gonio(&[
        "measure",
        "--sim",
        "G",
        "--spots",
        "1",
        "--out",
        dir.join("x").to_str().unwrap(),
        "--instrument",
        other_path.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("OTHER-7"), "{}", stderr(&out));
}

/// A profile that is not one is refused with the file and what is wrong; a valid one
/// round-trips through its JSON Schema's keys.
#[test]
fn a_damaged_profile_is_refused_with_the_figure_named() {
    let (_, result) = characterize_drawn(21);
    let path = std::path::Path::new("instrument.json");
    let good = serde_json::to_value(&result.profile).unwrap();
    let bytes = serde_json::to_vec(&good).unwrap();
    host::instrument::profile::InstrumentProfile::from_bytes(&bytes, path).expect("valid");
    let cases: Vec<(&str, serde_json::Value, &str)> = vec![
        ("/arm_zero_u_deg", serde_json::json!(-1.0), "arm_zero_u_deg"),
        (
            "/response/fwhm_deg/value",
            serde_json::json!(0.0),
            "response.fwhm_deg",
        ),
        ("/response/shares", serde_json::json!([]), "response"),
        ("/incidences", serde_json::json!([]), "incidences"),
        (
            "/schema",
            serde_json::json!("gonio-instrument/9"),
            "update gonio",
        ),
        (
            "/measured_at",
            serde_json::json!("yesterday"),
            "measured_at",
        ),
    ];
    for (pointer, value, expected) in cases {
        let mut doc = good.clone();
        *doc.pointer_mut(pointer).unwrap() = value;
        let err = host::instrument::profile::InstrumentProfile::from_bytes(
            &serde_json::to_vec(&doc).unwrap(),
            path,
        )
        .expect_err(pointer)
        .to_string();
        assert!(
            err.contains(expected) && err.contains("instrument.json"),
            "{pointer}: {err}"
        );
    }
}

/// The characterization report in a headless browser: the page parses whole, its tables
/// name the figures, and the response and lamp plots are in the DOM as SVG.
#[test]
fn the_characterization_report_renders_in_a_headless_browser() {
    let Some(chromium) = crate::common::chromium_or_skip() else {
        return;
    };
    let (_, result) = characterize_drawn(7);
    let dir = crate::cli_support::temp_dir("characterize", "browser");
    std::fs::create_dir_all(&dir).unwrap();
    let (json, page) = (dir.join("instrument.json"), dir.join("instrument.html"));
    host::output::characterization::write(&result, &json, &page).expect("written");
    let out = host::output::chromium::headless(&chromium, &page, &["--dump-dom".into()])
        .expect("chromium runs");
    let dom = String::from_utf8_lossy(&out.stdout);
    assert!(
        dom.contains("<title>Characterization of instrument SIM-0001</title>")
            && dom.contains("Angular response (black glass)")
            && dom.contains("homing repeatability"),
        "the page rendered: {}",
        crate::cli_support::stderr(&out)
    );
    assert!(
        dom.matches("<svg").count() >= 2 && (dom.contains("<polyline") || dom.contains("<path")),
        "the plots are in the DOM"
    );
    // One row per incidence swept.
    assert!(dom.matches("<td class=\"num\">").count() >= 5 * 4);
}

/// The second case: G on a point detector (σ 0.8°), fitted through the declared 1°
/// window, gave σ 0.7869 [0.7858, 0.7879], unflagged. Its interval still holds for the
/// declared response only; the bound the result carries holds the truth.
#[test]
fn a_point_detector_s_sigma_lies_within_the_declared_bound() {
    use crate::cli_support::{gonio, stderr, temp_dir};
    let dir = temp_dir("characterize", "point-detector");
    let out = gonio(&[
        "measure",
        "--sim",
        "G",
        "--acceptance",
        "0",
        "--policy",
        "sweep",
        "--spots",
        "1",
        "--seed",
        "11",
        "--json",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let r: serde_json::Value =
        serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {}", stderr(&out)));
    assert_eq!(r["class"], "G", "{r}");
    let bound = &r["instrument_bound"];
    assert_eq!(bound["widths_deg"], serde_json::json!([0.0, 3.0]));
    let sigma = &bound["sigma_deg"];
    assert!(
        sigma[0].as_f64().unwrap() <= 0.8 && sigma[1].as_f64().unwrap() >= 0.8,
        "σ's bound {sigma} misses 0.8"
    );
}
