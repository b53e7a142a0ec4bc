//! Frames for the host, waiting for the USB IN endpoint: the TX drop policy.
//!
//! The device never waits on USB (a host that stops reading must not stall the fail-safe
//! logic), so its frames go into a bounded queue of bytes that the USB task empties. The
//! policy: a frame is queued whole or not at all. One that does not fit is dropped whole
//! and counted (the board logs the count, at most once a second: [`DropLog`]); half a frame would turn the next one into
//! garbage as well. What is lost is visible to the host: a reply is asked for again (the
//! request is retried under its sequence number and answered from the device's reply
//! cache), a streamed reading leaves a gap in its indices, a stop shows in the status.
//! On a disconnect the queue is emptied: what it held was for the host that left.

/// A queue of whole frames in `N` bytes.
#[derive(Clone, Debug)]
pub struct FrameQueue<const N: usize> {
    bytes: [u8; N],
    head: usize,
    len: usize,
    dropped: u32,
}

impl<const N: usize> Default for FrameQueue<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// A frame was dropped: it did not fit in what is free.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dropped;

impl<const N: usize> FrameQueue<N> {
    /// Empty.
    pub const fn new() -> Self {
        FrameQueue {
            bytes: [0; N],
            head: 0,
            len: 0,
            dropped: 0,
        }
    }

    /// Queue `frame` whole, or drop it whole (and count it) when it does not fit.
    pub fn push_frame(&mut self, frame: &[u8]) -> Result<(), Dropped> {
        if frame.len() > N - self.len {
            self.dropped = self.dropped.saturating_add(1);
            return Err(Dropped);
        }
        for &byte in frame {
            self.bytes[(self.head + self.len) % N] = byte;
            self.len += 1;
        }
        Ok(())
    }

    /// Move up to `out.len()` queued bytes, in order, into `out`; how many.
    pub fn pop(&mut self, out: &mut [u8]) -> usize {
        let n = out.len().min(self.len);
        for slot in &mut out[..n] {
            *slot = self.bytes[self.head];
            self.head = (self.head + 1) % N;
        }
        self.len -= n;
        n
    }

    /// Bytes queued.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Forget what is queued (the host went away).
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }

    /// Frames dropped since the last call.
    pub fn take_dropped(&mut self) -> u32 {
        core::mem::take(&mut self.dropped)
    }
}

/// How often, at most, dropped frames are logged: once a second.
pub const DROP_LOG_PERIOD_US: u64 = 1_000_000;

/// Dropped frames, counted and logged at most once per [`DROP_LOG_PERIOD_US`].
///
/// A host that stops reading makes the device drop a frame at every status, bin or reply:
/// up to one per 1 ms poll. A log line for each floods the log, and the board's defmt
/// logger blocks with interrupts off while a probe reads it: the log would cost the device
/// the time it has for its deadlines. So the drops are counted, and the count is due when
/// the last log was at least a period ago (the first drop after a quiet second at once).
/// The board asks every poll, so the last count of a run of drops (the host reading
/// again) is logged within a period of it too. A log on every recovery, without the
/// period, could flood all the same: a host that reads in bursts recovers at every burst.
#[derive(Clone, Debug, Default)]
pub struct DropLog {
    pending: u32,
    last_log_us: Option<u64>,
}

impl DropLog {
    /// Nothing dropped, nothing logged.
    pub const fn new() -> Self {
        DropLog {
            pending: 0,
            last_log_us: None,
        }
    }

    /// Count `dropped` more frames ([`FrameQueue::take_dropped`]).
    pub fn count(&mut self, dropped: u32) {
        self.pending = self.pending.saturating_add(dropped);
    }

    /// The frames dropped since the last log, if they are to be logged at `now_us`; they are
    /// then counted as logged.
    pub fn due(&mut self, now_us: u64) -> Option<u32> {
        if self.pending == 0 {
            return None;
        }
        let quiet = self
            .last_log_us
            .is_none_or(|last| now_us.saturating_sub(last) >= DROP_LOG_PERIOD_US);
        if !quiet {
            return None;
        }
        self.last_log_us = Some(now_us);
        Some(core::mem::take(&mut self.pending))
    }
}

/// The USB packets of one IN transfer of `len` bytes on an endpoint of `max_packet` bytes,
/// as ranges of the transfer, in order: full packets, then the short one that ends it,
/// which is a zero-length packet when `len` is a multiple of `max_packet` (without it the
/// host's driver takes the transfer for unfinished and waits for more: the USB 2.0 rule a
/// bulk transfer ends with a short packet, 5.8.3). `max_packet` 0 is taken as 1.
pub fn transfer_packets(
    len: usize,
    max_packet: usize,
) -> impl Iterator<Item = core::ops::Range<usize>> {
    let max_packet = max_packet.max(1);
    // One more packet than the full ones: the short end, empty or not.
    (0..=len / max_packet).map(move |k| k * max_packet..((k + 1) * max_packet).min(len))
}
