//! The board's pin table: the ONE place that says which MCU pin does what.
//!
//! WeAct "Black Pill" STM32F411CEU6 (UFQFPN48). Fixed by the board, not ours to move:
//!
//! | Pin         | Use                                   |
//! |-------------|---------------------------------------|
//! | PA11 / PA12 | USB OTG FS D- / D+                    |
//! | PA13 / PA14 | SWDIO / SWCLK (probe-rs, defmt RTT)   |
//! | PC13        | on-board blue LED, active low         |
//! | PA0         | on-board KEY push button (to GND)     |
//! | PH0 / PH1   | HSE crystal, 25 or 8 MHz (`clocks`)   |
//! | PC14 / PC15 | 32.768 kHz LSE crystal                |
//! | PB2         | BOOT1 (strapped through a resistor)   |
//! | PB3         | SWO (kept free for trace)             |
//!
//! The instrument's signals (the table below is the code, [`BoardPins`]):
//!
//! | Signal     | Pin  | Peripheral / why this pin                                   | Idle state            |
//! |------------|------|-------------------------------------------------------------|-----------------------|
//! | `step_i`   | PB10 | TIM2_CH3 (AF1): source-arm STEP from a hardware timer       | low                   |
//! | `dir_i`    | PB12 | GPIO                                                        | low                   |
//! | `en_i`     | PB13 | GPIO, TMC2209 EN is active LOW                              | high (driver off)     |
//! | `step_r`   | PB0  | TIM3_CH3 (AF2): detector-arm STEP from a hardware timer     | low                   |
//! | `dir_r`    | PB14 | GPIO                                                        | low                   |
//! | `en_r`     | PB15 | GPIO, active LOW                                            | high (driver off)     |
//! | `home_i`   | PB8  | GPIO (polled, debounced), switch to GND, internal pull-up   | input                 |
//! | `home_r`   | PB9  | GPIO (polled, debounced), switch to GND, internal pull-up   | input                 |
//! | `diag_i`   | PA2  | driver fault: TMC2209 DIAG (high, pull-down) or DRV8825 nFAULT (low, pull-up), [`crate::driver`] | input |
//! | `diag_r`   | PA3  | as `diag_i`                                                 | input                 |
//! | `lamp_en`  | PA8  | TIM1_CH1 (AF1), so the lamp can be PWM-dimmed later         | low (lamp off)        |
//! | `detector` | PA1  | ADC1_IN1: transimpedance amplifier output (0..3.3 V)        | analog                |
//! | `range0`   | PB1  | GPIO, TIA range 0 (most sensitive) switch                   | high (range 0)        |
//! | `range1`   | PB5  | GPIO, TIA range 1 switch                                    | low                   |
//! | `range2`   | PA15 | GPIO, TIA range 2 switch (JTDI: free, we use SWD only)      | low                   |
//!
//! Why these pins:
//! - STEP pins sit on timer channels of two different general-purpose timers (TIM2, TIM3)
//!   so each arm gets its own hardware pulse train. TIM4 is the embassy time driver
//!   (`time-driver-tim4`), TIM5 paces the ADC decimation, TIM1 is kept for the lamp,
//!   TIM9–11 stay free. All but TIM1 and TIM9–11 stop while a debugger halts the core
//!   (`main::freeze_timers_in_debug_halt`).
//! - The detector is on PA1, not PA0: PA0 carries the Black Pill's KEY button, which
//!   would short the amplifier output when pressed.
//! - Kept free on purpose: SPI1 on PA4 (NSS) / PA5 (SCK) / PA6 (MISO) / PA7 (MOSI) for an
//!   external SPI ADC if the internal 12-bit ADC is not enough; USART1 on PA9 / PA10 for
//!   the TMC2209 single-wire UART (PA9 is also the OTG VBUS sense pin); I2C1 on PB6 / PB7.
//! - Range select is one-hot: line k closes the analog switch of feedback resistor k, so
//!   exactly one line is high (range 0, the most sensitive, at reset).
//! - External parts the idle states rely on: a pull-up on each EN (drivers stay off while
//!   the MCU is in reset), a pull-down on LAMP_EN.
//!
//! [`BoardPins::split`] puts every pin in its idle state and sorts them by user: STEP pins to
//! the step timers ([`crate::steppers`]), DIR/EN with them, PA1 to the ADC
//! ([`crate::detector_adc`]), switches, DIAG inputs, lamp and range lines to
//! [`crate::hardware::BoardHardware`].

use embassy_stm32::Peri;
use embassy_stm32::gpio::{AnyPin, Input, Level, Output, Pin, Pull, Speed};
use embassy_stm32::peripherals;

/// Declares [`BoardPins`] and `take_board_pins!` from one list, so the pin table exists once.
macro_rules! pin_table {
    ($d:tt $($(#[doc = $doc:literal])* $field:ident: $pin:ident,)*) => {
        /// Every instrument pin, by function (see the module table).
        pub struct BoardPins {
            $($(#[doc = $doc])* pub $field: Peri<'static, peripherals::$pin>,)*
        }

        /// Move the instrument pins out of `embassy_stm32::Peripherals`.
        macro_rules! take_board_pins {
            ($d p:ident) => {
                $crate::pins::BoardPins { $($field: $d p.$pin,)* }
            };
        }
        pub(crate) use take_board_pins;
    };
}

pin_table! { $
    /// Source arm (θi) driver STEP, TIM2_CH3.
    step_i: PB10,
    /// Source arm driver DIR.
    dir_i: PB12,
    /// Source arm driver EN, active low.
    en_i: PB13,
    /// Detector arm (θr) driver STEP, TIM3_CH3.
    step_r: PB0,
    /// Detector arm driver DIR.
    dir_r: PB14,
    /// Detector arm driver EN, active low.
    en_r: PB15,
    /// Source arm home switch, closes to GND.
    home_i: PB8,
    /// Detector arm home switch, closes to GND.
    home_r: PB9,
    /// Source arm driver DIAG, high on a fault.
    diag_i: PA2,
    /// Detector arm driver DIAG, high on a fault.
    diag_r: PA3,
    /// Lamp enable, active high.
    lamp_en: PA8,
    /// Detector amplifier output, ADC1_IN1.
    detector: PA1,
    /// TIA range 0 switch (most sensitive).
    range0: PB1,
    /// TIA range 1 switch.
    range1: PB5,
    /// TIA range 2 switch.
    range2: PA15,
    /// On-board LED, active low.
    led: PC13,
}

/// The pins, sorted by who drives them now.
pub struct SplitPins {
    /// STEP pins for the step timers, DIR low, EN high (drivers disabled).
    pub motors: MotorPins,
    /// Home switches (pull-up), source arm first.
    pub home: [Input<'static>; 2],
    /// Driver DIAG inputs (pull-down), source arm first.
    pub diag: [Input<'static>; 2],
    /// Lamp enable, off.
    pub lamp: Output<'static>,
    /// TIA range lines, range 0 selected.
    pub range: [Output<'static>; 3],
    /// The on-board LED, off.
    pub led: Output<'static>,
    /// The detector input, for the ADC.
    pub detector: Peri<'static, peripherals::PA1>,
}

/// The motor driver pins of both arms (source first in the arrays).
pub struct MotorPins {
    /// Source arm STEP, for TIM2_CH3.
    pub step_i: Peri<'static, peripherals::PB10>,
    /// Detector arm STEP, for TIM3_CH3.
    pub step_r: Peri<'static, peripherals::PB0>,
    /// DIR, low.
    pub dir: [Output<'static>; 2],
    /// EN (active low), high: drivers disabled.
    pub en: [Output<'static>; 2],
}

impl BoardPins {
    /// Put every pin in its idle state and hand each to its user. The STEP pins stay in
    /// their reset state (input) until the step timers take them, microseconds later.
    pub fn split(self) -> SplitPins {
        fn out(pin: Peri<'static, AnyPin>, level: Level) -> Output<'static> {
            Output::new(pin, level, Speed::Low)
        }
        // The fault handlers' safe stop drives these by register writes (crate::fault).
        crate::fault::register_safe_pins(
            [
                (self.en_i.port(), self.en_i.pin()),
                (self.en_r.port(), self.en_r.pin()),
            ],
            (self.lamp_en.port(), self.lamp_en.pin()),
        );
        SplitPins {
            motors: MotorPins {
                step_i: self.step_i,
                step_r: self.step_r,
                dir: [
                    out(self.dir_i.into(), Level::Low),
                    out(self.dir_r.into(), Level::Low),
                ],
                en: [
                    out(self.en_i.into(), Level::High),
                    out(self.en_r.into(), Level::High),
                ],
            },
            home: [
                Input::new(self.home_i, Pull::Up),
                Input::new(self.home_r, Pull::Up),
            ],
            diag: [
                Input::new(self.diag_i, crate::driver::DRIVER.fault_pull),
                Input::new(self.diag_r, crate::driver::DRIVER.fault_pull),
            ],
            lamp: out(self.lamp_en.into(), Level::Low),
            range: [
                out(self.range0.into(), Level::High),
                out(self.range1.into(), Level::Low),
                out(self.range2.into(), Level::Low),
            ],
            led: Output::new(self.led, Level::High, Speed::Low),
            detector: self.detector,
        }
    }
}
