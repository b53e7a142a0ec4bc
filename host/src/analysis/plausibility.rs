//! What the fit cannot see for itself: input that is numerically fine but cannot be a
//! paper measured in degrees and radiance factors. A table in percent fits as well as one
//! in fractions (the model scales), so it was classified with full confidence; one in
//! radians only fails as lack of fit, which says nothing of why. Each check names what
//! looks wrong, as a note (`percent_suspected`, `radians_suspected`,
//! `outside_population`), and the result is flagged `implausible-input`.
use crate::analysis::classify::Classification;
use crate::analysis::fit::{FitResult, Note, Observation};

/// A diffuse radiance factor above this is beyond any paper: a perfect diffuser is 1 and
/// Table 6's whitest paper 0.855; a table in percent puts it near 80.
pub(crate) const RHO_D_MAX: f64 = 1.5;
/// ρd / 100 at most this: the table reads as a paper's once divided by 100 (above it, the
/// values are beyond papers in either unit).
const RHO_D_PERCENT_MAX: f64 = 1.2;
/// Every |angle| at most this (π/2 ≈ 1.571 with room for rounding): the angles read as
/// radians; in degrees they would all lie within 1.6° of the normal.
pub(crate) const RADIANS_MAX: f64 = 1.6;
/// The nearest of Table 6's papers farther than this many combined standard uncertainties
/// (each paper's 10 % and the fit's own): outside the population of papers gonio's classes
/// were drawn from, where a class would be an extrapolation (none is given). Papers of those kinds lie within a
/// few; an unusual paper within tens.
pub(crate) const POPULATION_DISTANCE_MAX: f64 = 50.0;

/// The notes of what looks wrong with `observations` and their fit.
pub(crate) fn check(
    observations: &[Observation],
    fit: &FitResult,
    classification: &Classification,
) -> Vec<Note> {
    let mut notes = Vec::new();
    let max_abs_angle = observations
        .iter()
        .flat_map(|o| [o.theta_i_deg.abs(), o.theta_r_deg.abs()])
        .fold(0.0, f64::max);
    let max_theta_i = observations
        .iter()
        .map(|o| o.theta_i_deg.abs())
        .fold(0.0, f64::max);
    // Some incidence off the normal (a table of zeros is no table in radians either).
    if max_abs_angle <= RADIANS_MAX && max_theta_i > 0.01 {
        notes.push(Note::RadiansSuspected { max_abs_angle });
    }
    let rho_d = fit.params.rho_d;
    let max_radiance_factor = observations
        .iter()
        .map(|o| o.radiance_factor)
        .fold(f64::NEG_INFINITY, f64::max);
    if rho_d > RHO_D_MAX && rho_d / 100.0 <= RHO_D_PERCENT_MAX {
        notes.push(Note::PercentSuspected {
            rho_d,
            max_radiance_factor,
        });
    }
    let far = classification.nearest_distance > POPULATION_DISTANCE_MAX;
    if far || rho_d > RHO_D_MAX {
        notes.push(Note::OutsidePopulation {
            nearest_reference: classification.nearest_reference,
            distance: classification.nearest_distance,
            rho_d,
        });
    }
    notes
}
