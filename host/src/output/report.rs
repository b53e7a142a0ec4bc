//! `report.html`: the report a person reads, from a finished session or sheet folder's own
//! files (`session.json`, `calibration.json`, the plots, the manifest). One self-contained
//! file: the plots inline, no script, no font or style from the network, a print
//! stylesheet so that "print to PDF" gives a clean document.
//!
//! The page is a function of the folder's files and of nothing else (no clock, no host
//! name): drawing it again from the same folder gives the same bytes, so a report written
//! into a finished folder can be checked against its manifest like every other file.
//!
//! The page is a maud template: compiled with gonio, no template file to ship or find at
//! run time, and every value put into it escaped unless it is marked as markup (the
//! stylesheet, the plots' SVG, the sections drawn here). Text goes in as [`Text`], which
//! escapes `'` too, as the report always has. Whitespace between the elements is written
//! out (`"\n"`): the page's bytes are part of what `gonio verify` checks.
use crate::analysis::flags::Flag;
use crate::analysis::result::ResultDocument;
use crate::instrument::calibration::Calibration;
use crate::output::folder::documents::SpotResultDocument;
use crate::output::folder::sheet::{ReadFolder, ReadSheet};
use crate::output::folder::{Finding, MANIFEST, REPORT, SessionDoc};
use maud::{DOCTYPE, Markup, PreEscaped, Render, html};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Why the report of a folder cannot be drawn or written.
#[derive(Debug, Error)]
pub enum ReportError {
    /// The folder is not a finished session or sheet folder, or one of its documents is
    /// wrong.
    #[error("{0}")]
    Folder(Finding),
    /// A sheet folder with no spot.
    #[error("{}: a sheet without spots", .0.display())]
    NoSpots(PathBuf),
    /// A session's `result` is not a result document.
    #[error("{}: result: {source}", path.display())]
    Result {
        /// The session folder.
        path: PathBuf,
        /// What is wrong with it.
        source: serde_json::Error,
    },
    /// A file or folder could not be read.
    #[error("{}: {source}", path.display())]
    Read {
        /// The file or folder.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A folder that does not verify: its report would present changed data as the
    /// session's (issue 30, D7).
    #[error(
        "{}: does not verify, so no report is drawn from it (gonio verify {} tells the same; gonio report --unverified draws one marked as such):{}",
        dir.display(),
        dir.display(),
        problems.iter().map(|p| format!("\n  {p}")).collect::<String>()
    )]
    DoesNotVerify {
        /// The folder.
        dir: PathBuf,
        /// What `gonio verify` finds wrong, but for `report.html` (redrawn here).
        problems: Vec<Finding>,
    },
    /// The report could not be written.
    #[error("cannot write {}: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
}

impl From<Finding> for ReportError {
    fn from(problem: Finding) -> ReportError {
        ReportError::Folder(problem)
    }
}

/// What a flag means, for a reader of the report.
pub(crate) fn flag_meaning(flag: Flag) -> &'static str {
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
        Flag::InstrumentSensitive => {
            "without an instrument profile, the class changes within the bound on the detector's response (from a point detector to a top-hat of 3° full width, instead of the declared 1°): the class rests on a response nobody measured; characterize the instrument (gonio characterize) and measure again"
        }
        Flag::ModelExtended => {
            "informational: the paper's TSL model did not describe the readings and the fit added the term(s) the data called for (named under the fit, each with its test); σ, ρs, ρd, η are still the main lobe's, σ its half-maximum width as a Gaussian, so the paper's classification tree applies to them"
        }
        Flag::Outlier => {
            "a reading lies so far from the fit that it is taken for a gross error (named under the fit): check it, measure again"
        }
        Flag::FewDegreesOfFreedom => {
            "too few readings beyond the fitted parameters to judge the fit or state a class confidence"
        }
        Flag::ImplausibleInput => {
            "the readings cannot be a paper in degrees and radiance factors as they stand (a table in percent, angles in radians, or a paper far outside the population of papers; the note says which): check the units and fit again"
        }
        Flag::SpotsDisagree => {
            "informational, a sheet's: its accepted spots do not all have one class (named above); the sheet's class is its mean's, with the spot-to-spot variation in its confidence: look at the spots before reading the class alone"
        }
        Flag::InstrumentDeclared => {
            "informational: no instrument profile was in force (none, or older than the lab's limit): the fit took the detector's angular response and arm zero as declared, not as measured on this instrument (gonio characterize measures them)"
        }
    }
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
/// Text for the page, escaped: `&`, `<`, `>` and `"` as maud escapes them, and `'` as
/// `&#39;` (as the report has always written it: the same folder draws the same bytes).
pub(crate) struct Text<'a>(pub(crate) &'a str);

impl Render for Text<'_> {
    fn render_to(&self, out: &mut String) {
        for c in self.0.chars() {
            match c {
                '&' => out.push_str("&amp;"),
                '<' => out.push_str("&lt;"),
                '>' => out.push_str("&gt;"),
                '"' => out.push_str("&quot;"),
                '\'' => out.push_str("&#39;"),
                c => out.push(c),
            }
        }
    }
}

pub(crate) fn page(title: &str, body: Markup) -> String {
    html! {
        (DOCTYPE) "\n"
        html lang="en" {
            "\n"
            head {
                "\n"
                meta charset="utf-8"; "\n"
                meta name="generator" content=(concat!("gonio ", env!("CARGO_PKG_VERSION"))); "\n"
                title { (Text(title)) } "\n"
                style { (PreEscaped(STYLE)) } "\n"
            }
            "\n"
            body { "\n" (body) }
            "\n"
        }
        "\n"
    }
    .into_string()
}

/// `x` with `digits` decimals, `—` without a value.
fn number(x: Option<f64>, digits: usize) -> String {
    x.map_or_else(|| "—".to_string(), |x| format!("{x:.digits$}"))
}

/// A table row of a header cell and a data cell.
pub(crate) fn field_row(label: &str, value: impl Render) -> Markup {
    html! { tr { th { (label) } td { (value) } } "\n" }
}

/// A table row of data cells, each already markup.
fn row(cells: &[Markup]) -> Markup {
    html! { tr { @for cell in cells { td { (cell) } } } "\n" }
}

/// A heading of level 3 or 4 (the decisions of a spot are a level below a session's).
fn heading(level: u8, content: Markup) -> Markup {
    match level {
        3 => html! { h3 { (content) } },
        _ => html! { h4 { (content) } },
    }
}

/// The case fields of a session (`gonio measure --case --operator --note`).
fn case_section(case: Option<&crate::output::folder::CaseRecord>) -> Markup {
    let field = |v: Option<&String>| match v {
        Some(v) => html! { (Text(v)) },
        None => html! { span class="note" { "not given" } },
    };
    html! {
        table {
            "\n"
            (field_row("case", field(case.and_then(|c| c.case_id.as_ref()))))
            (field_row("operator", field(case.and_then(|c| c.operator.as_ref()))))
            (field_row("note", field(case.and_then(|c| c.note.as_ref()))))
            (field_row("orientation (machine direction)", crate::analysis::specimen::orientation_text(case.and_then(|c| c.orientation))))
            (field_row("side facing the instrument", crate::analysis::specimen::side_text(case.and_then(|c| c.side))))
        }
        "\n"
    }
}

/// The `result` of the session `doc` of the folder `dir` (all absent when it has none).
fn spot_result(dir: &Path, doc: &SessionDoc) -> Result<SpotResultDocument, ReportError> {
    doc.outcome()
        .result
        .transpose()
        .map(Option::unwrap_or_default)
        .map_err(|source| ReportError::Result {
            path: dir.to_path_buf(),
            source,
        })
}

/// The result of one session (one spot): class, parameters, fit, budget, plots.
fn result_section(dir: &Path, doc: &SessionDoc) -> Result<Markup, ReportError> {
    let result = spot_result(dir, doc)?;
    Ok(html! {
        (class_paragraph(&result.analysis))
        (parameters_table(&result.analysis))
        (instrument_profile_section(&result))
        (sampling_table(&result, doc))
        (budget_table(&result.analysis))
        (plots(dir)?)
    })
}

/// The instrument the analysis took: the profile in force (its hash, date and age, the
/// response it measured) and the gloss it allows, or the declared values and the bound
/// the readings give through a response nobody measured.
fn instrument_profile_section(result: &SpotResultDocument) -> Markup {
    let profile = result
        .analysis_settings
        .as_ref()
        .and_then(|s| s.instrument_profile.as_ref());
    let range = |r: Option<[f64; 2]>, digits: usize| {
        r.map_or_else(
            || "—".to_string(),
            |[lo, hi]| format!("{lo:.digits$} – {hi:.digits$}"),
        )
    };
    html! {
        h3 { "Instrument" } "
    "
        @if let Some(p) = profile {
            table {
                (field_row("profile", html! { span.hash { (Text(&p.sha256)) } }))
                (field_row("measured", Text(&format!("{} on instrument {}, {:.0} days before this analysis", p.measured_at, p.serial_number, p.age_days))))
                (field_row("detector response", format!("measured on black glass: FWHM {:.3}°, {} steps of {:.3}°", p.fwhm_deg, p.shares.len(), p.step_deg)))
                (field_row("arm zero", format!("{} (± {:.4}°)", p.arm_zero_deg.iter().map(|(t, z)| format!("{z:+.4}° at {t}°")).collect::<Vec<_>>().join(", "), p.arm_zero_u_deg)))
            } "
    "
            @if let Some(gloss) = &result.gloss {
                table {
                    tr { th { "gloss geometry" } th { "gloss (GU)" } } "
    "
                    @for g in gloss {
                        tr { td { (Text(&g.geometry)) } td.num { (format!("{:.1} ± {:.1}", g.gloss_units, 1.96 * g.u_gloss_units)) } } "
    "
                    }
                } "
    "
                p.note { "Specular gloss from the fitted model through each standard's apertures, 100 GU being its primary black glass (95 % intervals from the fit's covariance); the geometries whose receptor the arms reach." } "
    "
            }
        } @else {
            p { "No instrument profile was in force: the detector's response was taken as the declared top-hat and the arm zero as declared (flag instrument-declared). " }
            @if let Some(b) = &result.instrument_bound {
                table {
                    (field_row("σ through the bound (°)", range(b.sigma_deg, 3)))
                    (field_row("ρs through the bound", range(b.rho_s, 3)))
                    (field_row("ρd through the bound", range(b.rho_d, 4)))
                    (field_row("class at each width", Text(&b.widths_deg.iter().zip(&b.classes).map(|(w, c)| format!("{c} at {w}°")).collect::<Vec<_>>().join(", "))))
                } "
    "
                p.note { "The intervals above hold for the declared response; these ranges hold the 95 % intervals through a point detector and a 3° top-hat too (gonio characterize measures the response and narrows them)." } "
    "
            }
        }
    }
}

/// The class with its confidence and nearest reference, or why it was not decided.
fn class_paragraph(r: &ResultDocument) -> Markup {
    html! {
        h3 { "Class" } "\n"
        @match (&r.class, r.class_confidence) {
            (Some(class), Some(c)) => {
                p {
                    strong { (Text(class)) }
                    ", confidence " (format!("{c:.2}"))
                    ": the share of the parameters' uncertainty region (their fitted covariance) that lies in this class of the paper's tree. 0.95 or more reads as settled; a fit flagged lack-of-fit is capped at 0.90. Nearest reference paper of Table 6: "
                    (Text(r.nearest_reference.as_deref().unwrap_or("?")))
                    " (" (number(r.nearest_reference_distance, 1))
                    " combined standard uncertainties away)."
                }
            }
            _ => {
                p {
                    strong { "undecided" } ": "
                    (Text(r.class_undecided.as_deref().unwrap_or("the readings did not decide the class")))
                }
            }
        }
        "\n"
    }
}

/// σ, ρs, ρd and η with their 95 % intervals, and what the readings did not determine.
fn parameters_table(r: &ResultDocument) -> Markup {
    let rows = [
        ("σ, lobe width (degrees)", "sigma_deg", r.sigma_deg, 3),
        ("ρs, specular weight", "rho_s", r.rho_s, 4),
        ("ρd, diffuse (Lambert) weight", "rho_d", r.rho_d, 4),
        ("η, refractive index", "eta", r.eta, 3),
    ];
    let not_identified: Vec<String> = r
        .not_identified
        .iter()
        .map(|u| serde_json::to_string(u).unwrap_or_default())
        .collect();
    html! {
        h3 { "Parameters" } "\n"
        table {
            "\n"
            tr {
                th { "parameter" } th { "value" }
                th { "95 % interval, lower" } th { "95 % interval, upper" }
            }
            "\n"
            @for (label, key, value, digits) in rows {
                @let ci = r.ci95.of(key).unwrap_or_default();
                // Two significant digits of the uncertainty where an interval exists.
                @let digits = match ci {
                    [Some(lo), Some(hi)] => crate::analysis::result::interval_decimals(lo, hi).unwrap_or(digits),
                    _ => digits,
                };
                tr {
                    td { (Text(label)) " (" code { (key) } ")" }
                    td class="num" { (number(value, digits)) }
                    @if r.model.iter().any(|n| n == key) {
                        td class="num" { (number(ci[0], digits)) }
                        td class="num" { (number(ci[1], digits)) }
                    } @else {
                        td class="num" { "fixed, not fitted" }
                        td class="num" {}
                    }
                }
                "\n"
            }
        }
        "\n"
        @if !not_identified.is_empty() {
            p class="note" { "Not identified: " (Text(&not_identified.join("; "))) } "\n"
        }
    }
}

/// The σ_l check and the goodness of fit, with the geometries and the device time.
fn sampling_table(result: &SpotResultDocument, doc: &SessionDoc) -> Markup {
    let r = &result.analysis;
    let sigma_ok = if r.sigma_ok {
        "yes"
    } else {
        "NO: the geometries were not fine enough for the fitted peak"
    };
    let chi2 = match (r.chi2, r.gof_p) {
        (Some(c), Some(p)) => format!("χ² = {c:.1} on {} degrees of freedom, p = {p:.3}", r.dof),
        _ => "no χ² (the readings carry no uncertainty of their own)".into(),
    };
    let structure = r
        .structure
        .as_ref()
        .and_then(|s| s.p_value)
        .map_or("not run".to_string(), |p| format!("p = {p:.3}"));
    let lack_of_fit = if r.lack_of_fit {
        "YES: the model does not describe these readings"
    } else {
        "no"
    };
    // The readings' own count (issue 31: a sweep's blanked bins were counted as
    // geometries, "1400" for a fit and readings.csv of 1,385), and the readings taken.
    let readings = recorded_readings(doc);
    let usable = readings
        .iter()
        .filter(|p| !p.superseded && p.radiance_factor.is_some())
        .count();
    let geometries = if readings.is_empty() {
        result
            .geometries
            .map_or_else(|| "null".to_string(), |g| format!("{g} geometries"))
    } else if readings.len() > usable {
        format!(
            "{usable} geometries (of {} readings taken; {} not usable: blanked sweep bins, readings superseded after lost steps or not convertible)",
            readings.len(),
            readings.len() - usable
        )
    } else {
        format!("{usable} geometries")
    };
    html! {
        h3 { "Sampling and goodness of fit" } "\n"
        table {
            "\n"
            (field_row("σ > σ_l", format!(
                "{sigma_ok} (σ_l = {}°, δ = {}°)",
                number(r.sigma_l_deg, 3),
                number(r.delta_deg, 3)
            )))
            (field_row("NMAE", format!(
                "{} % (mean absolute residual over the mean radiance factor)",
                number(Some(100.0 * r.nmae).filter(|v| v.is_finite()), 2)
            )))
            (field_row("RMS residual", format!(
                "{} (radiance factor, dimensionless)",
                number(Some(r.rms).filter(|v| v.is_finite()), 5)
            )))
            (field_row("χ² test", chi2))
            (field_row("residual structure test", structure))
            (field_row("lack of fit", lack_of_fit))
            (field_row("geometries, device time", format!(
                "{geometries}, {} s measuring (+{} s homing and calibration)",
                number(result.device_seconds, 1),
                number(result.setup_seconds, 1)
            )))
        }
        "\n"
    }
}

/// Each kind of error's share of the variance of σ, ρs and ρd (when there is more than
/// the readings' noise).
fn budget_table(r: &ResultDocument) -> Markup {
    let kinds = Budget::deserialize(&r.budget)
        .map(|b| b.by_kind)
        .unwrap_or_default();
    if kinds.len() <= 1 {
        return html! {};
    }
    let share = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{:.1} %", 100.0 * v));
    html! {
        h3 { "Uncertainty budget" } "\n"
        p class="note" { "Each kind of error's share of the variance of σ, ρs and ρd." } "\n"
        table {
            "\n"
            tr { th { "error" } th { "σ" } th { "ρs" } th { "ρd" } } "\n"
            @for k in &kinds {
                (row(&[
                    html! { (Text(k.kind.as_deref().unwrap_or("?"))) },
                    html! { (share(k.share.sigma_deg)) },
                    html! { (share(k.share.rho_s)) },
                    html! { (share(k.share.rho_d)) },
                ]))
            }
        }
        "\n"
    }
}

/// The part of the result's uncertainty budget the report shows.
#[derive(Debug, Default, Deserialize)]
#[serde(default)]
struct Budget {
    /// Each kind's share of the variance.
    by_kind: Vec<KindShare>,
}

/// One kind of error's share of the variance of σ, ρs and ρd.
#[derive(Debug, Default, Deserialize)]
#[serde(default)]
struct KindShare {
    /// The kind.
    kind: Option<String>,
    /// Its shares.
    share: Shares,
}

/// A share of the variance of σ, ρs and ρd (`null`: not determined).
#[derive(Debug, Default, Deserialize)]
#[serde(default)]
struct Shares {
    rho_d: Option<f64>,
    rho_s: Option<f64>,
    sigma_deg: Option<f64>,
}

/// The plots the session drew, inline.
fn plots(dir: &Path) -> Result<Markup, ReportError> {
    let read_error = |path: PathBuf| move |source| ReportError::Read { path, source };
    let mut names: Vec<String> = crate::output::folder::entries(dir)
        .map_err(read_error(dir.to_path_buf()))?
        .into_iter()
        .filter(|n| n.starts_with("fig") && n.ends_with(".svg"))
        .collect();
    names.sort();
    let mut figures = Vec::new();
    for name in names {
        let path = dir.join(&name);
        let svg = std::fs::read_to_string(&path).map_err(read_error(path))?;
        figures.push((inline_svg(&svg), name));
    }
    Ok(html! {
        @if !figures.is_empty() {
            h3 { "Plots" } "\n"
            div class="plots" {
                "\n"
                @for (svg, name) in &figures {
                    // The SVG as plotters wrote it: gonio's own markup.
                    figure { (PreEscaped(svg)) figcaption { (Text(name)) } } "\n"
                }
            }
            "\n"
        }
    })
}

/// The SVG as plotters wrote it, without an XML declaration (not allowed inline).
fn inline_svg(svg: &str) -> String {
    let svg = svg.trim_start_matches(|c: char| c != '<');
    let svg = if svg.starts_with("<?xml") {
        svg.split_once("?>").map_or(svg, |(_, rest)| rest)
    } else {
        svg
    };
    svg.trim().to_string()
}

/// The readings `session.json` records (empty when it holds none that can be read).
fn recorded_readings(doc: &SessionDoc) -> Vec<crate::session::MeasuredPoint> {
    doc.rest
        .get("readings")
        .and_then(|r| serde_json::from_value(r.clone()).ok())
        .unwrap_or_default()
}

/// The plan's integration time as the readings had it: the point readings' setting, and
/// for sweep bins (the detector's time while the arm crossed each bin, set by the arm's
/// speed, not by the setting) their range and median (issue 31: "integration 100 ms" was
/// stated of sweeps whose bins were 1–34 ms).
fn integration_text(docs: &[&SessionDoc]) -> String {
    let Some(first) = docs.first() else {
        return String::new();
    };
    let setting = first.plan.integration_ms;
    let mut points = 0usize;
    let mut bins_ms: Vec<u16> = Vec::new();
    for doc in docs {
        for p in recorded_readings(doc) {
            if p.superseded || p.radiance_factor.is_none() {
                continue;
            }
            if p.theta_r_span_deg > 0.0 {
                bins_ms.push(p.reading.integration_ms);
            } else {
                points += 1;
            }
        }
    }
    if bins_ms.is_empty() {
        return format!("integration {setting} ms");
    }
    bins_ms.sort_unstable();
    let bins = format!(
        "sweep bins integrated {}–{} ms each (median {} ms: the detector's time while the arm crossed the bin)",
        bins_ms[0],
        bins_ms[bins_ms.len() - 1],
        bins_ms[bins_ms.len() / 2]
    );
    if points > 0 {
        format!("integration {setting} ms for the point readings; {bins}")
    } else {
        bins
    }
}

fn instrument_section(doc: &SessionDoc, docs: &[&SessionDoc]) -> Markup {
    let i = &doc.instrument;
    html! {
        table {
            "\n"
            (field_row("serial number", Text(&i.serial_number)))
            (field_row("board", Text(&i.board)))
            (field_row("firmware", Text(&i.firmware_version)))
            @if let Some(sim) = &i.simulated_sample {
                (field_row("simulated instrument", html! {
                    "yes: its scene is the sample '" (Text(sim)) "' (not a real measurement)"
                }))
            }
            (field_row("plan", html! {
                "policy " (Text(&doc.plan.policy))
                ", " (integration_text(docs))
                ", detector acceptance " (format!("{}", doc.plan.acceptance_deg)) "°"
            }))
        }
        "\n"
    }
}

fn calibration_section(
    calibration: Result<Option<&Calibration>, &Finding>,
    doc: &SessionDoc,
) -> Markup {
    let c: &Calibration = match calibration {
        Ok(Some(c)) => c,
        Ok(None) => return html! { p { "No calibration file." } "\n" },
        Err(p) => {
            return html! {
                p class="note" { "The calibration file cannot be read: " (Text(&p.to_string())) } "\n"
            };
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
    html! {
        table {
            "\n"
            (field_row("taken", html! { (taken) " on " (Text(&c.instrument)) }))
            (field_row("age when the session ended", age))
            (field_row("white tile", format!(
                "certified radiance factor {:.4}, standard uncertainty {:.2} %",
                c.white_radiance_factor,
                100.0 * c.white_relative_uncertainty
            )))
            (field_row("tile certificate", certificate(c)))
            (field_row("white readings", format!(
                "{} incidence angles; dark readings on {} ranges",
                c.white.len(),
                c.dark.len()
            )))
        }
        "\n"
    }
}

/// The white tile's certificate, or that there was none.
fn certificate(c: &Calibration) -> Markup {
    let Some(cert) = &c.white_certificate else {
        return html! {
            "none given: the tile's values were entered on the command line or are gonio's defaults (an assumption, not a certificate)"
        };
    };
    html! {
        "tile " (Text(&cert.tile)) ", certificate " (Text(&cert.certificate))
        @if let Some(by) = &cert.issued_by { " by " (Text(by)) }
        ", issued " (Text(&cert.issued))
        @if let Some(until) = &cert.valid_until { ", valid until " (Text(until)) }
        ": radiance factor " (format!("{}", cert.radiance_factor))
        " ± " (format!("{}", cert.expanded_uncertainty))
        " (expanded, k = " (format!("{}", cert.coverage_factor))
        "); file SHA-256 " (Text(cert.file_sha256.as_deref().unwrap_or("not recorded")))
    }
}

/// Every run of the session with its decisions, under headings of `level`.
fn decisions_section(doc: &SessionDoc, level: u8) -> Markup {
    html! {
        @for run in &doc.runs {
            (heading(level, html! {
                "Run " (run.run) ": " (Text(&run.started))
                " to " (Text(run.ended.as_deref().unwrap_or("not closed")))
                " (" (format!("{:?}", run.outcome))
                @if let Some(why) = &run.why { ": " (Text(why)) }
                ")"
            }))
            "\n"
            (decision_list(&run.decisions))
        }
    }
}

/// Decisions in order.
fn decision_list(decisions: &[String]) -> Markup {
    html! {
        ol class="decisions" {
            "\n"
            @for d in decisions { li { (Text(d)) } "\n" }
        }
        "\n"
    }
}

fn flags_section(flags: &[Flag]) -> Markup {
    if flags.is_empty() {
        return html! { p { "None." } "\n" };
    }
    html! {
        ul {
            "\n"
            @for f in flags {
                li { code { (f.name()) } ": " (Text(flag_meaning(*f))) } "\n"
            }
        }
        "\n"
    }
}

/// The files of the folder with their SHA-256, as its manifest lists them.
fn files_section(dir: &Path) -> Markup {
    let Ok(text) = std::fs::read_to_string(dir.join(MANIFEST)) else {
        return html! { p { "No " (MANIFEST) ": the folder is not finished." } "\n" };
    };
    html! {
        p class="note" {
            "As " (MANIFEST) " lists them (" code { "gonio verify" }
            " checks them, and that this report is the one they give: the report is drawn from them, so it cannot list itself)."
        }
        "\n"
        table {
            "\n"
            tr { th { "file" } th { "SHA-256" } } "\n"
            @for (hash, name) in text.lines().filter_map(|line| line.split_once("  ")) {
                tr { td { (Text(name)) } td class="hash" { (Text(hash)) } } "\n"
            }
        }
        "\n"
    }
}

fn verdict(ok: bool, flags: &[Flag]) -> Markup {
    let names = flags
        .iter()
        .map(|f| f.name())
        .collect::<Vec<_>>()
        .join(", ");
    html! {
        @if ok {
            p class="verdict ok" {
                "Result: clean"
                @if !flags.is_empty() { " (noted: " (names) ")" }
            }
        } @else {
            p class="verdict flagged" { "Result NOT CLEAN — flags: " (names) }
        }
        "\n"
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

/// The session's `ok` and `flags` (not clean and none when absent or unreadable).
fn outcome_of(doc: &SessionDoc) -> (bool, Vec<Flag>) {
    let outcome = doc.outcome();
    (
        outcome.ok().unwrap_or(false),
        outcome.flags().unwrap_or_default().to_vec(),
    )
}

/// The report of the finished session folder `dir`, from its documents as read.
fn session_html(
    dir: &Path,
    doc: &SessionDoc,
    calibration: Result<Option<&Calibration>, &Finding>,
) -> Result<String, ReportError> {
    let (ok, flags) = outcome_of(doc);
    let body = html! {
        h1 { "Sample " (Text(&doc.sample)) } "\n"
        p class="note" { "gonio session report of the folder " (Text(&folder_name(dir))) } "\n"
        (verdict(ok, &flags))
        h2 { "Case" } "\n"
        (case_section(doc.case.as_ref()))
        h2 { "Instrument" } "\n"
        (instrument_section(doc, &[doc]))
        h2 { "Calibration" } "\n"
        (calibration_section(calibration, doc))
        h2 { "Result" } "\n"
        (result_section(dir, doc)?)
        h2 { "Flags" } "\n"
        (flags_section(&flags))
        h2 { "Decisions" } "\n"
        (decisions_section(doc, 3))
        h2 { "Files" } "\n"
        (files_section(dir))
        (glossary())
    };
    Ok(page(&format!("gonio report: {}", doc.sample), body))
}

/// The report of a finished sheet folder (several spots), from its documents as read.
fn sheet_html(read: &ReadSheet) -> Result<String, ReportError> {
    let dir = read.dir.as_path();
    let summary = &read.summary;
    let first = read
        .spots
        .first()
        .ok_or_else(|| ReportError::NoSpots(dir.to_path_buf()))?;
    let first_doc = &first.doc;
    let body = html! {
        h1 { "Sample " (Text(&read.doc.sample)) ": a sheet of " (read.spots.len()) " spots" } "\n"
        p class="note" { "gonio sheet report of the folder " (Text(&folder_name(dir))) } "\n"
        (verdict(summary.ok(), &summary.flags))
        h2 { "Case" } "\n"
        (case_section(read.doc.case.as_ref().or(first_doc.case.as_ref())))
        h2 { "Instrument" } "\n"
        (instrument_section(first_doc, &read.spots.iter().map(|s| &s.doc).collect::<Vec<_>>()))
        h2 { "Calibration (shared by every spot)" } "\n"
        (calibration_section(first.calibration.as_ref().map(Option::as_ref), first_doc))
        (sheet_section(read))
        h2 { "Flags" } "\n"
        (flags_section(&summary.flags))
        h2 { "Decisions of the sheet" } "\n"
        (decision_list(&read.doc.decisions))
        @for s in &read.spots {
            (spot_section(s)?)
        }
        h2 { "Files" } "\n"
        (files_section(dir))
        (glossary())
    };
    Ok(page(
        &format!(
            "gonio report: {} ({} spots)",
            read.doc.sample,
            read.spots.len()
        ),
        body,
    ))
}

/// The sheet's mean and spread, and each spot's values and verdict.
fn sheet_section(read: &ReadSheet) -> Markup {
    let summary = &read.summary;
    html! {
        h2 { "The sheet" } "\n"
        @if let Some(answer) = &summary.answer { (answer_section(answer)) }
        table {
            "\n"
            tr {
                th { "parameter" } th { "geometric mean of the accepted spots" }
                th { "spot-to-spot relative sd" }
            }
            "\n"
            @for (i, label) in ["σ (degrees)", "ρs", "ρd"].iter().enumerate() {
                (row(&[
                    html! { (label) },
                    html! { (number(summary.mean[i], 4)) },
                    html! {
                        (summary.within_relative_sd.map_or("unknown (one spot)".to_string(), |sd| {
                            format!("{:.1} %", 100.0 * sd[i])
                        }))
                    },
                ]))
            }
        }
        "\n"
        p {
            (read.counts().sentence()) "."
        }
        "\n"
        table {
            "\n"
            tr {
                th { "spot" } th { "class" } th { "σ (deg)" } th { "ρs" } th { "ρd" }
                th { "flags" } th { "verdict" }
            }
            "\n"
            @for s in &read.spots { (spot_row(summary, s)) }
        }
        "\n"
        @for note in &summary.notes { p class="note" { (Text(note)) } "\n" }
    }
}

/// The sheet's answer: its class and confidence, the mean's 95 % intervals, the spots left
/// out, and a warning when the spots disagree in class.
fn answer_section(answer: &crate::analysis::spots::SheetAnswer) -> Markup {
    let interval = |i: Option<[f64; 2]>, digits: usize| {
        i.map_or_else(
            || "—".to_string(),
            |[lo, hi]| format!("{lo:.digits$} – {hi:.digits$}"),
        )
    };
    html! {
        p class="answer" {
            "The sheet's class: " strong { (answer.class.as_deref().unwrap_or("undecided")) }
            @if let Some(c) = answer.class_confidence { ", confidence " (format!("{c:.2}")) }
            @if let Some(why) = &answer.undecided { " (" (Text(why)) ")" }
            " — from the mean of its accepted spots, the spot-to-spot variation in its uncertainty"
            @if answer.excluded > 0 { "; " (answer.excluded) " flagged spot(s) left out" }
            "."
        }
        "\n"
        @if let Some(disagree) = &answer.spots_disagree {
            p class="verdict flagged" { "Warning (spots-disagree): " (Text(disagree)) "." } "\n"
        }
        table {
            "\n"
            tr { th { "parameter" } th { "95 % interval of the sheet's mean" } }
            "\n"
            (row(&[html! { "σ (degrees)" }, html! { (interval(answer.ci95.sigma_deg, 3)) }]))
            (row(&[html! { "ρs" }, html! { (interval(answer.ci95.rho_s, 4)) }]))
            (row(&[html! { "ρd" }, html! { (interval(answer.ci95.rho_d, 4)) }]))
        }
        "\n"
    }
}

/// A spot's line of the sheet's table.
fn spot_row(
    summary: &crate::analysis::spots::SheetSummary,
    s: &crate::output::folder::sheet::ReadSpot,
) -> Markup {
    let number = s.result.number;
    let verdict = html! {
        (Text(&crate::analysis::spots::SpotCounts::verdict_words(
            summary.verdicts.iter().find(|j| j.number == number).map(|j| &j.verdict),
            &s.result.flags,
        )))
    };
    let v = |i: usize, digits: usize| html! { (self::number(s.session.values[i], digits)) };
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
    row(&[
        html! { a href=(format!("#spot-{number}")) { (number) } },
        html! { (Text(s.session.class.as_deref().unwrap_or("undecided"))) },
        v(0, 3),
        v(1, 4),
        v(2, 4),
        html! { (flags) },
        verdict,
    ])
}

/// A spot of a sheet: its verdict, result and decisions.
fn spot_section(s: &crate::output::folder::sheet::ReadSpot) -> Result<Markup, ReportError> {
    let doc = &s.doc;
    let (ok, flags) = outcome_of(doc);
    let number = s.result.number;
    Ok(html! {
        h2 id=(format!("spot-{number}")) { "Spot " (number) } "\n"
        (verdict(ok, &flags))
        (result_section(&s.dir, doc)?)
        h3 { "Decisions" } "\n"
        (decisions_section(doc, 4))
    })
}

/// The report of a finished session or sheet folder.
pub fn html(dir: &Path) -> Result<String, ReportError> {
    if crate::output::folder::is_sheet_folder(dir) {
        let read = crate::output::folder::sheet::read_sheet(dir)?;
        return draw(&ReadFolder::Sheet(&read));
    }
    let doc = crate::output::folder::require_finished(dir)?;
    let calibration = crate::output::folder::read_calibration(dir);
    draw(&ReadFolder::Session {
        dir,
        doc: &doc,
        calibration: calibration.as_ref().map(Option::as_ref),
    })
}

/// The report of a finished folder already read (what `gonio verify` checks
/// `report.html` against, drawn from the documents it checked).
pub fn draw(folder: &ReadFolder) -> Result<String, ReportError> {
    match folder {
        ReadFolder::Session {
            dir,
            doc,
            calibration,
        } => session_html(dir, doc, *calibration),
        ReadFolder::Sheet(read) => sheet_html(read),
    }
}

fn glossary() -> Markup {
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
    html! {
        h2 { "Glossary" } "\n"
        dl {
            "\n"
            @for (term, meaning) in terms {
                dt { strong { (Text(term)) } } dd { (Text(meaning)) } "\n"
            }
        }
        "\n"
    }
}

/// Draw the report of the finished folder `dir` into `dir/report.html` (atomically: a
/// temporary file in the folder, renamed into place). Returns its path.
pub fn write_into(dir: &Path) -> Result<PathBuf, ReportError> {
    write_html(dir, &html(dir)?)
}

/// What `gonio verify` finds wrong with `dir`, but for its `report.html`: the report is
/// what is being drawn anew (the way to repair a stale one).
///
/// A signature that does not hold is among them, and so is a signer whose key is neither
/// the user's nor trusted ([`crate::output::folder::signature::untrusted_signers`]): a report is
/// not drawn as the session's from a folder that someone else could have re-signed.
pub fn problems(dir: &Path) -> Vec<Finding> {
    problems_and_read(dir).0
}

/// A folder as the check read it, when it verified.
enum Checked {
    // Boxed: both are large (a session document, a sheet of them).
    Session(Box<crate::output::folder::verify::Verified>),
    Sheet(Box<crate::output::folder::verify::VerifiedSheet>),
}

impl Checked {
    /// The report of the folder as read.
    fn draw(&self) -> Result<String, ReportError> {
        match self {
            Checked::Session(v) => draw(&ReadFolder::Session {
                dir: &v.dir,
                doc: &v.doc,
                calibration: Ok(v.calibration.as_ref()),
            }),
            Checked::Sheet(v) => draw(&ReadFolder::Sheet(&v.sheet)),
        }
    }
}

/// [`problems`], and the folder as that check read it when it verified (`None` when it did
/// not: then the folder is read again to draw its report).
fn problems_and_read(dir: &Path) -> (Vec<Finding>, Option<Checked>) {
    use crate::output::folder::signature::untrusted_signers;
    let (found, read) = if crate::output::folder::is_sheet_folder(dir) {
        match crate::output::folder::verify::verify_sheet(dir, draw) {
            Ok(v) => (
                untrusted_signers(
                    std::iter::once((dir, v.signed.as_ref()))
                        .chain(v.spots.iter().map(|s| (s.dir.as_path(), s.signed.as_ref()))),
                ),
                Some(Checked::Sheet(Box::new(v))),
            ),
            Err(found) => (found, None),
        }
    } else {
        match crate::output::folder::verify::verify(dir, draw) {
            Ok(v) => (
                untrusted_signers(std::iter::once((dir, v.signed.as_ref()))),
                Some(Checked::Session(Box::new(v))),
            ),
            Err(found) => (found, None),
        }
    };
    let found = found
        .into_iter()
        .filter(|p| p.file.file_name() != Some(std::ffi::OsStr::new(REPORT)))
        .collect();
    (found, read)
}

/// Draw the report of `dir` into `dir/report.html` when the folder verifies
/// ([`problems`]); when it does not, refuse ([`ReportError::DoesNotVerify`]), or with
/// `unverified` draw it with a banner at its top naming every problem, so that no one
/// reads changed data as the session's. Returns the path and the problems.
pub fn write_verified(
    dir: &Path,
    unverified: bool,
) -> Result<(PathBuf, Vec<Finding>), ReportError> {
    let (problems, read) = problems_and_read(dir);
    if problems.is_empty() {
        // Drawn from the folder as the check read it, when it verified.
        let drawn = match read {
            Some(read) => read.draw()?,
            None => html(dir)?,
        };
        return Ok((write_html(dir, &drawn)?, problems));
    }
    if !unverified {
        return Err(ReportError::DoesNotVerify {
            dir: dir.to_path_buf(),
            problems,
        });
    }
    let banner = html! {
        div class="verdict flagged" id="unverified" {
            p { strong { "This folder does not verify: " } "its files are not as the session left them, so what follows may not be what was measured." }
            ul { @for p in &problems { li { (Text(&p.to_string())) } } }
        }
        "\n"
    };
    let drawn = html(dir)?;
    // Right after <body>: the first thing read, and printed on the first page.
    let marked = match drawn.split_once("<body>\n") {
        Some((head, body)) => format!("{head}<body>\n{}{body}", banner.into_string()),
        None => format!("{}{drawn}", banner.into_string()),
    };
    Ok((write_html(dir, &marked)?, problems))
}

fn write_html(dir: &Path, html: &str) -> Result<PathBuf, ReportError> {
    let path = dir.join(REPORT);
    let temp = dir.join(crate::output::folder::temp_name(REPORT));
    crate::output::folder::store::create_in_folder(&temp)
        .and_then(|mut file| std::io::Write::write_all(&mut file, html.as_bytes()))
        .map_err(|source| ReportError::Write {
            path: temp.clone(),
            source,
        })?;
    std::fs::rename(&temp, &path).map_err(|source| ReportError::Write {
        path: path.clone(),
        source,
    })?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_escaped_as_the_report_always_has() {
        let text = html! { (Text("<b>O'Brien & \"co\"</b>")) }.into_string();
        assert_eq!(text, "&lt;b&gt;O&#39;Brien &amp; &quot;co&quot;&lt;/b&gt;");
    }

    #[test]
    fn the_page_is_laid_out_one_element_a_line() {
        let page = page("a 'title'", html! { p { "x" } "\n" });
        let head = format!(
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<meta name=\"generator\" content=\"gonio {}\">\n<title>a &#39;title&#39;</title>\n<style>\nbody {{",
            env!("CARGO_PKG_VERSION")
        );
        assert!(page.starts_with(&head), "{page}");
        assert!(page.ends_with("}\n</style>\n</head>\n<body>\n<p>x</p>\n</body>\n</html>\n"));
    }

    #[test]
    fn rows_are_one_a_line() {
        let cells = [html! { "a" }, html! { (Text("<")) }];
        assert_eq!(
            row(&cells).into_string(),
            "<tr><td>a</td><td>&lt;</td></tr>\n"
        );
        assert_eq!(
            field_row("σ > σ_l", "yes").into_string(),
            "<tr><th>σ &gt; σ_l</th><td>yes</td></tr>\n"
        );
    }
}
