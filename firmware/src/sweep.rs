//! Sweeps: the detector arm moving at a constant speed between its ramps while the
//! detector's blocks are binned by the step count ([`protocol::Sweep`]).
//!
//! WHAT A SWEEP IS. Both arms go to (θi, `from`) and settle there (also when already there:
//! the auto-ranging finds the range at rest, [`AutoRange`]); then one profile of the
//! detector arm from `from` to `to` ([`sweep_profile`]: from rest to rest, the top speed the
//! sweep's, the acceleration the instrument's). The ramps are KEPT, with their true
//! intervals: dropping them would cost a run-up and a run-down of v²/2a (10° at 60 °/s)
//! each, a third of a 70° sweep, and a bin's interval comes from the step counts whatever
//! the speed (a constant-speed model of a bin errs by ≈ w²/24d at a distance d from where
//! the arm was at rest: ≤ 0.0004° for 0.1° bins beyond the first degree, under a tick).
//!
//! BINS ARE WHOLE BLOCKS ([`Binner`]). Every detector sample is one block of
//! [`InstrumentConfig::detector_block_us`], stamped by the board with the detector arm's
//! step count at its end ([`crate::hardware::Sample`]); a block's start is the previous
//! block's end. Bin `k` closes with the first block whose end reaches its nominal end
//! `from + (k + 1)·bin_ticks` towards `to` (the last bin's is `to`), so the bins tile the
//! sweep exactly: the first starts at `from`, each starts where the one before ended, the
//! last ends at `to` (where the profile ends, on its step), and there are
//! ⌈|to − from| / bin_ticks⌉. A bin is never shorter than one block: the shortest accepted
//! is the travel of one block at the top speed plus a tick ([`min_bin_ticks`]), so one
//! block's end reaches at most one nominal end and at most one bin is sent per block. (Were
//! a block to cross two, the second bin would close with the next block: still tiled,
//! still in order.)
//!
//! AUTO-RANGING WHILE MOVING ([`AutoRange`]): on thresholds per block (out of a range at
//! [`InstrumentConfig::sweep_less_sensitive_above_fraction`] of full scale, into the more
//! sensitive one below [`InstrumentConfig::sweep_more_sensitive_below_fraction`] of its
//! full scale as predicted by the gain ratio). After a switch the blocks are dropped
//! ("blanked") for the NEW range's settling time ([`protocol::DetectorRange::settle_us`]):
//! the block the switch fell in (it straddles both ranges, and on the board the switch
//! comes up to a poll after the block that asked for it ended) and ⌈settle / block⌉ more,
//! so the first block kept after a switch begins at least the settling time after it.
//! Blanked blocks decide nothing (a transient is no level). A bin never mixes ranges: it
//! keeps the range of its first kept block, and a block on another range is dropped (the
//! bin is flagged [`SweepBin::BLANKED`] whenever a block of it was dropped). A block that
//! saturates a more sensitive range is clipped, so it is dropped and the range switched; one
//! that saturates the least sensitive range (or the forced one) is kept and its bin flagged
//! [`SweepBin::SATURATED`]: the mean is a lower bound, never a clipped value passed off as
//! one. A bin with no block kept is [`SweepBin::EMPTY`].
//!
//! REFUSED BEFORE ANY MOTION ([`check_sweep`], the order in [`protocol::Sweep`]'s doc):
//! the arms' range, the collision guard over the path (θr runs along a segment with θi
//! fixed, so θi + θr is least at an end, and the move to the start is a straight line in
//! (θi, θr) that the guard's half-plane holds when both ends do), the speed, the bin length
//! against one block at that speed and against the sweep, the bin count. The device adds
//! Busy, a driver fault and NotHomed before these.
//!
//! THE LINK: at most one [`SweepBin`] per block, a frame of ≤ 31 bytes in a session (46 at
//! worst), so ≤ 31 kB/s against USB full speed's 1.2 MB/s of bulk payload; the board's
//! 1 KiB TX queue holds 33 bins (the figures and their test: [`protocol::SweepBin`]). A
//! bin that does not fit is dropped whole, a gap in the indices that the host measures again.

use crate::config::InstrumentConfig;
use crate::detector::SampleStats;
use crate::hardware::Sample;
use crate::motion::{MoveProfile, STEPS_PER_DEG, angle_to_steps, deg_to_steps};
use protocol::{DeviceError, ErrorCode, MAX_SWEEP_BINS, Sweep, SweepBin};

/// The detector arm's profile of a sweep from `from` to `to` (steps) at a top speed of
/// `speed_mdeg_per_s`: from rest to rest at the instrument's acceleration (triangular when
/// too short to reach the speed). The host times sweeps with this same function.
pub fn sweep_profile(
    config: &InstrumentConfig,
    from: i32,
    to: i32,
    speed_mdeg_per_s: u32,
) -> MoveProfile {
    let top = speed_mdeg_per_s as f32 * (STEPS_PER_DEG / 1000.0);
    MoveProfile::fastest(from, to, 0.0, top, deg_to_steps(config.accel_deg_per_s2))
}

/// The shortest bin accepted at a top speed of `speed_mdeg_per_s`, ticks: the travel of
/// one detector block at that speed, rounded up, and one tick more (two step counts one
/// block apart differ by up to one more than the travel: the count's quantisation, and on
/// the board the stamp's few µs of jitter).
pub fn min_bin_ticks(config: &InstrumentConfig, speed_mdeg_per_s: u32) -> u32 {
    // mdeg/s × ticks/deg × µs → ticks × 10⁹.
    let per_block =
        u64::from(speed_mdeg_per_s) * STEPS_PER_DEG as u64 * u64::from(config.detector_block_us);
    (per_block.div_ceil(1_000_000_000) + 1) as u32
}

/// The fastest top speed accepted, mdeg/s.
pub fn max_speed_mdeg_per_s(config: &InstrumentConfig) -> u32 {
    (config.max_speed_deg_per_s * 1000.0) as u32
}

/// Check a sweep against the instrument (everything but the device's state: busy, drivers,
/// homing); its number of bins, or the refusal (see [`protocol::Sweep`] for the order and
/// the details). Nothing moves before this passes.
pub fn check_sweep(config: &InstrumentConfig, sweep: &Sweep) -> Result<u16, DeviceError> {
    let invalid = |detail: i64| {
        Err(DeviceError::with_detail(
            ErrorCode::InvalidArgument,
            detail as i32,
        ))
    };
    if sweep.sweep_id == 0 {
        return invalid(0);
    }
    let ranges = config.detector_ranges.len().min(protocol::MAX_RANGES);
    if sweep.range.is_some_and(|r| usize::from(r) >= ranges) {
        return invalid(ranges as i64);
    }
    for (arm, angle) in [sweep.theta_i, sweep.from, sweep.to]
        .into_iter()
        .enumerate()
    {
        if angle < config.arm_min || angle > config.arm_max {
            return Err(DeviceError::with_detail(
                ErrorCode::OutOfRange,
                arm.min(1) as i32,
            ));
        }
    }
    let lowest_r = sweep.from.min(sweep.to);
    if sweep.theta_i.ticks() + lowest_r.ticks() < config.collision_min_sum.ticks() {
        return Err(DeviceError::new(ErrorCode::CollisionGuard));
    }
    let (slowest, fastest) = (
        config.sweep_min_speed_mdeg_per_s,
        max_speed_mdeg_per_s(config),
    );
    if sweep.speed_mdeg_per_s < slowest {
        return invalid(i64::from(slowest));
    }
    if sweep.speed_mdeg_per_s > fastest {
        return invalid(i64::from(fastest));
    }
    let shortest = min_bin_ticks(config, sweep.speed_mdeg_per_s);
    if u32::from(sweep.bin_ticks) < shortest {
        return invalid(i64::from(shortest));
    }
    let travel = (sweep.to.ticks() - sweep.from.ticks()).unsigned_abs();
    if u32::from(sweep.bin_ticks) > travel {
        return invalid(i64::from(travel));
    }
    let bins = travel.div_ceil(u32::from(sweep.bin_ticks));
    if bins > u32::from(MAX_SWEEP_BINS) {
        return invalid(i64::from(MAX_SWEEP_BINS));
    }
    Ok(bins as u16)
}

/// What [`AutoRange`] makes of one block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlockClass {
    /// Dropped: within the settling after a switch, or clipped on a more sensitive range.
    Dropped,
    /// Usable, on this range; `saturated` on the least sensitive (or the forced) range.
    Kept {
        /// The range it was taken on.
        range: u8,
        /// It saturated where no less sensitive range is left: its value is a lower bound.
        saturated: bool,
    },
}

/// The range while a sweep runs: thresholds on each block, blanking after a switch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AutoRange {
    range: u8,
    forced: bool,
    /// Blocks still to drop after the last switch.
    blanking: u32,
    /// A usable block has been seen on this range since the last switch (and asked for
    /// none): the range is found.
    found: bool,
    /// The range to select, once the caller can (a switch decided while draining).
    pending: Option<u8>,
}

impl AutoRange {
    /// Start on `range` (auto-ranged unless `forced`); the caller selects it at once
    /// ([`AutoRange::take_switch`]), so its settling is blanked too.
    pub fn new(config: &InstrumentConfig, range: u8, forced: bool) -> AutoRange {
        let last = config.detector_ranges.len().saturating_sub(1) as u8;
        let mut ranging = AutoRange {
            range: 0,
            forced,
            blanking: 0,
            found: false,
            pending: None,
        };
        ranging.switch(config, range.min(last));
        ranging
    }

    /// The range blocks are being taken on now.
    pub fn range(&self) -> u8 {
        self.range
    }

    /// Whether the range is found: not blanking, and a block since the last switch was
    /// kept without asking for another.
    pub fn is_found(&self) -> bool {
        self.found && self.blanking == 0 && self.pending.is_none()
    }

    /// A switch decided since the last call: select this range now.
    pub fn take_switch(&mut self) -> Option<u8> {
        self.pending.take()
    }

    fn switch(&mut self, config: &InstrumentConfig, range: u8) {
        let settle_us = config.detector_ranges[usize::from(range)].settle_us;
        self.range = range;
        self.pending = Some(range);
        self.found = false;
        // The block the switch falls in, and the settling after it in whole blocks.
        self.blanking = 1 + settle_us.div_ceil(config.detector_block_us.max(1));
    }

    /// Classify one block (taken on [`AutoRange::range`] unless blanked) and decide the
    /// range of the next ones.
    pub fn block(&mut self, config: &InstrumentConfig, counts: u32) -> BlockClass {
        if self.blanking > 0 {
            self.blanking -= 1;
            return BlockClass::Dropped;
        }
        let ranges = config.detector_ranges;
        let index = usize::from(self.range);
        let here = ranges[index];
        let full_scale = here.full_scale_counts as f32;
        let value = counts as f32;
        let saturated = value >= config.saturation_fraction * full_scale;
        let less_sensitive = (index + 1 < ranges.len()).then_some(self.range + 1);
        if self.forced {
            self.found = true;
            return BlockClass::Kept {
                range: self.range,
                saturated,
            };
        }
        if saturated {
            return match less_sensitive {
                // Clipped: no value. The next range has room.
                Some(next) => {
                    self.switch(config, next);
                    BlockClass::Dropped
                }
                None => {
                    self.found = true;
                    BlockClass::Kept {
                        range: self.range,
                        saturated: true,
                    }
                }
            };
        }
        let kept = BlockClass::Kept {
            range: self.range,
            saturated: false,
        };
        if let Some(next) = less_sensitive
            .filter(|_| value >= config.sweep_less_sensitive_above_fraction * full_scale)
        {
            self.switch(config, next);
            return kept;
        }
        if index > 0 {
            let more = ranges[index - 1];
            let predicted = value * (more.relative_gain / here.relative_gain);
            if predicted
                < config.sweep_more_sensitive_below_fraction * more.full_scale_counts as f32
            {
                self.switch(config, self.range - 1);
                return kept;
            }
        }
        self.found = true;
        kept
    }
}

/// The bins of a running sweep, from its blocks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Binner {
    sweep_id: u16,
    from: i32,
    to: i32,
    direction: i32,
    bin_ticks: i32,
    bins: u16,
    /// The bin being filled (`bins` once done).
    index: u16,
    /// Where it starts, steps.
    start: i32,
    /// Where the last block ended, steps.
    last_end: i32,
    stats: SampleStats,
    range: Option<u8>,
    flags: u8,
}

impl Binner {
    /// The bins of `sweep` (checked by [`check_sweep`], `bins` its count), the detector arm
    /// at rest on `from`.
    pub fn new(sweep: &Sweep, bins: u16) -> Binner {
        let (from, to) = (angle_to_steps(sweep.from), angle_to_steps(sweep.to));
        Binner {
            sweep_id: sweep.sweep_id,
            from,
            to,
            direction: (to - from).signum(),
            bin_ticks: i32::from(sweep.bin_ticks),
            bins,
            index: 0,
            start: from,
            last_end: from,
            stats: SampleStats::new(),
            range: None,
            flags: 0,
        }
    }

    /// Bins closed so far.
    pub fn bins_sent(&self) -> u16 {
        self.index
    }

    /// Whether every bin is closed.
    pub fn is_done(&self) -> bool {
        self.index >= self.bins
    }

    /// Where bin `index` nominally ends, steps.
    fn nominal_end(&self, index: u16) -> i32 {
        if index + 1 >= self.bins {
            self.to
        } else {
            self.from + self.direction * (i32::from(index) + 1) * self.bin_ticks
        }
    }

    /// One block: its sample, what [`AutoRange`] made of it, the range in effect (an empty
    /// bin's), the device time now. The bin it closes, if it closes one.
    pub fn block(
        &mut self,
        sample: Sample,
        class: BlockClass,
        range_now: u8,
        now_us: u64,
    ) -> Option<SweepBin> {
        if self.is_done() {
            return None;
        }
        let end = sample.detector_steps;
        self.last_end = end;
        match class {
            BlockClass::Kept { range, saturated } if self.range.is_none_or(|r| r == range) => {
                self.range = Some(range);
                self.stats.add(sample.counts);
                if saturated {
                    self.flags |= SweepBin::SATURATED;
                }
            }
            BlockClass::Kept { .. } | BlockClass::Dropped => self.flags |= SweepBin::BLANKED,
        }
        if self.direction * (end - self.nominal_end(self.index)) < 0 {
            return None;
        }
        let kept = self.stats.count();
        let bin = SweepBin {
            sweep_id: self.sweep_id,
            index: self.index,
            start: protocol::Angle::from_ticks(self.start),
            end: protocol::Angle::from_ticks(end),
            mean_counts: self.stats.mean(),
            std_counts: self.stats.std_dev(),
            blocks: kept.min(u32::from(u16::MAX)) as u16,
            range: self.range.unwrap_or(range_now),
            flags: self.flags | if kept == 0 { SweepBin::EMPTY } else { 0 },
            device_time_us: now_us,
        };
        self.index += 1;
        self.start = end;
        self.stats = SampleStats::new();
        self.range = None;
        self.flags = 0;
        Some(bin)
    }

    /// Where the last block ended, steps.
    pub fn last_end(&self) -> i32 {
        self.last_end
    }
}
