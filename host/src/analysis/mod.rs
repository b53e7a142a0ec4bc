//! The science, pure (no I/O): the TSL model, the fit, the sampling check σ > σ_l,
//! classification, the comparison of two sheets, and the report of one analysis.
pub mod budget;
pub mod classify;
pub mod compare;
pub mod dataset;
pub mod evidence;
pub mod fit;
pub mod flags;
pub mod gof;
pub mod linalg;
pub mod model;
pub mod report;
pub mod sampling;
pub mod sheet;
