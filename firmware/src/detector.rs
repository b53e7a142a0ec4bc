//! Detector readings: statistics of the ADC samples over an integration time, and the
//! auto-ranging policy that picks the transimpedance range.
//!
//! Auto-ranging: a reading whose largest sample reaches the saturation threshold is
//! re-taken one range less sensitive; one that would still read well below full scale a
//! range more sensitive is re-taken there (never on a range that already saturated for
//! this reading, so it cannot oscillate). A reading that saturates on the least sensitive
//! range is returned flagged `saturated`: its mean is a lower bound, never a value.
//!
//! A forced range (for the host's gain calibration) is one integration on that range,
//! never re-taken on another, flagged `saturated` if it saturates there.

use crate::config::InstrumentConfig;
use crate::hardware::Detector;
use crate::sampling::SampleLoss;
use libm::sqrtf;
use protocol::Reading;

/// Running mean and variance of samples (Welford: one pass, no sum of squares to
/// overflow or cancel), and the largest sample for the saturation test.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SampleStats {
    count: u32,
    mean: f32,
    sum_sq_dev: f32,
    max: u32,
}

impl SampleStats {
    /// No samples.
    pub const fn new() -> SampleStats {
        SampleStats {
            count: 0,
            mean: 0.0,
            sum_sq_dev: 0.0,
            max: 0,
        }
    }

    /// Add one sample.
    pub fn add(&mut self, sample: u32) {
        self.count += 1;
        let x = sample as f32;
        let delta = x - self.mean;
        self.mean += delta / self.count as f32;
        self.sum_sq_dev += delta * (x - self.mean);
        self.max = self.max.max(sample);
    }

    /// Number of samples.
    pub fn count(&self) -> u32 {
        self.count
    }

    /// Mean, counts.
    pub fn mean(&self) -> f32 {
        self.mean
    }

    /// Sample standard deviation (n − 1), counts; 0 below two samples.
    pub fn std_dev(&self) -> f32 {
        if self.count < 2 {
            0.0
        } else {
            sqrtf(self.sum_sq_dev.max(0.0) / (self.count - 1) as f32)
        }
    }

    /// Largest sample.
    pub fn max(&self) -> u32 {
        self.max
    }
}

/// What to do with the statistics of one integration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RangeDecision {
    /// Keep it (flagged saturated if it saturated on the least sensitive range).
    Accept {
        /// Saturated: the mean is a lower bound.
        saturated: bool,
    },
    /// Take it again on this range.
    Retake(u8),
}

/// Whether samples with this largest value saturate `range`.
pub fn is_saturated(config: &InstrumentConfig, range: u8, max_sample: u32) -> bool {
    let full_scale = config.detector_ranges[usize::from(range)].full_scale_counts as f32;
    max_sample as f32 >= config.saturation_fraction * full_scale
}

/// The auto-ranging policy. `saturated_ranges` has bit r set for every range that
/// saturated earlier in the same reading.
pub fn decide_range(
    config: &InstrumentConfig,
    range: u8,
    stats: &SampleStats,
    saturated_ranges: u8,
) -> RangeDecision {
    let ranges = config.detector_ranges;
    let index = usize::from(range);
    if is_saturated(config, range, stats.max()) {
        return if index + 1 < ranges.len() {
            RangeDecision::Retake(range + 1)
        } else {
            RangeDecision::Accept { saturated: true }
        };
    }
    if index > 0 && saturated_ranges & (1 << (index - 1)) == 0 {
        let more = &ranges[index - 1];
        let predicted = stats.mean() * (more.relative_gain / ranges[index].relative_gain);
        if predicted < config.more_sensitive_below_fraction * more.full_scale_counts as f32 {
            return RangeDecision::Retake(range - 1);
        }
    }
    RangeDecision::Accept { saturated: false }
}

/// One integration on one range: samples during the amplifier's settling are discarded,
/// then collected for the integration time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Integration {
    range: u8,
    integration_ms: u16,
    collect_from_us: u64,
    end_us: u64,
    stats: SampleStats,
    /// Samples were lost during this integration (or just before it started).
    loss: Option<SampleLoss>,
}

impl Integration {
    /// Select `range` and start integrating at `now_us`.
    pub fn start(
        detector: &mut impl Detector,
        config: &InstrumentConfig,
        range: u8,
        integration_ms: u16,
        now_us: u64,
    ) -> Integration {
        detector.select_range(range);
        // Samples from before the range change belong to no reading; a loss among them
        // is still a loss (the device drains every poll, so it is a recent one).
        let loss = detector.drain_samples(&mut |_| {}).err();
        let collect_from_us = now_us + u64::from(config.range_settle_ms) * 1000;
        Integration {
            range,
            integration_ms,
            collect_from_us,
            end_us: collect_from_us + u64::from(integration_ms) * 1000,
            stats: SampleStats::new(),
            loss,
        }
    }

    /// The range integrated on.
    pub fn range(&self) -> u8 {
        self.range
    }

    /// Collect samples; the statistics once the integration time is over, or the loss
    /// as soon as samples were lost (a reading with a gap is no reading). Samples are
    /// timed by when they are drained, so the board polls often (every ms or so).
    pub fn poll(
        &mut self,
        detector: &mut impl Detector,
        now_us: u64,
    ) -> Result<Option<SampleStats>, SampleLoss> {
        let collecting = now_us > self.collect_from_us;
        let stats = &mut self.stats;
        let drained = detector.drain_samples(&mut |sample| {
            if collecting {
                stats.add(sample.counts);
            }
        });
        if let Some(loss) = self.loss.take().or(drained.err()) {
            return Err(loss);
        }
        Ok((now_us >= self.end_us).then_some(self.stats))
    }

    /// The reading these statistics make on this integration's range.
    pub fn reading(&self, stats: &SampleStats, saturated: bool) -> Reading {
        Reading {
            mean_counts: stats.mean(),
            std_counts: stats.std_dev(),
            samples: stats.count(),
            range: self.range,
            integration_ms: self.integration_ms,
            saturated,
        }
    }
}

/// What a reading is doing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ReadingProgress {
    /// Still integrating.
    Running,
    /// Done.
    Done(Reading),
    /// The detector gave no samples: a hardware fault.
    NoSamples,
    /// Samples were lost during the reading ([`crate::sampling`]).
    SamplesLost(SampleLoss),
}

/// One reading: auto-ranged (integrations until the policy accepts one) or on a forced
/// range (one integration).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RangedReading {
    integration: Integration,
    saturated_ranges: u8,
    /// One integration on this range, whatever it reads.
    forced: bool,
}

impl RangedReading {
    /// An auto-ranged reading, started on `first_range` (the range of the previous
    /// reading is a good guess).
    pub fn auto(
        detector: &mut impl Detector,
        config: &InstrumentConfig,
        first_range: u8,
        integration_ms: u16,
        now_us: u64,
    ) -> RangedReading {
        let range = first_range.min(config.detector_ranges.len().saturating_sub(1) as u8);
        RangedReading {
            integration: Integration::start(detector, config, range, integration_ms, now_us),
            saturated_ranges: 0,
            forced: false,
        }
    }

    /// One integration on `range` (an index into the configured ranges, checked by the
    /// caller), after the range's settle time.
    pub fn forced(
        detector: &mut impl Detector,
        config: &InstrumentConfig,
        range: u8,
        integration_ms: u16,
        now_us: u64,
    ) -> RangedReading {
        RangedReading {
            integration: Integration::start(detector, config, range, integration_ms, now_us),
            saturated_ranges: 0,
            forced: true,
        }
    }

    /// Whether the range was forced.
    pub fn is_forced(&self) -> bool {
        self.forced
    }

    /// Advance; an auto-ranged reading re-integrates on another range when the policy says so.
    pub fn poll(
        &mut self,
        detector: &mut impl Detector,
        config: &InstrumentConfig,
        now_us: u64,
    ) -> ReadingProgress {
        let stats = match self.integration.poll(detector, now_us) {
            Ok(Some(stats)) => stats,
            Ok(None) => return ReadingProgress::Running,
            Err(loss) => return ReadingProgress::SamplesLost(loss),
        };
        if stats.count() == 0 {
            return ReadingProgress::NoSamples;
        }
        let range = self.integration.range();
        if self.forced {
            let saturated = is_saturated(config, range, stats.max());
            return ReadingProgress::Done(self.integration.reading(&stats, saturated));
        }
        match decide_range(config, range, &stats, self.saturated_ranges) {
            RangeDecision::Accept { saturated } => {
                ReadingProgress::Done(self.integration.reading(&stats, saturated))
            }
            RangeDecision::Retake(next) => {
                if is_saturated(config, range, stats.max()) {
                    self.saturated_ranges |= 1 << range;
                }
                self.integration = Integration::start(
                    detector,
                    config,
                    next,
                    self.integration.integration_ms,
                    now_us,
                );
                ReadingProgress::Running
            }
        }
    }
}

/// Switch one-hot range lines (one line per feedback resistor, high = connected) to line
/// `to`, make before break: `set(to, true)` first, then `overlap()`, then `set(line, false)`
/// for every other line. `false`, and no call at all, when `to` is not one of the `lines`.
///
/// Why: while no feedback resistor is connected the transimpedance amplifier has no
/// feedback and its output slews to a rail, from which it needs far longer than the range's
/// settling time to recover (and the next readings would carry it). With two connected for
/// a moment, the gain is only the lower of the two, which the library's blanking after a
/// switch discards anyway. `overlap` is the wait between the two: an analog switch's
/// turn-on is slower than its turn-off, so two GPIO writes a few nanoseconds apart would
/// still break first.
pub fn switch_range_lines(
    lines: usize,
    to: usize,
    mut set: impl FnMut(usize, bool),
    overlap: impl FnOnce(),
) -> bool {
    if to >= lines {
        return false;
    }
    set(to, true);
    overlap();
    for line in (0..lines).filter(|&line| line != to) {
        set(line, false);
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every switch between three lines, from any starting state with a line connected:
    /// some line is connected at every moment, only the target at the end, and the wait
    /// comes between the make and the first break.
    #[test]
    fn range_switch_is_make_before_break() {
        const LINES: usize = 3;
        for start in 1u8..(1 << LINES) {
            for to in 0..LINES {
                let mut state = start;
                let events = core::cell::RefCell::new(Vec::new());
                let switched = switch_range_lines(
                    LINES,
                    to,
                    |line, on| {
                        if on {
                            state |= 1 << line;
                        } else {
                            state &= !(1 << line);
                        }
                        assert_ne!(state, 0, "no resistor connected: {start:03b} -> {to}");
                        events.borrow_mut().push(Some((line, on)));
                    },
                    || events.borrow_mut().push(None),
                );
                assert!(switched);
                assert_eq!(state, 1 << to, "{start:03b} -> {to}");
                let events = events.into_inner();
                assert_eq!(events[0], Some((to, true)));
                assert_eq!(events[1], None);
                assert!(events[2..].iter().all(|e| matches!(e, Some((_, false)))));
            }
        }
    }

    /// A range that is not a line changes nothing (the old one-hot loop switched all off).
    #[test]
    fn range_switch_refuses_a_missing_line() {
        let calls = core::cell::Cell::new(0);
        let count = || calls.set(calls.get() + 1);
        assert!(!switch_range_lines(3, 3, |_, _| count(), count));
        assert_eq!(calls.get(), 0);
    }

    fn stats(samples: &[u32]) -> SampleStats {
        let mut s = SampleStats::new();
        samples.iter().for_each(|&x| s.add(x));
        s
    }

    #[test]
    fn welford_matches_two_pass() {
        let s = stats(&[10, 12, 14, 16]);
        assert_eq!(s.count(), 4);
        assert!((s.mean() - 13.0).abs() < 1e-6);
        // Sample variance of 10,12,14,16 is 20/3.
        assert!((s.std_dev() - (20.0f32 / 3.0).sqrt()).abs() < 1e-5);
        assert_eq!(s.max(), 16);
    }

    #[test]
    fn ranging_policy() {
        let config = InstrumentConfig::REFERENCE;
        // Saturated on range 0: go less sensitive.
        assert_eq!(
            decide_range(&config, 0, &stats(&[65_535; 4]), 0),
            RangeDecision::Retake(1)
        );
        // Saturated on the least sensitive range: flagged, kept.
        assert_eq!(
            decide_range(&config, 2, &stats(&[65_535; 4]), 0b011),
            RangeDecision::Accept { saturated: true }
        );
        // Low on range 1: more sensitive would read 10× more, still below 80 %.
        assert_eq!(
            decide_range(&config, 1, &stats(&[3000; 4]), 0),
            RangeDecision::Retake(0)
        );
        // ... unless range 0 already saturated for this reading.
        assert_eq!(
            decide_range(&config, 1, &stats(&[3000; 4]), 0b001),
            RangeDecision::Accept { saturated: false }
        );
        // Mid-scale: kept.
        assert_eq!(
            decide_range(&config, 1, &stats(&[30_000; 4]), 0),
            RangeDecision::Accept { saturated: false }
        );
    }
}
