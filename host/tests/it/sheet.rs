//! A sheet measured at several spots (`gonio measure --spots N`): the operator is asked to
//! move the sheet between spots and may take minutes, the spots share the first one's
//! calibration, a flagged spot is replaced and excluded with the reason, a kill at any
//! write of the sheet's folder resumes to a folder that verifies, and the sheet is what
//! `gonio compare`, `gonio verify` and the library read.
use crate::common::in_process::measure_as as run;
use crate::measure_args;
use host::measure::{Measured, measure_with};
use host::output::folder::sheet::read_measured;
use host::output::folder::store::{Crash, StoreOptions};
use host::output::folder::verify::verify_sheet;
use host::output::report::draw;
use host::session::{DelayedOperator, Placement, SimulatedOperator};
use measure_args::parse_args;
use rand::{Rng, SeedableRng};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

fn dir(name: &str) -> PathBuf {
    crate::common::in_process::ram_dir("sheet", name)
}

fn args(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

fn sheet_of(
    measured: anyhow::Result<Measured>,
    what: &str,
) -> Box<host::output::folder::sheet::ReadSheet> {
    match measured {
        Ok(Measured::Sheet { sheet, .. }) => sheet,
        Ok(Measured::Done { .. }) => panic!("{what}: measured one spot, not a sheet"),
        Ok(Measured::Stopped { error, .. }) => panic!("{what}: stopped: {error}"),
        Err(e) => panic!("{what}: {e:#}"),
    }
}

#[test]
fn the_spots_of_a_sheet_share_the_calibration_and_a_slow_operator_moves_the_sheet_between_them() {
    for seed in [3u64, 17, 40] {
        let out = dir(&format!("three-{seed}"));
        let seed_text = seed.to_string();
        let mut person = DelayedOperator::answering_after(Duration::from_secs(120));
        let a = args(&[
            "--sim",
            "PPC",
            "--spots",
            "3",
            "--sheet-variation",
            "3",
            "--physics",
            "real",
            "--seed",
            &seed_text,
            "--out",
        ]);
        let sheet = sheet_of(
            run(
                &[a, vec![out.display().to_string()]].concat(),
                &mut person,
                None,
            ),
            &format!("seed {seed}"),
        );
        assert_eq!(
            person.asked,
            [
                Placement::WhiteTile,
                Placement::Sample,
                Placement::NextSpot { spot: 2, of: 3 },
                Placement::NextSpot { spot: 3, of: 3 }
            ],
            "seed {seed}: the tile and the sample once, then the sheet moved before each later spot"
        );
        assert_eq!(sheet.spots.len(), 3);
        assert_eq!(
            sheet.summary.accepted, 3,
            "seed {seed}: {:?}",
            sheet.summary.verdicts
        );
        let calibration = |k: usize| {
            std::fs::read(out.join(format!("spot-{k}/calibration.json"))).expect("calibration.json")
        };
        assert_eq!(
            calibration(1),
            calibration(2),
            "seed {seed}: one calibration for the sheet"
        );
        assert_eq!(calibration(1), calibration(3));
        // Each spot is another area of the sheet (3 % between spots): no two alike.
        let sigma: Vec<f64> = sheet
            .spots
            .iter()
            .map(|s| s.session.values[0].expect("σ"))
            .collect();
        assert!(
            sigma[0] != sigma[1] && sigma[1] != sigma[2],
            "seed {seed}: {sigma:?}"
        );
        let sd = sheet
            .summary
            .within_relative_sd
            .expect("three spots show their variation");
        assert!(
            sd.iter().all(|v| *v > 0.001 && *v < 0.15),
            "seed {seed}: spot-to-spot sd {sd:?}"
        );
        // Two minutes at each of four prompts are not the sheet's measuring or setup time.
        let result = sheet.doc.result.as_ref().expect("result");
        assert!(
            result.setup_seconds < 60.0 && result.device_seconds < 120.0,
            "seed {seed}: {result:?}"
        );
        let verified = verify_sheet(&out, draw).unwrap_or_else(|p| panic!("seed {seed}: {p:?}"));
        assert_eq!(verified.spots.len(), 3);
        let measured = read_measured(&out).expect("compare reads the sheet");
        assert_eq!(measured.sheet.spots.len(), 3);
        let _ = std::fs::remove_dir_all(&out);
    }
}

#[test]
fn a_flagged_spot_is_replaced_and_excluded_with_the_reason() {
    // The detector loses 40 steps once, during the first spot: that spot is flagged
    // lost-steps, a third spot is measured in its place.
    for seed in [1u64, 9] {
        let out = dir(&format!("flagged-{seed}"));
        let seed_text = seed.to_string();
        let a = args(&[
            "--sim",
            "PPC",
            "--spots",
            "2",
            "--faults",
            "lose-steps=detector:40",
            "--seed",
            &seed_text,
            "--out",
        ]);
        let sheet = sheet_of(
            run(
                &[a, vec![out.display().to_string()]].concat(),
                &mut SimulatedOperator,
                None,
            ),
            "lost steps",
        );
        assert_eq!(sheet.spots.len(), 3, "seed {seed}: a replacement measured");
        assert_eq!(sheet.summary.accepted, 2);
        let counts = sheet.counts();
        assert_eq!(
            (
                counts.planned,
                counts.measured,
                counts.accepted,
                counts.flagged
            ),
            (2, 3, 2, 1),
            "seed {seed}"
        );
        let excluded: Vec<_> = sheet
            .summary
            .verdicts
            .iter()
            .filter(|j| j.verdict != host::analysis::spots::SpotVerdict::Accepted)
            .collect();
        assert_eq!(
            excluded.len(),
            1,
            "seed {seed}: {:?}",
            sheet.summary.verdicts
        );
        assert!(
            matches!(&excluded[0].verdict, host::analysis::spots::SpotVerdict::Excluded { reason } if reason.contains("lost-steps"))
        );
        assert!(sheet.summary.ok(), "the sheet rests on its clean spots");
        assert!(
            sheet
                .doc
                .decisions
                .iter()
                .any(|d| d.contains("in place of a flagged spot")),
            "{:?}",
            sheet.doc.decisions
        );
        assert!(verify_sheet(&out, draw).is_ok());
        let _ = std::fs::remove_dir_all(&out);
    }
}

#[test]
fn a_kill_at_any_write_of_a_sheet_resumes_to_a_sheet_that_verifies() {
    // One sheet the same everywhere: the simulator of a resumed (new) process cannot know
    // the sheet stayed where it was, and would put another area of it under the beam (a
    // resumed spot of a varying sheet mixes two areas; its fit's lack-of-fit test is what
    // catches that, and the sheet replaces the spot). Here the folder's mechanics are tested.
    // One seed for every run: the count of writes is the count of this sheet's noise (an
    // adaptive spot takes as many geometries as its readings call for).
    let seed = crate::common::run_seed().to_string();
    let base = args(&["--sim", "SG", "--seed", &seed, "--spots", "2"]);
    let counting = Crash::counting();
    let first = dir("count");
    sheet_of(
        run(
            &[base.clone(), args(&["--out", &first.display().to_string()])].concat(),
            &mut SimulatedOperator,
            Some(counting.clone()),
        ),
        "counting",
    );
    let writes = counting.writes();
    assert!(writes > 40, "{writes} writes");
    let reference = verify_sheet(&first, draw)
        .expect("the uninterrupted sheet verifies")
        .sheet;
    // Every write of the first and last few (the sheet's own documents), evenly over the
    // rest, and random ones of a seed that changes with every run.
    let mut at: Vec<u64> = (1..=6)
        .chain(writes - 5..=writes)
        .chain((1..12).map(|k| k * writes / 12))
        .collect();
    let seed = crate::common::run_seed();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    at.extend((0..6).map(|_| rng.random_range(1..=writes)));
    for n in at {
        let what = format!("killed at write {n} of {writes} (random seed {seed})");
        let out = dir(&format!("crash-{n}"));
        let out_text = out.display().to_string();
        if let Ok(Measured::Sheet { .. }) = run(
            &[base.clone(), args(&["--out", &out_text])].concat(),
            &mut SimulatedOperator,
            Some(Crash::at(n)),
        ) {
            panic!("{what}: the sheet finished through its crash");
        }
        if !out.join("sheet.json").exists() {
            // Killed before the sheet's first document: nothing to resume, the folder is new.
            let sheet = sheet_of(
                run(
                    &[base.clone(), args(&["--out", &out_text])].concat(),
                    &mut SimulatedOperator,
                    None,
                ),
                &what,
            );
            assert_eq!(sheet.summary.accepted, 2, "{what}");
            let _ = std::fs::remove_dir_all(&out);
            continue;
        }
        let resumed = run(
            &args(&["--sim", "SG", "--resume", &out_text]),
            &mut SimulatedOperator,
            None,
        );
        let sheet = match resumed {
            Ok(Measured::Sheet { sheet, .. }) => sheet,
            Err(e) if e.to_string().contains("finished sheet") => Box::new(
                verify_sheet(&out, draw)
                    .unwrap_or_else(|p| panic!("{what}: {p:?}"))
                    .sheet,
            ),
            Ok(Measured::Stopped { error, .. }) => {
                panic!("{what}: the resumed sheet stopped: {error}")
            }
            Ok(Measured::Done { .. }) => panic!("{what}: resumed as one spot"),
            Err(e) => panic!("{what}: {e:#}"),
        };
        assert_eq!(
            sheet.summary.accepted, 2,
            "{what}: {:?}",
            sheet.summary.verdicts
        );
        // A flagged spot is replaced by one more (a resumed spot of two runs may be
        // flagged: the lack-of-fit test sees the two runs' readings, or a false alarm at its
        // rate): every spot beyond the reference's stands in for an excluded one.
        let excluded = |verdicts: &[host::analysis::spots::Judged]| {
            verdicts
                .iter()
                .filter(|j| j.verdict != host::analysis::spots::SpotVerdict::Accepted)
                .count()
        };
        let numbers: std::collections::BTreeSet<_> =
            sheet.summary.verdicts.iter().map(|j| j.number).collect();
        assert_eq!(
            numbers.len(),
            sheet.summary.verdicts.len(),
            "{what}: a spot judged twice"
        );
        assert_eq!(
            sheet.spots.len() - excluded(&sheet.summary.verdicts),
            reference.spots.len() - excluded(&reference.summary.verdicts),
            "{what}: no spot lost or measured twice: {:?} {:?}",
            sheet.summary,
            sheet
                .spots
                .iter()
                .map(|s| &s.result.flags)
                .collect::<Vec<_>>()
        );
        verify_sheet(&out, draw).unwrap_or_else(|p| panic!("{what}: {p:?}"));
        let _ = std::fs::remove_dir_all(&out);
    }
    let _ = std::fs::remove_dir_all(&first);
}

#[test]
fn two_sheets_of_one_stock_support_the_same_stock_and_the_library_keeps_their_spots() {
    let mut lrs = Vec::new();
    for seed in [5u64, 6, 7] {
        let dirs: Vec<PathBuf> = (0..2).map(|k| dir(&format!("pair-{seed}-{k}"))).collect();
        for (k, out) in dirs.iter().enumerate() {
            let seed_text = (100 * seed + k as u64).to_string();
            let a = args(&[
                "--sim",
                "G",
                "--spots",
                "3",
                "--sheet-variation",
                "3",
                "--physics",
                "real",
                "--seed",
                &seed_text,
                "--out",
            ]);
            sheet_of(
                run(
                    &[a, vec![out.display().to_string()]].concat(),
                    &mut SimulatedOperator,
                    None,
                ),
                "G",
            );
        }
        let (a, b) = (
            read_measured(&dirs[0]).unwrap(),
            read_measured(&dirs[1]).unwrap(),
        );
        let e = host::analysis::evidence::weigh(
            &host::analysis::evidence::Questioned::of(a.sheet.clone()),
            &host::analysis::evidence::Questioned::of(b.sheet.clone()),
            &host::analysis::evidence::Population::demonstration(),
        );
        assert_eq!(e.n_spots, (3, 3));
        assert_eq!(e.within_known, (true, true));
        lrs.push(e.ratio.log10_lr);
        let record = host::output::library::read_session_folder(&dirs[0], Some("L1"), false)
            .expect("the library reads a sheet folder");
        assert_eq!(record.spots.len(), 3);
        assert_eq!(record.sample, "G");
        for out in dirs {
            let _ = std::fs::remove_dir_all(out);
        }
    }
    assert!(
        lrs.iter().all(|lr| *lr > 0.0),
        "two sheets of one G stock: log10 LR {lrs:?}"
    );
}

#[test]
fn a_sheet_folder_that_was_changed_does_not_verify_and_bad_spot_options_are_refused() {
    let out = dir("tamper");
    let out_text = out.display().to_string();
    sheet_of(
        run(
            &args(&["--sim", "J1", "--spots", "2", "--out", &out_text]),
            &mut SimulatedOperator,
            None,
        ),
        "J1",
    );
    assert!(verify_sheet(&out, draw).is_ok());
    // A finished sheet is not measured again, with or without --spots.
    let again = run(
        &args(&["--sim", "J1", "--resume", &out_text]),
        &mut SimulatedOperator,
        None,
    )
    .err()
    .expect("refused")
    .to_string();
    assert!(
        again.contains("finished sheet") && again.contains("sheet.json"),
        "{again}"
    );
    // A spot's result changed after the sheet finished.
    let session = out.join("spot-2/session.json");
    let text = std::fs::read_to_string(&session).unwrap();
    std::fs::write(&session, text.replacen("\"sample\"", "\"sample\" ", 1)).unwrap();
    let problems = verify_sheet(&out, draw).expect_err("a changed spot");
    assert!(
        problems.iter().any(|p| p.to_string().contains("MANIFEST")),
        "{problems:?}"
    );
    std::fs::write(&session, text).unwrap();
    assert!(verify_sheet(&out, draw).is_ok());
    std::fs::write(out.join("notes.txt"), "x").unwrap();
    assert!(
        verify_sheet(&out, draw)
            .expect_err("an extra file")
            .iter()
            .any(|p| p.to_string().contains("not part of the sheet"))
    );
    std::fs::remove_file(out.join("notes.txt")).unwrap();
    std::fs::rename(out.join("spot-2"), out.join("spot-x")).unwrap();
    assert!(verify_sheet(&out, draw).is_err(), "a spot missing");
    let _ = std::fs::remove_dir_all(&out);

    for bad in ["0", "21", "many"] {
        let parsed = parse_args(args(&["--sim", "G", "--spots", bad]));
        let refused = match parsed {
            Err(e) => e.to_string(),
            Ok(a) => measure_with(
                &a,
                &mut SimulatedOperator,
                Arc::new(AtomicBool::new(false)),
                StoreOptions::default(),
            )
            .err()
            .expect("refused")
            .to_string(),
        };
        assert!(
            refused.contains("--spots") || refused.contains("invalid value"),
            "--spots {bad}: {refused}"
        );
    }
    // A session of one spot is continued as one.
    let single = dir("single");
    let single_text = single.display().to_string();
    let crash = Crash::at(30);
    let _ = run(
        &args(&["--sim", "J1", "--spots", "1", "--out", &single_text]),
        &mut SimulatedOperator,
        Some(crash),
    );
    let refused = run(
        &args(&["--sim", "J1", "--spots", "3", "--resume", &single_text]),
        &mut SimulatedOperator,
        None,
    )
    .err()
    .expect("refused")
    .to_string();
    assert!(refused.contains("without --spots 3"), "{refused}");
    let _ = std::fs::remove_dir_all(&single);
}
