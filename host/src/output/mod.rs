//! What goes to and comes from files: measured data sets (CSV), exports and plots.
pub mod dataset;
pub mod export;
pub mod plots;
pub mod record;
