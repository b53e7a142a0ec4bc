//! Detector samples from a free-running ADC, the logic of it: decimating the DMA's raw
//! circular buffer into 16-bit-effective samples ([`Decimator`]), the bounded ring the
//! device drains ([`SampleRing`]), and the rule that no lost sample goes unreported.
//! The board's TIM5 interrupt feeds the decimator the DMA's write position, the ADC's
//! overrun flag and the detector arm's step count; the tests a model of the DMA
//! (`tests/it/sampling.rs`).
//!
//! The board's ADC converts continuously, paced by the crystal: one conversion every
//! `cycles_per_conversion` CPU cycles (384 at 96 MHz: ADCCLK 24 MHz, 96 ADC clocks per
//! conversion), written by the DMA into [`RAW_LEN`] slots in a circle. Every 1 ms the
//! decimation sums each whole block of [`OVERSAMPLE`] conversions into one sample.
//!
//! THE OVERRUN RULE. Samples are lost, or would be mixed from two laps of the buffer, when:
//! 1. the ADC overran (the DMA missed a conversion; the ADC stops): [`SampleLoss::AdcOverrun`],
//!    the board restarts the conversions and the DMA from slot 0 ([`Decimator::restart`]);
//! 2. the decimation ran so late that the DMA may have come round to data not yet read
//!    (the DMA position alone cannot tell one lap from two, so the time since the last
//!    service decides, from the conversion rate, with a small margin):
//!    [`SampleLoss::DmaLapped`], the decimation goes on from the block being written;
//! 3. the ring was full when a sample came (nobody drained for 262 ms): [`SampleLoss::RingFull`].
//!
//! Each is recorded in the ring and reported by the next drain ([`SampleRing::take_loss`]):
//! a reading with a loss in it fails. An overrun or a lap is the ADC path missing its
//! deadline whether or not a reading runs, so it is also kept for
//! [`SampleRing::take_fault`], which the device asks every poll; a range change empties
//! the ring of samples (they belong to no reading) and of a full ring's loss, never of an
//! overrun or a lap. Either way the device takes its fail-safe stop
//! ([`protocol::ErrorCode::AdcOverrun`], detail [`SampleLoss::detail`]). Between readings
//! nobody drains, so a full ring there is no fault.

/// Conversions summed into one sample.
pub const OVERSAMPLE: usize = 256;
/// Raw DMA buffer: 4 blocks (4.1 ms at 250 k conversions/s); the 1 kHz decimation reads
/// one or two at a time.
pub const RAW_LEN: usize = 4 * OVERSAMPLE;
/// Decoded samples held for the device (262 ms of samples; the device drains every 1 ms).
/// Each with the detector arm's step count at its end: 6 bytes a sample, 1.5 KiB.
pub const RING_LEN: usize = 256;
/// Margin of the lap test, conversions: the clock and the DMA position are read a few
/// cycles apart, and the clock is not read at the instant of a conversion. (The summing
/// cannot be overtaken: it reads a slot every ~6 cycles, the DMA writes one every 384.)
pub const LAP_MARGIN_CONVERSIONS: u32 = 8;

/// Why samples were lost (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SampleLoss {
    /// The ADC overran.
    AdcOverrun,
    /// The DMA may have come round to unread data.
    DmaLapped,
    /// The ring was full.
    RingFull,
}

impl SampleLoss {
    /// The detail of the [`protocol::ErrorCode::AdcOverrun`] it causes: 1, 2, 3.
    pub const fn detail(self) -> i32 {
        match self {
            SampleLoss::AdcOverrun => 1,
            SampleLoss::DmaLapped => 2,
            SampleLoss::RingFull => 3,
        }
    }
}

/// The decoded samples, oldest first, each with the detector arm's step count at its end;
/// the first loss since the last drain; the first loss of the ADC path itself (an overrun
/// or a lap, not a full ring) since it was last taken.
#[derive(Clone, Debug)]
pub struct SampleRing {
    samples: [u16; RING_LEN],
    /// `detector_steps[i]` stamps `samples[i]` (two arrays: 6 bytes a sample, not 8).
    detector_steps: [i32; RING_LEN],
    head: usize,
    len: usize,
    loss: Option<SampleLoss>,
    fault: Option<SampleLoss>,
}

impl Default for SampleRing {
    fn default() -> Self {
        Self::new()
    }
}

impl SampleRing {
    /// Empty.
    pub const fn new() -> SampleRing {
        SampleRing {
            samples: [0; RING_LEN],
            detector_steps: [0; RING_LEN],
            head: 0,
            len: 0,
            loss: None,
            fault: None,
        }
    }

    /// Add a sample and the detector arm's step count at its end; when full, it is
    /// dropped and the loss recorded.
    pub fn push(&mut self, sample: u16, detector_steps: i32) {
        if self.len == RING_LEN {
            self.mark_loss(SampleLoss::RingFull);
            return;
        }
        let slot = (self.head + self.len) % RING_LEN;
        self.samples[slot] = sample;
        self.detector_steps[slot] = detector_steps;
        self.len += 1;
    }

    /// Record a loss (the first one since the last [`SampleRing::take_loss`] is kept; an
    /// overrun or a lap is also kept for [`SampleRing::take_fault`]).
    pub fn mark_loss(&mut self, loss: SampleLoss) {
        self.loss.get_or_insert(loss);
        if loss != SampleLoss::RingFull {
            self.fault.get_or_insert(loss);
        }
    }

    /// Move up to `out.len()` samples, oldest first, into `out`; how many.
    pub fn pop_into(&mut self, out: &mut [crate::hardware::Sample]) -> usize {
        let n = out.len().min(self.len);
        for slot in &mut out[..n] {
            *slot = crate::hardware::Sample {
                counts: u32::from(self.samples[self.head]),
                detector_steps: self.detector_steps[self.head],
            };
            self.head = (self.head + 1) % RING_LEN;
        }
        self.len -= n;
        n
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no sample is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The loss recorded since the last call, if any: what a drain reports.
    pub fn take_loss(&mut self) -> Option<SampleLoss> {
        self.loss.take()
    }

    /// The ADC path's own loss (an overrun or a lap) since the last call, drained or not:
    /// what the device checks every poll.
    pub fn take_fault(&mut self) -> Option<SampleLoss> {
        self.fault.take()
    }

    /// Drop the samples (a range change: they belong to no reading), and a full ring's
    /// loss with them (it was of samples nobody wanted). An overrun or a lap stays.
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
        if self.loss == Some(SampleLoss::RingFull) {
            self.loss = None;
        }
    }
}

/// Where [`Decimator::service`] puts what it finds: the samples and the losses.
///
/// [`SampleRing`] is one. The board's is the ring behind its critical-section lock, taken
/// once per sample and per loss: the decimation itself (256 loads and adds a block, about
/// 3,000 cycles) then runs with interrupts on, and the longest interrupt-off section it
/// costs is one push, not the whole sum.
pub trait SampleSink {
    /// A sample and the detector arm's step count at its block's end.
    fn push(&mut self, sample: u16, detector_steps: i32);
    /// Samples were lost ([`SampleRing::mark_loss`]).
    fn mark_loss(&mut self, loss: SampleLoss);
}

impl SampleSink for SampleRing {
    fn push(&mut self, sample: u16, detector_steps: i32) {
        SampleRing::push(self, sample, detector_steps);
    }

    fn mark_loss(&mut self, loss: SampleLoss) {
        SampleRing::mark_loss(self, loss);
    }
}

/// The decimation's position in the DMA's raw circle. `Copy`: the board keeps it in a
/// cell its interrupt copies out and back, so that no lock is held while it sums.
#[derive(Clone, Copy, Debug)]
pub struct Decimator {
    cycles_per_conversion: u32,
    /// The next raw slot to read: a block boundary.
    read: usize,
    /// The DMA's write slot and the time at the last service.
    last_write: usize,
    last_cycles: u32,
}

impl Decimator {
    /// For an ADC converting every `cycles_per_conversion` cycles of the clock that
    /// [`Decimator::service`] is given, started from slot 0 at `now_cycles`.
    pub const fn new(cycles_per_conversion: u32, now_cycles: u32) -> Decimator {
        Decimator {
            cycles_per_conversion,
            read: 0,
            last_write: 0,
            last_cycles: now_cycles,
        }
    }

    /// The conversions and the DMA were restarted from slot 0 at `now_cycles`.
    pub fn restart(&mut self, now_cycles: u32) {
        self.read = 0;
        self.last_write = 0;
        self.last_cycles = now_cycles;
    }

    /// One service (the decimation interrupt, once per block): `write` is the DMA's next
    /// slot (`RAW_LEN - NDTR`), `adc_overrun` the ADC's overrun flag, `now_cycles` the
    /// clock, `raw(i)` the conversion in slot `i`, `detector_steps` the detector arm's step
    /// count now. Every whole block found becomes a sample in `ring` (any
    /// [`SampleSink`]: each sample is summed before it is handed over), stamped with
    /// `detector_steps` (the board runs this interrupt just after each block ends, so the
    /// stamp is the count at the block's end; should a late service find two blocks, both
    /// get the later count); a loss is recorded there. Returns whether the board must
    /// restart the conversions and the DMA (after an ADC overrun; then call
    /// [`Decimator::restart`]).
    #[must_use]
    pub fn service(
        &mut self,
        write: usize,
        adc_overrun: bool,
        now_cycles: u32,
        raw: impl Fn(usize) -> u16,
        detector_steps: i32,
        ring: &mut impl SampleSink,
    ) -> bool {
        if adc_overrun {
            ring.mark_loss(SampleLoss::AdcOverrun);
            return true;
        }
        let write = write % RAW_LEN;
        let elapsed = now_cycles.wrapping_sub(self.last_cycles) / self.cycles_per_conversion.max(1);
        // What was unread at the last service: the DMA overwrites it after this many more.
        let unread = (self.last_write + RAW_LEN - self.read) % RAW_LEN;
        let room = (RAW_LEN - unread) as u32;
        // +1: a conversion may be under way at either end of the interval.
        if elapsed.saturating_add(1 + LAP_MARGIN_CONVERSIONS) >= room {
            ring.mark_loss(SampleLoss::DmaLapped);
            // Go on from the block the DMA is writing: its slots before `write` were just
            // written and the rest come next, so it will be one run of conversions.
            self.read = write / OVERSAMPLE * OVERSAMPLE;
        } else {
            while (write + RAW_LEN - self.read) % RAW_LEN >= OVERSAMPLE {
                let sum: u32 = (self.read..self.read + OVERSAMPLE)
                    .map(|i| u32::from(raw(i) & 0x0fff))
                    .sum();
                // 256 × 4095 = 1,048,320 → 65,520: fits u16.
                ring.push((sum >> 4) as u16, detector_steps);
                self.read = (self.read + OVERSAMPLE) % RAW_LEN;
            }
        }
        self.last_write = write;
        self.last_cycles = now_cycles;
        false
    }
}
