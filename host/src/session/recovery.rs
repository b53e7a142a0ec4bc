//! Recovery: from a broken link, a refusal or a stop of the instrument back to a known
//! state, before anything else is sent.
//!
//! The host never assumes what the instrument did while it could not hear it (Klipper's
//! rule). After ANY reconnection, refusal or fail-safe stop it reads the instrument's
//! state (`GetStatus`) and brings it to a known one:
//! 1. what still runs is waited for (a homing, a move, a reading: they end by
//!    themselves) or aborted (a schedule: what it missed is measured again);
//! 2. the arms are homed again only when the homing was really lost (the status's homed
//!    flags: a stop while the arms stand still keeps it), and that Home's step errors
//!    are a lost-steps check like any other (`steps`);
//! 3. the lamp is lit again if it went off while the session needed it.
//!
//! Then the step that failed is made again from its start.
//!
//! One deadline bounds it all: [`crate::instrument::link::RetryPolicy::give_up_after`]
//! (10 s) of silence from the instrument, on the transport's clock. Within it the host
//! re-opens the port (after an I/O error) and says hello again, as often as it takes;
//! past it, it gives up saying whether the port went away or stayed but fell silent,
//! with the decisions so far. Refusals the host cannot mend (a hardware fault, a target
//! out of range, a command the firmware lacks) end the session with what they mean.
use super::{LinkLoss, Session, SessionError, StepError};
use crate::instrument::link::{LinkError, Transport};
use protocol::{Command, DeviceError, DeviceState, ErrorCode, Reply, Status};
use std::time::Duration;

/// Recoveries in a row for one step (a request, a reading, a stage's round) before the
/// session gives up on it: each recovery heard the instrument, so this only ends a loop
/// of an instrument that answers but cannot do what is asked.
pub(super) const MAX_RECOVERIES: u32 = 8;

/// Between attempts to re-open the port or greet the instrument.
const RECONNECT_PAUSE: Duration = Duration::from_millis(250);

/// How long a reconnection goes on while bytes come from the port but no greeting is
/// answered, on the transport's clock. The silence deadline cannot end it: noise is heard.
/// At 1 % of bytes corrupted a greeting's answer is lost four times in five, so a minute
/// of greetings (about 30, each retried) all fail with a probability far below 10⁻⁶;
/// the greeting under way when the minute ends is finished first (at most
/// [`crate::instrument::link::HANDSHAKE_ROUNDS`] rounds, 32 s), so a session ends within
/// about 92 s of the last frame it could read (issue 30: a device answering only noise kept
/// the session reconnecting for ever).
pub(super) const RECONNECT_LIMIT: Duration = Duration::from_secs(60);

/// How often the state is read while waiting for something that runs to end.
const STATE_POLL: Duration = Duration::from_millis(200);

/// Something the session can recover from.
#[derive(Debug)]
pub(super) enum Failure {
    /// The link broke (an I/O error, silence, no reply, or an instrument that no longer
    /// knows this host): greet the instrument again first.
    Link(LinkError),
    /// The instrument refused a command it can carry out once in a known state.
    Refused {
        /// What was refused.
        command: &'static str,
        /// Why.
        error: DeviceError,
    },
    /// The instrument stopped on its own (its fail-safe stop).
    Stopped(ErrorCode),
}

/// Sort a link error into something to recover from, or the end of the session with
/// what it means.
pub(super) fn classify(error: LinkError) -> Result<Failure, SessionError> {
    match error {
        LinkError::Interrupted => Err(SessionError::Interrupted),
        LinkError::Io(_)
        | LinkError::Silent { .. }
        | LinkError::NoReply { .. }
        | LinkError::NoHandshake { .. } => Ok(Failure::Link(error)),
        LinkError::Device {
            command,
            error: refusal,
        } => match refusal.code {
            // A replug or a reset the host did not see: the instrument wants a hello.
            ErrorCode::VersionMismatch => Ok(Failure::Link(LinkError::Device { command, error: refusal })),
            // The instrument is doing something else, lost its homing, stopped, or lost
            // an upload with the link: all mended from a known state.
            ErrorCode::Busy
            | ErrorCode::NotHomed
            | ErrorCode::HeartbeatLost
            | ErrorCode::Aborted
            | ErrorCode::WatchdogReset
            // The device's own fail-safe stops that leave it whole: re-homed from there.
            | ErrorCode::StepLate
            | ErrorCode::AdcOverrun
            | ErrorCode::NoSchedule
            | ErrorCode::BadSchedule => Ok(Failure::Refused { command, error: refusal }),
            _ => Err(SessionError::Refused { command, error: refusal, advice: advice(command, refusal) }),
        },
        other @ (LinkError::VersionMismatch { .. } | LinkError::UnexpectedReply { .. }) => {
            Err(SessionError::Link(other))
        }
    }
}

fn arm_name(detail: i32) -> &'static str {
    if detail == 1 { "detector" } else { "source" }
}

/// What a refusal the host cannot mend means, and what to do.
fn advice(command: &str, error: DeviceError) -> String {
    match error.code {
        ErrorCode::HardwareFault => "a stepper driver, the detector or the lamp reported a fault: check the instrument's power and cables, then resume the session".into(),
        ErrorCode::HomeSwitchNotFound => format!("the {} arm's home switch did not trip within its search range: check the switch and its wire, then resume", arm_name(error.detail)),
        ErrorCode::HomeSwitchStuck => format!("the {} arm's home switch does not release: check the switch lever, then resume", arm_name(error.detail)),
        ErrorCode::NotSupported => format!("this firmware does not carry out {command}: update the instrument's firmware with `gonio flash` (README, \"Flashing the firmware\")"),
        ErrorCode::OutOfRange => format!("a {command} target outside the {} arm's working range: a host fault, please report it", arm_name(error.detail)),
        ErrorCode::CollisionGuard => format!("a {command} target that would bring the arms together (θi + θr below the guard): a host fault, please report it"),
        ErrorCode::InvalidArgument => format!("a parameter of {command} is outside what the instrument accepts (an integration time, a range): check the options"),
        ErrorCode::ScheduleTooLong => format!("the schedule is longer than the {} geometries the instrument holds", error.detail),
        _ => format!("the instrument's code {} ({}) is not one the host can mend", error.code.code(), error.code.description()),
    }
}

/// How a state reads in a sentence.
fn doing(state: DeviceState) -> &'static str {
    match state {
        DeviceState::Homing => "homing",
        DeviceState::Moving => "moving its arms",
        DeviceState::Measuring => "taking a reading",
        DeviceState::RunningSchedule => "running a schedule",
        DeviceState::Idle => "idle",
        DeviceState::Stopped => "stopped",
        DeviceState::Sweeping => "sweeping",
    }
}

impl<T: Transport> Session<'_, T> {
    /// One request, as it goes: a failure is for the caller to recover from.
    pub(super) fn request(&mut self, command: Command) -> Result<Reply, StepError> {
        self.client
            .request(command)
            .map_err(|e| self.link_failed(e))
    }

    /// Remember an I/O error (to tell a vanished port from a silent instrument) and sort
    /// the error.
    pub(super) fn link_failed(&mut self, error: LinkError) -> StepError {
        if let LinkError::Io(io) = &error {
            self.link.last_io_error = Some(io.to_string());
        }
        StepError::from_link(error)
    }

    /// A request, recovering from failures and sending it again once the instrument is
    /// in a known state. For commands that depend on nothing before them.
    pub(super) fn retrying(&mut self, command: Command) -> Result<Reply, SessionError> {
        for _ in 0..MAX_RECOVERIES {
            match self.request(command.clone()) {
                Ok(reply) => return Ok(reply),
                Err(StepError::Failure(failure)) => self.recover(failure)?,
                Err(StepError::Fatal(error)) => return Err(error),
            }
        }
        Err(SessionError::GaveUp(format!(
            "the instrument still could not carry out a command after {MAX_RECOVERIES} recoveries in a row (see the decisions)"
        )))
    }

    /// The instrument's state, through failures.
    pub(super) fn status(&mut self) -> Result<Status, SessionError> {
        match self.retrying(Command::GetStatus)? {
            Reply::Status(status) => Ok(status),
            other => Err(LinkError::UnexpectedReply {
                command: "GetStatus",
                reply: Box::new(other),
            }
            .into()),
        }
    }

    fn request_status(&mut self) -> Result<Status, StepError> {
        match self.request(Command::GetStatus)? {
            Reply::Status(status) => Ok(status),
            other => Err(StepError::Fatal(
                LinkError::UnexpectedReply {
                    command: "GetStatus",
                    reply: Box::new(other),
                }
                .into(),
            )),
        }
    }

    /// At the start: the instrument in a known state, homed. With `check` (a resumed
    /// session), the arms are checked for lost steps since the earlier readings.
    pub(super) fn ensure_ready(&mut self, check: bool) -> Result<(), SessionError> {
        let mut done = false;
        for _ in 0..MAX_RECOVERIES {
            match self.known_state() {
                Ok(()) => {
                    done = true;
                    break;
                }
                Err(StepError::Failure(failure)) => self.recover(failure)?,
                Err(StepError::Fatal(error)) => return Err(error),
            }
        }
        if !done {
            return Err(SessionError::GaveUp(format!(
                "the instrument could not be made ready after {MAX_RECOVERIES} recoveries (see the decisions)"
            )));
        }
        if check && self.steps.checked_upto < self.points.len() {
            self.check_steps("of the readings taken before the resume")?;
        }
        Ok(())
    }

    /// Recover from `failure`: greet the instrument again if the link broke, then bring
    /// it to a known state. Within the silence deadline, however often it takes.
    pub(super) fn recover(&mut self, failure: Failure) -> Result<(), SessionError> {
        let started = self.now();
        let mut reconnect = match &failure {
            Failure::Link(LinkError::Device { command, error }) => {
                self.decide(&format!("the instrument refused {command} with {error}: it no longer knows this host (re-plugged or reset); greeting it again"));
                true
            }
            Failure::Link(error) => {
                self.decide(&format!("link lost ({error}); reconnecting"));
                true
            }
            Failure::Refused { command, error } => {
                self.link.recoveries.refusals += 1;
                // A refused Home never ran: its report is not lost.
                if *command == "Home" {
                    self.steps.home_in_flight = false;
                }
                self.decide(&format!(
                    "the instrument refused {command}: {error}; reading its state"
                ));
                false
            }
            Failure::Stopped(reason) => {
                self.decide(&format!(
                    "the instrument took its fail-safe stop ({reason}); reading its state"
                ));
                false
            }
        };
        let mut rounds = 0;
        loop {
            rounds += 1;
            if rounds > MAX_RECOVERIES {
                return Err(SessionError::GaveUp(format!(
                    "the instrument could not be brought to a known state in {MAX_RECOVERIES} attempts (see the decisions)"
                )));
            }
            if reconnect {
                self.reconnect()?;
            }
            match self.known_state() {
                Ok(()) => break,
                Err(StepError::Fatal(error)) => return Err(error),
                Err(StepError::Failure(Failure::Link(error))) => {
                    self.decide(&format!(
                        "link lost again while recovering ({error}); reconnecting"
                    ));
                    reconnect = true;
                }
                Err(StepError::Failure(failure)) => {
                    self.decide(&format!(
                        "while recovering: {failure:?}; reading the state again"
                    ));
                    reconnect = false;
                    // Busy: something still runs that the state did not show (the arms
                    // ramping down from a fail-safe stop read `Stopped`, and a Home is
                    // refused until they rest): give it a poll's time, or every round
                    // goes by within milliseconds.
                    if let Failure::Refused { error: refusal, .. } = &failure
                        && refusal.code == ErrorCode::Busy
                        && let Err(lost) = self.client.keep_alive(STATE_POLL)
                    {
                        match self.link_failed(lost) {
                            StepError::Failure(Failure::Link(_)) => reconnect = true,
                            StepError::Failure(_) => {}
                            StepError::Fatal(error) => return Err(error),
                        }
                    }
                }
            }
        }
        self.link.recoveries.state_recoveries += 1;
        self.link.recoveries.seconds += (self.now() - started).as_secs_f64();
        Ok(())
    }

    /// Re-open the port if it failed, and say hello, until the instrument answers or the
    /// silence deadline passes.
    fn reconnect(&mut self) -> Result<(), SessionError> {
        let give_up_after = self.client.policy().give_up_after;
        let lost_at = self.now().saturating_sub(self.client.silent_for());
        let mut reopen = self.link.last_io_error.is_some();
        let garbled_before = self.client.stats().bad_frames;
        loop {
            // A Ctrl-C is the operator's, whatever the port does: a port that cannot be
            // re-opened must not hide it until the give-up time (issue 30 D3).
            if self.client.interrupted() {
                return Err(SessionError::Interrupted);
            }
            let silent_for = self.client.silent_for();
            if silent_for >= give_up_after {
                return Err(self.give_up(silent_for));
            }
            let trying_for = self.now().saturating_sub(lost_at);
            if trying_for >= RECONNECT_LIMIT {
                let garbled = self.client.stats().bad_frames - garbled_before;
                return Err(self.give_up_unreadable(trying_for, garbled));
            }
            if reopen && let Err(error) = self.client.transport_mut().reconnect() {
                self.link.last_io_error = Some(error.to_string());
                self.client
                    .transport_mut()
                    .pause(RECONNECT_PAUSE.min(give_up_after - silent_for));
                continue;
            }
            match self.client.hello() {
                Ok(info) => {
                    if info.serial_number != self.info.serial_number {
                        let error = SessionError::OtherInstrument {
                            expected: self.info.serial_number.to_string(),
                            found: info.serial_number.to_string(),
                        };
                        self.decide(&error.to_string());
                        return Err(error);
                    }
                    self.client.clear_unsolicited();
                    self.link.last_io_error = None;
                    self.link.recoveries.reconnections += 1;
                    let outage = (self.now() - lost_at).as_secs_f64();
                    self.decide(&format!("link back: the instrument greeted again, {outage:.1} s after it was last heard"));
                    // A restart the host did not see: say why (the state recovery re-homes).
                    if info.reset_cause.fault().is_some() {
                        self.decide(&format!(
                            "the instrument had restarted: {}; its arms are homed again",
                            info.reset_cause
                        ));
                    }
                    return Ok(());
                }
                Err(LinkError::Interrupted) => return Err(SessionError::Interrupted),
                Err(LinkError::Io(error)) => {
                    self.link.last_io_error = Some(error.to_string());
                    reopen = true;
                    let silent_for = self.client.silent_for();
                    self.client
                        .transport_mut()
                        .pause(RECONNECT_PAUSE.min(give_up_after.saturating_sub(silent_for)));
                }
                // The hello went out and nothing came back: try again (the deadline decides).
                Err(
                    LinkError::Silent { .. }
                    | LinkError::NoReply { .. }
                    | LinkError::NoHandshake { .. },
                ) => {}
                Err(error @ LinkError::VersionMismatch { .. }) => {
                    self.decide(&format!("after the reconnection: {error}"));
                    return Err(SessionError::Link(error));
                }
                Err(error) => return Err(SessionError::Link(error)),
            }
        }
    }

    /// The session ends: nothing heard for the give-up time. Says which way the link was
    /// lost, with the decisions so far (the caller says how to resume).
    fn give_up(&mut self, silent_for: Duration) -> SessionError {
        let loss = match &self.link.last_io_error {
            Some(error) => LinkLoss::PortGone(error.clone()),
            None => LinkLoss::NoAnswer,
        };
        self.lost(loss, silent_for)
    }

    /// The session ends on `loss`, `silent_for` after the instrument was last heard (or
    /// understood): the decision says so.
    fn lost(&mut self, loss: LinkLoss, silent_for: Duration) -> SessionError {
        let link = self.client.transport().name();
        let decision = match &loss {
            LinkLoss::PortGone(error) => format!(
                "giving up: the port is gone ({error}), nothing heard for {:.1} s",
                silent_for.as_secs_f64()
            ),
            LinkLoss::NoAnswer => format!(
                "giving up: the port is there but the instrument has not answered for {:.1} s",
                silent_for.as_secs_f64()
            ),
            LinkLoss::Unreadable { garbled } => format!(
                "giving up: bytes keep coming but no greeting was answered in {:.1} s of reconnecting ({garbled} garbled frames)",
                silent_for.as_secs_f64()
            ),
        };
        self.decide(&decision);
        SessionError::Lost {
            link,
            loss,
            silent_for,
            decisions: self.decisions.clone(),
        }
    }

    /// The session ends: bytes kept coming for [`RECONNECT_LIMIT`] but no greeting was
    /// answered. Says so, with the decisions so far (the caller says how to resume).
    fn give_up_unreadable(&mut self, trying_for: Duration, garbled: u32) -> SessionError {
        self.lost(LinkLoss::Unreadable { garbled }, trying_for)
    }

    /// Read the state and bring the instrument to a known one: nothing running, homed,
    /// the lamp as the session needs it.
    pub(super) fn known_state(&mut self) -> Result<(), StepError> {
        self.client.clear_unsolicited();
        let mut waited = Duration::ZERO;
        let mut aborted = false;
        let status = loop {
            let status = self.request_status()?;
            let limit = match status.state {
                // Homing takes up to 20 s; a reading up to one re-take per range.
                DeviceState::Homing => Duration::from_secs(40),
                DeviceState::Measuring => {
                    Duration::from_millis(4 * u64::from(self.plan.integration_ms) + 2000)
                }
                _ => Duration::from_secs(5),
            };
            match status.state {
                DeviceState::Idle | DeviceState::Stopped => break status,
                DeviceState::RunningSchedule | DeviceState::Sweeping if !aborted => {
                    let (id, taken) = status.schedule.unwrap_or_default();
                    let what = if status.state == DeviceState::Sweeping {
                        format!("sweep {id} ({taken} bins sent)")
                    } else {
                        format!("schedule {id} ({taken} readings taken)")
                    };
                    self.decide(&format!("the instrument is still running {what}: aborting it; what it missed is measured again"));
                    self.request(Command::Abort)?;
                    aborted = true;
                }
                state if waited < limit => {
                    if waited.is_zero() {
                        self.decide(&format!(
                            "the instrument is still {}: waiting for it to finish",
                            doing(state)
                        ));
                    }
                    self.client
                        .keep_alive(STATE_POLL)
                        .map_err(|e| self.link_failed(e))?;
                    waited += STATE_POLL;
                }
                state => {
                    self.decide(&format!(
                        "the instrument is still {} after {:.1} s: aborting",
                        doing(state),
                        waited.as_secs_f64()
                    ));
                    self.request(Command::Abort)?;
                    waited = Duration::ZERO;
                }
            }
        };
        if let Some(fault) = status
            .fault
            .filter(|f| Some(*f) != self.steps.fault_reported)
        {
            // A fault stays in the status until the next Home: told (and counted) once.
            self.steps.fault_reported = Some(fault);
            self.link.recoveries.stops += 1;
            let homing = if status.homed_i && status.homed_r {
                "the homing was kept"
            } else {
                "the homing was lost"
            };
            self.decide(&format!(
                "the instrument reports {fault} (state {}, lamp {}); {homing}",
                doing(status.state),
                if status.lamp_on { "on" } else { "off" }
            ));
        }
        if !(status.homed_i && status.homed_r) {
            if !self.steps.homed_once {
                self.decide("homing the arms");
                self.home("at the start")?;
            } else {
                self.decide("the arms lost their homing: homing again");
                self.link.recoveries.rehomings += 1;
                self.home("on re-homing")?;
            }
        } else if self.steps.home_in_flight {
            // A Home ran while the link was down, and its report went with the link.
            self.steps_unverified("the result of a Home was lost with the link")
                .map_err(StepError::Fatal)?;
        }
        if self.link.lamp_wanted && !status.lamp_on {
            self.decide(
                "the lamp is off (the instrument's stop switched it off): lighting it again",
            );
            self.request(Command::SetLamp { on: true })?;
            self.link.recoveries.lamp_relit += 1;
            self.link.lamp_went_off = true;
        }
        Ok(())
    }
}
