//! What is on the sample port: a reflectance function handed in by the caller.
//!
//! The caller supplies the sample's radiance factor as a function of (θi, θr): one of the
//! simulator's own sheets ([`crate::sheet`], physics of its own, not the fit's), a replayed
//! table ([`crate::table`]) or any function a test makes. A sample may differ from spot to
//! spot ([`Spots`]). While white-calibration readings are taken the port holds the white
//! reference tile instead.

use std::sync::Arc;

/// A sample's radiance factor (BRDF × π) in the specular plane, angles in degrees.
pub trait Scene: Send + Sync {
    /// Radiance factor at source angle `theta_i_deg` and detector angle `theta_r_deg`.
    fn radiance_factor(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64;
}

impl<F: Fn(f64, f64) -> f64 + Send + Sync> Scene for F {
    fn radiance_factor(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        self(theta_i_deg, theta_r_deg)
    }
}

/// Certified radiance factor of the reference instrument's white tile.
pub const WHITE_TILE_RADIANCE_FACTOR: f64 = 0.99;

/// The white reference tile: Lambertian, so the same radiance factor in every direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WhiteTile {
    /// Certified radiance factor.
    pub radiance_factor: f64,
}

impl Default for WhiteTile {
    fn default() -> Self {
        WhiteTile {
            radiance_factor: WHITE_TILE_RADIANCE_FACTOR,
        }
    }
}

impl Scene for WhiteTile {
    fn radiance_factor(&self, _theta_i_deg: f64, _theta_r_deg: f64) -> f64 {
        self.radiance_factor
    }
}

/// A sample whose spots differ (a sheet of paper is not the same everywhere): the scene
/// at each spot the operator may put under the beam.
pub trait Spots: Send + Sync {
    /// The scene at spot `index` (0 the first) in the run of `seed`. The same arguments
    /// give the same scene.
    fn spot(&self, seed: u64, index: u32) -> Arc<dyn Scene>;
}

/// The two things that can be on the port.
#[derive(Clone)]
pub struct SamplePort {
    /// The sample under test (at its first spot, when it has spots).
    pub sample: Arc<dyn Scene>,
    /// The white reference tile.
    pub white: WhiteTile,
    /// Where the sample's spots differ, their scenes; `None`: the same scene everywhere.
    pub spots: Option<Arc<dyn Spots>>,
}

impl SamplePort {
    /// A port holding `sample`, the same at every spot, with the default white tile for
    /// calibration.
    pub fn new(sample: Arc<dyn Scene>) -> SamplePort {
        SamplePort {
            sample,
            white: WhiteTile::default(),
            spots: None,
        }
    }

    /// A port holding a sample with spots of its own; spot 0 is on the port at first.
    pub fn with_spots(spots: Arc<dyn Spots>, seed: u64) -> SamplePort {
        SamplePort {
            sample: spots.spot(seed, 0),
            white: WhiteTile::default(),
            spots: Some(spots),
        }
    }
}
