//! A finished session's result into its folder: the summary files (the ASTM export, the
//! plots), `session.json` and the manifest.
use crate::analysis::fit::Observation;
use crate::analysis::result::ResultDocument;
use crate::instrument::calibration::instrument_name;
use crate::output::folder::documents::{FinishedSession, SpotResultDocument};
use crate::output::folder::record::FileRecorder;
use crate::session::Outcome;
use anyhow::Context;

/// Write the result into the folder (summary files, `session.json`, the manifest) and
/// return the result object printed by `--json`.
pub(super) fn write_session(
    recorder: &mut FileRecorder,
    sample: &str,
    info: &protocol::DeviceInfo,
    outcome: &Outcome,
) -> anyhow::Result<serde_json::Value> {
    // The analysis's own document, with the session's verdict in place of the analysis's
    // and without `file` (the folder is `session_dir`).
    let mut analysis = ResultDocument::of(&outcome.report);
    analysis.sample = sample.to_string();
    analysis.ok = outcome.ok();
    analysis.flags = outcome.flags.clone();
    analysis.file = None;
    analysis.schema = crate::schema::SPOT_RESULT.to_string();
    let covariance = outcome
        .report
        .fit
        .covariance
        .map(|row| row.map(|x| x.is_finite().then_some(x)));
    let result = SpotResultDocument {
        analysis,
        // What `gonio fit DIR` needs to make this analysis again from the folder.
        analysed_unix_s: Some(outcome.analysed_unix_s),
        analysis_settings: Some(outcome.analysis_settings.clone()),
        covariance: Some(covariance),
        device_seconds: Some(outcome.device_seconds),
        geometries: Some(outcome.usable_readings() as u64),
        instrument_bound: outcome.instrument_bound.clone(),
        // Gloss rests on the response and zero measured on the black glass: only with a
        // profile in force.
        gloss: outcome
            .analysis_settings
            .instrument_profile
            .as_ref()
            .map(|_| {
                crate::output::folder::documents::gloss_values(
                    &outcome.report.fit.params,
                    &outcome.report.fit.covariance,
                    info.arm_max.deg(),
                )
            }),
        refinements: outcome.refinements.clone(),
        session_dir: Some(recorder.dir().display().to_string()),
        setup_seconds: Some(outcome.setup_seconds),
        white_drift: outcome.white_drift,
        white_drift_exceeded: outcome.white_drift_exceeded,
    };
    let finished = FinishedSession {
        calibration: &outcome.calibration,
        fits: &outcome.fits,
        flags: &outcome.flags,
        ok: outcome.ok(),
        readings: &outcome.points,
        recoveries: &outcome.recoveries,
        refinements: &outcome.refinements,
        result: &result,
        step_checks: &outcome.step_checks,
    };
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
    files.push(shared_errors_file(recorder, sample, outcome)?);
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
        .finish(&finished, &files)
        .with_context(|| format!("cannot write the result into {}", dir.display()))?;
    Ok(result.to_value())
}

/// `readings.shared-errors.json`: what the analysis weighed readings.csv with besides each
/// reading's own noise; with it the folder's data alone re-analyse to this result
/// (`gonio fit readings.csv`). Tied to the readings.csv on disk by its SHA-256.
fn shared_errors_file(
    recorder: &FileRecorder,
    sample: &str,
    outcome: &Outcome,
) -> anyhow::Result<(String, Vec<u8>)> {
    let readings_path = recorder.dir().join(crate::output::folder::READINGS);
    let readings_csv = std::fs::read(&readings_path)
        .with_context(|| format!("cannot read {}", readings_path.display()))?;
    let bytes = crate::output::shared_errors::document_bytes(
        sample,
        &outcome.points,
        &outcome.calibration,
        &outcome.analysis_settings,
        outcome.analysed_unix_s,
        &readings_csv,
    )
    .context("cannot write the readings' shared errors")?;
    Ok((
        crate::output::shared_errors::SHARED_ERRORS.to_string(),
        bytes,
    ))
}
