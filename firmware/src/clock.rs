//! The board's clocks, the logic of them: the PLL settings and the clocks they derive
//! (the board asserts them at compile time, one set per crystal variant), the crystal's
//! frequency measured against the internal RC oscillator and whether it is the one the
//! build expects, and the LED blink code the board shows when it refuses its clocks.
//!
//! Why the board measures at all: WeAct's Black Pill is sold with a 25 MHz and with an
//! 8 MHz crystal, and the two look alike. PLL settings for one run the other out of the
//! PLL's spec (25 MHz settings on 8 MHz: a 0.32 MHz VCO input, under the 0.95 MHz minimum),
//! and USB, which needs 48 MHz within 0.25 %, never enumerates. Embassy's clock setup
//! trusts the frequency it is told, and waits for a crystal that is missing forever. So the
//! board starts the crystal itself with a timeout, counts its cycles against HSI (16 MHz,
//! on from reset), and only with the crystal the build was made for does it switch to the
//! PLL and start USB and the step timers ([`check_crystal`]); otherwise it stays on HSI and
//! blinks a [`ClockFault`] code ([`blink_led_on`]).

/// HSI, the reset clock, Hz: the reference the crystal is measured against.
pub const HSI_HZ: u32 = 16_000_000;
/// USB full speed needs exactly this from the PLL's Q output, Hz.
pub const USB_HZ: u32 = 48_000_000;
/// The STM32F411's SYSCLK limit, Hz.
pub const MAX_SYSCLK_HZ: u32 = 100_000_000;

/// How far, in percent, a measured crystal may be from the build's before it is refused.
///
/// The measurement's own error is HSI's: the factory-trimmed RC is within −8 % … +4.5 % of
/// 16 MHz over −40…105 °C (the F411 datasheet's HSI table; ±1 % at 25 °C), so a crystal of
/// exactly the expected frequency reads up to +8.7 % high (HSI 8 % slow) or 4.3 % low.
/// ±10 % covers that with margin, and still refuses every crystal a Black Pill is sold
/// with that is not the build's (8 ↔ 25 MHz: −68 % / +213 %), and the other common ones
/// (12, 16, 20 MHz for a 25 MHz build; 12 MHz for an 8 MHz build). It cannot tell 25 from
/// 24 MHz (−4 %): a 24 MHz crystal would pass, and USB would not enumerate (46 MHz).
pub const HSE_TOLERANCE_PERCENT: u32 = 10;

/// How far, in percent, SYSCLK measured against the crystal may be from the build's: the
/// PLL multiplies the crystal exactly, so this is only the count's resolution (two
/// ticks of ~100,000) plus margin. A wrong PLL setting is off by far more (a step of the
/// smallest divider is 25 %).
pub const SYSCLK_TOLERANCE_PERCENT: u32 = 1;

/// The main PLL's settings (RCC_PLLCFGR: PLLM, PLLN, PLLP, PLLQ) for a crystal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PllSettings {
    /// The crystal (HSE), Hz.
    pub hse_hz: u32,
    /// PLLM: crystal → VCO input.
    pub m: u32,
    /// PLLN: VCO input → VCO output.
    pub n: u32,
    /// PLLP: VCO output → SYSCLK (2, 4, 6 or 8).
    pub p: u32,
    /// PLLQ: VCO output → USB (48 MHz).
    pub q: u32,
}

impl PllSettings {
    /// VCO input, Hz (HSE / M; 0 for M = 0).
    pub const fn vco_in_hz(&self) -> u32 {
        or_zero(self.hse_hz.checked_div(self.m))
    }

    /// VCO output, Hz (VCO input × N), saturating.
    pub const fn vco_out_hz(&self) -> u32 {
        self.vco_in_hz().saturating_mul(self.n)
    }

    /// SYSCLK, Hz (VCO output / P; 0 for P = 0).
    pub const fn sysclk_hz(&self) -> u32 {
        or_zero(self.vco_out_hz().checked_div(self.p))
    }

    /// The USB clock, Hz (VCO output / Q; 0 for Q = 0).
    pub const fn usb_hz(&self) -> u32 {
        or_zero(self.vco_out_hz().checked_div(self.q))
    }

    /// Every division exact: the derived clocks are what [`Self::sysclk_hz`] and
    /// [`Self::usb_hz`] say, not rounded.
    pub const fn is_exact(&self) -> bool {
        self.m != 0
            && self.p != 0
            && self.q != 0
            && self.hse_hz.is_multiple_of(self.m)
            && self.vco_out_hz().is_multiple_of(self.p)
            && self.vco_out_hz().is_multiple_of(self.q)
    }

    /// Within the STM32F411's PLL limits (RM0383, RCC_PLLCFGR; DS10314's PLL table):
    /// HSE 4–26 MHz in oscillator mode, 2 ≤ M ≤ 63, VCO input 0.95–2.1 MHz, 50 ≤ N ≤ 432,
    /// VCO output 100–432 MHz, P ∈ {2, 4, 6, 8}, 2 ≤ Q ≤ 15, SYSCLK ≤ 100 MHz.
    pub const fn is_in_spec(&self) -> bool {
        let vco_in = self.vco_in_hz();
        let vco_out = self.vco_out_hz();
        self.hse_hz >= 4_000_000
            && self.hse_hz <= 26_000_000
            && self.m >= 2
            && self.m <= 63
            && vco_in >= 950_000
            && vco_in <= 2_100_000
            && self.n >= 50
            && self.n <= 432
            && vco_out >= 100_000_000
            && vco_out <= 432_000_000
            && matches!(self.p, 2 | 4 | 6 | 8)
            && self.q >= 2
            && self.q <= 15
            && self.sysclk_hz() <= MAX_SYSCLK_HZ
    }

    /// In spec, exact, giving `sysclk_hz` and exactly [`USB_HZ`]: what a board asserts
    /// at compile time of its settings.
    pub const fn gives(&self, sysclk_hz: u32) -> bool {
        self.is_in_spec()
            && self.is_exact()
            && self.sysclk_hz() == sysclk_hz
            && self.usb_hz() == USB_HZ
    }
}

/// A quotient, or 0 for a division by zero (settings that are refused anyway).
const fn or_zero(quotient: Option<u32>) -> u32 {
    match quotient {
        Some(q) => q,
        None => 0,
    }
}

/// Why the board refused its clocks: the count of blinks of its error code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClockFault {
    /// HSERDY never came: no crystal, a broken one, or a missing load capacitor.
    HseNotReady,
    /// The crystal oscillates but no cycle of it was counted (the measurement path).
    HseNotMeasured,
    /// The crystal is not the one the build expects (measured Hz).
    HseWrongFrequency(u32),
    /// SYSCLK, measured against the crystal after the PLL took over, is not the build's
    /// (measured Hz): the PLL settings did not take.
    SysclkWrong(u32),
}

impl ClockFault {
    /// Blinks per period of the code ([`blink_led_on`]): 2, 3, 4, 5. (One blink is not
    /// used: a single flash is too easily a glitch or a reset.)
    pub const fn blinks(self) -> u32 {
        match self {
            ClockFault::HseNotReady => 2,
            ClockFault::HseNotMeasured => 3,
            ClockFault::HseWrongFrequency(_) => 4,
            ClockFault::SysclkWrong(_) => 5,
        }
    }
}

/// `cycles` of a clock counted in `ref_ticks` of a reference at `ref_hz`: its frequency,
/// Hz (rounded down; saturating), or `None` with no reference ticks.
pub fn frequency_hz(cycles: u32, ref_ticks: u32, ref_hz: u32) -> Option<u32> {
    if ref_ticks == 0 {
        return None;
    }
    let hz = u64::from(cycles) * u64::from(ref_hz) / u64::from(ref_ticks);
    Some(u32::try_from(hz).unwrap_or(u32::MAX))
}

/// Input captures of a clock on a free-running 16-bit timer, summed into a count: the
/// board's TIM11 latches its counter every `cycles_per_capture` cycles of the clock
/// measured, and the ticks between the first capture and the last are the reference's.
///
/// Differences are taken modulo 2¹⁶, so the counter may wrap between captures any number
/// of times in all, but at most once between two of them: the board's captures come at
/// most 992 ticks apart.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CaptureCount {
    last: Option<u16>,
    periods: u32,
    ticks: u32,
}

impl CaptureCount {
    /// No capture yet.
    pub const fn new() -> CaptureCount {
        CaptureCount {
            last: None,
            periods: 0,
            ticks: 0,
        }
    }

    /// The counter was latched at `captured`.
    pub fn capture(&mut self, captured: u16) {
        if let Some(last) = self.last {
            self.ticks = self
                .ticks
                .saturating_add(u32::from(captured.wrapping_sub(last)));
            self.periods = self.periods.saturating_add(1);
        }
        self.last = Some(captured);
    }

    /// Reference ticks over the whole capture periods so far.
    pub const fn ticks(&self) -> u32 {
        self.ticks
    }

    /// Cycles of the measured clock in them, at `cycles_per_capture` a period.
    pub const fn cycles(&self, cycles_per_capture: u32) -> u32 {
        self.periods.saturating_mul(cycles_per_capture)
    }
}

/// Whether `measured` is within `percent` of `expected`.
pub fn within_percent(measured: u32, expected: u32, percent: u32) -> bool {
    let diff = u64::from(measured.abs_diff(expected));
    diff * 100 <= u64::from(expected) * u64::from(percent)
}

/// The crystal check: `hse_cycles` of the crystal counted in `hsi_ticks` of HSI. The
/// measured frequency when it is the build's `expected_hz` (within
/// [`HSE_TOLERANCE_PERCENT`]), else why not.
pub fn check_crystal(expected_hz: u32, hse_cycles: u32, hsi_ticks: u32) -> Result<u32, ClockFault> {
    if hse_cycles == 0 {
        return Err(ClockFault::HseNotMeasured);
    }
    let measured = frequency_hz(hse_cycles, hsi_ticks, HSI_HZ).ok_or(ClockFault::HseNotMeasured)?;
    if within_percent(measured, expected_hz, HSE_TOLERANCE_PERCENT) {
        Ok(measured)
    } else {
        Err(ClockFault::HseWrongFrequency(measured))
    }
}

/// The SYSCLK check after the switch to the PLL: `hse_cycles` of the crystal counted in
/// `sysclk_ticks` of SYSCLK. SYSCLK in Hz of the crystal's nominal `hse_hz` (as exact as
/// the crystal) when it is `expected_hz` within [`SYSCLK_TOLERANCE_PERCENT`], else why not.
pub fn check_sysclk(
    expected_hz: u32,
    hse_hz: u32,
    hse_cycles: u32,
    sysclk_ticks: u32,
) -> Result<u32, ClockFault> {
    // SYSCLK = hse_hz × ticks / cycles: the "reference" here is the crystal.
    let measured = frequency_hz(sysclk_ticks, hse_cycles, hse_hz).unwrap_or(0);
    if within_percent(measured, expected_hz, SYSCLK_TOLERANCE_PERCENT) {
        Ok(measured)
    } else {
        Err(ClockFault::SysclkWrong(measured))
    }
}

/// One blink: on this long, ms.
pub const BLINK_ON_MS: u32 = 200;
/// Then off this long, ms: 2 blinks a second, slow enough to count.
pub const BLINK_OFF_MS: u32 = 300;
/// After the code's blinks, dark this long, ms, so that one code is told from the next.
pub const BLINK_PAUSE_MS: u32 = 1_500;

/// The period of a code of `blinks` blinks, ms.
pub const fn blink_period_ms(blinks: u32) -> u32 {
    blinks * (BLINK_ON_MS + BLINK_OFF_MS) + BLINK_PAUSE_MS
}

/// Whether the LED is lit `elapsed_ms` into the endless repetition of a code of `blinks`
/// blinks: `blinks` × (on [`BLINK_ON_MS`], off [`BLINK_OFF_MS`]), then dark for
/// [`BLINK_PAUSE_MS`], again.
pub const fn blink_led_on(blinks: u32, elapsed_ms: u32) -> bool {
    let t = elapsed_ms % blink_period_ms(blinks);
    t < blinks * (BLINK_ON_MS + BLINK_OFF_MS) && t % (BLINK_ON_MS + BLINK_OFF_MS) < BLINK_ON_MS
}
