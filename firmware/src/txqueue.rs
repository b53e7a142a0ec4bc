//! Frames for the host, waiting for the USB IN endpoint: the TX drop policy.
//!
//! The device never waits on USB (a host that stops reading must not stall the fail-safe
//! logic), so its frames go into a bounded queue of bytes that the USB task empties. The
//! policy: a frame is queued whole or not at all. One that does not fit is dropped whole
//! and counted (the board logs the count); half a frame would turn the next one into
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
