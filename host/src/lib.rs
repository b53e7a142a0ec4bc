//! The gonio host library. Its folders are its parts:
//! - [`analysis`]: the model, the fit, the sampling check, classification, comparison and
//!   the analysis report: pure functions, no I/O;
//! - [`instrument`]: the link to the instrument, the serial port, the simulator
//!   connection and the calibration;
//! - [`session`]: the measurement session's state machine, the adaptive policy and the
//!   visiting order;
//! - [`study`]: campaigns over simulated sessions (the speed–accuracy trade);
//! - [`output`]: data sets, exports and plots;
//! - [`schema`]: the names and versions of gonio's JSON documents.
//!
//! The `gonio` command line is the binary's (`src/cli/`), on top of these.
// The numerics index vectors and matrices as the algebra writes them (a[row][col], l[k]);
// comparisons written `!(a > b)` are meant to be true for NaN as well.
#![allow(
    clippy::needless_range_loop,
    clippy::neg_cmp_op_on_partial_ord,
    clippy::nonminimal_bool
)]
pub mod analysis;
pub mod instrument;
pub mod output;
pub mod schema;
pub mod session;
pub mod study;
