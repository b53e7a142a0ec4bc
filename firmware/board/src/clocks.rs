//! The crystal, chosen at build time and checked at boot before anything depends on it.
//!
//! WeAct's Black Pill comes with a 25 MHz or an 8 MHz crystal (HSE). The build picks one
//! with a cargo feature, `hse-25mhz` (default) or `hse-8mhz`; [`PLL`] holds that variant's
//! PLL settings, asserted at compile time to give [`crate::SYSCLK_HZ`] (96 MHz) and exactly
//! 48 MHz for USB ([`firmware::clock::PllSettings::gives`]).
//!
//! At boot, before embassy's clock setup (which would wait for HSERDY forever and trust
//! the frequency it is told), [`check_crystal`] starts HSE with a timeout and counts its
//! cycles against HSI, the reset clock:
//!
//! - The F411 routes HSE, divided by RCC_CFGR.RTCPRE, to TIM11's channel 1 input for this
//!   purpose: TIM11_OR.TI1_RMP = 0b10, "HSE_RTC" (RM0383: the RCC chapter's "Internal/
//!   external clock measurement using TIM5/TIM11" and the TIM9–11 chapter's TIM11_OR;
//!   ST's HAL names the value TIM_TIM11_HSE). TIM5's channel 4 remap only reaches LSI,
//!   LSE and the RTC wakeup, not HSE, and every other timer and the DWT counter run on
//!   SYSCLK, so TIM11 is the only way to see HSE while the core runs on HSI.
//! - TIM11 counts its APB2 clock, HSI's 16 MHz at reset (all prescalers 1); input capture
//!   with the /8 prescaler latches the count every 8 × [`RTC_PRESCALER`] = 248 crystal
//!   cycles (every 159 ticks at 25 MHz, 496 at 8 MHz, ≤ 992 for any crystal of the
//!   oscillator's 4–26 MHz, so a 16-bit difference never wraps). The hardware latches the
//!   count, so the polling loop's own timing does not enter the result; an overcapture
//!   (a latch the loop missed) voids the measurement. About 1 ms of captures: ±2 ticks in
//!   16,000, far under HSI's own error, which sets the tolerance
//!   ([`firmware::clock::HSE_TOLERANCE_PERCENT`]).
//!
//! A crystal that is missing, silent or not the build's is refused: HSE is switched off
//! again, the chip stays on HSI (embassy's setup never runs), and `main` puts every pin in
//! its safe idle state, starts neither USB nor the step timers nor the ADC, and blinks the
//! [`ClockFault`] code on the LED. After the switch to the
//! PLL, [`measure_sysclk`] counts SYSCLK against the crystal the same way (TIM11 then
//! counts SYSCLK), so the boot log carries both, measured.

use embassy_stm32::pac;
use firmware::clock::{CaptureCount, ClockFault, PllSettings};

#[cfg(all(feature = "hse-25mhz", feature = "hse-8mhz"))]
compile_error!(
    "features `hse-25mhz` and `hse-8mhz` are exclusive: pick the crystal on your board \
     (`--no-default-features --features hse-8mhz` for an 8 MHz one)"
);
#[cfg(not(any(feature = "hse-25mhz", feature = "hse-8mhz")))]
compile_error!(
    "pick the board's crystal: feature `hse-25mhz` (the default) or `hse-8mhz` \
     (`--no-default-features --features hse-8mhz`)"
);

/// 25 MHz crystal → /25 → 1 MHz VCO input (25 cannot be divided to the recommended
/// 2 MHz) → ×192 → 192 MHz VCO → /2 = 96 MHz SYSCLK, /4 = 48 MHz USB.
#[cfg(not(feature = "hse-8mhz"))]
pub const PLL: PllSettings = PllSettings {
    hse_hz: 25_000_000,
    m: 25,
    n: 192,
    p: 2,
    q: 4,
};
/// 8 MHz crystal → /4 → 2 MHz VCO input (RM0383 recommends 2 MHz for the least jitter)
/// → ×96 → 192 MHz VCO → /2 = 96 MHz SYSCLK, /4 = 48 MHz USB.
#[cfg(feature = "hse-8mhz")]
pub const PLL: PllSettings = PllSettings {
    hse_hz: 8_000_000,
    m: 4,
    n: 96,
    p: 2,
    q: 4,
};

// Both variants give the same SYSCLK (the step timers' and the ADC's cycle counts depend on
// it) and exactly 48 MHz for USB, within the PLL's limits, with no rounded division.
const _: () = assert!(PLL.gives(crate::SYSCLK_HZ));

/// RCC_CFGR.RTCPRE: HSE / 31 feeds TIM11 (2…31; the largest gives the longest capture
/// period, so the polling loop has the most time).
const RTC_PRESCALER: u8 = 31;
/// TIM11 input capture prescaler: a capture every 8th edge (IC1PSC = 0b11).
const CAPTURE_EDGES: u32 = 8;
/// Crystal cycles per capture.
const CYCLES_PER_CAPTURE: u32 = CAPTURE_EDGES * RTC_PRESCALER as u32;
/// TIM11_OR.TI1_RMP value connecting HSE_RTC to TIM11_CH1.
const TI1_RMP_HSE_RTC: u32 = 0b10;

/// How long HSE gets to start, in HSI cycles: 100 ms, ST's HAL default HSE_STARTUP_TIMEOUT,
/// 50× the crystal's typical 2 ms start-up (DS10314's HSE table).
const HSE_START_TIMEOUT_CYCLES: u32 = firmware::clock::HSI_HZ / 10;

/// What [`check_crystal`] found.
pub struct CrystalReport {
    /// The crystal's frequency measured against HSI, Hz, if it got that far.
    pub measured_hse_hz: Option<u32>,
    /// Ok: the build's crystal, HSE left on for embassy's setup. Err: refused, HSE off.
    pub verdict: Result<(), ClockFault>,
}

/// Start HSE with a timeout and measure it against HSI (see the module doc). Runs on the
/// reset clocks, before `embassy_stm32::init`; leaves TIM11 reset and unclocked and
/// RTCPRE at its reset value.
pub fn check_crystal() -> CrystalReport {
    let rcc = pac::RCC;
    rcc.cr().modify(|w| {
        w.set_hsebyp(false); // a crystal, not an external clock
        w.set_hseon(true);
    });
    let mut waited = 0u32;
    while !rcc.cr().read().hserdy() {
        if waited >= HSE_START_TIMEOUT_CYCLES {
            rcc.cr().modify(|w| w.set_hseon(false));
            return CrystalReport {
                measured_hse_hz: None,
                verdict: Err(ClockFault::HseNotReady),
            };
        }
        cortex_m::asm::delay(1_000);
        waited += 1_000;
    }
    // About 1 ms of HSI ticks.
    let counted = count_hse(firmware::clock::HSI_HZ / 1_000);
    let (cycles, ticks) = counted.unwrap_or((0, 0));
    let verdict = firmware::clock::check_crystal(PLL.hse_hz, cycles, ticks);
    let measured_hse_hz = firmware::clock::frequency_hz(cycles, ticks, firmware::clock::HSI_HZ)
        .filter(|_| cycles > 0);
    if verdict.is_err() {
        rcc.cr().modify(|w| w.set_hseon(false));
    }
    CrystalReport {
        measured_hse_hz,
        verdict: verdict.map(|_| ()),
    }
}

/// Clock the GPIO ports, which embassy's setup does when it runs: for the pins' safe
/// idle state and the LED when the crystal is refused before it.
pub fn enable_gpio_clocks() {
    pac::RCC.ahb1enr().modify(|w| {
        w.set_gpioaen(true);
        w.set_gpioben(true);
        w.set_gpiocen(true);
    });
    let _ = pac::RCC.ahb1enr().read(); // on before the first port write
}

/// After the switch to the PLL: SYSCLK measured against the crystal (TIM11 counts PCLK2 =
/// SYSCLK, APB2 undivided), in Hz of the crystal's nominal frequency, or why it is wrong.
pub fn measure_sysclk() -> Result<u32, ClockFault> {
    // About 1 ms of SYSCLK ticks.
    let (cycles, ticks) = count_hse(crate::SYSCLK_HZ / 1_000).unwrap_or((0, 0));
    firmware::clock::check_sysclk(crate::SYSCLK_HZ, PLL.hse_hz, cycles, ticks)
}

/// Count whole capture periods of HSE_RTC on TIM11 for at least `window_ticks` of TIM11's
/// clock: (crystal cycles, ticks). `None` when no edge comes, or one was missed.
fn count_hse(window_ticks: u32) -> Option<(u32, u32)> {
    let rcc = pac::RCC;
    let tim = pac::TIM11;
    rcc.cfgr().modify(|w| w.set_rtcpre(RTC_PRESCALER));
    rcc.apb2enr().modify(|w| w.set_tim11en(true));
    let _ = rcc.apb2enr().read(); // the clock is on before the first register write
    tim.or().write_value(TI1_RMP_HSE_RTC);
    tim.psc().write_value(0);
    tim.arr().write(|w| w.set_arr(0xffff));
    tim.ccmr_input(0).write(|w| {
        w.set_ccs(0, pac::timer::vals::CcmrInputCcs::TI4); // CC1S = 01: IC1 on TI1
        w.set_icpsc(0, 0b11); // every 8th edge
    });
    tim.ccer().write(|w| w.set_cce(0, true));
    tim.egr().write(|w| w.set_ug(true));
    tim.sr().write_value(pac::timer::regs::Sr1ch(0));
    tim.cr1().write(|w| w.set_cen(true));

    // A capture comes at least every 992 ticks for any crystal the oscillator can run; a
    // loop pass is a few tens of cycles, so this bound is ≥ 20 windows' worth of polling.
    let mut polls_left = 20 * window_ticks;
    let mut count = CaptureCount::new();
    let mut result = None;
    while polls_left > 0 {
        polls_left -= 1;
        let sr = tim.sr().read();
        if sr.ccof(0) {
            break; // a capture was overwritten unread: the count would be short
        }
        if !sr.ccif(0) {
            continue;
        }
        count.capture(tim.ccr(0).read().ccr()); // the read clears CC1IF
        if count.ticks() >= window_ticks {
            result = Some((count.cycles(CYCLES_PER_CAPTURE), count.ticks()));
            break;
        }
    }
    tim.cr1().write(|w| w.set_cen(false));
    rcc.apb2rstr().modify(|w| w.set_tim11rst(true));
    rcc.apb2rstr().modify(|w| w.set_tim11rst(false));
    rcc.apb2enr().modify(|w| w.set_tim11en(false));
    rcc.cfgr().modify(|w| w.set_rtcpre(0));
    result
}
