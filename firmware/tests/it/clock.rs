//! The board's clock logic: the PLL settings of both crystal variants, the crystal's
//! classification from counts against HSI, the SYSCLK check, the blink code.

use firmware::clock::{
    BLINK_OFF_MS, BLINK_ON_MS, BLINK_PAUSE_MS, CaptureCount, ClockFault, HSE_TOLERANCE_PERCENT,
    HSI_HZ, PllSettings, USB_HZ, blink_led_on, blink_period_ms, check_crystal, check_sysclk,
    frequency_hz,
};
use proptest::prelude::*;

/// The board's two variants (firmware/board/src/clocks.rs), 96 MHz SYSCLK each.
const PLL_25: PllSettings = PllSettings {
    hse_hz: 25_000_000,
    m: 25,
    n: 192,
    p: 2,
    q: 4,
};
const PLL_8: PllSettings = PllSettings {
    hse_hz: 8_000_000,
    m: 4,
    n: 96,
    p: 2,
    q: 4,
};
const SYSCLK_HZ: u32 = 96_000_000;

#[test]
fn both_variants_give_96_mhz_and_exactly_48_mhz_usb() {
    for pll in [PLL_25, PLL_8] {
        assert!(pll.is_in_spec(), "{pll:?}");
        assert!(pll.is_exact(), "{pll:?}");
        assert_eq!(pll.sysclk_hz(), SYSCLK_HZ);
        assert_eq!(pll.usb_hz(), USB_HZ);
        assert!(pll.gives(SYSCLK_HZ));
    }
    // The 8 MHz variant's VCO input is 2 MHz, the jitter recommendation's; 25 MHz cannot
    // be divided to 2 MHz, so it has 1 MHz.
    assert_eq!(PLL_8.vco_in_hz(), 2_000_000);
    assert_eq!(PLL_25.vco_in_hz(), 1_000_000);
}

#[test]
fn the_other_crystal_under_a_variants_settings_is_out_of_spec() {
    // What issue 26 item 2 is about: an 8 MHz board running the 25 MHz build.
    let wrong = PllSettings {
        hse_hz: 8_000_000,
        ..PLL_25
    };
    assert!(!wrong.is_in_spec());
    assert!(!wrong.gives(SYSCLK_HZ));
    assert_eq!(wrong.usb_hz(), 15_360_000);
    // And a 25 MHz board running the 8 MHz build: VCO input 6.25 MHz, output 600 MHz.
    let wrong = PllSettings {
        hse_hz: 25_000_000,
        ..PLL_8
    };
    assert!(!wrong.is_in_spec());
}

#[test]
fn settings_off_by_a_divider_are_refused() {
    assert!(!PllSettings { q: 5, ..PLL_25 }.gives(SYSCLK_HZ)); // 38.4 MHz USB
    assert!(!PllSettings { p: 4, ..PLL_25 }.gives(SYSCLK_HZ)); // 48 MHz SYSCLK
    assert!(
        !PllSettings {
            n: 200,
            q: 4,
            ..PLL_25
        }
        .gives(SYSCLK_HZ)
    ); // 50 MHz USB
    assert!(!PllSettings { p: 3, ..PLL_25 }.is_in_spec()); // no such PLLP
    assert!(
        !PllSettings {
            n: 440,
            p: 4,
            q: 9,
            ..PLL_25
        }
        .is_in_spec()
    ); // VCO 440 MHz
    // Zeros do not divide by zero: they are refused.
    assert!(!PllSettings { m: 0, ..PLL_25 }.gives(SYSCLK_HZ));
    assert!(!PllSettings { p: 0, ..PLL_25 }.gives(SYSCLK_HZ));
    assert!(!PllSettings { q: 0, ..PLL_25 }.gives(SYSCLK_HZ));
}

/// `hse_hz` counted for about `window_ticks` of an HSI that is `hsi_error_ppm` off 16 MHz,
/// as the board counts: whole capture periods of `period_cycles` crystal cycles.
fn counts(hse_hz: u32, hsi_error_ppm: i64, period_cycles: u32, window_ticks: u32) -> (u32, u32) {
    let hsi_actual = HSI_HZ as f64 * (1.0 + hsi_error_ppm as f64 * 1e-6);
    let ticks_per_period = f64::from(period_cycles) * hsi_actual / f64::from(hse_hz);
    let periods = (f64::from(window_ticks) / ticks_per_period).ceil();
    (
        (periods as u32) * period_cycles,
        (periods * ticks_per_period).round() as u32,
    )
}

#[test]
fn the_right_crystal_passes_over_the_hsi_error_band() {
    // HSI −8 % … +4.5 % (the datasheet's full temperature range), and ±1 % at 25 °C.
    for pll in [PLL_25, PLL_8] {
        for hsi_error_ppm in [-80_000, -40_000, -10_000, 0, 10_000, 45_000] {
            let (cycles, ticks) = counts(pll.hse_hz, hsi_error_ppm, 8 * 31, 16_000);
            let measured = check_crystal(pll.hse_hz, cycles, ticks);
            assert!(
                measured.is_ok(),
                "{pll:?} HSI {hsi_error_ppm} ppm: {measured:?}"
            );
        }
        // With HSI exact, the measurement is the crystal to the count's resolution.
        let (cycles, ticks) = counts(pll.hse_hz, 0, 8 * 31, 16_000);
        let measured = check_crystal(pll.hse_hz, cycles, ticks).unwrap();
        assert!(
            measured.abs_diff(pll.hse_hz) < pll.hse_hz / 5_000,
            "{measured}"
        );
    }
}

#[test]
fn the_other_variants_crystal_and_common_wrong_ones_are_refused() {
    for (expected, actual) in [
        (25_000_000, 8_000_000),
        (8_000_000, 25_000_000),
        (25_000_000, 12_000_000),
        (25_000_000, 16_000_000),
        (25_000_000, 20_000_000),
        (8_000_000, 12_000_000),
    ] {
        for hsi_error_ppm in [-80_000, 0, 45_000] {
            let (cycles, ticks) = counts(actual, hsi_error_ppm, 8 * 31, 16_000);
            assert!(
                matches!(
                    check_crystal(expected, cycles, ticks),
                    Err(ClockFault::HseWrongFrequency(_))
                ),
                "{actual} Hz for a {expected} Hz build, HSI {hsi_error_ppm} ppm"
            );
        }
    }
}

#[test]
fn no_count_is_no_measurement() {
    assert_eq!(
        check_crystal(25_000_000, 0, 16_000),
        Err(ClockFault::HseNotMeasured)
    );
    assert_eq!(
        check_crystal(25_000_000, 248, 0),
        Err(ClockFault::HseNotMeasured)
    );
    assert_eq!(frequency_hz(1, 0, HSI_HZ), None);
    // Saturates instead of wrapping.
    assert_eq!(frequency_hz(u32::MAX, 1, u32::MAX), Some(u32::MAX));
}

proptest! {
    /// The tolerance is a band: inside passes with the measured value, outside is refused
    /// with it, whatever the counts.
    #[test]
    fn classification_is_the_tolerance_band(cycles in 1u32..1_000_000, ticks in 1u32..1_000_000) {
        let expected = 25_000_000u32;
        let measured = frequency_hz(cycles, ticks, HSI_HZ).unwrap();
        let inside = u64::from(measured.abs_diff(expected)) * 100
            <= u64::from(expected) * u64::from(HSE_TOLERANCE_PERCENT);
        match check_crystal(expected, cycles, ticks) {
            Ok(hz) => prop_assert!(inside && hz == measured),
            Err(ClockFault::HseWrongFrequency(hz)) => prop_assert!(!inside && hz == measured),
            Err(other) => prop_assert!(false, "{other:?}"),
        }
    }
}

#[test]
fn sysclk_checked_against_the_crystal() {
    // 1 ms of SYSCLK ticks for 100 capture periods of 248 crystal cycles at 25 MHz.
    let cycles = 100 * 248;
    let ticks = (u64::from(cycles) * 96 / 25) as u32;
    assert_eq!(
        check_sysclk(SYSCLK_HZ, 25_000_000, cycles, ticks),
        Ok(SYSCLK_HZ)
    );
    // Off by a tick or two: still the PLL's.
    assert!(check_sysclk(SYSCLK_HZ, 25_000_000, cycles, ticks + 2).is_ok());
    // A PLL that did not take (still HSI: 16 MHz), or half of it.
    let hsi_ticks = (u64::from(cycles) * 16 / 25) as u32;
    assert!(matches!(
        check_sysclk(SYSCLK_HZ, 25_000_000, cycles, hsi_ticks),
        Err(ClockFault::SysclkWrong(16_000_000))
    ));
    assert!(check_sysclk(SYSCLK_HZ, 25_000_000, cycles, ticks / 2).is_err());
    assert!(check_sysclk(SYSCLK_HZ, 25_000_000, 0, ticks).is_err());
}

/// Rising edges of the LED in `[0, until_ms)`, sampled every ms.
fn blinks_in(blinks: u32, from_ms: u32, until_ms: u32) -> u32 {
    let mut lit = blink_led_on(blinks, from_ms.wrapping_sub(1));
    let mut edges = 0;
    for t in from_ms..until_ms {
        let now = blink_led_on(blinks, t);
        if now && !lit {
            edges += 1;
        }
        lit = now;
    }
    edges
}

#[test]
fn each_code_blinks_its_count_then_pauses() {
    for fault in [
        ClockFault::HseNotReady,
        ClockFault::HseNotMeasured,
        ClockFault::HseWrongFrequency(8_000_000),
        ClockFault::SysclkWrong(16_000_000),
    ] {
        let n = fault.blinks();
        let period = blink_period_ms(n);
        // Lit at the start of a period, n blinks in it, in every period.
        assert!(blink_led_on(n, 0));
        for k in 0..3 {
            assert_eq!(blinks_in(n, k * period, (k + 1) * period), n, "{fault:?}");
        }
        // Each blink is BLINK_ON_MS lit, and the pause is dark.
        let lit_ms = (0..period).filter(|&t| blink_led_on(n, t)).count() as u32;
        assert_eq!(lit_ms, n * BLINK_ON_MS);
        assert!((period - BLINK_PAUSE_MS..period).all(|t| !blink_led_on(n, t)));
        assert!((BLINK_ON_MS..BLINK_ON_MS + BLINK_OFF_MS).all(|t| !blink_led_on(n, t)));
    }
    // The codes differ in their count.
    let counts: Vec<u32> = [
        ClockFault::HseNotReady,
        ClockFault::HseNotMeasured,
        ClockFault::HseWrongFrequency(0),
        ClockFault::SysclkWrong(0),
    ]
    .iter()
    .map(|f| f.blinks())
    .collect();
    assert_eq!(counts, [2, 3, 4, 5]);
}

#[test]
fn the_blink_survives_the_millisecond_counter_wrapping() {
    // No panic anywhere in u32, and still a blink pattern.
    for t in [u32::MAX - 1, u32::MAX, 0] {
        let _ = blink_led_on(2, t);
    }
}

#[test]
fn captures_count_whole_periods_across_the_counter_wrapping() {
    let mut count = CaptureCount::new();
    assert_eq!((count.cycles(248), count.ticks()), (0, 0));
    // The first capture only starts the count.
    count.capture(65_400);
    assert_eq!((count.cycles(248), count.ticks()), (0, 0));
    // 159 ticks a period (25 MHz against 16 MHz), through 65,535 → 0.
    for k in 1..=4u32 {
        count.capture((65_400 + 159 * k) as u16);
    }
    assert_eq!(count.cycles(248), 4 * 248);
    assert_eq!(count.ticks(), 4 * 159);
    assert!(check_crystal(25_000_000, count.cycles(248), count.ticks()).is_ok());
}

proptest! {
    /// Whatever the counter's start and the periods (under 2¹⁶ each), the ticks are their
    /// sum and the cycles one period's worth per capture after the first.
    #[test]
    fn capture_count_is_the_sum_of_the_periods(
        start in any::<u16>(),
        periods in proptest::collection::vec(1u32..65_536, 0..200),
    ) {
        let mut count = CaptureCount::new();
        let mut at = u32::from(start);
        count.capture(start);
        for &p in &periods {
            at = at.wrapping_add(p);
            count.capture(at as u16);
        }
        prop_assert_eq!(count.ticks(), periods.iter().sum::<u32>());
        prop_assert_eq!(count.cycles(248), periods.len() as u32 * 248);
    }
}
