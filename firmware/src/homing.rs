//! Homing of one arm: fast search toward the switch, back off, slow re-approach.
//!
//! The switches sit beyond the working range on the far side from the normal, so homing
//! moves every arm away from the other one. Where the slow re-approach trips the switch
//! is the arm's reference; the step count the arm believed it had there, compared with
//! the switch's angle, is the step error reported on re-homing (lost steps).

use crate::config::InstrumentConfig;
use crate::hardware::{Arm, Arms};
use crate::motion::{ArmMotion, MoveProfile, angle_to_steps, deg_to_steps};
use protocol::{DeviceError, ErrorCode};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Begin,
    /// Fast toward the switch, at most the search range.
    Search,
    /// Switch found; ramping down.
    SearchStopping,
    /// Fast away from the switch by the back-off distance; it must release.
    BackOff,
    /// Slowly toward the switch again.
    Approach,
    /// Switch tripped at `trip_steps`; ramping down.
    ApproachStopping { trip_steps: i32 },
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
}

impl ArmHoming {
    /// Homing of `arm`, not started.
    pub const fn new(arm: Arm) -> ArmHoming {
        ArmHoming { arm, phase: Phase::Begin }
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
        let profile = MoveProfile::fastest(here, here + distance_steps, 0.0, speed, deg_to_steps(config.accel_deg_per_s2));
        motion.start(hardware, self.arm, profile, now_us);
    }

    fn fail(&mut self, code: ErrorCode) -> HomingStatus {
        self.phase = Phase::Finished;
        HomingStatus::Failed(DeviceError::with_detail(code, self.arm.index() as i32))
    }

    /// Advance. Call often while homing (every ms): the switch is sampled here.
    pub fn poll(
        &mut self,
        hardware: &mut impl Arms,
        motion: &mut ArmMotion,
        config: &InstrumentConfig,
        now_us: u64,
    ) -> HomingStatus {
        let pressed = hardware.home_switch_pressed(self.arm);
        let moving = motion.is_moving(hardware, self.arm);
        let search_steps = angle_to_steps(config.home_search_range);
        let backoff_steps = angle_to_steps(config.home_backoff);
        let max_speed = deg_to_steps(config.max_speed_deg_per_s);
        let accel = deg_to_steps(config.accel_deg_per_s2);
        match self.phase {
            Phase::Begin => {
                if pressed {
                    // Already on the switch: straight to backing off.
                    self.constant_speed_move(hardware, motion, config, -backoff_steps, config.home_fast_deg_per_s, now_us);
                    self.phase = Phase::BackOff;
                } else {
                    self.constant_speed_move(hardware, motion, config, search_steps, config.home_fast_deg_per_s, now_us);
                    self.phase = Phase::Search;
                }
            }
            Phase::Search => {
                if pressed {
                    motion.stop(hardware, self.arm, max_speed, accel, now_us);
                    self.phase = Phase::SearchStopping;
                } else if !moving {
                    return self.fail(ErrorCode::HomeSwitchNotFound);
                }
            }
            Phase::SearchStopping => {
                if !moving {
                    self.constant_speed_move(hardware, motion, config, -backoff_steps, config.home_fast_deg_per_s, now_us);
                    self.phase = Phase::BackOff;
                }
            }
            Phase::BackOff => {
                if !moving {
                    if pressed {
                        return self.fail(ErrorCode::HomeSwitchStuck);
                    }
                    // Back over the whole back-off and one degree more: the switch must trip.
                    let approach = backoff_steps + angle_to_steps(protocol::Angle::from_whole_deg(1));
                    self.constant_speed_move(hardware, motion, config, approach, config.home_slow_deg_per_s, now_us);
                    self.phase = Phase::Approach;
                }
            }
            Phase::Approach => {
                if pressed {
                    let trip_steps = hardware.position_steps(self.arm);
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
