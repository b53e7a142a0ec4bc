//! SVG figures: which files are written for glossy and rough samples, that they are SVG
//! with the sample's name and the axis labels, and that the drawn curve reaches a glossy peak.
use crate::common;
use host::analysis::classify::{self, Group};
use host::analysis::fit::{self, FitOptions, Observation};
use host::analysis::model;
use host::output::plots::{self, FIG4_FILE, FIG5_FILE, FIG7_FILE};
use std::path::{Path, PathBuf};

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gonio-plots-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn read_svg(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let head = text.trim_start();
    assert!(
        head.starts_with("<svg") || head.starts_with("<?xml"),
        "{} does not start as SVG: {:.80}",
        path.display(),
        head
    );
    assert!(
        text.trim_end().ends_with("</svg>"),
        "{} is not a complete SVG",
        path.display()
    );
    text
}

/// Readings of a reference paper with their uncertainties, fitted and classified.
fn fitted(
    name: &str,
    geometries: &[(f64, f64)],
) -> (Vec<Observation>, fit::FitResult, classify::Classification) {
    let points = common::synthetic(
        &common::reference(name),
        geometries,
        model::DEFAULT_ACCEPTANCE_DEG,
        0.01,
        0.003,
        7,
        true,
    );
    let result = fit::fit(&points, &FitOptions::default()).expect("the fit converges");
    let classification = classify::classify(&result);
    (points, result, classification)
}

#[test]
fn glossy_sample_gets_fig4_and_fig5_but_no_fig7() {
    let (points, result, classification) = fitted("G", &common::strategy2(1));
    assert_eq!(classification.group, Some(Group::Glossy));
    let dir = temp_dir("glossy");
    let written = plots::write_plots(&dir, "sheet-G42", &points, &result, &classification)
        .expect("plots written");
    assert_eq!(written, vec![dir.join(FIG4_FILE), dir.join(FIG5_FILE)]);
    assert!(
        !dir.join(FIG7_FILE).exists(),
        "no ρs–ρd figure for a glossy sample"
    );

    let fig4 = read_svg(&dir.join(FIG4_FILE));
    for needle in [
        "sheet-G42",
        "θr [deg]",
        "radiance factor",
        "θi = 20°",
        "θi = 30°",
        "θi = 45°",
        "θi = 60°",
        "TSL fit",
        "measured",
    ] {
        assert!(fig4.contains(needle), "Fig. 4 lacks {needle:?}");
    }
    let fig5 = read_svg(&dir.join(FIG5_FILE));
    for needle in [
        "sheet-G42",
        "σ [deg]",
        "ρs",
        "σ = ρs",
        "glossy (σ &lt; ρs)",
        "G",
        "SG",
        "PPC",
        "MC",
        "J1",
        "J2",
        "J3",
        "J4",
    ] {
        assert!(fig5.contains(needle), "Fig. 5 lacks {needle:?}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn rough_sample_gets_fig7_with_group_boundaries_and_rough_references() {
    let (points, result, classification) = fitted("PPC", &common::strategy1_m12());
    assert_eq!(classification.group, Some(Group::Rough));
    let dir = temp_dir("rough");
    let written = plots::write_plots(&dir, "copier & co", &points, &result, &classification)
        .expect("plots written");
    assert_eq!(written.len(), 3);
    let fig7 = read_svg(&dir.join(FIG7_FILE));
    // The name is escaped in SVG text.
    assert!(fig7.contains("copier &amp; co"), "sample name");
    for needle in [
        "ρs",
        "ρd",
        "ρd/ρs = 1/2.53",
        "ρd/ρs = 1.83",
        "rough-I",
        "rough-III",
        "PPC",
        "MC",
        "J1",
        "J4",
    ] {
        assert!(fig7.contains(needle), "Fig. 7 lacks {needle:?}");
    }
    // Only the six rough papers are labelled: the glossy ones' names never stand alone.
    assert!(
        !fig7.contains(">SG<") && !fig7.contains(">G<"),
        "glossy references in Fig. 7"
    );
    let fig4 = read_svg(&dir.join(FIG4_FILE));
    assert!(fig4.contains("θi = 20°") && fig4.contains("θi = 60°"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn fig4_curve_reaches_the_glossy_peak() {
    let g = common::reference("G");
    for ti in [20.0, 30.0, 45.0, 60.0, 33.33] {
        for acceptance in [None, Some(model::DEFAULT_ACCEPTANCE_DEG)] {
            let curve = plots::fig4_curve(&g, acceptance, ti);
            let peak = match acceptance {
                Some(a) => model::observed_radiance_factor(&g, ti, ti, a),
                None => model::radiance_factor(&g, ti, ti),
            };
            let max = curve.iter().map(|p| p.1).fold(f64::MIN, f64::max);
            assert!(
                (max - peak).abs() <= 0.01 * peak,
                "θi {ti} acceptance {acceptance:?}: drawn max {max}, peak {peak}"
            );
            assert!(
                max > 5.0 * g.rho_d,
                "a glossy peak stands far above the diffuse level: {max}"
            );
            assert_eq!(curve.first().map(|p| p.0), Some(0.0));
            assert!((curve.last().map_or(0.0, |p| p.0) - plots::THETA_R_MAX_DEG).abs() < 1e-9);
            assert!(
                curve
                    .windows(2)
                    .all(|w| w[1].0 > w[0].0 && w[1].0 - w[0].0 <= plots::CURVE_STEP_DEG + 1e-9),
                "ascending, fine steps"
            );
        }
    }
}

#[test]
fn sample_without_readings_at_some_incidence_gets_only_its_panels() {
    let geometries: Vec<(f64, f64)> = common::strategy1_m12()
        .into_iter()
        .filter(|g| g.0 != 60.0)
        .collect();
    let (points, result, classification) = fitted("MC", &geometries);
    assert_eq!(plots::incidence_angles(&points), vec![20.0, 30.0, 45.0]);
    let dir = temp_dir("three-panels");
    plots::write_plots(&dir, "mc", &points, &result, &classification).expect("plots written");
    let fig4 = read_svg(&dir.join(FIG4_FILE));
    assert!(fig4.contains("θi = 45°") && !fig4.contains("θi = 60°"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn unwritable_directory_is_an_io_error() {
    let (points, result, classification) = fitted("J1", &common::strategy1_m12());
    let file = std::env::temp_dir().join(format!("gonio-plots-{}-not-a-dir", std::process::id()));
    std::fs::write(&file, "x").expect("write");
    assert!(plots::write_plots(&file, "j1", &points, &result, &classification).is_err());
    let _ = std::fs::remove_file(&file);
}

/// The texts of an SVG's `<text>` elements.
fn texts(svg: &str) -> Vec<String> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| {
            t.split_once('>')
                .and_then(|(_, rest)| rest.split_once("</text>"))
                .map(|(text, _)| text.trim().to_string())
        })
        .collect()
}

#[test]
fn fig4_labels_every_decade_shows_one_legend_and_a_residual_panel_per_incidence() {
    assert_eq!(
        plots::log_ticks(0.6, 90.0),
        [1.0, 2.0, 5.0, 10.0, 20.0, 50.0]
    );
    assert_eq!(plots::log_ticks(0.05, 0.3), [0.05, 0.1, 0.2]);
    assert!(plots::log_ticks(0.0, 1.0).is_empty());
    let (points, result, classification) = fitted("G", &common::strategy2(1));
    let dir = temp_dir("fig4-ticks");
    plots::write_plots(&dir, "G", &points, &result, &classification).expect("plots written");
    let svg = read_svg(&dir.join(FIG4_FILE));
    let t = texts(&svg);
    let panels = plots::incidence_angles(&points).len();
    // G's peaks reach ~57: the decade 10–100 is labelled, not only 1 and 10.
    for label in ["1", "2", "5", "10", "20", "50"] {
        assert_eq!(
            t.iter().filter(|x| *x == label).count(),
            panels,
            "the tick {label} in every panel: {t:?}"
        );
    }
    assert_eq!(
        t.iter().filter(|x| *x == "TSL fit").count(),
        1,
        "one legend"
    );
    assert_eq!(
        t.iter().filter(|x| x.starts_with("residual")).count(),
        panels,
        "a residual panel per θi"
    );
    assert!(
        svg.matches("<circle").count() >= 2 * points.len(),
        "each reading in its panel and its residual"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn fig5_and_fig7_name_the_sheet_in_a_legend_and_the_groups_as_the_report_does() {
    let (points, result, classification) = fitted("PPC", &common::strategy1_m12());
    let dir = temp_dir("fig57-legend");
    plots::write_plots(&dir, "PPC", &points, &result, &classification).expect("plots written");
    for file in [FIG5_FILE, FIG7_FILE] {
        let t = texts(&read_svg(&dir.join(file)));
        // "PPC" once: the reference's label; the sheet is named in the legend, not over it.
        assert_eq!(t.iter().filter(|x| *x == "PPC").count(), 1, "{file}: {t:?}");
        assert!(
            t.iter().any(|x| x == "this sheet: PPC (95 % intervals)"),
            "{file}: {t:?}"
        );
        assert!(
            t.iter().any(|x| x.starts_with("reference papers")),
            "{file}: {t:?}"
        );
    }
    let t = texts(&read_svg(&dir.join(FIG7_FILE)));
    for group in ["rough-I", "rough-II", "rough-III"] {
        assert!(t.iter().any(|x| x == group), "{group}: {t:?}");
    }
    assert!(
        !t.iter().any(|x| x.starts_with("group")),
        "the report's class names: {t:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
