//! The self-test ([`protocol::Command::SelfTest`]): what a builder runs before a first
//! motion and a lab before a case. It measures; the host judges (`gonio selftest` holds
//! the limits), so a limit can change without a firmware release.
//!
//! What it does, in about 1.3 s at the reference limits:
//! - the lamp off and both drivers disabled (EN high): the arms hold no torque and no
//!   pulse moves them, so the test is safe on a board with its belts on, before any homing;
//! - each arm's step generator runs [`protocol::SELF_TEST_PULSE_STEPS`] at the speed and
//!   acceleration limits ([`crate::hardware::Arms::run_pulse_check`]): the steps it
//!   counted against the profile's, and the time it took by the device clock against the
//!   profile's duration (the step timer's clock against the one the device runs on);
//! - the detector's blocks counted over the same time against the block period (the ADC's
//!   pace), and any sample loss;
//! - read back: the clocks measured at boot, the worst step-interrupt lateness and the
//!   longest interrupt-off section since boot, the stack's high-water mark
//!   ([`crate::hardware::Diagnostics`]), the home switches, the drivers' fault outputs (with
//!   the drivers disabled, where a TMC2209's latched DIAG is released: what stays is a
//!   wiring fault), the range lines.
//!
//! Afterwards the step counts are put back where they were, the drivers stay disabled and
//! the arms count as not homed: an arm without torque may have moved (a belt's tension,
//! a hand), so the next `Home` searches for the switches.

use crate::config::InstrumentConfig;
use crate::hardware::{Arm, Hardware};
use crate::motion::{deg_to_steps, plan_move};
use crate::stepgen::{LATE_MARGIN_TICKS, MIN_SEGMENT_TICKS};
use protocol::{PulseCheck, SELF_TEST_PULSE_STEPS, SelfTestReport};

/// A self-test under way.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SelfTestRun {
    started_us: u64,
    /// The step counts before the pulse check, put back after it.
    start_steps: [i32; 2],
    expected: [PulseCheck; 2],
    /// When each arm's generator was first seen at rest.
    ended_us: [Option<u64>; 2],
    blocks: u32,
    sample_losses: u16,
}

/// The range the self-test selects and reads back: the most sensitive, where the
/// instrument rests (any would do; the line of each range is one GPIO).
const RANGE_CHECKED: u8 = 0;

impl SelfTestRun {
    /// Start the pulse checks: lamp off, both drivers disabled, each arm's generator on a
    /// profile of [`SELF_TEST_PULSE_STEPS`] at the limits. Samples taken before now are
    /// dropped (the block count starts here). The arms must be at rest.
    pub fn start(hardware: &mut impl Hardware, config: &InstrumentConfig, now_us: u64) -> Self {
        hardware.set_lamp(false);
        hardware.select_range(RANGE_CHECKED);
        let _ = hardware.drain_samples(&mut |_| {});
        let start_steps = Arm::BOTH.map(|arm| hardware.position_steps(arm));
        let steps = i32::try_from(SELF_TEST_PULSE_STEPS).unwrap_or(i32::MAX);
        // Forward from where each count stands; the counts are put back afterwards.
        let profiles = plan_move(
            start_steps,
            start_steps.map(|s| s.saturating_add(steps)),
            deg_to_steps(config.max_speed_deg_per_s),
            deg_to_steps(config.accel_deg_per_s2),
        );
        for arm in Arm::BOTH {
            hardware.set_driver_enabled(arm, false);
            hardware.run_pulse_check(arm, &profiles[arm.index()]);
        }
        let expected = profiles.map(|profile| PulseCheck {
            steps_expected: profile.step_count(),
            steps_counted: 0,
            duration_expected_us: u32::try_from(profile.duration_us()).unwrap_or(u32::MAX),
            duration_measured_us: 0,
        });
        SelfTestRun {
            started_us: now_us,
            start_steps,
            expected,
            ended_us: [None; 2],
            blocks: 0,
            sample_losses: 0,
        }
    }

    /// Advance to `now_us`: count the blocks, note each generator's end. Once both are at
    /// rest, put the step counts back and return the report.
    pub fn poll(
        &mut self,
        hardware: &mut impl Hardware,
        config: &InstrumentConfig,
        now_us: u64,
    ) -> Option<SelfTestReport> {
        let mut blocks = 0u32;
        if hardware.drain_samples(&mut |_| blocks += 1).is_err() {
            self.sample_losses = self.sample_losses.saturating_add(1);
        }
        self.blocks = self.blocks.saturating_add(blocks);
        for arm in Arm::BOTH {
            if self.ended_us[arm.index()].is_none() && !hardware.is_moving(arm) {
                self.ended_us[arm.index()] = Some(now_us);
            }
        }
        let [Some(end_i), Some(end_r)] = self.ended_us else {
            return None;
        };
        let pulses = [(Arm::Source, end_i), (Arm::Detector, end_r)].map(|(arm, end_us)| {
            let counted = hardware
                .position_steps(arm)
                .wrapping_sub(self.start_steps[arm.index()]);
            hardware.set_position_steps(arm, self.start_steps[arm.index()]);
            PulseCheck {
                steps_counted: counted.unsigned_abs(),
                duration_measured_us: u32::try_from(end_us.saturating_sub(self.started_us))
                    .unwrap_or(u32::MAX),
                ..self.expected[arm.index()]
            }
        });
        let elapsed_us = now_us.saturating_sub(self.started_us);
        let clocks = hardware.clocks();
        let stack = hardware.stack_use();
        let [pulses_source, pulses_detector] = pulses;
        Some(SelfTestReport {
            hse_expected_hz: clocks.hse_expected_hz,
            hse_measured_hz: clocks.hse_measured_hz,
            sysclk_expected_hz: clocks.sysclk_expected_hz,
            sysclk_measured_hz: clocks.sysclk_measured_hz,
            pulses_source,
            pulses_detector,
            blocks_expected: u32::try_from(elapsed_us / u64::from(config.detector_block_us.max(1)))
                .unwrap_or(u32::MAX),
            blocks_counted: self.blocks,
            sample_losses: self.sample_losses,
            worst_step_late_us: hardware.worst_step_late_us(),
            step_deadline_us: step_deadline_us(),
            longest_interrupts_off_us: hardware.longest_interrupts_off_us(),
            stack_used_bytes: stack.map(|s| s.used_bytes),
            stack_size_bytes: stack.map_or(0, |s| s.size_bytes),
            switch_source: hardware.home_switch_pressed(Arm::Source),
            switch_detector: hardware.home_switch_pressed(Arm::Detector),
            driver_fault_source: hardware.driver_fault(Arm::Source),
            driver_fault_detector: hardware.driver_fault(Arm::Detector),
            range_selected: RANGE_CHECKED,
            range_read_back: hardware.range_read_back(),
            resets_since_power_on: hardware.resets_since_power_on(),
        })
    }

    /// Stop the pulse checks where they are (an abort, a fail-safe stop) and put the step
    /// counts back: the drivers were disabled, nothing moved.
    pub fn cancel(&self, hardware: &mut impl Hardware) {
        for arm in Arm::BOTH {
            let here = hardware.position_steps(arm);
            hardware.run_profile(arm, &crate::motion::MoveProfile::rest(here));
            hardware.set_position_steps(arm, self.start_steps[arm.index()]);
        }
    }
}

/// The step interrupt's deadline in the shortest segment the generator makes, µs (a tick
/// is 1 µs): lateness from there on stops the arm ([`crate::stepgen`]).
pub const fn step_deadline_us() -> u32 {
    MIN_SEGMENT_TICKS - LATE_MARGIN_TICKS
}
