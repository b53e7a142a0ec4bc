//! The gonio host library. Its folders are its parts:
//! - [`analysis`]: the model, the fit, the sampling check, classification, comparison,
//!   the calibration's conversion and uncertainty budget, the arms' motion times and the
//!   analysis report: pure functions, no I/O;
//! - [`instrument`]: the link to the instrument, the serial port, the simulator
//!   connection and the calibration's files and clock;
//! - [`session`]: the measurement session's state machine, the adaptive policy and the
//!   visiting order;
//! - [`study`]: campaigns over simulated sessions (the speed–accuracy trade);
//! - [`output`]: session and sheet folders (written, verified, reported), data sets,
//!   exports, plots and the stock library;
//! - [`measure`]: a whole `gonio measure`, a session or a sheet of spots, run on a
//!   session and written to its folder;
//! - [`schema`]: the names and versions of gonio's JSON documents;
//! - [`text`]: text from a file made safe to show on a terminal (escaped, cut short).
//!
//! Layers, bottom to top: analysis, instrument, session, output, measure and study (which
//! runs sessions and draws with output's plots); schema and text are read from anywhere. A layer
//! imports only those below it, without exception. The `gonio` command line is the
//! binary's (`src/cli/`), on top of them all.
// The numerics index vectors and matrices as the algebra writes them (a[row][col], l[k]);
// comparisons written `!(a > b)` are meant to be true for NaN as well.
#![allow(
    clippy::needless_range_loop,
    clippy::neg_cmp_op_on_partial_ord,
    clippy::nonminimal_bool
)]
pub mod analysis;
pub mod instrument;
pub mod measure;
pub mod output;
pub mod schema;
pub mod session;
pub mod study;
pub mod text;

/// A value given on the command line that is not acceptable (out of its range, an unknown
/// name): the command line was wrong, whichever layer found it, so `gonio` exits with its
/// usage code (2) as clap does for a value it refuses itself (README, "Exit codes").
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

/// `anyhow::bail!` for a [`UsageError`].
#[macro_export]
macro_rules! usage_bail {
    ($($arg:tt)*) => {
        return Err(anyhow::Error::new($crate::UsageError(format!($($arg)*))))
    };
}
