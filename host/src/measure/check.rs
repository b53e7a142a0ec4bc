//! The options checked before anything is connected, moved or written.
use super::{DEFAULT_SPOTS, MAX_SPOTS, MeasureOptions};
use crate::analysis::calibration::{Tile, max_age_from_hours};
use anyhow::{Context, bail};
use std::time::Duration;

/// Options checked before anything is connected.
pub(super) struct Checked {
    pub(super) max_calibration_age: Duration,
    pub(super) tile: Tile,
    pub(super) spots: u16,
    pub(super) case: Option<crate::output::folder::CaseRecord>,
}

pub(super) fn check(args: &MeasureOptions) -> anyhow::Result<Checked> {
    let max_calibration_age = max_age_from_hours(args.max_calibration_age_h)
        .map_err(|e| crate::UsageError(format!("{e:#}")))?;
    if let Some(limit) = args.white_drift_limit_pct
        && !(limit > 0.0 && limit <= 100.0)
    {
        crate::usage_bail!(
            "--white-drift-limit-pct must be a percentage above 0 and at most 100, not {limit:?}"
        );
    }
    if let Some(sample) = &args.sample
        && (sample.trim().is_empty() || sample.chars().any(char::is_control))
    {
        crate::usage_bail!("--sample must be a name (no control characters), not {sample:?}");
    }
    let tile = match &args.tile_certificate {
        Some(path) => crate::instrument::calibration::TileCertificate::read(
            path,
            chrono::Local::now().date_naive(),
        )
        .and_then(|c| c.tile())
        .context("--tile-certificate")?,
        None => Tile::new(args.tile_radiance_factor, args.tile_uncertainty_pct).map_err(|e| {
            crate::UsageError(format!(
                "--tile-radiance-factor / --tile-uncertainty-pct: {e}"
            ))
        })?,
    };
    let zero = args.arm_zero_uncertainty_deg;
    if !(0.0..=5.0).contains(&zero) {
        crate::usage_bail!(
            "--arm-zero-uncertainty-deg must be between 0 and 5 degrees, not {zero:?}"
        );
    }
    let spots = args.spots.unwrap_or(DEFAULT_SPOTS);
    if !(1..=MAX_SPOTS).contains(&spots) {
        crate::usage_bail!("--spots must be 1 to {MAX_SPOTS}, not {spots}");
    }
    for (option, value) in [
        ("--case", &args.case_id),
        ("--operator", &args.operator),
        ("--note", &args.note),
    ] {
        if let Some(v) = value
            && (v.trim().is_empty() || v.chars().any(char::is_control) || v.chars().count() > 500)
        {
            crate::usage_bail!(
                "{option} must be text of 1 to 500 characters without control characters, not {v:?}"
            );
        }
    }
    let case = crate::output::folder::CaseRecord {
        case_id: args.case_id.clone(),
        operator: args.operator.clone(),
        note: args.note.clone(),
        orientation: args.orientation,
        side: args.side,
    };
    Ok(Checked {
        max_calibration_age,
        tile,
        spots,
        case: (!case.is_empty()).then_some(case),
    })
}

/// A regular file or a folder given as `--port` is no serial port: say so before opening it.
pub(super) fn check_port(path: &str) -> anyhow::Result<()> {
    let meta = match std::fs::metadata(path) {
        Ok(meta) => meta,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("--port {path}: no such port (gonio ports lists the serial ports)")
        }
        Err(e) => bail!("cannot open --port {path}: {e}"),
    };
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let kind = meta.file_type();
        if !kind.is_char_device() {
            let what = if kind.is_dir() {
                "a folder"
            } else if kind.is_file() {
                "a regular file"
            } else {
                "not a device"
            };
            bail!(
                "--port {path} is not a serial port (it is {what}): give the instrument's port, e.g. /dev/ttyACM0 (gonio ports lists them)"
            );
        }
    }
    #[cfg(not(unix))]
    let _ = meta;
    Ok(())
}
