//! Arm motion: angle ↔ microstep conversion and velocity profiles.
//!
//! One tick of [`protocol::Angle`] is one microstep (0.0125°), so conversion is exact.
//! A [`MoveProfile`] is a trapezoidal (or, for short moves, triangular) velocity profile
//! that ends exactly on its target step. The library plans profiles; the board executes
//! them with a hardware timer, asking [`MoveProfile::step_time_us`] for the time of each
//! step (one square root per step, cheap on the Cortex-M4F's FPU), so step timing never
//! depends on how busy the CPU is with USB.
//!
//! Both arms move at once and ARRIVE TOGETHER: the arm with the longer travel gets the
//! fastest profile within the limits, the other arm the same profile scaled down in
//! distance (same phase durations, proportionally lower speed and acceleration). Why:
//! - the move takes as long as the longer travel anyway, so arriving together costs no time;
//! - scaled profiles put the arms on a straight line in (θi, θr), so the collision guard
//!   θi + θr ≥ 10° (a half-plane) holds all the way when it holds at both ends; a stop
//!   keeps them on that line too ([`ArmMotion::stop_both`]);
//! - one arrival, one settle, and the shorter arm moves gentler (less vibration).

use crate::hardware::{Arm, Arms};
use libm::{ceilf, floorf, sqrtf};
use protocol::Angle;
use protocol::geometry::TICKS_PER_DEG;

/// Microsteps per degree (one tick is one microstep).
pub const STEPS_PER_DEG: f32 = TICKS_PER_DEG as f32;

/// The microstep position of an angle.
pub const fn angle_to_steps(angle: Angle) -> i32 {
    angle.ticks()
}

/// The angle of a microstep position.
pub const fn steps_to_angle(steps: i32) -> Angle {
    Angle::from_ticks(steps)
}

/// A speed or acceleration in °/s (°/s²) as steps/s (steps/s²).
pub fn deg_to_steps(deg: f32) -> f32 {
    deg * STEPS_PER_DEG
}

/// One arm's move: accelerate from `start_speed` to `peak_speed`, cruise, decelerate to
/// rest on the target. Speeds in steps/s, acceleration in steps/s², times in s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MoveProfile {
    start_steps: i32,
    distance_steps: i32,
    start_speed: f32,
    peak_speed: f32,
    accel: f32,
    accel_s: f32,
    cruise_s: f32,
    decel_s: f32,
}

impl MoveProfile {
    /// A move of no distance, at `steps`.
    pub const fn rest(steps: i32) -> MoveProfile {
        MoveProfile {
            start_steps: steps,
            distance_steps: 0,
            start_speed: 0.0,
            peak_speed: 0.0,
            accel: 0.0,
            accel_s: 0.0,
            cruise_s: 0.0,
            decel_s: 0.0,
        }
    }

    /// The fastest move from `start` to `target` within `max_speed` and `accel`, entered
    /// at `start_speed` towards the target. Needs room to stop:
    /// |target − start| ≥ start_speed² / (2·accel) (true for a move from rest).
    pub fn fastest(
        start: i32,
        target: i32,
        start_speed: f32,
        max_speed: f32,
        accel: f32,
    ) -> MoveProfile {
        let distance = (target - start).unsigned_abs() as f32;
        if distance == 0.0 || accel <= 0.0 || max_speed <= 0.0 {
            return MoveProfile::rest(start);
        }
        // Not f32::clamp: its check of the bounds formats floats in its panic message,
        // which links core::fmt's float code (12 KiB) into the firmware.
        let start_speed = start_speed.max(0.0).min(max_speed);
        // Accelerate to v and decelerate to 0 in `distance`: (v² − v0²)/2a + v²/2a = d.
        let triangle_peak = sqrtf(accel * distance + start_speed * start_speed / 2.0);
        let (peak_speed, cruise_s) = if triangle_peak <= max_speed {
            (triangle_peak.max(start_speed), 0.0)
        } else {
            let ramps = (2.0 * max_speed * max_speed - start_speed * start_speed) / (2.0 * accel);
            (max_speed, ((distance - ramps) / max_speed).max(0.0))
        };
        MoveProfile {
            start_steps: start,
            distance_steps: target - start,
            start_speed,
            peak_speed,
            accel,
            accel_s: (peak_speed - start_speed) / accel,
            cruise_s,
            decel_s: peak_speed / accel,
        }
    }

    /// A ramped stop: from `start` moving in `direction` (±1) at `speed`, decelerate at
    /// `accel` and come to rest on the first whole step at or beyond the braking distance.
    pub fn stop(start: i32, direction: i32, speed: f32, max_speed: f32, accel: f32) -> MoveProfile {
        if speed <= 0.0 || accel <= 0.0 {
            return MoveProfile::rest(start);
        }
        let braking_steps = ceilf(speed * speed / (2.0 * accel)) as i32;
        let target = start + direction.signum() * braking_steps.max(1);
        MoveProfile::fastest(start, target, speed, max_speed.max(speed), accel)
    }

    /// This profile's timing applied to another arm's move from `start` to `target`:
    /// same phase durations, speeds and acceleration scaled by the distance ratio.
    /// Both arms then arrive together on a straight line in (θi, θr).
    pub fn scaled(&self, start: i32, target: i32) -> MoveProfile {
        let own = self.distance_steps.unsigned_abs() as f32;
        let other = (target - start).unsigned_abs() as f32;
        if own == 0.0 || other == 0.0 {
            return MoveProfile::rest(start);
        }
        let ratio = other / own;
        MoveProfile {
            start_steps: start,
            distance_steps: target - start,
            start_speed: self.start_speed * ratio,
            peak_speed: self.peak_speed * ratio,
            accel: self.accel * ratio,
            ..*self
        }
    }

    /// Where the move starts, steps.
    pub fn start_steps(&self) -> i32 {
        self.start_steps
    }

    /// Where the move ends, steps.
    pub fn target_steps(&self) -> i32 {
        self.start_steps + self.distance_steps
    }

    /// Steps to go: |target − start|.
    pub fn step_count(&self) -> u32 {
        self.distance_steps.unsigned_abs()
    }

    /// +1 or −1 (0 for no move).
    pub fn direction(&self) -> i32 {
        self.distance_steps.signum()
    }

    /// The highest speed reached, steps/s.
    pub fn peak_speed(&self) -> f32 {
        self.peak_speed
    }

    /// The acceleration used, steps/s².
    pub fn accel(&self) -> f32 {
        self.accel
    }

    /// Duration, s.
    pub fn duration_s(&self) -> f32 {
        self.accel_s + self.cruise_s + self.decel_s
    }

    /// Duration, µs, rounded up so that the move is over at `duration_us`.
    pub fn duration_us(&self) -> u64 {
        ceilf(self.duration_s() * 1e6) as u64
    }

    fn accel_end_distance(&self) -> f32 {
        self.start_speed * self.accel_s + 0.5 * self.accel * self.accel_s * self.accel_s
    }

    /// Distance travelled (≥ 0, along the direction) after `t_s` seconds, continuous.
    pub fn travelled(&self, t_s: f32) -> f32 {
        let distance = self.step_count() as f32;
        if t_s <= 0.0 {
            return 0.0;
        }
        if t_s < self.accel_s {
            return self.start_speed * t_s + 0.5 * self.accel * t_s * t_s;
        }
        let accel_end = self.accel_end_distance();
        if t_s < self.accel_s + self.cruise_s {
            return accel_end + self.peak_speed * (t_s - self.accel_s);
        }
        if t_s < self.duration_s() {
            let tau = t_s - self.accel_s - self.cruise_s;
            let s = accel_end + self.peak_speed * self.cruise_s + self.peak_speed * tau
                - 0.5 * self.accel * tau * tau;
            return s.min(distance);
        }
        distance
    }

    /// Speed (≥ 0) after `t_s` seconds, steps/s.
    pub fn speed_at(&self, t_s: f32) -> f32 {
        if t_s < 0.0 || t_s >= self.duration_s() {
            0.0
        } else if t_s < self.accel_s {
            self.start_speed + self.accel * t_s
        } else if t_s < self.accel_s + self.cruise_s {
            self.peak_speed
        } else {
            (self.peak_speed - self.accel * (t_s - self.accel_s - self.cruise_s)).max(0.0)
        }
    }

    /// The step position after `elapsed_us`: whole steps completed, exactly the target at
    /// and after the end.
    pub fn position_at(&self, elapsed_us: u64) -> i32 {
        if elapsed_us >= self.duration_us() {
            return self.target_steps();
        }
        let done = floorf(self.travelled(elapsed_us as f32 * 1e-6) + 1e-3) as i32;
        self.start_steps + self.direction() * done.clamp(0, self.step_count() as i32)
    }

    /// When step `k` (1 … step count) is issued, s after the start. The last step is at
    /// the end of the profile. Numerically stable forms (no cancellation near the ends).
    pub fn step_time_s(&self, k: u32) -> f32 {
        let count = self.step_count();
        if k == 0 {
            return 0.0;
        }
        if k >= count {
            return self.duration_s();
        }
        let s = k as f32;
        let accel_end = self.accel_end_distance();
        let cruise_end = accel_end + self.peak_speed * self.cruise_s;
        let t = if s <= accel_end {
            // v0·t + a·t²/2 = s
            let root = sqrtf(self.start_speed * self.start_speed + 2.0 * self.accel * s);
            2.0 * s / (self.start_speed + root)
        } else if s <= cruise_end {
            self.accel_s + (s - accel_end) / self.peak_speed
        } else {
            // vp·τ − a·τ²/2 = s − cruise_end
            let rest = s - cruise_end;
            let root =
                sqrtf((self.peak_speed * self.peak_speed - 2.0 * self.accel * rest).max(0.0));
            self.accel_s + self.cruise_s + 2.0 * rest / (self.peak_speed + root)
        };
        t.min(self.duration_s())
    }

    /// When step `k` is issued, µs after the start (what a timer-driven step generator
    /// loads: the difference between consecutive steps is the next timer period).
    pub fn step_time_us(&self, k: u32) -> u64 {
        if k >= self.step_count() {
            return self.duration_us();
        }
        (self.step_time_s(k) * 1e6) as u64
    }
}

/// Plan a move of both arms (source, detector) from `from` to `to`, arriving together.
pub fn plan_move(from: [i32; 2], to: [i32; 2], max_speed: f32, accel: f32) -> [MoveProfile; 2] {
    let leader = if (to[0] - from[0]).unsigned_abs() >= (to[1] - from[1]).unsigned_abs() {
        0
    } else {
        1
    };
    let follower = 1 - leader;
    let lead = MoveProfile::fastest(from[leader], to[leader], 0.0, max_speed, accel);
    let follow = lead.scaled(from[follower], to[follower]);
    let mut profiles = [lead; 2];
    profiles[follower] = follow;
    profiles
}

/// Duration of a move of both arms, µs, as [`plan_move`] plans it.
pub fn move_duration_us(from: [i32; 2], to: [i32; 2], max_speed: f32, accel: f32) -> u64 {
    let [source, detector] = plan_move(from, to, max_speed, accel);
    source.duration_us().max(detector.duration_us())
}

/// A profile an arm is running, and since when.
#[derive(Clone, Copy, Debug, PartialEq)]
struct RunningProfile {
    profile: MoveProfile,
    started_us: u64,
}

/// Which profile each arm runs: the library's record, so that any motion can be
/// stopped with a ramp from its current speed.
#[derive(Clone, Debug, Default)]
pub struct ArmMotion {
    running: [Option<RunningProfile>; 2],
}

impl ArmMotion {
    /// No arm moving.
    pub const fn new() -> ArmMotion {
        ArmMotion {
            running: [None, None],
        }
    }

    /// Hand `profile` to the arm's step generator at `now_us`. A profile of no steps
    /// still reaches a moving arm: it ends what runs (a stop at zero speed, in the same
    /// poll as the start, must not let the move run on).
    pub fn start(&mut self, hardware: &mut impl Arms, arm: Arm, profile: MoveProfile, now_us: u64) {
        if profile.step_count() == 0 {
            if hardware.is_moving(arm) {
                hardware.run_profile(arm, &profile);
            }
            self.running[arm.index()] = None;
            return;
        }
        hardware.run_profile(arm, &profile);
        self.running[arm.index()] = Some(RunningProfile {
            profile,
            started_us: now_us,
        });
    }

    /// Bring the arm to rest with a deceleration ramp from the speed it has now, at
    /// `accel`. Alone, for an arm that moves on its own (homing); a stop of whatever both
    /// arms run is [`ArmMotion::stop_both`], which keeps them on their line.
    pub fn stop(
        &mut self,
        hardware: &mut impl Arms,
        arm: Arm,
        max_speed: f32,
        accel: f32,
        now_us: u64,
    ) {
        let Some((here, speed)) = self.state_at(hardware, arm, now_us) else {
            return;
        };
        let profile = self.stop_profile(arm, here, speed, max_speed, accel);
        self.start(hardware, arm, profile, now_us);
    }

    /// Bring both arms to rest together, on the straight line in (θi, θr) they move along.
    ///
    /// Why not [`ArmMotion::stop`] on each: at full deceleration each arm would take its
    /// own time to stop (the slower arm less), so the arm with the shorter travel would stop
    /// early and leave the move's line. The collision guard θi + θr ≥ 10° is a half-plane:
    /// it holds on the straight line between two points that keep it, not off it (a move
    /// (20°, 0°) → (0°, 10°) stopped at peak speed came to rest at (0.01°, 7.50°)).
    /// So both arms stop in the time T the faster one needs at `accel`, each decelerating at
    /// its own speed / T: the ratio of their speeds stays what it was (that of the move,
    /// [`plan_move`]), so each braking distance is its speed × T / 2 and the arms come to
    /// rest on the move's line, short of (or at) its end, within the one-step rounding of
    /// each arm. The slower arm brakes more gently; no arm brakes harder than `accel`. An
    /// arm is never sent past the target of the profile it was running, so a stop ends
    /// between the move's endpoints, which both keep the guard.
    pub fn stop_both(&mut self, hardware: &mut impl Arms, max_speed: f32, accel: f32, now_us: u64) {
        let states = Arm::BOTH.map(|arm| self.state_at(hardware, arm, now_us));
        let fastest = states
            .iter()
            .flatten()
            .map(|&(_, speed)| speed)
            .fold(0.0f32, f32::max);
        // The common stopping time, s; zero when nothing moves (each arm then stops where
        // it is).
        let stop_s = if accel > 0.0 { fastest / accel } else { 0.0 };
        for arm in Arm::BOTH {
            let Some((here, speed)) = states[arm.index()] else {
                continue;
            };
            let arm_accel = if stop_s > 0.0 { speed / stop_s } else { 0.0 };
            let profile = self.stop_profile(arm, here, speed, max_speed, arm_accel);
            self.start(hardware, arm, profile, now_us);
        }
    }

    /// Stop the arm where it is, with no ramp (a faulted driver: its motion is lost anyway,
    /// and its step count no longer says where it is).
    pub fn stop_dead(&mut self, hardware: &mut impl Arms, arm: Arm, now_us: u64) {
        let here = hardware.position_steps(arm);
        self.start(hardware, arm, MoveProfile::rest(here), now_us);
    }

    /// Where a moving arm is and its speed (steps/s) at `now_us`; `None` when it is at
    /// rest (then its record is dropped).
    fn state_at(&mut self, hardware: &impl Arms, arm: Arm, now_us: u64) -> Option<(i32, f32)> {
        let running = self.running[arm.index()]?;
        if !hardware.is_moving(arm) {
            self.running[arm.index()] = None;
            return None;
        }
        let elapsed_s = now_us.saturating_sub(running.started_us) as f32 * 1e-6;
        let speed = running.profile.speed_at(elapsed_s);
        Some((hardware.position_steps(arm), speed))
    }

    /// The ramp that stops `arm` from `here` at `speed`, decelerating at `accel`, and not
    /// past the target of the profile it runs: that target is where the arm was going
    /// anyway, and the rounding up of the braking distance to a whole step must not carry
    /// a stop beyond a move's end. (Short of the braking distance only by that rounding: the
    /// profile then ends its last fraction of a step a little early.)
    fn stop_profile(
        &self,
        arm: Arm,
        here: i32,
        speed: f32,
        max_speed: f32,
        accel: f32,
    ) -> MoveProfile {
        let Some(running) = self.running[arm.index()] else {
            return MoveProfile::rest(here);
        };
        let direction = running.profile.direction();
        let ramp = MoveProfile::stop(here, direction, speed, max_speed, accel);
        let room = (running.profile.target_steps() - here) * direction;
        if room <= 0 {
            return MoveProfile::rest(here);
        }
        if ramp.step_count() as i32 <= room {
            return ramp;
        }
        MoveProfile::fastest(
            here,
            here + direction * room,
            speed,
            max_speed.max(speed),
            accel,
        )
    }

    /// Whether the arm's step generator still runs a profile.
    pub fn is_moving(&self, hardware: &impl Arms, arm: Arm) -> bool {
        hardware.is_moving(arm)
    }

    /// Whether either arm moves.
    pub fn any_moving(&self, hardware: &impl Arms) -> bool {
        Arm::BOTH.iter().any(|&arm| hardware.is_moving(arm))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const VMAX: f32 = 4800.0;
    const AMAX: f32 = 14_400.0;

    #[test]
    fn long_move_is_trapezoidal_short_move_triangular() {
        let long = MoveProfile::fastest(0, 6800, 0.0, VMAX, AMAX);
        assert_eq!(long.peak_speed(), VMAX);
        // 85° at 60°/s plus one ramp time (1/3 s).
        assert!((long.duration_s() - (85.0 / 60.0 + 1.0 / 3.0)).abs() < 1e-4);
        let short = MoveProfile::fastest(100, 20, 0.0, VMAX, AMAX);
        assert!(short.peak_speed() < VMAX);
        assert_eq!(short.target_steps(), 20);
        assert_eq!(short.position_at(short.duration_us()), 20);
    }

    #[test]
    fn stop_decelerates_from_speed() {
        let stop = MoveProfile::stop(1000, -1, VMAX, VMAX, AMAX);
        assert_eq!(stop.target_steps(), 1000 - 800);
        assert!(stop.peak_speed() <= VMAX * 1.0001);
        assert!((stop.duration_s() - 1.0 / 3.0).abs() < 1e-3);
    }
}
