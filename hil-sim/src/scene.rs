//! What is on the sample port: a reflectance function handed in by the caller.
//!
//! The caller supplies the sample's radiance factor as a function of (θi, θr): one of the
//! simulator's own sheets ([`crate::sheet`], physics of its own, not the fit's), a replayed
//! table ([`crate::table`]) or any function a test makes. A sample may differ from spot to
//! spot ([`Spots`]). While white-calibration readings are taken the port holds the white
//! reference tile instead.
//!
//! A mirror is not a point function: its reflected beam is as narrow as the lamp's, so no
//! radiance factor at (θi, θr) describes it. A scene says it is one
//! ([`Scene::mirror_index`]) and the detector reads the beam through its own angular
//! response ([`crate::detector::Detector::seen_radiance_factor`]); the black glass gloss
//! standard is such a scene ([`BlackGlass`]).

use std::sync::Arc;

/// A sample's radiance factor (BRDF × π) in the specular plane, angles in degrees.
pub trait Scene: Send + Sync {
    /// Radiance factor at source angle `theta_i_deg` and detector angle `theta_r_deg`.
    fn radiance_factor(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64;

    /// The refractive index of a polished surface that reflects the lamp's beam as a
    /// mirror, on top of [`Scene::radiance_factor`]; `None` (the default): no mirror.
    fn mirror_index(&self) -> Option<f64> {
        None
    }
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

/// Refractive index of the black glass gloss standard (ISO 2813's primary standard, at
/// 587.6 nm): its specular reflectance defines 100 gloss units.
pub const BLACK_GLASS_INDEX: f64 = 1.567;

/// A polished black glass plane: a mirror of [`BLACK_GLASS_INDEX`] with nothing else (the
/// light it refracts is absorbed in the glass, so nothing comes back off specular).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlackGlass {
    /// Refractive index.
    pub refractive_index: f64,
}

impl Default for BlackGlass {
    fn default() -> Self {
        BlackGlass {
            refractive_index: BLACK_GLASS_INDEX,
        }
    }
}

impl Scene for BlackGlass {
    fn radiance_factor(&self, _theta_i_deg: f64, _theta_r_deg: f64) -> f64 {
        0.0
    }

    fn mirror_index(&self) -> Option<f64> {
        Some(self.refractive_index)
    }
}

/// Reflectance of a smooth plane of refractive index `n` (from air) for unpolarized light
/// at incidence `theta_i_deg`: the mean of the s and p Fresnel reflectances (the lamp is
/// unpolarized). 1 beyond the critical angle of an `n` below 1.
pub fn fresnel_unpolarized(n: f64, theta_i_deg: f64) -> f64 {
    let (sin_i, cos_i) = theta_i_deg.to_radians().sin_cos();
    let cos_i = cos_i.abs();
    let sin_t = sin_i / n;
    if sin_t.abs() >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin_t * sin_t).sqrt();
    let rs = (cos_i - n * cos_t) / (cos_i + n * cos_t);
    let rp = (n * cos_i - cos_t) / (n * cos_i + cos_t);
    0.5 * (rs * rs + rp * rp)
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
