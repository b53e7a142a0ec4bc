//! What goes to and comes from files: measured data sets (CSV), exports and plots, and
//! the session folder (its files, the one writer of them, its manifest and its check), the
//! folder of a sheet of several spots, and the stock library.
pub mod catalogue;
pub mod chromium;
pub mod dataset;
pub mod export;
pub mod folder;
pub mod library;
pub mod manifest;
pub mod plots;
pub mod reanalysis;
pub mod record;
pub mod report;
pub mod sheet;
pub mod store;
pub mod verify;
