//! Angles and geometries at the instrument's resolution.
//!
//! An angle is an integer count of the arm resolution (0.0125° = one microstep of a
//! 200-step motor at 16 microsteps through a 9:1 reduction), so a geometry sent to the
//! device is exactly a reachable arm position and equality is exact.

use core::fmt;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Ticks per degree: 200 steps × 16 microsteps × 9 / 360°.
pub const TICKS_PER_DEG: i32 = 80;

/// A polar angle of one arm, in device ticks of [`Angle::RESOLUTION_DEG`].
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    Schema,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Angle(i32);

impl Angle {
    /// Size of one tick in degrees.
    pub const RESOLUTION_DEG: f64 = 1.0 / TICKS_PER_DEG as f64;
    /// 0°.
    pub const ZERO: Angle = Angle(0);

    /// An angle from a whole number of ticks.
    pub const fn from_ticks(ticks: i32) -> Angle {
        Angle(ticks)
    }

    /// An angle from whole degrees (exact).
    pub const fn from_whole_deg(deg: i32) -> Angle {
        Angle(deg * TICKS_PER_DEG)
    }

    /// The nearest angle to `deg`, or `None` when `deg` is not finite or lies beyond
    /// ±1000° (no arm position is that far; the bound keeps the tick count in range).
    pub fn from_deg(deg: f64) -> Option<Angle> {
        if !deg.is_finite() || deg.abs() > 1000.0 {
            return None;
        }
        Some(Angle(libm::round(deg * TICKS_PER_DEG as f64) as i32))
    }

    /// The tick count.
    pub const fn ticks(self) -> i32 {
        self.0
    }

    /// The angle in degrees.
    pub fn deg(self) -> f64 {
        self.0 as f64 / TICKS_PER_DEG as f64
    }
}

impl fmt::Display for Angle {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Ticks are 1/80°, so four decimals show every angle exactly.
        let whole = self.0 / TICKS_PER_DEG;
        let frac = (self.0 % TICKS_PER_DEG).unsigned_abs() * 125;
        let sign = if self.0 < 0 && whole == 0 { "-" } else { "" };
        if frac == 0 {
            write!(f, "{sign}{whole}")
        } else {
            let mut frac = frac;
            let mut width = 4;
            while frac.is_multiple_of(10) {
                frac /= 10;
                width -= 1;
            }
            write!(f, "{sign}{whole}.{frac:0width$}")
        }
    }
}

/// One measurement geometry in the specular plane: the source arm at `theta_i` on one
/// side of the normal, the detector arm at `theta_r` on the other.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    Schema,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Geometry {
    /// Polar angle of the source.
    pub theta_i: Angle,
    /// Polar angle of the detector.
    pub theta_r: Angle,
}

impl Geometry {
    /// A geometry from two angles.
    pub const fn new(theta_i: Angle, theta_r: Angle) -> Geometry {
        Geometry { theta_i, theta_r }
    }

    /// A geometry from whole degrees (exact).
    pub const fn from_whole_deg(theta_i: i32, theta_r: i32) -> Geometry {
        Geometry::new(
            Angle::from_whole_deg(theta_i),
            Angle::from_whole_deg(theta_r),
        )
    }

    /// The nearest geometry to the given angles in degrees; `None` if either is not finite
    /// or absurdly large.
    pub fn from_deg(theta_i: f64, theta_r: f64) -> Option<Geometry> {
        Some(Geometry::new(
            Angle::from_deg(theta_i)?,
            Angle::from_deg(theta_r)?,
        ))
    }

    /// The mirror direction of this geometry's source.
    pub fn is_specular(&self) -> bool {
        self.theta_i == self.theta_r
    }
}

impl fmt::Display for Geometry {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "({}°, {}°)", self.theta_i, self.theta_r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolution_is_one_microstep() {
        assert_eq!(Angle::RESOLUTION_DEG, 0.0125);
        assert_eq!(Angle::from_deg(0.0125), Some(Angle::from_ticks(1)));
        assert_eq!(Angle::from_deg(45.0).unwrap().deg(), 45.0);
        assert_eq!(Angle::from_deg(0.006), Some(Angle::from_ticks(0)));
        assert_eq!(Angle::from_deg(f64::NAN), None);
        assert_eq!(Angle::from_deg(f64::INFINITY), None);
        assert_eq!(Angle::from_deg(1e12), None);
    }

    #[test]
    fn display_is_exact() {
        assert_eq!(Angle::from_ticks(1).to_string(), "0.0125");
        assert_eq!(Angle::from_whole_deg(20).to_string(), "20");
        assert_eq!(Angle::from_ticks(-1).to_string(), "-0.0125");
        assert_eq!(Angle::from_ticks(3660).to_string(), "45.75");
        assert_eq!(Geometry::from_whole_deg(20, 70).to_string(), "(20°, 70°)");
    }
}
