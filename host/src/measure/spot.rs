//! One session (a whole measurement, or one spot of a sheet) in its folder: the folder
//! made or resumed, the session run, the instrument left safe, the result written.
use super::plan::{external_calibration, plan_of, plan_record};
use super::write::write_session;
use super::{Measured, Run, SessionFolder, SpotContext, draw_report, resume_command, status_of};
use crate::instrument::link::Transport;
use crate::output::folder::Status;
use crate::output::folder::record::{Existing, FileRecorder, Identity};
use crate::session::Recorder as _;
use crate::session::{Session, SessionError};
use anyhow::{Context, bail};
use std::path::Path;

/// One session (a whole measurement, or one spot of a sheet) in `folder`.
pub(super) fn run_session<T: Transport>(
    cx: &mut Run<'_, T>,
    folder: SessionFolder,
    spot: Option<SpotContext>,
) -> anyhow::Result<Measured> {
    let (args, checked, info) = (cx.options, cx.checked, cx.info.clone());
    let Opened {
        mut recorder,
        points,
        calibration,
        sample,
        plan,
    } = open_record(cx, &folder, spot.as_ref())?;
    let dir = recorder.dir().to_path_buf();
    cx.operator.attach_progress(&recorder.bar);
    recorder.set_resume_with(
        spot.as_ref()
            .map_or_else(|| resume_command(args, &dir), |s| s.resume_with.clone()),
    );
    let resumed = matches!(folder, SessionFolder::Resume(_));
    if let (Some(c), false) = (&calibration, dir.join("calibration.json").exists()) {
        recorder
            .calibration(c)
            .with_context(|| format!("cannot write {}", dir.join("calibration.json").display()))?;
    }
    cx.client.set_interrupt(Some(cx.interrupted.clone()));
    let mut session = Session::new(
        cx.client,
        info.clone(),
        plan_of(&plan, &sample),
        &mut recorder,
        cx.operator,
    )
    .with_calibration_limit(checked.max_calibration_age)
    .with_tile(checked.tile.clone())
    .with_arm_zero_uncertainty(args.arm_zero_uncertainty_deg)
    .with_model_extensions(plan.model_choice()?.extensions())
    .with_profile(cx.profile.clone());
    if let Some(spot) = &spot {
        session = session.at_spot(spot.number, spot.of);
    }
    let outcome = session.resume_from(calibration, points).run();
    recorder.bar.finish_and_clear();
    let mut outcome = match outcome {
        Ok(outcome) => outcome,
        Err(error) => return Ok(stopped(cx, &mut recorder, dir, error)),
    };
    // The lamp stays on between the spots of a sheet: the calibration holds for its output.
    if spot.as_ref().is_none_or(|s| s.number >= s.of) {
        let _ = cx.client.request(protocol::Command::SetLamp { on: false });
    }
    if resumed
        && !outcome
            .flags
            .contains(&crate::analysis::flags::Flag::Resumed)
    {
        outcome.flags.push(crate::analysis::flags::Flag::Resumed);
    }
    // The report names the session's folder, not the file name of its readings inside it.
    outcome.report.file = dir.display().to_string();
    match write_session(&mut recorder, &sample, &info, &outcome) {
        Ok(summary) => {
            // A spot's report is its sheet's.
            if spot.is_none() {
                draw_report(&dir);
            }
            Ok(Measured::Done {
                dir,
                outcome: Box::new(outcome),
                summary,
            })
        }
        Err(e) => {
            let why = format!(
                "the session was measured but its result could not be written: {}",
                crate::text::error_chain(&e)
            );
            let _ = recorder.stop(Status::Failed, &why);
            let how = spot.as_ref().map_or_else(
                || format!("gonio measure --resume {}", dir.display()),
                |s| s.resume_with.clone(),
            );
            bail!(
                "{why}; every reading is in {}: {how} writes the result",
                dir.display()
            )
        }
    }
}

/// A session's folder, made or resumed, and what the session starts from.
struct Opened {
    recorder: FileRecorder,
    /// The readings of an earlier run.
    points: Vec<crate::session::MeasuredPoint>,
    /// The session's own calibration, else the one given (the sheet's, `--calibration`).
    calibration: Option<crate::instrument::calibration::Calibration>,
    sample: String,
    plan: crate::output::folder::PlanRecord,
}

/// Make the session's folder, or take the interrupted one's when the sample, instrument,
/// plan and calibration are its own.
fn open_record<T: Transport>(
    cx: &mut Run<'_, T>,
    folder: &SessionFolder,
    spot: Option<&SpotContext>,
) -> anyhow::Result<Opened> {
    let (args, checked, info) = (cx.options, cx.checked, &cx.info);
    let existing = match folder {
        SessionFolder::Resume(dir) => Some(Existing::open(dir, cx.store.clone())?),
        SessionFolder::New(_) => None,
    };
    let sample = args
        .sample
        .clone()
        .or(cx.sim_sample.clone())
        .or_else(|| existing.as_ref().map(|e| e.doc().sample.clone()))
        .unwrap_or_else(|| "sample".into());
    let plan = match spot {
        // A spot of a sheet is measured under the sheet's plan, whatever its own folder says:
        // a spot whose recorded plan differs is refused by `check_matches`, by name.
        Some(spot) => spot.plan.clone(),
        None => plan_record(args, info, existing.as_ref().map(|e| &e.doc().plan))?,
    };
    let mut identity = Identity::new(&sample, info, plan.clone());
    identity.instrument.simulated_sample = cx.sim_sample.clone();
    identity.instrument.simulated_seed =
        cx.sim_sample.as_ref().map(|_| cx.options.sim_options.seed);
    identity.case = checked.case.clone();
    let sheet_calibration = spot.and_then(|s| s.calibration.clone());
    let given_calibration = match (&sheet_calibration, &args.calibration) {
        (Some(sheet), _) => Some(sheet.clone()),
        (None, Some(path)) => Some(external_calibration(path, checked, info)?),
        (None, None) => None,
    };
    let (recorder, points, calibration) = match existing {
        Some(existing) => {
            existing.check_matches(&identity)?;
            if let Some(own) = existing.calibration() {
                let file = existing_path(folder, "calibration.json");
                own.check(&file, checked.max_calibration_age, info)?;
                // A resumed spot keeps the calibration its readings were converted with
                // (a sheet written before the fix of issue 30 D1 may hold a spot whose
                // calibration lacks spot 1's gain ratios); only an explicit --calibration
                // that differs is refused, and only it is named.
                if sheet_calibration.is_none()
                    && given_calibration.as_ref().is_some_and(|given| given != own)
                {
                    bail!(
                        "--calibration differs from the calibration the session's readings were converted with ({file}): a session keeps one calibration; resume without --calibration"
                    );
                }
            }
            let (recorder, points, own) = existing.resume(cx.store.clone())?;
            (recorder, points, own.or(given_calibration))
        }
        None => {
            let recorder = match folder {
                SessionFolder::New(Some(dir)) => {
                    FileRecorder::create(dir, identity, cx.store.clone())?
                }
                _ => {
                    FileRecorder::create_default(Path::new("sessions"), identity, cx.store.clone())?
                }
            };
            (recorder, Vec::new(), given_calibration)
        }
    };
    Ok(Opened {
        recorder,
        points,
        calibration,
        sample,
        plan,
    })
}

/// A session that ended early: the instrument left safe (arms stopped, lamp off; the
/// readings are on disk already; a second Ctrl-C must not stop this) and the folder told why.
fn stopped<T: Transport>(
    cx: &mut Run<'_, T>,
    recorder: &mut FileRecorder,
    dir: std::path::PathBuf,
    error: SessionError,
) -> Measured {
    cx.client.set_interrupt(None);
    let _ = cx.client.request(protocol::Command::Abort);
    let _ = cx.client.request(protocol::Command::SetLamp { on: false });
    let record_error = recorder
        .stop(status_of(&error), &error.to_string())
        .err()
        .map(|e| e.to_string());
    Measured::Stopped {
        dir,
        error,
        record_error,
    }
}

/// A file of the resumed folder, for messages.
fn existing_path(folder: &SessionFolder, name: &str) -> String {
    match folder {
        SessionFolder::Resume(dir) => dir.join(name).display().to_string(),
        SessionFolder::New(_) => name.to_string(),
    }
}
