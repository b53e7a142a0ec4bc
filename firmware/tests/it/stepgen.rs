//! The step generator on a cycle-exact model of the board's timer (PWM mode 1 with
//! preloaded period and compare, one-pulse mode, the update flag, an interrupt that runs
//! some random latency after it, whose register writes land a few cycles into it).
//!
//! Properties over random profiles, latencies and replacement times:
//! - the pulses are the profile's steps: as many, at exactly `step_time_us(k)`;
//! - a running profile replaced (a stop ramp, another move, a reversal, a cancel) issues
//!   no runt: every pulse whole, none closer than a minimum segment to the one before,
//!   DIR never changed within a pulse nor just before the next,
//!   the count equal to the pulses issued (signed by DIR at their edge), the new profile's
//!   steps all issued on its timing;
//! - an interrupt too late to preload in time is always reported (every segment the
//!   hardware repeated comes with a `StepFault` from the interrupt it happened under), the
//!   timer then stops at once, and an interrupt in time is never reported.

use firmware::motion::MoveProfile;
use firmware::stepgen::*;
use proptest::prelude::*;

/// Model cycles per timer tick (the board has 96; 3 exercises the division as well).
const CPT: u64 = 3;

#[derive(Clone, Copy, Debug)]
struct Pulse {
    at: u64,
    positive: bool,
}

/// The timer, its pins, and what they did.
struct Model {
    now: u64,
    counting: bool,
    one_pulse: bool,
    shadow: Segment,
    preload: Segment,
    segment_start: u64,
    /// The update flag, and since when it is set (the interrupt is pending).
    update_since: Option<u64>,
    preload_written: bool,
    dir_positive: bool,
    enabled: bool,
    pulses: Vec<Pulse>,
    dir_changes: Vec<u64>,
    /// Update events that reloaded a segment the interrupt had not replaced: the hardware
    /// repeated it (and its pulse, if it had one).
    repeats: u32,
}

impl Model {
    fn new() -> Model {
        let idle = Segment {
            ticks: MIN_SEGMENT_TICKS,
            pulse: false,
        };
        Model {
            now: 0,
            counting: false,
            one_pulse: false,
            shadow: idle,
            preload: idle,
            segment_start: 0,
            update_since: None,
            preload_written: false,
            dir_positive: true,
            enabled: false,
            pulses: Vec::new(),
            dir_changes: Vec::new(),
            repeats: 0,
        }
    }

    fn segment_end(&self) -> Option<u64> {
        self.counting
            .then(|| self.segment_start + u64::from(self.shadow.ticks) * CPT)
    }

    /// Let the hardware run until `to`.
    fn advance(&mut self, to: u64) {
        while let Some(end) = self.segment_end() {
            if end > to {
                break;
            }
            self.update_since.get_or_insert(end);
            if self.one_pulse {
                self.counting = false;
                self.shadow = self.preload;
                break;
            }
            if !self.preload_written {
                self.repeats += 1;
            }
            self.shadow = self.preload;
            self.segment_start = end;
            self.preload_written = false;
            if self.shadow.pulse {
                self.pulses.push(Pulse {
                    at: end,
                    positive: self.dir_positive,
                });
            }
        }
        self.now = self.now.max(to);
    }

    fn step_high(&self, at: u64) -> bool {
        self.pulses
            .last()
            .is_some_and(|p| at >= p.at && at < p.at + u64::from(PULSE_TICKS) * CPT)
    }
}

/// The model seen by code running at `entry`, whose register writes land at `write_at`.
struct ModelTimer<'a> {
    model: &'a mut Model,
    entry: u64,
    write_at: u64,
}

impl StepTimer for ModelTimer<'_> {
    const CYCLES_PER_TICK: u32 = CPT as u32;

    fn preload(&mut self, segment: Segment) {
        self.model.advance(self.write_at);
        assert!(
            (MIN_SEGMENT_TICKS..=MAX_SEGMENT_TICKS).contains(&segment.ticks),
            "segment {segment:?}"
        );
        self.model.preload = segment;
        self.model.preload_written = true;
    }

    fn start(&mut self) {
        self.model.advance(self.write_at);
        assert!(
            !self.model.counting,
            "start() while the counter runs would cut a segment short"
        );
        self.model.shadow = self.model.preload;
        self.model.segment_start = self.write_at;
        self.model.counting = true;
        self.model.one_pulse = false;
        self.model.preload_written = false;
        assert!(
            !self.model.shadow.pulse,
            "a move must begin with a pulse-less segment (DIR setup)"
        );
    }

    fn stop_at_end_of_segment(&mut self) {
        self.model.advance(self.write_at);
        self.model.preload = Segment {
            ticks: MIN_SEGMENT_TICKS,
            pulse: false,
        };
        self.model.preload_written = true;
        self.model.one_pulse = true;
    }

    fn take_update(&mut self) -> bool {
        self.model.update_since.take().is_some()
    }

    fn set_direction(&mut self, positive: bool) {
        self.model.advance(self.write_at);
        assert!(
            !self.model.step_high(self.write_at),
            "DIR changed while STEP is high"
        );
        if positive != self.model.dir_positive {
            self.model.dir_changes.push(self.write_at);
        }
        self.model.dir_positive = positive;
    }

    fn enable_driver(&mut self) {
        self.model.enabled = true;
    }

    fn now_cycles(&self) -> u32 {
        self.entry as u32
    }
}

/// When a second profile is handed over, and how it is made from the arm's state then.
#[derive(Clone, Copy, Debug)]
enum Replace {
    /// The device's stop: a ramp from the speed the first profile has at that time.
    Stop,
    /// Another move from where the count is (same direction or reversed).
    Move(i32),
    /// A profile of no steps: stop after the committed segments.
    Cancel,
}

struct Run {
    model: Model,
    channel: StepChannel,
    started_at: u64,
    /// The replacement: when it was handed over, the profile, pulses issued by then.
    replaced: Option<(u64, MoveProfile, usize)>,
    faults: Vec<StepFault>,
    /// Interrupts during whose latency or writes the hardware repeated a segment, and
    /// that reported no fault.
    unreported_repeats: u32,
    /// When the first interrupt that reported a fault began.
    first_fault_at: Option<u64>,
}

const VMAX: f32 = 4800.0;
const AMAX: f32 = 14_400.0;

/// When an interrupt runs after the update that raised it.
#[derive(Clone, Copy, Debug)]
enum Latency {
    /// This many cycles after the update.
    After(u64),
    /// This many cycles before the end of the segment that update began (negative: after
    /// it), at the update at the earliest: probes the deadline itself.
    BeforeEnd(i64),
}

/// Run `profile` from rest to the end, interrupts `latencies` (cycles, cycled through) late,
/// each interrupt's writes `exec` cycles after it begins; optionally replace it at `replace_at`.
fn run(
    profile: &MoveProfile,
    latencies: &[u64],
    exec: u64,
    replace: Option<(u64, Replace)>,
) -> Run {
    let latencies: Vec<Latency> = latencies.iter().map(|&l| Latency::After(l)).collect();
    run_with(profile, &latencies, exec, replace, false)
}

fn run_with(
    profile: &MoveProfile,
    latencies: &[Latency],
    exec: u64,
    replace: Option<(u64, Replace)>,
    pulse_check: bool,
) -> Run {
    let mut model = Model::new();
    let mut channel = StepChannel::new();
    channel.set_position(profile.start_steps());
    let started_at = 10;
    model.advance(started_at);
    let mut timer = ModelTimer {
        model: &mut model,
        entry: started_at - exec.min(10),
        write_at: started_at,
    };
    if pulse_check {
        channel.run_pulse_check(&mut timer, firmware::stepgen::Start::prepare(profile));
    } else {
        channel.run_profile(&mut timer, profile);
    }
    let mut replace = replace.map(|(at, how)| (started_at + at, how));
    let mut replaced = None;
    let mut faults = Vec::new();
    let mut next_latency = latencies.iter().copied().cycle();
    let mut isr_at: Option<u64> = None;
    let mut unreported_repeats = 0;
    let mut first_fault_at = None;
    for _ in 0..10_000_000 {
        if let (None, Some(since)) = (isr_at, model.update_since) {
            let segment_cycles = u64::from(model.shadow.ticks) * CPT;
            isr_at = Some(match next_latency.next().unwrap_or(Latency::After(0)) {
                Latency::After(cycles) => since + cycles,
                Latency::BeforeEnd(cycles) => {
                    (since as i64 + segment_cycles as i64 - cycles).max(since as i64) as u64
                }
            });
        }
        let next_hardware = isr_at.or(model.segment_end());
        // The thread-mode handover: it runs with interrupts masked, so before a pending one.
        let handover = replace.filter(|&(at, _)| next_hardware.is_none_or(|t| at <= t));
        if let Some((at, how)) = handover {
            model.advance(at);
            let here = channel.position();
            let elapsed_s = (at - started_at) as f32 / CPT as f32 * 1e-6;
            let second = match how {
                Replace::Stop => MoveProfile::stop(
                    here,
                    profile.direction(),
                    profile.speed_at(elapsed_s),
                    VMAX,
                    AMAX,
                ),
                Replace::Move(distance) => {
                    MoveProfile::fastest(here, here + distance, 0.0, VMAX, AMAX)
                }
                Replace::Cancel => MoveProfile::rest(here),
            };
            replaced = Some((at, second, model.pulses.len()));
            channel.run_profile(
                &mut ModelTimer {
                    model: &mut model,
                    entry: at,
                    write_at: at + exec,
                },
                &second,
            );
            replace = None;
            continue;
        }
        match (isr_at, model.segment_end()) {
            (Some(at), _) => {
                let repeats_before = model.repeats;
                model.advance(at);
                channel.on_update(&mut ModelTimer {
                    model: &mut model,
                    entry: at,
                    write_at: at + exec,
                });
                isr_at = None;
                let fault = channel.take_fault();
                // A segment repeated while this interrupt was pending or writing: this
                // interrupt must say so.
                if model.repeats > repeats_before && fault.is_none() {
                    unreported_repeats += 1;
                }
                if fault.is_some() && first_fault_at.is_none() {
                    first_fault_at = Some(at);
                }
                faults.extend(fault);
            }
            (None, Some(end)) => model.advance(end),
            (None, None) => break,
        }
    }
    assert!(
        !channel.is_moving(),
        "the channel still moves after the timer stopped"
    );
    Run {
        model,
        channel,
        started_at,
        replaced,
        faults,
        unreported_repeats,
        first_fault_at,
    }
}

fn signed_pulses(model: &Model, from: i32) -> i32 {
    model
        .pulses
        .iter()
        .fold(from, |p, pulse| p + if pulse.positive { 1 } else { -1 })
}

fn profile_strategy() -> impl Strategy<Value = MoveProfile> {
    // Full speed down to very slow (a scaled-down arm: gaps past the 16-bit counter).
    (
        -3000i32..3000,
        -3000i32..3000,
        prop_oneof![Just(VMAX), 100.0f32..VMAX, 2.0f32..40.0],
        200.0f32..AMAX,
    )
        .prop_filter("a move", |(a, b, _, _)| a != b && (a - b).abs() <= 2500)
        .prop_map(|(start, target, speed, accel)| {
            MoveProfile::fastest(start, target, 0.0, speed, accel)
        })
        .prop_filter("not too long to simulate", |p| p.duration_s() < 300.0)
}

/// Latencies that leave the interrupt time to preload (under the margin of the shortest
/// segment, writes included).
fn timely_latencies(exec: u64) -> impl Strategy<Value = Vec<u64>> {
    let limit = (u64::from(MIN_SEGMENT_TICKS - LATE_MARGIN_TICKS) - 1) * CPT - 2 * exec;
    proptest::collection::vec(0..limit, 1..64)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn pulses_are_the_profiles_steps_at_its_step_times(profile in profile_strategy(), latencies in timely_latencies(3)) {
        let run = run(&profile, &latencies, 3, None);
        prop_assert_eq!(run.model.pulses.len() as u32, profile.step_count());
        prop_assert_eq!(run.model.repeats, 0);
        prop_assert!(run.faults.is_empty(), "false alarm: {:?}", run.faults);
        prop_assert_eq!(run.channel.position(), profile.target_steps());
        prop_assert_eq!(signed_pulses(&run.model, profile.start_steps()), profile.target_steps());
        for (k, pulse) in run.model.pulses.iter().enumerate() {
            let expected = run.started_at + profile.step_time_us(k as u32 + 1) * CPT;
            prop_assert_eq!(pulse.at, expected, "step {} of {}", k + 1, profile.step_count());
        }
        prop_assert!(run.model.enabled);
        // The self-test's figure: the latest interrupt, never more than the latencies
        // given (and their writes), and at least the first one's.
        let (first, max) = (latencies[0] / CPT, latencies.iter().max().unwrap() / CPT);
        let worst = u64::from(run.channel.worst_late_ticks());
        prop_assert!(worst + 1 >= first && worst <= max + 1, "worst {} ticks, latencies {:?} cycles", worst, latencies);
    }

    /// The self-test's pulse check: the same pulses at the same times, the driver left
    /// disabled.
    #[test]
    fn a_pulse_check_steps_without_enabling_the_driver(profile in profile_strategy(), latencies in timely_latencies(3)) {
        let latencies: Vec<Latency> = latencies.iter().map(|&l| Latency::After(l)).collect();
        let run = run_with(&profile, &latencies, 3, None, true);
        prop_assert_eq!(run.model.pulses.len() as u32, profile.step_count());
        prop_assert_eq!(run.channel.position(), profile.target_steps());
        for (k, pulse) in run.model.pulses.iter().enumerate() {
            prop_assert_eq!(pulse.at, run.started_at + profile.step_time_us(k as u32 + 1) * CPT);
        }
        prop_assert!(!run.model.enabled);
    }

    #[test]
    fn replacing_a_running_profile_issues_no_runt(
        profile in profile_strategy(),
        at_fraction in 0.0f64..1.0,
        how in prop_oneof![Just(Replace::Stop), Just(Replace::Cancel), (-2000i32..2000).prop_filter("moves", |d| *d != 0).prop_map(Replace::Move)],
        latencies in timely_latencies(2),
    ) {
        let at = (profile.duration_us() as f64 * at_fraction * CPT as f64) as u64;
        let run = run(&profile, &latencies, 2, Some((at, how)));
        let (replaced_at, second, pulses_before) = run.replaced.expect("replaced");
        let pulses = &run.model.pulses;
        prop_assert_eq!(run.model.repeats, 0);
        prop_assert!(run.faults.is_empty(), "false alarm: {:?}", run.faults);
        // The count is the pulses issued, signed by DIR at their edge.
        prop_assert_eq!(run.channel.position(), signed_pulses(&run.model, profile.start_steps()));
        // No two pulses closer than a minimum segment (a runt would be).
        for pair in pulses.windows(2) {
            prop_assert!(pair[1].at - pair[0].at >= u64::from(MIN_SEGMENT_TICKS) * CPT, "pulses {} cycles apart", pair[1].at - pair[0].at);
        }
        // DIR: never while STEP is high (the model asserts it), and in a timely interrupt
        // microseconds before the next pulse (what is left of a minimum segment after the
        // interrupt's latency; the TMC2209 needs 20 ns).
        for &change in &run.model.dir_changes {
            if let Some(next) = pulses.iter().find(|p| p.at > change) {
                prop_assert!(next.at - change >= 5 * CPT, "DIR {} cycles before a pulse", next.at - change);
            }
        }
        // Of the first profile, at most the one committed pulse after the handover.
        let new_steps = second.step_count() as usize;
        let old_pulses = pulses.len() - new_steps.min(pulses.len());
        prop_assert!(pulses.len() >= new_steps);
        prop_assert!(old_pulses <= pulses_before + 1, "{} old pulses after the handover", old_pulses - pulses_before);
        prop_assert!(old_pulses as u32 <= profile.step_count());
        // The second profile: all its steps, none early, and after its first exactly on its
        // own timing (delayed as a whole where the committed segments outlast its first
        // step time, never compressed).
        if new_steps > 0 {
            let origin = if old_pulses > 0 { pulses[old_pulses - 1].at } else { replaced_at };
            let first = pulses[old_pulses].at;
            let first_planned = origin + second.step_time_us(1) * CPT;
            prop_assert!(first + CPT >= first_planned, "the new profile's first step early: {} < {}", first, first_planned);
            // Late by at most what was committed at the handover (two segments) and one
            // minimum segment.
            let committed = 2 * u64::from(MAX_SEGMENT_TICKS) + u64::from(MIN_SEGMENT_TICKS);
            prop_assert!(first <= replaced_at + (second.step_time_us(1) + committed) * CPT + CPT);
            // A stop at cruise speed (the fail-safe stop mid-move): the ramp's first step
            // within a minimum segment of its time (decelerating, the committed gaps are
            // longer than the ramp's first, and it waits for them).
            let cruising = profile.speed_at((replaced_at - run.started_at) as f32 / CPT as f32 * 1e-6) >= 0.999 * profile.peak_speed()
                && profile.peak_speed() >= 0.999 * VMAX;
            if matches!(how, Replace::Stop) && old_pulses > 0 && cruising {
                prop_assert!(first <= first_planned + u64::from(MIN_SEGMENT_TICKS) * CPT + CPT);
            }
            let clamped = second.step_time_us(1) < u64::from(MIN_SEGMENT_TICKS);
            for (j, pulse) in pulses[old_pulses..].iter().enumerate() {
                prop_assert_eq!(pulse.positive, second.direction() > 0);
                let planned = (second.step_time_us(j as u32 + 1) - second.step_time_us(1)) * CPT;
                let actual = pulse.at - first;
                if clamped {
                    prop_assert!(actual.abs_diff(planned) <= u64::from(MIN_SEGMENT_TICKS) * CPT);
                } else {
                    prop_assert_eq!(actual, planned, "new step {}", j + 1);
                }
            }
        }
    }

    #[test]
    fn a_late_interrupt_is_always_reported(
        profile in profile_strategy(),
        latencies in proptest::collection::vec(prop_oneof![
            8 => (0u64..(u64::from(MIN_SEGMENT_TICKS) * CPT)).prop_map(Latency::After),
            1 => (0u64..(2 * u64::from(TAIL_TICKS) * CPT)).prop_map(Latency::After),
            1 => (0u64..(2 * u64::from(MAX_SEGMENT_TICKS) * CPT)).prop_map(Latency::After),
            // Around the deadline: from a margin before the segment's end to a bit after it.
            2 => (-(CPT as i64) * 4..(i64::from(LATE_MARGIN_TICKS) + 2) * CPT as i64).prop_map(Latency::BeforeEnd),
        ], 1..64),
        exec in 1u64..(u64::from(LATE_MARGIN_TICKS) * CPT),
    ) {
        let run = run_with(&profile, &latencies, exec, None, false);
        prop_assert_eq!(run.unreported_repeats, 0, "{} repeated segments in all", run.model.repeats);
        if run.model.repeats > 0 {
            prop_assert!(!run.faults.is_empty());
        }
        // After a fault the timer stops: at most the pulse of a segment that began while
        // that interrupt was writing.
        if let Some(at) = run.first_fault_at {
            let after = run.model.pulses.iter().filter(|p| p.at > at).count();
            prop_assert!(after <= 1, "{} pulses after the fault", after);
            prop_assert_eq!(run.faults.len(), 1, "one fault, then stopped");
        }
        if run.faults.is_empty() {
            prop_assert_eq!(run.model.pulses.len() as u32, profile.step_count());
            prop_assert_eq!(run.channel.position(), profile.target_steps());
        }
    }
}

#[test]
fn segments_add_up_to_the_profile() {
    for (target, speed) in [(1, VMAX), (2, VMAX), (6800, VMAX), (-500, 160.0), (40, 3.0)] {
        let profile = MoveProfile::fastest(0, target, 0.0, speed, AMAX);
        let mut generator = StepGen::new(&profile);
        let (mut ticks, mut pulses, mut segments) = (0u64, 0u32, 0u32);
        while let Some(segment) = generator.next_segment() {
            assert!((MIN_SEGMENT_TICKS..=MAX_SEGMENT_TICKS).contains(&segment.ticks));
            ticks += u64::from(segment.ticks);
            pulses += u32::from(segment.pulse);
            segments += 1;
        }
        assert_eq!(pulses, profile.step_count());
        // The last pulse at the end of the profile, then its tail.
        assert_eq!(
            ticks,
            profile.duration_us() + u64::from(TAIL_TICKS),
            "target {target}"
        );
        // A slow move splits its gaps; only the first part of each carries the pulse.
        if speed < 10.0 {
            assert!(segments > pulses + 1);
        }
    }
}

/// A gap just past the 16-bit counter (step 1 of a slow two-step move at 65,536 µs and a
/// few more) is split so that its rest is a whole minimum segment: every step still comes
/// at its time. (Found by `pulses_are_the_profiles_steps_at_its_step_times`: a rest of
/// 12 µs lengthened to 20 put step 1 8 µs late.)
#[test]
fn a_gap_just_past_the_counter_keeps_its_step_on_time() {
    let mut crossings = 0;
    for i in 0..400 {
        // Peak speeds whose step 1 falls 0–60 µs either side of 65,536 µs.
        let speed = 15.2 + 0.001 * f64::from(i);
        let profile = MoveProfile::fastest(0, 2, 0.0, speed as f32, 6477.589);
        let first_us = profile.step_time_us(1);
        let over = first_us.saturating_sub(u64::from(MAX_SEGMENT_TICKS));
        crossings += usize::from(over > 0 && over < u64::from(MIN_SEGMENT_TICKS));
        let mut generator = StepGen::new(&profile);
        let (mut at, mut step) = (0u64, 0u32);
        while let Some(segment) = generator.next_segment() {
            assert!((MIN_SEGMENT_TICKS..=MAX_SEGMENT_TICKS).contains(&segment.ticks));
            if segment.pulse {
                step += 1;
                assert_eq!(at, profile.step_time_us(step), "speed {speed}: step {step}");
            }
            at += u64::from(segment.ticks);
        }
        assert_eq!(step, profile.step_count());
    }
    assert!(
        crossings >= 5,
        "only {crossings} gaps just past the counter tried"
    );
}

#[test]
fn a_stop_at_once_after_the_start_still_stops() {
    // The device's stop in the same poll as the start: speed 0, so the stop profile has
    // no steps (MoveProfile::rest). It must end the move after the committed segments,
    // not let the first profile run on.
    let profile = MoveProfile::fastest(0, 4000, 0.0, VMAX, AMAX);
    let run = run(&profile, &[30], 2, Some((0, Replace::Cancel)));
    assert!(
        run.model.pulses.len() <= 1,
        "{} pulses",
        run.model.pulses.len()
    );
    assert_eq!(run.channel.position(), signed_pulses(&run.model, 0));
}
