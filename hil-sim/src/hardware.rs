//! The instrument's hardware as the firmware library sees it, simulated.
//!
//! Mechanics (steppers that follow the firmware's own motion profiles, home switches,
//! driver faults, lost steps, the lamp switch) are the firmware's model,
//! [`firmware::testing::FakeHardware`], so there is one arm model. The detector is this
//! crate's physics ([`crate::detector`], [`crate::amplifier`]): the scene on the port seen
//! through the detector's angular response (a mirror's beam as that response itself), lamp
//! drift, range gains, the amplifier's response, noise and saturation, block by block.
//!
//! A BLOCK (one detector sample, [`Detector::sample_period_us`]) reads the amplifier's
//! output averaged over the block, which is what the board's decimation makes of its 256
//! conversions. The input over the block is what the detector truly sees while the arms go
//! where the mechanics put them: the arms stand on a microstep between two step pulses
//! ([`firmware::testing::FakeArm::steps_at`]), so the input is piecewise constant in time,
//! one piece per geometry the block visits (one piece at rest; about five at 60 °/s), and
//! the amplifier's first-order response is solved exactly over each piece
//! ([`crate::amplifier::respond`]), its state carried from block to block. A piece's input
//! is the scene through the detector's response at that geometry; where a block crosses many
//! microsteps, the scene is evaluated at the ends and the middle of the block's path and
//! only further where it is not linear within [`INTERPOLATION_TOLERANCE_FRACTION`] of full
//! scale (a lobe narrow against the block's travel), else interpolated.
//!
//! Events between two drains (a range switch, the lamp, the operator changing what is on
//! the port, a new profile or a redefined step count) first bring the detector up to the
//! event's time, so every block reads what was there while it was taken, in order.
//!
//! At rest, once the amplifier has settled (its output equals its input exactly), a block
//! reads what it read before the amplifier was modelled, to the bit: the same radiance
//! factor, the same noise draw (one per block from the detector's stream), so point
//! readings taken standing keep their values.

use crate::amplifier::{self, Response};
use crate::detector::{Detector, DetectorParams};
use crate::scene::{SamplePort, Scene};
use firmware::config::InstrumentConfig;
use firmware::hardware::{
    Arm, Arms, Detector as DetectorTrait, Diagnostics, Lamp, MeasuredClocks, Sample, StackUse,
};
use firmware::motion::MoveProfile;
use firmware::sampling::SampleLoss;
use firmware::testing::{ConstantScene, FakeHardware};
use protocol::{DetectorRange, Geometry, Target};
use std::collections::VecDeque;

/// Where a block's path crosses several microsteps, the scene is taken as linear between
/// two evaluated points when the middle one is within this fraction of full scale of the
/// line through them (0.07 counts: below the ADC's rounding, ~1/2000 of one block's noise).
pub const INTERPOLATION_TOLERANCE_FRACTION: f64 = 1e-6;

/// Simulated arms, lamp and detector on virtual time.
pub struct SimHardware {
    /// Arms, switches and lamp (its own detector model is not used).
    mechanics: FakeHardware<ConstantScene>,
    detector: Detector,
    /// The instrument's ranges (their amplifier time constants).
    ranges: &'static [DetectorRange],
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
    /// The end of the block being taken.
    next_sample_us: u64,
    /// Radiance factor seen at the last (geometry, target, spot), reused while the arms
    /// stand.
    seen: Option<(Geometry, Target, u32, f64)>,
    /// Radiance factors seen at the last few geometries of the path (cleared when what is
    /// on the port changes): a block's end is the next block's start.
    seen_on_path: VecDeque<(Geometry, f64)>,
    /// The amplifier's output, counts above dark on the current range, with the lamp's
    /// drift factored out (it changes by 6e-10 per block: far too slow for τ to matter).
    amp_output: f64,
    /// The amplifier is recovering from a range switch until then, µs: output held.
    amp_hold_until_us: f64,
    /// The detector is simulated up to this time, µs.
    simulated_us: u64,
    /// The block being taken: the output's integral so far (counts·µs), time at the rail.
    block_integral: f64,
    block_rail_us: f64,
    /// The block has been at rest with the amplifier settled so far: the radiance factor
    /// and θi it saw (`None` once anything changed during it).
    block_steady: Option<(f64, f64)>,
    /// Blocks taken and not yet drained.
    pending: VecDeque<Sample>,
    /// Scratch: the pieces of constant geometry of the interval being simulated.
    pieces: Vec<Piece>,
}

/// A stretch of time on one geometry.
#[derive(Clone, Copy, Debug)]
struct Piece {
    geometry: Geometry,
    duration_us: u64,
    /// Microsteps travelled along the path from the interval's start (both arms).
    path: i64,
    /// The amplifier's input, counts (lamp drift factored out).
    input: f64,
}

impl SimHardware {
    /// Hardware of `config` with the arms standing at `start` (unknown to the firmware
    /// until it homes), the detector drawing its noise from `seed`.
    pub fn new(
        config: &InstrumentConfig,
        port: SamplePort,
        detector: DetectorParams,
        seed: u64,
        start: Geometry,
    ) -> SimHardware {
        let detector = Detector::new(detector, seed);
        let next_sample_us = detector.sample_period_us();
        SimHardware {
            mechanics: FakeHardware::new(config, ConstantScene(0.0), start),
            detector,
            ranges: config.detector_ranges,
            port,
            target: Target::Sample,
            spot: 0,
            seed,
            theta_r_offset_deg: 0.0,
            range: 0,
            now_us: 0,
            next_sample_us,
            seen: None,
            seen_on_path: VecDeque::new(),
            amp_output: 0.0,
            amp_hold_until_us: 0.0,
            simulated_us: 0,
            block_integral: 0.0,
            block_rail_us: 0.0,
            block_steady: None,
            pending: VecDeque::new(),
            pieces: Vec::new(),
        }
    }

    /// Advance virtual time: the arms follow their profiles.
    pub fn advance_to(&mut self, now_us: u64) {
        self.now_us = self.now_us.max(now_us);
        self.mechanics.advance_to(self.now_us);
    }

    /// A detector arm whose true angle is the believed one plus `deg` (a zero error).
    pub fn set_theta_r_offset_deg(&mut self, deg: f64) {
        self.simulate_detector();
        self.theta_r_offset_deg = deg;
        self.scene_changed();
    }

    /// The operator puts `target` on the sample port. The sample going back on after the
    /// white tile lands on another spot of it: nobody puts a sheet back to the fibre.
    pub fn place(&mut self, target: Target) {
        self.simulate_detector();
        if self.target == Target::WhiteReference && target == Target::Sample {
            self.next_spot();
        }
        if self.target != target {
            self.scene_changed();
        }
        self.target = target;
    }

    /// The sample moves to its next spot (an operator shifting the sheet).
    pub fn next_spot(&mut self) {
        self.simulate_detector();
        self.spot += 1;
        if let Some(spots) = &self.port.spots {
            self.port.sample = spots.spot(self.seed, self.spot);
        }
        self.scene_changed();
    }

    fn scene_changed(&mut self) {
        self.seen = None;
        self.seen_on_path.clear();
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

    /// The mechanics, to inject faults (lost steps, a switch that never triggers). The
    /// detector is brought up to now first: the fault happens now.
    pub fn mechanics_mut(&mut self) -> &mut FakeHardware<ConstantScene> {
        self.simulate_detector();
        self.seen_on_path.clear();
        &mut self.mechanics
    }

    /// The detector, to change (its noise stream: [`Detector::reseed_noise`]).
    pub fn detector_mut(&mut self) -> &mut Detector {
        &mut self.detector
    }

    /// The detector model.
    pub fn detector(&self) -> &Detector {
        &self.detector
    }

    /// The range selected.
    pub fn range(&self) -> u8 {
        self.range
    }

    /// The amplifier's output now, counts above dark on the current range (lamp drift
    /// factored out): what the blocks read, before noise.
    pub fn amplifier_output_counts(&mut self) -> f64 {
        self.simulate_detector();
        self.amp_output
    }

    fn scene(&self) -> &dyn Scene {
        match self.target {
            Target::Sample => self.port.sample.as_ref(),
            Target::WhiteReference => &self.port.white,
        }
    }

    /// The radiance factor the detector sees now (the port's scene through the detector's
    /// response, at the detector's true angle).
    pub fn seen_radiance_factor(&mut self) -> f64 {
        let geometry = self.mechanics.true_geometry();
        self.seen_at(geometry)
    }

    /// The radiance factor the detector sees with the arms truly at `geometry`.
    fn seen_at(&mut self, geometry: Geometry) -> f64 {
        if let Some((g, t, spot, value)) = self.seen {
            if g == geometry && t == self.target && spot == self.spot {
                return value;
            }
        }
        if let Some(&(_, value)) = self.seen_on_path.iter().find(|(g, _)| *g == geometry) {
            return value;
        }
        let theta_r = geometry.theta_r.deg() + self.theta_r_offset_deg;
        let value =
            self.detector
                .seen_radiance_factor(self.scene(), geometry.theta_i.deg(), theta_r);
        if self.mechanics.true_geometry() == geometry {
            self.seen = Some((geometry, self.target, self.spot, value));
        }
        if self.seen_on_path.len() == 4 {
            self.seen_on_path.pop_front();
        }
        self.seen_on_path.push_back((geometry, value));
        value
    }

    /// The amplifier's input at `geometry` on the current range, counts above dark (lamp
    /// drift factored out).
    fn input_at(&mut self, geometry: Geometry) -> f64 {
        if !self.mechanics.lamp_on() {
            return 0.0;
        }
        let radiance_factor = self.seen_at(geometry);
        self.detector.signal_counts(
            radiance_factor,
            geometry.theta_i.deg(),
            usize::from(self.range),
            1.0,
        )
    }

    /// The amplifier's output limit, counts above dark: where the ADC reads full scale.
    fn rail_counts(&self) -> f64 {
        self.detector.params().full_scale_counts - self.detector.dark_offset_counts()
    }

    fn time_constant_us(&self) -> f64 {
        self.ranges
            .get(usize::from(self.range))
            .map_or(0.0, |r| f64::from(r.time_constant_us))
    }

    /// Take the detector's blocks up to now (into `pending`), the amplifier following.
    fn simulate_detector(&mut self) {
        while self.simulated_us < self.now_us {
            let until = self.now_us.min(self.next_sample_us);
            self.simulate_interval(self.simulated_us, until);
            self.simulated_us = until;
            if until == self.next_sample_us {
                self.close_block();
            }
        }
    }

    /// The pieces of constant true geometry of [from, to) (µs; the geometry at time t holds
    /// over [t, t + 1)). Within a block each arm follows one profile (profiles start at
    /// polls, which are block boundaries or events that simulate up to themselves first),
    /// so it is monotonic: equal ends mean no motion between.
    fn split_into_pieces(&mut self, from: u64, to: u64) {
        self.pieces.clear();
        let first = self.mechanics.true_geometry_at(from);
        let last = self.mechanics.true_geometry_at(to - 1);
        if first == last {
            self.pieces.push(Piece {
                geometry: first,
                duration_us: to - from,
                path: 0,
                input: 0.0,
            });
            return;
        }
        let mut stack = vec![(from, to, first, last)];
        // Depth first, left half first: pieces come out in time order.
        while let Some((a, b, ga, gl)) = stack.pop() {
            if ga == gl || b - a == 1 {
                match self.pieces.last_mut() {
                    Some(piece) if piece.geometry == ga => piece.duration_us += b - a,
                    _ => self.pieces.push(Piece {
                        geometry: ga,
                        duration_us: b - a,
                        path: 0,
                        input: 0.0,
                    }),
                }
                continue;
            }
            let mid = a + (b - a) / 2;
            let (g_left_end, g_mid) = (
                self.mechanics.true_geometry_at(mid - 1),
                self.mechanics.true_geometry_at(mid),
            );
            stack.push((mid, b, g_mid, gl));
            stack.push((a, mid, ga, g_left_end));
        }
        let mut path = 0;
        for k in 1..self.pieces.len() {
            let (before, here) = (self.pieces[k - 1].geometry, self.pieces[k].geometry);
            path += i64::from((here.theta_i.ticks() - before.theta_i.ticks()).abs())
                + i64::from((here.theta_r.ticks() - before.theta_r.ticks()).abs());
            self.pieces[k].path = path;
        }
    }

    /// The inputs of the pieces `lo..=hi`, the ends already set: evaluated where the scene
    /// bends, interpolated along the path where it is straight.
    fn fill_inputs(&mut self, lo: usize, hi: usize) {
        if hi <= lo + 1 {
            return;
        }
        let mid = lo + (hi - lo) / 2;
        let geometry = self.pieces[mid].geometry;
        self.pieces[mid].input = self.input_at(geometry);
        let (a, b, m) = (self.pieces[lo], self.pieces[hi], self.pieces[mid]);
        let along = |p: &Piece| (p.path - a.path) as f64 / (b.path - a.path).max(1) as f64;
        let line = a.input + (b.input - a.input) * along(&m);
        let tolerance = INTERPOLATION_TOLERANCE_FRACTION * self.detector.params().full_scale_counts;
        if (m.input - line).abs() <= tolerance {
            for k in lo + 1..hi {
                if k != mid {
                    let f = along(&self.pieces[k]);
                    self.pieces[k].input = a.input + (b.input - a.input) * f;
                }
            }
        } else {
            self.fill_inputs(lo, mid);
            self.fill_inputs(mid, hi);
        }
    }

    /// The amplifier over [from, to), within one block.
    fn simulate_interval(&mut self, from: u64, to: u64) {
        self.split_into_pieces(from, to);
        let last = self.pieces.len() - 1;
        for k in [0, last] {
            let geometry = self.pieces[k].geometry;
            self.pieces[k].input = self.input_at(geometry);
        }
        self.fill_inputs(0, last);
        let (tau_us, rail) = (self.time_constant_us(), self.rail_counts());
        let mut t = from as f64;
        for k in 0..self.pieces.len() {
            let piece = self.pieces[k];
            let duration = piece.duration_us as f64;
            // Settled at rest: the output is the input, and the block reads it as before.
            let steady =
                self.amp_output == piece.input && piece.input < rail && t >= self.amp_hold_until_us;
            if !steady
                || self
                    .block_steady
                    .is_some_and(|(rf, _)| rf.to_bits() != self.seen_at(piece.geometry).to_bits())
            {
                self.block_steady = None;
            }
            let held_us = (self.amp_hold_until_us - t).clamp(0.0, duration);
            let mut response = Response {
                end: self.amp_output,
                integral: 0.0,
                rail_us: 0.0,
            };
            if held_us > 0.0 {
                response.integral = self.amp_output * held_us;
                response.rail_us = if self.amp_output >= rail {
                    held_us
                } else {
                    0.0
                };
            }
            let follows = amplifier::respond(
                self.amp_output,
                piece.input,
                duration - held_us,
                tau_us,
                rail,
            );
            response.end = follows.end;
            response.integral += follows.integral;
            response.rail_us += follows.rail_us;
            self.amp_output = response.end;
            self.block_integral += response.integral;
            self.block_rail_us += response.rail_us;
            t += duration;
        }
    }

    /// The block ending at `next_sample_us` is over: its sample, stamped with the detector
    /// arm's step count at its end.
    fn close_block(&mut self) {
        let end_us = self.next_sample_us;
        let period = self.detector.sample_period_us();
        let lamp = self.detector.lamp_output(end_us as f64 * 1e-6);
        let counts = if self.block_rail_us >= period as f64 {
            // Every conversion at full scale.
            self.detector.saturated_sample()
        } else {
            let signal = match self.block_steady {
                Some((radiance_factor, theta_i)) if self.mechanics.lamp_on() => self
                    .detector
                    .signal_counts(radiance_factor, theta_i, usize::from(self.range), lamp),
                Some(_) => 0.0,
                None => self.block_integral / period as f64 * lamp,
            };
            self.detector.sample(signal)
        };
        let detector_steps = self.mechanics.arms[Arm::Detector.index()].steps_at(end_us);
        self.pending.push_back(Sample {
            counts,
            detector_steps,
        });
        self.next_sample_us += period;
        self.block_integral = 0.0;
        self.block_rail_us = 0.0;
        // The next block starts steady if the arms stand and the output is its input.
        let geometry = self.mechanics.true_geometry_at(end_us);
        let radiance_factor = self.seen_at(geometry);
        self.block_steady = Some((radiance_factor, geometry.theta_i.deg()));
    }
}

impl Arms for SimHardware {
    fn run_profile(&mut self, arm: Arm, profile: &MoveProfile) {
        // The blocks so far were taken on the old profile's path.
        self.simulate_detector();
        self.mechanics.run_profile(arm, profile);
    }

    fn position_steps(&self, arm: Arm) -> i32 {
        self.mechanics.position_steps(arm)
    }

    fn is_moving(&self, arm: Arm) -> bool {
        self.mechanics.is_moving(arm)
    }

    fn set_position_steps(&mut self, arm: Arm, steps: i32) {
        self.simulate_detector();
        self.mechanics.set_position_steps(arm, steps);
    }

    fn home_switch_pressed(&self, arm: Arm) -> bool {
        self.mechanics.home_switch_pressed(arm)
    }

    fn driver_fault(&self, arm: Arm) -> bool {
        self.mechanics.driver_fault(arm)
    }

    fn set_driver_enabled(&mut self, arm: Arm, enabled: bool) {
        self.mechanics.set_driver_enabled(arm, enabled);
    }

    fn take_step_fault(&mut self, arm: Arm) -> bool {
        // The simulated step generator is perfect, unless a test made it late.
        self.mechanics.take_step_fault(arm)
    }

    fn run_pulse_check(&mut self, arm: Arm, profile: &MoveProfile) {
        self.simulate_detector();
        self.mechanics.run_pulse_check(arm, profile);
    }
}

/// The mechanics' model answers for the board: its clocks as modelled, no interrupts to
/// time and no stack to paint (`None`: not measured), the range lines as selected.
impl Diagnostics for SimHardware {
    fn clocks(&self) -> MeasuredClocks {
        self.mechanics.clocks()
    }

    fn worst_step_late_us(&self) -> u32 {
        self.mechanics.worst_step_late_us()
    }

    fn longest_interrupts_off_us(&self) -> Option<u32> {
        self.mechanics.longest_interrupts_off_us()
    }

    fn stack_use(&self) -> Option<StackUse> {
        self.mechanics.stack_use()
    }

    fn range_read_back(&self) -> Option<u8> {
        Some(self.mechanics.range_lines_read.unwrap_or(self.range))
    }

    fn resets_since_power_on(&self) -> Option<protocol::ResetCounts> {
        self.mechanics.resets_since_power_on()
    }
}

impl Lamp for SimHardware {
    fn set_lamp(&mut self, on: bool) {
        self.simulate_detector();
        self.mechanics.set_lamp(on);
    }
}

impl DetectorTrait for SimHardware {
    fn select_range(&mut self, range: u8) {
        // The blocks so far were taken on the old range.
        self.simulate_detector();
        if range != self.range {
            // The output stays where it is and relaxes to the new range's level with the new
            // τ, after the switch's charge and the op-amp's recovery.
            let kick = amplifier::SWITCH_KICK_FRACTION * self.detector.params().full_scale_counts;
            self.amp_output = (self.amp_output + kick).min(self.rail_counts());
            self.amp_hold_until_us = self.now_us as f64 + amplifier::SWITCH_RECOVERY_US;
            self.block_steady = None;
        }
        self.range = range;
    }

    fn drain_samples(&mut self, sink: &mut dyn FnMut(Sample)) -> Result<(), SampleLoss> {
        // Losses injected into the mechanics' model are reported here too.
        let injected = self.mechanics.sample_loss.take();
        self.simulate_detector();
        while let Some(sample) = self.pending.pop_front() {
            sink(sample);
        }
        injected.map_or(Ok(()), Err)
    }

    fn take_sample_fault(&mut self) -> Option<SampleLoss> {
        self.mechanics.take_sample_fault()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detector::{MIRROR_SCALE_DEG, Response as AngularResponse};
    use crate::scene::{BlackGlass, fresnel_unpolarized};
    use protocol::Angle;
    use std::sync::Arc;

    const CONFIG: InstrumentConfig = InstrumentConfig::REFERENCE;
    const THETA_I_TICKS: i32 = 1600;

    /// The black glass swept by the detector arm from θr = θi − `half_span_deg` to θi +
    /// `half_span_deg` at `speed_deg_per_s` on `range`, noiseless and without drift: each
    /// block's reading above dark, in time order (block k ends at (k + 1) ms), and the
    /// hardware after the sweep.
    fn swept_black_glass(
        response: AngularResponse,
        offset_deg: f64,
        range: u8,
        speed_deg_per_s: f32,
        half_span_deg: f64,
    ) -> (Vec<f64>, SimHardware) {
        let params = DetectorParams {
            response,
            noise_scale: 0.0,
            lamp_drift_per_hour: 0.0,
            ..DetectorParams::default()
        };
        let span_ticks = (half_span_deg * 80.0).round() as i32;
        let start = Geometry::new(
            Angle::from_ticks(THETA_I_TICKS),
            Angle::from_ticks(THETA_I_TICKS - span_ticks),
        );
        let port = SamplePort::new(Arc::new(BlackGlass::default()));
        let mut hardware = SimHardware::new(&CONFIG, port, params, 1, start);
        hardware.set_theta_r_offset_deg(offset_deg);
        hardware.set_lamp(true);
        hardware.select_range(range);
        // Settled at rest first (the range switch's transient long gone).
        hardware.advance_to(20_000);
        let profile = MoveProfile::fastest(
            0,
            2 * span_ticks,
            0.0,
            speed_deg_per_s * 80.0,
            CONFIG.accel_deg_per_s2 * 80.0,
        );
        hardware.run_profile(Arm::Detector, &profile);
        let end_us = 20_000 + profile.duration_us() + 20_000;
        let mut blocks = Vec::new();
        let dark = hardware.detector().dark_offset_counts();
        for t in (21_000..=end_us).step_by(1000) {
            hardware.advance_to(t);
            hardware
                .drain_samples(&mut |s| blocks.push(f64::from(s.counts) - dark))
                .unwrap();
        }
        (blocks, hardware)
    }

    /// What the blocks of [`swept_black_glass`] should read, from the true path the
    /// mechanics took, microsecond by microsecond: the mirror through the response at each
    /// true θr (plus the zero error), through the range's first-order amplifier solved
    /// exactly over each microstep of constant input, averaged over each block.
    fn reference_blocks(
        hardware: &SimHardware,
        response: AngularResponse,
        offset_deg: f64,
        range: u8,
        blocks: usize,
    ) -> Vec<f64> {
        let detector = hardware.detector();
        let theta_i = Angle::from_ticks(THETA_I_TICKS).deg();
        let input = |t_us: u64| {
            let theta_r = hardware.mechanics().true_geometry_at(t_us).theta_r.deg() + offset_deg;
            let seen = fresnel_unpolarized(1.567, theta_i)
                * response.density(theta_r - theta_i)
                * MIRROR_SCALE_DEG
                / theta_i.to_radians().cos();
            detector.signal_counts(seen, theta_i, usize::from(range), 1.0)
        };
        let tau = f64::from(CONFIG.detector_ranges[usize::from(range)].time_constant_us);
        let decay = (-1.0 / tau).exp();
        let mut output = input(20_000);
        let mut out = Vec::with_capacity(blocks);
        for k in 0..blocks as u64 {
            let mut integral = 0.0;
            for t in k * 1000..(k + 1) * 1000 {
                if t < 20_000 {
                    continue;
                }
                let x = input(t);
                integral += x + (output - x) * tau * (1.0 - decay);
                output = x + (output - x) * decay;
            }
            out.push(if k < 20 { f64::NAN } else { integral / 1000.0 });
        }
        out
    }

    /// A slow sweep (2 °/s) and a fast one (60 °/s) over the black glass: every 25 blocks'
    /// mean is the response averaged along the true path the arm took over them, to 1e-4 of
    /// the peak (the ADC's rounding of each block is 0.5 count in tens of thousands), for a
    /// 0.3° top-hat (edges a block's path must not step over unseen) and a 3° Gaussian,
    /// the zero error off the tick grid.
    #[test]
    fn a_sweep_over_the_black_glass_reads_the_response_along_the_true_path() {
        let cases = [
            (AngularResponse::TopHat { width_deg: 0.3 }, 1u8, 0.5),
            (AngularResponse::Gaussian { fwhm_deg: 3.0 }, 0, 4.0),
            (
                AngularResponse::Trapezoid {
                    top_deg: 0.1,
                    base_deg: 0.5,
                },
                1,
                0.6,
            ),
        ];
        for (response, range, half_span_deg) in cases {
            for speed in [2.0f32, 60.0] {
                let offset = 0.0371;
                // The fast sweep long enough to reach its speed (v²/2a = 10° of run-up).
                let half_span_deg = if speed > 10.0 { 12.0 } else { half_span_deg };
                let (blocks, hardware) =
                    swept_black_glass(response, offset, range, speed, half_span_deg);
                let reference = reference_blocks(&hardware, response, offset, range, blocks.len());
                let peak = reference[20..].iter().copied().fold(0.0, f64::max);
                assert!(
                    peak > 2_000.0 && peak < 60_000.0,
                    "{response:?} on range {range}: peak {peak} counts"
                );
                let bins = 25;
                let mut worst = 0.0f64;
                for (got, want) in blocks[20..].chunks(bins).zip(reference[20..].chunks(bins)) {
                    let n = got.len() as f64;
                    let (got, want) = (got.iter().sum::<f64>() / n, want.iter().sum::<f64>() / n);
                    worst = worst.max((got - want).abs() / peak);
                }
                assert!(
                    worst < 1e-4,
                    "{response:?} at {speed} °/s: a bin off by {worst:e} of the peak"
                );
            }
        }
    }
}
