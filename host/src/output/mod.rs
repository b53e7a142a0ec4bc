//! What goes to and comes from files: measured data sets (CSV), exports and plots, and
//! the session folder (its files, the one writer of them, its manifest and its check), the
//! folder of a sheet of several spots, and the stock library.
//!
//! # Layers
//!
//! Each module imports only those below it (none imports one above it, none another of its
//! own row but as listed), so each can be read, and tested, knowing only what is under it:
//!
//! | layer | modules | imports from `output` |
//! |---|---|---|
//! | uses of folders | [`catalogue`], [`reanalysis`], [`library`], [`characterization`] (an instrument profile and its report) | any below (the library hands [`report::draw`] to [`folder::verify`]) |
//! | rendering | [`report`] | `folder` |
//! | writers apart from the folder | [`export`], [`plots`], [`shared_errors`]: what `readings.csv`'s readings share, written and read back | `folder` |
//! | the session or sheet folder | [`folder`]: its names and documents, its store, manifest and signature, reading, writing and verifying it (its own layers are in its page) | none |
//!
//! [`dataset`] (CSV data sets) stands apart: no folder module uses it. Verification checks
//! that `report.html` is the report of the folder's files, yet sits below rendering: the
//! check is handed the drawing ([`folder::verify::DrawReport`]).
pub mod batch;
pub mod catalogue;
pub mod characterization;
pub mod chromium;
pub mod comparison;
pub mod dataset;
pub mod export;
pub mod folder;
pub mod library;
pub mod plots;
pub mod reanalysis;
pub mod report;
pub mod shared_errors;
