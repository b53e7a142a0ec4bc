//! The device end of the link: frames in, frames out, each sequence number answered once.
//!
//! A host that lost a reply retries with the same sequence number; the link answers it
//! from the cached reply instead of handing the command to the device a second time.
//!
//! The cache belongs to one host session. `Hello` starts a new one: it is never answered
//! from the cache nor taken for a repeat of the request in progress, and
//! [`Link::new_session`] (which the device calls on every `Hello`) empties the cache and
//! forgets the request in progress, so a new host process may start again at sequence 1.
//! A USB reset ([`Link::reset`]) does the same and drops a partial frame. The reply of a
//! command accepted before either is still sent when it is done, but not cached: it must
//! not answer the new host's request that happens to carry the same number.
//!
//! A frame with a good CRC that holds no request of this version but a readable sequence
//! number is answered `Reply { seq, Err(NotSupported) }` ([`protocol::Sequenced`]), so the
//! host stops retrying at once; only a frame without one is answered `FrameRejected`.

use heapless::Vec;
use protocol::{
    Command, DeviceError, DeviceMessage, ErrorCode, FrameDecoder, FrameError, MAX_FRAME_LEN, Reply,
    Request,
};

/// What arrived on the link.
#[derive(Debug, PartialEq)]
pub enum Incoming {
    /// A request not seen before (or a `Hello`): carry it out.
    Fresh(Request),
    /// A repeat of the last request, already answered again from the cache.
    Repeat,
    /// A repeat of a request still being carried out: its reply is still to come.
    RepeatInProgress,
    /// A request this version cannot read, already answered `NotSupported` under its `seq`.
    Unsupported {
        /// The sequence number it carried.
        seq: u32,
    },
    /// A frame that could not be read, nor its sequence number; already reported to the
    /// host with `FrameRejected`.
    Rejected(FrameError),
}

/// Frame decoding, encoding and the reply cache.
pub struct Link {
    decoder: FrameDecoder,
    /// Sequence number and encoded frame of the last reply to a command that acts
    /// (read-only commands and `Hello` are not cached, so heartbeats never push a reply out).
    last_reply: Option<(u32, Vec<u8, MAX_FRAME_LEN>)>,
    /// Sequence number of a request accepted in this session but not answered yet.
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
        Link {
            decoder: FrameDecoder::new(),
            last_reply: None,
            in_progress: None,
        }
    }

    /// After a USB reset or reconnect: drop a partial frame and start a new session.
    pub fn reset(&mut self) {
        self.decoder.reset();
        self.new_session();
    }

    /// A new host session (on `Hello`): forget the reply cache and the request in
    /// progress, whose reply, when it comes, is sent but not cached.
    pub fn new_session(&mut self) {
        self.last_reply = None;
        self.in_progress = None;
    }

    /// Take one received byte. Returns what arrived when a frame ends; repeats, unreadable
    /// requests and bad frames have then already been answered through `send`.
    pub fn push(&mut self, byte: u8, send: &mut impl FnMut(&[u8])) -> Option<Incoming> {
        let incoming = match self.decoder.push::<Request>(byte)? {
            Ok(request) => self.classify(request, send),
            Err(FrameError::UnknownMessage { seq: Some(seq) }) => {
                // Answered, not cached (the same frame again gets the same answer) and
                // without touching the request in progress: it starts and ends nothing.
                self.send(
                    &DeviceMessage::Reply {
                        seq,
                        result: Err(DeviceError::new(ErrorCode::NotSupported)),
                    },
                    send,
                );
                Incoming::Unsupported { seq }
            }
            Err(error) => {
                self.send(&DeviceMessage::FrameRejected { code: error.code() }, send);
                Incoming::Rejected(error)
            }
        };
        Some(incoming)
    }

    fn classify(&mut self, request: Request, send: &mut impl FnMut(&[u8])) -> Incoming {
        // Hello starts a fresh link, whatever its number; Abort must always get through,
        // even as a retry of a lost abort.
        if matches!(request.command, Command::Hello { .. }) {
            return Incoming::Fresh(request);
        }
        if self.in_progress == Some(request.seq) && request.command != Command::Abort {
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

    /// Mark `seq` as accepted; its reply follows later through [`Link::finish`].
    pub fn begin(&mut self, seq: u32) {
        self.in_progress = Some(seq);
    }

    /// Answer the request `seq` just received, and remember the answer for a retry.
    pub fn reply(
        &mut self,
        seq: u32,
        result: Result<Reply, DeviceError>,
        send: &mut impl FnMut(&[u8]),
    ) {
        self.answer(seq, result, true, send);
    }

    /// Answer a request accepted with [`Link::begin`], now done. Cached for a retry only if
    /// it is still this session's request in progress (not one from before a `Hello` or a
    /// reset).
    pub fn finish(
        &mut self,
        seq: u32,
        result: Result<Reply, DeviceError>,
        send: &mut impl FnMut(&[u8]),
    ) {
        let ours = self.in_progress == Some(seq);
        self.answer(seq, result, ours, send);
    }

    /// Answer a request whose repeat may simply be carried out again (read-only commands,
    /// see [`protocol::Command::is_read_only`], and `Hello`) without caching.
    pub fn reply_uncached(
        &mut self,
        seq: u32,
        result: Result<Reply, DeviceError>,
        send: &mut impl FnMut(&[u8]),
    ) {
        self.answer(seq, result, false, send);
    }

    fn answer(
        &mut self,
        seq: u32,
        result: Result<Reply, DeviceError>,
        cache: bool,
        send: &mut impl FnMut(&[u8]),
    ) {
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
                let fallback = DeviceMessage::Reply {
                    seq,
                    result: Err(DeviceError::new(ErrorCode::HardwareFault)),
                };
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
