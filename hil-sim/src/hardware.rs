//! The instrument's hardware as the firmware library sees it, simulated.
//!
//! Mechanics (steppers that follow the firmware's own motion profiles, home switches,
//! driver faults, lost steps, the lamp switch) are the firmware's model,
//! [`firmware::testing::FakeHardware`], so there is one arm model. The detector is this
//! crate's physics ([`crate::detector`]): the scene on the port seen through the
//! acceptance, lamp drift, range gains, noise and saturation, sample by sample.

use crate::detector::{Detector, DetectorParams};
use crate::scene::{SamplePort, Scene};
use firmware::config::InstrumentConfig;
use firmware::hardware::{Arm, Arms, Detector as DetectorTrait, Lamp, Sample};
use firmware::motion::MoveProfile;
use firmware::sampling::SampleLoss;
use firmware::testing::{ConstantScene, FakeHardware};
use protocol::{Geometry, Target};

/// Simulated arms, lamp and detector on virtual time.
pub struct SimHardware {
    /// Arms, switches and lamp (its own detector model is not used).
    mechanics: FakeHardware<ConstantScene>,
    detector: Detector,
    port: SamplePort,
    /// What the operator has on the port now.
    target: Target,
    /// The spot of the sample under the beam (counts from 0).
    spot: u32,
    /// Seed of the run: the spots' scenes come from it.
    seed: u64,
    /// θr zero error: the detector's true angle is the one the firmware believes plus this.
    theta_r_offset_deg: f64,
    range: u8,
    now_us: u64,
    next_sample_us: u64,
    /// Radiance factor seen at the last (geometry, target, spot), reused while the arms
    /// stand.
    seen: Option<(Geometry, Target, u32, f64)>,
}

impl SimHardware {
    /// Hardware of `config` with the arms standing at `start` (unknown to the firmware
    /// until it homes), the detector drawing its noise from `seed`.
    pub fn new(config: &InstrumentConfig, port: SamplePort, detector: DetectorParams, seed: u64, start: Geometry) -> SimHardware {
        let detector = Detector::new(detector, seed);
        let next_sample_us = detector.sample_period_us();
        SimHardware {
            mechanics: FakeHardware::new(config, ConstantScene(0.0), start),
            detector,
            port,
            target: Target::Sample,
            spot: 0,
            seed,
            theta_r_offset_deg: 0.0,
            range: 0,
            now_us: 0,
            next_sample_us,
            seen: None,
        }
    }

    /// Advance virtual time: the arms follow their profiles.
    pub fn advance_to(&mut self, now_us: u64) {
        self.now_us = self.now_us.max(now_us);
        self.mechanics.advance_to(self.now_us);
    }

    /// A detector arm whose true angle is the believed one plus `deg` (a zero error).
    pub fn set_theta_r_offset_deg(&mut self, deg: f64) {
        self.theta_r_offset_deg = deg;
        self.seen = None;
    }

    /// The operator puts `target` on the sample port. The sample going back on after the
    /// white tile lands on another spot of it: nobody puts a sheet back to the fibre.
    pub fn place(&mut self, target: Target) {
        if self.target == Target::WhiteReference && target == Target::Sample {
            self.next_spot();
        }
        self.target = target;
    }

    /// The sample moves to its next spot (an operator shifting the sheet).
    pub fn next_spot(&mut self) {
        self.spot += 1;
        if let Some(spots) = &self.port.spots {
            self.port.sample = spots.spot(self.seed, self.spot);
        }
        self.seen = None;
    }

    /// The spot under the beam (0 the first).
    pub fn spot(&self) -> u32 {
        self.spot
    }

    /// What the port holds: the sample at its current spot and the white tile.
    pub fn port(&self) -> &SamplePort {
        &self.port
    }

    /// What is on the sample port.
    pub fn target(&self) -> Target {
        self.target
    }

    /// The mechanics, to read true angles or inject faults.
    pub fn mechanics(&self) -> &FakeHardware<ConstantScene> {
        &self.mechanics
    }

    /// The mechanics, to inject faults (lost steps, a switch that never triggers).
    pub fn mechanics_mut(&mut self) -> &mut FakeHardware<ConstantScene> {
        &mut self.mechanics
    }

    /// The detector model.
    pub fn detector(&self) -> &Detector {
        &self.detector
    }

    /// The radiance factor the detector sees now (the port's scene through the acceptance,
    /// at the detector's true angle).
    pub fn seen_radiance_factor(&mut self) -> f64 {
        let geometry = self.mechanics.true_geometry();
        if let Some((g, t, spot, value)) = self.seen {
            if g == geometry && t == self.target && spot == self.spot {
                return value;
            }
        }
        let scene: &dyn Scene = match self.target {
            Target::Sample => self.port.sample.as_ref(),
            Target::WhiteReference => &self.port.white,
        };
        let theta_r = geometry.theta_r.deg() + self.theta_r_offset_deg;
        let value = self.detector.seen_radiance_factor(scene, geometry.theta_i.deg(), theta_r);
        self.seen = Some((geometry, self.target, self.spot, value));
        value
    }
}

impl Arms for SimHardware {
    fn run_profile(&mut self, arm: Arm, profile: &MoveProfile) {
        self.mechanics.run_profile(arm, profile);
    }

    fn position_steps(&self, arm: Arm) -> i32 {
        self.mechanics.position_steps(arm)
    }

    fn is_moving(&self, arm: Arm) -> bool {
        self.mechanics.is_moving(arm)
    }

    fn set_position_steps(&mut self, arm: Arm, steps: i32) {
        self.mechanics.set_position_steps(arm, steps);
    }

    fn home_switch_pressed(&self, arm: Arm) -> bool {
        self.mechanics.home_switch_pressed(arm)
    }

    fn driver_fault(&self, arm: Arm) -> bool {
        self.mechanics.driver_fault(arm)
    }

    fn take_step_fault(&mut self, arm: Arm) -> bool {
        // The simulated step generator is perfect, unless a test made it late.
        self.mechanics.take_step_fault(arm)
    }
}

impl Lamp for SimHardware {
    fn set_lamp(&mut self, on: bool) {
        self.mechanics.set_lamp(on);
    }
}

impl DetectorTrait for SimHardware {
    fn select_range(&mut self, range: u8) {
        self.range = range;
    }

    fn drain_samples(&mut self, sink: &mut dyn FnMut(Sample)) -> Result<(), SampleLoss> {
        // Losses injected into the mechanics' model are reported here too.
        let injected = self.mechanics.sample_loss.take();
        if self.next_sample_us > self.now_us {
            return injected.map_or(Ok(()), Err);
        }
        let signal = if self.mechanics.lamp_on() {
            let radiance_factor = self.seen_radiance_factor();
            let theta_i = self.mechanics.true_geometry().theta_i.deg();
            let lamp = self.detector.lamp_output(self.now_us as f64 * 1e-6);
            self.detector.signal_counts(radiance_factor, theta_i, usize::from(self.range), lamp)
        } else {
            0.0
        };
        let period = self.detector.sample_period_us();
        while self.next_sample_us <= self.now_us {
            let detector_steps = self.mechanics.arms[Arm::Detector.index()].steps_at(self.next_sample_us);
            self.next_sample_us += period;
            sink(Sample { counts: self.detector.sample(signal), detector_steps });
        }
        injected.map_or(Ok(()), Err)
    }

    fn take_sample_fault(&mut self) -> Option<SampleLoss> {
        self.mechanics.take_sample_fault()
    }
}
