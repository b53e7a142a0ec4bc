//! The simulated instrument: the firmware library ([`firmware::Device`]) running on
//! simulated hardware ([`hardware::SimHardware`]) and virtual time, reached through the
//! same byte-level protocol as the real board, in process or on a pseudo-terminal
//! ([`pty`]).
//!
//! It models the instrument and nothing more: the arms (the firmware's own motion
//! profiles), the home switches, the lamp, the detector ([`detector`]: its angular
//! response, a top-hat, Gaussian or trapezoid, and its amplifier's response in time,
//! [`amplifier`], so that a sweep's bins read the scene integrated over the arm's motion,
//! lagged and range-switched as the instrument's) and the link, and the instrument's own
//! errors ([`InstrumentErrors`]: range gains off their nominal values, a white tile off its
//! certificate, a detector arm zero error). The scene on the sample port is handed in by
//! the caller ([`scene`]): a simulated sheet ([`sheet`]), a table of measured values
//! ([`table`]), the black glass standard (a mirror, [`scene::BlackGlass`]) or any function;
//! while the host takes white-reference readings (the protocol marks them), the simulated
//! operator has the white tile on the port, and when the sample goes back on it lands on
//! another spot.
//!
//! Virtual time passes only when asked ([`SimInstrument::read`] waiting for output,
//! [`SimInstrument::advance_ms`]): a session's device seconds take microseconds.

pub mod amplifier;
pub mod detector;
pub mod hardware;
pub mod pty;
pub mod readings_csv;
pub mod scene;
pub mod sheet;
pub mod table;

/// The random streams of a run: every effect draws from its own stream of the run's seed
/// (ChaCha12 keyed by the seed, one stream number each), so switching one effect on or
/// changing its size never changes another's draws or the detector noise.
pub mod streams {
    /// The detector's noise and the lamp drift's direction.
    pub const DETECTOR: u64 = 0;
    /// The range gains' errors.
    pub const GAINS: u64 = 1;
    /// The white tile's error.
    pub const TILE: u64 = 2;
    /// The detector arm zero's drawn error.
    pub const ARM_ZERO: u64 = 3;
    /// What a caller draws of a whole instrument beyond these (the host's `--physics
    /// drawn`: the detector's response, its arm zero, its noise scale), handed in as fixed
    /// values.
    pub const DRAWN_INSTRUMENT: u64 = 4;
    // Spot k of a sheet: stream 2³² + k (crate::sheet). The link's faults have a key of
    // their own (seed ^ "link").
}

use detector::DetectorParams;
use firmware::Device;
use firmware::config::InstrumentConfig;
use firmware::hardware::{Arm, ResetCause};
use hardware::SimHardware;
use protocol::{Command, FrameDecoder, Geometry, Request};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;
use rand_distr::StandardNormal;
use scene::SamplePort;
use std::collections::VecDeque;
use std::time::Duration;

/// Faults to inject.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Faults {
    /// Probability that any byte on the link (either way) is corrupted.
    pub corrupt: f64,
    /// Probability that any frame on the link (either way) is lost.
    pub drop: f64,
    /// Times the USB cable is pulled, and how long it stays out each time. Outages that
    /// overlap are one outage, until the last of them ends.
    pub unplugs: Vec<Unplug>,
    /// Steps one arm loses (it stalls) during the first move the host commands.
    pub lose_steps: Option<(Arm, i32)>,
    /// An arm whose home switch never triggers.
    pub switch_missing: Option<Arm>,
    /// An arm whose home switch reads pressed wherever the arm is.
    pub switch_stuck: Option<Arm>,
    /// An arm whose driver's fault line reads a fault whatever the driver does.
    pub diag_stuck: Option<Arm>,
    /// The crystal the board's boot measured, Hz (`None`: the one it was built for).
    pub crystal_hz: Option<u32>,
    /// The step timers' tick off its nominal by this fraction (0.01: 1 % slow).
    pub step_timer_error: f64,
    /// The range select lines read back this range whatever is selected.
    pub range_lines: Option<u8>,
}

/// One pull of the USB cable.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Unplug {
    /// Device time at which the cable is pulled, seconds.
    pub at_s: f64,
    /// How long it stays out, seconds. Past the firmware's heartbeat timeout (2 s on the
    /// reference instrument) a device with the lamp on or the arms moving takes its
    /// fail-safe stop before the cable is back.
    pub for_s: f64,
}

/// How long a pulled cable stays out when the fault does not say.
pub const DEFAULT_UNPLUG_S: f64 = 1.0;

impl Unplug {
    /// The cable pulled at `at_s` for `for_s` seconds of device time.
    pub fn new(at_s: f64, for_s: f64) -> Unplug {
        Unplug { at_s, for_s }
    }

    fn span_us(&self) -> (u64, u64) {
        let at_us = (self.at_s.max(0.0) * 1e6) as u64;
        (
            at_us,
            at_us.saturating_add((self.for_s.max(0.0) * 1e6) as u64),
        )
    }
}

/// Everything that makes one simulated instrument.
#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    /// Firmware configuration (limits, timing) — the reference instrument by default.
    pub instrument: InstrumentConfig,
    /// Detector physics.
    pub detector: DetectorParams,
    /// Seed of every random draw (noise, drift direction, link faults).
    pub seed: u64,
    /// Times the instrument was switched on before this one (0: the first). Its errors,
    /// sheet and drift stay those of `seed`; its detector noise is drawn afresh from
    /// `seed` and this count, as a real detector's does not repeat after a restart (with
    /// the noise replayed, a session resumed after a crash read its sample with the very
    /// noise of its first run's dark and white readings, and its fit failed χ²).
    pub power_on: u64,
    /// Injected faults.
    pub faults: Faults,
    /// Where the arms stand at power-up (the firmware learns it by homing).
    pub start: Geometry,
    /// The instrument's serial number in the handshake. One simulated instrument, whatever
    /// the seed: a seed is a run, not another instrument.
    pub serial_number: String,
    /// The instrument's own errors (none by default: the ideal instrument).
    pub errors: InstrumentErrors,
}

/// Errors of the instrument that no reading shows by itself, drawn from the seed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InstrumentErrors {
    /// Relative standard deviation of each range-gain ratio's error. Range 0 is the
    /// reference (its absolute gain cancels in the white calibration); the true ratio of
    /// each range to the one before it, g(k)/g(k−1), is its nominal ratio (what the
    /// firmware announces) × (1 + p·z), z ~ N(0, 1), independently for each k. So every
    /// adjacent ratio is off by a drawn amount of standard deviation p, and range k's
    /// gain by about p·√k relative to range 0.
    pub gain_ratio_sd: f64,
    /// Relative standard deviation of the white tile's error: its true radiance factor is
    /// its certificate's × (1 + p·z).
    pub tile_sd: f64,
    /// Detector arm zero error, degrees: the detector's true angle is the one the
    /// firmware believes plus this (plus the drawn part below).
    pub theta_r_offset_deg: f64,
    /// Standard deviation of a drawn detector arm zero error, degrees: an instrument whose
    /// zero is good to this much, its actual error N(0, sd²) drawn from the seed.
    pub theta_r_offset_sd_deg: f64,
}

/// What the instrument truly is in this run (the drawn errors, and the detector it was
/// given), for tests and studies.
#[derive(Clone, Debug, PartialEq)]
pub struct Truth {
    /// True gain of each range relative to range 0's nominal gain.
    pub relative_gains: Vec<f64>,
    /// Each adjacent ratio's drawn factor: the true g(k)/g(k−1) over its nominal, for k = 1,
    /// 2, … (1 + p·z of [`InstrumentErrors::gain_ratio_sd`]).
    pub gain_ratio_factors: Vec<f64>,
    /// True radiance factor of the white tile.
    pub tile_radiance_factor: f64,
    /// The tile's drawn factor: its true radiance factor over its certificate's.
    pub tile_factor: f64,
    /// Detector arm zero error, degrees.
    pub theta_r_offset_deg: f64,
    /// The detector's angular response.
    pub response: detector::Response,
    /// The detector's noise scale (1: the reference instrument's noise).
    pub noise_scale: f64,
    /// Lamp drift, fraction per hour of device time, with its drawn sign.
    pub lamp_drift_per_hour: f64,
}

impl SimConfig {
    /// What the instrument of this configuration truly is, with `white` the tile on its
    /// port: its errors drawn from the seed, exactly as [`SimInstrument::new`] draws them
    /// (it calls this), so a study can know them without a run.
    pub fn truth(&self, white: scene::WhiteTile) -> Truth {
        let errors = &self.errors;
        // Every ratio is drawn, used or not, so the draws of range k do not depend on p.
        let mut gains_rng = stream(self.seed, streams::GAINS);
        let nominal = &self.detector.relative_gains;
        let mut relative_gains = nominal.clone();
        let mut gain_ratio_factors = Vec::with_capacity(nominal.len().saturating_sub(1));
        for k in 1..nominal.len() {
            let factor = error_factor(&mut gains_rng, errors.gain_ratio_sd);
            relative_gains[k] = relative_gains[k - 1] * nominal[k] / nominal[k - 1] * factor;
            gain_ratio_factors.push(factor);
        }
        let tile_factor = error_factor(&mut stream(self.seed, streams::TILE), errors.tile_sd);
        let drawn_zero_deg: f64 = {
            let z: f64 = stream(self.seed, streams::ARM_ZERO).sample(StandardNormal);
            errors.theta_r_offset_sd_deg * z
        };
        // The drift's sign is the detector's first draw from the seed (power-ons keep it).
        let lamp_drift_per_hour =
            detector::Detector::new(self.detector.clone(), self.seed).lamp_drift_per_hour();
        Truth {
            relative_gains,
            gain_ratio_factors,
            tile_radiance_factor: white.radiance_factor * tile_factor,
            tile_factor,
            theta_r_offset_deg: errors.theta_r_offset_deg + drawn_zero_deg,
            response: self.detector.response,
            noise_scale: self.detector.noise_scale,
            lamp_drift_per_hour,
        }
    }
}

/// Serial number of the simulated instrument.
pub const SIM_SERIAL_NUMBER: &str = "SIM-0001";

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            instrument: InstrumentConfig::REFERENCE,
            detector: DetectorParams::default(),
            seed: 0,
            power_on: 0,
            faults: Faults::default(),
            start: Geometry::from_whole_deg(30, 30),
            serial_number: SIM_SERIAL_NUMBER.to_string(),
            errors: InstrumentErrors::default(),
        }
    }
}

/// Poll period of the simulated board loop (the board polls every millisecond).
const POLL_US: u64 = 1000;

/// The firmware logic on simulated hardware behind a byte pipe, on virtual time.
pub struct SimInstrument {
    device: Device<SimHardware>,
    /// Bytes the device sent that reached the host's side and are not read yet.
    to_host: VecDeque<u8>,
    now_us: u64,
    faults: Faults,
    link_rng: ChaCha12Rng,
    /// The operator watches the host's requests to put the white tile on the port.
    operator: FrameDecoder,
    /// Whether the host frame now arriving is being lost.
    dropping_host_frame: bool,
    /// At a frame boundary on the host-to-device side.
    host_frame_start: bool,
    steps_lost: bool,
    /// The outages, in device µs (pulled, back), in time order and merged where they
    /// overlap.
    outages: Vec<(u64, u64)>,
    /// The next outage not yet begun.
    next_outage: usize,
    /// While the cable is out: when it comes back.
    back_at_us: Option<u64>,
    unplugged: bool,
    truth: Truth,
}

/// A generator on `stream` of the run's `seed` (see [`streams`]).
pub fn stream(seed: u64, stream: u64) -> ChaCha12Rng {
    let mut rng = ChaCha12Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    rng
}

/// A relative error factor 1 + sd·z, z ~ N(0, 1), kept positive (at 20 % and below the
/// floor is beyond 4.5 standard deviations).
fn error_factor(rng: &mut ChaCha12Rng, sd: f64) -> f64 {
    let z: f64 = rng.sample(StandardNormal);
    (1.0 + sd * z).max(0.1)
}

/// The link is down: the cable is out.
fn unplugged_error() -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::NotConnected,
        "simulated USB cable unplugged",
    )
}

impl SimInstrument {
    /// A simulated instrument with `port` on its sample port.
    pub fn new(mut port: SamplePort, config: SimConfig) -> SimInstrument {
        let truth = config.truth(port.white);
        let mut detector = config.detector.clone();
        detector.relative_gains = truth.relative_gains.clone();
        port.white.radiance_factor = truth.tile_radiance_factor;
        let theta_r_offset_deg = truth.theta_r_offset_deg;
        let mut hardware = SimHardware::new(
            &config.instrument,
            port,
            detector,
            config.seed,
            config.start,
        );
        hardware.set_theta_r_offset_deg(theta_r_offset_deg);
        if config.power_on > 0 {
            let noise_seed = stream(
                config.seed ^ config.power_on.wrapping_mul(0x9e37_79b9_7f4a_7c15),
                streams::DETECTOR,
            )
            .random::<u64>();
            hardware.detector_mut().reseed_noise(noise_seed);
        }
        let faults = &config.faults;
        let mechanics = hardware.mechanics_mut();
        if let Some(arm) = faults.switch_stuck {
            mechanics.arms[arm.index()].switch_stuck = true;
        }
        if let Some(arm) = faults.diag_stuck {
            mechanics.arms[arm.index()].diag_stuck = true;
        }
        if let Some(hz) = faults.crystal_hz {
            mechanics.clocks.hse_measured_hz = Some(hz);
        }
        mechanics.step_timer_scale = (1.0 + faults.step_timer_error) as f32;
        mechanics.range_lines_read = faults.range_lines;
        if let Some(arm) = config.faults.switch_missing {
            hardware.mechanics_mut().arms[arm.index()].switch_missing = true;
        }
        let outages = merged_outages(&config.faults.unplugs);
        SimInstrument {
            device: Device::new(config.instrument, hardware, ResetCause::PowerOn)
                .with_serial_number(&config.serial_number),
            to_host: VecDeque::new(),
            now_us: 0,
            faults: config.faults,
            // A stream of its own, so that link faults do not shift the detector noise.
            link_rng: ChaCha12Rng::seed_from_u64(config.seed ^ 0x6c69_6e6b),
            operator: FrameDecoder::new(),
            dropping_host_frame: false,
            host_frame_start: true,
            steps_lost: false,
            outages,
            next_outage: 0,
            back_at_us: None,
            unplugged: false,
            truth,
        }
    }

    /// What the instrument truly is in this run: its drawn gains, tile and zero error, its
    /// response, noise scale and lamp drift.
    pub fn truth(&self) -> &Truth {
        &self.truth
    }

    /// The operator shifts the sample to another spot (a multi-spot session asks for it);
    /// spots also change whenever the sample goes back on after the white tile.
    pub fn next_spot(&mut self) {
        self.device.hardware_mut().next_spot();
    }

    /// Bytes from the host arrive at the device (through the link's faults).
    pub fn write(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        if self.unplugged {
            return Err(unplugged_error());
        }
        for &sent in bytes {
            if self.host_frame_start {
                self.dropping_host_frame = chance(&mut self.link_rng, self.faults.drop);
            }
            self.host_frame_start = sent == 0;
            if self.dropping_host_frame {
                continue;
            }
            let byte = corrupt(&mut self.link_rng, self.faults.corrupt, sent);
            if let Some(Ok(request)) = self.operator.push::<Request>(byte) {
                self.operator_sees(&request);
            }
            let (device, to_host, mut link) = self.split();
            device.receive(&[byte], link.now_us, &mut |frame: &[u8]| {
                link.deliver(frame, to_host)
            });
        }
        Ok(())
    }

    /// Bytes from the device, waiting up to `wait` of device time for some to arrive.
    pub fn read(&mut self, buf: &mut [u8], wait: Duration) -> std::io::Result<usize> {
        let deadline = self.now_us + wait.as_micros() as u64;
        loop {
            if self.unplugged {
                while self.unplugged && self.now_us < deadline {
                    self.step();
                }
                return Err(unplugged_error());
            }
            if !self.to_host.is_empty() {
                let n = buf.len().min(self.to_host.len());
                for (slot, byte) in buf.iter_mut().zip(self.to_host.drain(..n)) {
                    *slot = byte;
                }
                return Ok(n);
            }
            if self.now_us >= deadline {
                return Ok(0);
            }
            self.step();
        }
    }

    /// Run the firmware forward by `ms` of virtual time.
    pub fn advance_ms(&mut self, ms: u64) {
        for _ in 0..ms {
            self.step();
        }
    }

    /// One board-loop period: hardware moves on, the firmware polls.
    fn step(&mut self) {
        self.now_us += POLL_US;
        self.update_cable();
        self.device.hardware_mut().advance_to(self.now_us);
        let (device, to_host, mut link) = self.split();
        device.poll(link.now_us, &mut |frame: &[u8]| {
            link.deliver(frame, to_host)
        });
    }

    fn update_cable(&mut self) {
        if let Some(back_us) = self.back_at_us {
            if self.now_us < back_us {
                return;
            }
            self.back_at_us = None;
            self.unplugged = false;
            self.host_frame_start = true;
            self.operator.reset();
        }
        if let Some(&(at_us, back_us)) = self.outages.get(self.next_outage) {
            if self.now_us >= at_us {
                self.next_outage += 1;
                self.back_at_us = Some(back_us);
                self.unplugged = true;
                self.to_host.clear();
                self.device.disconnected();
            }
        }
    }

    fn operator_sees(&mut self, request: &Request) {
        let hardware = self.device.hardware_mut();
        match &request.command {
            Command::TakeReading { target, .. } => hardware.place(*target),
            Command::RunSchedule(run) => hardware.place(run.target),
            Command::Sweep(sweep) => hardware.place(sweep.target),
            _ => {}
        }
        if matches!(
            request.command,
            Command::MoveTo(_) | Command::RunSchedule(_)
        ) && !self.steps_lost
        {
            if let Some((arm, steps)) = self.faults.lose_steps {
                self.steps_lost = true;
                hardware.mechanics_mut().lose_steps(arm, steps);
            }
        }
    }

    /// The device, the host's receive buffer and the link, borrowed apart.
    fn split(&mut self) -> (&mut Device<SimHardware>, &mut VecDeque<u8>, LinkSide<'_>) {
        let link = LinkSide {
            now_us: self.now_us,
            faults: &self.faults,
            rng: &mut self.link_rng,
            unplugged: self.unplugged,
        };
        (&mut self.device, &mut self.to_host, link)
    }

    /// Whether the firmware has nothing under way.
    pub fn is_idle(&self) -> bool {
        self.device.is_idle()
    }

    /// Whether the simulated cable is out.
    pub fn is_unplugged(&self) -> bool {
        self.unplugged
    }

    /// The simulated hardware (true arm angles, lamp, what is on the port).
    pub fn hardware(&self) -> &SimHardware {
        self.device.hardware()
    }

    /// The simulated hardware, to inject faults.
    pub fn hardware_mut(&mut self) -> &mut SimHardware {
        self.device.hardware_mut()
    }

    /// Virtual device time since power-up, µs.
    pub fn device_time_us(&self) -> u64 {
        self.now_us
    }

    /// Device time of the last frame from the host the firmware heard (its heartbeat
    /// timeout runs from it); a frame dropped on the link is not heard.
    pub fn last_heard_us(&self) -> u64 {
        self.device.last_heard_us()
    }

    /// The firmware's heartbeat timeout.
    pub fn heartbeat_timeout(&self) -> Duration {
        Duration::from_millis(u64::from(self.device.config().heartbeat_timeout_ms))
    }
}

/// The outages of `unplugs` as (pulled, back) in device µs, in time order, overlapping
/// ones merged. A zero-length outage still pulls the cable for one poll period: the
/// firmware sees the disconnect.
fn merged_outages(unplugs: &[Unplug]) -> Vec<(u64, u64)> {
    let mut spans: Vec<(u64, u64)> = unplugs.iter().map(Unplug::span_us).collect();
    spans.sort_unstable();
    let mut merged: Vec<(u64, u64)> = Vec::with_capacity(spans.len());
    for (at, back) in spans {
        match merged.last_mut() {
            Some(last) if at <= last.1 => last.1 = last.1.max(back),
            _ => merged.push((at, back)),
        }
    }
    merged
}

/// The device-to-host direction of the link, with its faults.
struct LinkSide<'a> {
    now_us: u64,
    faults: &'a Faults,
    rng: &'a mut ChaCha12Rng,
    unplugged: bool,
}

impl LinkSide<'_> {
    fn deliver(&mut self, frame: &[u8], to_host: &mut VecDeque<u8>) {
        if self.unplugged || chance(self.rng, self.faults.drop) {
            return;
        }
        to_host.extend(
            frame
                .iter()
                .map(|&byte| corrupt(self.rng, self.faults.corrupt, byte)),
        );
    }
}

/// True with probability `p` (never for p ≤ 0 or NaN, always for p ≥ 1). No draw is
/// made when `p` is 0, so a fault-free run has the same link stream as before.
fn chance(rng: &mut ChaCha12Rng, p: f64) -> bool {
    p > 0.0 && rng.random::<f64>() < p
}

/// `byte`, or with probability `p` a different byte.
fn corrupt(rng: &mut ChaCha12Rng, p: f64, byte: u8) -> u8 {
    if chance(rng, p) {
        byte ^ rng.random_range(1..=255u8)
    } else {
        byte
    }
}
