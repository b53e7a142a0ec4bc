//! `gonio characterize`'s procedure: the instrument measured with the standards a lab has
//! (a black glass gloss standard and the white tile), so that sessions use the instrument
//! as it is instead of as it is declared ([`crate::instrument::profile`]).
//!
//! - **Black glass.** At each incidence, the detector arm sweeps up and then down through
//!   the glass's specular peak on one held range: the peak is the instrument's whole
//!   in-plane angular response (acceptance and source divergence together), its centroid
//!   the arm zero ([`crate::analysis::response_estimate`]). Up less down is the detector
//!   arm's backlash (the amplifier's lag, v·τ of the range, taken out first). Each pair of
//!   adjacent ranges is read still, on both, where a peak's top reads 30–85 % of the more
//!   sensitive one's full scale (a top is flat: the arm's last microstep does not matter;
//!   a flank of a sharp response is too steep to hold a level), else on the white tile
//!   where it does: their gain ratio. The white tile reads 4 % of full scale on range 1,
//!   too little for the ratio 1/2.
//! - **Homing.** The arms are homed again and one incidence swept each time: the spread of
//!   the peak's centroid is the homing's repeatability, which every session inherits.
//! - **White tile.** Darks repeated on every range; the tile read repeatedly on each range
//!   (its noise) and over a stated time (the lamp's drift since it was switched on).
//!
//! The operator is asked for each standard with the lamp off and the arms still, so that
//! nothing needs the link while a person works.
use crate::analysis::response_estimate::{
    self, Measured, Peak, PeakError, Trace, TraceBin, mean_and_error,
};
use crate::instrument::link::{Client, LinkError, Transport};
use crate::instrument::profile::{
    GainRatioFigure, IncidenceFigures, InstrumentProfile, LampFigures, RangeNoise, ResponseFigures,
    SCHEMA, Standards,
};
use crate::session::operator::{Operator, Placement};
use protocol::{
    Angle, Command, DeviceInfo, DeviceMessage, Geometry, Reading, Reply, Sweep, SweepBin, Target,
};
use std::time::Duration;

/// Incidences swept on the black glass: the policies' 20° and 60°, the paper's 45°, and
/// 30° and 75° between and beyond (the arm zero is interpolated between them).
pub const INCIDENCES_DEG: [f64; 5] = [20.0, 30.0, 45.0, 60.0, 75.0];
/// The incidence swept after each re-homing.
const REHOME_INCIDENCE_DEG: f64 = 45.0;
/// Detector speed of the sweeps, °/s: a 0.025° bin is then about 6 of the detector's blocks
/// and the amplifier's lag (≤ 1 ms) 0.004°, taken out.
const SPEED_DEG_PER_S: f64 = 4.0;
/// Bin length, ticks of 0.0125°: 0.025°, a twelfth of the narrowest response (0.3°).
const BIN_TICKS: u16 = 2;
/// Half the first sweep's span, degrees: a 3° Gaussian response to 0.5 % of its height and
/// an arm zero of 0.5°, with room; later sweeps fit the response found.
const FIRST_HALF_SPAN_DEG: f64 = 6.0;
/// Widest half span tried when a peak runs into a sweep's end, degrees.
const MAX_HALF_SPAN_DEG: f64 = 9.0;
/// Readings' integration time, ms.
const INTEGRATION_MS: u16 = 100;
/// Darks per range.
const DARKS: usize = 5;
/// White readings per range for its noise.
const WHITES_PER_RANGE: usize = 5;
/// The white tile's geometry: θi 20°, θr 0 (where the reference instrument's white reads
/// 40 % of full scale on the most sensitive range).
const WHITE_GEOMETRY_DEG: (f64, f64) = (20.0, 0.0);
/// Levels on the more sensitive range of a pair at which its gain ratio is read, fraction
/// of full scale above dark: on the other range it then reads 3–8.5 %, well above its
/// noise at [`GAIN_INTEGRATION_MS`]; below saturation with room for a gain a few percent
/// off and the noise.
const GAIN_LEVELS: (f64, f64) = (0.3, 0.85);
/// Integration of a gain ratio's readings, ms (the device's longest if shorter): the less
/// sensitive range's read noise is then a twentieth of a 100 ms reading's.
const GAIN_INTEGRATION_MS: u16 = 1000;
/// Reading pairs per gain ratio.
const GAIN_REPEATS: usize = 3;

/// What is asked for besides the defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// The standards (their certificates).
    pub standards: Standards,
    /// Times the arms are homed again for the repeatability (≥ 1).
    pub rehomes: usize,
    /// How long the lamp's drift is followed on the white tile, s of device time.
    pub lamp_s: f64,
}

/// A characterization: the profile, and what the report draws.
#[derive(Clone, Debug)]
pub struct Characterization {
    /// The profile.
    pub profile: InstrumentProfile,
    /// Every black glass sweep with its peak.
    pub sweeps: Vec<(Trace, Peak)>,
    /// The lamp's white readings: (s since the first, signal relative to their mean).
    pub lamp_series: Vec<(f64, f64)>,
}

/// Why a characterization stopped.
#[derive(Debug, thiserror::Error)]
pub enum CharacterizeError {
    /// The link failed.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The device refused or stopped.
    #[error("the instrument {0}")]
    Device(String),
    /// No usable peak.
    #[error(transparent)]
    Peak(#[from] PeakError),
    /// The operator could not answer.
    #[error("no one answered the prompt: {0}")]
    Operator(std::io::Error),
    /// A figure could not be formed.
    #[error("{0}")]
    Figure(String),
}

/// One held-range sweep's bins.
struct RangeSweep {
    theta_i_deg: f64,
    direction: f64,
    range: u8,
    bins: Vec<SweepBin>,
}

struct Run<'a, T: Transport> {
    client: &'a mut Client<T>,
    info: &'a DeviceInfo,
    next_id: u16,
    /// Dark mean per range, counts.
    dark: Vec<f64>,
}

/// Run the characterization on a handshaken instrument (`info` its handshake).
pub fn run<T: Transport>(
    client: &mut Client<T>,
    info: &DeviceInfo,
    operator: &mut dyn Operator,
    options: &Options,
) -> Result<Characterization, CharacterizeError> {
    let started = client.transport().now();
    let mut run = Run {
        client,
        info,
        next_id: 1,
        dark: Vec::new(),
    };
    run.request(Command::Home)?;
    run.place(operator, Placement::BlackGlass)?;
    let noise_darks = run.darks()?;
    let mut sweeps = Vec::new();
    let mut incidences = Vec::new();
    let mut half_span = FIRST_HALF_SPAN_DEG;
    for &theta_i in &INCIDENCES_DEG {
        let (pair, peaks, range) = run.peak_pair(theta_i, &mut half_span)?;
        incidences.push(incidence_figures(theta_i, &peaks, range));
        for (sweep, peak) in pair.into_iter().zip(peaks) {
            sweeps.push((sweep, peak));
        }
    }
    // Gain ratios where a peak's top reads high on the more sensitive range of a pair.
    let mut gain_ratios = Vec::new();
    for r in 0..run.dark.len().saturating_sub(1) as u8 {
        if let Some((theta_i, centre)) = run.gain_spot(r, &sweeps, &incidences) {
            let at = Geometry::from_deg(theta_i, centre);
            if let Some(ratio) = run.still_ratio(at, Target::Sample, r)? {
                gain_ratios.push(ratio);
            }
        }
    }
    // Homing again: the centroid at one incidence after each.
    let mut centroids: Vec<f64> = sweeps
        .iter()
        .filter(|(t, _)| t.theta_i_deg == REHOME_INCIDENCE_DEG && t.direction > 0.0)
        .map(|(_, p)| p.centroid_deg)
        .collect();
    let range = incidences
        .iter()
        .find(|i| i.theta_i_deg == REHOME_INCIDENCE_DEG)
        .map_or(0, |i| i.range);
    let mut range = range;
    for _ in 0..options.rehomes {
        run.request(Command::Home)?;
        let peak = run.measure_up_unsaturated(REHOME_INCIDENCE_DEG, half_span, &mut range)?;
        centroids.push(peak.centroid_deg);
    }
    run.place(operator, Placement::WhiteTile)?;
    // The pairs no peak served, on the white tile where it reads high enough.
    for r in 0..run.dark.len().saturating_sub(1) as u8 {
        if gain_ratios.iter().all(|g: &GainRatioFigure| g.range != r) {
            let (ti, tr) = WHITE_GEOMETRY_DEG;
            if run.white_level(r)?
                && let Some(ratio) =
                    run.still_ratio(Geometry::from_deg(ti, tr), Target::WhiteReference, r)?
            {
                gain_ratios.push(ratio);
            }
        }
    }
    gain_ratios.sort_by_key(|g| g.range);
    let White {
        noise,
        lamp,
        series: lamp_series,
    } = run.white(&noise_darks, options.lamp_s)?;
    run.request(Command::SetLamp { on: false })?;
    let device_seconds = (run.client.transport().now() - started).as_secs_f64();
    let profile = figures(
        run.info,
        options,
        Figures {
            sweeps: &sweeps,
            incidences,
            centroids: &centroids,
            gain_ratios,
            noise,
            lamp,
            device_seconds,
        },
    )?;
    Ok(Characterization {
        profile,
        sweeps,
        lamp_series,
    })
}

/// What the white tile gave: noise per range, the lamp, its readings over time.
struct White {
    noise: Vec<RangeNoise>,
    lamp: LampFigures,
    series: Vec<(f64, f64)>,
}

/// What [`figures`] forms the profile from.
struct Figures<'a> {
    sweeps: &'a [(Trace, Peak)],
    incidences: Vec<IncidenceFigures>,
    centroids: &'a [f64],
    gain_ratios: Vec<GainRatioFigure>,
    noise: Vec<RangeNoise>,
    lamp: LampFigures,
    device_seconds: f64,
}

fn incidence_figures(theta_i: f64, peaks: &[Peak; 2], range: u8) -> IncidenceFigures {
    let centre = 0.5 * (peaks[0].centroid_deg + peaks[1].centroid_deg);
    let u = 0.5 * peaks[0].centroid_u_deg.hypot(peaks[1].centroid_u_deg);
    IncidenceFigures {
        theta_i_deg: theta_i,
        arm_zero_deg: Measured {
            value: theta_i - centre,
            u,
        },
        fwhm_deg: mean_and_error(&[peaks[0].fwhm_deg, peaks[1].fwhm_deg], f64::NAN),
        range,
    }
}

/// The profile from the measurements.
fn figures(
    info: &DeviceInfo,
    options: &Options,
    f: Figures<'_>,
) -> Result<InstrumentProfile, CharacterizeError> {
    let peaks: Vec<Peak> = f.sweeps.iter().map(|(_, p)| *p).collect();
    let traces: Vec<Trace> = f.sweeps.iter().map(|(t, _)| t.clone()).collect();
    let widths: Vec<f64> = peaks.iter().map(|p| p.fwhm_deg).collect();
    let fwhm = mean_and_error(&widths, f64::NAN);
    let equivalent: Vec<f64> = peaks
        .iter()
        .map(|p| (12.0 * p.variance_deg2).sqrt())
        .collect();
    let (response, shares_u) = response_estimate::response_steps(&traces, &peaks, fwhm.value)
        .ok_or_else(|| CharacterizeError::Figure("no response could be formed".into()))?;
    // Up less down, per incidence.
    let backlash: Vec<f64> = f
        .sweeps
        .chunks(2)
        .filter(|pair| pair.len() == 2)
        .map(|pair| pair[0].1.centroid_deg - pair[1].1.centroid_deg)
        .collect();
    let backlash = mean_and_error(&backlash, f64::NAN);
    let n = f.centroids.len() as f64;
    let repeatability = {
        let m = mean_and_error(f.centroids, 0.0);
        let sd = m.u * n.sqrt();
        Measured {
            value: sd,
            u: sd / (2.0 * (n - 1.0).max(1.0)).sqrt(),
        }
    };
    // A session's zero: the incidences' own, the homing's spread, and half the backlash
    // (a still reading approached from either side) as a uniform bound.
    let zero_u = f
        .incidences
        .iter()
        .map(|i| i.arm_zero_deg.u)
        .fold(0.0, f64::max);
    let arm_zero_u =
        (zero_u.powi(2) + repeatability.value.powi(2) + (0.5 * backlash.value.abs()).powi(2) / 3.0)
            .sqrt();
    let steps = response.steps();
    Ok(InstrumentProfile {
        schema: SCHEMA.to_string(),
        serial_number: info.serial_number.to_string(),
        firmware_version: info.firmware_version.to_string(),
        gonio_version: env!("CARGO_PKG_VERSION").to_string(),
        measured_at: chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Secs, true),
        device_seconds: f.device_seconds,
        standards: options.standards.clone(),
        response: ResponseFigures {
            fwhm_deg: fwhm,
            equivalent_width_deg: mean_and_error(&equivalent, f64::NAN),
            declared_acceptance_deg: f64::from(info.acceptance_deg),
            step_deg: response.step_deg(),
            first_offset_deg: steps[0].0,
            shares: steps.iter().map(|s| s.1).collect(),
            shares_u,
        },
        incidences: f.incidences,
        arm_zero_u_deg: arm_zero_u,
        backlash_deg: backlash,
        home_repeatability_deg: repeatability,
        gain_ratios: f.gain_ratios,
        noise: f.noise,
        lamp: f.lamp,
    })
}

fn usable(bin: &SweepBin) -> bool {
    !bin.is_saturated() && !bin.is_blanked() && !bin.is_empty() && bin.blocks > 0
}

impl<T: Transport> Run<'_, T> {
    /// `command`'s reply (a device's refusal is the link's error, naming the command).
    fn request(&mut self, command: Command) -> Result<Reply, CharacterizeError> {
        Ok(self.client.request(command)?)
    }

    /// Ask for `placement` with the lamp off and the arms still; the lamp on after.
    fn place(
        &mut self,
        operator: &mut dyn Operator,
        placement: Placement,
    ) -> Result<(), CharacterizeError> {
        self.request(Command::SetLamp { on: false })?;
        operator
            .ask(placement, self.client.transport().now())
            .map_err(CharacterizeError::Operator)?;
        while !operator
            .answered(self.client.transport().now())
            .map_err(CharacterizeError::Operator)?
        {
            self.client.keep_alive(Duration::from_millis(100))?;
        }
        self.request(Command::SetLamp { on: true })?;
        Ok(())
    }

    /// [`DARKS`] darks: their mean per range kept for the sweeps, every one returned.
    fn darks(&mut self) -> Result<Vec<Vec<Reading>>, CharacterizeError> {
        let mut all = Vec::new();
        for _ in 0..DARKS {
            match self.request(Command::TakeDark {
                integration_ms: INTEGRATION_MS,
            })? {
                Reply::Dark(readings) => all.push(readings.to_vec()),
                other => return Err(unexpected("TakeDark", other)),
            }
        }
        // A dark leaves the lamp off.
        self.request(Command::SetLamp { on: true })?;
        let ranges = all.first().map_or(0, Vec::len);
        self.dark = (0..ranges)
            .map(|r| {
                all.iter().map(|d| f64::from(d[r].mean_counts)).sum::<f64>() / all.len() as f64
            })
            .collect();
        Ok(all)
    }

    /// The range whose scale holds the peak at `theta_i` (a reading at the specular
    /// direction, auto-ranged).
    fn peak_range(&mut self, theta_i: f64) -> Result<u8, CharacterizeError> {
        let geometry = Geometry::from_deg(theta_i, theta_i).ok_or_else(|| {
            CharacterizeError::Figure(format!("θi {theta_i}° is outside the arms"))
        })?;
        self.request(Command::MoveTo(geometry))?;
        match self.request(Command::TakeReading {
            integration_ms: INTEGRATION_MS,
            target: Target::Sample,
            range: None,
        })? {
            Reply::Reading(r) => Ok(r.range),
            other => Err(unexpected("TakeReading", other)),
        }
    }

    /// Up and down across the peak at `theta_i` on one range (the next less sensitive one
    /// where a bin saturates; a wider span where the peak runs into an end).
    fn peak_pair(
        &mut self,
        theta_i: f64,
        half_span: &mut f64,
    ) -> Result<([Trace; 2], [Peak; 2], u8), CharacterizeError> {
        let mut range = self.peak_range(theta_i)?;
        loop {
            // Up, then down on the same range: a saturation in either (the noise on a
            // peak near full scale differs between them) takes both to the next range.
            let pair = match self.measure(theta_i, 1.0, *half_span, range) {
                Ok(up) => self
                    .measure(theta_i, -1.0, *half_span, range)
                    .map(|down| (up, down)),
                Err(e) => Err(e),
            };
            match pair {
                Err(CharacterizeError::Figure(ref why)) if why == SATURATED => {
                    range = self.less_sensitive(range, theta_i)?;
                }
                Err(CharacterizeError::Peak(PeakError::Truncated { .. }))
                    if *half_span < MAX_HALF_SPAN_DEG =>
                {
                    *half_span = (*half_span * 1.5).min(MAX_HALF_SPAN_DEG);
                }
                Err(e) => return Err(e),
                Ok(((trace_up, peak_up), (trace_down, peak_down))) => {
                    // Later sweeps: the response found, with room.
                    *half_span =
                        (2.0 * peak_up.fwhm_deg + (theta_i - peak_up.centroid_deg).abs() + 0.5)
                            .clamp(1.5, MAX_HALF_SPAN_DEG);
                    return Ok(([trace_up, trace_down], [peak_up, peak_down], range));
                }
            }
        }
    }

    /// Where a black glass peak's top reads within [`GAIN_LEVELS`] of range `r`'s full
    /// scale (its level on the range it was swept on, scaled by the nominal gains): the
    /// incidence and the peak's centroid, the highest such level. A top is flat enough to
    /// read the same on both ranges whatever the arm's last microstep.
    fn gain_spot(
        &self,
        r: u8,
        sweeps: &[(Trace, Peak)],
        incidences: &[IncidenceFigures],
    ) -> Option<(f64, f64)> {
        let gain = |k: u8| {
            self.info
                .detector_ranges
                .get(usize::from(k))
                .map(|d| f64::from(d.relative_gain))
        };
        let full = f64::from(
            self.info
                .detector_ranges
                .get(usize::from(r))?
                .full_scale_counts,
        ) - self.dark.get(usize::from(r)).copied().unwrap_or(0.0);
        incidences
            .iter()
            .filter_map(|i| {
                let (_, peak) = sweeps
                    .iter()
                    .find(|(t, _)| t.theta_i_deg == i.theta_i_deg && t.direction > 0.0)?;
                let level = peak.peak_signal * gain(r)? / gain(i.range)? / full;
                (GAIN_LEVELS.0..=GAIN_LEVELS.1).contains(&level).then_some((
                    level,
                    i.theta_i_deg,
                    peak.centroid_deg,
                ))
            })
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, theta_i, centre)| (theta_i, centre))
    }

    /// Whether the white tile (on the port, at the white geometry) reads within
    /// [`GAIN_LEVELS`] of range `r`'s full scale.
    fn white_level(&mut self, r: u8) -> Result<bool, CharacterizeError> {
        let (ti, tr) = WHITE_GEOMETRY_DEG;
        self.request(Command::MoveTo(Geometry::from_deg(ti, tr).ok_or_else(
            || CharacterizeError::Figure("the white geometry is outside the arms".into()),
        )?))?;
        let full = self
            .info
            .detector_ranges
            .get(usize::from(r))
            .map_or(f64::NAN, |d| f64::from(d.full_scale_counts))
            - self.dark.get(usize::from(r)).copied().unwrap_or(0.0);
        let (_, level) = self.white_reading(r)?;
        Ok((GAIN_LEVELS.0..=GAIN_LEVELS.1).contains(&(level / full)))
    }

    /// G(r + 1)/G(r) from still readings at `at` on both ranges, alternated
    /// [`GAIN_REPEATS`] times (a drift of the lamp between them then averages out); `None`
    /// where one saturates.
    fn still_ratio(
        &mut self,
        at: Option<Geometry>,
        target: Target,
        r: u8,
    ) -> Result<Option<GainRatioFigure>, CharacterizeError> {
        let at =
            at.ok_or_else(|| CharacterizeError::Figure("a gain spot outside the arms".into()))?;
        self.request(Command::MoveTo(at))?;
        let integration_ms = GAIN_INTEGRATION_MS.min(self.info.max_integration_ms);
        let mut ratios = Vec::with_capacity(GAIN_REPEATS);
        for _ in 0..GAIN_REPEATS {
            let mut levels = [0.0; 2];
            for (k, range) in [r, r + 1].into_iter().enumerate() {
                let reading = match self.request(Command::TakeReading {
                    integration_ms,
                    target,
                    range: Some(range),
                })? {
                    Reply::Reading(reading) => reading,
                    other => return Err(unexpected("TakeReading", other)),
                };
                if reading.saturated {
                    return Ok(None);
                }
                levels[k] = f64::from(reading.mean_counts)
                    - self.dark.get(usize::from(range)).copied().unwrap_or(0.0);
            }
            ratios.push(levels[1] / levels[0]);
        }
        let gain = |k: u8| {
            self.info
                .detector_ranges
                .get(usize::from(k))
                .map_or(f64::NAN, |d| f64::from(d.relative_gain))
        };
        Ok(Some(GainRatioFigure {
            range: r,
            ratio: mean_and_error(&ratios, f64::NAN),
            nominal: gain(r + 1) / gain(r),
        }))
    }

    /// The range after `range`, or an error when it is the least sensitive.
    fn less_sensitive(&self, range: u8, theta_i: f64) -> Result<u8, CharacterizeError> {
        if usize::from(range) + 1 >= self.info.detector_ranges.len() {
            return Err(CharacterizeError::Figure(format!(
                "the black glass peak at θi = {theta_i}° saturates the least sensitive range"
            )));
        }
        Ok(range + 1)
    }

    /// [`Run::measure`] up, on `range` or, where that saturates, a less sensitive one.
    fn measure_up_unsaturated(
        &mut self,
        theta_i: f64,
        half_span: f64,
        range: &mut u8,
    ) -> Result<Peak, CharacterizeError> {
        loop {
            match self.measure(theta_i, 1.0, half_span, *range) {
                Err(CharacterizeError::Figure(ref why)) if why == SATURATED => {
                    *range = self.less_sensitive(*range, theta_i)?;
                }
                other => return other.map(|(_, peak)| peak),
            }
        }
    }

    /// One sweep across the peak at `theta_i` (centred on θi) and its peak.
    fn measure(
        &mut self,
        theta_i: f64,
        direction: f64,
        half_span: f64,
        range: u8,
    ) -> Result<(Trace, Peak), CharacterizeError> {
        let (from, to) = if direction > 0.0 {
            (theta_i - half_span, theta_i + half_span)
        } else {
            (theta_i + half_span, theta_i - half_span)
        };
        let sweep = self.sweep(theta_i, from, to, range)?;
        if sweep.bins.iter().any(SweepBin::is_saturated) {
            return Err(CharacterizeError::Figure(SATURATED.to_string()));
        }
        let trace = self.trace(&sweep);
        let peak = response_estimate::measure_peak(&trace)?;
        Ok((trace, peak))
    }

    /// A sweep's bins as a trace: above dark, at their mean position less the
    /// amplifier's lag v·τ.
    fn trace(&self, sweep: &RangeSweep) -> Trace {
        let tau_s = self
            .info
            .detector_ranges
            .get(usize::from(sweep.range))
            .map_or(0.0, |r| f64::from(r.time_constant_us) * 1e-6);
        let lag = sweep.direction * SPEED_DEG_PER_S * tau_s;
        let dark = self
            .dark
            .get(usize::from(sweep.range))
            .copied()
            .unwrap_or(0.0);
        Trace {
            theta_i_deg: sweep.theta_i_deg,
            direction: sweep.direction,
            bins: sweep
                .bins
                .iter()
                .filter(|b| usable(b))
                .map(|b| TraceBin {
                    theta_r_deg: 0.5 * (b.start.deg() + b.end.deg()) - lag,
                    span_deg: (b.end.deg() - b.start.deg()).abs(),
                    signal: f64::from(b.mean_counts) - dark,
                    std: f64::from(b.std_counts) / f64::from(b.blocks).sqrt(),
                })
                .collect(),
        }
    }

    /// A sweep from `from` to `to` at `theta_i` held on `range`: its bins.
    fn sweep(
        &mut self,
        theta_i: f64,
        from: f64,
        to: f64,
        range: u8,
    ) -> Result<RangeSweep, CharacterizeError> {
        let lowest = self.info.arm_min.deg();
        let highest = self.info.arm_max.deg();
        let clamp = |v: f64| v.clamp(lowest, highest);
        let (Some(theta_i_angle), Some(from_angle), Some(to_angle)) = (
            Angle::from_deg(theta_i),
            Angle::from_deg(clamp(from)),
            Angle::from_deg(clamp(to)),
        ) else {
            return Err(CharacterizeError::Figure(format!(
                "a sweep outside the arms: θi {theta_i}°, θr {from}°…{to}°"
            )));
        };
        let sweep_id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1).max(1);
        let command = Sweep {
            sweep_id,
            theta_i: theta_i_angle,
            from: from_angle,
            to: to_angle,
            speed_mdeg_per_s: (SPEED_DEG_PER_S * 1000.0) as u32,
            bin_ticks: BIN_TICKS,
            range: Some(range),
            target: Target::Sample,
        };
        let planned = match self.request(Command::Sweep(command))? {
            Reply::Sweep(plan) => plan.bins,
            other => return Err(unexpected("Sweep", other)),
        };
        let mut bins: Vec<SweepBin> = Vec::with_capacity(usize::from(planned));
        loop {
            match self.client.next_unsolicited(Duration::from_secs(5))? {
                Some(DeviceMessage::SweepBin(bin)) if bin.sweep_id == sweep_id => {
                    if !bins.iter().any(|b| b.index == bin.index) {
                        bins.push(bin);
                    }
                }
                Some(DeviceMessage::SweepDone { sweep_id: id, .. }) if id == sweep_id => break,
                Some(DeviceMessage::Stopped { reason }) => {
                    return Err(CharacterizeError::Device(format!("stopped: {reason:?}")));
                }
                Some(_) => {}
                None => {
                    // Silence: the end may have been lost on the link; ask.
                    if let Reply::Status(status) = self.request(Command::GetStatus)?
                        && status.schedule.is_none_or(|(id, _)| id != sweep_id)
                    {
                        break;
                    }
                }
            }
        }
        bins.sort_by_key(|b| b.index);
        Ok(RangeSweep {
            theta_i_deg: theta_i,
            direction: if to > from { 1.0 } else { -1.0 },
            range,
            bins,
        })
    }

    /// The white tile: its noise on every range, and the lamp followed for `lamp_s`.
    fn white(&mut self, darks: &[Vec<Reading>], lamp_s: f64) -> Result<White, CharacterizeError> {
        let (ti, tr) = WHITE_GEOMETRY_DEG;
        let geometry = Geometry::from_deg(ti, tr).ok_or_else(|| {
            CharacterizeError::Figure("the white geometry is outside the arms".into())
        })?;
        self.request(Command::MoveTo(geometry))?;
        let ranges = self.dark.len();
        let mut noise = Vec::with_capacity(ranges);
        for r in 0..ranges {
            let values: Vec<f64> = (0..WHITES_PER_RANGE)
                .map(|_| self.white_reading(r as u8).map(|(_, v)| v))
                .collect::<Result<_, _>>()?;
            let dark: Vec<f64> = darks.iter().map(|d| f64::from(d[r].mean_counts)).collect();
            let dark_m = mean_and_error(&dark, f64::NAN);
            let white = mean_and_error(&values, f64::NAN);
            let white_sd = white.u * (values.len() as f64).sqrt();
            noise.push(RangeNoise {
                range: r as u8,
                dark_counts: Measured {
                    value: dark_m.value,
                    u: dark_m.u * (dark.len() as f64).sqrt(),
                },
                white_relative_sd: (white.value > 0.0).then(|| white_sd / white.value),
                integration_ms: INTEGRATION_MS,
            });
        }
        // The lamp: the most sensitive range's white every second for lamp_s.
        let start = self.client.transport().now();
        let mut series: Vec<(f64, f64)> = Vec::new();
        loop {
            let (at, value) = self.white_reading(0)?;
            let t = (at - start).as_secs_f64();
            series.push((t, value));
            if t >= lamp_s {
                break;
            }
            self.client.keep_alive(Duration::from_millis(900))?;
        }
        let mean = series.iter().map(|p| p.1).sum::<f64>() / series.len() as f64;
        let relative: Vec<(f64, f64)> = series.iter().map(|&(t, v)| (t, v / mean)).collect();
        let drift = slope(&relative);
        let lamp = LampFigures {
            drift_pct_per_h: Measured {
                value: drift.value * 100.0 * 3600.0,
                u: drift.u * 100.0 * 3600.0,
            },
            over_s: relative.last().map_or(0.0, |p| p.0),
        };
        Ok(White {
            noise,
            lamp,
            series: relative,
        })
    }

    /// One white reading on `range` above dark, and when it was taken.
    fn white_reading(&mut self, range: u8) -> Result<(Duration, f64), CharacterizeError> {
        match self.request(Command::TakeReading {
            integration_ms: INTEGRATION_MS,
            target: Target::WhiteReference,
            range: Some(range),
        })? {
            Reply::Reading(r) => Ok((
                self.client.transport().now(),
                f64::from(r.mean_counts)
                    - self.dark.get(usize::from(range)).copied().unwrap_or(0.0),
            )),
            other => Err(unexpected("TakeReading", other)),
        }
    }
}

/// The marker of a sweep that saturated (tried again on a less sensitive range).
const SATURATED: &str = "saturated";

fn unexpected(command: &'static str, reply: Reply) -> CharacterizeError {
    CharacterizeError::Link(LinkError::UnexpectedReply {
        command,
        reply: Box::new(reply),
    })
}

/// Least-squares slope of (t, y) and its standard error.
fn slope(points: &[(f64, f64)]) -> Measured {
    let n = points.len() as f64;
    if points.len() < 3 {
        return Measured {
            value: f64::NAN,
            u: f64::NAN,
        };
    }
    let (mt, my) = (
        points.iter().map(|p| p.0).sum::<f64>() / n,
        points.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let stt: f64 = points.iter().map(|p| (p.0 - mt).powi(2)).sum();
    let sty: f64 = points.iter().map(|p| (p.0 - mt) * (p.1 - my)).sum();
    let b = sty / stt;
    let rss: f64 = points
        .iter()
        .map(|p| (p.1 - my - b * (p.0 - mt)).powi(2))
        .sum();
    Measured {
        value: b,
        u: (rss / (n - 2.0) / stt).sqrt(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slope_and_its_error() {
        let points: Vec<(f64, f64)> = (0..10).map(|k| (k as f64, 1.0 + 0.01 * k as f64)).collect();
        let s = slope(&points);
        assert!((s.value - 0.01).abs() < 1e-12 && s.u < 1e-9);
        assert!(slope(&points[..2]).value.is_nan());
    }
}
