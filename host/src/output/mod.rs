//! What goes to and comes from files: measured data sets (CSV), exports and plots, and
//! the session folder (its files, the one writer of them, its manifest and its check).
pub mod dataset;
pub mod export;
pub mod folder;
pub mod manifest;
pub mod plots;
pub mod record;
pub mod store;
pub mod verify;
pub mod library;
// TEMPORARY: stands in for analysis::evidence until it lands on main (see the file).
