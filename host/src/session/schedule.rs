//! Measuring a stage: the geometries it wants and any still missing, as the built-in
//! Strategy 1 or an uploaded list in the fastest visiting order, the stream recorded as it
//! arrives, what the link lost measured again.
use super::recovery::Failure;
use super::{MeasuredPoint, Progress, Session, SessionError, StepError};
use crate::instrument::link::{LinkError, Transport};
use protocol::schedules::strategy1;
use protocol::{
    Command, DeviceMessage, ErrorCode, Geometry, Reading, Reply, RunSchedule, SCHEDULE_CHUNK_LEN,
    ScheduleChunk, ScheduleSource, Target,
};
use std::collections::BTreeSet;
use std::time::Duration;

/// Rounds of a stage without a new reading before the session gives up on it.
const MAX_STALLED_ROUNDS: u32 = 6;

/// Where a stage's missing geometries come from.
enum ScheduleList<'l> {
    /// The instrument's built-in Strategy 1.
    BuiltIn,
    /// This list, uploaded.
    Upload(&'l [Geometry]),
}

impl<T: Transport> Session<'_, T> {
    /// Measure every geometry of `schedule` (and any wanted one still missing) not yet
    /// measured, measuring again what the link lost.
    pub(super) fn measure(
        &mut self,
        stage: &str,
        schedule: &[Geometry],
    ) -> Result<(), SessionError> {
        for g in schedule {
            if !self.wanted.contains(g) {
                self.wanted.push(*g);
            }
        }
        let builtin: BTreeSet<Geometry> = strategy1(12)
            .map(|s| s.iter().copied().collect())
            .unwrap_or_default();
        self.recorder.stage(stage, schedule.len());
        let mut stalled = 0;
        let mut round = 0;
        loop {
            let missing = self.missing();
            if missing.is_empty() {
                // The gain ratios the readings now use, calibrated where they were not yet
                // (`gains`); every reading is converted again with them.
                return self.calibrate_gains();
            }
            round += 1;
            self.within_device_time()?;
            if round > 1 {
                self.remeasure_round(&format!("{} geometries", missing.len()))?;
                self.link.recoveries.readings_remeasured += missing.len();
                self.decide(&format!(
                    "measuring again {} geometries lost on the link or superseded (round {round})",
                    missing.len()
                ));
            }
            let before = self.points.len();
            let list = if missing.iter().copied().collect::<BTreeSet<_>>() == builtin {
                ScheduleList::BuiltIn
            } else {
                ScheduleList::Upload(&missing)
            };
            match self.run_schedule(list, schedule.len().max(missing.len())) {
                Ok(()) => {}
                Err(StepError::Failure(failure)) => self.recover(failure)?,
                Err(StepError::Fatal(error)) => return Err(error),
            }
            if self.points.len() == before {
                stalled += 1;
                if stalled >= MAX_STALLED_ROUNDS {
                    return Err(SessionError::GaveUp(format!(
                        "{} geometries still missing after {stalled} rounds without a reading: the link or the instrument is failing",
                        self.missing().len()
                    )));
                }
            } else {
                stalled = 0;
            }
        }
    }

    /// Run the built-in Strategy 1 or upload and run a list, recording readings.
    fn run_schedule(&mut self, list: ScheduleList<'_>, stage_len: usize) -> Result<(), StepError> {
        let schedule_id = self.next_schedule_id;
        self.next_schedule_id = self.next_schedule_id.wrapping_add(1).max(1);
        // A stop the host did not hear would let the schedule run in the dark.
        if let Some(failure) = self.lamp_went_out().map_err(StepError::Fatal)? {
            return Err(StepError::Failure(failure));
        }
        let source = match list {
            ScheduleList::BuiltIn => ScheduleSource::Strategy1,
            ScheduleList::Upload(list) => {
                // The firmware visits a list in the order sent: send the fastest.
                let here = self.status().map_err(StepError::Fatal)?.position;
                let planned = crate::session::order::plan(&self.motion, here, list);
                if list.len() > 1 {
                    self.decide(&format!(
                        "visiting order of {} geometries: {:.2} s of travel, {:.3}× the {} and {:.2}× the order listed",
                        list.len(),
                        planned.travel_us as f64 * 1e-6,
                        planned.travel_ratio_to_best(),
                        if planned.exact { "fastest" } else { "lower bound" },
                        planned.travel_ratio_to_given()
                    ));
                }
                let list = planned.order.as_slice();
                let total_len = list.len() as u16;
                for (k, chunk) in list.chunks(SCHEDULE_CHUNK_LEN).enumerate() {
                    let geometries = heapless::Vec::from_slice(chunk).unwrap_or_default();
                    let offset = (k * SCHEDULE_CHUNK_LEN) as u16;
                    self.request(Command::UploadSchedule(ScheduleChunk {
                        schedule_id,
                        total_len,
                        offset,
                        geometries,
                    }))?;
                }
                ScheduleSource::Uploaded
            }
        };
        let run = RunSchedule {
            schedule_id,
            source,
            integration_ms: self.plan.integration_ms,
            target: Target::Sample,
        };
        let len = match self.request(Command::RunSchedule(run))? {
            Reply::ScheduleStarted { len, .. } => len,
            other => {
                return Err(StepError::Fatal(
                    LinkError::UnexpectedReply {
                        command: "RunSchedule",
                        reply: Box::new(other),
                    }
                    .into(),
                ));
            }
        };
        let mut seen = BTreeSet::new();
        let already = stage_len.saturating_sub(usize::from(len));
        let started = self.now();
        loop {
            let message = self
                .client
                .next_unsolicited(Duration::from_secs(5))
                .map_err(StepError::from_link)?;
            match message {
                Some(DeviceMessage::Reading(r)) if r.schedule_id == schedule_id => {
                    if !seen.insert(r.index) {
                        continue; // a duplicate
                    }
                    self.record(
                        r.geometry,
                        r.reading,
                        schedule_id,
                        r.index,
                        r.device_time_us,
                    )
                    .map_err(StepError::Fatal)?;
                    let done = seen.len();
                    let per_reading = (self.now() - started) / done as u32;
                    let remaining =
                        per_reading * (usize::from(len) - done.min(usize::from(len))) as u32;
                    self.recorder.progress(Progress {
                        done: already + done,
                        planned: stage_len,
                        remaining,
                    });
                }
                Some(DeviceMessage::ScheduleDone(done)) if done.schedule_id == schedule_id => {
                    return match done.error {
                        None | Some(ErrorCode::Aborted) => self.lit_throughout(schedule_id),
                        Some(reason) => Err(StepError::Failure(Failure::Stopped(reason))),
                    };
                }
                Some(DeviceMessage::Stopped { reason }) => {
                    return Err(StepError::Failure(Failure::Stopped(reason)));
                }
                // Stale messages of an earlier schedule: nothing to do with this one.
                Some(_) => {}
                // Silence: the end may have been lost on the link. Ask.
                None => {
                    let status = self.request(Command::GetStatus)?;
                    if let Reply::Status(status) = status
                        && status.schedule.is_none_or(|(id, _)| id != schedule_id)
                    {
                        return self.lit_throughout(schedule_id);
                    }
                }
            }
        }
    }

    /// After a schedule ended: if the lamp is off now, it went off during the schedule
    /// (a stop whose message was lost) and some of its readings may be dark. Which ones
    /// cannot be told: all of them are superseded and measured again.
    pub(super) fn lit_throughout(&mut self, schedule_id: u16) -> Result<(), StepError> {
        let Some(failure) = self.lamp_went_out().map_err(StepError::Fatal)? else {
            return Ok(());
        };
        let why = format!(
            "the lamp was off at the end of schedule {schedule_id}: its readings may be dark"
        );
        let superseded = self
            .supersede_schedule(schedule_id, &why)
            .map_err(StepError::Fatal)?;
        self.decide(&format!(
            "{why}; {superseded} readings superseded and measured again"
        ));
        Err(StepError::Failure(failure))
    }

    fn record(
        &mut self,
        geometry: Geometry,
        reading: Reading,
        schedule_id: u16,
        index: u16,
        device_time_us: u64,
    ) -> Result<(), SessionError> {
        let (theta_i_deg, theta_r_deg) = (geometry.theta_i.deg(), geometry.theta_r.deg());
        let calibration = self
            .calibration
            .as_ref()
            .ok_or(SessionError::Fit("no calibration".into()))?;
        let mut point = MeasuredPoint {
            theta_i_deg,
            theta_r_deg,
            theta_r_span_deg: 0.0,
            radiance_factor: None,
            std: None,
            reading,
            schedule_id,
            index,
            device_time_us,
            note: None,
            superseded: false,
            unusable: None,
        };
        point.convert_with(calibration);
        self.recorder.point(&point).map_err(SessionError::record)?;
        self.points.push(point);
        Ok(())
    }
}
