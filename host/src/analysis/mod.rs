//! The science, pure (no I/O): the TSL model, the fit, the sampling check σ > σ_l,
//! classification, the comparison of two sheets, the report of one analysis, the design
//! of sweeps, the calibration's conversion of readings and its uncertainty budget.
pub mod batch;
pub mod budget;
pub mod calibration;
pub mod classify;
pub mod compare;
pub mod dataset;
pub mod evidence;
pub mod fit;
pub mod flags;
pub mod gloss;
pub mod gof;
pub mod linalg;
pub mod model;
pub mod motion;
pub mod plausibility;
pub mod response_estimate;
pub mod result;
pub mod sampling;
pub mod specimen;
pub mod spots;
pub mod sweep_design;
