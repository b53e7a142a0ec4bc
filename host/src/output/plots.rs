//! SVG figures of a fitted sample, after the paper's figures: Fig. 4 (radiance factor vs θr,
//! measured and fitted, one panel per θi), Fig. 5 (the σ–ρs plane that splits glossy from
//! rough) and Fig. 7 (the ρs–ρd plane that splits the rough groups).
//!
//! Drawn with plotters' SVG backend only: text becomes SVG `<text>` and its size is
//! estimated without fonts, so nothing here needs fontconfig, freetype or system fonts.
use crate::analysis::classify::{
    Class, Classification, Group, REFERENCES, ROUGH_I_MAX_RATIO, ROUGH_III_MIN_RATIO,
};
use crate::analysis::fit::{FitResult, Observation};
use crate::analysis::model::{self, Params, RHO_D, RHO_S, SIGMA};
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use std::io;
use std::path::{Path, PathBuf};

/// File name of the radiance-factor figure (the paper's Fig. 4).
pub const FIG4_FILE: &str = "fig4-radiance-factor.svg";
/// File name of the σ–ρs figure (Fig. 5).
pub const FIG5_FILE: &str = "fig5-sigma-rho_s.svg";
/// File name of the ρs–ρd figure (Fig. 7), written for rough samples only.
pub const FIG7_FILE: &str = "fig7-rho_s-rho_d.svg";

/// Step of the fitted curve in θr, degrees: fine enough that a glossy peak under 1° wide
/// (G: σ = 0.8°, FWHM ≈ 3.8°) is drawn with dozens of points.
pub const CURVE_STEP_DEG: f64 = 0.05;
/// θr range of Fig. 4, degrees (the instrument's range, Table 2).
pub const THETA_R_MAX_DEG: f64 = 70.0;
/// Fig. 4 uses a log y axis when the curves span more than this ratio (a glossy peak of
/// ~59 over a diffuse level of ~0.8); below it a linear axis from 0 shows the shape better.
const LOG_AXIS_MIN_SPAN: f64 = 10.0;

pub(crate) const SAMPLE_COLOR: RGBColor = RGBColor(200, 30, 30);
pub(crate) const CURVE_COLOR: RGBColor = RGBColor(20, 70, 180);
const REFERENCE_COLOR: RGBColor = RGBColor(90, 90, 90);
pub(crate) const GUIDE_COLOR: RGBColor = RGBColor(40, 140, 60);

pub(crate) type DrawResult<T> = Result<T, DrawingAreaErrorKind<io::Error>>;

pub(crate) fn to_io(e: DrawingAreaErrorKind<io::Error>) -> io::Error {
    io::Error::other(e.to_string())
}

/// The fitted curve of Fig. 4 for one θi: (θr, radiance factor) from 0 to 70° in
/// [`CURVE_STEP_DEG`] steps, plus θr = θi itself so the peak is never stepped over. With
/// an acceptance window the curve is what the detector sees (as the fit modelled it).
pub fn fig4_curve(
    params: &Params,
    acceptance_deg: Option<f64>,
    theta_i_deg: f64,
) -> Vec<(f64, f64)> {
    let steps = (THETA_R_MAX_DEG / CURVE_STEP_DEG).round() as usize;
    let mut theta_r: Vec<f64> = (0..=steps).map(|k| k as f64 * CURVE_STEP_DEG).collect();
    if (0.0..=THETA_R_MAX_DEG).contains(&theta_i_deg) {
        let at = theta_r.partition_point(|&t| t < theta_i_deg);
        if theta_r.get(at) != Some(&theta_i_deg) {
            theta_r.insert(at, theta_i_deg);
        }
    }
    theta_r
        .into_iter()
        .map(|tr| {
            let f = match acceptance_deg {
                Some(a) => model::observed_radiance_factor(params, theta_i_deg, tr, a),
                None => model::radiance_factor(params, theta_i_deg, tr),
            };
            (tr, f)
        })
        .collect()
}

/// The distinct θi of the readings, ascending (equal within 1e-6°).
pub fn incidence_angles(points: &[Observation]) -> Vec<f64> {
    let mut angles: Vec<f64> = points
        .iter()
        .map(|o| o.theta_i_deg)
        .filter(|t| t.is_finite())
        .collect();
    angles.sort_by(f64::total_cmp);
    angles.dedup_by(|a, b| (*a - *b).abs() < 1e-6);
    angles
}

/// Write the figures into `dir` (created if missing) and return their paths: Fig. 4 and
/// Fig. 5 always, Fig. 7 when the sample is rough.
pub fn write_plots(
    dir: &Path,
    sample: &str,
    points: &[Observation],
    fit: &FitResult,
    classification: &Classification,
) -> io::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    let mut written = Vec::new();

    let fig4 = dir.join(FIG4_FILE);
    draw_fig4(&fig4, sample, points, fit, classification).map_err(to_io)?;
    written.push(fig4);

    let fig5 = dir.join(FIG5_FILE);
    draw_fig5(&fig5, sample, fit, classification).map_err(to_io)?;
    written.push(fig5);

    if classification.class.is_some_and(has_fig7) {
        let fig7 = dir.join(FIG7_FILE);
        draw_fig7(&fig7, sample, fit, classification).map_err(to_io)?;
        written.push(fig7);
    }
    Ok(written)
}

// ---------------------------------------------------------------- Fig. 4

/// One panel of Fig. 4: the readings at one θi and the fitted curve.
struct Panel {
    theta_i_deg: f64,
    curve: Vec<(f64, f64)>,
    /// (θr, radiance factor, std, fitted value there) of the readings at this θi.
    readings: Vec<(f64, f64, Option<f64>, f64)>,
}

/// Tick values 1, 2, 5 × 10^k within `lo..hi`: every decade labelled, the peak's included.
pub fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) {
        return Vec::new();
    }
    let (first, last) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    (first..=last)
        .flat_map(|k| [1.0, 2.0, 5.0].map(|m| m * 10f64.powi(k)))
        .filter(|v| (lo..=hi).contains(v))
        .collect()
}

/// A tick label: as many digits as the value needs, no trailing ".0" on whole numbers.
pub(crate) fn tick_label(v: &f64) -> String {
    if *v >= 1.0 {
        format!("{}", (v * 1e6).round() / 1e6)
    } else {
        format!("{}", (v * 1e9).round() / 1e9)
    }
}

fn draw_fig4(
    path: &Path,
    sample: &str,
    points: &[Observation],
    fit: &FitResult,
    classification: &Classification,
) -> DrawResult<()> {
    let panels = fig4_panels(points, fit);
    let columns = panels.len().clamp(1, 2);
    let rows = panels.len().div_ceil(2).max(1);
    let size = (1000, 60 + 500 * rows as u32);
    let root = SVGBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    let title = format!(
        "{sample}: radiance factor in the specular plane, measured (±1 standard uncertainty) and TSL fit (class {}{})",
        classification.class_name(),
        fit.acceptance_deg
            .map_or_else(String::new, |a| format!(", acceptance {a}°"))
    );
    let root = root.titled(&title, ("sans-serif", 18))?;
    let range = Fig4Range::of(&panels);
    let scale = ResidualScale::of(&panels);
    let areas = root.split_evenly((rows, columns));
    for (k, (panel, area)) in panels.iter().zip(areas.iter()).enumerate() {
        let (upper, lower) = area.split_vertically(area.dim_in_pixel().1 * 68 / 100);
        let caption = format!("θi = {}°", panel.theta_i_deg);
        let mut builder = ChartBuilder::on(&upper);
        builder
            .caption(caption, ("sans-serif", 16))
            .margin(10)
            .margin_bottom(0)
            .x_label_area_size(22)
            .y_label_area_size(60);
        // The legend once, in the first panel.
        let legend = k == 0;
        if range.log_axis {
            let (lo, hi) = (0.7 * range.min_positive, 1.5 * range.max);
            let mut chart = builder.build_cartesian_2d(
                0.0..THETA_R_MAX_DEG,
                (lo..hi).log_scale().with_key_points(log_ticks(lo, hi)),
            )?;
            fill_fig4_panel(&mut chart, panel, Some(lo), legend)?;
        } else {
            let mut chart =
                builder.build_cartesian_2d(0.0..THETA_R_MAX_DEG, 0.0..1.1 * range.max)?;
            fill_fig4_panel(&mut chart, panel, None, legend)?;
        }
        draw_fig4_residuals(&lower, panel, &scale)?;
    }
    root.present()
}

/// The panels of Fig. 4, one per θi: the fitted curve and the readings with the fitted
/// value at each.
fn fig4_panels(points: &[Observation], fit: &FitResult) -> Vec<Panel> {
    let fitted = |ti: f64, tr: f64| match fit.acceptance_deg {
        Some(a) => model::observed_radiance_factor(&fit.params, ti, tr, a),
        None => model::radiance_factor(&fit.params, ti, tr),
    };
    incidence_angles(points)
        .into_iter()
        .map(|ti| Panel {
            theta_i_deg: ti,
            curve: fig4_curve(&fit.params, fit.acceptance_deg, ti),
            readings: points
                .iter()
                .filter(|o| (o.theta_i_deg - ti).abs() < 1e-6)
                .map(|o| {
                    (
                        o.theta_r_deg,
                        o.radiance_factor,
                        o.std,
                        fitted(ti, o.theta_r_deg),
                    )
                })
                .collect(),
        })
        .collect()
}

/// The y range of Fig. 4's panels: one for all, so that the panels compare at a glance.
struct Fig4Range {
    /// The largest value drawn (curve, readings ± u).
    max: f64,
    /// The smallest positive value drawn (the floor of a log axis).
    min_positive: f64,
    /// A log axis: the curves span more than [`LOG_AXIS_MIN_SPAN`].
    log_axis: bool,
}

impl Fig4Range {
    fn of(panels: &[Panel]) -> Fig4Range {
        let curve_values = panels.iter().flat_map(|p| p.curve.iter().map(|&(_, f)| f));
        let reading_values = panels.iter().flat_map(|p| {
            p.readings
                .iter()
                .flat_map(|&(_, f, s, _)| [f - s.unwrap_or(0.0), f + s.unwrap_or(0.0)])
        });
        let all: Vec<f64> = curve_values
            .chain(reading_values)
            .filter(|v| v.is_finite())
            .collect();
        let max = all.iter().copied().fold(0.0, f64::max).max(1e-3);
        let min_positive = all
            .iter()
            .copied()
            .filter(|&v| v > 0.0)
            .fold(f64::INFINITY, f64::min)
            .min(max);
        let curve_max = panels
            .iter()
            .flat_map(|p| p.curve.iter().map(|c| c.1))
            .fold(0.0, f64::max);
        let curve_min = panels
            .iter()
            .flat_map(|p| p.curve.iter().map(|c| c.1))
            .fold(f64::INFINITY, f64::min);
        Fig4Range {
            max,
            min_positive,
            log_axis: curve_min > 0.0 && curve_max / curve_min > LOG_AXIS_MIN_SPAN,
        }
    }
}

/// The residuals' scale of Fig. 4: in standard uncertainties where the readings have them,
/// else relative; one limit for all panels.
struct ResidualScale {
    normalised: bool,
    limit: f64,
}

impl ResidualScale {
    fn of(panels: &[Panel]) -> ResidualScale {
        let normalised = panels
            .iter()
            .flat_map(|p| &p.readings)
            .all(|r| r.2.is_some_and(|s| s > 0.0 && s.is_finite()));
        let mut scale = ResidualScale {
            normalised,
            limit: 0.0,
        };
        let extreme = panels
            .iter()
            .flat_map(|p| p.readings.iter().map(|r| scale.residual(r)))
            .filter(|v| v.is_finite())
            .fold(0.0f64, |a, v| a.max(v.abs()));
        scale.limit = if normalised {
            extreme.max(3.0) * 1.15
        } else {
            extreme.max(0.02) * 1.15
        };
        scale
    }

    /// The residual of a reading (θr, radiance factor, std, fitted value).
    fn residual(&self, &(_, f, s, m): &(f64, f64, Option<f64>, f64)) -> f64 {
        if self.normalised {
            (f - m) / s.unwrap_or(1.0)
        } else {
            (f - m) / m.abs().max(1e-12)
        }
    }
}

/// The residuals of one panel, under it.
fn draw_fig4_residuals(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    panel: &Panel,
    scale: &ResidualScale,
) -> DrawResult<()> {
    let limit = scale.limit;
    let mut residuals = ChartBuilder::on(area)
        .margin(10)
        .margin_top(2)
        .x_label_area_size(36)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..THETA_R_MAX_DEG, -limit..limit)?;
    residuals
        .configure_mesh()
        .x_desc("θr [deg]")
        .y_desc(if scale.normalised {
            "residual / u"
        } else {
            "relative residual"
        })
        .y_labels(5)
        .light_line_style(WHITE)
        .draw()?;
    residuals.draw_series(LineSeries::new(
        [(0.0, 0.0), (THETA_R_MAX_DEG, 0.0)],
        CURVE_COLOR.stroke_width(1),
    ))?;
    if scale.normalised {
        for band in [-2.0, 2.0] {
            residuals.draw_series(LineSeries::new(
                [(0.0, band), (THETA_R_MAX_DEG, band)],
                BLACK.mix(0.3).stroke_width(1),
            ))?;
        }
    }
    residuals.draw_series(panel.readings.iter().filter_map(|r| {
        let residual = scale.residual(r);
        residual
            .is_finite()
            .then(|| Circle::new((r.0, residual), 3, SAMPLE_COLOR.filled()))
    }))?;
    Ok(())
}

/// Mesh, fitted curve, readings and error bars of one panel; `log_floor` is the bottom of
/// a log axis (readings at or below 0 cannot be drawn there and are left out).
fn fill_fig4_panel<'a, Y>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<RangedCoordf64, Y>>,
    panel: &Panel,
    log_floor: Option<f64>,
    legend: bool,
) -> DrawResult<()>
where
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .y_desc("radiance factor")
        .y_label_formatter(&tick_label)
        .x_label_formatter(&|_| String::new())
        .light_line_style(WHITE)
        .draw()?;
    let curve = chart.draw_series(LineSeries::new(
        panel
            .curve
            .iter()
            .copied()
            .filter(|&(_, f)| log_floor.is_none_or(|_| f > 0.0)),
        CURVE_COLOR.stroke_width(2),
    ))?;
    if legend {
        curve.label("TSL fit").legend(|(x, y)| {
            PathElement::new(vec![(x, y), (x + 20, y)], CURVE_COLOR.stroke_width(2))
        });
    }
    let drawable = |f: f64| log_floor.is_none_or(|_| f > 0.0);
    chart.draw_series(panel.readings.iter().filter_map(|&(tr, f, std, _)| {
        let std = std.filter(|s| s.is_finite() && *s > 0.0)?;
        let lo = log_floor.map_or(f - std, |floor| (f - std).max(floor));
        drawable(f)
            .then(|| PathElement::new(vec![(tr, lo), (tr, f + std)], SAMPLE_COLOR.stroke_width(1)))
    }))?;
    let measured = chart.draw_series(
        panel
            .readings
            .iter()
            .filter(|r| drawable(r.1))
            .map(|&(tr, f, _, _)| Circle::new((tr, f), 3, SAMPLE_COLOR.filled())),
    )?;
    if legend {
        measured
            .label("measured ± u")
            .legend(|(x, y)| Circle::new((x + 10, y), 3, SAMPLE_COLOR.filled()));
        // Upper left: the peaks sit at θr = θi ≥ 20° and rough curves rise towards 70°.
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
    }
    Ok(())
}

// ---------------------------------------------------------------- Fig. 5 and Fig. 7

/// The sample's point in a parameter plane with its 95 % intervals: (value, (low, high)).
#[derive(Clone, Copy, Debug)]
struct Estimate {
    value: f64,
    interval: (f64, f64),
}

/// An estimate of parameter `index` with its interval (the value itself when there is none).
fn estimate(fit: &FitResult, index: usize) -> Option<Estimate> {
    let value = fit.reported(index)?;
    let interval = fit.ci95[index].unwrap_or((value, value));
    Some(Estimate { value, interval })
}

/// σ for Fig. 5: the estimate, or, when the peak was not resolved, the upper limit with an
/// interval reaching down to 0 (drawn to the axis).
fn sigma_estimate(fit: &FitResult) -> Option<Estimate> {
    match (fit.sigma_deg(), fit.sigma_upper_deg()) {
        (Some(_), _) => estimate(fit, SIGMA),
        (None, Some(upper)) => Some(Estimate {
            value: upper,
            interval: (0.0, upper),
        }),
        (None, None) => None,
    }
}

/// Decade bounds [10^floor(log10 min), 10^ceil(log10 max)] of positive values.
fn decades(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return (0.1, 100.0);
    }
    (
        10f64.powf(lo.log10().floor()),
        10f64
            .powf(hi.log10().ceil())
            .max(10f64.powf(lo.log10().floor() + 1.0)),
    )
}

fn draw_fig5(
    path: &Path,
    sample: &str,
    fit: &FitResult,
    classification: &Classification,
) -> DrawResult<()> {
    let sigma = sigma_estimate(fit);
    let rho_s = estimate(fit, RHO_S).filter(|e| e.value > 0.0);
    let sample_point = sigma.zip(rho_s);

    let sample_sigmas = sample_point
        .iter()
        .flat_map(|(s, _)| [s.value, s.interval.1]);
    let (x_lo, x_hi) = decades(
        REFERENCES
            .iter()
            .map(|r| r.params.sigma_deg)
            .chain(sample_sigmas),
    );
    let sample_rhos = sample_point
        .iter()
        .flat_map(|(_, r)| [r.value, r.interval.0, r.interval.1]);
    let (y_lo, y_hi) = decades(REFERENCES.iter().map(|r| r.params.rho_s).chain(sample_rhos));

    let root = SVGBackend::new(path, (800, 720)).into_drawing_area();
    root.fill(&WHITE)?;
    let title = format!(
        "{sample}: σ–ρs plane (class {}, glossy when σ < ρs)",
        classification.class_name()
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(16)
        .x_label_area_size(45)
        .y_label_area_size(65)
        .build_cartesian_2d((x_lo..x_hi).log_scale(), (y_lo..y_hi).log_scale())?;
    chart
        .configure_mesh()
        .x_desc("σ [deg]")
        .y_desc("ρs")
        .draw()?;

    // The σ = ρs line over the part of the plot where both are in range.
    let (d_lo, d_hi) = (x_lo.max(y_lo), x_hi.min(y_hi));
    if d_lo < d_hi {
        chart.draw_series(LineSeries::new(
            [(d_lo, d_lo), (d_hi, d_hi)],
            GUIDE_COLOR.stroke_width(2),
        ))?;
        let mid = (d_lo * d_hi).sqrt();
        chart.draw_series([Text::new(
            "σ = ρs",
            (mid * 1.3, mid),
            ("sans-serif", 15).into_font().color(&GUIDE_COLOR),
        )])?;
    }
    let font = ("sans-serif", 16).into_font();
    chart.draw_series([
        Text::new(
            "glossy (σ < ρs)",
            (x_lo * 1.3, y_hi / 2.0),
            font.clone().color(&GUIDE_COLOR),
        ),
        Text::new(
            "rough (σ ≥ ρs)",
            (x_hi / 12.0, y_lo * 1.5),
            font.color(&GUIDE_COLOR),
        ),
    ])?;

    draw_references(
        &mut chart,
        REFERENCES
            .iter()
            .map(|r| (r.params.sigma_deg, r.params.rho_s, r.name)),
    )?;
    match sample_point {
        Some((s, r)) => draw_sample(&mut chart, sample, s, r, (x_lo, y_lo))?,
        None => {
            let note = format!("{sample}: no specular part fitted, so no point in this plane");
            chart.draw_series([Text::new(
                note,
                (x_lo * 1.3, y_lo * 3.0),
                ("sans-serif", 15).into_font().color(&SAMPLE_COLOR),
            )])?;
        }
    }
    root.present()
}

fn draw_fig7(
    path: &Path,
    sample: &str,
    fit: &FitResult,
    classification: &Classification,
) -> DrawResult<()> {
    let rho_s = estimate(fit, RHO_S);
    let rho_d = estimate(fit, RHO_D);
    let rough: Vec<_> = REFERENCES
        .iter()
        .filter(|r| r.class.group() == Group::Rough)
        .collect();

    let sample_x = rho_s.iter().flat_map(|e| [e.value, e.interval.1]);
    let sample_y = rho_d.iter().flat_map(|e| [e.value, e.interval.1]);
    let x_hi = 1.15
        * rough
            .iter()
            .map(|r| r.params.rho_s)
            .chain(sample_x)
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
    let y_hi = 1.15
        * rough
            .iter()
            .map(|r| r.params.rho_d)
            .chain(sample_y)
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);

    let root = SVGBackend::new(path, (800, 720)).into_drawing_area();
    root.fill(&WHITE)?;
    let title = format!(
        "{sample}: ρs–ρd plane of rough papers (class {})",
        classification.class_name()
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(16)
        .x_label_area_size(45)
        .y_label_area_size(65)
        .build_cartesian_2d(0.0..x_hi, 0.0..y_hi)?;
    chart.configure_mesh().x_desc("ρs").y_desc("ρd").draw()?;

    // Group boundaries are lines ρd = k·ρs through the origin, drawn to the plot's edge.
    let font = ("sans-serif", 15).into_font();
    for (slope, label) in [
        (ROUGH_I_MAX_RATIO, "ρd/ρs = 1/2.53"),
        (ROUGH_III_MIN_RATIO, "ρd/ρs = 1.83"),
    ] {
        let x_end = x_hi.min(y_hi / slope);
        chart.draw_series(LineSeries::new(
            [(0.0, 0.0), (x_end, slope * x_end)],
            GUIDE_COLOR.stroke_width(2),
        ))?;
        chart.draw_series([Text::new(
            label,
            (0.55 * x_end, 0.55 * slope * x_end),
            font.clone().color(&GUIDE_COLOR),
        )])?;
    }
    // Group names inside their wedges: below 1/2.53, between, above 1.83.
    chart.draw_series([
        Text::new(
            "rough-I",
            (0.8 * x_hi, 0.1 * y_hi.min(ROUGH_I_MAX_RATIO * x_hi)),
            font.clone().color(&GUIDE_COLOR),
        ),
        Text::new(
            "rough-II",
            (0.75 * x_hi.min(y_hi), 0.9 * x_hi.min(y_hi)),
            font.clone().color(&GUIDE_COLOR),
        ),
        Text::new(
            "rough-III",
            (0.05 * x_hi, 0.93 * y_hi),
            font.color(&GUIDE_COLOR),
        ),
    ])?;

    draw_references(
        &mut chart,
        rough
            .iter()
            .map(|r| (r.params.rho_s, r.params.rho_d, r.name)),
    )?;
    if let Some((x, y)) = rho_s.zip(rho_d) {
        draw_sample(&mut chart, sample, x, y, (0.0, 0.0))?;
    }
    root.present()
}

/// Grey circles with the Table 6 names beside them.
fn draw_references<'n, X, Y>(
    chart: &mut ChartContext<'_, SVGBackend<'_>, Cartesian2d<X, Y>>,
    points: impl Iterator<Item = (f64, f64, &'n str)>,
) -> DrawResult<()>
where
    X: Ranged<ValueType = f64>,
    Y: Ranged<ValueType = f64>,
{
    let font = ("sans-serif", 14).into_font().color(&REFERENCE_COLOR);
    chart.draw_series(points.map(|(x, y, name)| {
        EmptyElement::at((x, y))
            + Circle::new((0, 0), 4, REFERENCE_COLOR.filled())
            + Text::new(name.to_string(), label_offset_px(name), font.clone())
    }))?;
    Ok(())
}

/// Where a reference's name goes relative to its point, pixels: Table 6's neighbours
/// (J1/J2, PPC/J3/J4) would overprint each other with one common offset.
fn label_offset_px(name: &str) -> (i32, i32) {
    match name {
        "J1" => (-22, -16),
        "PPC" => (-34, -6),
        "J3" => (6, 2),
        _ => (6, -16),
    }
}

/// The sample as a red ring (its bars show through) with its 95 % intervals as bars with
/// end caps, cut at the plot's lower corner `floor` (a log axis cannot show 0); named in a
/// legend with the references, not beside its point, where it would overprint a reference
/// of the same name.
fn draw_sample<'a, X, Y>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<X, Y>>,
    sample: &str,
    x: Estimate,
    y: Estimate,
    floor: (f64, f64),
) -> DrawResult<()>
where
    X: Ranged<ValueType = f64>,
    Y: Ranged<ValueType = f64>,
{
    let style = SAMPLE_COLOR.stroke_width(2);
    let x_interval = (x.interval.0.max(floor.0), x.interval.1);
    let y_interval = (y.interval.0.max(floor.1), y.interval.1);
    chart.draw_series([
        PathElement::new(
            vec![(x_interval.0, y.value), (x_interval.1, y.value)],
            style,
        ),
        PathElement::new(
            vec![(x.value, y_interval.0), (x.value, y_interval.1)],
            style,
        ),
    ])?;
    // End caps, 5 px across, so that an interval shorter than the ring still shows.
    chart.draw_series([x_interval.0, x_interval.1].map(|at| {
        EmptyElement::at((at, y.value)) + PathElement::new(vec![(0, -5), (0, 5)], style)
    }))?;
    chart.draw_series([y_interval.0, y_interval.1].map(|at| {
        EmptyElement::at((x.value, at)) + PathElement::new(vec![(-5, 0), (5, 0)], style)
    }))?;
    chart
        .draw_series([EmptyElement::at((x.value, y.value)) + Circle::new((0, 0), 6, style)])?
        .label(format!("this sheet: {sample} (95 % intervals)"))
        .legend(|(x, y)| Circle::new((x + 10, y), 6, SAMPLE_COLOR.stroke_width(2)));
    chart
        .draw_series([Circle::new(
            (f64::NAN, f64::NAN),
            0,
            REFERENCE_COLOR.filled(),
        )])?
        .label("reference papers (Akao et al., Table 6)")
        .legend(|(x, y)| Circle::new((x + 10, y), 4, REFERENCE_COLOR.filled()));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerLeft)
        .label_font(("sans-serif", 14))
        .draw()?;
    Ok(())
}

/// Whether a class is drawn in Fig. 7 (the rough ones).
pub(crate) fn has_fig7(class: Class) -> bool {
    class.group() == Group::Rough
}
