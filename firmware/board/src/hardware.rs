//! The board's side of the firmware library's hardware traits ([`firmware::Arms`],
//! [`firmware::Detector`], [`firmware::Lamp`]): it acts and reports, it decides nothing.
//!
//! Wired now: home switches, driver DIAG inputs, the lamp and the TIA range lines.
//! Not yet (a later issue): the timer step generators and ADC sampling. Until then the
//! arms report that they do not move and the detector reports no samples, so the
//! library refuses or fails moves and readings by its own rules (a move that does not
//! arrive, a reading without samples: hardware fault) instead of the board pretending.

use defmt::warn;
use embassy_stm32::gpio::{Input, Output};
use firmware::motion::MoveProfile;
use firmware::{Arm, Arms, Detector, Lamp};

/// The instrument as the firmware library sees it.
pub struct BoardHardware {
    home: [Input<'static>; 2],
    diag: [Input<'static>; 2],
    lamp: Output<'static>,
    range: [Output<'static>; 3],
    /// Step counts: with no step generator yet, they change only by `set_position_steps`.
    steps: [i32; 2],
}

impl BoardHardware {
    /// From the pins of [`crate::pins`], already in their idle state.
    pub fn new(
        home: [Input<'static>; 2],
        diag: [Input<'static>; 2],
        lamp: Output<'static>,
        range: [Output<'static>; 3],
    ) -> Self {
        BoardHardware {
            home,
            diag,
            lamp,
            range,
            steps: [0; 2],
        }
    }
}

impl Arms for BoardHardware {
    fn run_profile(&mut self, arm: Arm, _profile: &MoveProfile) {
        warn!(
            "{}: no step generator in this firmware build; the arm does not move",
            arm
        );
    }

    fn position_steps(&self, arm: Arm) -> i32 {
        self.steps[arm.index()]
    }

    fn is_moving(&self, _arm: Arm) -> bool {
        false
    }

    fn set_position_steps(&mut self, arm: Arm, steps: i32) {
        self.steps[arm.index()] = steps;
    }

    fn home_switch_pressed(&self, arm: Arm) -> bool {
        self.home[arm.index()].is_low()
    }

    fn driver_fault(&self, arm: Arm) -> bool {
        self.diag[arm.index()].is_high()
    }
}

impl Detector for BoardHardware {
    fn select_range(&mut self, range: u8) {
        // One-hot: exactly one feedback resistor switched in.
        for (index, line) in self.range.iter_mut().enumerate() {
            line.set_level((index == usize::from(range)).into());
        }
    }

    fn drain_samples(&mut self, _sink: &mut dyn FnMut(u32)) {
        // No ADC sampling in this firmware build.
    }
}

impl Lamp for BoardHardware {
    fn set_lamp(&mut self, on: bool) {
        self.lamp.set_level(on.into());
    }
}
