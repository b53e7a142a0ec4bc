//! Homing of one arm: fast search toward the switch, back off, slow re-approach; or, on an
//! arm whose step count can be trusted, the quick re-home.
//!
//! The switches sit beyond the working range on the far side from the normal, so homing
//! moves every arm away from the other one. An arm that starts on its switch backs off in
//! steps of `home_backoff` until it releases (at most `home_release_max`, or the switch is
//! stuck). Where the slow re-approach trips the switch
//! is the arm's reference; the step count the arm believed it had there, compared with
//! the switch's angle, is the step error reported on re-homing (lost steps).
//!
//! QUICK RE-HOME ([`ArmHoming::quick`]): the step count says where the switch is, so the
//! arm goes there at full speed (the arm's speed and acceleration limits) up to
//! `home_quick_margin` (1.5°) short of it, then approaches slowly for at most
//! `home_quick_approach` (3°): the switch is found by the same slow approach as in the full
//! homing, so the step error is just as exact. Two ways out of the plan:
//! - the switch trips during the fast move (the arm is further than it believes, by more
//!   than the margin): stop (ramped), back off (past the trip point, then the usual
//!   clearance) and approach slowly as in the full homing. Tripped on the fast move's
//!   deceleration, the arm overshoots the switch by the error beyond the margin (at most
//!   the 10° braking distance from full speed): it ends where the fast move would have put
//!   it, as any move with that error overshoots its target;
//! - the slow approach ends without the switch (the arm is behind its count by more than
//!   the approach minus the margin, 1.5°): fall back to the full search from there.
//!
//! Device time of `Home`, both arms at once, on the reference instrument (virtual time on
//! `FakeHardware`; `tests/it/homing.rs` prints this table and bounds the quick re-home at 3 s
//! and three quarters of the full homing). "−40": the arm lost 40 steps (0.5°) and stands
//! behind its count; "+40": ahead of it.
//!
//! | from (θi, θr) | full homing | quick re-home | source −40 | detector −40 | source +40 | detector +40 |
//! |---------------|-------------|---------------|------------|--------------|------------|--------------|
//! | (20°, 0°)     | 5.75 s      | 2.54 s        | 2.54 s     | 2.79 s       | 2.54 s     | 2.29 s       |
//! | (45°, 45°)    | 3.50 s      | 1.79 s        | 2.04 s     | 2.04 s       | 1.79 s     | 1.79 s       |
//! | (60°, 70°)    | 2.75 s      | 1.54 s        | 1.79 s     | 1.62 s       | 1.37 s     | 1.54 s       |
//!
//! The slow approach (1.5° at 2°/s, 0.75 s) is most of the quick re-home from near the
//! switch; the full homing's search runs at 20°/s instead of 60°/s and adds a back-off.
//! From (45°, 45°), an arm 2.5° or 8° ahead (the switch trips in the fast move) takes
//! 2.30 s, one 5° behind (the full search after the approach) 4.10 s; all still exact.

use crate::config::InstrumentConfig;
use crate::hardware::{Arm, Arms};
use crate::motion::{ArmMotion, MoveProfile, angle_to_steps, deg_to_steps};
use crate::switches::SwitchState;
use protocol::{DeviceError, ErrorCode};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Begin,
    /// Quick re-home: full speed to the margin short of where the count puts the switch.
    QuickRun,
    /// Quick re-home: slowly toward the switch, at most the quick approach distance.
    QuickApproach,
    /// Fast toward the switch, at most the search range.
    Search,
    /// Switch found at `trip_steps`; ramping down.
    SearchStopping {
        trip_steps: i32,
    },
    /// Fast away from the switch by `distance_steps`, `total_steps` in all since the switch
    /// was found pressed; it must release within `home_release_max`.
    BackOff {
        distance_steps: i32,
        total_steps: i32,
    },
    /// Slowly toward the switch again.
    Approach,
    /// Switch tripped at `trip_steps`; ramping down.
    ApproachStopping {
        trip_steps: i32,
    },
    Finished,
}

/// What a homing arm reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HomingStatus {
    /// Still homing.
    Running,
    /// Done: the switch tripped when the arm's step count was `trip_steps`.
    Homed {
        /// Step count at the switch.
        trip_steps: i32,
    },
    /// Failed; the arm is at rest (or ramping down).
    Failed(DeviceError),
}

/// One arm's homing state machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ArmHoming {
    arm: Arm,
    phase: Phase,
    /// The quick re-home was asked for and has not fallen back to the full search.
    quick: bool,
}

impl ArmHoming {
    /// The full homing of `arm` (search from anywhere), not started.
    pub const fn new(arm: Arm) -> ArmHoming {
        ArmHoming {
            arm,
            phase: Phase::Begin,
            quick: false,
        }
    }

    /// The quick re-home of `arm`, not started: for an arm whose step count still says
    /// where it is (homed since reset, no driver fault since), so that the switch is
    /// where the count puts it, `config.home_switch`, give or take a few lost steps.
    pub const fn quick(arm: Arm) -> ArmHoming {
        ArmHoming {
            arm,
            phase: Phase::Begin,
            quick: true,
        }
    }

    /// Whether this homing is (still) the quick one: false after a fall-back to the full
    /// search.
    pub fn is_quick(&self) -> bool {
        self.quick
    }

    fn start_slow_approach(
        &mut self,
        hardware: &mut impl Arms,
        motion: &mut ArmMotion,
        config: &InstrumentConfig,
        distance_steps: i32,
        now_us: u64,
    ) {
        self.constant_speed_move(
            hardware,
            motion,
            config,
            distance_steps,
            config.home_slow_deg_per_s,
            now_us,
        );
    }

    fn start_backoff(
        &mut self,
        hardware: &mut impl Arms,
        motion: &mut ArmMotion,
        config: &InstrumentConfig,
        distance_steps: i32,
        total_steps: i32,
        now_us: u64,
    ) {
        self.constant_speed_move(
            hardware,
            motion,
            config,
            -distance_steps,
            config.home_fast_deg_per_s,
            now_us,
        );
        self.phase = Phase::BackOff {
            distance_steps,
            total_steps: total_steps + distance_steps,
        };
    }

    fn start_search(
        &mut self,
        hardware: &mut impl Arms,
        motion: &mut ArmMotion,
        config: &InstrumentConfig,
        now_us: u64,
    ) {
        let search_steps = angle_to_steps(config.home_search_range);
        self.constant_speed_move(
            hardware,
            motion,
            config,
            search_steps,
            config.home_fast_deg_per_s,
            now_us,
        );
        self.phase = Phase::Search;
    }

    fn constant_speed_move(
        &self,
        hardware: &mut impl Arms,
        motion: &mut ArmMotion,
        config: &InstrumentConfig,
        distance_steps: i32,
        speed_deg_per_s: f32,
        now_us: u64,
    ) {
        let here = hardware.position_steps(self.arm);
        let speed = deg_to_steps(speed_deg_per_s.min(config.max_speed_deg_per_s));
        let profile = MoveProfile::fastest(
            here,
            here + distance_steps,
            0.0,
            speed,
            deg_to_steps(config.accel_deg_per_s2),
        );
        motion.start(hardware, self.arm, profile, now_us);
    }

    fn fail(&mut self, code: ErrorCode) -> HomingStatus {
        self.phase = Phase::Finished;
        HomingStatus::Failed(DeviceError::with_detail(code, self.arm.index() as i32))
    }

    /// Advance. Call at every poll while homing, with the arm's switch as debounced at
    /// this poll ([`crate::switches`]): a trip's step count is where the press began.
    pub fn poll(
        &mut self,
        hardware: &mut impl Arms,
        motion: &mut ArmMotion,
        config: &InstrumentConfig,
        switch: SwitchState,
        now_us: u64,
    ) -> HomingStatus {
        let pressed = switch.pressed;
        let moving = motion.is_moving(hardware, self.arm);
        let backoff_steps = angle_to_steps(config.home_backoff);
        let max_speed = deg_to_steps(config.max_speed_deg_per_s);
        let accel = deg_to_steps(config.accel_deg_per_s2);
        // Where the count puts the end of the quick fast move.
        let quick_target =
            angle_to_steps(config.home_switch) - angle_to_steps(config.home_quick_margin);
        match self.phase {
            Phase::Begin => {
                if pressed {
                    // Already on the switch: straight to backing off.
                    self.start_backoff(hardware, motion, config, backoff_steps, 0, now_us);
                } else if !self.quick {
                    self.start_search(hardware, motion, config, now_us);
                } else if hardware.position_steps(self.arm) < quick_target {
                    let here = hardware.position_steps(self.arm);
                    motion.start(
                        hardware,
                        self.arm,
                        MoveProfile::fastest(here, quick_target, 0.0, max_speed, accel),
                        now_us,
                    );
                    self.phase = Phase::QuickRun;
                } else {
                    // Believed within the margin already: only the slow approach is left.
                    let approach = angle_to_steps(config.home_quick_approach);
                    self.start_slow_approach(hardware, motion, config, approach, now_us);
                    self.phase = Phase::QuickApproach;
                }
            }
            Phase::QuickRun => {
                if pressed {
                    // Further than the count says: from here on as the full homing does.
                    let trip_steps = switch.since_steps;
                    motion.stop(hardware, self.arm, max_speed, accel, now_us);
                    self.phase = Phase::SearchStopping { trip_steps };
                } else if !moving {
                    let approach = angle_to_steps(config.home_quick_approach);
                    self.start_slow_approach(hardware, motion, config, approach, now_us);
                    self.phase = Phase::QuickApproach;
                }
            }
            Phase::QuickApproach => {
                if pressed {
                    let trip_steps = switch.since_steps;
                    motion.stop(hardware, self.arm, max_speed, accel, now_us);
                    self.phase = Phase::ApproachStopping { trip_steps };
                } else if !moving {
                    // Not where the count says, by more than the approach covers: search.
                    self.quick = false;
                    self.start_search(hardware, motion, config, now_us);
                }
            }
            Phase::Search => {
                if pressed {
                    let trip_steps = switch.since_steps;
                    motion.stop(hardware, self.arm, max_speed, accel, now_us);
                    self.phase = Phase::SearchStopping { trip_steps };
                } else if !moving {
                    return self.fail(ErrorCode::HomeSwitchNotFound);
                }
            }
            Phase::SearchStopping { trip_steps } => {
                if !moving {
                    // The back-off, or more after a longer overshoot (a trip during the
                    // quick re-home's fast move stops from up to full speed): past the trip
                    // point by the overshoot, then half the back-off clear of it (the full
                    // search's 1.1° overshoot leaves 1.9°).
                    let overshoot = (hardware.position_steps(self.arm) - trip_steps).max(0);
                    let distance = backoff_steps.max(overshoot + backoff_steps / 2);
                    self.start_backoff(hardware, motion, config, distance, 0, now_us);
                }
            }
            Phase::BackOff {
                distance_steps,
                total_steps,
            } => {
                if !moving {
                    if pressed {
                        // Further past the switch than one back-off (an arm far ahead of its
                        // count): another one, up to the limit, then it is stuck.
                        if total_steps + backoff_steps > angle_to_steps(config.home_release_max) {
                            return self.fail(ErrorCode::HomeSwitchStuck);
                        }
                        self.start_backoff(
                            hardware,
                            motion,
                            config,
                            backoff_steps,
                            total_steps,
                            now_us,
                        );
                        return HomingStatus::Running;
                    }
                    // Back over the whole back-off and one degree more: the switch must trip.
                    let approach =
                        distance_steps + angle_to_steps(protocol::Angle::from_whole_deg(1));
                    self.start_slow_approach(hardware, motion, config, approach, now_us);
                    self.phase = Phase::Approach;
                }
            }
            Phase::Approach => {
                if pressed {
                    let trip_steps = switch.since_steps;
                    motion.stop(hardware, self.arm, max_speed, accel, now_us);
                    self.phase = Phase::ApproachStopping { trip_steps };
                } else if !moving {
                    return self.fail(ErrorCode::HomeSwitchNotFound);
                }
            }
            Phase::ApproachStopping { trip_steps } => {
                if !moving {
                    self.phase = Phase::Finished;
                    return HomingStatus::Homed { trip_steps };
                }
            }
            Phase::Finished => {}
        }
        HomingStatus::Running
    }
}

/// The longest a `Home` of both arms can take on an instrument with `config`, µs: a bound
/// over the ways through the state machine above (the arms home at once, so one arm's
/// worst is the device's). Announced in the handshake (`DeviceInfo::longest_home_ms`), so
/// that a host waits for the answer as long as the device may need and not much longer;
/// tested against homings on the fake hardware (`tests/it/homing.rs`).
///
/// Every homing begins with at most a quick run over the whole travel at full speed and
/// its stop, then goes one of two ways:
/// - the switch trips in the fast run (an arm ahead of its count): a back-off past the
///   overshoot (at most the full-speed braking distance) and half a back-off, then the
///   slow approach over that and a degree more;
/// - the quick approach misses (or the homing is a full one): the quick approach, the full
///   search over the search range, its stop, back-offs up to the longest release (one ramp
///   pair each), and the slow approach over a back-off and a degree more.
pub fn longest_homing_us(config: &InstrumentConfig) -> u64 {
    let accel = deg_to_steps(config.accel_deg_per_s2).max(1.0);
    let full = deg_to_steps(config.max_speed_deg_per_s);
    let fast = deg_to_steps(config.home_fast_deg_per_s.min(config.max_speed_deg_per_s));
    let slow = deg_to_steps(config.home_slow_deg_per_s.min(config.max_speed_deg_per_s));
    let travel = |steps: i32, speed: f32| {
        MoveProfile::fastest(0, steps.max(0), 0.0, speed, accel).duration_us()
    };
    let stop = |speed: f32| (speed / accel * 1e6) as u64 + 1;
    let degree = angle_to_steps(protocol::Angle::from_whole_deg(1));
    let backoff = angle_to_steps(config.home_backoff).max(1);
    let braking = (full * full / (2.0 * accel)) as i32 + 1;
    let quick_run = travel(
        angle_to_steps(config.home_switch) - angle_to_steps(config.arm_min),
        full,
    ) + stop(full);
    let tripped_in_the_run = {
        let back = braking + backoff / 2 + backoff;
        travel(back, fast) + stop(fast) + travel(back + degree, slow) + stop(slow)
    };
    let searched = {
        let releases = angle_to_steps(config.home_release_max) / backoff + 1;
        travel(angle_to_steps(config.home_quick_approach), slow)
            + stop(slow)
            + travel(angle_to_steps(config.home_search_range), fast)
            + stop(fast)
            + releases as u64 * (travel(backoff, fast) + stop(fast))
            + travel(backoff + degree, slow)
            + stop(slow)
    };
    quick_run + tripped_in_the_run.max(searched)
}
