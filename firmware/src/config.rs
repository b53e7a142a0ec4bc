//! Limits of the reference instrument. Each value is where it is
//! defined; change one only with a reason written beside it.

use protocol::{Angle, DetectorRange, DeviceInfo, PROTOCOL_VERSION, ResetCause};

/// Limits and timing of the instrument a firmware build drives.
#[derive(Clone, Debug, PartialEq)]
pub struct InstrumentConfig {
    /// Board name for the handshake.
    pub board: &'static str,
    /// Working range of both arms.
    pub arm_min: Angle,
    /// Working range of both arms.
    pub arm_max: Angle,
    /// Every target keeps θi + θr at or above this (the arms touch near the normal).
    pub collision_min_sum: Angle,
    /// Arm speed limit, °/s.
    pub max_speed_deg_per_s: f32,
    /// Arm acceleration limit, °/s².
    pub accel_deg_per_s2: f32,
    /// Settling time after a move.
    pub settle_ms: u16,
    /// Detector ranges, most sensitive first, each with its amplifier's time constant and
    /// settling time (the reasons are at [`REFERENCE_RANGES`]).
    pub detector_ranges: &'static [DetectorRange],
    /// The detector's block period, µs: one ADC sample (a block of oversampled
    /// conversions) per period. The fake hardware and the simulator sample at this rate;
    /// the board announces its own (its ADC's clock makes 1,024 µs, `firmware/board`).
    pub detector_block_us: u32,
    /// Detector acceptance, full width, degrees.
    pub acceptance_deg: f32,
    /// Longest schedule held.
    pub max_schedule_len: u16,
    /// Default integration time.
    pub default_integration_ms: u16,
    /// Longest integration time accepted.
    pub max_integration_ms: u16,
    /// Shortest integration time accepted.
    pub min_integration_ms: u16,
    /// The host must be heard this often while the arms move or the lamp is on.
    pub heartbeat_timeout_ms: u32,
    /// Where both home switches trip, beyond the working range so that homing moves the
    /// arms away from the normal, where they could touch each other.
    pub home_switch: Angle,
    /// Homing: longest travel searching for the switch (from anywhere in the range).
    pub home_search_range: Angle,
    /// Homing: travel back off the switch; it must release within it after the search.
    pub home_backoff: Angle,
    /// Homing: most travel backing off a switch found pressed (in steps of `home_backoff`)
    /// before it counts as stuck: an arm may stand further past it than one back-off.
    pub home_release_max: Angle,
    /// Homing: speed of the search and the back-off, °/s.
    pub home_fast_deg_per_s: f32,
    /// Homing: speed of the re-approach that locates the switch, °/s.
    pub home_slow_deg_per_s: f32,
    /// Quick re-home: the fast move (at full speed) stops this far short of where the
    /// step count puts the switch.
    pub home_quick_margin: Angle,
    /// Quick re-home: the slow approach from there goes at most this far before falling
    /// back to the full search (the margin plus as much again for steps lost).
    pub home_quick_approach: Angle,
    /// Samples after a range change that are discarded while the amplifier settles.
    pub range_settle_ms: u16,
    /// A reading whose largest sample reaches this fraction of full scale is saturated.
    pub saturation_fraction: f32,
    /// Auto-ranging goes one range more sensitive when the mean, scaled by the gain
    /// ratio, would stay below this fraction of full scale there.
    pub more_sensitive_below_fraction: f32,
    /// Sweeps: a block at or above this fraction of full scale switches to the next less
    /// sensitive range (the block itself is kept unless it saturated).
    pub sweep_less_sensitive_above_fraction: f32,
    /// Sweeps: a block that, scaled by the gain ratio, would read below this fraction of
    /// full scale on the next more sensitive range switches there.
    pub sweep_more_sensitive_below_fraction: f32,
    /// Sweeps: the lowest top speed accepted, mdeg/s.
    pub sweep_min_speed_mdeg_per_s: u32,
}

/// 16-bit-effective ADC path: full scale in counts.
const FULL_SCALE_COUNTS: u32 = 65_535;

/// Three transimpedance ranges a decade apart, most sensitive first.
///
/// INSTRUMENT ASSUMPTIONS (no board has been measured yet; these are a plausible design, to
/// be replaced by a measured step response): the photodiode feeds a transimpedance
/// amplifier whose feedback resistor is switched a decade apart per range, 100 MΩ, 10 MΩ
/// and 1 MΩ (the white tile reads 40 % of full scale on the most sensitive range from a
/// few nA of photocurrent into 3.3 V), each with the same 4.7 pF compensation capacitor
/// across it (stable with a ~100 pF photodiode on a 10 MHz op-amp, which needs well under
/// 1 pF on 100 MΩ and about 1.3 pF on 1 MΩ; the larger value also limits the noise
/// bandwidth). A first-order response, so τ = R·C: 470 µs, 47 µs and 4.7 µs. While the
/// detector arm moves at v, a reading trails the angle by v·τ: 0.028° at 60 °/s on the
/// most sensitive range (where the diffuse part is read, flat), 0.003° and 0.0003° on the
/// others (the specular peak): the host corrects bins for it from these announced values.
///
/// Settling after a switch to a range: a full-scale step decays below 1e-4 of full scale
/// (20 times below one block's noise) in τ·ln(10⁴) = 9.2 τ, plus 100 µs for the analog
/// switch's charge injection and the op-amp's recovery: 4.43, 0.53 and 0.14 ms, rounded up
/// to 4.5, 0.6 and 0.15 ms. A sweep drops the blocks within it after each switch; a still
/// reading waits [`InstrumentConfig::range_settle_ms`] (5 ms), which covers the slowest.
pub const REFERENCE_RANGES: [DetectorRange; 3] = [
    DetectorRange {
        relative_gain: 1.0,
        full_scale_counts: FULL_SCALE_COUNTS,
        time_constant_us: 470.0,
        settle_us: 4_500,
    },
    DetectorRange {
        relative_gain: 0.1,
        full_scale_counts: FULL_SCALE_COUNTS,
        time_constant_us: 47.0,
        settle_us: 600,
    },
    DetectorRange {
        relative_gain: 0.01,
        full_scale_counts: FULL_SCALE_COUNTS,
        time_constant_us: 4.7,
        settle_us: 150,
    },
];

impl InstrumentConfig {
    /// The reference instrument.
    pub const REFERENCE: InstrumentConfig = InstrumentConfig {
        board: "gonio STM32F411 black pill",
        arm_min: Angle::from_whole_deg(0),
        arm_max: Angle::from_whole_deg(85),
        collision_min_sum: Angle::from_whole_deg(10),
        max_speed_deg_per_s: 60.0,
        accel_deg_per_s2: 180.0,
        settle_ms: 100,
        detector_ranges: &REFERENCE_RANGES,
        // INSTRUMENT.md's 1 kHz decimated detector.
        detector_block_us: 1_000,
        acceptance_deg: 1.0,
        // Strategy 2 at δ = 1° is 91 geometries and the full grid 284: hold the full grid.
        max_schedule_len: protocol::schedules::MAX_SCHEDULE_LEN as u16,
        default_integration_ms: 100,
        max_integration_ms: 10_000,
        // The amplifier settles for `range_settle_ms` (5 ms) after a range change; 10 ms
        // leaves at least 5 samples at 1 kHz for a mean and a standard deviation.
        min_integration_ms: 10,
        heartbeat_timeout_ms: 2_000,
        // 2.5° beyond the working range: clear of every target, inside the mechanics.
        home_switch: Angle::from_ticks(87 * 80 + 40),
        // More than the whole travel from 0° to the switch, plus margin for lost steps.
        home_search_range: Angle::from_whole_deg(100),
        // The fast search overshoots the switch by its stop ramp (20²/(2·180) ≈ 1.1°).
        home_backoff: Angle::from_whole_deg(3),
        // The full-speed braking distance (60²/(2·180) = 10°) past the switch, and margin.
        home_release_max: Angle::from_whole_deg(12),
        home_fast_deg_per_s: 20.0,
        // 160 steps/s: polled every 1 ms, the trip is located to within 0.2 step.
        home_slow_deg_per_s: 2.0,
        // 120 steps: a session that lost more than that has a gross fault, found either
        // way (the switch trips during the fast move); the slow part costs 0.75 s.
        home_quick_margin: Angle::from_ticks(120),
        // The margin plus 1.5° for an arm behind its count; beyond, the full search.
        home_quick_approach: Angle::from_ticks(240),
        range_settle_ms: 5,
        saturation_fraction: 0.98,
        // A decade more gain takes 8 % of full scale to 80 %: clear of saturation.
        more_sensitive_below_fraction: 0.8,
        // While the arm moves the signal goes on changing through the blanking after a
        // switch, so the sweep's thresholds leave more room than a still reading's: out of
        // a range at 90 % of full scale (a specular peak rises by less than a tenth within
        // the few blocks of a switch at 60 °/s), into the more sensitive one when it
        // would read below 60 % there (6 % here for decade ranges). A still signal never
        // switches back: 90 % here is 9 % on the less sensitive range, above its 6 %.
        sweep_less_sensitive_above_fraction: 0.9,
        sweep_more_sensitive_below_fraction: 0.6,
        // 0.1 °/s: slower is a still reading (and its blocks' stamps would repeat).
        sweep_min_speed_mdeg_per_s: 100,
    };

    /// The handshake answer for this configuration.
    ///
    /// `serial_number` is the board's unique ID as text (the STM32's 96-bit UID in hex;
    /// the simulator's from its seed); longer text is cut at 24 characters. The reset
    /// cause is [`ResetCause::PowerOn`]; a device puts in its own
    /// ([`crate::Device`] does).
    pub fn device_info(&self, serial_number: &str) -> DeviceInfo {
        let mut firmware_version = heapless::String::new();
        let _ = firmware_version.push_str(crate::FIRMWARE_VERSION);
        let mut board = heapless::String::new();
        let _ = board.push_str(self.board);
        let mut detector_ranges = heapless::Vec::new();
        for range in self.detector_ranges.iter().take(protocol::MAX_RANGES) {
            let _ = detector_ranges.push(*range);
        }
        DeviceInfo {
            protocol_version: PROTOCOL_VERSION,
            firmware_version,
            board,
            arm_min: self.arm_min,
            arm_max: self.arm_max,
            arm_resolution: Angle::from_ticks(1),
            collision_min_sum: self.collision_min_sum,
            max_speed_deg_per_s: self.max_speed_deg_per_s,
            accel_deg_per_s2: self.accel_deg_per_s2,
            settle_ms: self.settle_ms,
            detector_ranges,
            acceptance_deg: self.acceptance_deg,
            max_schedule_len: self.max_schedule_len,
            default_integration_ms: self.default_integration_ms,
            max_integration_ms: self.max_integration_ms,
            min_integration_ms: self.min_integration_ms,
            heartbeat_timeout_ms: self.heartbeat_timeout_ms,
            longest_home_ms: crate::homing::longest_homing_us(self)
                .div_ceil(1000)
                .min(u64::from(u32::MAX)) as u32,
            serial_number: {
                let mut serial = heapless::String::new();
                for c in serial_number.chars() {
                    if serial.push(c).is_err() {
                        break;
                    }
                }
                serial
            },
            reset_cause: ResetCause::PowerOn,
            detector_block_us: self.detector_block_us,
        }
    }
}
