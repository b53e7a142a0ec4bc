//! The analysis of one data set, pure (no I/O): fit the TSL model, check σ against σ_l,
//! classify, and the report's JSON object and human table. The session, the trade study
//! and `gonio fit` all use it.
use crate::analysis::budget::SharedError;
use crate::analysis::classify::{self, Classification};
use crate::analysis::fit::{self, FitOptions, FitResult};
use crate::analysis::model::{self, PARAM_NAMES};
use crate::analysis::sampling::{self, Delta, SigmaCheck};
use crate::output::dataset::DataSet;
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
}

/// Fit, check and classify one data set; errors are `line: message`.
pub fn analyse(file: &Path, set: &DataSet, options: &FitOptions, delta_deg: Option<f64>) -> Result<Report, String> {
    analyse_with_shared(file, set, &[], options, delta_deg)
}

/// [`analyse`] with errors the readings share (`analysis::budget`).
pub fn analyse_with_shared(file: &Path, set: &DataSet, shared: &[SharedError], options: &FitOptions, delta_deg: Option<f64>) -> Result<Report, String> {
    // TEMPORARY until wp-e-fit lands `fit::fit_with_shared`: the shared errors are not yet used.
    let _ = shared;
    let result = fit::fit(&set.observations, options).map_err(|e| {
        let line = e.reading_index().and_then(|i| set.lines.get(i)).or(set.lines.first()).copied().unwrap_or(1);
        format!("{line}: sample '{}': {e}", set.sample)
    })?;
    let delta = sampling::delta(&set.geometries(), delta_deg);
    let check = delta.map(|d| sampling::check_sigma(result.sigma_deg(), d.deg));
    let classification = classify::classify(&result);
    Ok(Report { file: file.to_path_buf(), sample: set.sample.clone(), fit: result, delta, check, classification })
}

fn finite_or_null(x: Option<f64>) -> Value {
    x.filter(|v| v.is_finite()).map_or(Value::Null, |v| json!(v))
}

/// The JSON object of a report (one line of `--json`).
pub fn to_json(r: &Report) -> Value {
    let f = &r.fit;
    let mut ci = serde_json::Map::new();
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        ci.insert(name.to_string(), f.ci95[i].map_or(Value::Null, |(lo, hi)| json!([lo, hi])));
    }
    json!({
        "file": r.file.display().to_string(),
        "sample": r.sample,
        "n": f.n,
        "sigma_deg": finite_or_null(f.sigma_deg()),
        "sigma_upper_deg": finite_or_null(f.sigma_upper_deg()),
        "rho_s": finite_or_null(f.reported(model::RHO_S)),
        "rho_d": finite_or_null(f.reported(model::RHO_D)),
        "eta": finite_or_null(f.reported(model::ETA)),
        "nmae": f.nmae,
        "rms": f.rms,
        "cost": f.cost,
        "delta_deg": finite_or_null(r.delta.map(|d| d.deg)),
        "delta_source": r.delta.map(|d| d.source),
        "sigma_l_deg": finite_or_null(r.check.map(|c| c.sigma_l_deg)),
        "sigma_ok": r.check.is_some_and(|c| c.sigma_ok),
        "group": r.classification.group.name(),
        "class": r.classification.class.name(),
        "class_confidence": r.classification.confidence,
        "nearest_reference": r.classification.nearest_reference,
        "nearest_reference_distance": finite_or_null(Some(r.classification.nearest_distance)),
        "ci95": ci,
        "model": f.model.names(),
        "active_bounds": f.active_bounds,
        "notes": f.notes,
        "acceptance_deg": f.acceptance_deg,
        "iterations": f.iterations,
        "status": f.status,
        "weighted": f.weighted,
    })
}

fn fmt_value(x: Option<f64>) -> String {
    x.map_or_else(|| "—".to_string(), |v| format!("{v:.4}"))
}

/// The human table of a report.
pub fn to_table(r: &Report) -> String {
    let f = &r.fit;
    let c = &r.classification;
    let mut s = format!("{}  sample {}  (n = {}, fitted: {})\n", r.file.display(), r.sample, f.n, f.model.names().join(" "));
    s += "  parameter        value       95 % interval\n";
    let values = [f.sigma_deg(), f.reported(model::RHO_S), f.reported(model::RHO_D), f.reported(model::ETA)];
    for (i, name) in ["sigma [deg]", "rho_s", "rho_d", "eta"].iter().enumerate() {
        let ci = f.ci95[i].map_or_else(String::new, |(lo, hi)| format!("[{lo:.4}, {hi:.4}]"));
        let value = match (i, f.sigma_upper_deg()) {
            (model::SIGMA, Some(up)) => format!("≤ {up:.4}"),
            _ => fmt_value(values[i]),
        };
        s += &format!("  {name:<14} {value:>10}   {ci}\n");
    }
    s += &format!("  NMAE {:.2} %   RMS {:.4}   {} iterations, {:?}\n", 100.0 * f.nmae, f.rms, f.iterations, f.status);
    match (r.delta, r.check) {
        (Some(d), Some(chk)) => {
            s += &format!(
                "  δ {:.3}°   σ_l {:.3}°   σ > σ_l: {}\n",
                d.deg,
                chk.sigma_l_deg,
                if chk.sigma_ok { "yes" } else { "NO (measure closer to the specular direction)" }
            )
        }
        _ => s += "  δ unknown (no neighbours of the specular direction): σ_l check not made\n",
    }
    s += &format!(
        "  class {} ({}), confidence {:.0} %, nearest reference {} (distance {:.2})\n",
        c.class.name(),
        c.group.name(),
        100.0 * c.confidence,
        c.nearest_reference,
        c.nearest_distance
    );
    for note in &f.notes {
        s += &format!("  note: {note}\n");
    }
    s
}
