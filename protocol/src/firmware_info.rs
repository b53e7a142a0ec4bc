//! What a firmware image says it is: the `.gonio.info` section of the board's ELF.
//!
//! Written by the board crate at compile time (a `static` in a section the link script keeps
//! out of flash) and read by `gonio flash` before it touches a probe: the firmware version,
//! the protocol version the image speaks and the board it was built for.
//!
//! Not a wire message: it never crosses the USB link, so it is not part of
//! [`crate::SCHEMA_HASH`]. Its encoding is pinned on its own, by [`FIRMWARE_INFO_LAYOUT`]
//! and the tests below, because it must be readable by hosts of other releases (a host
//! has to be able to say "this image speaks protocol 7, I speak 4").
//!
//! A fixed layout rather than postcard, because a `static` initialiser must be a constant
//! expression and postcard's encoder is not `const`. [`FIRMWARE_INFO_LEN`] bytes:
//!
//! | bytes  | what                                                             |
//! |--------|------------------------------------------------------------------|
//! | 0..8   | magic `GONIOINF`                                                 |
//! | 8      | layout version, [`FIRMWARE_INFO_LAYOUT`]                         |
//! | 9      | 0                                                                |
//! | 10..12 | protocol version, u16 little-endian                              |
//! | 12     | length of the firmware version, at most [`crate::FIRMWARE_VERSION_LEN`] |
//! | 13..29 | firmware version, UTF-8, zero-padded                             |
//! | 29     | length of the board name, at most [`crate::BOARD_NAME_LEN`]      |
//! | 30..62 | board name, UTF-8, zero-padded                                   |
//! | 62..64 | 0                                                                |
use crate::{BOARD_NAME_LEN, FIRMWARE_VERSION_LEN};
use core::fmt;
use heapless::String;

/// Bytes of the encoded [`FirmwareInfo`].
pub const FIRMWARE_INFO_LEN: usize = 64;
/// The first bytes of every encoded [`FirmwareInfo`].
pub const FIRMWARE_INFO_MAGIC: [u8; 8] = *b"GONIOINF";
/// Version of the layout above; a reader refuses any other.
pub const FIRMWARE_INFO_LAYOUT: u8 = 1;
/// The board name of the STM32F411 board (`firmware/board`), as `.gonio.info` carries it.
pub const F411_BOARD_NAME: &str = "gonio-f411";

const VERSION_AT: usize = 12;
const BOARD_AT: usize = VERSION_AT + 1 + FIRMWARE_VERSION_LEN;
const RESERVED_AT: usize = BOARD_AT + 1 + BOARD_NAME_LEN;

/// The contents of `.gonio.info`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FirmwareInfo {
    /// The firmware's version (the `firmware` crate's, as `DeviceInfo` reports it).
    pub firmware_version: String<FIRMWARE_VERSION_LEN>,
    /// The [`crate::PROTOCOL_VERSION`] the image speaks.
    pub protocol_version: u16,
    /// The board it was built for.
    pub board: String<BOARD_NAME_LEN>,
}

/// Why bytes are not an encoded [`FirmwareInfo`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FirmwareInfoError {
    /// Not [`FIRMWARE_INFO_LEN`] bytes.
    Length(usize),
    /// Does not start with [`FIRMWARE_INFO_MAGIC`].
    Magic,
    /// A layout version this reader does not know.
    Layout(u8),
    /// A text field's length byte is larger than the field.
    FieldTooLong {
        /// Which field.
        field: &'static str,
        /// Its length byte.
        len: usize,
        /// The field's size.
        max: usize,
    },
    /// A text field is not UTF-8.
    NotUtf8(&'static str),
    /// A reserved or padding byte is not zero.
    NonZeroPadding(usize),
}

impl fmt::Display for FirmwareInfoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FirmwareInfoError::Length(len) => {
                write!(f, "{len} bytes, where the layout has {FIRMWARE_INFO_LEN}")
            }
            FirmwareInfoError::Magic => write!(f, "does not start with \"GONIOINF\""),
            FirmwareInfoError::Layout(layout) => {
                write!(
                    f,
                    "layout version {layout}, where this host reads version {FIRMWARE_INFO_LAYOUT}"
                )
            }
            FirmwareInfoError::FieldTooLong { field, len, max } => {
                write!(
                    f,
                    "the {field} is {len} bytes long, longer than its field ({max} bytes)"
                )
            }
            FirmwareInfoError::NotUtf8(field) => write!(f, "the {field} is not UTF-8 text"),
            FirmwareInfoError::NonZeroPadding(at) => write!(f, "byte {at} (padding) is not zero"),
        }
    }
}

impl core::error::Error for FirmwareInfoError {}

impl FirmwareInfo {
    /// The encoded section, at compile time: a field too long for the layout is a compile
    /// error in a `static` initialiser.
    pub const fn encode(
        firmware_version: &str,
        protocol_version: u16,
        board: &str,
    ) -> [u8; FIRMWARE_INFO_LEN] {
        let mut out = [0u8; FIRMWARE_INFO_LEN];
        let mut i = 0;
        while i < FIRMWARE_INFO_MAGIC.len() {
            out[i] = FIRMWARE_INFO_MAGIC[i];
            i += 1;
        }
        out[8] = FIRMWARE_INFO_LAYOUT;
        let protocol = protocol_version.to_le_bytes();
        out[10] = protocol[0];
        out[11] = protocol[1];
        let out = put_text(
            out,
            VERSION_AT,
            firmware_version.as_bytes(),
            FIRMWARE_VERSION_LEN,
        );
        put_text(out, BOARD_AT, board.as_bytes(), BOARD_NAME_LEN)
    }

    /// Read an encoded section. Strict: every padding byte must be zero, so that a layout
    /// that grew fields is not misread as this one.
    pub fn decode(bytes: &[u8]) -> Result<FirmwareInfo, FirmwareInfoError> {
        if bytes.len() != FIRMWARE_INFO_LEN {
            return Err(FirmwareInfoError::Length(bytes.len()));
        }
        if bytes[..8] != FIRMWARE_INFO_MAGIC {
            return Err(FirmwareInfoError::Magic);
        }
        if bytes[8] != FIRMWARE_INFO_LAYOUT {
            return Err(FirmwareInfoError::Layout(bytes[8]));
        }
        for at in [9, RESERVED_AT, RESERVED_AT + 1] {
            if bytes[at] != 0 {
                return Err(FirmwareInfoError::NonZeroPadding(at));
            }
        }
        let protocol_version = u16::from_le_bytes([bytes[10], bytes[11]]);
        let firmware_version = text(bytes, VERSION_AT, FIRMWARE_VERSION_LEN, "firmware version")?;
        let board = text(bytes, BOARD_AT, BOARD_NAME_LEN, "board name")?;
        Ok(FirmwareInfo {
            firmware_version,
            protocol_version,
            board,
        })
    }
}

const fn put_text(
    mut out: [u8; FIRMWARE_INFO_LEN],
    at: usize,
    text: &[u8],
    max: usize,
) -> [u8; FIRMWARE_INFO_LEN] {
    assert!(
        text.len() <= max,
        "a .gonio.info text field is longer than the layout allows"
    );
    out[at] = text.len() as u8;
    let mut i = 0;
    while i < text.len() {
        out[at + 1 + i] = text[i];
        i += 1;
    }
    out
}

fn text<const N: usize>(
    bytes: &[u8],
    at: usize,
    max: usize,
    field: &'static str,
) -> Result<String<N>, FirmwareInfoError> {
    let len = usize::from(bytes[at]);
    if len > max {
        return Err(FirmwareInfoError::FieldTooLong { field, len, max });
    }
    let area = &bytes[at + 1..at + 1 + max];
    if let Some(offset) = area[len..].iter().position(|&b| b != 0) {
        return Err(FirmwareInfoError::NonZeroPadding(at + 1 + len + offset));
    }
    let text = core::str::from_utf8(&area[..len]).map_err(|_| FirmwareInfoError::NotUtf8(field))?;
    let mut out = String::new();
    // Cannot fail: len <= max == N.
    out.push_str(text)
        .map_err(|()| FirmwareInfoError::FieldTooLong { field, len, max: N })?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layout_is_pinned() {
        let bytes = FirmwareInfo::encode("1.2.3", 0x0104, "gonio-f411");
        let mut expected = [0u8; FIRMWARE_INFO_LEN];
        expected[..8].copy_from_slice(b"GONIOINF");
        expected[8] = 1;
        expected[10..12].copy_from_slice(&[0x04, 0x01]);
        expected[12] = 5;
        expected[13..18].copy_from_slice(b"1.2.3");
        expected[29] = 10;
        expected[30..40].copy_from_slice(b"gonio-f411");
        assert_eq!(bytes, expected);
        assert_eq!(RESERVED_AT, 62);
    }

    #[test]
    fn what_is_encoded_decodes() {
        for (version, protocol, board) in [
            ("0.1.0", 4, F411_BOARD_NAME),
            ("", 0, ""),
            (
                "16-bytes-exactly",
                u16::MAX,
                "a board name of 32 bytes exactly",
            ),
        ] {
            let info =
                FirmwareInfo::decode(&FirmwareInfo::encode(version, protocol, board)).unwrap();
            assert_eq!(
                (
                    info.firmware_version.as_str(),
                    info.protocol_version,
                    info.board.as_str()
                ),
                (version, protocol, board)
            );
        }
    }

    #[test]
    fn every_damage_is_named() {
        let good = FirmwareInfo::encode("0.1.0", 4, F411_BOARD_NAME);
        assert_eq!(
            FirmwareInfo::decode(&good[..63]),
            Err(FirmwareInfoError::Length(63))
        );
        let mut bad = good;
        bad[0] = b'X';
        assert_eq!(FirmwareInfo::decode(&bad), Err(FirmwareInfoError::Magic));
        let mut bad = good;
        bad[8] = 2;
        assert_eq!(
            FirmwareInfo::decode(&bad),
            Err(FirmwareInfoError::Layout(2))
        );
        let mut bad = good;
        bad[12] = 17;
        assert!(matches!(
            FirmwareInfo::decode(&bad),
            Err(FirmwareInfoError::FieldTooLong {
                len: 17,
                max: 16,
                ..
            })
        ));
        let mut bad = good;
        bad[13] = 0xff;
        assert_eq!(
            FirmwareInfo::decode(&bad),
            Err(FirmwareInfoError::NotUtf8("firmware version"))
        );
        let mut bad = good;
        bad[63] = 1;
        assert_eq!(
            FirmwareInfo::decode(&bad),
            Err(FirmwareInfoError::NonZeroPadding(63))
        );
        let mut bad = good;
        bad[20] = b'x';
        assert_eq!(
            FirmwareInfo::decode(&bad),
            Err(FirmwareInfoError::NonZeroPadding(20))
        );
    }

    #[test]
    fn any_bytes_decode_or_fail_without_panic() {
        // Every single-byte change of a good section, at every position.
        let good = FirmwareInfo::encode("0.1.0", 4, F411_BOARD_NAME);
        for at in 0..FIRMWARE_INFO_LEN {
            for value in [0u8, 1, 0x7f, 0x80, 0xff] {
                let mut bytes = good;
                bytes[at] = value;
                let _ = FirmwareInfo::decode(&bytes);
            }
        }
    }
}
