//! The bench session in process: a person slow at the prompts, arms that slip, and the
//! recoveries the issue reproduced (a schedule still running after a replug, an outage
//! long enough to stop the arms mid-move, a heartbeat loss while the arms wait parked), a
//! cable pulled for good and a frozen instrument. Each on the simulated instrument in
//! virtual time; where a fault must land at a given moment (mid-move, mid-schedule, during
//! a prompt), the moment is read off the same session run without the fault, so the test
//! holds for any seed.

use firmware::hardware::Arm;
use hil_sim::SimInstrument;
use host::analysis::flags::Flag;
use host::instrument::calibration::Calibration;
use host::instrument::link::{Client, RetryPolicy, Transport};
use host::instrument::sim::SimOptions;
use host::session::{
    DelayedOperator, DiscardRecorder, LinkLoss, MeasuredPoint, Operator, Outcome, Placement, Plan,
    Policy, PolicyChoice, Session, SessionError,
};
use protocol::{Command, FrameDecoder, Request};
use std::collections::BTreeSet;
use std::time::Duration;

/// The simulated instrument with a log of what the host sent, and faults of the test's own:
/// an arm that slips at a given moment, an instrument that freezes.
struct Watched {
    sim: SimInstrument,
    decoder: FrameDecoder,
    /// Device time (s) and command of every request but heartbeats and status reads (a
    /// request sent again under its sequence number counts once).
    log: Vec<(f64, Command)>,
    logged: BTreeSet<u32>,
    /// At this device time (s) the arm loses this many steps.
    slip: Option<(f64, Arm, i32)>,
    /// From this device time (s) on, the instrument hears nothing and says nothing.
    freeze_at_s: Option<f64>,
    /// Over this span of device time (s) the host's bytes are lost (a host that stalls).
    mute: Option<(f64, f64)>,
    /// The instrument's `Stopped` messages are lost on the way (the others pass).
    lose_stops: bool,
    /// Another host's request, sent to the instrument just before this host's first
    /// request of the kind `ghost_before` matches.
    ghost: Option<(fn(&Command) -> bool, Command)>,
    /// Device bytes read, not yet passed on (whole frames are passed, or filtered).
    from_device: FrameDecoder,
    to_host: std::collections::VecDeque<u8>,
}

impl Watched {
    fn new(sim: SimInstrument) -> Watched {
        Watched {
            sim,
            decoder: FrameDecoder::new(),
            log: Vec::new(),
            logged: BTreeSet::new(),
            slip: None,
            freeze_at_s: None,
            mute: None,
            lose_stops: false,
            ghost: None,
            from_device: FrameDecoder::new(),
            to_host: Default::default(),
        }
    }

    fn now_s(&self) -> f64 {
        self.sim.device_time_us() as f64 * 1e-6
    }

    /// The freeze on the simulator's microsecond clock (rounded up): a freeze between two
    /// ticks left a wait of under 1 µs before it, which the simulator reads as no wait,
    /// and the link's loop asked again at the same instant for ever.
    fn freeze_at_us(&self) -> Option<u64> {
        self.freeze_at_s.map(|at| (at.max(0.0) * 1e6).ceil() as u64)
    }

    fn frozen(&self) -> bool {
        self.freeze_at_us()
            .is_some_and(|at| self.sim.device_time_us() >= at)
    }

    /// Device times (s) at which `matches` was sent.
    fn times(&self, matches: impl Fn(&Command) -> bool) -> Vec<f64> {
        self.log
            .iter()
            .filter(|(_, c)| matches(c))
            .map(|(t, _)| *t)
            .collect()
    }
}

/// A wait in the simulator's whole milliseconds, rounded up.
fn whole_ms(wait: Duration) -> u64 {
    u64::try_from(wait.as_micros().div_ceil(1000)).unwrap_or(u64::MAX)
}

impl Transport for Watched {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let now = self.now_s();
        let mut ghost_now = None;
        for &byte in bytes {
            if let Some(Ok(request)) = self.decoder.push::<Request>(byte) {
                if self
                    .ghost
                    .as_ref()
                    .is_some_and(|(before, _)| before(&request.command))
                {
                    ghost_now = self.ghost.take().map(|(_, command)| command);
                }
                if !matches!(request.command, Command::Heartbeat | Command::GetStatus)
                    && self.logged.insert(request.seq)
                {
                    self.log.push((now, request.command));
                }
            }
        }
        if let Some(command) = ghost_now {
            let mut frame = [0u8; protocol::MAX_FRAME_LEN];
            let frame = protocol::encode_frame(&Request { seq: 7, command }, &mut frame)
                .unwrap()
                .to_vec();
            self.sim.write(&frame)?;
        }
        if let Some((at, arm, steps)) = self.slip {
            if now >= at {
                self.sim
                    .hardware_mut()
                    .mechanics_mut()
                    .lose_steps(arm, steps);
                self.slip = None;
            }
        }
        if self.frozen()
            || self
                .mute
                .is_some_and(|(from, to)| (from..to).contains(&now))
        {
            return Ok(());
        }
        self.sim.write(bytes)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        if self.frozen() {
            // At least the wait asked for: a wait under 1 ms rounded down to none would
            // leave the link's loop asking again at the same instant.
            self.sim.advance_ms(whole_ms(timeout));
            return Ok(0);
        }
        // Nothing the instrument says after it froze reaches the host.
        let timeout = match self.freeze_at_us() {
            Some(at) => timeout.min(Duration::from_micros(
                at.saturating_sub(self.sim.device_time_us()),
            )),
            None => timeout,
        };
        if !self.lose_stops {
            return self.sim.read(buf, timeout);
        }
        // Whole frames only, the stops left out.
        let deadline = self.now_s() + timeout.as_secs_f64();
        while self.to_host.is_empty() {
            let mut raw = [0u8; 512];
            let left = Duration::from_secs_f64((deadline - self.now_s()).max(0.0));
            let n = self.sim.read(&mut raw, left)?;
            if n == 0 {
                return Ok(0);
            }
            for &byte in &raw[..n] {
                if let Some(Ok(message)) = self.from_device.push::<protocol::DeviceMessage>(byte) {
                    if !matches!(message, protocol::DeviceMessage::Stopped { .. }) {
                        let mut frame = [0u8; protocol::MAX_FRAME_LEN];
                        self.to_host.extend(
                            protocol::encode_frame(&message, &mut frame)
                                .unwrap()
                                .iter()
                                .copied(),
                        );
                    }
                }
            }
        }
        let n = buf.len().min(self.to_host.len());
        for (slot, byte) in buf.iter_mut().zip(self.to_host.drain(..n)) {
            *slot = byte;
        }
        Ok(n)
    }

    fn pause(&mut self, duration: Duration) {
        self.sim.advance_ms(whole_ms(duration));
    }

    fn now(&self) -> Duration {
        Duration::from_micros(self.sim.device_time_us())
    }

    fn first_seq(&self) -> u32 {
        1
    }
}

/// A simulated person who takes `delay` (device time) and notes when they were asked.
struct Person {
    inner: DelayedOperator,
    asked_at_s: Vec<f64>,
}

impl Person {
    fn taking(delay_s: f64) -> Person {
        Person {
            inner: DelayedOperator::answering_after(Duration::from_secs_f64(delay_s)),
            asked_at_s: Vec::new(),
        }
    }
}

impl Operator for Person {
    fn ask(&mut self, placement: Placement, now: Duration) -> std::io::Result<()> {
        self.asked_at_s.push(now.as_secs_f64());
        self.inner.ask(placement, now)
    }
    fn answered(&mut self, now: Duration) -> std::io::Result<bool> {
        self.inner.answered(now)
    }
}

/// What a session is run with.
#[derive(Clone)]
struct Setup {
    sample: &'static str,
    seed: u64,
    faults: String,
    policy: PolicyChoice,
    operator_s: f64,
    white_check: bool,
    calibration: Option<Calibration>,
    slip: Option<(f64, Arm, i32)>,
    freeze_at_s: Option<f64>,
    mute: Option<(f64, f64)>,
    lose_stops: bool,
    ghost: Option<(fn(&Command) -> bool, Command)>,
    max_calibration_age: Duration,
}

impl Setup {
    fn new(sample: &'static str, seed: u64) -> Setup {
        Setup {
            sample,
            seed,
            faults: String::new(),
            policy: PolicyChoice::Adaptive,
            operator_s: 0.0,
            white_check: false,
            calibration: None,
            slip: None,
            freeze_at_s: None,
            mute: None,
            lose_stops: false,
            ghost: None,
            max_calibration_age: Duration::from_secs(8 * 3600),
        }
    }

    fn faults(mut self, faults: &str) -> Setup {
        self.faults = faults.into();
        self
    }

    fn policy(mut self, policy: PolicyChoice) -> Setup {
        self.policy = policy;
        self
    }
}

struct Ran {
    outcome: Result<Outcome, SessionError>,
    watched: Watched,
    person: Person,
}

fn run(setup: &Setup) -> Ran {
    let options = SimOptions {
        seed: setup.seed,
        faults: setup.faults.clone(),
        ..SimOptions::default()
    };
    let mut watched = Watched::new(
        options
            .instrument(setup.sample)
            .expect("simulated instrument"),
    );
    watched.slip = setup.slip;
    watched.freeze_at_s = setup.freeze_at_s;
    watched.mute = setup.mute;
    watched.lose_stops = setup.lose_stops;
    watched.ghost = setup.ghost.clone();
    let mut client = Client::new(watched, RetryPolicy::default());
    let info = client.hello().expect("handshake");
    let plan = Plan {
        sample: setup.sample.into(),
        integration_ms: info.default_integration_ms,
        policy: Policy::from(setup.policy),
        acceptance_deg: f64::from(info.acceptance_deg),
        white_check: setup.white_check,
        white_drift_limit: 0.005,
    };
    let mut person = Person::taking(setup.operator_s);
    let mut recorder = DiscardRecorder;
    let mut session = Session::new(&mut client, info, plan, &mut recorder, &mut person)
        .with_calibration_limit(setup.max_calibration_age);
    if let Some(calibration) = &setup.calibration {
        session = session.with_calibration(calibration.clone());
    }
    let outcome = session.run();
    Ran {
        outcome,
        watched: client.into_transport(),
        person,
    }
}

fn class_of(sample: &str) -> &'static str {
    host::analysis::classify::REFERENCES
        .iter()
        .find(|r| r.name == sample)
        .unwrap()
        .class
        .name()
}

fn truth_sigma(sample: &str) -> f64 {
    host::instrument::sim::sample_params(sample)
        .unwrap()
        .sigma_deg
}

/// The checks every finished session passes: the paper's class, σ > σ_l, every geometry
/// once among the current readings, every superseded geometry measured again.
fn assert_sound(what: &str, outcome: &Outcome) {
    let sample = outcome.report.sample.as_str();
    assert_eq!(
        outcome.report.classification.class_name(),
        class_of(sample),
        "{what}: {:#?}",
        outcome.decisions
    );
    assert!(
        outcome.report.check.is_some_and(|c| c.sigma_ok),
        "{what}: σ ≤ σ_l"
    );
    let key = |p: &MeasuredPoint| {
        (
            (p.theta_i_deg * 1e3).round() as i64,
            (p.theta_r_deg * 1e3).round() as i64,
        )
    };
    let current: Vec<_> = outcome.current_points().map(key).collect();
    let distinct: BTreeSet<_> = current.iter().copied().collect();
    assert_eq!(
        distinct.len(),
        current.len(),
        "{what}: a geometry has two current readings"
    );
    for p in outcome.points.iter().filter(|p| p.superseded) {
        assert!(
            distinct.contains(&key(p)),
            "{what}: superseded ({}, {}) not measured again",
            p.theta_i_deg,
            p.theta_r_deg
        );
    }
}

fn ok<'r>(what: &str, ran: &'r Ran) -> &'r Outcome {
    match &ran.outcome {
        Ok(outcome) => outcome,
        Err(error) => panic!("{what}: {error}"),
    }
}

fn decided(outcome: &Outcome, words: &str) -> bool {
    outcome.decisions.iter().any(|d| d.contains(words))
}

fn homes(watched: &Watched) -> usize {
    watched.times(|c| matches!(c, Command::Home)).len()
}

#[test]
fn operators_who_take_10_s_or_2_min_at_every_prompt_keep_the_instrument_homed_and_lit() {
    for delay_s in [10.0, 120.0] {
        for sample in ["G", "SG", "PPC", "J1"] {
            for policy in [PolicyChoice::Paper, PolicyChoice::Adaptive] {
                let what = format!("{sample} {policy:?}, {delay_s} s at each prompt");
                let setup = Setup {
                    operator_s: delay_s,
                    white_check: true,
                    ..Setup::new(sample, 7).policy(policy)
                };
                let ran = run(&setup);
                let outcome = ok(&what, &ran);
                assert_sound(&what, outcome);
                assert!(outcome.ok(), "{what}: {:?}", outcome.flags);
                // Tile, sample, tile again for the white check: each answered after the delay.
                assert_eq!(ran.person.asked_at_s.len(), 3, "{what}");
                let answered = outcome
                    .decisions
                    .iter()
                    .filter(|d| d.contains(&format!("answered after {delay_s:.1} s")))
                    .count();
                assert_eq!(answered, 3, "{what}: {:#?}", outcome.decisions);
                // The instrument never stopped, kept its homing and its lamp: the first Home,
                // the check after the white calibration and the one before the report only.
                let r = &outcome.recoveries;
                assert_eq!(
                    (r.stops, r.rehomings, r.lamp_relit),
                    (0, 0, 0),
                    "{what}: {r:?}"
                );
                assert_eq!(homes(&ran.watched), 3, "{what}");
                assert!(
                    outcome.white_drift.is_some_and(|d| d.abs() < 0.005),
                    "{what}: {:?}",
                    outcome.white_drift
                );
            }
        }
    }
}

/// σ within 2 % of the truth: a 40-step slip left uncorrected gives 10 % on G.
fn assert_sigma_right(what: &str, outcome: &Outcome) {
    let sample = outcome.report.sample.as_str();
    let sigma = outcome.report.fit.sigma_deg().expect("σ resolved");
    assert!(
        (sigma / truth_sigma(sample) - 1.0).abs() < 0.02,
        "{what}: σ = {sigma}, truth {}",
        truth_sigma(sample)
    );
}

#[test]
fn lost_steps_are_never_reported_clean_and_the_affected_readings_are_measured_again() {
    // The calibration an instrument without slips takes, to reuse: then the slip (at the
    // first move) hits the sample's readings instead of the white ones.
    let calibration = ok("clean", &run(&Setup::new("G", 99))).calibration.clone();
    let mut superseded_total = 0;
    for seed in 1..=20 {
        for (arm, name) in [(Arm::Source, "source"), (Arm::Detector, "detector")] {
            for policy in [PolicyChoice::Paper, PolicyChoice::Adaptive] {
                let sample = if seed % 2 == 0 { "G" } else { "SG" };
                let mut setup = Setup::new(sample, seed)
                    .policy(policy)
                    .faults(&format!("lose-steps={name}:40"));
                let reused = seed % 4 < 2;
                if reused {
                    setup.calibration = Some(calibration.clone());
                }
                let what = format!(
                    "{sample} seed {seed} {name} {policy:?}{}",
                    if reused { " (calibration reused)" } else { "" }
                );
                let ran = run(&setup);
                let outcome = ok(&what, &ran);
                assert!(
                    outcome.flags.contains(&Flag::LostSteps) && !outcome.ok(),
                    "{what}: reported clean: {:?}",
                    outcome.flags
                );
                assert!(
                    decided(outcome, "40 steps (0.500°)"),
                    "{what}: {:#?}",
                    outcome.decisions
                );
                assert_sound(&what, outcome);
                assert_sigma_right(&what, outcome);
                let superseded = outcome.points.iter().filter(|p| p.superseded).count();
                if reused {
                    // Found before the report: everything since the first homing was off.
                    assert!(superseded >= 12, "{what}: {superseded} superseded");
                } else {
                    // Found after the white calibration, which was taken again at once.
                    assert!(decided(outcome, "taking them again"), "{what}");
                }
                superseded_total += superseded;
                let lost = outcome
                    .step_checks
                    .iter()
                    .find(|c| c.lost_steps)
                    .expect("the check that found it");
                let error = if arm == Arm::Source {
                    lost.step_error_i
                } else {
                    lost.step_error_r
                };
                assert_eq!(error.map(i32::abs), Some(40), "{what}: {lost:?}");
            }
        }
    }
    assert!(superseded_total > 0);
}

#[test]
fn a_slip_at_any_moment_of_the_session_is_found_and_measured_again() {
    for (k, sample) in ["G", "SG", "PPC", "J1"].iter().cycle().take(20).enumerate() {
        let policy = if k % 2 == 0 {
            PolicyChoice::Paper
        } else {
            PolicyChoice::Adaptive
        };
        let base = Setup::new(sample, 40 + k as u64).policy(policy);
        let clean = run(&base);
        ok("clean", &clean);
        // Between the end of the first homing (the first move) and the check before the
        // report (the last Home), evenly over the session.
        let first_move = clean.watched.times(|c| matches!(c, Command::MoveTo(_)))[0];
        let last_home = *clean
            .watched
            .times(|c| matches!(c, Command::Home))
            .last()
            .unwrap();
        let at = first_move + (k as f64 + 0.5) / 20.0 * (last_home - first_move);
        let arm = if k % 3 == 0 {
            Arm::Detector
        } else {
            Arm::Source
        };
        let what = format!("{sample} {policy:?} slip of {arm:?} at {at:.1} s");
        let ran = run(&Setup {
            slip: Some((at, arm, 40)),
            ..base
        });
        let outcome = ok(&what, &ran);
        assert!(
            outcome.flags.contains(&Flag::LostSteps) && !outcome.ok(),
            "{what}: {:?}",
            outcome.flags
        );
        assert_sound(&what, outcome);
        if sample.starts_with('G') || sample.starts_with('S') {
            assert_sigma_right(&what, outcome);
        }
    }
}

#[test]
fn a_schedule_still_running_after_a_replug_is_aborted_not_refused_busy() {
    for (seed, sample) in [(1, "G"), (2, "PPC"), (3, "SG"), (4, "J1")] {
        let base = Setup::new(sample, seed);
        let clean = run(&base);
        let started = clean
            .watched
            .times(|c| matches!(c, Command::RunSchedule(_)))[0];
        // Out for half a second, a second into Strategy 1: back before the heartbeat
        // timeout, so the instrument is still running it.
        let what = format!("{sample} seed {seed}");
        let ran = run(&base.faults(&format!("unplug-at={}:0.5", started + 1.0)));
        let outcome = ok(&what, &ran);
        assert!(
            decided(outcome, "still running schedule"),
            "{what}: {:#?}",
            outcome.decisions
        );
        assert_sound(&what, outcome);
        assert!(
            outcome.ok() && outcome.flags == [Flag::LinkRecovered, Flag::InstrumentDeclared],
            "{what}: {:?}",
            outcome.flags
        );
        assert_eq!(outcome.recoveries.rehomings, 0, "{what}");
    }
}

#[test]
fn an_outage_that_stops_the_arms_mid_move_costs_the_homing_which_is_done_again() {
    for (seed, sample) in [(5, "G"), (6, "PPC"), (7, "SG"), (8, "J2")] {
        let base = Setup::new(sample, seed);
        let clean = run(&base);
        let outcome = ok("clean", &clean);
        // Strategy 1's readings: the longest move is after reading k. The instrument stops
        // 1.8–2.0 s after the host was last heard (heartbeats every 0.2 s): pull the cable
        // so that the stop comes 20 ms into that move.
        let times: Vec<f64> = outcome
            .points
            .iter()
            .take(12)
            .map(|p| p.device_time_us as f64 * 1e-6)
            .collect();
        let k = (0..11)
            .max_by(|&a, &b| (times[a + 1] - times[a]).total_cmp(&(times[b + 1] - times[b])))
            .unwrap();
        assert!(
            times[k + 1] - times[k] > 0.5,
            "{sample}: no move long enough"
        );
        let at = times[k] - 1.8 + 0.02;
        let what = format!("{sample} seed {seed}, cable out at {at:.2} s for 3 s");
        let ran = run(&base.faults(&format!("unplug-at={at}:3")));
        let outcome = ok(&what, &ran);
        assert!(
            outcome.recoveries.rehomings >= 1 && decided(outcome, "lost their homing"),
            "{what}: {:#?}",
            outcome.decisions
        );
        assert!(decided(outcome, "heartbeat lost"), "{what}");
        // A ramped stop loses no steps: the re-homing finds the counts exact.
        let rehome = outcome
            .step_checks
            .iter()
            .find(|c| c.when == "on re-homing")
            .expect("a re-homing");
        assert!(!rehome.lost_steps, "{what}: {rehome:?}");
        assert_sound(&what, outcome);
        assert!(outcome.ok(), "{what}: {:?}", outcome.flags);
    }
}

#[test]
fn a_heartbeat_loss_while_the_arms_wait_parked_keeps_the_homing_and_the_lamp_is_lit_again() {
    for (seed, sample, prompt) in [(9, "G", 0), (10, "PPC", 1), (11, "SG", 1), (12, "J1", 0)] {
        let base = Setup {
            operator_s: 30.0,
            ..Setup::new(sample, seed)
        };
        let clean = run(&base);
        ok("clean", &clean);
        let asked = clean.person.asked_at_s[prompt];
        let what = format!("{sample} seed {seed}, cable out 5 s into prompt {prompt} for 4 s");
        let ran = run(&base.faults(&format!("unplug-at={}:4", asked + 5.0)));
        let outcome = ok(&what, &ran);
        let r = &outcome.recoveries;
        assert!(
            r.stops >= 1 && r.lamp_relit >= 1,
            "{what}: {r:?}\n{:#?}",
            outcome.decisions
        );
        assert_eq!(
            r.rehomings, 0,
            "{what}: the arms stood still, the homing must be kept"
        );
        assert_eq!(
            homes(&ran.watched),
            homes(&clean.watched),
            "{what}: no extra Home"
        );
        assert!(decided(outcome, "the homing was kept"), "{what}");
        // The lamp was off: the white tile is read again at the end.
        assert!(
            outcome.white_drift.is_some_and(|d| d.abs() < 0.005),
            "{what}: {:?}",
            outcome.white_drift
        );
        assert_sound(&what, outcome);
        assert!(outcome.ok(), "{what}: {:?}", outcome.flags);
    }
}

#[test]
fn a_cable_pulled_for_good_is_given_up_within_10_s_saying_the_port_is_gone() {
    for (k, sample) in ["G", "SG", "PPC", "J1", "MC"].iter().enumerate() {
        let base = Setup::new(sample, 20 + k as u64);
        let clean = run(&base);
        let end = clean.watched.now_s();
        let at = end * (k as f64 + 0.5) / 5.0;
        let what = format!("{sample}: cable out at {at:.1} s of {end:.1}");
        let ran = run(&base.faults(&format!("unplug-at={at}:3600")));
        let error = ran
            .outcome
            .err()
            .unwrap_or_else(|| panic!("{what}: finished without the instrument"));
        let SessionError::Lost {
            loss,
            silent_for,
            decisions,
            ..
        } = &error
        else {
            panic!("{what}: {error}")
        };
        assert!(matches!(loss, LinkLoss::PortGone(_)), "{what}: {loss:?}");
        assert!(
            *silent_for >= Duration::from_secs(10) && *silent_for <= Duration::from_millis(10_300),
            "{what}: {silent_for:?}"
        );
        // The host's own clock agrees: it gave up within 10 s of the pull.
        let gave_up_after = ran.watched.now_s() - at;
        assert!(
            (0.0..=10.0).contains(&gave_up_after),
            "{what}: gave up {gave_up_after:.2} s after the pull"
        );
        let text = error.to_string();
        assert!(
            text.contains("port is gone")
                && text.contains("simulated USB cable unplugged")
                && text.contains("decisions so far"),
            "{what}: {text}"
        );
        assert!(
            decisions.iter().any(|d| d.contains("link lost"))
                && decisions.iter().any(|d| d.starts_with("giving up")),
            "{what}: {decisions:?}"
        );
    }
}

#[test]
fn a_frozen_instrument_is_given_up_within_10_s_saying_nothing_answers() {
    for (k, sample) in ["G", "PPC", "SG"].iter().enumerate() {
        let base = Setup::new(sample, 30 + k as u64);
        let end = run(&base).watched.now_s();
        let at = end * (k as f64 + 0.5) / 3.0;
        let what = format!("{sample}: frozen at {at:.1} s of {end:.1}");
        let ran = run(&Setup {
            freeze_at_s: Some(at),
            ..base
        });
        let error = ran
            .outcome
            .err()
            .unwrap_or_else(|| panic!("{what}: finished with a frozen instrument"));
        let SessionError::Lost {
            loss, silent_for, ..
        } = &error
        else {
            panic!("{what}: {error}")
        };
        assert_eq!(*loss, LinkLoss::NoAnswer, "{what}");
        assert!(
            *silent_for <= Duration::from_millis(10_300),
            "{what}: {silent_for:?}"
        );
        assert!(
            (0.0..=10.0).contains(&(ran.watched.now_s() - at)),
            "{what}: {:.2} s",
            ran.watched.now_s() - at
        );
        let text = error.to_string();
        assert!(
            text.contains("port is there")
                && text.contains("has not answered for 10.0 s")
                && text.contains("power-cycle"),
            "{what}: {text}"
        );
    }
}

#[test]
fn a_stop_whose_message_is_lost_does_not_let_a_reading_be_taken_in_the_dark() {
    // While the person works, the host stalls for 2.5 s (its heartbeats lost): the
    // instrument takes its fail-safe stop (arms parked: homing kept, lamp off, idle) and
    // its `Stopped` never arrives. The next reading (white after the first prompt, the
    // sample's Strategy 1 after the second) would be taken with the lamp off.
    for (seed, sample) in [(14, "G"), (15, "PPC"), (16, "SG"), (17, "J1")] {
        let base = Setup {
            operator_s: 10.0,
            ..Setup::new(sample, seed)
        };
        let clean = run(&base);
        ok("clean", &clean);
        for prompt in [0, 1] {
            let at = clean.person.asked_at_s[prompt] + 3.0;
            let what =
                format!("{sample} seed {seed}, host stalled during prompt {prompt} ({at:.2} s)");
            let ran = run(&Setup {
                mute: Some((at, at + 2.5)),
                lose_stops: true,
                ..base.clone()
            });
            let outcome = ok(&what, &ran);
            assert!(
                outcome.recoveries.lamp_relit >= 1,
                "{what}: {:#?}",
                outcome.decisions
            );
            assert_eq!(outcome.recoveries.rehomings, 0, "{what}");
            // Every reading the result rests on was taken with the lamp on: the white ones
            // (else the calibration would be off by its dark reading) and the sample's.
            assert!(
                outcome
                    .calibration
                    .white
                    .iter()
                    .all(|w| w.reading.mean_counts > 5_000.0),
                "{what}: {:?}",
                outcome.calibration.white
            );
            assert_sound(&what, outcome);
            assert!(outcome.ok(), "{what}: {:?}", outcome.flags);
        }
    }
}

#[test]
fn a_busy_refusal_is_mended_from_the_instruments_state() {
    // Another host (or a command of this one that the host lost track of) homes the arms
    // just as this session starts Strategy 1: RunSchedule is refused busy; the session reads
    // the state, waits for the homing to end and starts the schedule again.
    for (seed, sample) in [(18, "G"), (19, "PPC")] {
        let what = format!("{sample} seed {seed}");
        let setup = Setup {
            ghost: Some((|c| matches!(c, Command::RunSchedule(_)), Command::Home)),
            ..Setup::new(sample, seed)
        };
        let ran = run(&setup);
        let outcome = ok(&what, &ran);
        assert!(
            decided(outcome, "refused RunSchedule: busy"),
            "{what}: {:#?}",
            outcome.decisions
        );
        assert!(
            decided(outcome, "still homing: waiting"),
            "{what}: {:#?}",
            outcome.decisions
        );
        assert!(outcome.recoveries.refusals >= 1, "{what}");
        assert_sound(&what, outcome);
        assert!(outcome.ok(), "{what}: {:?}", outcome.flags);
    }
}

#[test]
fn a_calibration_that_goes_stale_before_the_report_flags_the_result() {
    let mut calibration = ok("clean", &run(&Setup::new("MC", 21))).calibration.clone();
    calibration.taken_unix_s -= 3600;
    let fresh = Setup {
        calibration: Some(calibration),
        max_calibration_age: Duration::from_secs(4 * 3600),
        ..Setup::new("MC", 22)
    };
    let outcome = ok("1 h old, 4 h limit", &run(&fresh)).flags.clone();
    assert!(!outcome.contains(&Flag::CalibrationStale), "{outcome:?}");
    let stale = Setup {
        max_calibration_age: Duration::from_secs(1800),
        ..fresh
    };
    let ran = run(&stale);
    let outcome = ok("1 h old, 30 min limit", &ran);
    assert!(
        outcome.flags.contains(&Flag::CalibrationStale) && !outcome.ok(),
        "{:?}",
        outcome.flags
    );
    assert!(
        decided(outcome, "1.0 h old at the end of the session (limit 0.5 h)"),
        "{:#?}",
        outcome.decisions
    );
}
