//! The analysis of one data set, pure (no I/O): fit the TSL model, check σ against σ_l,
//! classify, and the report's JSON object and human table. The session, the trade study
//! and `gonio fit` all use it.
use crate::analysis::classify::{self, Classification};
use crate::analysis::dataset::DataSet;
use crate::analysis::fit::{self, FitOptions, FitResult, SharedError};
use crate::analysis::flags::{self, Flag};
use crate::analysis::model::{self, PARAM_NAMES};
use crate::analysis::sampling::{self, Delta, SigmaCheck};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// Everything reported about one data set.
pub struct Report {
    /// File it came from.
    pub file: PathBuf,
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

/// Fit, check and classify one data set; errors are `line: message`.
pub fn analyse(
    file: &Path,
    set: &DataSet,
    options: &FitOptions,
    delta_deg: Option<f64>,
) -> Result<Report, String> {
    analyse_with_shared(file, set, &[], options, delta_deg)
}

/// [`analyse`] with errors the readings share (the calibration's uncertainty budget).
pub fn analyse_with_shared(
    file: &Path,
    set: &DataSet,
    shared: &[SharedError],
    options: &FitOptions,
    delta_deg: Option<f64>,
) -> Result<Report, String> {
    let result = fit::fit_with_shared(&set.observations, shared, options).map_err(|e| {
        let line = e
            .reading_index()
            .and_then(|i| set.lines.get(i))
            .or(set.lines.first())
            .copied()
            .unwrap_or(1);
        format!("{line}: sample '{}': {e}", set.sample)
    })?;
    let delta = sampling::delta(&set.geometries(), delta_deg);
    let check = delta.map(|d| sampling::check_sigma(result.sigma_deg(), d.deg));
    let classification = classify::classify(&result);
    let flags = flags_of(&result, check.as_ref(), &classification);
    Ok(Report {
        file: file.to_path_buf(),
        sample: set.sample.clone(),
        fit: result,
        delta,
        check,
        classification,
        flags,
    })
}

/// The analysis's flags, sorted and without repeats.
pub fn flags_of(
    fit: &FitResult,
    check: Option<&SigmaCheck>,
    classification: &Classification,
) -> Vec<Flag> {
    let mut out = fit.flags.clone();
    if classification.class.is_none() {
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

fn finite_or_null(x: Option<f64>) -> Value {
    x.filter(|v| v.is_finite())
        .map_or(Value::Null, |v| json!(v))
}

/// The JSON object of a report (one line of `--json`; the session's `result` too).
pub fn to_json(r: &Report) -> Value {
    let f = &r.fit;
    let c = &r.classification;
    let mut ci = serde_json::Map::new();
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        ci.insert(
            name.to_string(),
            f.ci95[i].map_or(Value::Null, |(lo, hi)| json!([lo, hi])),
        );
    }
    // Two objects merged: one json! of all the keys exceeds the macro's recursion limit.
    let mut object = json!({
        "file": r.file.display().to_string(),
        "sample": r.sample,
        "n": f.n,
        "sigma_deg": finite_or_null(f.sigma_deg()),
        "sigma_upper_deg": finite_or_null(f.sigma_upper_deg()),
        "rho_s": finite_or_null(f.reported(model::RHO_S)),
        "rho_s_lower": finite_or_null(f.rho_s_lower()),
        "rho_d": finite_or_null(f.reported(model::RHO_D)),
        "eta": finite_or_null(f.reported(model::ETA)),
        "not_identified": f.not_identified(),
        "nmae": f.nmae,
        "rms": f.rms,
        "cost": f.cost,
        "chi2": finite_or_null(f.chi2),
        "dof": f.dof,
        "gof_p": finite_or_null(f.gof_p),
        "structure": f.structure,
        "lack_of_fit": f.lack_of_fit,
        "variance_scale": f.variance_scale,
        "noise_from_residuals": finite_or_null(f.noise_from_residuals),
        "arm_offset_deg": finite_or_null(f.arm_offset.map(|a| a.deg)),
        "arm_offset": f.arm_offset.map(|a| json!({
            "deg": a.deg,
            "std_deg": finite_or_null(Some(a.std_deg)),
            "ci95": [finite_or_null(Some(a.ci95.0)), finite_or_null(Some(a.ci95.1))],
            "lr": finite_or_null(Some(a.lr)),
        })),
        "arm_offset_statistic": finite_or_null(f.arm_offset_statistic),
        "budget": crate::analysis::budget::to_json(f),
    });
    let rest = json!({
        "delta_deg": finite_or_null(r.delta.map(|d| d.deg)),
        "delta_source": r.delta.map(|d| d.source),
        "sigma_l_deg": finite_or_null(r.check.map(|c| c.sigma_l_deg)),
        "sigma_ok": r.check.is_some_and(|c| c.sigma_ok),
        "group": c.group.map(|g| g.name()),
        "class": c.class.map(|k| k.name()),
        "class_confidence": c.class.map(|_| c.confidence),
        "class_undecided": c.undecided,
        "nearest_reference": c.nearest_reference,
        "nearest_reference_distance": finite_or_null(Some(c.nearest_distance)),
        "ci95": ci,
        "model": f.model.names(),
        "active_bounds": f.active_bounds,
        "notes": f.notes,
        "acceptance_deg": f.acceptance_deg,
        "iterations": f.iterations,
        "status": f.status,
        "weighted": f.weighted,
        "flags": r.flags.iter().map(|g| g.name()).collect::<Vec<_>>(),
        "ok": r.ok(),
    });
    if let (Some(object), Value::Object(rest)) = (object.as_object_mut(), rest) {
        object.extend(rest);
    }
    crate::schema::tagged(crate::schema::ANALYSIS, object)
}

fn fmt_value(x: Option<f64>) -> String {
    x.map_or_else(|| "—".to_string(), |v| format!("{v:.4}"))
}

/// The human table of a report.
pub fn to_table(r: &Report) -> String {
    let f = &r.fit;
    let c = &r.classification;
    let mut s = format!(
        "{}  sample {}  (n = {}, fitted: {})\n",
        r.file.display(),
        r.sample,
        f.n,
        f.model.names().join(" ")
    );
    s += "  parameter        value       95 % interval\n";
    let values = [
        f.sigma_deg(),
        f.reported(model::RHO_S),
        f.reported(model::RHO_D),
        f.reported(model::ETA),
    ];
    for (i, name) in ["sigma [deg]", "rho_s", "rho_d", "eta"].iter().enumerate() {
        let ci = f.ci95[i].map_or_else(String::new, |(lo, hi)| format!("[{lo:.4}, {hi:.4}]"));
        let value = match (i, f.sigma_upper_deg(), f.rho_s_lower()) {
            (model::SIGMA, Some(up), _) => format!("≤ {up:.4}"),
            (model::RHO_S, _, Some(lower)) => format!("≥ {lower:.4}"),
            _ => fmt_value(values[i]),
        };
        s += &format!("  {name:<14} {value:>10}   {ci}\n");
    }
    if let Some(a) = f.arm_offset {
        s += &format!(
            "  arm offset     {:>+10.4}   [{:.4}, {:.4}] (θr + δ0)\n",
            a.deg, a.ci95.0, a.ci95.1
        );
    }
    for u in f.not_identified() {
        s += &format!("  not identified: {} ({})\n", u.param, u.reason);
    }
    s += &format!(
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
    s += &format!(
        "  fit: {chi2}; {structure}{}\n",
        if f.lack_of_fit {
            " — LACK OF FIT"
        } else {
            ""
        }
    );
    match (r.delta, r.check) {
        (Some(d), Some(chk)) => {
            s += &format!(
                "  δ {:.3}° (spacing around the specular direction)   σ_l {:.3}° (the narrowest lobe it resolves)   σ > σ_l: {}\n",
                d.deg,
                chk.sigma_l_deg,
                if chk.sigma_ok {
                    "yes"
                } else {
                    "NO (measure closer to the specular direction)"
                }
            )
        }
        _ => s += "  δ unknown (no neighbours of the specular direction): σ_l check not made\n",
    }
    match c.class {
        Some(class) => {
            s += &format!(
                "  class {} ({}), confidence {:.0} % (of the parameters' uncertainty region in the class), nearest reference {} ({:.2} combined standard uncertainties away)\n",
                class.name(),
                class.group().name(),
                100.0 * c.confidence,
                c.nearest_reference,
                c.nearest_distance
            )
        }
        None => {
            s += &format!(
                "  class undecided (group {}): {}; nearest reference {} ({:.2} combined standard uncertainties away)\n",
                c.group_name(),
                c.undecided.unwrap_or("not determined"),
                c.nearest_reference,
                c.nearest_distance
            )
        }
    }
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
