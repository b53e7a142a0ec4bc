//! The sheet's answer (`gonio measure --spots N`): the class and confidence of the sheet
//! from its accepted spots, with the spot-to-spot variation in the uncertainty, and the
//! mean's 95 % intervals — on simulated sheets of several papers and seeds whose spots vary
//! about the stock (the simulator's truth), with a flagged spot left out and counted, and a
//! sheet written before the answer was recorded (`gonio-sheet/2`) still read and verified.
use crate::common::in_process::{measure, ram_dir};
use host::analysis::classify::REFERENCES;
use host::measure::Measured;
use host::output::folder::sheet::{ReadSheet, read_measured};
use host::output::folder::verify::verify_sheet;
use serde_json::Value;
use std::path::Path;

fn sheet(list: &[&str], what: &str) -> Box<ReadSheet> {
    match measure(list, None) {
        Ok(Measured::Sheet { sheet, .. }) => sheet,
        Ok(_) => panic!("{what}: not a sheet"),
        Err(e) => panic!("{what}: {e:#}"),
    }
}

#[test]
fn a_sheets_answer_is_its_papers_class_and_its_intervals_cover_the_stock() {
    let papers = ["G", "SG", "PPC", "MC", "J2"];
    let seeds = [11u64, 29];
    let (mut checked, mut covered) = (0, 0);
    let mut misses = Vec::new();
    for paper in papers {
        for seed in seeds {
            let out = ram_dir("sheet-answer", &format!("{paper}-{seed}"));
            let seed_text = seed.to_string();
            let what = format!("{paper} seed {seed}");
            let read = sheet(
                &[
                    "--sim",
                    paper,
                    "--spots",
                    "3",
                    "--sheet-variation",
                    "3",
                    "--seed",
                    &seed_text,
                    "--out",
                    out.to_str().unwrap(),
                ],
                &what,
            );
            let answer = read.summary.answer.clone().expect("an answer");
            let want = REFERENCES.iter().find(|r| r.name == paper).unwrap();
            assert_eq!(
                answer.class.as_deref(),
                Some(want.class.name()),
                "{what}: {answer:?}"
            );
            let confidence = answer.class_confidence.expect("a confidence");
            assert!(
                confidence > 0.5 && confidence <= 1.0,
                "{what}: {confidence}"
            );
            assert_eq!(answer.excluded, 0, "{what}");
            let truth = host::instrument::sim::sample_params(paper).unwrap();
            for (name, interval, value) in [
                ("σ", answer.ci95.sigma_deg, truth.sigma_deg),
                ("ρs", answer.ci95.rho_s, truth.rho_s),
                ("ρd", answer.ci95.rho_d, truth.rho_d),
            ] {
                let [lo, hi] = interval.unwrap_or_else(|| panic!("{what}: no {name} interval"));
                checked += 1;
                if lo <= value && value <= hi {
                    covered += 1;
                } else {
                    misses.push(format!("{what} {name}: {value} not in [{lo}, {hi}]"));
                }
            }
            // The mean lies inside its own interval, and the file names its fields.
            let mean = read.summary.mean;
            let [lo, hi] = answer.ci95.sigma_deg.unwrap();
            assert!(lo < mean[0].unwrap() && mean[0].unwrap() < hi, "{what}");
            let doc: Value =
                serde_json::from_str(&std::fs::read_to_string(out.join("sheet.json")).unwrap())
                    .unwrap();
            assert_eq!(doc["schema"], "gonio-sheet/3");
            assert_eq!(
                doc["result"]["mean"]["sigma_deg"].as_f64(),
                mean[0],
                "{what}"
            );
            assert_eq!(
                doc["result"]["answer"]["class"],
                want.class.name(),
                "{what}"
            );
            verify_sheet(&out, host::output::report::draw)
                .unwrap_or_else(|p| panic!("{what}: {p:?}"));
            let report = std::fs::read_to_string(out.join("report.html")).unwrap();
            assert!(
                report.contains("The sheet's class: ")
                    && report.contains("95 % interval of the sheet's mean"),
                "{what}: the report shows the answer"
            );
            let _ = std::fs::remove_dir_all(&out);
        }
    }
    // 95 % intervals: with 30 of them, more than 4 misses is below 1 % likely.
    assert!(
        covered + 4 >= checked,
        "{covered} of {checked} intervals cover the truth: {misses:?}"
    );
}

#[test]
fn a_flagged_spot_is_left_out_of_the_answer_and_counted() {
    // The detector loses steps once, during spot 1: it is flagged, two more are measured.
    for seed in [2u64, 7] {
        let out = ram_dir("sheet-answer", &format!("flagged-{seed}"));
        let seed_text = seed.to_string();
        let read = sheet(
            &[
                "--sim",
                "PPC",
                "--spots",
                "2",
                "--sheet-variation",
                "3",
                "--faults",
                "lose-steps=detector:40",
                "--seed",
                &seed_text,
                "--out",
                out.to_str().unwrap(),
            ],
            &format!("seed {seed}"),
        );
        let answer = read.summary.answer.clone().expect("an answer");
        assert_eq!(read.spots.len(), 3, "seed {seed}");
        assert_eq!(answer.excluded, 1, "seed {seed}: {answer:?}");
        assert_eq!(answer.class.as_deref(), Some("rough-II"), "seed {seed}");
        assert!(
            answer.flags.iter().all(|f| f.name() != "lost-steps"),
            "seed {seed}: the excluded spot's flag is not the answer's: {:?}",
            answer.flags
        );
        // The mean is the accepted spots' alone.
        let accepted: Vec<f64> = read.spots[1..]
            .iter()
            .map(|s| s.session.values[0].unwrap())
            .collect();
        let geometric = (accepted[0] * accepted[1]).sqrt();
        assert!(
            (read.summary.mean[0].unwrap() - geometric).abs() < 1e-9 * geometric,
            "seed {seed}"
        );
        let _ = std::fs::remove_dir_all(&out);
    }
}

/// Rewrite `dir/sheet.json` with `edit` and its manifest line to match (a folder as an
/// older gonio wrote it).
fn rewrite_sheet(dir: &Path, edit: impl FnOnce(&mut Value)) {
    let path = dir.join("sheet.json");
    let mut doc: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut doc);
    let bytes = serde_json::to_vec_pretty(&doc).unwrap();
    std::fs::write(&path, &bytes).unwrap();
    let manifest = std::fs::read_to_string(dir.join("MANIFEST.sha256")).unwrap();
    let fixed: String = manifest
        .lines()
        .map(|line| {
            if line.ends_with("  sheet.json") {
                format!(
                    "{}  sheet.json\n",
                    host::output::folder::manifest::sha256_hex(&bytes)
                )
            } else {
                format!("{line}\n")
            }
        })
        .collect();
    std::fs::write(dir.join("MANIFEST.sha256"), fixed).unwrap();
    // Its report was drawn by that gonio: verify checks a report only against the gonio
    // that drew it (`gonio report` draws it again).
    let _ = std::fs::remove_file(dir.join("report.html"));
}

#[test]
fn a_sheet_written_before_the_answer_is_read_verified_and_answered() {
    let out = ram_dir("sheet-answer", "v2");
    let _ = sheet(
        &[
            "--sim",
            "SG",
            "--spots",
            "2",
            "--sheet-variation",
            "3",
            "--seed",
            "5",
            "--out",
            out.to_str().unwrap(),
        ],
        "SG",
    );
    // As gonio-sheet/2 wrote it: the mean and the spread as arrays, no answer.
    rewrite_sheet(&out, |doc| {
        doc["schema"] = "gonio-sheet/2".into();
        let result = doc["result"].as_object_mut().unwrap();
        result.remove("answer");
        for key in ["mean", "within_relative_sd"] {
            let named = result[key].clone();
            result.insert(
                key.into(),
                serde_json::json!([named["sigma_deg"], named["rho_s"], named["rho_d"]]),
            );
        }
    });
    let verified = verify_sheet(&out, host::output::report::draw)
        .unwrap_or_else(|p| panic!("a gonio-sheet/2 folder verifies: {p:?}"));
    assert_eq!(
        verified
            .sheet
            .summary
            .answer
            .as_ref()
            .and_then(|a| a.class.as_deref()),
        Some("SG"),
        "its answer is computed from its spots"
    );
    let measured = read_measured(&out).expect("compare and the library read it");
    assert_eq!(measured.sheet.spots.len(), 2);
    // A newer version is refused, naming it.
    rewrite_sheet(&out, |doc| doc["schema"] = "gonio-sheet/4".into());
    let message = read_measured(&out).unwrap_err().to_string();
    assert!(message.contains("gonio-sheet/4"), "{message}");
    let _ = std::fs::remove_dir_all(&out);
}
