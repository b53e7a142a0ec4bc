//! Framing: `COBS( postcard(message) ++ CRC-32(payload) ) ++ 0x00`.
//!
//! Encoding is postcard's own flavor stack (`CrcModifier` over `Cobs` over `Slice`), so
//! the CRC and the byte stuffing are postcard's. Decoding uses the same `cobs` crate
//! and postcard's CRC-checking deserializer.
//!
//! Why not `postcard::accumulator::CobsAccumulator`: it deserializes the COBS-decoded
//! bytes itself and keeps them private, so the CRC could not be checked before trusting
//! the payload, and a corrupted frame could not be told from an unknown message.
//! [`FrameDecoder`] keeps its semantics (bounded buffer, resynchronise at the next
//! delimiter) and adds exactly one [`FrameError::TooLong`] per over-long frame.
//!
//! A frame whose CRC matched but whose payload this version cannot read (a newer peer's
//! command or reply) is [`FrameError::UnknownMessage`], with the sequence number it names
//! when the payload holds one at the place every version keeps it ([`Sequenced`]): the
//! device answers such a request `NotSupported` (the host then stops retrying at once),
//! and the host can fail the request an unreadable reply belongs to.

use crate::MAX_FRAME_LEN;
use core::fmt;
use postcard::ser_flavors::{Cobs, Slice, crc::CrcModifier};
use serde::{Serialize, de::DeserializeOwned};

/// A wire message whose sequence number sits at a place of its encoding that no protocol
/// version moves, so that a frame of this type that cannot be decoded can still be tied to
/// the request it belongs to.
pub trait Sequenced: DeserializeOwned {
    /// The sequence number of `payload` (a CRC-checked postcard payload that did not decode
    /// as `Self`), when it holds one; `None` when it is too short or names no request.
    fn seq_of_unreadable(payload: &[u8]) -> Option<u32>;
}

/// CRC-32 (ISO-HDLC, as in Ethernet and zlib) over the postcard payload.
pub const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// A frame that could not be read. Transport errors: they never reach the domain types.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// More than [`MAX_FRAME_LEN`] bytes before a delimiter; the bytes up to the next
    /// delimiter were dropped.
    TooLong,
    /// Not valid COBS, or too short to hold a CRC.
    BadFrame,
    /// The CRC did not match.
    BadCrc,
    /// The CRC matched but the payload is no message of this protocol version: an unknown
    /// variant, a field it cannot read, or bytes after the message (the CRC rules out
    /// corruption, so those were sent that way: a peer of another version).
    UnknownMessage {
        /// The sequence number the payload names ([`Sequenced::seq_of_unreadable`]): for
        /// a request, its leading `seq`; for a device message, the `seq` of a reply.
        seq: Option<u32>,
    },
    /// Encoding only: the message does not fit in a frame.
    MessageTooLarge,
}

impl FrameError {
    /// The protocol error code a device reports for this frame error.
    pub const fn code(self) -> crate::ErrorCode {
        match self {
            FrameError::TooLong => crate::ErrorCode::FrameTooLong,
            FrameError::BadFrame | FrameError::MessageTooLarge => crate::ErrorCode::BadFrame,
            FrameError::BadCrc => crate::ErrorCode::BadCrc,
            FrameError::UnknownMessage { .. } => crate::ErrorCode::UnknownMessage,
        }
    }
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FrameError::TooLong => "frame longer than the maximum frame length",
            FrameError::BadFrame => "malformed frame",
            FrameError::BadCrc => "frame CRC mismatch",
            FrameError::UnknownMessage { .. } => "frame holds no known message",
            FrameError::MessageTooLarge => "message too large for one frame",
        })
    }
}

/// Encode `message` as one frame into `buf`, delimiter included; returns the frame.
pub fn encode_frame<'b, T: Serialize + ?Sized>(
    message: &T,
    buf: &'b mut [u8],
) -> Result<&'b mut [u8], FrameError> {
    let limit = buf.len().min(MAX_FRAME_LEN);
    let flavor =
        Cobs::try_new(Slice::new(&mut buf[..limit])).map_err(|_| FrameError::MessageTooLarge)?;
    postcard::serialize_with_flavor(message, CrcModifier::new(flavor, CRC.digest()))
        .map_err(|_| FrameError::MessageTooLarge)
}

/// Decode the COBS-decoded content of one frame (payload and CRC).
fn decode_payload<T: Sequenced>(bytes: &[u8]) -> Result<T, FrameError> {
    let payload_len = bytes.len().checked_sub(4).ok_or(FrameError::BadFrame)?;
    let (payload, crc_bytes) = bytes.split_at(payload_len);
    let mut sent = [0u8; 4];
    sent.copy_from_slice(crc_bytes);
    if CRC.checksum(payload) != u32::from_le_bytes(sent) {
        return Err(FrameError::BadCrc);
    }
    match postcard::take_from_bytes::<T>(payload) {
        Ok((message, [])) => Ok(message),
        // The CRC over the whole payload matched, so a shorter message followed by more
        // bytes was sent that way: a message of another version (a field appended), not
        // this one with junk. Not ours to guess what the rest means.
        Ok((_, _)) | Err(_) => Err(FrameError::UnknownMessage {
            seq: T::seq_of_unreadable(payload),
        }),
    }
}

/// Splits a byte stream into frames and decodes them; never panics, whatever the input.
///
/// Feed it bytes as they arrive ([`FrameDecoder::push`] or [`FrameDecoder::feed`]); it
/// yields one result per delimiter (empty frames, i.e. repeated delimiters, yield
/// nothing). After any error it is back in step at the next delimiter.
pub struct FrameDecoder<const N: usize = MAX_FRAME_LEN> {
    buf: [u8; N],
    len: usize,
    overflowed: bool,
}

impl<const N: usize> Default for FrameDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameDecoder<N> {
    /// An empty decoder.
    pub const fn new() -> Self {
        FrameDecoder {
            buf: [0; N],
            len: 0,
            overflowed: false,
        }
    }

    /// Drop a partly received frame (after a link reset).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflowed = false;
    }

    /// Bytes of a frame received so far (0 between frames).
    pub fn pending(&self) -> usize {
        self.len
    }

    /// Take one byte; returns a decoded message or an error at each frame's end.
    pub fn push<T: Sequenced>(&mut self, byte: u8) -> Option<Result<T, FrameError>> {
        if byte != 0 {
            if self.overflowed {
                return None;
            }
            // N - 1: the delimiter is part of MAX_FRAME_LEN.
            if self.len >= N - 1 {
                self.overflowed = true;
                self.len = 0;
                return None;
            }
            self.buf[self.len] = byte;
            self.len += 1;
            return None;
        }
        let len = core::mem::take(&mut self.len);
        if core::mem::take(&mut self.overflowed) {
            return Some(Err(FrameError::TooLong));
        }
        if len == 0 {
            return None;
        }
        let decoded = match cobs::decode_in_place(&mut self.buf[..len]) {
            Ok(n) => n,
            Err(_) => return Some(Err(FrameError::BadFrame)),
        };
        Some(decode_payload(&self.buf[..decoded]))
    }

    /// Take a chunk of bytes, calling `on_frame` for each frame that ends in it.
    pub fn feed<T: Sequenced>(
        &mut self,
        bytes: &[u8],
        mut on_frame: impl FnMut(Result<T, FrameError>),
    ) {
        for &byte in bytes {
            if let Some(result) = self.push(byte) {
                on_frame(result);
            }
        }
    }
}
