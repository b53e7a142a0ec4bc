//! `gonio forensic --library FILE`: the validation of a lab's own library as the population
//! its comparisons are weighed against ([`crate::analysis::evidence::validation`]): every
//! same- and different-stock pair of its sheets weighed against the stocks outside both
//! pairs' folds, the calibrator, the ELUB bounds, Cllr, Cllr_min, Cllr_cal, the rates of
//! misleading evidence both ways, the calibration by reported decade, a Tippett plot and an
//! empirical cross-entropy plot.
use crate::analysis::evidence::validation::{pav, validate};
use crate::analysis::evidence::{EvidenceError, LibrarySheet, Population, PopulationSource};
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

/// The library's population, validated: what `compare --library` uses.
pub fn run(sheets: &[LibrarySheet]) -> Result<Population, EvidenceError> {
    validate(sheets)
}

/// ECE (bits) of log10 LRs at prior log10 odds `prior` (Ramos & González-Rodríguez):
/// the cross-entropy of the posteriors the ratios give, each class weighed by its prior.
pub fn ece(same: &[f64], different: &[f64], prior: f64) -> f64 {
    let ln10 = std::f64::consts::LN_10;
    let p = 1.0 / (1.0 + (-prior * ln10).exp());
    // −log2 of the posterior of the true proposition, from log10 posterior odds.
    let bits = |log10_odds: f64| -> f64 {
        let t = -log10_odds * ln10;
        (if t > 30.0 { t } else { t.exp().ln_1p() }) / std::f64::consts::LN_2
    };
    let s = same.iter().map(|&x| bits(x + prior)).sum::<f64>() / same.len().max(1) as f64;
    let d =
        different.iter().map(|&x| bits(-(x + prior))).sum::<f64>() / different.len().max(1) as f64;
    p * s + (1.0 - p) * d
}

/// The ECE plot over prior log10 odds −3…3: the reported ratios, the same after PAV (the
/// best they could be calibrated) and the neutral reference (LR = 1).
pub fn ece_svg(
    same: &[f64],
    different: &[f64],
    path: &Path,
) -> Result<(), super::forensic::ForensicError> {
    let (pav_same, pav_different) = pav(same, different);
    let priors: Vec<f64> = (0..=120).map(|k| -3.0 + 6.0 * k as f64 / 120.0).collect();
    let curve = |s: &[f64], d: &[f64]| -> Vec<(f64, f64)> {
        priors.iter().map(|&x| (x, ece(s, d, x))).collect()
    };
    let reference = curve(&[0.0], &[0.0]);
    let top = reference.iter().map(|p| p.1).fold(1.0, f64::max) * 1.1;
    let root = SVGBackend::new(path, (720, 460)).into_drawing_area();
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption("Empirical cross-entropy", ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(-3.0f64..3.0, 0.0..top)?;
        chart
            .configure_mesh()
            .x_desc("prior log10 odds (same stock : different stocks)")
            .y_desc("empirical cross-entropy (bits)")
            .draw()?;
        chart
            .draw_series(LineSeries::new(curve(same, different), RED.stroke_width(2)))?
            .label("reported LRs")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(2)));
        chart
            .draw_series(LineSeries::new(
                curve(&pav_same, &pav_different),
                BLUE.stroke_width(2),
            ))?
            .label("after PAV (discrimination alone)")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        chart
            .draw_series(LineSeries::new(reference, BLACK.mix(0.5)))?
            .label("neutral reference (LR = 1)")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5)));
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE.mix(0.9))
            .position(SeriesLabelPosition::UpperRight)
            .draw()?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| super::forensic::ForensicError::Draw {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// The summary a lab reads: its library's population and what its validation found.
pub fn summary_markdown(library: &impl std::fmt::Display, population: &Population) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Validation of the library {}\n\nPopulation identity `{}`.\n",
        library,
        population.identity()
    );
    if let PopulationSource::Library {
        stocks,
        lots,
        sheets,
        spots,
        instruments,
        left_out_sheets,
    } = &population.source
    {
        let _ = writeln!(
            s,
            "{stocks} stocks, {lots} lots recorded, {sheets} sheets, {spots} spots, {instruments} instruments; {left_out_sheets} sheets left out (a spot that did not determine σ, ρs and ρd).\n"
        );
    }
    let pct = |sd: [f64; 3]| {
        sd.iter()
            .map(|v| format!("{:.1} %", 100.0 * v))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let _ = writeln!(
        s,
        "| level | σ, ρs, ρd (relative sd, as used: upper 95 % bounds) | degrees of freedom |\n|---|---|---:|"
    );
    let _ = writeln!(
        s,
        "| spots within a sheet | {} | {} |",
        pct(population.spot.used_relative_sd()),
        population.spot.dof
    );
    let _ = writeln!(
        s,
        "| sheets within a stock | {} | {}{} |",
        pct(population.sheet.used_relative_sd()),
        population.sheet.dof,
        if population.sheet.measured() {
            ""
        } else {
            " (not measured: taken as the spot level)"
        }
    );
    let kernel: [f64; 3] =
        std::array::from_fn(|i| population.kernel[i][i].max(0.0).exp_m1().sqrt());
    let _ = writeln!(
        s,
        "| stock density's kernel | {} | bandwidth {} |\n",
        pct(kernel),
        population
            .bandwidth
            .map_or("assumed".to_string(), |h| format!("{h:.3}"))
    );
    match &population.validation {
        Some(v) => s += &validation_markdown(v),
        None => s += "Not validated.\n",
    }
    s
}

/// The validation's figures: pairs, calibrator, bounds, Cllr, misleading rates, decades.
fn validation_markdown(v: &crate::analysis::evidence::Validation) -> String {
    let mut s = String::new();
    let rate = |k: usize, n: usize| {
        let (lo, hi) = super::forensic::wilson(k, n);
        format!(
            "{k} of {n} ({:.2} %; 95 % CI {:.2}–{:.2} %)",
            100.0 * k as f64 / n.max(1) as f64,
            100.0 * lo,
            100.0 * hi
        )
    };
    let _ = writeln!(
        s,
        "## Validation\n\nEvery pair of the library's sheets, weighed against the stocks outside both sheets' folds ({} folds); calibrated fold by fold (logistic); bounded by ELUB.\n",
        v.folds
    );
    let _ = writeln!(s, "| measure | value |\n|---|---|");
    let _ = writeln!(
        s,
        "| same-stock / different-stock pairs | {} / {} |",
        v.same_pairs, v.different_pairs
    );
    let _ = writeln!(
        s,
        "| calibrator | log10 LR = {:+.3} + {:.3} · raw |",
        v.calibrator.intercept, v.calibrator.slope
    );
    let _ = writeln!(
        s,
        "| ELUB bounds of log10 LR | [{:+.2}, {:+.2}] |",
        v.bounds.0, v.bounds.1
    );
    let _ = writeln!(
        s,
        "| Cllr / Cllr_min / Cllr_cal (bits) | {:.3} / {:.3} / {:.3} |",
        v.cllr, v.cllr_min, v.cllr_cal
    );
    let _ = writeln!(s, "| Cllr of the model's raw ratios | {:.3} |", v.cllr_raw);
    let _ = writeln!(
        s,
        "| same-stock pairs below LR 1 | {} |",
        rate(v.same_below.0, v.same_pairs)
    );
    let _ = writeln!(
        s,
        "| same-stock pairs below LR 1/100 | {} |",
        rate(v.same_below.1, v.same_pairs)
    );
    let _ = writeln!(
        s,
        "| different-stock pairs above LR 1 | {} |",
        rate(v.different_above.0, v.different_pairs)
    );
    let _ = writeln!(
        s,
        "| different-stock pairs above LR 100 | {} |\n",
        rate(v.different_above.1, v.different_pairs)
    );
    let _ = writeln!(
        s,
        "## Calibration by reported decade\n\n| reported log10 LR | same-stock pairs | different-stock pairs | observed log10 ratio |\n|---|---:|---:|---:|"
    );
    for b in &v.bins {
        let _ = writeln!(
            s,
            "| [{:+.0}, {:+.0}) | {} | {} | {} |",
            b.from,
            b.from + 1.0,
            b.same,
            b.different,
            b.observed_log10_lr
                .map_or("—".to_string(), |x| format!("{x:+.2}"))
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ece_at_even_odds_is_cllr_and_the_reference_peaks_at_one_bit() {
        let same = [2.0, 0.5, -0.3, 3.0];
        let different = [-2.0, 0.4, -1.0, -4.0];
        let cllr = crate::analysis::evidence::validation::cllr(&same, &different);
        assert!((ece(&same, &different, 0.0) - cllr).abs() < 1e-12);
        assert!((ece(&[0.0], &[0.0], 0.0) - 1.0).abs() < 1e-12);
        assert!(ece(&[0.0], &[0.0], 2.0) < 0.2);
    }
}
