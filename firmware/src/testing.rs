//! Hardware models on virtual time, for the library's tests and for the simulator.
//!
//! Arms follow the profiles they are given exactly (a perfect step generator), with their
//! true angle offset from the step count by an unknown amount until homed; home switches
//! press at the configured angle. The detector samples once per block period (1 kHz):
//! dark offset plus, with the lamp on, a [`Scene`]'s signal at the arms' true angles at the
//! sample's time, times the range gain, plus deterministic noise, clipped at full scale;
//! each sample is stamped with the detector arm's step count at its time. The amplifier's
//! settling after a range switch can be made visible ([`FakeHardware::settling_counts`]).
//! Faults (a missing or stuck switch, a driver fault, a dead ADC,
//! lost samples, a late step interrupt, lost steps) can be injected, and a fault handler's
//! safe stop ([`crate::fault::SafeOutputs`]) applied. Nothing here is linked into the
//! board firmware.

use crate::config::InstrumentConfig;
use crate::fault::SafeOutputs;
use crate::hardware::{Arm, Arms, Detector, Diagnostics, Lamp, MeasuredClocks, Sample, StackUse};
use crate::motion::MoveProfile;
use crate::sampling::SampleLoss;
use libm::sqrtf;
use protocol::{Angle, DetectorRange, Geometry};

/// The modelled board's crystal and core clock, Hz (the reference Black Pill's).
const MODEL_HSE_HZ: u32 = 25_000_000;
const MODEL_SYSCLK_HZ: u32 = 96_000_000;

/// What the detector sees with the lamp on.
pub trait Scene {
    /// Signal in counts on the most sensitive range (dark offset excluded) with the arms
    /// at these true angles, degrees.
    fn signal_counts(&self, theta_i_deg: f32, theta_r_deg: f32) -> f32;
}

/// The same signal at every geometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConstantScene(pub f32);

impl Scene for ConstantScene {
    fn signal_counts(&self, _theta_i_deg: f32, _theta_r_deg: f32) -> f32 {
        self.0
    }
}

impl<F: Fn(f32, f32) -> f32> Scene for F {
    fn signal_counts(&self, theta_i_deg: f32, theta_r_deg: f32) -> f32 {
        self(theta_i_deg, theta_r_deg)
    }
}

/// One modelled arm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FakeArm {
    steps: i32,
    /// True angle in ticks = steps + offset (unknown to the firmware until it homes).
    offset_steps: i32,
    running: Option<(MoveProfile, u64)>,
    /// The last profile and its start, kept after it ends: where the arm was at a time
    /// before now (a sample's stamp). `None` after the count was redefined or the arm was
    /// stopped dead.
    last: Option<(MoveProfile, u64)>,
    /// The switch never presses (broken wire).
    pub switch_missing: bool,
    /// The switch stays pressed (welded, stuck lever).
    pub switch_stuck: bool,
    /// The driver reports a fault (DIAG high): latched, as a TMC2209 does, until the
    /// driver is disabled.
    pub driver_fault: bool,
    /// The cause of the fault is still there (a shorted coil, a driver still too hot):
    /// DIAG is high again whenever the driver is enabled.
    pub driver_fault_persists: bool,
    /// The DIAG line reads a fault whatever the driver does (a wiring fault, a dead or
    /// missing driver module with a pull-up): no EN cycle clears it.
    pub diag_stuck: bool,
    /// The step interrupt ran late once (taken by the next `take_step_fault`).
    pub step_late: bool,
    /// The driver is enabled (from the first move, or when the library enables it, until
    /// the library or a fault handler disables it).
    pub driver_enabled: bool,
    /// How many times the driver was disabled by the library.
    pub driver_disables: u32,
    /// Lowest and highest true angle reached, ticks.
    pub travel_ticks: (i32, i32),
    /// The running profile is a pulse check: pulses counted, driver disabled, no motion.
    pulses_only: bool,
}

impl FakeArm {
    fn at(true_angle: Angle) -> FakeArm {
        let ticks = true_angle.ticks();
        FakeArm {
            steps: 0,
            offset_steps: ticks,
            running: None,
            last: None,
            switch_missing: false,
            switch_stuck: false,
            driver_fault: false,
            driver_fault_persists: false,
            diag_stuck: false,
            step_late: false,
            driver_enabled: false,
            driver_disables: 0,
            travel_ticks: (ticks, ticks),
            pulses_only: false,
        }
    }

    /// True angle, ticks.
    pub fn true_ticks(&self) -> i32 {
        self.steps + self.offset_steps
    }

    /// Whether its step timer runs (a profile is being stepped).
    pub fn step_timer_running(&self) -> bool {
        self.running.is_some()
    }

    /// The step count at `t_us` (at or before the last `advance_to`): from the last
    /// profile (its start before it began: the arm was arriving there).
    pub fn steps_at(&self, t_us: u64) -> i32 {
        match self.last {
            Some((profile, started_us)) => profile.position_at(t_us.saturating_sub(started_us)),
            None => self.steps,
        }
    }
}

/// Fake arms, detector and lamp on a virtual clock that the test advances.
#[derive(Clone, Debug)]
pub struct FakeHardware<S: Scene> {
    now_us: u64,
    /// The arms, source first.
    pub arms: [FakeArm; 2],
    switch_ticks: i32,
    lamp_on: bool,
    range: u8,
    /// When the range was last selected.
    range_selected_us: u64,
    ranges: &'static [DetectorRange],
    sample_period_us: u64,
    /// Dark offset, counts.
    pub dark_counts: f32,
    /// Standard deviation of the sample noise, counts.
    pub noise_counts: f32,
    next_sample_us: u64,
    rng: u32,
    /// What the detector sees.
    pub scene: S,
    /// The ADC delivers nothing.
    pub detector_dead: bool,
    /// Samples were lost (taken by the next drain or fault check, which reports it).
    pub sample_loss: Option<SampleLoss>,
    /// Profiles handed to the step generators so far (both arms).
    pub profiles_started: u32,
    /// Profiles started whose speed or acceleration broke the configured limits.
    pub profiles_over_limits: u32,
    /// `Some(counts)`: a sample whose block overlaps the settling time of the range just
    /// selected (its [`DetectorRange::settle_us`] after the switch) reads `counts`, the
    /// amplifier's transient made obvious: no sweep bin may contain one.
    pub settling_counts: Option<u32>,
    /// Every range selected, with its time (the tests' record of the switches).
    pub range_log: heapless::Vec<(u64, u8), 64>,
    /// What the board's boot measured of its clocks (exact by default: the model's own).
    pub clocks: MeasuredClocks,
    /// The step timers' true tick over their nominal one: a pulse check's profile takes
    /// its duration × this (1: exact).
    pub step_timer_scale: f32,
    /// The latest a step interrupt ran, µs (a board's record; 0: a perfect generator).
    pub worst_step_late_us: u32,
    /// The longest interrupt-off section, µs (`None`: the model has no interrupts).
    pub longest_interrupts_off_us: Option<u32>,
    /// The stack's use (`None`: the model has no stack to paint).
    pub stack_use: Option<StackUse>,
    /// The range lines read back this instead of the range selected (a shorted or open
    /// select line).
    pub range_lines_read: Option<u8>,
    /// The resets since power-on (none by default: the model was just switched on).
    pub resets: protocol::ResetCounts,
    max_speed: f32,
    accel: f32,
}

impl<S: Scene> FakeHardware<S> {
    /// The reference hardware, arms standing at these true angles (unknown to the firmware).
    pub fn new(config: &InstrumentConfig, scene: S, true_position: Geometry) -> FakeHardware<S> {
        FakeHardware {
            now_us: 0,
            arms: [
                FakeArm::at(true_position.theta_i),
                FakeArm::at(true_position.theta_r),
            ],
            switch_ticks: config.home_switch.ticks(),
            lamp_on: false,
            range: 0,
            range_selected_us: 0,
            ranges: config.detector_ranges,
            sample_period_us: u64::from(config.detector_block_us.max(1)),
            // the reference instrument: dark ≈ 0.3 % and read noise 0.02 % of full scale.
            dark_counts: 0.003 * 65_535.0,
            noise_counts: 0.0002 * 65_535.0,
            next_sample_us: u64::from(config.detector_block_us.max(1)),
            rng: 0x2545_f491,
            scene,
            detector_dead: false,
            sample_loss: None,
            profiles_started: 0,
            profiles_over_limits: 0,
            settling_counts: None,
            range_log: heapless::Vec::new(),
            clocks: MeasuredClocks {
                hse_expected_hz: MODEL_HSE_HZ,
                hse_measured_hz: Some(MODEL_HSE_HZ),
                sysclk_expected_hz: MODEL_SYSCLK_HZ,
                sysclk_measured_hz: Some(MODEL_SYSCLK_HZ),
            },
            step_timer_scale: 1.0,
            worst_step_late_us: 0,
            longest_interrupts_off_us: None,
            stack_use: None,
            range_lines_read: None,
            resets: protocol::ResetCounts::default(),
            max_speed: crate::motion::deg_to_steps(config.max_speed_deg_per_s),
            accel: crate::motion::deg_to_steps(config.accel_deg_per_s2),
        }
    }

    /// Advance virtual time: the arms follow their profiles.
    pub fn advance_to(&mut self, now_us: u64) {
        self.now_us = now_us.max(self.now_us);
        for arm in &mut self.arms {
            if let Some((profile, started_us)) = arm.running {
                let real_us = self.now_us - started_us;
                let elapsed = if arm.pulses_only {
                    // The step timer's own pace; the pulses move nothing.
                    (real_us as f64 / f64::from(self.step_timer_scale.max(1e-3))) as u64
                } else {
                    real_us
                };
                let before = arm.steps;
                arm.steps = profile.position_at(elapsed);
                if arm.pulses_only {
                    arm.offset_steps -= arm.steps - before;
                }
                if elapsed >= profile.duration_us() {
                    arm.running = None;
                    arm.pulses_only = false;
                }
                let t = arm.true_ticks();
                arm.travel_ticks = (arm.travel_ticks.0.min(t), arm.travel_ticks.1.max(t));
            }
        }
    }

    /// The arms' true angles.
    pub fn true_geometry(&self) -> Geometry {
        Geometry::new(
            Angle::from_ticks(self.arms[0].true_ticks()),
            Angle::from_ticks(self.arms[1].true_ticks()),
        )
    }

    /// The arms' true angles at `t_us` (at or before now; see [`FakeArm::steps_at`]).
    pub fn true_geometry_at(&self, t_us: u64) -> Geometry {
        let [i, r] = self.arms.map(|arm| arm.steps_at(t_us) + arm.offset_steps);
        Geometry::new(Angle::from_ticks(i), Angle::from_ticks(r))
    }

    /// Virtual time now, µs.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// The arm slipped: its true angle falls behind its step count by `steps`.
    pub fn lose_steps(&mut self, arm: Arm, steps: i32) {
        self.arms[arm.index()].offset_steps -= steps;
    }

    /// Whether the lamp is on.
    pub fn lamp_on(&self) -> bool {
        self.lamp_on
    }

    /// The range selected.
    pub fn range(&self) -> u8 {
        self.range
    }

    fn noise(&mut self) -> f32 {
        // xorshift32; the sum of four uniforms is close enough to normal for a test.
        let mut sum = 0.0;
        for _ in 0..4 {
            self.rng ^= self.rng << 13;
            self.rng ^= self.rng >> 17;
            self.rng ^= self.rng << 5;
            sum += self.rng as f32 / u32::MAX as f32 - 0.5;
        }
        // Variance of the sum: 4/12.
        sum * sqrtf(3.0) * self.noise_counts
    }
}

impl<S: Scene> Arms for FakeHardware<S> {
    fn run_profile(&mut self, arm: Arm, profile: &MoveProfile) {
        let limits_ok = profile.peak_speed() <= self.max_speed * 1.0001
            && profile.accel() <= self.accel * 1.0001;
        self.profiles_over_limits += u32::from(!limits_ok);
        self.profiles_started += 1;
        let arm = &mut self.arms[arm.index()];
        assert_eq!(
            profile.start_steps(),
            arm.steps,
            "a profile must start where the arm is"
        );
        if profile.step_count() == 0 {
            // Ends what runs (the arm stops where it is: a perfect step generator).
            arm.running = None;
            arm.last = None;
            return;
        }
        arm.driver_enabled = true;
        arm.pulses_only = false;
        arm.running = Some((*profile, self.now_us));
        arm.last = arm.running;
    }

    fn run_pulse_check(&mut self, arm: Arm, profile: &MoveProfile) {
        let arm = &mut self.arms[arm.index()];
        assert_eq!(
            profile.start_steps(),
            arm.steps,
            "a pulse check starts where the count is"
        );
        // Nothing moves: the true angle stays where it is whatever the count does.
        arm.pulses_only = true;
        arm.running = Some((*profile, self.now_us));
        arm.last = None;
    }

    fn position_steps(&self, arm: Arm) -> i32 {
        self.arms[arm.index()].steps
    }

    fn is_moving(&self, arm: Arm) -> bool {
        self.arms[arm.index()].running.is_some()
    }

    fn set_position_steps(&mut self, arm: Arm, steps: i32) {
        let arm = &mut self.arms[arm.index()];
        arm.offset_steps += arm.steps - steps;
        arm.steps = steps;
        arm.last = None;
    }

    fn home_switch_pressed(&self, arm: Arm) -> bool {
        let arm = &self.arms[arm.index()];
        !arm.switch_missing && (arm.switch_stuck || arm.true_ticks() >= self.switch_ticks)
    }

    fn driver_fault(&self, arm: Arm) -> bool {
        let arm = &self.arms[arm.index()];
        arm.diag_stuck || arm.driver_fault || (arm.driver_enabled && arm.driver_fault_persists)
    }

    fn set_driver_enabled(&mut self, arm: Arm, enabled: bool) {
        let arm = &mut self.arms[arm.index()];
        if !enabled {
            // EN high resets the latch; a cause still there sets it again on enabling.
            arm.driver_fault = false;
            arm.driver_disables += 1;
        }
        arm.driver_enabled = enabled;
    }

    fn take_step_fault(&mut self, arm: Arm) -> bool {
        core::mem::take(&mut self.arms[arm.index()].step_late)
    }
}

impl<S: Scene> Detector for FakeHardware<S> {
    fn select_range(&mut self, range: u8) {
        self.range = range;
        self.range_selected_us = self.now_us;
        if self.range_log.is_full() {
            self.range_log.remove(0);
        }
        let _ = self.range_log.push((self.now_us, range));
    }

    fn drain_samples(&mut self, sink: &mut dyn FnMut(Sample)) -> Result<(), SampleLoss> {
        let range = self.ranges[usize::from(self.range)];
        let settled_us = self.range_selected_us + u64::from(range.settle_us);
        while self.next_sample_us <= self.now_us {
            let at_us = self.next_sample_us;
            self.next_sample_us += self.sample_period_us;
            if self.detector_dead {
                continue;
            }
            let geometry = self.true_geometry_at(at_us);
            let signal = if self.lamp_on {
                self.scene
                    .signal_counts(geometry.theta_i.deg() as f32, geometry.theta_r.deg() as f32)
                    * range.relative_gain
            } else {
                0.0
            };
            let counts = self.dark_counts + signal + self.noise();
            let counts = match self.settling_counts {
                // The block ended after the switch and began before the amplifier settled.
                Some(transient)
                    if at_us > self.range_selected_us
                        && at_us - self.sample_period_us < settled_us =>
                {
                    transient
                }
                _ => counts.clamp(0.0, range.full_scale_counts as f32) as u32,
            };
            sink(Sample {
                counts,
                detector_steps: self.arms[Arm::Detector.index()].steps_at(at_us),
            });
        }
        match self.sample_loss.take() {
            Some(loss) => Err(loss),
            None => Ok(()),
        }
    }

    fn take_sample_fault(&mut self) -> Option<SampleLoss> {
        self.sample_loss
            .take_if(|loss| *loss != SampleLoss::RingFull)
    }
}

impl<S: Scene> Diagnostics for FakeHardware<S> {
    fn clocks(&self) -> MeasuredClocks {
        self.clocks
    }

    fn worst_step_late_us(&self) -> u32 {
        self.worst_step_late_us
    }

    fn longest_interrupts_off_us(&self) -> Option<u32> {
        self.longest_interrupts_off_us
    }

    fn stack_use(&self) -> Option<StackUse> {
        self.stack_use
    }

    fn range_read_back(&self) -> Option<u8> {
        Some(self.range_lines_read.unwrap_or(self.range))
    }

    fn resets_since_power_on(&self) -> Option<protocol::ResetCounts> {
        Some(self.resets)
    }
}

impl<S: Scene> Lamp for FakeHardware<S> {
    fn set_lamp(&mut self, on: bool) {
        self.lamp_on = on;
    }
}

/// What a fault handler does to the board's outputs, done to the models: the arms stop
/// dead where they are, the drivers are disabled, the lamp goes off.
impl<S: Scene> SafeOutputs for FakeHardware<S> {
    fn stop_step_timers(&mut self) {
        let now_us = self.now_us;
        self.advance_to(now_us);
        for arm in &mut self.arms {
            arm.running = None;
            arm.last = None;
        }
    }

    fn disable_drivers(&mut self) {
        for arm in &mut self.arms {
            arm.driver_enabled = false;
        }
    }

    fn lamp_off(&mut self) {
        self.lamp_on = false;
    }
}
