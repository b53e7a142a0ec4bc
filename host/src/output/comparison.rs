//! What `gonio compare` reports, as one typed document: the propositions, the bounded
//! likelihood ratio and its verbal equivalent, the population and its assumptions, every
//! warning, both sheets and the audit trail; printed as JSON (`--json`), as text, or as a
//! self-contained HTML page in the style of the session report (`--report FILE`).
use crate::analysis::evidence::{
    self, Evidence, PARAM_LABELS, PARAMS, Population, PopulationSource, ReportedRatio, Warning,
};
use crate::output::folder::CaseRecord;
use crate::output::folder::sheet::MeasuredSheet;
use crate::output::report::{Text, field_row, page};
use maud::{Markup, html};
use serde::Serialize;
use std::collections::BTreeMap;

/// The label every output of the demonstration population carries.
pub(crate) const DEMONSTRATION_LABEL: &str = "for demonstration, not evidence";

/// The population a comparison was weighed against, as the examiner is told of it.
#[derive(Clone, Debug)]
pub struct PopulationInUse {
    /// The population.
    pub population: Population,
    /// What it is: the library file, or "the demonstration population".
    pub name: String,
    /// Why it has no validation, when it has none.
    pub not_validated_because: Option<String>,
    /// How the sheets of each stock lay (stock, its sheets' lays, ordered by name), when the
    /// population is a library's: a sheet is weighed against them with a warning where
    /// they were measured otherwise ([`evidence::stock_lay_warnings`]). `None` for the
    /// demonstration population, whose stocks are no measured sheets.
    pub stock_lays: Option<Vec<(String, Vec<crate::analysis::specimen::SheetLay>)>>,
    /// The state of the library the population was made from, when it is a library's.
    pub library_state: Option<LibraryState>,
}

/// The state of a library a search or comparison weighed against: enough to recover its
/// contents later from the library's audit trail (`gonio library history --contents-at`).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct LibraryState {
    /// The last audit entry of the state read (`None`: the trail was empty).
    pub audit_entry: Option<i64>,
    /// The contents identity of the sheets weighed (`evidence::population::contents_identity`).
    pub contents: String,
    /// Sessions of the library left out (the questioned sheet itself, when it is in it).
    pub left_out_sessions: Vec<String>,
}

impl PopulationInUse {
    /// `warnings` with the population's own reason for not being validated: replacing the
    /// general one, or added when the population was validated only for this use.
    pub fn warnings(&self, warnings: &[Warning]) -> Vec<Warning> {
        let mut out = warnings.to_vec();
        let Some(why) = &self.not_validated_because else {
            return out;
        };
        let mut said = false;
        for w in out.iter_mut() {
            if let Warning::NotValidated { why: w } = w {
                *w = why.clone();
                said = true;
            }
        }
        if !said {
            out.push(Warning::NotValidated { why: why.clone() });
        }
        out
    }

    /// Whether sheet `side`, laid as `lay`, was measured as the population's stocks were
    /// ([`evidence::stock_lay_warnings`] over the stocks the population holds); nothing for
    /// the demonstration population.
    pub fn lay_warnings(
        &self,
        side: evidence::Side,
        lay: crate::analysis::specimen::SheetLay,
    ) -> Vec<Warning> {
        let Some(stock_lays) = &self.stock_lays else {
            return Vec::new();
        };
        let held: std::collections::HashSet<&str> = self
            .population
            .stocks
            .iter()
            .map(|s| s.name.as_str())
            .collect();
        let stocks: Vec<(String, Vec<crate::analysis::specimen::SheetLay>)> = stock_lays
            .iter()
            .filter(|(name, _)| held.contains(name.as_str()))
            .cloned()
            .collect();
        evidence::stock_lay_warnings(side, lay, &stocks)
    }

    /// How the sheets of stock `name` lay: for orientation and side each, the one way all
    /// its sheets lay, `mixed`, or `unknown` (none recorded, or not a library's stock).
    pub fn stock_lay(&self, name: &str) -> (&'static str, &'static str) {
        use crate::analysis::specimen::{Orientation, Side};
        // By name, in order (made from a BTreeMap): a search of 20,000 stocks looked each
        // shown stock up; a linear scan made that quadratic (4.9 s of a 5 s search).
        let Some((_, lays)) = self.stock_lays.as_ref().and_then(|all| {
            all.binary_search_by(|(n, _)| n.as_str().cmp(name))
                .ok()
                .map(|k| &all[k])
        }) else {
            return ("unknown", "unknown");
        };
        fn one(mut values: impl Iterator<Item = Option<&'static str>>) -> &'static str {
            let first = values.next().flatten();
            match values.all(|v| v == first).then_some(first) {
                Some(Some(v)) => v,
                Some(None) => "unknown",
                None => "mixed",
            }
        }
        (
            one(lays.iter().map(|l| l.orientation.map(Orientation::name))),
            one(lays.iter().map(|l| l.side.map(Side::name))),
        )
    }
}

/// The propositions weighed.
#[derive(Clone, Debug, Serialize)]
pub struct Propositions {
    /// Hp.
    pub same: String,
    /// Hd.
    pub different: String,
}

/// One parameter's variation at each level, as relative standard deviations.
#[derive(Clone, Debug, Serialize)]
pub(crate) struct Level {
    /// σ, ρs, ρd, as the ratio uses them (upper confidence bounds when measured).
    pub(crate) relative_sd: BTreeMap<&'static str, f64>,
    /// Degrees of freedom behind them; 0: assumed, not measured.
    pub dof: usize,
}

/// The population as a report states it.
#[derive(Clone, Debug, Serialize)]
pub struct PopulationSummary {
    /// What it is.
    pub name: String,
    /// [`DEMONSTRATION_LABEL`] for the demonstration population.
    pub label: Option<&'static str>,
    /// SHA-256 of its parameters (stocks, variances, kernel, validation).
    pub identity: String,
    /// Where it came from, with its counts.
    pub source: PopulationSource,
    /// Its stocks.
    pub stocks: Vec<String>,
    /// Spots about their sheet's mean.
    pub(crate) spot_level: Level,
    /// Sheets about their stock's mean.
    pub(crate) sheet_level: Level,
    /// The kernel of the stock density about each stock.
    pub(crate) kernel_relative_sd: BTreeMap<&'static str, f64>,
    /// Its bandwidth, when chosen from the data.
    pub bandwidth: Option<f64>,
    /// Its validation: pairs, Cllr, bounds, calibrator.
    pub validation: Option<serde_json::Value>,
    /// Why it has none.
    pub not_validated_because: Option<String>,
    /// The state of the library it was made from (its last audit entry, the contents
    /// identity), when it is a library's: `gonio library history --contents-at` recovers
    /// those contents from the trail.
    pub library_state: Option<LibraryState>,
}

/// One side of a comparison.
#[derive(Clone, Debug, Serialize)]
pub struct Side {
    /// What was read.
    pub file: String,
    /// The sample.
    pub sample: String,
    /// The first spot's class (information only).
    pub class: Option<String>,
    /// Every accepted spot's class.
    pub(crate) spot_classes: Vec<Option<String>>,
    /// Spots weighed.
    pub n_spots: usize,
    /// The spots' relative standard deviations, when two or more.
    pub within_relative_sd: Option<[f64; 3]>,
    /// σ, ρs, ρd (geometric mean over spots).
    pub values: BTreeMap<&'static str, Option<f64>>,
    /// Their 95 % intervals.
    pub ci95: BTreeMap<&'static str, Option<(f64, f64)>>,
    /// The result's flags.
    pub flags: Vec<String>,
    /// The folder's identity (its manifest's SHA-256).
    pub identity: Option<String>,
    /// The instrument's serial number.
    pub instrument: Option<String>,
    /// The case, when given.
    pub case: Option<CaseRecord>,
    /// The sheet's orientation on the port: md, cd or unknown.
    pub orientation: &'static str,
    /// The side that faced the instrument: felt, wire or unknown.
    pub side: &'static str,
}

/// One parameter's raw log10 LR alone.
#[derive(Clone, Debug, Serialize)]
pub struct Contribution {
    /// The parameter.
    pub parameter: &'static str,
    /// Its log10 LR alone.
    pub log10_lr: f64,
}

/// Who computed it, when, with what.
#[derive(Clone, Debug, Serialize)]
pub struct Audit {
    /// gonio's version.
    pub(crate) gonio_version: &'static str,
    /// The command line.
    pub(crate) command_line: Vec<String>,
    /// When (UTC, RFC 3339).
    pub(crate) computed_at: String,
}

impl Audit {
    /// This process: its version, its arguments, now.
    pub fn now() -> Audit {
        Audit {
            gonio_version: env!("CARGO_PKG_VERSION"),
            command_line: std::env::args().collect(),
            computed_at: chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Secs, true),
        }
    }
}

/// `gonio compare`'s document (`gonio-compare/5`).
#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    /// [`crate::schema::COMPARE`].
    pub schema: &'static str,
    /// The propositions.
    pub propositions: Propositions,
    /// The likelihood ratio as reported (calibrated, within the validation's bounds, in
    /// words), its keys at this level of the document.
    #[serde(flatten)]
    pub ratio: ReportedRatio,
    /// Every warning, each with its `kind` and `message`.
    pub warnings: Vec<serde_json::Value>,
    /// The two sheets were measured in different (stated) orientations or sides: the
    /// comparison ran only because `--allow-lay-mismatch` was given, and its warnings
    /// (`lay-differs`) say which.
    pub lay_differs: bool,
    /// The population.
    pub population: PopulationSummary,
    /// Spots of A and B.
    pub n_spots: [usize; 2],
    /// Whether each side's own spots showed its scatter.
    pub(crate) within_sheet_variation_known: [bool; 2],
    /// The parameters compared.
    pub parameters: Vec<&'static str>,
    /// Those left out, with why.
    pub left_out: Vec<BTreeMap<&'static str, &'static str>>,
    /// Each parameter's raw log10 LR alone.
    pub contributions: Vec<Contribution>,
    /// Sheet A.
    pub a: Side,
    /// Sheet B.
    pub b: Side,
    /// Who, when, with what.
    pub audit: Audit,
    #[serde(skip)]
    warning_texts: Vec<String>,
}

fn per_param(values: [f64; 3]) -> BTreeMap<&'static str, f64> {
    PARAMS.iter().copied().zip(values).collect()
}

impl PopulationSummary {
    fn of(p: &PopulationInUse) -> PopulationSummary {
        let population = &p.population;
        let demonstration = population.is_demonstration();
        PopulationSummary {
            name: p.name.clone(),
            label: demonstration.then_some(DEMONSTRATION_LABEL),
            identity: population.identity(),
            source: population.source.clone(),
            stocks: population.stocks.iter().map(|s| s.name.clone()).collect(),
            spot_level: Level {
                relative_sd: per_param(population.spot.used_relative_sd()),
                dof: population.spot.dof,
            },
            sheet_level: Level {
                relative_sd: per_param(population.sheet.used_relative_sd()),
                dof: population.sheet.dof,
            },
            kernel_relative_sd: per_param(std::array::from_fn(|i| {
                population.kernel[i][i].max(0.0).exp_m1().sqrt()
            })),
            bandwidth: population.bandwidth,
            validation: population
                .validation
                .as_ref()
                .and_then(|v| serde_json::to_value(v).ok()),
            not_validated_because: p.not_validated_because.clone(),
            library_state: p.library_state.clone(),
        }
    }
}

/// Parameter `i` of a sheet: one spot's value, or the geometric mean of its spots.
fn value(r: &MeasuredSheet, i: usize) -> Option<f64> {
    match &r.summary {
        Some(summary) => summary.mean[i],
        None => r.sheet.spots.first().and_then(|s| s.values[i]),
    }
}

/// A 95 % interval of parameter `i` of the sheet's mean, if determined: ±1.96 standard
/// uncertainties of one spot's fit; for several spots, in log space from the spots' own
/// scatter over √n and their fits' mean relative variance (the calibration's share does
/// not average out).
fn interval(r: &MeasuredSheet, i: usize) -> Option<(f64, f64)> {
    let v = value(r, i)?;
    // The spots as reported: a sheet's own interval keeps what the evidence weighs
    // otherwise (the model-form widening).
    let spots = &r.reported.spots;
    if spots.len() == 1 {
        let var = spots[0].covariance[i][i];
        return (var >= 0.0 && var.is_finite())
            .then(|| (v - 1.96 * var.sqrt(), v + 1.96 * var.sqrt()));
    }
    let fit_relative_var = spots
        .iter()
        .map(|s| s.values[i].map_or(f64::NAN, |x| s.covariance[i][i] / (x * x)))
        .sum::<f64>()
        / spots.len() as f64;
    let scatter = r
        .summary
        .as_ref()
        .and_then(|s| s.within_log_covariance)
        .map_or(0.0, |c| c[i][i] / spots.len() as f64);
    let half = 1.96 * (fit_relative_var + scatter).sqrt();
    half.is_finite()
        .then(|| (v * (-half).exp(), v * half.exp()))
}

/// How a sheet lay on the port, as its case records it (unknown without one).
pub fn lay(r: &MeasuredSheet) -> crate::analysis::specimen::SheetLay {
    r.case.as_ref().map(CaseRecord::lay).unwrap_or_default()
}

/// A difference in how the two sheets lay, as a warning of the comparison: kind
/// `lay-differs` (both stated, different) or `lay-unknown` (one stated).
fn lay_warning(d: &crate::analysis::specimen::Difference) -> serde_json::Value {
    use crate::analysis::specimen::Difference;
    let (kind, what, a, b) = match d {
        Difference::Differs { what, a, b } => ("lay-differs", what, a, b),
        Difference::Unknown { what, a, b } => ("lay-unknown", what, a, b),
    };
    serde_json::json!({"kind": kind, "what": what, "a": a, "b": b, "message": d.to_string()})
}

impl Side {
    fn of(r: &MeasuredSheet) -> Side {
        Side {
            file: r.path.display().to_string(),
            sample: r.sample.clone(),
            class: r.classes.first().cloned().flatten(),
            spot_classes: r.classes.clone(),
            n_spots: r.sheet.spots.len(),
            within_relative_sd: r.summary.as_ref().and_then(|s| s.within_relative_sd),
            values: (0..3).map(|i| (PARAMS[i], value(r, i))).collect(),
            ci95: (0..3).map(|i| (PARAMS[i], interval(r, i))).collect(),
            flags: r.flags.clone(),
            identity: r.identity.clone(),
            instrument: r.instrument.clone(),
            case: r.case.clone(),
            orientation: crate::analysis::specimen::orientation_text(lay(r).orientation),
            side: crate::analysis::specimen::side_text(lay(r).side),
        }
    }

    fn cell(&self, i: usize) -> String {
        match (self.values[PARAMS[i]], self.ci95[PARAMS[i]]) {
            (Some(v), Some((lo, hi))) => format!("{v:.4} [{lo:.4}, {hi:.4}]"),
            (Some(v), None) => format!("{v:.4}"),
            _ => "not determined".to_string(),
        }
    }
}

impl Comparison {
    /// The document of A and B weighed against `population` as `e`.
    pub fn new(
        a: &MeasuredSheet,
        b: &MeasuredSheet,
        e: &Evidence,
        population: &PopulationInUse,
        audit: Audit,
    ) -> Comparison {
        let relevant = match &population.population.source {
            PopulationSource::Demonstration => {
                "the demonstration population (the eight reference papers of Akao et al. with assumed variations)".to_string()
            }
            PopulationSource::Library { stocks, .. } => {
                format!("the {stocks} stocks of the library {}", population.name)
            }
        };
        let mut warnings = population.warnings(&e.warnings);
        // Each sheet against the library's stocks, laid as they were or not.
        warnings.extend(population.lay_warnings(evidence::Side::A, lay(a)));
        warnings.extend(population.lay_warnings(evidence::Side::B, lay(b)));
        let lay_differences = crate::analysis::specimen::differences(lay(a), lay(b));
        Comparison {
            lay_differs: lay_differences.iter().any(|d| d.is_known()),
            schema: crate::schema::COMPARE,
            propositions: Propositions {
                same: "Hp: the two sheets come from one paper stock".to_string(),
                different: format!(
                    "Hd: the two sheets come from different stocks of the relevant population: {relevant}"
                ),
            },
            ratio: e.ratio.clone(),
            // How the sheets lay first: the ratio means little if they lay differently.
            warnings: lay_differences
                .iter()
                .map(lay_warning)
                .chain(warnings.iter().map(Warning::to_json))
                .collect(),
            warning_texts: lay_differences
                .iter()
                .map(|d| {
                    if d.is_known() {
                        format!("LAY DIFFERS: {d}")
                    } else {
                        d.to_string()
                    }
                })
                .chain(warnings.iter().map(ToString::to_string))
                .collect(),
            population: PopulationSummary::of(population),
            n_spots: [e.n_spots.0, e.n_spots.1],
            within_sheet_variation_known: [e.within_known.0, e.within_known.1],
            parameters: e.parameters.clone(),
            left_out: e
                .left_out
                .iter()
                .map(|(p, why)| BTreeMap::from([("parameter", *p), ("why", *why)]))
                .collect(),
            contributions: e
                .contributions
                .iter()
                .map(|&(parameter, log10_lr)| Contribution {
                    parameter,
                    log10_lr,
                })
                .collect(),
            a: Side::of(a),
            b: Side::of(b),
            audit,
        }
    }

    /// Whether it carries a warning.
    pub fn warned(&self) -> bool {
        !self.warnings.is_empty()
    }

    /// As JSON.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or_default()
    }

    fn bounds_text(&self) -> String {
        match self.ratio.bounds {
            Some((lo, hi)) => format!("[{lo:+.2}, {hi:+.2}]"),
            None => "none (not validated)".to_string(),
        }
    }

    /// The report for a terminal.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        if let Some(label) = self.population.label {
            s += &format!("** {} **\n", label.to_uppercase());
        }
        for (name, side) in [("A", &self.a), ("B", &self.b)] {
            s += &format!(
                "{name}  {}  sample {}  {} spot{}  orientation {}, side {}  class {}\n",
                side.file,
                side.sample,
                side.n_spots,
                if side.n_spots == 1 { "" } else { "s" },
                side.orientation,
                side.side,
                side.spot_classes
                    .iter()
                    .map(|c| c.as_deref().unwrap_or("undecided"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        s += &format!(
            "  {:<10} {:>34} {:>34}\n",
            "parameter", "A: value [95 % interval]", "B: value [95 % interval]"
        );
        for (i, label) in PARAM_LABELS.iter().enumerate() {
            s += &format!(
                "  {label:<10} {:>34} {:>34}\n",
                self.a.cell(i),
                self.b.cell(i)
            );
        }
        s += &format!(
            "  {}\n  {}\n",
            self.propositions.same, self.propositions.different
        );
        s += &format!(
            "  likelihood ratio (Hp : Hd): LR = 10^{:.2}  (log10 LR = {:+.2}; the model's own {:+.2}, calibrated {:+.2}, bounds {})\n",
            self.ratio.log10_lr,
            self.ratio.log10_lr,
            self.ratio.raw_log10_lr,
            self.ratio.calibrated_log10_lr,
            self.bounds_text()
        );
        s += &format!("  {}\n", self.ratio.verbal);
        if self.ratio.bounded {
            s += &format!(
                "  the calibrated ratio (log10 {:+.2}) is beyond what the population's validation supports: reported at its bound\n",
                self.ratio.calibrated_log10_lr
            );
        }
        if !self.contributions.is_empty() {
            let each: Vec<String> = self
                .contributions
                .iter()
                .map(|c| format!("{} {:+.2}", c.parameter, c.log10_lr))
                .collect();
            s += &format!(
                "  each parameter alone, the model's log10 LR: {} (correlated: they do not add up to the whole)\n",
                each.join(", ")
            );
        }
        for m in &self.left_out {
            s += &format!("  {} left out: {}\n", m["parameter"], m["why"]);
        }
        s += &format!("  population: {}\n", self.population_text());
        for (name, side) in [("A", &self.a), ("B", &self.b)] {
            if side.n_spots < 2 {
                s += &format!(
                    "  {name}: {} spot: its own within-sheet variation is unknown; the population's stands for it\n",
                    side.n_spots
                );
            }
        }
        for w in &self.warning_texts {
            s += &format!("  warning: {w}\n");
        }
        s += "  classes are shown for information: the evidence weighs the parameters, not the class boundaries\n";
        s
    }

    fn population_text(&self) -> String {
        let p = &self.population;
        let pct = |m: &BTreeMap<&'static str, f64>| {
            PARAMS
                .iter()
                .map(|k| format!("{:.1}", 100.0 * m[k]))
                .collect::<Vec<_>>()
                .join("/")
        };
        let counts = match &p.source {
            PopulationSource::Demonstration => "assumed figures".to_string(),
            PopulationSource::Library {
                stocks,
                lots,
                sheets,
                spots,
                ..
            } => format!("{stocks} stocks, {lots} lots, {sheets} sheets, {spots} spots"),
        };
        format!(
            "{} ({counts}; identity {}); per spot {} %, per sheet {} % (σ/ρs/ρd, {}), stock kernel {} %",
            p.name,
            &p.identity[..12.min(p.identity.len())],
            pct(&p.spot_level.relative_sd),
            pct(&p.sheet_level.relative_sd),
            if p.sheet_level.dof == 0 {
                "assumed".to_string()
            } else {
                format!("{} dof", p.sheet_level.dof)
            },
            pct(&p.kernel_relative_sd)
        )
    }

    /// The self-contained HTML page.
    pub fn to_html(&self) -> String {
        let title = format!("gonio compare: {} and {}", self.a.sample, self.b.sample);
        let side_rows = |side: &Side| -> Markup {
            html! {
                (field_row("file", html! { (Text(&side.file)) }))
                (field_row("sample", html! { (Text(&side.sample)) }))
                (field_row("spots", html! { (side.n_spots) }))
                (field_row("instrument", html! { (Text(side.instrument.as_deref().unwrap_or("not recorded"))) }))
                (field_row("flags", html! { (Text(&if side.flags.is_empty() { "none".to_string() } else { side.flags.join(", ") })) }))
                (field_row("folder identity", html! { code { (Text(side.identity.as_deref().unwrap_or("no manifest"))) } }))
            }
        };
        let body = html! {
            h1 { "Comparison of two sheets" } "\n"
            @if let Some(label) = self.population.label {
                p class="verdict flagged" { (Text(&label.to_uppercase())) } "\n"
            }
            h2 { "Propositions" } "\n"
            ul { li { (Text(&self.propositions.same)) } li { (Text(&self.propositions.different)) } } "\n"
            h2 { "Result" } "\n"
            p class={ "verdict " (if self.warned() { "flagged" } else { "ok" }) } {
                "LR = 10" sup { (format!("{:.2}", self.ratio.log10_lr)) } ": " (Text(&self.ratio.verbal))
            } "\n"
            table {
                (field_row("reported log10 LR", html! { (format!("{:+.2}", self.ratio.log10_lr)) }))
                (field_row("the model's own", html! { (format!("{:+.2}", self.ratio.raw_log10_lr)) }))
                (field_row("after calibration", html! { (format!("{:+.2}", self.ratio.calibrated_log10_lr)) }))
                (field_row("empirical bounds (ELUB)", html! { (Text(&self.bounds_text())) }))
            } "\n"
            h2 { "Warnings" } "\n"
            @if self.warning_texts.is_empty() {
                p { "None: no assumption behind the ratio is contradicted by these data." } "\n"
            } @else {
                ul class="warnings" { @for w in &self.warning_texts { li { (Text(w)) } } } "\n"
            }
            h2 { "The sheets" } "\n"
            table {
                tr { th { "parameter" } th { "A: value [95 % interval]" } th { "B: value [95 % interval]" } }
                @for (i, label) in PARAM_LABELS.iter().enumerate() {
                    tr { td { (label) } td class="num" { (Text(&self.a.cell(i))) } td class="num" { (Text(&self.b.cell(i))) } }
                }
            } "\n"
            h3 { "A" } table { (side_rows(&self.a)) } "\n"
            h3 { "B" } table { (side_rows(&self.b)) } "\n"
            h2 { "Population and assumptions" } "\n"
            p { (Text(&self.population_text())) } "\n"
            @if let Some(why) = &self.population.not_validated_because {
                p class="note" { "Not validated: " (Text(why)) } "\n"
            }
            h2 { "Audit trail" } "\n"
            table {
                (field_row("gonio version", html! { (self.audit.gonio_version) }))
                (field_row("command line", html! { code { (Text(&self.audit.command_line.join(" "))) } }))
                (field_row("computed at", html! { (Text(&self.audit.computed_at)) }))
                (field_row("population identity", html! { code { (Text(&self.population.identity)) } }))
            } "\n"
            p class="note" { "Classes are shown for information: the evidence weighs the parameters, not the class boundaries. The ratio is a statement about the findings given each proposition, not about the propositions." } "\n"
        };
        page(&title, body)
    }
}
