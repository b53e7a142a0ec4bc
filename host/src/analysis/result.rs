//! The analysis of one data set, pure (no I/O): fit the TSL model, check σ against σ_l,
//! classify; and its result document ([`ResultDocument`], the `gonio-analysis/1` JSON
//! object) and human table. The session, the trade study and `gonio fit` all use it.
//!
//! The document is a serde struct tree written through [`serde_json::Value`], whose object
//! keys serde_json (without `preserve_order`) keeps sorted: the JSON is the same bytes
//! whatever the order of the fields here (they are kept alphabetical, as the JSON reads).
//! Parts whose types belong to the fit and are written by it (the notes, the active
//! bounds, δ's source, the uncertainty budget) are held as the JSON the fit writes.
use crate::analysis::classify::{self, Classification};
use crate::analysis::fit::{self, FitError, FitOptions, FitResult, Observation, SharedError};
use crate::analysis::flags::{self, Flag};
use crate::analysis::model;
use crate::analysis::sampling::{self, Delta, SigmaCheck};
use serde::{Deserialize, Deserializer, Serialize};
use serde_json::Value;
use thiserror::Error;

/// Everything reported about one data set.
pub struct Report {
    /// Where the readings came from, as the result names it (a file, a session folder).
    pub file: String,
    /// Sample name.
    pub sample: String,
    /// The fit.
    pub fit: FitResult,
    /// δ used for the σ_l check, if one could be found.
    pub delta: Option<Delta>,
    /// The σ_l check.
    pub check: Option<SigmaCheck>,
    /// The classification.
    pub classification: Classification,
    /// What makes the result less than clean: the fit's (`lack-of-fit`), `not-identified`
    /// when the class could not be decided, `sigma-not-resolved` when σ is unresolved or
    /// fails σ > σ_l. The session adds its own.
    pub flags: Vec<Flag>,
}

impl Report {
    /// No flag but the informational ones.
    pub fn ok(&self) -> bool {
        flags::ok(&self.flags)
    }
}

/// The readings of one data set, as the analysis takes them.
#[derive(Clone, Copy, Debug)]
pub struct Readings<'a> {
    /// Where they came from, as the result names it (a file, a session folder).
    pub source: &'a str,
    /// Sample name.
    pub sample: &'a str,
    /// The readings, in their source's order.
    pub observations: &'a [Observation],
    /// The 1-based line of each reading in its source, for the errors.
    pub lines: &'a [usize],
}

/// Why a data set could not be analysed: the fit's error, at the line of its source it
/// points to (the first line when it points to none).
#[derive(Debug, Error)]
#[error("{line}: sample '{}': {source}", crate::text::shown(.sample))]
pub struct AnalysisError {
    /// The 1-based line of the reading the error is about.
    pub line: usize,
    /// Sample name.
    pub sample: String,
    /// What the fit found.
    pub source: FitError,
}

/// Fit, check and classify one data set.
pub fn analyse(
    readings: &Readings,
    options: &FitOptions,
    delta_deg: Option<f64>,
) -> Result<Report, AnalysisError> {
    analyse_with_shared(readings, &[], options, delta_deg)
}

/// [`analyse`] with errors the readings share (the calibration's uncertainty budget).
pub(crate) fn analyse_with_shared(
    readings: &Readings,
    shared: &[SharedError],
    options: &FitOptions,
    delta_deg: Option<f64>,
) -> Result<Report, AnalysisError> {
    let result = fit::fit_with_shared(readings.observations, shared, options).map_err(|e| {
        let line = e
            .reading_index()
            .and_then(|i| readings.lines.get(i))
            .or(readings.lines.first())
            .copied()
            .unwrap_or(1);
        AnalysisError {
            line,
            sample: readings.sample.to_string(),
            source: e,
        }
    })?;
    let mut result = result;
    for note in result.notes.iter_mut() {
        // The file's line is what the user can find the reading by.
        if let fit::Note::Outlier { index, line, .. } = note {
            *line = readings.lines.get(*index).copied();
        }
    }
    let geometries: Vec<(f64, f64)> = readings
        .observations
        .iter()
        .map(|o| (o.theta_i_deg, o.theta_r_deg))
        .collect();
    let delta = sampling::delta(&geometries, delta_deg);
    let check = delta.map(|d| sampling::check_sigma(result.sigma_deg(), d.deg));
    let mut classification = classify::classify(&result);
    // What the fit cannot see: percent, radians, a paper outside the population. A flag
    // beside a class would be a guess read as an answer: the class is withheld.
    let implausible =
        crate::analysis::plausibility::check(readings.observations, &result, &classification);
    if !implausible.is_empty() {
        result.notes.extend(implausible);
        result
            .flags
            .push(crate::analysis::flags::Flag::ImplausibleInput);
        classification = classification.withheld(classify::IMPLAUSIBLE_UNDECIDED);
    }
    let flags = flags_of(&result, check.as_ref(), &classification);
    Ok(Report {
        file: readings.source.to_string(),
        sample: readings.sample.to_string(),
        fit: result,
        delta,
        check,
        classification,
        flags,
    })
}

/// The analysis's flags, sorted and without repeats.
pub(crate) fn flags_of(
    fit: &FitResult,
    check: Option<&SigmaCheck>,
    classification: &Classification,
) -> Vec<Flag> {
    let mut out = fit.flags.clone();
    // ρs known only from below with η held at 1: not identified, whether or not its
    // lower limit decided the class.
    if classification.class.is_none() || (fit.eta_at_floor() && fit.has_specular_term()) {
        out.push(Flag::NotIdentified);
    }
    let sigma_failed = fit.has_specular_term()
        && (fit.sigma_upper_deg().is_some() || check.is_some_and(|c| !c.sigma_ok));
    if sigma_failed {
        out.push(Flag::SigmaNotResolved);
    }
    out.sort();
    out.dedup();
    out
}

/// The result document of one analysis (`gonio-analysis/1`): a line of `gonio fit --json`,
/// each `fits[].report` of `session.json`, and the analysis part of a spot's `result`.
/// Absent fields read as their defaults; `null` numbers as `None` (or NaN where the field
/// is always written).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub(crate) struct ResultDocument {
    /// The detector's full angular acceptance modelled in the fit, degrees.
    pub acceptance_deg: Option<f64>,
    /// The parameters at a bound, as the fit writes them.
    pub active_bounds: Value,
    /// The fitted arm zero offset, if one was fitted.
    pub arm_offset: Option<ArmOffsetDocument>,
    /// Its value, degrees.
    pub arm_offset_deg: Option<f64>,
    /// The likelihood-ratio statistic of the test for it.
    pub(crate) arm_offset_statistic: Option<f64>,
    /// The uncertainty budget, as [`crate::analysis::budget::to_json`] writes it.
    pub budget: Value,
    /// χ² of the fit.
    pub chi2: Option<f64>,
    /// The 95 % intervals.
    pub ci95: Intervals,
    /// The class, when decided.
    pub class: Option<String>,
    /// The share of the parameters' uncertainty region in the class.
    pub class_confidence: Option<f64>,
    /// Why the class was not decided.
    pub(crate) class_undecided: Option<String>,
    /// The fit's cost.
    #[serde(deserialize_with = "null_as_nan")]
    pub cost: f64,
    /// δ of the σ_l check, degrees.
    pub delta_deg: Option<f64>,
    /// Where δ came from, as the sampling check writes it.
    pub(crate) delta_source: Value,
    /// Degrees of freedom.
    pub dof: u64,
    /// η.
    pub eta: Option<f64>,
    /// Where the readings came from (absent from a spot's result).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    /// The flags.
    pub flags: Vec<Flag>,
    /// The χ² test's p-value.
    pub gof_p: Option<f64>,
    /// Glossy or rough, when decided.
    pub group: Option<String>,
    /// Iterations of the fit.
    pub iterations: u64,
    /// The fit is flagged lack-of-fit.
    pub lack_of_fit: bool,
    /// The fitted parameters' names.
    pub model: Vec<String>,
    /// The extension step ([`crate::analysis::fit::Extension`]): the terms added to the
    /// paper's model, every term's test, the members the data cannot exclude; `null` when
    /// not run.
    pub model_extension: Value,
    /// Number of readings.
    pub n: u64,
    /// The nearest reference paper of Table 6.
    pub nearest_reference: Option<String>,
    /// Its distance in combined standard uncertainties.
    pub(crate) nearest_reference_distance: Option<f64>,
    /// Normalised mean absolute error.
    #[serde(deserialize_with = "null_as_nan")]
    pub nmae: f64,
    /// The noise estimated from the residuals, when the readings carry none.
    pub noise_from_residuals: Option<f64>,
    /// The parameters the readings did not determine.
    pub not_identified: Vec<NotIdentifiedDocument>,
    /// The fit's notes, as the fit writes them.
    pub notes: Value,
    /// No flag but the informational ones.
    pub ok: bool,
    /// ρd.
    pub rho_d: Option<f64>,
    /// ρs.
    pub rho_s: Option<f64>,
    /// ρs's lower bound when σ is unresolved.
    pub(crate) rho_s_lower: Option<f64>,
    /// RMS residual.
    #[serde(deserialize_with = "null_as_nan")]
    pub rms: f64,
    /// Sample name.
    pub sample: String,
    /// The document's schema and version.
    pub schema: String,
    /// σ, degrees.
    pub sigma_deg: Option<f64>,
    /// σ_l, degrees.
    pub sigma_l_deg: Option<f64>,
    /// σ > σ_l.
    pub sigma_ok: bool,
    /// σ's upper bound when it is unresolved, degrees.
    pub sigma_upper_deg: Option<f64>,
    /// How the iteration ended.
    pub status: String,
    /// The residual-structure test, when run.
    pub structure: Option<StructureDocument>,
    /// The variance scale.
    #[serde(deserialize_with = "null_as_nan")]
    pub variance_scale: f64,
    /// The readings carried their own uncertainty.
    pub weighted: bool,
}

/// The 95 % intervals of the four parameters (`null`: none).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub(crate) struct Intervals {
    /// η's.
    pub eta: Option<Interval>,
    /// ρd's.
    pub rho_d: Option<Interval>,
    /// ρs's.
    pub rho_s: Option<Interval>,
    /// σ's, degrees.
    pub sigma_deg: Option<Interval>,
}

/// An interval's lower and upper end (`null`: not finite).
pub(crate) type Interval = [Option<f64>; 2];

impl Intervals {
    /// The interval of the parameter named `name` ([`model::PARAM_NAMES`]).
    pub fn of(&self, name: &str) -> Option<Interval> {
        match name {
            "sigma_deg" => self.sigma_deg,
            "rho_s" => self.rho_s,
            "rho_d" => self.rho_d,
            "eta" => self.eta,
            _ => None,
        }
    }

    fn from_fit(ci95: &[Option<(f64, f64)>; fit::N_PARAMS]) -> Intervals {
        let at = |i: usize| ci95[i].map(|(lo, hi)| [Some(lo), Some(hi)]);
        Intervals {
            eta: at(model::ETA),
            rho_d: at(model::RHO_D),
            rho_s: at(model::RHO_S),
            sigma_deg: at(model::SIGMA),
        }
    }
}

/// The fitted arm zero offset.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub(crate) struct ArmOffsetDocument {
    /// Its 95 % interval, degrees.
    pub ci95: Interval,
    /// δ0, degrees.
    #[serde(deserialize_with = "null_as_nan")]
    pub deg: f64,
    /// The likelihood-ratio statistic.
    pub lr: Option<f64>,
    /// Standard uncertainty, degrees.
    pub(crate) std_deg: Option<f64>,
}

/// The residual-structure test.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub(crate) struct StructureDocument {
    /// Pooled lag-1 autocorrelation.
    #[serde(deserialize_with = "null_as_nan")]
    pub(crate) lag1: f64,
    /// One-sided p-value.
    pub p_value: Option<f64>,
    /// θr-neighbour pairs used.
    pub pairs: u64,
    /// Z.
    #[serde(deserialize_with = "null_as_nan")]
    pub(crate) statistic: f64,
}

/// A parameter the readings did not determine, and why.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub(crate) struct NotIdentifiedDocument {
    /// The parameter's name.
    pub param: String,
    /// Why.
    pub reason: String,
}

/// A number written as `null` when not finite, read back as NaN.
fn null_as_nan<'de, D: Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(deserializer)?.unwrap_or(f64::NAN))
}

/// The fit's own serialisation of one of its types (as `json!` made it).
fn fit_json<T: Serialize>(value: &T) -> Value {
    serde_json::to_value(value).expect("the fit's types serialise to JSON")
}

impl ResultDocument {
    /// The document of a report.
    pub fn of(r: &Report) -> ResultDocument {
        let f = &r.fit;
        let c = &r.classification;
        ResultDocument {
            acceptance_deg: f.acceptance_deg,
            active_bounds: fit_json(&f.active_bounds),
            arm_offset: f.arm_offset.map(|a| ArmOffsetDocument {
                ci95: [Some(a.ci95.0), Some(a.ci95.1)],
                deg: a.deg,
                lr: Some(a.lr),
                std_deg: Some(a.std_deg),
            }),
            arm_offset_deg: f.arm_offset.map(|a| a.deg),
            arm_offset_statistic: f.arm_offset_statistic,
            budget: crate::analysis::budget::to_json(f),
            chi2: f.chi2,
            ci95: Intervals::from_fit(&f.ci95),
            class: c.class.map(|k| k.name().to_string()),
            class_confidence: c.class.map(|_| c.confidence),
            class_undecided: c.undecided.map(str::to_string),
            cost: f.cost,
            delta_deg: r.delta.map(|d| d.deg),
            delta_source: fit_json(&r.delta.map(|d| d.source)),
            dof: f.dof as u64,
            eta: f.reported(model::ETA),
            file: Some(r.file.clone()),
            flags: r.flags.clone(),
            gof_p: f.gof_p,
            group: c.group.map(|g| g.name().to_string()),
            iterations: f.iterations as u64,
            lack_of_fit: f.lack_of_fit,
            model: f.model.names().into_iter().map(str::to_string).collect(),
            model_extension: fit_json(&f.extension),
            n: f.n as u64,
            nearest_reference: Some(c.nearest_reference.to_string()),
            nearest_reference_distance: Some(c.nearest_distance),
            nmae: f.nmae,
            noise_from_residuals: f.noise_from_residuals,
            not_identified: f
                .not_identified()
                .into_iter()
                .map(|u| NotIdentifiedDocument {
                    param: u.param.to_string(),
                    reason: u.reason.to_string(),
                })
                .collect(),
            notes: fit_json(&f.notes),
            ok: r.ok(),
            rho_d: f.reported(model::RHO_D),
            rho_s: f.reported(model::RHO_S),
            rho_s_lower: f.rho_s_lower(),
            rms: f.rms,
            sample: r.sample.clone(),
            schema: crate::schema::ANALYSIS.to_string(),
            sigma_deg: f.sigma_deg(),
            sigma_l_deg: r.check.map(|c| c.sigma_l_deg),
            sigma_ok: r.check.is_some_and(|c| c.sigma_ok),
            sigma_upper_deg: f.sigma_upper_deg(),
            status: f.status.name().to_string(),
            structure: f.structure.map(|t| StructureDocument {
                lag1: t.lag1,
                p_value: Some(t.p_value),
                pairs: t.pairs as u64,
                statistic: t.statistic,
            }),
            variance_scale: f.variance_scale,
            weighted: f.weighted,
        }
    }

    /// The document as a JSON value: its keys sorted, non-finite numbers `null`.
    pub fn to_value(&self) -> Value {
        serde_json::to_value(self).expect("a result document serialises to JSON")
    }
}

/// The JSON object of a report (one line of `--json`; the session's `result` too).
pub fn to_json(r: &Report) -> Value {
    ResultDocument::of(r).to_value()
}

fn fmt_value(x: Option<f64>) -> String {
    x.map_or_else(|| "—".to_string(), |v| format!("{v:.4}"))
}

/// Decimals that show a value with a 95 % interval to its precision: two significant
/// digits of its standard uncertainty, the interval's half-width over 1.96 (issue 31: ρs
/// was printed to 4 decimals whatever its uncertainty, "57.3820 [51.0520, 64.4969]").
/// `None` for an interval of no width or not finite. The files keep every digit.
pub fn interval_decimals(lo: f64, hi: f64) -> Option<usize> {
    uncertainty_decimals((hi - lo) / 2.0 / 1.959_963_984_540_054)
}

/// Decimals that show a value to the precision of its standard uncertainty `u`: two
/// significant digits of `u`. `None` for an uncertainty of zero or not finite.
pub fn uncertainty_decimals(u: f64) -> Option<usize> {
    (u.is_finite() && u > 0.0).then(|| (1 - u.log10().floor() as i64).clamp(0, 9) as usize)
}

/// A value and its 95 % interval, both to [`interval_decimals`] (4 decimals without a
/// usable interval).
pub fn value_with_interval(value: f64, lo: f64, hi: f64) -> (String, String) {
    let d = interval_decimals(lo, hi).unwrap_or(4);
    (format!("{value:.d$}"), format!("[{lo:.d$}, {hi:.d$}]"))
}

/// The human table of a report.
pub fn to_table(r: &Report) -> String {
    let f = &r.fit;
    let mut s = format!(
        "{}  sample {}  (n = {}, fitted: {})\n",
        r.file,
        crate::text::shown(&r.sample),
        f.n,
        f.model.names().join(" ")
    );
    s += &parameter_lines(f);
    s += &fit_lines(f);
    s += &sampling_line(r.delta, r.check);
    s += &class_line(&r.classification);
    s += &crate::analysis::budget::to_table(f);
    for note in &f.notes {
        s += &format!("  note: {note}\n");
    }
    s += &format!(
        "  flags: {}\n",
        if r.flags.is_empty() {
            "none".to_string()
        } else {
            r.flags
                .iter()
                .map(|g| g.name())
                .collect::<Vec<_>>()
                .join(", ")
        }
    );
    s
}

/// The table's parameters with their intervals, the arm offset and what was not identified.
fn parameter_lines(f: &FitResult) -> String {
    // Each parameter by its symbol and its key in --json and the files: the mapping is
    // said where the values are (issue 31: σ, ρs in the terminal, sigma_deg, rho_s in JSON).
    let mut s = format!(
        "  {:<17} {:>10}   95 % interval\n",
        "parameter (key)", "value"
    );
    let values = [
        f.sigma_deg(),
        f.reported(model::RHO_S),
        f.reported(model::RHO_D),
        f.reported(model::ETA),
    ];
    for (i, name) in ["σ [°] (sigma_deg)", "ρs (rho_s)", "ρd (rho_d)", "η (eta)"]
        .iter()
        .enumerate()
    {
        let (shown, ci) = match (values[i], f.ci95[i]) {
            (Some(v), Some((lo, hi))) => {
                let (v, ci) = value_with_interval(v, lo, hi);
                (Some(v), ci)
            }
            (v, ci) => (
                v.map(|v| format!("{v:.4}")),
                ci.map_or_else(String::new, |(lo, hi)| format!("[{lo:.4}, {hi:.4}]")),
            ),
        };
        let value = match (i, f.sigma_upper_deg(), f.rho_s_lower()) {
            (model::SIGMA, Some(up), _) => format!("≤ {up:.4}"),
            (model::RHO_S, _, Some(lower)) => format!("≥ {lower:.4}"),
            _ => shown.unwrap_or_else(|| fmt_value(None)),
        };
        s += &format!("  {name:<17} {value:>10}   {ci}\n");
    }
    if let Some(a) = f.arm_offset {
        s += &format!(
            "  arm offset        {:>+10.4}   [{:.4}, {:.4}] (θr + δ0)\n",
            a.deg, a.ci95.0, a.ci95.1
        );
    }
    for u in f.not_identified() {
        s += &format!("  not identified: {} ({})\n", u.param, u.reason);
    }
    s += &extension_lines(f);
    s
}

/// The table's lines on the model: the terms added with their tests, and the members the
/// data cannot exclude (inside the intervals).
fn extension_lines(f: &FitResult) -> String {
    let Some(e) = &f.extension else {
        return String::new();
    };
    let mut s = String::new();
    if e.terms.is_empty() {
        s += "  model: the paper's TSL (no term called for)\n";
    }
    for t in &e.terms {
        s += &format!(
            "  model extended — {} (test {:.1} > {:.1})\n",
            t.description, t.statistic, t.critical
        );
    }
    if !e.terms.is_empty() {
        s += "    σ, ρs, ρd, η are the main lobe's (σ its half-maximum width as a Gaussian): the paper's classification applies to them\n";
    }
    if !e.plausible.is_empty() {
        s += &format!(
            "    not excluded by the data (inside the intervals): {}\n",
            e.plausible.join("; ")
        );
    }
    s
}

/// The table's lines on the fit: its residuals, iterations and goodness.
fn fit_lines(f: &FitResult) -> String {
    let mut s = format!(
        "  NMAE {:.2} %   RMS {:.4} (radiance factor)   {} iterations, {}\n",
        100.0 * f.nmae,
        f.rms,
        f.iterations,
        f.status.name()
    );
    let chi2 = match (f.chi2, f.gof_p) {
        (Some(chi2), Some(p)) => format!(
            "χ² {chi2:.1} on {} dof (χ²/ν {:.2}, p {p:.3})",
            f.dof,
            chi2 / f.dof.max(1) as f64
        ),
        (Some(chi2), None) => format!("χ² {chi2:.1} on {} dof", f.dof),
        _ => format!("no χ² (noise from the residuals), {} dof", f.dof),
    };
    let structure = f.structure.map_or_else(
        || "structure test not run".to_string(),
        |t| {
            format!(
                "residual structure Z {:.2} (lag-1 {:.2}, p {:.3}, {} pairs)",
                t.statistic, t.lag1, t.p_value, t.pairs
            )
        },
    );
    let lack_of_fit = if f.lack_of_fit {
        " — LACK OF FIT"
    } else {
        ""
    };
    s += &format!("  fit: {chi2}; {structure}{lack_of_fit}\n");
    s
}

/// The table's line on the σ_l check.
fn sampling_line(delta: Option<Delta>, check: Option<SigmaCheck>) -> String {
    match (delta, check) {
        (Some(d), Some(chk)) => format!(
            "  δ {:.3}° (spacing around the specular direction)   σ_l {:.3}° (the narrowest lobe it resolves)   σ > σ_l: {}\n",
            d.deg,
            chk.sigma_l_deg,
            if chk.sigma_ok {
                "yes"
            } else {
                "NO (measure closer to the specular direction)"
            }
        ),
        _ => "  δ unknown (no neighbours of the specular direction): σ_l check not made\n"
            .to_string(),
    }
}

/// The table's line on the class.
fn class_line(c: &Classification) -> String {
    match c.class {
        Some(class) => format!(
            "  class {} ({}), confidence {:.2} (the share of the parameters' uncertainty region in the class), nearest reference {} ({:.2} combined standard uncertainties away)\n",
            class.name(),
            class.group().name(),
            c.confidence,
            c.nearest_reference,
            c.nearest_distance
        ),
        None => format!(
            "  class undecided (group {}): {}; nearest reference {} ({:.2} combined standard uncertainties away)\n",
            c.group_name(),
            c.undecided.unwrap_or("not determined"),
            c.nearest_reference,
            c.nearest_distance
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::model::Params;

    /// Readings of glossy paper on a grid, with a small deterministic wobble as noise.
    fn observations(std: Option<f64>) -> Vec<Observation> {
        let p = Params {
            sigma_deg: 4.0,
            rho_s: 0.05,
            rho_d: 0.8,
            eta: 1.5,
        };
        let mut out = Vec::new();
        for theta_i in [20.0, 40.0, 60.0] {
            for k in 0..15 {
                let theta_r = f64::from(k) * 5.0;
                let wobble = 1.0 + 0.002 * ((theta_r + theta_i) * 0.7).sin();
                out.push(Observation {
                    theta_i_deg: theta_i,
                    theta_r_deg: theta_r,
                    radiance_factor: model::radiance_factor(&p, theta_i, theta_r) * wobble,
                    std,
                    theta_r_span_deg: 0.0,
                });
            }
        }
        out
    }

    fn report(std: Option<f64>) -> Report {
        let obs = observations(std);
        let lines: Vec<usize> = (2..2 + obs.len()).collect();
        let readings = Readings {
            source: "grid.csv",
            sample: "grid",
            observations: &obs,
            lines: &lines,
        };
        analyse(&readings, &FitOptions::default(), None).expect("a valid data set")
    }

    /// The document reads back into the same document, and its JSON is the same text
    /// written from the value (sorted keys) or read back and written again.
    #[test]
    fn the_document_reads_back_as_written() {
        for std in [None, Some(0.002)] {
            let r = report(std);
            let value = to_json(&r);
            let text = value.to_string();
            let read: ResultDocument = serde_json::from_str(&text).expect("a result document");
            assert_eq!(read.to_value().to_string(), text);
            assert_eq!(read.file.as_deref(), Some("grid.csv"));
            assert_eq!(read.schema, crate::schema::ANALYSIS);
            let ci = read.ci95.of("sigma_deg").expect("σ's interval");
            assert!(ci[0].is_some_and(|lo| lo < read.sigma_deg.unwrap_or(f64::NAN)));
        }
    }

    /// Every key of the document, as `gonio-analysis/1` has them.
    #[test]
    fn the_document_has_every_key() {
        let value = to_json(&report(Some(0.002)));
        let keys: Vec<&str> = value
            .as_object()
            .expect("an object")
            .keys()
            .map(String::as_str)
            .collect();
        let expected = [
            "acceptance_deg",
            "active_bounds",
            "arm_offset",
            "arm_offset_deg",
            "arm_offset_statistic",
            "budget",
            "chi2",
            "ci95",
            "class",
            "class_confidence",
            "class_undecided",
            "cost",
            "delta_deg",
            "delta_source",
            "dof",
            "eta",
            "file",
            "flags",
            "gof_p",
            "group",
            "iterations",
            "lack_of_fit",
            "model",
            "model_extension",
            "n",
            "nearest_reference",
            "nearest_reference_distance",
            "nmae",
            "noise_from_residuals",
            "not_identified",
            "notes",
            "ok",
            "rho_d",
            "rho_s",
            "rho_s_lower",
            "rms",
            "sample",
            "schema",
            "sigma_deg",
            "sigma_l_deg",
            "sigma_ok",
            "sigma_upper_deg",
            "status",
            "structure",
            "variance_scale",
            "weighted",
        ];
        assert_eq!(keys, expected);
    }

    /// The intervals' keys are the parameters' names.
    #[test]
    fn intervals_are_keyed_by_the_parameter_names() {
        let r = report(Some(0.002));
        let value = to_json(&r);
        let keys: Vec<&String> = value["ci95"].as_object().expect("ci95").keys().collect();
        let mut names = model::PARAM_NAMES.to_vec();
        names.sort();
        assert_eq!(keys, names);
        for name in model::PARAM_NAMES {
            assert!(ResultDocument::of(&r).ci95.of(name).is_some(), "{name}");
        }
    }

    /// A number that is not finite is written as null and read back as NaN or none.
    #[test]
    fn numbers_that_are_not_finite_are_null() {
        let mut r = report(None);
        r.fit.nmae = f64::NAN;
        r.fit.chi2 = Some(f64::INFINITY);
        let value = to_json(&r);
        assert!(
            value["nmae"].is_null() && value["chi2"].is_null(),
            "{value}"
        );
        let read = ResultDocument::deserialize(&value).expect("a result document");
        assert!(read.nmae.is_nan() && read.chi2.is_none());
        assert_eq!(read.to_value(), value);
    }

    /// A fit error names the line of the reading it is about.
    #[test]
    fn errors_name_the_line() {
        let mut obs = observations(None);
        obs[3].radiance_factor = f64::NAN;
        let lines: Vec<usize> = (10..10 + obs.len()).collect();
        let readings = Readings {
            source: "bad.csv",
            sample: "bad",
            observations: &obs,
            lines: &lines,
        };
        let e = analyse(&readings, &FitOptions::default(), None)
            .err()
            .expect("an error");
        assert!(e.to_string().starts_with("13: sample 'bad': "), "{e}");
    }
}
