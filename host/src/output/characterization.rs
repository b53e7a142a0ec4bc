//! A characterization's files: the instrument profile (`instrument.json`, written whole
//! through a temporary file so that a crash never leaves half a profile) and the short
//! HTML report a lab files with it (the response per incidence and the lamp, drawn as
//! inline SVG; every figure with its uncertainty).
use crate::analysis::response_estimate::Measured;
use crate::output::plots::{CURVE_COLOR, SAMPLE_COLOR};
use crate::output::report::{Text, field_row, page};
use crate::session::characterize::Characterization;
use anyhow::Context;
use maud::{PreEscaped, html};
use plotters::prelude::*;
use std::path::Path;

/// Write `bytes` to `path` through a temporary file in the same folder, renamed over it.
fn write_whole(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut file = tempfile::NamedTempFile::new_in(dir)
        .with_context(|| format!("cannot write in {}", dir.display()))?;
    std::io::Write::write_all(&mut file, bytes)
        .and_then(|()| file.as_file().sync_all())
        .with_context(|| format!("cannot write {}", path.display()))?;
    file.persist(path)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// Write the profile to `json` and the report to `html`; returns the profile's SHA-256.
pub fn write(result: &Characterization, json: &Path, html: &Path) -> anyhow::Result<String> {
    let mut bytes = serde_json::to_vec_pretty(&result.profile)?;
    bytes.push(b'\n');
    write_whole(json, &bytes)?;
    let sha = crate::instrument::profile::sha256_hex(&bytes);
    write_whole(html, report(result, &sha)?.as_bytes())?;
    Ok(sha)
}

fn measured(m: Measured, digits: usize, unit: &str) -> String {
    if m.value.is_finite() {
        format!("{:.digits$} ± {:.digits$}{unit}", m.value, m.u)
    } else {
        "not measured".to_string()
    }
}

/// The report's page.
pub fn report(result: &Characterization, sha256: &str) -> anyhow::Result<String> {
    let p = &result.profile;
    let title = format!("Characterization of instrument {}", p.serial_number);
    let body = html! {
        h1 { (Text(&title)) } "\n"
        p.note { "Measured " (Text(&p.measured_at)) " by gonio " (Text(&p.gonio_version))
            ", firmware " (Text(&p.firmware_version)) ", in " (format!("{:.0}", p.device_seconds))
            " s of device time. Profile SHA-256 " span.hash { (sha256) } "." } "\n"
        h2 { "Standards" } "\n"
        table {
            (field_row("black glass", Text(&format!("{} (n = {})", p.standards.black_glass.id, p.standards.black_glass.refractive_index))))
            (field_row("white tile", Text(&format!("{} (radiance factor {})", p.standards.white_tile.id, p.standards.white_tile.radiance_factor))))
        } "\n"
        h2 { "Angular response (black glass)" } "\n"
        p.note { "Each sweep through the glass's specular peak, normalised to unit area and centred on its centroid: the detector's acceptance and the source's divergence together. The firmware declares a top-hat of "
            (format!("{}°", p.response.declared_acceptance_deg)) "." } "\n"
        table {
            (field_row("FWHM", measured(p.response.fwhm_deg, 3, "°")))
            (field_row("top-hat width of the same variance", measured(p.response.equivalent_width_deg, 3, "°")))
            (field_row("backlash (up − down)", measured(p.backlash_deg, 4, "°")))
            (field_row("homing repeatability (sd)", measured(p.home_repeatability_deg, 4, "°")))
            (field_row("arm zero uncertainty a session takes", format!("{:.4}°", p.arm_zero_u_deg)))
        } "\n"
        div.plots { figure { (PreEscaped(response_svg(result)?)) } } "\n"
        h3 { "Per incidence" } "\n"
        table {
            tr { th { "θi" } th { "arm zero" } th { "FWHM" } th { "range" } } "\n"
            @for i in &p.incidences {
                tr {
                    td.num { (format!("{}°", i.theta_i_deg)) }
                    td.num { (measured(i.arm_zero_deg, 4, "°")) }
                    td.num { (measured(i.fwhm_deg, 3, "°")) }
                    td.num { (i.range) }
                } "\n"
            }
        } "\n"
        h2 { "Detector" } "\n"
        table {
            tr { th { "ranges" } th { "gain ratio measured" } th { "nominal" } } "\n"
            @for g in &p.gain_ratios {
                tr { td { (format!("{} → {}", g.range, g.range + 1)) } td.num { (measured(g.ratio, 5, "")) } td.num { (format!("{}", g.nominal)) } } "\n"
            }
        } "\n"
        @if p.gain_ratios.is_empty() { p.note { "No gain ratio measured: no black glass peak needed a less sensitive range." } }
        table {
            tr { th { "range" } th { "dark (counts)" } th { "white relative sd" } } "\n"
            @for n in &p.noise {
                tr { td.num { (n.range) } td.num { (measured(n.dark_counts, 1, "")) }
                    td.num { (n.white_relative_sd.map_or_else(|| "—".to_string(), |s| format!("{:.2e} at {} ms", s, n.integration_ms))) } } "\n"
            }
        } "\n"
        h2 { "Lamp" } "\n"
        p { "White drift " (measured(p.lamp.drift_pct_per_h, 2, " %/h")) " over " (format!("{:.0}", p.lamp.over_s)) " s after the lamp was switched on." } "\n"
        div.plots { figure { (PreEscaped(lamp_svg(result)?)) } } "\n"
    };
    Ok(page(&title, body))
}

fn response_svg(result: &Characterization) -> anyhow::Result<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (760, 420)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
        let mut curves: Vec<(f64, Vec<(f64, f64)>)> = Vec::new();
        let (mut lo, mut hi, mut top) = (0.0f64, 0.0f64, 0.0f64);
        for (trace, peak) in &result.sweeps {
            let mut points: Vec<(f64, f64)> = trace
                .bins
                .iter()
                .map(|b| (b.theta_r_deg - peak.centroid_deg, b.signal / peak.area))
                .collect();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            for &(u, r) in &points {
                if r > 0.01 * peak.peak_signal / peak.area {
                    lo = lo.min(u);
                    hi = hi.max(u);
                }
                top = top.max(r);
            }
            curves.push((trace.theta_i_deg, points));
        }
        let margin = 0.3 * (hi - lo).max(0.5);
        let (lo, hi) = (lo - margin, hi + margin);
        let mut chart = ChartBuilder::on(&root)
            .caption("Normalised response, every sweep", ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(lo..hi, 0.0..1.1 * top.max(1e-9))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc("θr − peak centroid (°)")
            .y_desc("response (1/°)")
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        for (k, (_, points)) in curves.iter().enumerate() {
            let colour = if k % 2 == 0 {
                CURVE_COLOR
            } else {
                SAMPLE_COLOR
            };
            chart
                .draw_series(LineSeries::new(
                    points.iter().copied().filter(|p| p.0 >= lo && p.0 <= hi),
                    colour.mix(0.6),
                ))
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    Ok(svg)
}

fn lamp_svg(result: &Characterization) -> anyhow::Result<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (760, 300)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
        let series = &result.lamp_series;
        let t_max = series.last().map_or(1.0, |p| p.0).max(1.0);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for p in series {
            lo = lo.min(p.1);
            hi = hi.max(p.1);
        }
        if !(lo < hi) {
            (lo, hi) = (0.999, 1.001);
        }
        let pad = 0.2 * (hi - lo);
        let mut chart = ChartBuilder::on(&root)
            .caption("White reading relative to its mean", ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..t_max, (lo - pad)..(hi + pad))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc("device time since the lamp came on (s)")
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .draw_series(
                series
                    .iter()
                    .map(|&(t, v)| Circle::new((t, v), 3, CURVE_COLOR.filled())),
            )
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    Ok(svg)
}
