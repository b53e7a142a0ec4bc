//! The board's side of the firmware library's hardware traits ([`firmware::Arms`],
//! [`firmware::Detector`], [`firmware::Lamp`]): it acts and reports, it decides nothing.
//!
//! - Arms: one hardware timer per arm issues the step pulses of the library's
//!   [`MoveProfile`] (TIM2 → source arm, TIM3 → detector arm; see [`crate::steppers`]).
//!   The step count is kept by the timer interrupts, one count per pulse issued, so it
//!   is the position the drivers were told, whatever the CPU was doing. The drivers are
//!   enabled (EN low) at the first move and stay enabled to hold position; the library
//!   disables a faulted arm's driver in its fail-safe stop and cycles EN on the next
//!   `Home` to clear the TMC2209's latched DIAG.
//! - Home switches and driver DIAG: GPIO inputs, read when the library asks.
//! - Detector: the TIA range lines (one-hot GPIO) and the photodiode ADC (ADC1 on PA1,
//!   256× oversampled to 16 bits, one sample per 1.024 ms block into a bounded ring, each
//!   stamped with the detector arm's step count at the block's end; see
//!   [`crate::detector_adc`]).
//! - Lamp: a GPIO.

use defmt::warn;
use embassy_stm32::gpio::{Input, Output};
use embassy_stm32::pac;
use embassy_stm32::pac::gpio::vals::Idr;
use firmware::detector;
use firmware::motion::MoveProfile;
use firmware::sampling::SampleLoss;
use firmware::{Arm, Arms, Detector, Diagnostics, Lamp, MeasuredClocks, Sample, StackUse};
use protocol::ResetCounts;

use crate::detector_adc::DetectorAdc;
use crate::steppers::Steppers;

/// How long two feedback resistors are both connected in a range switch, µs: longer than
/// an analog switch's turn-on time exceeds its turn-off time (CMOS switches turn on in
/// ≲ 0.5 µs), so the make is complete before the break starts. A busy wait in the device
/// task, interrupts on.
const RANGE_OVERLAP_US: u32 = 2;

/// The instrument as the firmware library sees it.
pub struct BoardHardware {
    steppers: Steppers,
    adc: DetectorAdc,
    home: [Input<'static>; 2],
    diag: [Input<'static>; 2],
    lamp: Output<'static>,
    range: [Output<'static>; 3],
    /// What `main` found at boot.
    boot: Boot,
}

/// What `main` measured and counted at boot, for the self-test.
pub struct Boot {
    /// The clocks, measured.
    pub clocks: MeasuredClocks,
    /// The resets since power-on, this one included.
    pub resets: ResetCounts,
}

impl BoardHardware {
    /// From the running step generators and ADC, and the pins of [`crate::pins`] in their
    /// idle state.
    /// `switches`: the home switches and the drivers' DIAG inputs.
    pub fn new(
        steppers: Steppers,
        adc: DetectorAdc,
        switches: [[Input<'static>; 2]; 2],
        lamp: Output<'static>,
        range: [Output<'static>; 3],
        boot: Boot,
    ) -> Self {
        let [home, diag] = switches;
        BoardHardware {
            steppers,
            adc,
            home,
            diag,
            lamp,
            range,
            boot,
        }
    }
}

impl Arms for BoardHardware {
    fn run_profile(&mut self, arm: Arm, profile: &MoveProfile) {
        self.steppers.run_profile(arm, profile);
    }

    fn position_steps(&self, arm: Arm) -> i32 {
        self.steppers.position_steps(arm)
    }

    fn is_moving(&self, arm: Arm) -> bool {
        self.steppers.is_moving(arm)
    }

    fn set_position_steps(&mut self, arm: Arm, steps: i32) {
        self.steppers.set_position_steps(arm, steps);
    }

    fn home_switch_pressed(&self, arm: Arm) -> bool {
        self.home[arm.index()].is_low()
    }

    fn driver_fault(&self, arm: Arm) -> bool {
        crate::driver::is_fault(self.diag[arm.index()].is_high())
    }

    fn set_driver_enabled(&mut self, arm: Arm, enabled: bool) {
        self.steppers.set_driver_enabled(arm, enabled);
    }

    fn take_step_fault(&mut self, arm: Arm) -> bool {
        let Some(fault) = self.steppers.take_fault(arm) else {
            return false;
        };
        warn!(
            "{} arm: step interrupt {} µs into a {} µs segment: too late, timer stopped",
            arm, fault.late_ticks, fault.segment_ticks
        );
        true
    }

    fn run_pulse_check(&mut self, arm: Arm, profile: &MoveProfile) {
        self.steppers.run_pulse_check(arm, profile);
    }
}

/// The range lines' pins as the input buffers see them (IDR, not the output register): a
/// line shorted to a rail or a neighbour reads what it is, not what was written. The pins
/// of `crate::pins`: range 0 PB1, range 1 PB5, range 2 PA15.
fn range_lines_read() -> [bool; 3] {
    let high = |port: pac::gpio::Gpio, pin: usize| port.idr().read().idr(pin) == Idr::HIGH;
    [
        high(pac::GPIOB, 1),
        high(pac::GPIOB, 5),
        high(pac::GPIOA, 15),
    ]
}

impl Diagnostics for BoardHardware {
    fn clocks(&self) -> MeasuredClocks {
        self.boot.clocks
    }

    fn worst_step_late_us(&self) -> u32 {
        // One timer tick is 1 µs (`crate::steppers`).
        Arm::BOTH
            .map(|arm| self.steppers.worst_late_ticks(arm))
            .into_iter()
            .max()
            .unwrap_or(0)
    }

    fn longest_interrupts_off_us(&self) -> Option<u32> {
        Some(crate::timing::longest_interrupts_off_us())
    }

    fn stack_use(&self) -> Option<StackUse> {
        let (used_bytes, size_bytes) = crate::stack::use_bytes();
        Some(StackUse {
            used_bytes,
            size_bytes,
        })
    }

    fn range_read_back(&self) -> Option<u8> {
        let lines = range_lines_read();
        let mut high = (0u8..).zip(lines).filter(|&(_, on)| on);
        Some(match (high.next(), high.next()) {
            (Some((range, _)), None) => range,
            _ => u8::MAX,
        })
    }

    fn resets_since_power_on(&self) -> Option<ResetCounts> {
        Some(self.boot.resets)
    }
}

impl Detector for BoardHardware {
    fn select_range(&mut self, range: u8) {
        // One-hot, make before break: the new range's feedback resistor is connected before
        // the old one is disconnected, so the amplifier is never without feedback (it would
        // slew to a rail); the library's `switch_range_lines` has the order and its test.
        let lines = &mut self.range;
        let switched = detector::switch_range_lines(
            lines.len(),
            usize::from(range),
            |line, connect| lines[line].set_level(connect.into()),
            || cortex_m::asm::delay(RANGE_OVERLAP_US * (crate::SYSCLK_HZ / 1_000_000)),
        );
        if !switched {
            warn!("range {}: no such range line, range unchanged", range);
        }
        // Samples from before the switch belong to no reading (the library discards them
        // too); dropping them here keeps a full ring between readings, when nobody drains,
        // from counting as a loss (an ADC overrun still does: firmware::sampling).
        self.adc.clear();
    }

    fn drain_samples(&mut self, sink: &mut dyn FnMut(Sample)) -> Result<(), SampleLoss> {
        self.adc.drain(sink)
    }

    fn take_sample_fault(&mut self) -> Option<SampleLoss> {
        self.adc.take_fault()
    }
}

impl Lamp for BoardHardware {
    fn set_lamp(&mut self, on: bool) {
        self.lamp.set_level(on.into());
    }
}
