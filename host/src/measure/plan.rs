//! What a session measures: the options given, else the resumed session's, else the
//! defaults, checked against the instrument's announced limits; and a calibration given
//! from an earlier session.
use super::MeasureOptions;
use super::check::Checked;
use crate::instrument::calibration::Calibration;
use crate::output::folder::{AdaptiveTargetsRecord, PlanRecord};
use crate::session::adaptive::AdaptiveTargets;
use crate::session::{Plan, Policy, PolicyChoice};
use anyhow::bail;
use std::path::Path;

/// The white drift limit when none is given, percent.
pub const DEFAULT_WHITE_DRIFT_LIMIT_PCT: f64 = 0.5;
/// The largest detector acceptance the fit models, degrees (full width): its acceptance
/// window is a small-angle average over the lobe, and the instrument's is about 2°.
pub const MAX_ACCEPTANCE_DEG: f64 = 10.0;

/// What is measured: the options given, else the resumed session's, else the defaults;
/// checked against the instrument's announced limits.
pub(super) fn plan_record(
    args: &MeasureOptions,
    info: &protocol::DeviceInfo,
    earlier: Option<&PlanRecord>,
) -> anyhow::Result<PlanRecord> {
    let policy = match (args.policy, earlier) {
        (Some(choice), _) => choice,
        (None, Some(plan)) => <PolicyChoice as clap::ValueEnum>::from_str(&plan.policy, true)
            .map_err(|_| anyhow::anyhow!("the session's policy '{}' is not one this gonio knows (paper, adaptive, sweep, mixed)", plan.policy))?,
        (None, None) => PolicyChoice::Adaptive,
    };
    let adaptive_targets = match Policy::from(policy) {
        Policy::Adaptive(t) | Policy::Mixed(t, _) => Some(AdaptiveTargetsRecord {
            sigma_rel_half_width: t.sigma_rel_half_width,
            class_confidence: t.class_confidence,
            batch: t.batch,
            max_batches: t.max_batches,
        }),
        _ => None,
    };
    let (integration_ms, from) = match (args.integration_ms, earlier) {
        (Some(ms), _) => (ms, "--integration-ms".to_string()),
        (None, Some(plan)) => (
            plan.integration_ms,
            "the resumed session's integration time".to_string(),
        ),
        (None, None) => (
            info.default_integration_ms,
            "the instrument's default integration time".to_string(),
        ),
    };
    let (min, max) = (info.min_integration_ms.max(1), info.max_integration_ms);
    if !(min..=max).contains(&integration_ms) {
        crate::usage_bail!(
            "{from} {integration_ms} ms is outside what the instrument (serial {}) accepts: {min} to {max} ms",
            info.serial_number
        );
    }
    let acceptance_deg = f64::from(info.acceptance_deg);
    if !(acceptance_deg.is_finite() && (0.0..=MAX_ACCEPTANCE_DEG).contains(&acceptance_deg)) {
        bail!(
            "the instrument (serial {}) announces a detector acceptance of {acceptance_deg}°: the fit models 0 to {MAX_ACCEPTANCE_DEG}°",
            info.serial_number
        );
    }
    let sweep_targets = match Policy::from(policy) {
        Policy::Sweep(t) | Policy::Mixed(_, t) => Some(t),
        _ => None,
    };
    let model = match (args.model, earlier) {
        (Some(choice), _) => choice,
        (None, Some(plan)) => plan.model_choice()?,
        (None, None) => crate::analysis::fit::ModelChoice::by_default(),
    };
    Ok(PlanRecord {
        policy: policy.name().into(),
        adaptive_targets,
        sweep_targets,
        integration_ms,
        acceptance_deg,
        white_check: args.white_check || earlier.is_some_and(|p| p.white_check),
        white_drift_limit_pct: args
            .white_drift_limit_pct
            .or(earlier.map(|p| p.white_drift_limit_pct))
            .unwrap_or(DEFAULT_WHITE_DRIFT_LIMIT_PCT),
        model: Some(model.name().into()),
    })
}

/// The plan of a sheet in `dir`: the one it recorded (`recorded`; for a sheet written
/// before sheets recorded their plan, spot 1's), else the options given. Options given
/// that would change a recorded plan are refused, each by name: a sheet is one procedure.
pub(super) fn sheet_plan(
    args: &MeasureOptions,
    info: &protocol::DeviceInfo,
    dir: &Path,
    recorded: Option<&PlanRecord>,
) -> anyhow::Result<PlanRecord> {
    let spot_1 = || {
        crate::output::folder::read_session(&dir.join(crate::output::folder::spot_folder(1)))
            .ok()
            .flatten()
            .map(|doc| doc.plan)
    };
    let Some(recorded) = recorded.cloned().or_else(spot_1) else {
        return plan_record(args, info, None);
    };
    let mut differences = Vec::new();
    if let Some(policy) = args.policy.filter(|p| p.name() != recorded.policy) {
        differences.push(format!("--policy {}", policy.name()));
    }
    if let Some(ms) = args
        .integration_ms
        .filter(|ms| *ms != recorded.integration_ms)
    {
        differences.push(format!("--integration-ms {ms}"));
    }
    if args.white_check && !recorded.white_check {
        differences.push("--white-check".to_string());
    }
    if let Some(pct) = args
        .white_drift_limit_pct
        .filter(|pct| *pct != recorded.white_drift_limit_pct)
    {
        differences.push(format!("--white-drift-limit-pct {pct}"));
    }
    if let Some(model) = args.model {
        let recorded_model = recorded.model_choice()?;
        if model != recorded_model {
            differences.push(format!("--model {}", model.name()));
        }
    }
    if !differences.is_empty() {
        bail!(
            "{} differs from the sheet's plan: {}; a sheet is measured under one plan (resume without {})",
            differences.join(", "),
            describe(&recorded),
            if differences.len() == 1 { "it" } else { "them" }
        );
    }
    // The recorded plan, checked against this instrument's limits as a new one would be.
    let mut unchanged = args.clone();
    unchanged.policy = None;
    unchanged.integration_ms = None;
    unchanged.white_check = false;
    unchanged.white_drift_limit_pct = None;
    unchanged.model = None;
    plan_record(&unchanged, info, Some(&recorded))?;
    Ok(recorded)
}

/// A plan in words: its policy first (the option most often left out of a resume).
fn describe(plan: &PlanRecord) -> String {
    format!(
        "{} (--integration-ms {}, {}, white drift limit {} %)",
        plan.policy,
        plan.integration_ms,
        if plan.white_check {
            "with --white-check"
        } else {
            "no white check"
        },
        plan.white_drift_limit_pct
    )
}

pub(super) fn plan_of(record: &PlanRecord, sample: &str) -> Plan {
    let adaptive = record.adaptive_targets.as_ref().map(|t| AdaptiveTargets {
        sigma_rel_half_width: t.sigma_rel_half_width,
        class_confidence: t.class_confidence,
        batch: t.batch,
        max_batches: t.max_batches,
    });
    let policy = match (record.policy.as_str(), adaptive) {
        ("sweep", _) => Policy::Sweep(record.sweep_targets.unwrap_or_default()),
        ("mixed", Some(t)) => Policy::Mixed(t, record.sweep_targets.unwrap_or_default()),
        (_, Some(t)) => Policy::Adaptive(t),
        (_, None) => Policy::Paper,
    };
    Plan {
        sample: sample.to_string(),
        integration_ms: record.integration_ms,
        policy,
        acceptance_deg: record.acceptance_deg,
        white_check: record.white_check,
        white_drift_limit: record.white_drift_limit_pct / 100.0,
    }
}

/// `--calibration`: a session folder, its `session.json` or a `calibration.json`, checked
/// for age and instrument (its serial number too, when a session document names it).
pub(super) fn external_calibration(
    path: &Path,
    checked: &Checked,
    info: &protocol::DeviceInfo,
) -> anyhow::Result<Calibration> {
    let file = if path.is_dir() {
        path.join("calibration.json")
    } else {
        path.to_path_buf()
    };
    let calibration = Calibration::load(&file, checked.max_calibration_age, info)?;
    let session = if path.is_dir() {
        path.join("session.json")
    } else {
        file.with_file_name("session.json")
    };
    if let Some(serial) = std::fs::read(&session)
        .ok()
        .and_then(|b| serde_json::from_slice::<SessionInstrument>(&b).ok())
        .map(|d| d.instrument.serial_number)
        && serial != info.serial_number.as_str()
    {
        bail!(
            "calibration {} was taken on instrument serial {serial}, not on this one (serial {})",
            file.display(),
            info.serial_number
        );
    }
    Ok(calibration)
}

/// What a calibration's `session.json` is read for: the instrument it was taken on.
#[derive(serde::Deserialize)]
struct SessionInstrument {
    instrument: SerialNumber,
}

/// An instrument's serial number, as `session.json` records it.
#[derive(serde::Deserialize)]
struct SerialNumber {
    serial_number: String,
}
