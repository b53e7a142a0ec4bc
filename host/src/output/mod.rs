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
//! | uses of folders | [`catalogue`], [`reanalysis`], [`library`], [`characterization`] (an instrument profile and its report) | any below (the library hands [`report::html`] to [`verify`]) |
//! | rendering | [`report`] | `folder`, `sheet_folder` |
//! | verification | [`verify`]: every check of a finished folder | `folder`, `manifest`, `sheet_folder` |
//! | writers | [`record`] (a session folder), [`sheet_folder`] (a sheet's), [`export`], [`plots`] | `folder`, `lock`, `store`, `manifest` |
//! | signatures | [`signature`]: the manifest's signature, a file's, the keys | `folder`, `manifest`, `store` |
//! | store and manifest | [`store`], [`manifest`], [`lock`] | `folder` |
//! | names and documents | [`folder`]: file names, `session.json`, findings, reading; [`documents`]: the typed result and outcome of a finished `session.json`; [`shared_errors`]: what `readings.csv`'s readings share, written and read back | none (`documents`: `folder`; `shared_errors`: `folder`, `manifest`) |
//!
//! [`dataset`] (CSV data sets) stands apart: no folder module uses it. Verification checks
//! that `report.html` is the report of the folder's files, yet sits below rendering: the
//! check is handed the drawing ([`verify::DrawReport`]).
pub mod batch;
pub mod catalogue;
pub mod characterization;
pub mod chromium;
pub mod comparison;
pub mod dataset;
pub mod documents;
pub mod export;
pub mod folder;
pub mod library;
pub mod lock;
pub mod manifest;
pub mod plots;
pub mod reanalysis;
pub mod record;
pub mod report;
pub mod shared_errors;
pub mod sheet_folder;
pub mod signature;
pub mod store;
pub mod verify;
