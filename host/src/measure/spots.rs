//! A sheet of several spots: one session per spot in `DIR/spot-K`
//! ([`crate::output::folder::sheet`]), the first spot's calibration for all, which spots count
//! decided by [`crate::session::multi_spot`].
use super::spot::run_session;
use super::{Measured, Run, SessionFolder, SpotContext, draw_report, resume_command, status_of};
use crate::analysis::flags::Flag;
use crate::analysis::spots::SpotResult;
use crate::analysis::spots::SpotVerdict;
use crate::instrument::calibration::Calibration;
use crate::instrument::link::Transport;
use crate::output::folder::Status;
use crate::output::folder::lock::FolderError;
use crate::output::folder::record::Existing;
use crate::output::folder::sheet::{SheetFolder, SheetResult, SheetStart, read_sheet, read_spot};
use crate::session::SessionError;
use anyhow::{Context, bail};
use serde::Serialize;
use std::path::Path;

/// How a spot of a sheet ended, when not measured.
enum SpotStop {
    /// The session stopped (see [`Measured::Stopped`]).
    Stopped(SessionError, Option<String>),
    /// Anything else (a folder that cannot be written, a bad calibration…).
    Other(anyhow::Error),
}

/// A sheet of several spots (`--spots N`, or `--resume` of a sheet's folder): one session
/// per spot in `DIR/spot-K` ([`crate::output::folder::sheet`]), the first spot's calibration for all.
pub(super) fn run_sheet<T: Transport>(cx: &mut Run<'_, T>) -> anyhow::Result<Measured> {
    let mut folder = open_sheet(cx)?;
    let dir = folder.dir().to_path_buf();
    let sheet_plan = super::plan::sheet_plan(cx.options, &cx.info, &dir, folder.doc.plan.as_ref())?;
    folder.doc.plan = Some(sheet_plan.clone());
    let resume_with = resume_command(cx.options, &dir);
    folder.start_run(resume_with.clone()).with_context(|| {
        format!(
            "cannot write {}",
            dir.join(crate::output::folder::SHEET).display()
        )
    })?;
    let plan = crate::session::multi_spot::SheetPlan {
        spots: folder.doc.spots_planned,
        replacements: folder.doc.replacements,
    };
    let done = spots_done(cx, &folder)?;
    let first = dir
        .join(crate::output::folder::spot_folder(1))
        .join("calibration.json");
    let mut calibration = if first.is_file() {
        Some(Calibration::load(
            &first,
            cx.checked.max_calibration_age,
            &cx.info,
        )?)
    } else {
        None
    };
    let decisions = std::cell::RefCell::new(Vec::<String>::new());
    let measured = crate::session::multi_spot::measure_sheet(
        plan,
        done,
        |number, of| -> Result<SpotResult, SpotStop> {
            let spot_dir = folder.start_spot(number).map_err(|e| {
                SpotStop::Other(anyhow::anyhow!(
                    "cannot write {}: {e}",
                    dir.join(crate::output::folder::SHEET).display()
                ))
            })?;
            let kind = if spot_dir.join(crate::output::folder::SESSION).is_file() {
                SessionFolder::Resume(spot_dir.clone())
            } else {
                SessionFolder::New(Some(spot_dir.clone()))
            };
            let context = SpotContext {
                number,
                of,
                calibration: calibration.clone(),
                resume_with: resume_with.clone(),
                plan: sheet_plan.clone(),
            };
            match run_session(cx, kind, Some(context)).map_err(SpotStop::Other)? {
                Measured::Done { outcome, .. } => {
                    // Spot 1's calibration as it finished is the sheet's: a resumed spot 1
                    // was handed its folder's calibration as the kill left it, which may
                    // still lack the gain ratios it calibrates on the sample. Keeping that
                    // one gave later spots a calibration spot 1 never converted with.
                    if number == 1 {
                        calibration = Some(outcome.calibration.clone());
                    } else {
                        calibration.get_or_insert_with(|| outcome.calibration.clone());
                    }
                    read_spot(&spot_dir, number)
                        .map(|s| s.result)
                        .map_err(|p| SpotStop::Other(anyhow::anyhow!("{p}")))
                }
                Measured::Stopped {
                    error,
                    record_error,
                    ..
                } => Err(SpotStop::Stopped(error, record_error)),
                Measured::Sheet { .. } => Err(SpotStop::Other(anyhow::anyhow!(
                    "a spot measured as a sheet"
                ))),
            }
        },
        |text| decisions.borrow_mut().push(text.to_string()),
    );
    for text in decisions.into_inner() {
        folder.decision(&text);
    }
    let summary = match measured {
        Ok((_, summary)) => summary,
        Err(stop) => return stopped(&mut folder, stop, &resume_with),
    };
    let _ = cx.client.request(protocol::Command::SetLamp { on: false });
    finish(folder, summary)
}

/// The sheet's folder: a new one, or the interrupted sheet's when the options given are
/// its own.
fn open_sheet<T: Transport>(cx: &mut Run<'_, T>) -> anyhow::Result<SheetFolder> {
    let args = cx.options;
    let sample = args
        .sample
        .clone()
        .or(cx.sim_sample.clone())
        .unwrap_or_else(|| "sample".into());
    let folder = match &args.resume {
        Some(dir) => {
            let folder = SheetFolder::open(dir, cx.store.clone())?;
            if let Some(spots) = args.spots.filter(|n| *n != folder.doc.spots_planned) {
                bail!(
                    "{} is a sheet of {} spots: it is continued as it began (without --spots, or --spots {}), not with --spots {spots}",
                    dir.display(),
                    folder.doc.spots_planned,
                    folder.doc.spots_planned
                );
            }
            if cx
                .checked
                .case
                .as_ref()
                .is_some_and(|c| Some(c) != folder.doc.case.as_ref())
            {
                bail!(
                    "{} was measured under other case fields ({:?}): a sheet is continued as it began (leave out --case, --operator and --note)",
                    dir.display(),
                    folder.doc.case
                );
            }
            if args
                .sample
                .as_ref()
                .is_some_and(|s| *s != folder.doc.sample)
            {
                bail!(
                    "{} is a sheet of '{}', not of '{sample}': a sheet is continued as it began",
                    dir.display(),
                    folder.doc.sample
                );
            }
            folder
        }
        None => {
            // The plan and the case fields are in the first sheet.json: a sheet killed
            // before its first run began is resumed under them, not under the defaults.
            let first = SheetStart {
                case: cx.checked.case.clone(),
                plan: Some(super::plan::plan_record(args, &cx.info, None)?),
            };
            match &args.out {
                Some(dir) => SheetFolder::create(
                    dir,
                    &sample,
                    cx.checked.spots,
                    crate::analysis::spots::MAX_REPLACEMENTS,
                    first,
                    cx.store.clone(),
                )?,
                None => SheetFolder::create_default(
                    Path::new("sessions"),
                    &sample,
                    cx.checked.spots,
                    crate::analysis::spots::MAX_REPLACEMENTS,
                    first,
                    cx.store.clone(),
                )?,
            }
        }
    };
    Ok(folder)
}

/// Spots of an earlier run: finished ones count as they are; the first unfinished one
/// (resumed next) ends the list.
fn spots_done<T: Transport>(
    cx: &Run<'_, T>,
    folder: &SheetFolder,
) -> anyhow::Result<Vec<SpotResult>> {
    let dir = folder.dir();
    let mut done: Vec<SpotResult> = Vec::new();
    for entry in folder.doc.spots.clone() {
        let spot_dir = dir.join(&entry.folder);
        match Existing::open(&spot_dir, cx.store.clone()) {
            Err(FolderError::Finished { .. }) => done.push(
                read_spot(&spot_dir, entry.number)
                    .map_err(|p| anyhow::anyhow!("{p}"))?
                    .result,
            ),
            Ok(_) | Err(FolderError::NoSession(_) | FolderError::NoFolder(_)) => break,
            Err(e) => return Err(e.into()),
        }
    }
    Ok(done)
}

/// A sheet whose spot stopped: the sheet's folder says why; a session that stopped is
/// [`Measured::Stopped`], anything else an error naming the command that continues.
fn stopped(
    folder: &mut SheetFolder,
    stop: SpotStop,
    resume_with: &str,
) -> anyhow::Result<Measured> {
    let dir = folder.dir().to_path_buf();
    match stop {
        SpotStop::Stopped(error, record_error) => {
            let sheet_error = folder
                .stop(status_of(&error), &error.to_string())
                .err()
                .map(|e| e.to_string());
            Ok(Measured::Stopped {
                dir,
                error,
                record_error: record_error.or(sheet_error),
            })
        }
        SpotStop::Other(error) => {
            let _ = folder.stop(Status::Failed, &crate::text::error_chain(&error));
            Err(error.context(format!(
                "the sheet in {} stopped; continue it with {resume_with}",
                dir.display()
            )))
        }
    }
}

/// The sheet's result written from its spots' folders, its report drawn, the sheet read
/// back.
fn finish(
    mut folder: SheetFolder,
    summary: crate::analysis::spots::SheetSummary,
) -> anyhow::Result<Measured> {
    let dir = folder.dir().to_path_buf();
    let spots: Vec<crate::output::folder::sheet::ReadSpot> = folder
        .doc
        .spots
        .iter()
        .map(|s| read_spot(&dir.join(&s.folder), s.number))
        .collect::<Result<_, _>>()
        .map_err(|p| anyhow::anyhow!("{p}"))?;
    let result = SheetResult {
        summary,
        device_seconds: spots.iter().map(|s| s.seconds.0).sum(),
        setup_seconds: spots.iter().map(|s| s.seconds.1).sum(),
        spot_classes: spots.iter().map(|s| s.session.class.clone()).collect(),
    };
    folder
        .finish(result)
        .with_context(|| format!("cannot write the sheet's result into {}", dir.display()))?;
    draw_report(&dir);
    let sheet = read_sheet(&dir).map_err(|p| anyhow::anyhow!("{p}"))?;
    let json = sheet_json(&sheet);
    Ok(Measured::Sheet {
        dir,
        sheet: Box::new(sheet),
        json,
    })
}

/// The `--json` object of a sheet (`gonio-sheet-result/2`). Written through
/// [`serde_json::Value`], whose keys are sorted: the order of the fields does not matter.
#[derive(Serialize)]
struct SheetResultDocument<'a> {
    accepted: usize,
    flagged: usize,
    measured: usize,
    answer: Option<&'a crate::analysis::spots::SheetAnswer>,
    device_seconds: Option<f64>,
    flags: &'a [Flag],
    notes: &'a [String],
    ok: bool,
    rho_d: Option<f64>,
    rho_s: Option<f64>,
    sample: &'a str,
    schema: &'static str,
    session_dir: String,
    setup_seconds: Option<f64>,
    sigma_deg: Option<f64>,
    spots: Vec<SheetSpotDocument<'a>>,
    spots_planned: u16,
    within_log_covariance: Option<[[f64; 3]; 3]>,
    within_relative_sd: Option<[f64; 3]>,
}

/// One spot of [`SheetResultDocument`].
#[derive(Serialize)]
struct SheetSpotDocument<'a> {
    class: Option<&'a str>,
    flags: &'a [Flag],
    folder: String,
    number: u16,
    rho_d: Option<f64>,
    rho_s: Option<f64>,
    sigma_deg: Option<f64>,
    verdict: Option<&'a SpotVerdict>,
}

/// The `--json` object of a sheet.
fn sheet_json(sheet: &crate::output::folder::sheet::ReadSheet) -> serde_json::Value {
    let summary = &sheet.summary;
    let result = sheet.doc.result.as_ref();
    let spots = sheet
        .spots
        .iter()
        .map(|s| SheetSpotDocument {
            class: s.session.class.as_deref(),
            flags: &s.result.flags,
            folder: s.dir.display().to_string(),
            number: s.result.number,
            rho_d: s.session.values[2],
            rho_s: s.session.values[1],
            sigma_deg: s.session.values[0],
            verdict: summary
                .verdicts
                .iter()
                .find(|j| j.number == s.result.number)
                .map(|j| &j.verdict),
        })
        .collect();
    let counts = sheet.counts();
    let document = SheetResultDocument {
        accepted: counts.accepted,
        flagged: counts.flagged,
        measured: counts.measured,
        answer: summary.answer.as_ref(),
        device_seconds: result.map(|r| r.device_seconds),
        flags: &summary.flags,
        notes: &summary.notes,
        ok: summary.ok(),
        rho_d: summary.mean[2],
        rho_s: summary.mean[1],
        sample: &sheet.doc.sample,
        schema: crate::schema::SHEET_RESULT,
        session_dir: sheet.dir.display().to_string(),
        setup_seconds: result.map(|r| r.setup_seconds),
        sigma_deg: summary.mean[0],
        spots,
        spots_planned: sheet.doc.spots_planned,
        within_log_covariance: summary.within_log_covariance,
        within_relative_sd: summary.within_relative_sd,
    };
    serde_json::to_value(&document).expect("a sheet's result serialises to JSON")
}
