//! The wire contract between the gonio instrument and its host.
//!
//! One small `no_std`, allocation-free crate that firmware, simulator and host all
//! share (the postcard-rpc "ICD" pattern): every message ([`messages`]), the framing
//! ([`framing`]: postcard + CRC-32 + COBS), the geometry type ([`geometry`]) and the
//! measurement schedules of the method ([`schedules`]); and what a firmware image says it
//! is ([`firmware_info`], not a wire message). Nothing else lives here.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod firmware_info;
pub mod framing;
pub mod geometry;
pub mod messages;
pub mod schedules;
pub mod schema;

pub use firmware_info::{F411_BOARD_NAME, FIRMWARE_INFO_LEN, FirmwareInfo, FirmwareInfoError};
pub use framing::{FrameDecoder, FrameError, Sequenced, encode_frame};
pub use geometry::{Angle, Geometry};
pub use messages::*;
pub use schema::SCHEMA_HASH;

/// Version of this wire contract. Bumped on any change to the encoding of a message;
/// the handshake refuses a peer with a different version.
///
/// `Command::Hello` and the leading `protocol_version` of its reply keep their encoding
/// across versions, so that a mismatch can always be reported in words.
///
/// Every encoding is pinned by `tests/data/golden.hex`; `cargo test -p protocol --test
/// golden` fails on any change until this is bumped and the file regenerated
/// (`GONIO_BLESS=1 cargo test -p protocol --test it golden`).
///
/// History: 1, the first release; 2, `DeviceInfo` gained `min_integration_ms`,
/// `heartbeat_timeout_ms` and `serial_number`, and `TakeReading` a forced `range`;
/// 3, `DeviceInfo` gained `reset_cause` (why the device restarted: a fault of its own
/// with the reason, the watchdog, power-on) and `longest_home_ms`; 4, sweeps
/// (`Command::Sweep`, `Reply::Sweep`, `DeviceMessage::SweepBin` and `SweepDone`,
/// `DeviceState::Sweeping`), and what a host needs to plan and correct them: each
/// `DetectorRange`'s amplifier time constant and settling time, `DeviceInfo`'s
/// `detector_block_us`, and `MAX_SWEEP_BINS`; 5, the self-test (`Command::SelfTest`,
/// `Reply::SelfTest` with its `SelfTestReport` and `PulseCheck`).
///
/// The shape of every message is also pinned as one number, [`schema::SCHEMA_HASH`],
/// which must be the hash of this version in [`SCHEMA_HISTORY`] (`tests/it/schema.rs`).
pub const PROTOCOL_VERSION: u16 = 5;

/// The wire schema hash ([`schema::SCHEMA_HASH`]) of each protocol version since 2, oldest
/// first. A change of any message's encoding changes the hash: then bump
/// [`PROTOCOL_VERSION`] and append `(new version, new hash)` here (`cargo test -p protocol
/// --test it schema` prints it); an entry is never edited.
pub const SCHEMA_HISTORY: &[(u16, u64)] = &[
    (2, 0xf4fc_c159_3ea1_cc3a),
    (3, 0xe291_1f63_e599_b75a),
    (4, 0x2e9e_016a_ac26_78b5),
    (5, 0xe2db_c9c2_1f83_8cd7),
];

/// Largest encoded frame on the wire, delimiter included. Sized for the largest message
/// (a schedule chunk or the device info) with margin; both sides size their buffers to it.
pub const MAX_FRAME_LEN: usize = 256;

/// Largest postcard payload of one frame (the CRC and the COBS overhead take the rest).
pub const MAX_PAYLOAD_LEN: usize = MAX_FRAME_LEN - 1 - 4 - MAX_FRAME_LEN.div_ceil(254);

/// USB identity of the instrument, (vendor id, product id): 1209:0001, pid.codes' shared
/// TEST id. pid.codes (VID 0x1209) leaves 0x0001 to anyone's testing, so unrelated test
/// devices share it and a host cannot tell the instrument by it alone (the host also matches
/// [`USB_PRODUCT`]). A production build needs a PID of its own: pid.codes allocates free
/// ones to open-hardware projects (a request to their registry, github.com/pidcodes). Not
/// to be replaced by a number of our own choosing: a PID is only ours once allocated.
/// The one place the pair is set; the board and the host's port detection read it.
pub const USB_VID_PID: (u16, u16) = (0x1209, 0x0001);
/// The vendor id of [`USB_VID_PID`].
pub const USB_VID: u16 = USB_VID_PID.0;
/// The product id of [`USB_VID_PID`].
pub const USB_PID: u16 = USB_VID_PID.1;
/// USB product string; host auto-detection matches on it as well as VID/PID.
pub const USB_PRODUCT: &str = "gonio reflectometer";
