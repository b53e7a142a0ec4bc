//! The motion limits of an instrument and the times of its moves and sweeps as its
//! firmware plans them ([`firmware::motion`]): pure arithmetic, which the sweep design and
//! the session's visiting order ([`crate::session::order`]) both use.

use firmware::config::InstrumentConfig;
use firmware::motion::{angle_to_steps, deg_to_steps, move_duration_us};
use protocol::{DeviceInfo, Geometry};

/// Time per geometry besides settle and integration: an allowance for one detector range
/// change (the reference `range_settle_ms`) and the step between readings.
pub const READING_OVERHEAD_US: u64 = 5_000;

/// A device description the planner cannot use.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum MotionError {
    /// Speed limit not a positive finite number.
    #[error("arm speed limit {0} °/s is not a positive number")]
    BadSpeed(f32),
    /// Acceleration limit not a positive finite number.
    #[error("arm acceleration limit {0} °/s² is not a positive number")]
    BadAccel(f32),
}

/// The motion limits of an instrument, as its firmware plans moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    max_speed_steps_per_s: f32,
    accel_steps_per_s2: f32,
    settle_us: u64,
}

impl Motion {
    /// The limits an instrument reported in its handshake.
    pub fn from_info(info: &DeviceInfo) -> Result<Motion, MotionError> {
        Motion::new(
            info.max_speed_deg_per_s,
            info.accel_deg_per_s2,
            info.settle_ms,
        )
    }

    /// The reference instrument (60 °/s, 180 °/s², settle 100 ms).
    pub fn reference() -> Motion {
        let config = InstrumentConfig::REFERENCE;
        Motion {
            max_speed_steps_per_s: deg_to_steps(config.max_speed_deg_per_s),
            accel_steps_per_s2: deg_to_steps(config.accel_deg_per_s2),
            settle_us: u64::from(config.settle_ms) * 1000,
        }
    }

    /// Limits in °/s, °/s² and ms.
    pub fn new(
        max_speed_deg_per_s: f32,
        accel_deg_per_s2: f32,
        settle_ms: u16,
    ) -> Result<Motion, MotionError> {
        if !(max_speed_deg_per_s.is_finite() && max_speed_deg_per_s > 0.0) {
            return Err(MotionError::BadSpeed(max_speed_deg_per_s));
        }
        if !(accel_deg_per_s2.is_finite() && accel_deg_per_s2 > 0.0) {
            return Err(MotionError::BadAccel(accel_deg_per_s2));
        }
        Ok(Motion {
            max_speed_steps_per_s: deg_to_steps(max_speed_deg_per_s),
            accel_steps_per_s2: deg_to_steps(accel_deg_per_s2),
            settle_us: u64::from(settle_ms) * 1000,
        })
    }

    /// The firmware's time for the move from `from` to `to`, µs (both arms at once).
    pub fn move_us(&self, from: Geometry, to: Geometry) -> u64 {
        move_duration_us(
            steps(from),
            steps(to),
            self.max_speed_steps_per_s,
            self.accel_steps_per_s2,
        )
    }

    /// Travel from `start` through `order` in that order, µs.
    pub fn travel_us(&self, start: Geometry, order: &[Geometry]) -> u64 {
        let mut here = start;
        let mut total = 0u64;
        for &next in order {
            total = total.saturating_add(self.move_us(here, next));
            here = next;
        }
        total
    }

    /// The firmware's time for a sweep of the detector arm from `from_deg` to `to_deg` at a
    /// top speed of `speed_deg_per_s` (from rest to rest at the instrument's
    /// acceleration), µs; the source arm holds still.
    pub(crate) fn sweep_us(&self, from_deg: f64, to_deg: f64, speed_deg_per_s: f64) -> u64 {
        let to_steps = |deg: f64| {
            protocol::Angle::from_deg(deg)
                .map_or(0, angle_to_steps)
                .clamp(-STEPS_LIMIT, STEPS_LIMIT)
        };
        let top = deg_to_steps(speed_deg_per_s as f32).min(self.max_speed_steps_per_s);
        firmware::motion::MoveProfile::fastest(
            to_steps(from_deg),
            to_steps(to_deg),
            0.0,
            top,
            self.accel_steps_per_s2,
        )
        .duration_us()
    }

    /// The detector arm's profile for a sweep as the firmware plans it
    /// (`firmware::sweep::sweep_profile`): from rest at `from_steps` to rest at `to_steps`,
    /// the top speed as the request states it, the instrument's acceleration.
    pub(crate) fn sweep_profile(
        &self,
        from_steps: i32,
        to_steps: i32,
        speed_mdeg_per_s: u32,
    ) -> firmware::motion::MoveProfile {
        let top = speed_mdeg_per_s as f32 * (firmware::motion::STEPS_PER_DEG / 1000.0);
        firmware::motion::MoveProfile::fastest(
            from_steps,
            to_steps,
            0.0,
            top,
            self.accel_steps_per_s2,
        )
    }

    /// Settling time after a move, µs.
    pub fn settle_us(&self) -> u64 {
        self.settle_us
    }

    /// Device time per geometry besides travel, µs: settle, integration and
    /// [`READING_OVERHEAD_US`].
    pub fn per_geometry_us(&self, integration_ms: u32) -> u64 {
        self.settle_us + u64::from(integration_ms) * 1000 + READING_OVERHEAD_US
    }
}

/// The sweep design's times ([`crate::analysis::sweep_design`]) are the firmware's profiles.
impl crate::analysis::sweep_design::ArmTiming for Motion {
    fn move_us(&self, from: Geometry, to: Geometry) -> u64 {
        Motion::move_us(self, from, to)
    }

    fn settle_us(&self) -> u64 {
        Motion::settle_us(self)
    }

    fn sweep_us(&self, from_deg: f64, to_deg: f64, speed_deg_per_s: f64) -> u64 {
        Motion::sweep_us(self, from_deg, to_deg, speed_deg_per_s)
    }
}

/// Largest position passed to the firmware's planner, steps: it subtracts positions in
/// `i32`, so they are kept where no difference overflows (±13 million degrees: no real
/// position is near).
const STEPS_LIMIT: i32 = (1 << 30) - 1;

fn steps(g: Geometry) -> [i32; 2] {
    let clamp = |steps: i32| steps.clamp(-STEPS_LIMIT, STEPS_LIMIT);
    [
        clamp(angle_to_steps(g.theta_i)),
        clamp(angle_to_steps(g.theta_r)),
    ]
}
