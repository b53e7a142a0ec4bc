//! `gonio compare A B`: are two measured sheets distinguishable, or could they be the same
//! paper stock? A and B are session folders (or their `session.json`) of `gonio measure`.
use crate::analysis::compare::{self, Comparison, DEFAULT_ALPHA, PARAM_LABELS, SessionResult};
use serde_json::json;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio compare`.
#[derive(clap::Args)]
pub struct Args {
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Significance level: distinguishable when the chi-square p-value is below it.
    #[arg(long, value_name = "P", default_value_t = DEFAULT_ALPHA)]
    pub alpha: f64,
    /// First sheet: a session folder or its session.json.
    #[arg(value_name = "A")]
    pub a: PathBuf,
    /// Second sheet: a session folder or its session.json.
    #[arg(value_name = "B")]
    pub b: PathBuf,
}

/// The JSON object of `--json`.
pub fn to_json(a: &SessionResult, b: &SessionResult, c: &Comparison) -> serde_json::Value {
    let z: serde_json::Map<String, serde_json::Value> = c.parameters.iter().map(|p| (p.name.to_string(), json!(p.z))).collect();
    json!({
        "distinguishable": c.distinguishable,
        "reason": c.reason,
        "p_value": c.p_value,
        "distance": c.distance,
        "dof": c.dof,
        "alpha": c.alpha,
        "z": z,
        "class_a": c.class_a,
        "class_b": c.class_b,
        "sample_a": a.sample,
        "sample_b": b.sample,
        "file_a": a.file.display().to_string(),
        "file_b": b.file.display().to_string(),
        "parameters": c.parameters,
        "correlations_dropped": c.correlations_dropped,
    })
}

fn value_with_uncertainty(v: Option<f64>, u: Option<f64>) -> String {
    match (v, u) {
        (Some(v), Some(u)) => format!("{v:.4} ± {u:.4}"),
        (Some(v), None) => format!("{v:.4}"),
        _ => "—".to_string(),
    }
}

/// The human table.
pub fn to_table(a: &SessionResult, b: &SessionResult, c: &Comparison) -> String {
    let mut s = format!("A  {}  sample {}  class {}\n", a.file.display(), a.sample, c.class_a);
    s += &format!("B  {}  sample {}  class {}\n", b.file.display(), b.sample, c.class_b);
    s += &format!("  {:<12} {:>20} {:>20}  {:<7} {:>8}\n", "parameter", "A", "B", "space", "z");
    for (p, label) in c.parameters.iter().zip(PARAM_LABELS) {
        let z = p.z.map_or_else(|| "—".to_string(), |z| format!("{z:+.2}"));
        let space = p.space.unwrap_or("skipped");
        s += &format!("  {label:<12} {:>20} {:>20}  {space:<7} {z:>8}", value_with_uncertainty(p.a, p.u_a), value_with_uncertainty(p.b, p.u_b));
        if let Some(why) = p.skipped {
            s += &format!("  ({why})");
        }
        s += "\n";
    }
    s += &format!(
        "  Mahalanobis distance {:.3} over {} parameter(s); chi-square p = {}{}\n",
        c.distance,
        c.dof,
        if c.p_value >= 1e-3 { format!("{:.3}", c.p_value) } else { format!("{:.2e}", c.p_value) },
        if c.correlations_dropped { " (correlations dropped: summed covariance not positive definite)" } else { "" }
    );
    let verdict = match c.reason {
        "different classes" => format!("DISTINGUISHABLE: different classes ({} vs {}), whatever p says", c.class_a, c.class_b),
        "p < alpha" => format!("DISTINGUISHABLE at α = {}: p < α, not the same paper stock", c.alpha),
        _ => format!("not distinguishable at α = {}: p ≥ α, consistent with the same paper stock", c.alpha),
    };
    s += &format!("  verdict: {verdict}\n");
    s
}

/// Run `gonio compare`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.alpha > 0.0 && args.alpha < 1.0, "--alpha must lie strictly between 0 and 1, not {}", args.alpha);
    let a = compare::read_session(&args.a)?;
    let b = compare::read_session(&args.b)?;
    let c = compare::compare(&a, &b, args.alpha);
    if args.json {
        println!("{}", to_json(&a, &b, &c));
    } else {
        print!("{}", to_table(&a, &b, &c));
    }
    Ok(ExitCode::SUCCESS)
}
