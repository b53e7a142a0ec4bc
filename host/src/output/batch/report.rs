//! `batch.html`: the batch report a person reads, from `batch.json` alone. One
//! self-contained page (no script, nothing fetched), a maud template: every text from the
//! documents (sample and stock names, flags, reasons) is escaped by construction.
use super::{BatchDoc, BatchSheet};
use crate::analysis::batch::{LABELS, PARAMETERS, Statistics, gloss_label, shown_value};
use crate::output::folder::Status;
use maud::{DOCTYPE, Markup, html};

const STYLE: &str = r#"
body { font-family: "DejaVu Sans", "Liberation Sans", Arial, sans-serif; margin: 2em auto; max-width: 64em; color: #111; line-height: 1.4; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; }
h2 { font-size: 1.25em; border-bottom: 1px solid #999; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.5em 0; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: left; vertical-align: top; }
th { background: #eee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.verdict { font-size: 1.2em; padding: 0.4em 0.8em; display: inline-block; border-radius: 0.3em; }
.pass { background: #d8f0d8; }
.fail { background: #f6c8c0; }
.undecided { background: #fbecc0; }
.note { color: #444; font-size: 0.92em; }
.charts svg { border: 1px solid #ddd; margin: 0.3em 0.3em 0 0; }
@media print { body { margin: 0; max-width: none; font-size: 10pt; } table, svg { break-inside: avoid; } }
"#;

/// A value of parameter `i` as the report writes it.
fn value(i: usize, v: Option<f64>) -> String {
    match v {
        Some(v) if i == 0 => format!("{v:.3}°"),
        Some(v) => format!("{v:.4}"),
        None => "—".to_string(),
    }
}

fn pct(v: Option<f64>, signed: bool) -> String {
    match v {
        Some(v) if signed => format!("{v:+.2} %"),
        Some(v) => format!("{v:.2} %"),
        None => "—".to_string(),
    }
}

/// The page of `doc`.
pub fn html(doc: &BatchDoc) -> String {
    let title = format!(
        "QA batch of {} against the master stock {}",
        doc.plan.sample, doc.master.stock
    );
    let page = html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                title { (title) }
                style { (maud::PreEscaped(STYLE)) }
            }
            body {
                h1 { (title) }
                (summary(doc))
                h2 { "Master stock and tolerances" }
                (master(doc))
                h2 { "Sheets" }
                (sheets(doc))
                h2 { "Statistics across the sheets" }
                p.note { "Flagged sheets left out; " (doc.chart) "." }
                (statistics(doc))
                div.charts {
                    @for s in &doc.statistics {
                        (chart(doc, s))
                    }
                }
            }
        }
    };
    page.into_string()
}

fn summary(doc: &BatchDoc) -> Markup {
    let c = doc.counts;
    let class = if c.fail > 0 {
        "verdict fail"
    } else if c.undecided > 0 {
        "verdict undecided"
    } else {
        "verdict pass"
    };
    html! {
        p.(class) {
            (doc.sheets.len()) " of " (doc.plan.sheets) " sheets measured: "
            (c.pass) " pass, " (c.fail) " fail, " (c.undecided) " undecided"
        }
        @if doc.status != Status::Finished {
            p.verdict.undecided {
                "The batch is " (doc.status.to_string()) "; "
                (doc.why.clone().unwrap_or_default())
                @if let Some(how) = &doc.resume_with { " — continue it with " code { (how) } }
            }
        }
        p.note {
            (doc.plan.spots) " spot(s) per sheet; "
            @match &doc.plan.sim {
                Some(paper) => {
                    "on the simulator: paper " (paper) ", sheet k of seed "
                    (doc.plan.sim_seed.unwrap_or(0)) " + k − 1, each sheet's parameters drawn about the paper's with a relative sd of "
                    (doc.plan.sheet_to_sheet_pct.unwrap_or(0.0)) " %. "
                }
                None => { "on the instrument. " }
            }
            "Master read from " code { (doc.plan.library) } " when the batch began."
        }
    }
}

fn master(doc: &BatchDoc) -> Markup {
    let m = &doc.master;
    html! {
        p { "Stock " strong { (m.stock) } ": " (m.sheets) " sheet(s), " (m.spots) " spot(s) in the library." }
        table {
            tr { th { "parameter" } th { "master value" } th { "sheet-to-sheet sd" } th { "spot-to-spot sd" } th { "spots' own u" } th { "tolerance" } th { "basis" } }
            @for i in 0..3 {
                tr {
                    td { (LABELS[i]) }
                    td.num { (value(i, m.values[i])) }
                    td.num { (pct(m.sheet_to_sheet_relative_sd[i].map(|x| 100.0 * x), false)) }
                    td.num { (pct(m.spot_to_spot_relative_sd[i].map(|x| 100.0 * x), false)) }
                    td.num { (pct(m.spot_relative_uncertainty[i].map(|x| 100.0 * x), false)) }
                    td.num { "± " (format!("{:.1}", doc.tolerance_pct[i])) " %" }
                    td.note { (doc.tolerance_basis[i]) }
                }
            }
        }
        @if doc.plan.gloss_spec.is_empty() {
            p.note { "No gloss specification (--gloss-spec): gloss is not judged (the library keeps no gloss, so the master gives none)." }
        } @else {
            table {
                tr { th { "gloss specification" } th { "geometry" } th { "target" } th { "tolerance" } }
                @for g in &doc.plan.gloss_spec {
                    tr {
                        td { (g.label()) " (--gloss-spec " code { (g.text()) } ")" }
                        td { (g.geometry) }
                        td.num { (g.target_gloss_units) " GU" }
                        td.num { "± " (g.tolerance_gloss_units) " GU" }
                    }
                }
            }
        }
        p.note { "A sheet passes when each parameter's deviation from the master is within its tolerance and its gloss within each specification; it fails when any is beyond; it is undecided when its own result is flagged, it did not determine a parameter, or it has no gloss at a specified geometry (no instrument profile in force, or the arms do not reach it)." }
    }
}

fn verdict_class(s: &BatchSheet) -> &'static str {
    s.verdict.name()
}

fn sheets(doc: &BatchDoc) -> Markup {
    let angles = super::gloss_angles(doc);
    let gloss = |s: &BatchSheet, angle: f64| {
        s.gloss
            .iter()
            .find(|g| g.angle_deg == angle)
            .map_or_else(|| "—".to_string(), |g| format!("{:.1}", g.gloss_units))
    };
    html! {
        table {
            tr {
                th { "sheet" }
                @for l in LABELS { th { (l) } }
                @for l in LABELS { th { "Δ" (l) } }
                @for a in &angles { th { (gloss_label(*a)) " (GU)" } }
                th { "verdict" } th { "flags" } th { "report" }
            }
            @for s in &doc.sheets {
                tr.(verdict_class(s)) {
                    td.num { (s.number) }
                    @for i in 0..3 { td.num { (value(i, s.values[i])) } }
                    @for i in 0..3 { td.num { (pct(s.deviation_pct[i], true)) } }
                    @for a in &angles { td.num { (gloss(s, *a)) } }
                    td { (s.verdict.text()) }
                    td { (if s.flags.is_empty() { "none".to_string() } else { s.flags.join(", ") }) }
                    td { a href=(format!("{}/report.html", s.folder)) { (s.folder) } }
                }
            }
        }
    }
}

fn statistics(doc: &BatchDoc) -> Markup {
    let number = |k: usize, v: Option<f64>| shown_value(&doc.statistics[k].quantity, v);
    html! {
        @if doc.statistics.is_empty() {
            p { "No clean sheet yet." }
        } @else {
            table {
                tr { th { "" } th { "n" } th { "mean" } th { "sd" } th { "min" } th { "max" } th { "LCL" } th { "UCL" } th { "MR̄" } th { "MR UCL" } th { "out of control" } }
                @for (k, s) in doc.statistics.iter().enumerate() {
                    tr {
                        td { (crate::analysis::batch::label(&s.quantity)) }
                        td.num { (s.n) }
                        td.num { (number(k, Some(s.mean))) }
                        td.num { (number(k, s.sd)) }
                        td.num { (number(k, Some(s.min))) }
                        td.num { (number(k, Some(s.max))) }
                        td.num { (number(k, s.lower_control_limit)) }
                        td.num { (number(k, s.upper_control_limit)) }
                        td.num { (number(k, s.moving_range_mean)) }
                        td.num { (number(k, s.moving_range_upper_limit)) }
                        td {
                            @if s.out_of_control.is_empty() { "none" }
                            @else { "sheets " (s.out_of_control.iter().map(u16::to_string).collect::<Vec<_>>().join(", ")) }
                        }
                    }
                }
            }
        }
    }
}

/// The individuals chart of `s`: the sheets in order, the centre line and
/// control limits (dashed), the master's value and tolerance (green).
fn chart(doc: &BatchDoc, s: &Statistics) -> Markup {
    let (width, height, margin) = (420.0, 200.0, 36.0);
    let i = PARAMETERS.iter().position(|p| *p == s.quantity);
    // A gloss chart's green lines are its specification's target and limits.
    let spec = doc.plan.gloss_spec.iter().find(|g| g.label() == s.quantity);
    let angle = doc
        .sheets
        .iter()
        .flat_map(|b| &b.gloss)
        .find(|g| gloss_label(g.angle_deg) == s.quantity)
        .map(|g| g.angle_deg);
    let target: Option<(f64, f64, f64)> = match (i, spec) {
        (Some(i), _) => doc.master.values[i].map(|m| {
            let t = doc.tolerance_pct[i] / 100.0;
            (m, m * (1.0 - t), m * (1.0 + t))
        }),
        (None, Some(g)) => Some((
            g.target_gloss_units,
            g.target_gloss_units - g.tolerance_gloss_units,
            g.target_gloss_units + g.tolerance_gloss_units,
        )),
        (None, None) => None,
    };
    let points: Vec<(u16, f64)> = doc
        .sheets
        .iter()
        .filter_map(|b| match (i, angle) {
            (Some(i), _) => b.values[i].map(|v| (b.number, v)),
            (None, Some(a)) => b
                .gloss
                .iter()
                .find(|g| g.angle_deg == a)
                .map(|g| (b.number, g.gloss_units)),
            (None, None) => None,
        })
        .collect();
    let mut levels: Vec<f64> = points.iter().map(|p| p.1).collect();
    levels.extend(s.lower_control_limit);
    levels.extend(s.upper_control_limit);
    if let Some((_, lo, hi)) = target {
        levels.extend([lo, hi]);
    }
    let lo = levels.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = levels.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let span = if hi > lo { hi - lo } else { lo.abs().max(1e-9) };
    let (lo, hi) = (lo - 0.08 * span, hi + 0.08 * span);
    let n = doc.plan.sheets.max(2) as f64;
    let x = |number: u16| margin + (width - 2.0 * margin) * (number as f64 - 1.0) / (n - 1.0);
    let y = |v: f64| height - margin - (height - 2.0 * margin) * (v - lo) / (hi - lo);
    let line = |v: f64| format!("M{margin:.1},{:.1} H{:.1}", y(v), width - margin);
    let path: String = points
        .iter()
        .enumerate()
        .map(|(j, p)| {
            format!(
                "{}{:.1},{:.1}",
                if j == 0 { "M" } else { " L" },
                x(p.0),
                y(p.1)
            )
        })
        .collect();
    let label = i.map_or(s.quantity.as_str(), |i| LABELS[i]);
    html! {
        svg xmlns="http://www.w3.org/2000/svg" width=(width) height=(height) viewBox=(format!("0 0 {width} {height}")) role="img" aria-label=(format!("individuals chart of {label}")) {
            text x=(margin) y="16" font-size="13" { "individuals chart: " (label) }
            @if let Some((m, lo, hi)) = target {
                path d=(line(m)) stroke="#393" stroke-width="1.5" {}
                path d=(line(lo)) stroke="#393" stroke-width="1" {}
                path d=(line(hi)) stroke="#393" stroke-width="1" {}
            }
            path d=(line(s.mean)) stroke="#333" stroke-width="1" {}
            @for l in [s.lower_control_limit, s.upper_control_limit].into_iter().flatten() {
                path d=(line(l)) stroke="#c33" stroke-dasharray="5,4" stroke-width="1" {}
            }
            path d=(path) fill="none" stroke="#136" stroke-width="1.2" {}
            @for p in &points {
                circle cx=(format!("{:.1}", x(p.0))) cy=(format!("{:.1}", y(p.1))) r="3"
                    fill=(if s.out_of_control.contains(&p.0) { "#c33" } else { "#136" }) {}
            }
            text x=(margin) y=(height - 8.0) font-size="11" { "sheet 1 … " (doc.plan.sheets) "; " (match (target, i) { (None, _) => "", (Some(_), Some(_)) => "green: master ± tolerance, ", (Some(_), None) => "green: specification, " }) "red dashed: control limits" }
        }
    }
}
