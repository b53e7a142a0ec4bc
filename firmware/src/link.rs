//! The device end of the link: frames in, frames out, each sequence number answered once.
//!
//! A host that lost a reply retries with the same sequence number; the link answers it
//! from the cached reply instead of handing the command to the device a second time.

use heapless::Vec;
use protocol::{DeviceError, DeviceMessage, ErrorCode, FrameDecoder, FrameError, MAX_FRAME_LEN, Reply, Request};

/// What arrived on the link.
#[derive(Debug, PartialEq)]
pub enum Incoming {
    /// A request not seen before: carry it out.
    Fresh(Request),
    /// A repeat of the last request, already answered again from the cache.
    Repeat,
    /// A repeat of a request still being carried out: its reply is still to come.
    RepeatInProgress,
    /// A frame that could not be read; already reported to the host.
    Rejected(FrameError),
}

/// Frame decoding, encoding and the reply cache.
pub struct Link {
    decoder: FrameDecoder,
    /// Sequence number and encoded frame of the last reply to a command that acts
    /// (read-only commands are not cached, so heartbeats never push a reply out).
    last_reply: Option<(u32, Vec<u8, MAX_FRAME_LEN>)>,
    /// Sequence number of a request accepted but not answered yet.
    in_progress: Option<u32>,
}

impl Default for Link {
    fn default() -> Self {
        Self::new()
    }
}

impl Link {
    /// A link with nothing received.
    pub const fn new() -> Link {
        Link { decoder: FrameDecoder::new(), last_reply: None, in_progress: None }
    }

    /// Forget partial frames and the reply cache (after a USB reset or reconnect).
    pub fn reset(&mut self) {
        self.decoder.reset();
        self.in_progress = None;
    }

    /// Take one received byte. Returns what arrived when a frame ends; repeats and bad
    /// frames have then already been answered through `send`.
    pub fn push(&mut self, byte: u8, send: &mut impl FnMut(&[u8])) -> Option<Incoming> {
        let incoming = match self.decoder.push::<Request>(byte)? {
            Ok(request) => self.classify(request, send),
            Err(error) => {
                self.send(&DeviceMessage::FrameRejected { code: error.code() }, send);
                Incoming::Rejected(error)
            }
        };
        Some(incoming)
    }

    fn classify(&mut self, request: Request, send: &mut impl FnMut(&[u8])) -> Incoming {
        // Abort must always get through, even as a retry of a lost abort.
        if self.in_progress == Some(request.seq) && request.command != protocol::Command::Abort {
            return Incoming::RepeatInProgress;
        }
        match &self.last_reply {
            Some((seq, frame)) if *seq == request.seq && !request.command.is_read_only() => {
                send(frame);
                Incoming::Repeat
            }
            _ => Incoming::Fresh(request),
        }
    }

    /// Mark `seq` as accepted; its reply follows later through [`Link::reply`].
    pub fn begin(&mut self, seq: u32) {
        self.in_progress = Some(seq);
    }

    /// Answer request `seq`, and remember the answer for a retry.
    pub fn reply(&mut self, seq: u32, result: Result<Reply, DeviceError>, send: &mut impl FnMut(&[u8])) {
        self.answer(seq, result, true, send);
    }

    /// Answer a read-only request (see [`protocol::Command::is_read_only`]) without
    /// caching: a repeat is simply carried out again.
    pub fn reply_uncached(&mut self, seq: u32, result: Result<Reply, DeviceError>, send: &mut impl FnMut(&[u8])) {
        self.answer(seq, result, false, send);
    }

    fn answer(&mut self, seq: u32, result: Result<Reply, DeviceError>, cache: bool, send: &mut impl FnMut(&[u8])) {
        if self.in_progress == Some(seq) {
            self.in_progress = None;
        }
        let mut buf = [0u8; MAX_FRAME_LEN];
        let message = DeviceMessage::Reply { seq, result };
        let frame = match protocol::encode_frame(&message, &mut buf) {
            Ok(frame) => frame,
            // Every reply fits by construction (checked by the protocol tests); should
            // one not, the host must still hear about it.
            Err(_) => {
                let fallback = DeviceMessage::Reply { seq, result: Err(DeviceError::new(ErrorCode::HardwareFault)) };
                match protocol::encode_frame(&fallback, &mut buf) {
                    Ok(frame) => frame,
                    Err(_) => return,
                }
            }
        };
        send(frame);
        if cache {
            self.last_reply = Vec::from_slice(frame).ok().map(|frame| (seq, frame));
        }
    }

    /// Send a message that answers no request (streamed readings, stops).
    pub fn send(&mut self, message: &DeviceMessage, send: &mut impl FnMut(&[u8])) {
        let mut buf = [0u8; MAX_FRAME_LEN];
        if let Ok(frame) = protocol::encode_frame(message, &mut buf) {
            send(frame);
        }
    }
}
