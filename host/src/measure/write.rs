//! A finished session's result into its folder: the summary files (the ASTM export, the
//! plots), `session.json` and the manifest.
use crate::analysis::fit::Observation;
use crate::instrument::calibration::instrument_name;
use crate::output::record::FileRecorder;
use crate::session::Outcome;
use anyhow::Context;
use serde_json::json;

/// Write the result into the folder (summary files, `session.json`, the manifest) and
/// return the result object printed by `--json`.
pub(super) fn write_session(
    recorder: &mut FileRecorder,
    sample: &str,
    info: &protocol::DeviceInfo,
    outcome: &Outcome,
) -> anyhow::Result<serde_json::Value> {
    let mut result = crate::analysis::result::to_json(&outcome.report);
    if let Some(object) = result.as_object_mut() {
        object.insert("sample".into(), json!(sample));
        object.insert("geometries".into(), json!(outcome.current_points().count()));
        object.insert("device_seconds".into(), json!(outcome.device_seconds));
        object.insert("setup_seconds".into(), json!(outcome.setup_seconds));
        object.insert("refinements".into(), json!(outcome.refinements));
        object.insert("covariance".into(), json!(outcome.report.fit.covariance));
        object.insert("white_drift".into(), json!(outcome.white_drift));
        object.insert(
            "white_drift_exceeded".into(),
            json!(outcome.white_drift_exceeded),
        );
        object.insert("ok".into(), json!(outcome.ok()));
        object.insert("flags".into(), json!(outcome.flags));
        object.insert(
            "session_dir".into(),
            json!(recorder.dir().display().to_string()),
        );
        // What `gonio fit DIR` needs to make this analysis again from the folder.
        object.insert("analysis_settings".into(), json!(outcome.analysis_settings));
        object.insert("analysed_unix_s".into(), json!(outcome.analysed_unix_s));
        object.remove("file");
    }
    let result = crate::schema::tagged(crate::schema::SPOT_RESULT, result);
    let mut rest = serde_json::Map::new();
    rest.insert("ok".into(), json!(outcome.ok()));
    rest.insert("flags".into(), json!(outcome.flags));
    rest.insert("calibration".into(), json!(outcome.calibration));
    rest.insert("readings".into(), json!(outcome.points));
    rest.insert("fits".into(), json!(outcome.fits));
    rest.insert("refinements".into(), json!(outcome.refinements));
    rest.insert("step_checks".into(), json!(outcome.step_checks));
    rest.insert("recoveries".into(), json!(outcome.recoveries));
    rest.insert("result".into(), result.clone());
    // Superseded readings (taken while an arm was off) stay in session.json, marked, and
    // out of the export.
    let observations: Vec<Observation> = outcome
        .current_points()
        .filter_map(|p| {
            Some(Observation {
                theta_i_deg: p.theta_i_deg,
                theta_r_deg: p.theta_r_deg,
                radiance_factor: p.radiance_factor?,
                std: p.std,
                theta_r_span_deg: 0.0,
            })
        })
        .collect();
    let meta = crate::output::export::AstmMetadata {
        sample: sample.to_string(),
        instrument: format!("{} serial {}", instrument_name(info), info.serial_number),
        measured_at: std::time::SystemTime::now(),
        acceptance_deg: outcome.analysis_settings.acceptance_deg,
        integration_ms: outcome
            .points
            .first()
            .map_or(0, |p| p.reading.integration_ms),
        white_radiance_factor: outcome.calibration.white_radiance_factor,
        white_relative_uncertainty: outcome.calibration.white_relative_uncertainty,
        white_certificate: outcome.calibration.white_certificate.clone(),
    };
    let mut files = vec![(
        crate::output::export::astm_file_name(sample),
        crate::output::export::astm(&meta, &observations).into_bytes(),
    )];
    // The plots are drawn outside the folder, then replaced into it like every summary file.
    let staging = tempfile::tempdir().context("cannot make a temporary folder for the plots")?;
    for path in crate::output::plots::write_plots(
        staging.path(),
        sample,
        &observations,
        &outcome.report.fit,
        &outcome.report.classification,
    )
    .context("cannot draw the plots")?
    {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .context("a plot without a file name")?;
        files.push((
            name,
            std::fs::read(&path)
                .with_context(|| format!("cannot read the plot {}", path.display()))?,
        ));
    }
    let dir = recorder.dir().to_path_buf();
    recorder
        .finish(rest, &files)
        .with_context(|| format!("cannot write the result into {}", dir.display()))?;
    Ok(result)
}
