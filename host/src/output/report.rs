//! `report.html`: the report a person reads, from a finished session or sheet folder's own
//! files (`session.json`, `calibration.json`, the plots, the manifest). One self-contained
//! file: the plots inline, no script, no font or style from the network, a print
//! stylesheet so that "print to PDF" gives a clean document.
//!
//! The page is a function of the folder's files and of nothing else (no clock, no host
//! name): drawing it again from the same folder gives the same bytes, so a report written
//! into a finished folder can be checked against its manifest like every other file.
use crate::analysis::flags::Flag;
use crate::instrument::calibration::Calibration;
use crate::output::folder::{MANIFEST, REPORT, SessionDoc};
use serde_json::Value;
use std::fmt::Write as _;
use std::path::Path;

/// What a flag means, for a reader of the report.
pub fn flag_meaning(flag: Flag) -> &'static str {
    match flag {
        Flag::LostSteps => {
            "an arm lost steps and the readings it affected could not all be measured again: some geometries may be off"
        }
        Flag::WhiteDrift => {
            "the white tile read at the end differed from the calibration by more than the limit: the lamp or detector drifted"
        }
        Flag::CalibrationStale => {
            "the calibration was older than the accepted age when the session ended"
        }
        Flag::LackOfFit => {
            "the TSL model does not describe the readings within their uncertainty (χ² or residual-structure test): the intervals are widened and the class confidence capped below 0.95"
        }
        Flag::SigmaNotResolved => {
            "σ ≤ σ_l at the end: the geometries were not close enough to the specular direction for the fitted peak"
        }
        Flag::NotIdentified => {
            "a parameter the class or a comparison needs was not determined by the readings"
        }
        Flag::LinkRecovered => {
            "informational: the link to the instrument failed and was recovered; nothing was lost"
        }
        Flag::Resumed => {
            "informational: the session was interrupted and resumed; the readings taken before were kept"
        }
    }
}

/// HTML-escape text.
fn esc(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

const STYLE: &str = r#"
body { font-family: "DejaVu Sans", "Liberation Sans", Arial, sans-serif; margin: 2em auto; max-width: 60em; color: #111; line-height: 1.4; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; }
h2 { font-size: 1.25em; border-bottom: 1px solid #999; margin-top: 1.6em; }
h3 { font-size: 1.05em; }
table { border-collapse: collapse; margin: 0.5em 0; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: left; vertical-align: top; }
th { background: #eee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.verdict { font-size: 1.2em; padding: 0.4em 0.8em; display: inline-block; border-radius: 0.3em; }
.ok { background: #d8f0d8; border: 1px solid #393; }
.flagged { background: #fbe0d0; border: 1px solid #c63; }
.note { color: #444; font-size: 0.92em; }
.plots { display: flex; flex-wrap: wrap; gap: 1em; }
.plots figure { margin: 0; }
.plots svg { max-width: 100%; height: auto; border: 1px solid #ddd; }
code, .hash { font-family: "DejaVu Sans Mono", monospace; font-size: 0.85em; word-break: break-all; }
ol.decisions li { margin: 0.1em 0; }
@media print {
  body { margin: 0; max-width: none; font-size: 10pt; }
  h2 { break-after: avoid; }
  table, figure, .verdict { break-inside: avoid; }
  .plots svg { max-width: 48%; }
  a { color: inherit; text-decoration: none; }
}
"#;

fn page(title: &str, body: &str) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<meta name=\"generator\" content=\"gonio {}\">\n<title>{}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n{body}</body>\n</html>\n",
        env!("CARGO_PKG_VERSION"),
        esc(title)
    )
}

fn number(v: &Value, digits: usize) -> String {
    v.as_f64()
        .map_or_else(|| "—".to_string(), |x| format!("{x:.digits$}"))
}

fn row(cells: &[String]) -> String {
    format!(
        "<tr>{}</tr>\n",
        cells
            .iter()
            .map(|c| format!("<td>{c}</td>"))
            .collect::<String>()
    )
}

/// The case fields of a session (`gonio measure --case --operator --note`).
fn case_section(case: Option<&crate::output::folder::CaseRecord>) -> String {
    let field = |v: Option<&String>| {
        v.map_or_else(
            || "<span class=\"note\">not given</span>".to_string(),
            |v| esc(v),
        )
    };
    let mut s = String::from("<table>\n");
    s += &format!(
        "<tr><th>case</th><td>{}</td></tr>\n",
        field(case.and_then(|c| c.case_id.as_ref()))
    );
    s += &format!(
        "<tr><th>operator</th><td>{}</td></tr>\n",
        field(case.and_then(|c| c.operator.as_ref()))
    );
    s += &format!(
        "<tr><th>note</th><td>{}</td></tr>\n",
        field(case.and_then(|c| c.note.as_ref()))
    );
    s + "</table>\n"
}

/// The result of one session (one spot): class, parameters, fit, budget, plots.
fn result_section(dir: &Path, doc: &SessionDoc, heading: &str) -> Result<String, String> {
    let result = doc.rest.get("result").cloned().unwrap_or(Value::Null);
    let mut s = String::new();
    let class = result["class"].as_str();
    let confidence = result["class_confidence"].as_f64();
    let _ = writeln!(s, "<h{heading}>Class</h{heading}>");
    match (class, confidence) {
        (Some(class), Some(c)) => {
            let _ = writeln!(
                s,
                "<p><strong>{}</strong>, confidence {c:.2}: the share of the parameters' uncertainty region (their fitted covariance) that lies in this class of the paper's tree. 0.95 or more reads as settled; a fit flagged lack-of-fit is capped at 0.90. Nearest reference paper of Table 6: {} ({} combined standard uncertainties away).</p>",
                esc(class),
                esc(result["nearest_reference"].as_str().unwrap_or("?")),
                number(&result["nearest_reference_distance"], 1)
            );
        }
        _ => {
            let _ = writeln!(
                s,
                "<p><strong>undecided</strong>: {}</p>",
                esc(result["class_undecided"]
                    .as_str()
                    .unwrap_or("the readings did not decide the class"))
            );
        }
    }
    let _ = writeln!(
        s,
        "<h{heading}>Parameters</h{heading}>\n<table>\n<tr><th>parameter</th><th>value</th><th>95 % interval, lower</th><th>95 % interval, upper</th></tr>"
    );
    for (label, key, digits) in [
        ("σ, lobe width (degrees)", "sigma_deg", 3),
        ("ρs, specular weight", "rho_s", 4),
        ("ρd, diffuse (Lambert) weight", "rho_d", 4),
        ("η, refractive index", "eta", 3),
    ] {
        let ci = &result["ci95"][key];
        let fitted = result["model"]
            .as_array()
            .is_none_or(|names| names.iter().any(|n| n.as_str() == Some(key)));
        let (lower, upper) = if fitted {
            (number(&ci[0], digits), number(&ci[1], digits))
        } else {
            ("fixed, not fitted".to_string(), String::new())
        };
        let _ = write!(
            s,
            "{}",
            row(&[esc(label), number(&result[key], digits), lower, upper])
                .replace("<td>", "<td class=\"num\">")
                .replacen("<td class=\"num\">", "<td>", 1)
        );
    }
    let _ = writeln!(s, "</table>");
    if let Some(names) = result["not_identified"]
        .as_array()
        .filter(|a| !a.is_empty())
    {
        let _ = writeln!(
            s,
            "<p class=\"note\">Not identified: {}</p>",
            esc(&names
                .iter()
                .map(Value::to_string)
                .collect::<Vec<_>>()
                .join("; "))
        );
    }
    let _ = writeln!(
        s,
        "<h{heading}>Sampling and goodness of fit</h{heading}>\n<table>"
    );
    let sigma_ok = if result["sigma_ok"].as_bool() == Some(true) {
        "yes"
    } else {
        "NO: the geometries were not fine enough for the fitted peak"
    };
    let _ = writeln!(
        s,
        "<tr><th>σ &gt; σ_l</th><td>{sigma_ok} (σ_l = {}°, δ = {}°)</td></tr>",
        number(&result["sigma_l_deg"], 3),
        number(&result["delta_deg"], 3)
    );
    let _ = writeln!(
        s,
        "<tr><th>NMAE</th><td>{} % (mean absolute residual over the mean radiance factor)</td></tr>",
        result["nmae"]
            .as_f64()
            .map_or("—".into(), |v| format!("{:.2}", 100.0 * v))
    );
    let _ = writeln!(
        s,
        "<tr><th>RMS residual</th><td>{} (radiance factor, dimensionless)</td></tr>",
        number(&result["rms"], 5)
    );
    let chi2 = match (result["chi2"].as_f64(), result["gof_p"].as_f64()) {
        (Some(c), Some(p)) => format!(
            "χ² = {c:.1} on {} degrees of freedom, p = {p:.3}",
            result["dof"]
        ),
        _ => "no χ² (the readings carry no uncertainty of their own)".into(),
    };
    let _ = writeln!(s, "<tr><th>χ² test</th><td>{chi2}</td></tr>");
    let structure = result["structure"]["p_value"]
        .as_f64()
        .map_or("not run".to_string(), |p| format!("p = {p:.3}"));
    let _ = writeln!(
        s,
        "<tr><th>residual structure test</th><td>{structure}</td></tr>"
    );
    let _ = writeln!(
        s,
        "<tr><th>lack of fit</th><td>{}</td></tr>",
        if result["lack_of_fit"].as_bool() == Some(true) {
            "YES: the model does not describe these readings"
        } else {
            "no"
        }
    );
    let _ = writeln!(
        s,
        "<tr><th>geometries, device time</th><td>{} geometries, {} s measuring (+{} s homing and calibration)</td></tr>",
        result["geometries"],
        number(&result["device_seconds"], 1),
        number(&result["setup_seconds"], 1)
    );
    let _ = writeln!(s, "</table>");
    if let Some(kinds) = result["budget"]["by_kind"]
        .as_array()
        .filter(|k| k.len() > 1)
    {
        let _ = writeln!(
            s,
            "<h{heading}>Uncertainty budget</h{heading}>\n<p class=\"note\">Each kind of error's share of the variance of σ, ρs and ρd.</p>\n<table>\n<tr><th>error</th><th>σ</th><th>ρs</th><th>ρd</th></tr>"
        );
        for k in kinds {
            let share = |key: &str| {
                k["share"][key]
                    .as_f64()
                    .map_or("—".to_string(), |v| format!("{:.1} %", 100.0 * v))
            };
            let _ = write!(
                s,
                "{}",
                row(&[
                    esc(k["kind"].as_str().unwrap_or("?")),
                    share("sigma_deg"),
                    share("rho_s"),
                    share("rho_d")
                ])
            );
        }
        let _ = writeln!(s, "</table>");
    }
    // The plots the session drew, inline.
    let mut plots: Vec<String> = crate::output::folder::entries(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .into_iter()
        .filter(|n| n.starts_with("fig") && n.ends_with(".svg"))
        .collect();
    plots.sort();
    if !plots.is_empty() {
        let _ = writeln!(s, "<h{heading}>Plots</h{heading}>\n<div class=\"plots\">");
        for name in plots {
            let svg = std::fs::read_to_string(dir.join(&name))
                .map_err(|e| format!("{}: {e}", dir.join(&name).display()))?;
            // The SVG as plotters wrote it, without an XML declaration (not allowed inline).
            let svg = svg.trim_start_matches(|c: char| c != '<').to_string();
            let svg = if svg.starts_with("<?xml") {
                svg.split_once("?>")
                    .map_or(svg.clone(), |(_, rest)| rest.to_string())
            } else {
                svg
            };
            let _ = writeln!(
                s,
                "<figure>{}<figcaption>{}</figcaption></figure>",
                svg.trim(),
                esc(&name)
            );
        }
        let _ = writeln!(s, "</div>");
    }
    Ok(s)
}

fn instrument_section(doc: &SessionDoc) -> String {
    let i = &doc.instrument;
    let mut s = String::from("<table>\n");
    s += &format!(
        "<tr><th>serial number</th><td>{}</td></tr>\n",
        esc(&i.serial_number)
    );
    s += &format!("<tr><th>board</th><td>{}</td></tr>\n", esc(&i.board));
    s += &format!(
        "<tr><th>firmware</th><td>{}</td></tr>\n",
        esc(&i.firmware_version)
    );
    if let Some(sim) = &i.simulated_sample {
        s += &format!(
            "<tr><th>simulated instrument</th><td>yes: its scene is the sample '{}' (not a real measurement)</td></tr>\n",
            esc(sim)
        );
    }
    s += &format!(
        "<tr><th>plan</th><td>policy {}, integration {} ms, detector acceptance {}°</td></tr>\n",
        esc(&doc.plan.policy),
        doc.plan.integration_ms,
        doc.plan.acceptance_deg
    );
    s + "</table>\n"
}

fn calibration_section(dir: &Path, doc: &SessionDoc) -> String {
    let c: Calibration = match crate::output::folder::read_calibration(dir) {
        Ok(Some(c)) => c,
        Ok(None) => return "<p>No calibration file.</p>\n".to_string(),
        Err(p) => {
            return format!(
                "<p class=\"note\">The calibration file cannot be read: {}</p>\n",
                esc(&p.to_string())
            );
        }
    };
    let taken = chrono::DateTime::from_timestamp(c.taken_unix_s as i64, 0)
        .map_or("?".to_string(), |t| {
            t.format("%Y-%m-%d %H:%M:%S UTC").to_string()
        });
    let ended = doc
        .runs
        .last()
        .and_then(|r| r.ended.as_deref())
        .and_then(|t| chrono::DateTime::parse_from_rfc3339(t).ok());
    let age = ended.map_or("unknown".to_string(), |end| {
        let minutes = (end.timestamp() - c.taken_unix_s as i64) as f64 / 60.0;
        if minutes < 120.0 {
            format!("{minutes:.1} min")
        } else {
            format!("{:.1} h", minutes / 60.0)
        }
    });
    let mut s = String::from("<table>\n");
    s += &format!(
        "<tr><th>taken</th><td>{taken} on {}</td></tr>\n",
        esc(&c.instrument)
    );
    s += &format!("<tr><th>age when the session ended</th><td>{age}</td></tr>\n");
    s += &format!(
        "<tr><th>white tile</th><td>certified radiance factor {:.4}, standard uncertainty {:.2} %</td></tr>\n",
        c.white_radiance_factor,
        100.0 * c.white_relative_uncertainty
    );
    match &c.white_certificate {
        Some(cert) => {
            s += &format!(
                "<tr><th>tile certificate</th><td>tile {}, certificate {}{}, issued {}{}: radiance factor {} ± {} (expanded, k = {}); file SHA-256 {}</td></tr>\n",
                esc(&cert.tile),
                esc(&cert.certificate),
                cert.issued_by
                    .as_ref()
                    .map_or_else(String::new, |by| format!(" by {}", esc(by))),
                esc(&cert.issued),
                cert.valid_until
                    .as_ref()
                    .map_or_else(String::new, |u| format!(", valid until {}", esc(u))),
                cert.radiance_factor,
                cert.expanded_uncertainty,
                cert.coverage_factor,
                esc(cert.file_sha256.as_deref().unwrap_or("not recorded"))
            );
        }
        None => {
            s += "<tr><th>tile certificate</th><td>none given: the tile's values were entered on the command line or are gonio's defaults (an assumption, not a certificate)</td></tr>\n"
        }
    }
    s += &format!(
        "<tr><th>white readings</th><td>{} incidence angles; dark readings on {} ranges</td></tr>\n",
        c.white.len(),
        c.dark.len()
    );
    s + "</table>\n"
}

fn decisions_section(doc: &SessionDoc) -> String {
    let mut s = String::new();
    for run in &doc.runs {
        let _ = writeln!(
            s,
            "<h3>Run {}: {} to {} ({:?}{})</h3>\n<ol class=\"decisions\">",
            run.run,
            esc(&run.started),
            esc(run.ended.as_deref().unwrap_or("not closed")),
            run.outcome,
            run.why
                .as_deref()
                .map_or(String::new(), |w| format!(": {}", esc(w)))
        );
        for d in &run.decisions {
            let _ = writeln!(s, "<li>{}</li>", esc(d));
        }
        let _ = writeln!(s, "</ol>");
    }
    s
}

fn flags_section(flags: &[Flag]) -> String {
    if flags.is_empty() {
        return "<p>None.</p>\n".to_string();
    }
    let mut s = String::from("<ul>\n");
    for f in flags {
        let _ = writeln!(
            s,
            "<li><code>{}</code>: {}</li>",
            f.name(),
            esc(flag_meaning(*f))
        );
    }
    s + "</ul>\n"
}

/// The files of the folder with their SHA-256, as its manifest lists them.
fn files_section(dir: &Path) -> String {
    let Ok(text) = std::fs::read_to_string(dir.join(MANIFEST)) else {
        return format!("<p>No {MANIFEST}: the folder is not finished.</p>\n");
    };
    let mut s = format!(
        "<p class=\"note\">As {MANIFEST} lists them (<code>gonio verify</code> checks them, and that this report is the one they give: the report is drawn from them, so it cannot list itself).</p>\n<table>\n<tr><th>file</th><th>SHA-256</th></tr>\n"
    );
    for line in text.lines() {
        if let Some((hash, name)) = line.split_once("  ") {
            let _ = writeln!(
                s,
                "<tr><td>{}</td><td class=\"hash\">{}</td></tr>",
                esc(name),
                esc(hash)
            );
        }
    }
    s + "</table>\n"
}

fn verdict(ok: bool, flags: &[Flag]) -> String {
    if ok {
        let noted = if flags.is_empty() {
            String::new()
        } else {
            format!(
                " (noted: {})",
                flags
                    .iter()
                    .map(|f| f.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        };
        format!("<p class=\"verdict ok\">Result: clean{noted}</p>\n")
    } else {
        format!(
            "<p class=\"verdict flagged\">Result NOT CLEAN — flags: {}</p>\n",
            flags
                .iter()
                .map(|f| f.name())
                .collect::<Vec<_>>()
                .join(", ")
        )
    }
}

/// The folder's own name: the report does not depend on the path it was drawn from.
fn folder_name(dir: &Path) -> String {
    let absolute = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    absolute.file_name().map_or_else(
        || dir.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

fn session_doc(dir: &Path) -> Result<SessionDoc, String> {
    crate::output::folder::require_finished(dir).map_err(|p| p.to_string())
}

fn flags_of(doc: &SessionDoc) -> Vec<Flag> {
    doc.rest
        .get("flags")
        .cloned()
        .and_then(|f| serde_json::from_value(f).ok())
        .unwrap_or_default()
}

/// The report of the finished session folder `dir`.
pub fn session_html(dir: &Path) -> Result<String, String> {
    let doc = session_doc(dir)?;
    let flags = flags_of(&doc);
    let ok = doc.rest.get("ok").and_then(Value::as_bool).unwrap_or(false);
    let mut b = format!(
        "<h1>Sample {}</h1>\n<p class=\"note\">gonio session report of the folder {}</p>\n",
        esc(&doc.sample),
        esc(&folder_name(dir))
    );
    b += &verdict(ok, &flags);
    b += "<h2>Case</h2>\n";
    b += &case_section(doc.case.as_ref());
    b += "<h2>Instrument</h2>\n";
    b += &instrument_section(&doc);
    b += "<h2>Calibration</h2>\n";
    b += &calibration_section(dir, &doc);
    b += "<h2>Result</h2>\n";
    b += &result_section(dir, &doc, "3")?;
    b += "<h2>Flags</h2>\n";
    b += &flags_section(&flags);
    b += "<h2>Decisions</h2>\n";
    b += &decisions_section(&doc);
    b += "<h2>Files</h2>\n";
    b += &files_section(dir);
    b += &glossary();
    Ok(page(&format!("gonio report: {}", doc.sample), &b))
}

/// The report of the finished sheet folder `dir` (several spots).
pub fn sheet_html(dir: &Path) -> Result<String, String> {
    let read = crate::output::sheet_folder::read_sheet(dir).map_err(|p| p.to_string())?;
    let summary = &read.summary;
    let first = read
        .spots
        .first()
        .ok_or_else(|| format!("{}: a sheet without spots", dir.display()))?;
    let first_doc = session_doc(&first.dir)?;
    let mut b = format!(
        "<h1>Sample {}: a sheet of {} spots</h1>\n<p class=\"note\">gonio sheet report of the folder {}</p>\n",
        esc(&read.doc.sample),
        read.spots.len(),
        esc(&folder_name(dir))
    );
    b += &verdict(summary.ok(), &summary.flags);
    b += "<h2>Case</h2>\n";
    b += &case_section(read.doc.case.as_ref().or(first_doc.case.as_ref()));
    b += "<h2>Instrument</h2>\n";
    b += &instrument_section(&first_doc);
    b += "<h2>Calibration (shared by every spot)</h2>\n";
    b += &calibration_section(&first.dir, &first_doc);
    b += "<h2>The sheet</h2>\n<table>\n<tr><th>parameter</th><th>geometric mean of the accepted spots</th><th>spot-to-spot relative sd</th></tr>\n";
    for (i, label) in ["σ (degrees)", "ρs", "ρd"].iter().enumerate() {
        let sd = summary
            .within_relative_sd
            .map_or("unknown (one spot)".to_string(), |sd| {
                format!("{:.1} %", 100.0 * sd[i])
            });
        b += &row(&[
            label.to_string(),
            summary.mean[i].map_or("—".into(), |v| format!("{v:.4}")),
            sd,
        ]);
    }
    b += "</table>\n";
    b += &format!(
        "<p>{} of {} spots planned accepted, {} measured.</p>\n",
        summary.accepted,
        read.doc.spots_planned,
        read.spots.len()
    );
    b += "<table>\n<tr><th>spot</th><th>class</th><th>σ (deg)</th><th>ρs</th><th>ρd</th><th>flags</th><th>verdict</th></tr>\n";
    for s in &read.spots {
        let verdict = match summary
            .verdicts
            .iter()
            .find(|j| j.number == s.result.number)
            .map(|j| &j.verdict)
        {
            Some(crate::analysis::spots::SpotVerdict::Accepted) => "accepted".to_string(),
            Some(crate::analysis::spots::SpotVerdict::Excluded { reason }) => {
                format!("excluded: {}", esc(reason))
            }
            None => "?".to_string(),
        };
        let v = |i: usize, d: usize| {
            s.session.values[i].map_or("—".to_string(), |x| format!("{x:.d$}"))
        };
        let flags = if s.result.flags.is_empty() {
            "none".to_string()
        } else {
            s.result
                .flags
                .iter()
                .map(|f| f.name())
                .collect::<Vec<_>>()
                .join(", ")
        };
        b += &row(&[
            format!(
                "<a href=\"#spot-{}\">{}</a>",
                s.result.number, s.result.number
            ),
            esc(s.session.class.as_deref().unwrap_or("undecided")),
            v(0, 3),
            v(1, 4),
            v(2, 4),
            flags,
            verdict,
        ]);
    }
    b += "</table>\n";
    for note in &summary.notes {
        b += &format!("<p class=\"note\">{}</p>\n", esc(note));
    }
    b += "<h2>Flags</h2>\n";
    b += &flags_section(&summary.flags);
    b += "<h2>Decisions of the sheet</h2>\n<ol class=\"decisions\">\n";
    for d in &read.doc.decisions {
        b += &format!("<li>{}</li>\n", esc(d));
    }
    b += "</ol>\n";
    for s in &read.spots {
        let doc = session_doc(&s.dir)?;
        b += &format!(
            "<h2 id=\"spot-{}\">Spot {}</h2>\n",
            s.result.number, s.result.number
        );
        b += &verdict(
            doc.rest.get("ok").and_then(Value::as_bool).unwrap_or(false),
            &flags_of(&doc),
        );
        b += &result_section(&s.dir, &doc, "3")?;
        b += "<h3>Decisions</h3>\n";
        b += &decisions_section(&doc)
            .replace("<h3>", "<h4>")
            .replace("</h3>", "</h4>");
    }
    b += "<h2>Files</h2>\n";
    b += &files_section(dir);
    b += &glossary();
    Ok(page(
        &format!(
            "gonio report: {} ({} spots)",
            read.doc.sample,
            read.spots.len()
        ),
        &b,
    ))
}

/// The report of a finished session or sheet folder.
pub fn html(dir: &Path) -> Result<String, String> {
    if crate::output::folder::is_sheet_folder(dir) {
        sheet_html(dir)
    } else {
        session_html(dir)
    }
}

fn glossary() -> String {
    let terms = [
        (
            "TSL model",
            "Torrance–Sparrow specular lobe plus a Lambert (diffuse) term, fitted to the radiance factor in the specular plane (Akao et al.)",
        ),
        (
            "σ",
            "the width of the specular lobe (degrees): small for glossy paper",
        ),
        ("ρs, ρd", "the weights of the specular and the diffuse term"),
        ("η", "the refractive index in the Fresnel factor"),
        (
            "σ_l, δ",
            "the narrowest lobe the geometries measured can resolve, from their spacing δ around the specular direction; σ > σ_l means the sampling was fine enough",
        ),
        (
            "radiance factor",
            "the sample's radiance over that of a perfect white diffuser under the same light (BRDF × π)",
        ),
        (
            "NMAE",
            "normalised mean absolute error: the mean absolute residual over the mean radiance factor",
        ),
        (
            "95 % interval",
            "the range that holds the true value in 95 % of sessions, with the readings' noise and the errors they share (white tile, gains, lamp drift, arm zero)",
        ),
        (
            "confidence",
            "the share of the parameters' uncertainty region that lies in the reported class",
        ),
        ("device s", "seconds of the instrument's own clock"),
    ];
    let mut s = String::from("<h2>Glossary</h2>\n<dl>\n");
    for (term, meaning) in terms {
        let _ = writeln!(
            s,
            "<dt><strong>{}</strong></dt><dd>{}</dd>",
            esc(term),
            esc(meaning)
        );
    }
    s + "</dl>\n"
}

/// Draw the report of the finished folder `dir` into `dir/report.html` (atomically: a
/// temporary file in the folder, renamed into place). Returns its path.
pub fn write_into(dir: &Path) -> Result<std::path::PathBuf, String> {
    let html = html(dir)?;
    let path = dir.join(REPORT);
    let temp = dir.join(crate::output::folder::temp_name(REPORT));
    std::fs::write(&temp, html.as_bytes())
        .map_err(|e| format!("cannot write {}: {e}", temp.display()))?;
    std::fs::rename(&temp, &path).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    Ok(path)
}
