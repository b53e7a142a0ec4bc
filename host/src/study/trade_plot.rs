//! The trade study's Pareto plot (`gonio trade` writes it), drawn with the figures'
//! helpers of [`crate::output::plots`]; it sits with the study whose points it draws.
use crate::output::plots::{
    CURVE_COLOR, DrawResult, GUIDE_COLOR, SAMPLE_COLOR, log_ticks, tick_label, to_io,
};
use crate::study::trade::{ParetoPoint, SIGMA_TARGET};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::io;
use std::path::Path;

/// File name of the trade study's plot.
pub const PARETO_FILE: &str = "pareto.svg";

/// The trade study's plot: device seconds against the 95th percentile of σ's relative
/// error over the glossy papers, one point per configuration, coloured by policy, the
/// Pareto front joined by a line. Unresolved σ (an infinite error) is drawn at the top.
pub fn write_pareto(path: &Path, points: &[(ParetoPoint, bool)]) -> io::Result<()> {
    draw_pareto(path, points).map_err(to_io)
}

fn policy_color(policy: &str) -> RGBColor {
    match policy {
        "strategy1" => RGBColor(120, 120, 120),
        "strategy2" => CURVE_COLOR,
        "paper" => RGBColor(230, 130, 0),
        _ => SAMPLE_COLOR,
    }
}

fn draw_pareto(path: &Path, points: &[(ParetoPoint, bool)]) -> DrawResult<()> {
    // Unresolved σ has no error to plot: such points go in a band above the errors,
    // labelled as what they are (not as a "1000 %" error).
    const TOP: f64 = 10.0;
    let y = |e: f64| {
        if e.is_finite() {
            e.clamp(1e-4, TOP)
        } else {
            TOP
        }
    };
    let x_hi = points
        .iter()
        .map(|(p, _)| p.device_seconds)
        .fold(1.0, f64::max)
        * 1.08;
    let y_lo = points
        .iter()
        .map(|(p, _)| y(p.p95_sigma_err))
        .fold(TOP, f64::min)
        / 2.0;
    let root = SVGBackend::new(path, (960, 680)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Glossy papers: device time against σ error (95th percentile)",
            ("sans-serif", 20),
        )
        .margin(16)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(
            0.0..x_hi,
            (y_lo..TOP * 1.5)
                .log_scale()
                .with_key_points(log_ticks(y_lo, 1.0).into_iter().chain([TOP]).collect()),
        )?;
    chart
        .configure_mesh()
        .x_desc("device seconds measuring the sample (mean)")
        .y_desc("σ relative error, 95th percentile")
        .y_label_formatter(&|v| {
            if *v >= TOP * 0.99 {
                "σ unresolved".to_string()
            } else {
                format!("{} %", tick_label(&(100.0 * v)))
            }
        })
        .draw()?;
    chart.draw_series(LineSeries::new(
        [(0.0, TOP / 2.0), (x_hi, TOP / 2.0)],
        BLACK.mix(0.4).stroke_width(1),
    ))?;
    chart.draw_series(LineSeries::new(
        [(0.0, SIGMA_TARGET), (x_hi, SIGMA_TARGET)],
        GUIDE_COLOR.stroke_width(1),
    ))?;
    chart.draw_series([Text::new(
        "5 % target",
        (x_hi * 0.85, SIGMA_TARGET * 1.15),
        ("sans-serif", 14).into_font().color(&GUIDE_COLOR),
    )])?;
    let mut front: Vec<(f64, f64)> = points
        .iter()
        .filter(|(_, on)| *on)
        .map(|(p, _)| (p.device_seconds, y(p.p95_sigma_err)))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    chart.draw_series(LineSeries::new(front, BLACK.stroke_width(1)))?;
    for policy in ["strategy1", "strategy2", "paper", "adaptive"] {
        let color = policy_color(policy);
        let mine: Vec<&ParetoPoint> = points
            .iter()
            .map(|(p, _)| p)
            .filter(|p| p.policy == policy)
            .collect();
        if mine.is_empty() {
            continue;
        }
        chart
            .draw_series(
                mine.iter().map(|p| {
                    Circle::new((p.device_seconds, y(p.p95_sigma_err)), 5, color.filled())
                }),
            )?
            .label(policy)
            .legend(move |(x, y)| Circle::new((x, y), 5, color.filled()));
        if policy == "paper" || policy == "adaptive" {
            // Labels of points near the right edge end at their point instead of starting there.
            chart.draw_series(mine.iter().map(|p| {
                let pos = if p.device_seconds > 0.8 * x_hi {
                    Pos::new(HPos::Right, VPos::Bottom)
                } else {
                    Pos::new(HPos::Left, VPos::Bottom)
                };
                Text::new(
                    format!("{policy} {}", p.label),
                    (p.device_seconds, y(p.p95_sigma_err) * 1.15),
                    ("sans-serif", 12).into_font().color(&color).pos(pos),
                )
            }))?;
        }
    }
    chart
        .configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.9))
        .position(SeriesLabelPosition::UpperRight)
        .draw()?;
    root.present()
}
