//! Step pulses from a hardware timer, the logic of it: which timer periods ("segments")
//! make a [`MoveProfile`], how a running profile is replaced without a runt pulse, and
//! how an interrupt that came too late is noticed. The board implements [`StepTimer`] with
//! the registers of one general-purpose timer per arm (and its DIR/EN pins); the tests
//! with a cycle-exact model of that timer (`tests/it/stepgen.rs`).
//!
//! THE TIMER: 1 µs ticks, PWM mode 1, period (ARR) and compare (CCR) preloaded. A segment
//! is one timer period that starts with a step pulse of [`PULSE_TICKS`] or without one.
//! At each update event the hardware loads the preloaded segment, raises STEP if it has a
//! pulse, and sets the update flag; the update interrupt ([`StepChannel::on_update`])
//! counts that pulse and preloads the segment after it. So the pulse edges come from the
//! hardware and the interrupt only has to run at some time during the segment
//! (≥ 208 µs at 4,800 steps/s) for the timing to be exact. After the last step's pulse
//! the timer stops by itself at the end of that segment ([`TAIL_TICKS`], one-pulse mode),
//! and the interrupt of that update ends the move.
//!
//! SEGMENTS ([`StepGen`]): step `k` is issued `profile.step_time_us(k)` after the start;
//! the gap before it is one segment, or several of at most [`MAX_SEGMENT_TICKS`] (the
//! 16-bit counter) of which only the first after a step carries a pulse, the last at least
//! [`MIN_SEGMENT_TICKS`] (the one before it shortened so), so the step stays on time. No segment is
//! shorter than [`MIN_SEGMENT_TICKS`]: an interrupt needs that long to preload the next.
//!
//! REPLACING A RUNNING PROFILE ([`StepChannel::run_profile`] while moving): the segment
//! running and the one already preloaded are the hardware's; nothing is cut short. The
//! new profile takes over at the next update interrupt, after the preloaded segment: the
//! pulses committed so far are issued whole and counted, and the new profile's steps
//! follow, timed from the last pulse issued (so a stop ramp continues from the speed the
//! arm has), or later where the committed segments last longer than the new profile's
//! first step time: then the whole new profile is delayed, never compressed, so no step
//! comes faster than the profile allows ([`StepGen::after`]). The new profile's start
//! step only tells its direction and length: its steps are counted from where the
//! committed ones end. DIR changes when the new profile's first segment begins, which has
//! no pulse: after the last old pulse, most of a segment before the first new one. From
//! rest, a profile starts at once with a pulse-less segment (DIR set before it).
//!
//! A LATE INTERRUPT: the interrupt knows when the segment it handles began (the sum of the
//! segment lengths since the start, in cycles of a free-running counter that runs from
//! the same clock as the timer, [`StepTimer::now_cycles`]). If it runs so late that it
//! could not have preloaded the next segment [`LATE_MARGIN_TICKS`] before the segment
//! ends, the hardware may have repeated the segment and issued a step nobody counted (and
//! this record is then a segment behind the hardware). The channel stops the timer at the
//! end of the segment it runs, whichever that is (Klipper's "timer too close" shutdown:
//! nothing more is stepped on a timeline that is no longer known), drops profiles handed
//! to it until the arm is at rest, and latches a [`StepFault`]; the device turns it into
//! its fail-safe stop ([`protocol::ErrorCode::StepLate`]), arms not homed. The check is
//! conservative: every repeat is reported by the interrupt it happened under (a property
//! test drives the model with late interrupts), and only an interrupt within the margin of
//! its deadline is reported without one.

use crate::motion::MoveProfile;

/// STEP high time, ticks (TMC2209: ≥ 100 ns).
pub const PULSE_TICKS: u16 = 2;
/// Shortest segment, ticks: keeps a rounding artefact from asking for a period shorter
/// than the pulse or than the interrupt's latency (full speed is 208 µs per step).
pub const MIN_SEGMENT_TICKS: u32 = 20;
/// Longest segment, ticks: ARR is 16 bits and the counter counts 0..=ARR.
pub const MAX_SEGMENT_TICKS: u32 = 1 << 16;
/// The segment of the last step's pulse: long enough for its interrupt to set one-pulse
/// mode in time (the same margin as a step at full speed).
pub const TAIL_TICKS: u32 = 200;
/// How long before the end of its segment the update interrupt must have preloaded the
/// next one, ticks: what its own code takes (≲ 5 µs at 96 MHz by the disassembly), with
/// margin. A later interrupt is a [`StepFault`].
pub const LATE_MARGIN_TICKS: u32 = 8;

/// One timer period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment {
    /// Length, timer ticks (µs), `MIN_SEGMENT_TICKS ..= MAX_SEGMENT_TICKS`.
    pub ticks: u32,
    /// Whether it starts with a step pulse.
    pub pulse: bool,
}

/// Turns a profile into segments, one step time computed per step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepGen {
    profile: MoveProfile,
    count: u32,
    /// The step whose time ends the segment being generated (count + 1 after the last).
    next_step: u32,
    /// `step_time_us(next_step)`.
    next_time_us: u64,
    /// Where the segments generated so far end, µs after the profile's start.
    planned_us: u64,
    /// The next segment starts with a step pulse.
    pulse_next: bool,
}

impl StepGen {
    /// The segments of `profile` from its start: a pulse-less wait for step 1 first.
    pub fn new(profile: &MoveProfile) -> StepGen {
        StepGen::after(profile, 0)
    }

    /// The segments of `profile` when its start (its time 0) was `elapsed_us` before the
    /// first segment this makes: step `k` comes `step_time_us(k)` after the start. Where
    /// step 1 would then come sooner than a minimum segment from now, the start is taken
    /// later, just enough: the whole profile is delayed, never compressed (catching up
    /// would step faster than the profile allows).
    pub fn after(profile: &MoveProfile, elapsed_us: u32) -> StepGen {
        StepGen::after_first_step(profile, profile.step_time_us(1), elapsed_us)
    }

    /// [`StepGen::after`] with `profile.step_time_us(1)` computed beforehand (`first_us`):
    /// the step interrupt that takes over a profile is spared the arithmetic.
    fn after_first_step(profile: &MoveProfile, first_us: u64, elapsed_us: u32) -> StepGen {
        let elapsed_us =
            u64::from(elapsed_us).min(first_us.saturating_sub(u64::from(MIN_SEGMENT_TICKS)));
        StepGen {
            profile: *profile,
            count: profile.step_count(),
            next_step: 1,
            next_time_us: first_us,
            planned_us: elapsed_us,
            pulse_next: false,
        }
    }

    /// The next segment; `None` after the last step's pulse segment.
    pub fn next_segment(&mut self) -> Option<Segment> {
        let pulse = core::mem::replace(&mut self.pulse_next, false);
        if self.next_step > self.count {
            // The last step's pulse, then nothing.
            return pulse.then_some(Segment {
                ticks: TAIL_TICKS,
                pulse: true,
            });
        }
        let gap = self.next_time_us.saturating_sub(self.planned_us);
        if gap > u64::from(MAX_SEGMENT_TICKS) {
            // Leave the rest at least a minimum segment: a rest of 12 µs lengthened to 20
            // put step 1 of a slow move (65,548 µs) 8 µs late.
            let ticks = MAX_SEGMENT_TICKS.min((gap - u64::from(MIN_SEGMENT_TICKS)) as u32);
            self.planned_us += u64::from(ticks);
            return Some(Segment { ticks, pulse });
        }
        let ticks = (gap as u32).max(MIN_SEGMENT_TICKS);
        self.planned_us += u64::from(ticks);
        self.next_step += 1;
        if self.next_step <= self.count {
            self.next_time_us = self.profile.step_time_us(self.next_step);
        }
        self.pulse_next = true;
        Some(Segment { ticks, pulse })
    }
}

/// One arm's step timer and its DIR and EN lines, as a [`StepChannel`] drives them.
pub trait StepTimer {
    /// Cycles of [`StepTimer::now_cycles`] per timer tick (96 on the board: the CPU clock
    /// and the timer's 1 µs tick come from the same PLL).
    const CYCLES_PER_TICK: u32;
    /// Write `segment` into the preload registers: it runs from the next update event.
    fn preload(&mut self, segment: Segment);
    /// Load the preloaded segment now and count it from 0 (one-pulse mode off; no update
    /// interrupt for this load). Called only while the counter is stopped.
    fn start(&mut self);
    /// Make the running segment the last: a pulse-less preload and one-pulse mode, so the
    /// counter stops at its end with STEP low (and the update interrupt of that stop comes).
    fn stop_at_end_of_segment(&mut self);
    /// Read and clear the update flag: whether a segment began since the last call.
    fn take_update(&mut self) -> bool;
    /// DIR: `true` for positive steps.
    fn set_direction(&mut self, positive: bool);
    /// Enable the driver (it then holds the arm; it stays enabled between moves).
    fn enable_driver(&mut self);
    /// A free-running, wrapping cycle counter.
    fn now_cycles(&self) -> u32;
}

/// A step interrupt that ran too late ([`StepChannel::on_update`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepFault {
    /// How long after its segment began the interrupt ran, ticks.
    pub late_ticks: u32,
    /// The segment's length, ticks.
    pub segment_ticks: u32,
}

/// A profile's start from rest, computed ahead ([`Start::prepare`]): its first two
/// segments (the wait for step 1, then step 1's pulse) and the generator after them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Start {
    generator: StepGen,
    first: Segment,
    second: Segment,
    direction: i32,
    /// `step_time_us(1)`, for a take-over while moving ([`StepGen::after`]).
    first_step_us: u64,
}

/// A profile handed over while the arm moves, taken over by the update interrupt, with
/// step 1's time computed beforehand (`None` for a profile of no steps: a stop). Small on
/// purpose: it is copied under the lock the step interrupt shares (with the whole
/// [`Start`] in it the locked hand-over took 520 instructions instead of 160). An arm that
/// comes to rest before the take-over starts it from rest in the interrupt, the rare case.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Replacement {
    profile: MoveProfile,
    first_step_us: Option<u64>,
}

impl Start {
    /// `profile`'s start; `None` for a profile of no steps (nothing to start).
    pub fn prepare(profile: &MoveProfile) -> Option<Start> {
        if profile.step_count() == 0 {
            return None;
        }
        let mut generator = StepGen::new(profile);
        let first = generator.next_segment()?;
        let second = generator.next_segment()?;
        Some(Start {
            generator,
            first,
            second,
            direction: profile.direction(),
            first_step_us: profile.step_time_us(1),
        })
    }
}

/// One arm's step generator: the state its timer's update interrupt works on. The board
/// keeps it behind a critical-section mutex shared by the interrupt and the device task.
#[derive(Clone, Debug)]
pub struct StepChannel {
    generator: Option<StepGen>,
    /// The segment the counter is running and when it began (cycles, by the sum of the
    /// segment lengths since the start, so exact up to the start's few cycles).
    running: Segment,
    running_start: u32,
    /// The segment in the preload registers; `None` when the running one is the last
    /// (one-pulse mode) or the channel is idle.
    preloaded: Option<Segment>,
    /// Ticks from the last pulse to the start of the running segment (`None`: no pulse
    /// since the arm was at rest).
    pulse_age: Option<u32>,
    /// A profile to take over at the next update interrupt.
    replacement: Option<Replacement>,
    /// The DIR of a profile taken over, set when its first (pulse-less) segment begins.
    new_direction: Option<i32>,
    /// +1 or −1: what each pulse adds to the position.
    direction: i32,
    position: i32,
    moving: bool,
    /// A late interrupt stopped the timer: profiles handed over until it is at rest are
    /// dropped (a stop ramp from the old speed would restart an arm already stopped).
    halted: bool,
    fault: Option<StepFault>,
    /// The latest any update interrupt ran after its segment began, ticks (the
    /// self-test's figure: how close the interrupts come to their deadline).
    worst_late_ticks: u32,
}

impl Default for StepChannel {
    fn default() -> Self {
        Self::new()
    }
}

impl StepChannel {
    /// At rest, position 0.
    pub const fn new() -> StepChannel {
        StepChannel {
            generator: None,
            running: Segment {
                ticks: 0,
                pulse: false,
            },
            running_start: 0,
            preloaded: None,
            pulse_age: None,
            replacement: None,
            new_direction: None,
            direction: 0,
            position: 0,
            moving: false,
            halted: false,
            fault: None,
            worst_late_ticks: 0,
        }
    }

    /// Run `profile`: from rest at once; while moving, taking over after the segments the
    /// hardware has committed (see the module doc). A profile of no steps stops the arm
    /// after them.
    pub fn run_profile<T: StepTimer>(&mut self, timer: &mut T, profile: &MoveProfile) {
        self.run_prepared(timer, profile, Start::prepare(profile));
    }

    /// [`StepChannel::run_profile`] with its start computed beforehand ([`Start::prepare`]):
    /// a board prepares it before it takes the lock the step interrupt shares, so that the
    /// interrupts stay masked only for the hand-over (the preparation is most of the cost:
    /// about 1,100 of 1,150 instructions on the Cortex-M4, `firmware/target-tests`). The
    /// start is used only if the arm is at rest.
    pub fn run_prepared<T: StepTimer>(
        &mut self,
        timer: &mut T,
        profile: &MoveProfile,
        start: Option<Start>,
    ) {
        if self.moving {
            if !self.halted {
                self.replacement = Some(Replacement {
                    profile: *profile,
                    first_step_us: start.map(|start| start.first_step_us),
                });
            }
        } else if let Some(start) = start {
            self.start(timer, start, true);
        }
    }

    /// Run `profile` from rest with the driver left as it is (disabled: the self-test's
    /// pulse check, [`crate::selftest`]); refused (nothing runs) while the arm moves.
    pub fn run_pulse_check<T: StepTimer>(&mut self, timer: &mut T, start: Option<Start>) {
        if let (false, Some(start)) = (self.moving, start) {
            self.start(timer, start, false);
        }
    }

    fn start<T: StepTimer>(&mut self, timer: &mut T, start: Start, enable: bool) {
        // DIR at least a whole (pulse-less) segment before the first pulse.
        timer.set_direction(start.direction > 0);
        if enable {
            timer.enable_driver();
        }
        timer.preload(start.first);
        // Read before the start, so that lateness is, if anything, overestimated.
        let started = timer.now_cycles();
        timer.start();
        timer.preload(start.second);
        self.generator = Some(start.generator);
        self.running = start.first;
        self.running_start = started;
        self.preloaded = Some(start.second);
        self.pulse_age = None;
        self.new_direction = None;
        self.direction = start.direction;
        self.moving = true;
    }

    /// The timer's update interrupt: a segment began (or the last one ended).
    pub fn on_update<T: StepTimer>(&mut self, timer: &mut T) {
        if !timer.take_update() {
            return;
        }
        let now = timer.now_cycles();
        let cycles_per_tick = T::CYCLES_PER_TICK.max(1);
        let began = self
            .running_start
            .wrapping_add(self.running.ticks.wrapping_mul(cycles_per_tick));
        let Some(segment) = self.preloaded.take() else {
            // The last segment ended and the counter stopped.
            self.moving = false;
            self.halted = false;
            self.generator = None;
            if let Some(start) = self
                .replacement
                .take()
                .and_then(|replacement| Start::prepare(&replacement.profile))
            {
                self.start(timer, start, true);
            }
            return;
        };
        // Signed: the start is read a few cycles early, so "now" may be a hair before.
        let late_ticks = (now.wrapping_sub(began) as i32).max(0) as u32 / cycles_per_tick;
        self.worst_late_ticks = self.worst_late_ticks.max(late_ticks);
        if late_ticks + LATE_MARGIN_TICKS >= segment.ticks {
            // The hardware may be a segment ahead of this record now: stop at the end of
            // the segment it runs, whatever it is, and take no profile until at rest.
            self.fault.get_or_insert(StepFault {
                late_ticks,
                segment_ticks: segment.ticks,
            });
            self.halted = true;
            self.generator = None;
            self.replacement = None;
            self.new_direction = None;
        }
        self.pulse_age = if segment.pulse {
            Some(0)
        } else {
            self.pulse_age
                .map(|age| age.saturating_add(self.running.ticks))
        };
        self.running = segment;
        self.running_start = began;
        if segment.pulse {
            self.position = self.position.wrapping_add(self.direction);
        } else if let Some(direction) = self.new_direction.take() {
            timer.set_direction(direction > 0);
            self.direction = direction;
        }
        if let Some(Replacement {
            profile,
            first_step_us,
        }) = self.replacement.take()
        {
            match first_step_us {
                None => self.generator = None,
                Some(first_step_us) => {
                    // Its time 0 is the last pulse; its first segment follows this one.
                    let elapsed_us = self
                        .pulse_age
                        .map_or(0, |age| age.saturating_add(segment.ticks));
                    // DIR changes at the start of the new profile's first segment, which
                    // has no pulse: STEP is low then, and the first new pulse is a segment
                    // away.
                    let direction = profile.direction();
                    self.new_direction = (direction != self.direction).then_some(direction);
                    self.generator = Some(StepGen::after_first_step(
                        &profile,
                        first_step_us,
                        elapsed_us,
                    ));
                }
            }
        }
        match self.generator.as_mut().and_then(StepGen::next_segment) {
            Some(next) => {
                timer.preload(next);
                self.preloaded = Some(next);
            }
            None => {
                // This segment is the last: the counter stops at its end, STEP low.
                timer.stop_at_end_of_segment();
                self.generator = None;
            }
        }
    }

    /// The step count: one per pulse issued (counted when its segment's interrupt runs).
    pub fn position(&self) -> i32 {
        self.position
    }

    /// Redefine the step count (homing; arm at rest).
    pub fn set_position(&mut self, steps: i32) {
        self.position = steps;
    }

    /// Whether a profile runs (until the counter stopped after the last segment).
    pub fn is_moving(&self) -> bool {
        self.moving
    }

    /// The latest any update interrupt ran after its segment began, since this channel
    /// was made, ticks.
    pub fn worst_late_ticks(&self) -> u32 {
        self.worst_late_ticks
    }

    /// Take the fault latched by a late interrupt, if any.
    pub fn take_fault(&mut self) -> Option<StepFault> {
        self.fault.take()
    }
}
