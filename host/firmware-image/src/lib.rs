//! The firmware image built into this release of `gonio`, if any: `GONIO_FIRMWARE_IMAGE`
//! names the board's ELF at build time (`build.rs`). `gonio flash` with no IMAGE writes it.
include!(concat!(env!("OUT_DIR"), "/firmware_image.rs"));
