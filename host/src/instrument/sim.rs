//! The simulated instrument from the host's side: the options shared by `gonio sim` and
//! `gonio measure --sim`, the samples it can hold, and the in-process [`Transport`].
//!
//! The simulator knows no fit: its sheets are its own physics ([`hil_sim::sheet`]), which
//! this module maps the sample names to (the reference papers of
//! [`crate::analysis::classify::REFERENCES`], or `custom:`), with the options of the
//! realistic sheet and instrument. One sample is no sheet: `black-glass` (`BG`), the
//! polished black glass gloss standard ([`hil_sim::scene::BlackGlass`]), a mirror through
//! which the detector's own angular response can be measured.
//!
//! `--physics drawn` is an instrument that is not the one the host assumes: besides the
//! realistic errors, its detector response (shape and width), its arm zero and its noise are
//! drawn from the seed and announced to nobody ([`SimOptions::instrument_truth`] tells a
//! test or a study what they are), so that characterizing it is tested as on a built one.

use crate::analysis::classify::REFERENCES;
use crate::analysis::model::{self, Params};
use crate::instrument::link::Transport;
use firmware::hardware::Arm;
use hil_sim::detector::Response;
use hil_sim::scene::{BlackGlass, SamplePort, WhiteTile};
use hil_sim::sheet::{Departures, Lobe, SheetError, SheetSpec, Stock};
use hil_sim::table::{TableError, TableScene};
use hil_sim::{DEFAULT_UNPLUG_S, Faults, InstrumentErrors, SimConfig, SimInstrument, Unplug};
use rand::Rng;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

impl Transport for SimInstrument {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.write(bytes)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        SimInstrument::read(self, buf, timeout)
    }

    fn pause(&mut self, duration: Duration) {
        // At least the pause asked for, in the simulator's whole milliseconds: rounded down,
        // a pause under 1 ms would not move device time at all.
        self.advance_ms(u64::try_from(duration.as_micros().div_ceil(1000)).unwrap_or(u64::MAX));
    }

    /// Device time: waiting on the simulator runs it forward instead of sleeping.
    fn now(&self) -> Duration {
        Duration::from_micros(self.device_time_us())
    }

    fn now_is_device_time(&self) -> bool {
        true
    }

    /// The simulator in process lives and dies with this host process: no earlier host
    /// can have used its sequence numbers. A fixed start keeps a seed's run repeatable
    /// (the numbers' encoded length changes which bytes the link faults hit).
    fn first_seq(&self) -> u32 {
        1
    }

    fn sample_moved(&mut self) {
        self.next_spot();
    }

    fn name(&self) -> String {
        "the simulated instrument (in process)".to_string()
    }
}

/// Which set of instrument errors the simulator starts from (each one overridable).
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Physics {
    /// The ideal instrument: exact nominal gains, the tile exactly its certificate, no
    /// arm zero error (the detector window and the lamp drift are on, as always).
    #[default]
    Ideal,
    /// The realistic set: detector window, range-gain error, tile error, lamp drift and an
    /// arm zero error, the lobe kept Gaussian.
    // (The figures are `REAL_PHYSICS`'s; no intra-doc link here: clap prints this text.)
    Real,
    /// An instrument unlike the declared one: the realistic gain, tile
    /// and lamp errors, and drawn from the seed its detector response (top-hat, Gaussian or
    /// trapezoid, FWHM 0.3–3°), its arm zero error (uniform in ±0.5°) and its noise scale
    /// (log-uniform in [0.5, 2]).
    Drawn,
}

/// The facet distribution of the simulated sheet's specular lobe.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LobeChoice {
    /// exp(−θa²/2σ²): the TSL lobe.
    #[default]
    Gaussian,
    /// Trowbridge–Reitz (GGX) with the Gaussian's FWHM: tails as θa⁻⁴.
    Ggx,
    /// Cauchy (Lorentzian) with the Gaussian's FWHM: tails as θa⁻².
    Cauchy,
    /// Beckmann (Cook–Torrance) with the Gaussian's FWHM, σ ≤ 39°.
    Beckmann,
    /// Blinn–Phong, cosⁿθa, with the Gaussian's FWHM.
    BlinnPhong,
}

impl LobeChoice {
    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            LobeChoice::Gaussian => "gaussian",
            LobeChoice::Ggx => "ggx",
            LobeChoice::Cauchy => "cauchy",
            LobeChoice::Beckmann => "beckmann",
            LobeChoice::BlinnPhong => "blinn-phong",
        }
    }
}

impl From<LobeChoice> for Lobe {
    fn from(choice: LobeChoice) -> Lobe {
        match choice {
            LobeChoice::Gaussian => Lobe::Gaussian,
            LobeChoice::Ggx => Lobe::Ggx,
            LobeChoice::Cauchy => Lobe::Cauchy,
            LobeChoice::Beckmann => Lobe::Beckmann,
            LobeChoice::BlinnPhong => Lobe::BlinnPhong,
        }
    }
}

/// The forms of `--departure`, for its help and its errors.
pub const DEPARTURE_FORMS: &str = "haze:FRACTION:SIGMA_DEG, peak-shift:DEG, asymmetry:RATIO, fresnel-flat:T, sigma-slope:K, oren-nayar:ROUGHNESS_DEG, grazing:T or retro:AMPLITUDE:WIDTH_DEG";

/// The departures from TSL of `--departure` items (each `NAME:VALUE[:VALUE]`, each name at
/// most once), their ranges left to the sheet ([`SheetSpec::validate`]).
pub fn parse_departures(items: &[String]) -> Result<Departures, SimOptionError> {
    let mut d = Departures::NONE;
    let mut seen: Vec<String> = Vec::new();
    for item in items {
        let bad = |why: String| SimOptionError::BadDeparture {
            spec: item.clone(),
            why,
        };
        let mut parts = item.split(':').map(str::trim);
        let name = parts.next().unwrap_or_default().to_ascii_lowercase();
        let values = parts
            .map(|v| {
                v.parse::<f64>()
                    .map_err(|_| bad(format!("'{v}' is not a number")))
            })
            .collect::<Result<Vec<f64>, _>>()?;
        let form = match name.as_str() {
            "haze" => "haze:FRACTION:SIGMA_DEG",
            "peak-shift" => "peak-shift:DEG",
            "asymmetry" => "asymmetry:RATIO",
            "fresnel-flat" => "fresnel-flat:T",
            "sigma-slope" => "sigma-slope:K",
            "oren-nayar" => "oren-nayar:ROUGHNESS_DEG",
            "grazing" => "grazing:T",
            "retro" => "retro:AMPLITUDE:WIDTH_DEG",
            _ => return Err(bad(format!("no departure '{name}': use {DEPARTURE_FORMS}"))),
        };
        let wanted = form.matches(':').count();
        if values.len() != wanted {
            return Err(bad(format!(
                "{name} takes {wanted} value{}: {form}",
                if wanted == 1 { "" } else { "s" }
            )));
        }
        if seen.contains(&name) {
            return Err(bad(format!("{name} is given twice")));
        }
        seen.push(name.clone());
        match name.as_str() {
            "haze" => (d.haze, d.haze_sigma_deg) = (values[0], values[1]),
            "peak-shift" => d.peak_shift_deg = values[0],
            "asymmetry" => d.asymmetry = values[0],
            "fresnel-flat" => d.fresnel_flat = values[0],
            "sigma-slope" => d.sigma_slope = values[0],
            "oren-nayar" => d.oren_nayar_deg = values[0],
            "grazing" => d.grazing = values[0],
            _ => (d.retro, d.retro_width_deg) = (values[0], values[1]),
        }
    }
    Ok(d)
}

/// Magnitudes of one set of instrument errors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PhysicsSet {
    /// Relative standard deviation of each adjacent range-gain ratio's error, percent.
    pub(crate) gain_error_pct: f64,
    /// Relative standard deviation of the white tile's true radiance factor about its
    /// certificate, percent.
    pub(crate) tile_error_pct: f64,
    /// Lamp drift, percent per hour (its sign drawn from the seed).
    pub lamp_drift_pct_per_h: f64,
    /// Detector arm zero error, degrees.
    pub arm_offset_deg: f64,
    /// Standard deviation of a drawn detector arm zero error, degrees (added to the fixed
    /// one, drawn from the seed).
    pub(crate) arm_zero_sd_deg: f64,
}

/// `--physics ideal`: today's ideal instrument.
pub(crate) const IDEAL_PHYSICS: PhysicsSet = PhysicsSet {
    gain_error_pct: 0.0,
    tile_error_pct: 0.0,
    lamp_drift_pct_per_h: 0.2,
    arm_offset_deg: 0.0,
    arm_zero_sd_deg: 0.0,
};

/// `--physics real`: the effects the uncertainty budget and the model account for, at
/// magnitudes a built instrument has before its own calibration of them:
///
/// - gain error 1 % per adjacent ratio: the transimpedance ranges are set by 1 % feedback
///   resistors (two per ratio, plus the amplifier's own gain error), so an uncalibrated
///   decade is off by about 1 % (issue 12 measured that 1–2 % moves SG's ρs by 17 %);
/// - tile error 0.5 %: a calibrated white tile's certificate states its radiance factor to
///   about ±1 % at k = 2, i.e. 0.5 % standard uncertainty;
/// - lamp drift 0.2 %/h: the reference instrument's value, as in the ideal set;
/// - arm offset N(0, 0.1°), drawn from the seed: the detector's zero, set at the home
///   switch and by aligning the aperture, is good to about 8 microsteps (0.1°), small
///   against the glossy lobe's 1.6° standard deviation in θr but seen by a fit (0.3° moves
///   G's σ by 5 %); drawn like the gains and the tile, so that over many seeds the
///   instruments are a population whose zero is known to 0.1°, the uncertainty a session
///   assumes ([`crate::analysis::fit::DEFAULT_ARM_ZERO_UNCERTAINTY_DEG`]);
/// - the detector window (1° full width) as in the ideal set.
pub(crate) const REAL_PHYSICS: PhysicsSet = PhysicsSet {
    gain_error_pct: 1.0,
    tile_error_pct: 0.5,
    lamp_drift_pct_per_h: 0.2,
    arm_offset_deg: 0.0,
    arm_zero_sd_deg: 0.1,
};

/// `--physics drawn`: the gain, tile and lamp errors of [`REAL_PHYSICS`]; the arm zero is
/// drawn uniform in ±[`DRAWN_ARM_ZERO_HALF_RANGE_DEG`] instead of normal (its standard
/// deviation, 0.5°/√3, is what this set states), and with it the response and the noise
/// ([`DrawnInstrument`]).
pub(crate) const DRAWN_PHYSICS: PhysicsSet = PhysicsSet {
    gain_error_pct: 1.0,
    tile_error_pct: 0.5,
    lamp_drift_pct_per_h: 0.2,
    arm_offset_deg: 0.0,
    arm_zero_sd_deg: DRAWN_ARM_ZERO_HALF_RANGE_DEG / SQRT_3,
};

/// √3: a uniform's half-range over its standard deviation.
const SQRT_3: f64 = 1.732_050_807_568_877_2;

/// The FWHMs a drawn detector response takes, degrees (uniform between): from a detector
/// much sharper than the declared 1° to one three times as wide, on which a glossy paper's
/// fit must know it.
pub const DRAWN_FWHM_RANGE_DEG: (f64, f64) = (0.3, 3.0);

/// A drawn trapezoid's top as a fraction of its base (uniform between).
pub const DRAWN_TOP_FRACTION_RANGE: (f64, f64) = (0.2, 0.8);

/// A drawn arm zero error is uniform in ± this, degrees: five times the 0.1° a session
/// assumes, what an instrument whose zero was never measured may be off by.
pub const DRAWN_ARM_ZERO_HALF_RANGE_DEG: f64 = 0.5;

/// A drawn noise scale is log-uniform between these (half to twice the reference's).
pub const DRAWN_NOISE_SCALE_RANGE: (f64, f64) = (0.5, 2.0);

/// What `--physics drawn` draws of the instrument beyond the errors the simulator draws
/// itself (gains, tile): from the seed's stream [`hil_sim::streams::DRAWN_INSTRUMENT`], so
/// the detector's noise and every other draw stay what they were.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DrawnInstrument {
    /// The detector's angular response.
    pub response: Response,
    /// The detector arm's zero error, degrees.
    pub arm_zero_deg: f64,
    /// The detector's noise relative to the reference instrument's.
    pub noise_scale: f64,
}

impl DrawnInstrument {
    /// The instrument drawn for `seed`. Every value is drawn whatever the options override,
    /// in a fixed order, so that overriding one leaves the others as they were.
    pub fn draw(seed: u64) -> DrawnInstrument {
        let mut rng = hil_sim::stream(seed, hil_sim::streams::DRAWN_INSTRUMENT);
        let shape: f64 = rng.random();
        let fwhm_deg = lerp(DRAWN_FWHM_RANGE_DEG, rng.random());
        let top_fraction = lerp(DRAWN_TOP_FRACTION_RANGE, rng.random());
        let arm_zero_deg = DRAWN_ARM_ZERO_HALF_RANGE_DEG * (2.0 * rng.random::<f64>() - 1.0);
        let (low, high) = DRAWN_NOISE_SCALE_RANGE;
        let noise_scale = (low.ln() + (high.ln() - low.ln()) * rng.random::<f64>()).exp();
        let response = if shape < 1.0 / 3.0 {
            Response::TopHat {
                width_deg: fwhm_deg,
            }
        } else if shape < 2.0 / 3.0 {
            Response::Gaussian { fwhm_deg }
        } else {
            // FWHM = (top + base)/2 with top = fraction × base.
            let base_deg = 2.0 * fwhm_deg / (1.0 + top_fraction);
            Response::Trapezoid {
                top_deg: top_fraction * base_deg,
                base_deg,
            }
        };
        DrawnInstrument {
            response,
            arm_zero_deg,
            noise_scale,
        }
    }
}

/// The point a fraction `u` of the way from `range.0` to `range.1`.
fn lerp(range: (f64, f64), u: f64) -> f64 {
    range.0 + (range.1 - range.0) * u
}

/// What the simulated instrument truly is (none of it announced to the host), for tests
/// and studies that check what a characterization finds.
#[derive(Clone, Debug, PartialEq)]
pub struct InstrumentTruth {
    /// The detector's angular response.
    pub response: Response,
    /// Detector arm zero error, degrees: the true θr is the firmware's plus this (a mirror's
    /// peak appears at the firmware's θr = θi − this).
    pub arm_zero_deg: f64,
    /// The detector's noise relative to the reference instrument's (1: as the host
    /// assumes).
    pub noise_scale: f64,
    /// True gain of each range relative to range 0's nominal gain (nominal 1, 0.1, 0.01).
    pub relative_gains: Vec<f64>,
    /// Each adjacent range-gain ratio's relative error: the true g(k)/g(k−1) over its
    /// nominal, minus 1, for k = 1, 2, ….
    pub gain_ratio_errors: Vec<f64>,
    /// The white tile's true radiance factor over its certificate's.
    pub tile_factor: f64,
    /// Lamp drift, fraction per hour of device time, signed.
    pub lamp_drift_per_hour: f64,
}

/// Options of the simulated instrument (the same on `gonio sim` and `gonio measure --sim`).
#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct SimOptions {
    /// Seed of the simulated noise and link faults: the same seed repeats a run exactly
    /// (default: one drawn for the run, printed and recorded in session.json; a resumed
    /// session's recorded one).
    #[arg(long = "seed", value_name = "N")]
    pub seed_given: Option<u64>,
    /// The seed in use: `--seed`, else what [`SimOptions::with_seed`] drew or was given
    /// (1 when built in code without one).
    #[arg(skip = 1u64)]
    pub seed: u64,
    /// Detector acceptance, full width, degrees: a top-hat response (0: a point detector;
    /// --response gives another shape).
    #[arg(long, value_name = "DEG", default_value_t = model::DEFAULT_ACCEPTANCE_DEG, allow_negative_numbers = true)]
    pub acceptance: f64,
    /// The detector's angular response in place of --acceptance's top-hat (and of the drawn
    /// one): top-hat:WIDTH, gaussian:FWHM or trapezoid:TOP,BASE, full widths in degrees.
    #[arg(long, value_name = "SHAPE:DEG", conflicts_with = "acceptance")]
    pub response: Option<String>,
    /// Scale of every detector noise term (1 = the reference instrument, 0 = noiseless; with
    /// --physics drawn it multiplies the drawn instrument's own scale).
    #[arg(
        long,
        value_name = "FACTOR",
        default_value_t = 1.0,
        allow_negative_numbers = true
    )]
    pub noise_scale: f64,
    /// Faults to inject: corrupt=P,drop=P,unplug-at=T[:SECONDS],lose-steps=ARM:COUNT,no-switch=ARM
    /// (ARM is source or detector). unplug-at pulls the cable at device time T for SECONDS
    /// (default 1; past the 2 s heartbeat timeout the instrument takes its fail-safe stop)
    /// and may be given more than once. What `gonio selftest` checks: stuck-switch=ARM (reads
    /// pressed everywhere), diag-stuck=ARM (the driver's fault line reads a fault),
    /// crystal=HZ (the crystal the boot measured), step-timer=PCT (the step timers' tick off
    /// by PCT %), range-lines=N (the range lines read back range N).
    #[arg(long, value_name = "LIST", default_value = "")]
    pub faults: String,
    /// Instrument errors to start from: ideal (exact gains and tile, no arm zero error), real
    /// (gain error 1 %, tile error 0.5 %, lamp drift 0.2 %/h, arm offset drawn N(0, 0.1°)) or
    /// drawn (real's gain, tile and lamp errors; from the seed a detector response, top-hat,
    /// Gaussian or trapezoid of FWHM 0.3–3°, an arm offset uniform in ±0.5° and a noise scale
    /// log-uniform in [0.5, 2], none of it announced to the host); --response and the options
    /// below override single values.
    #[arg(long, value_enum, default_value_t = Physics::Ideal)]
    pub physics: Physics,
    /// Facet distribution of the sheet's specular lobe; ggx and cauchy have the Gaussian's
    /// FWHM in θr and heavier tails.
    #[arg(long, value_enum, default_value_t = LobeChoice::Gaussian)]
    pub lobe: LobeChoice,
    /// Share of --lobe's shape in a blend with the Gaussian of the same FWHM (two facet
    /// populations): 1 the lobe alone, 0.5 half each.
    #[arg(
        long,
        value_name = "W",
        default_value_t = 1.0,
        allow_negative_numbers = true
    )]
    pub lobe_weight: f64,
    /// A departure of the sheet from TSL (repeatable, each once): haze:FRACTION:SIGMA_DEG
    /// (a broad second lobe, its peak FRACTION of the main one's), peak-shift:DEG (the lobe
    /// centred at θr = θi + DEG), asymmetry:RATIO (σ past the peak over σ before it),
    /// fresnel-flat:T (the Fresnel factor flattened toward F(45°), 1 flat), sigma-slope:K
    /// (σ(θi) = σ·(1 + K·(θi − 45°)/45°)), oren-nayar:ROUGHNESS_DEG (an Oren–Nayar body),
    /// grazing:T (the body blended with Lommel–Seeliger's, rising toward grazing),
    /// retro:AMPLITUDE:WIDTH_DEG (the body's surge toward retro-reflection). The stock's σ,
    /// ρs, ρd stay the truth: the main lobe's half-maximum width, the body at 45°/0°.
    #[arg(long, value_name = "NAME:VALUES", allow_hyphen_values = true)]
    pub departure: Vec<String>,
    /// Forward scattering of fibrous papers: F·u² added, u = (θr − θi)/(90° − θi) past
    /// specular (0 before it): a radiance factor F at grazing θr.
    #[arg(
        long,
        value_name = "F",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub forward_lobe: f64,
    /// The narrow rise around specular seen on J1/J2: B·cos²θi·exp(−(θr − θi)²/(2·2.5²))
    /// added (2.5° standard deviation in θr).
    #[arg(
        long,
        value_name = "B",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub specular_bump: f64,
    /// Detector arm zero error: the true θr is the firmware's plus DEG exactly [ideal 0, real: drawn N(0, 0.1°) from the seed, drawn: uniform in ±0.5°].
    #[arg(long, value_name = "DEG", allow_negative_numbers = true)]
    pub arm_offset: Option<f64>,
    /// Each range-gain ratio to the range before it off its nominal by N(0, PCT %), drawn
    /// from the seed; range 0 is the reference [ideal 0, real and drawn 1].
    #[arg(long, value_name = "PCT", allow_negative_numbers = true)]
    pub gain_error: Option<f64>,
    /// The white tile's true radiance factor: its certificate (0.99) × (1 + N(0, PCT %)),
    /// drawn from the seed [ideal 0, real and drawn 0.5].
    #[arg(long, value_name = "PCT", allow_negative_numbers = true)]
    pub tile_error: Option<f64>,
    /// Lamp drift, percent per hour of device time, its sign drawn from the seed [0.2].
    #[arg(long, value_name = "PCT", allow_negative_numbers = true)]
    pub lamp_drift_pct_per_h: Option<f64>,
    /// Between-spot variation of the sheet: each spot draws σ, ρs and ρd log-normally
    /// about the stock's, relative standard deviation PCT %; a new spot whenever the
    /// sample goes back on after the white tile.
    #[arg(
        long,
        value_name = "PCT",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub sheet_variation: f64,
    /// Replay a table of radiance factors (the CSV gonio fit reads: theta_i, theta_r,
    /// radiance_factor) instead of a built-in sheet; the sample name is then a label.
    /// PCHIP in θr, linear in θi, the edge value held outside.
    #[arg(long, value_name = "CSV")]
    pub scene_file: Option<PathBuf>,
    /// Times the simulated instrument was switched on before for this session (0: a new
    /// session; a resumed one counts its earlier runs): its detector noise is then its
    /// own, as a real instrument's is after a restart ([`hil_sim::SimConfig::power_on`]).
    #[arg(skip)]
    pub power_on: u64,
}

impl Default for SimOptions {
    /// The same as no option on the command line.
    fn default() -> Self {
        SimOptions {
            seed_given: None,
            seed: 1,
            acceptance: model::DEFAULT_ACCEPTANCE_DEG,
            response: None,
            noise_scale: 1.0,
            faults: String::new(),
            physics: Physics::Ideal,
            lobe: LobeChoice::Gaussian,
            lobe_weight: 1.0,
            departure: Vec::new(),
            forward_lobe: 0.0,
            specular_bump: 0.0,
            arm_offset: None,
            gain_error: None,
            tile_error: None,
            lamp_drift_pct_per_h: None,
            sheet_variation: 0.0,
            scene_file: None,
            power_on: 0,
        }
    }
}

/// Runs a session folder (or a sheet folder and its spots' sessions) records: what a
/// resumed session's simulated instrument counts as its earlier power-ons. 0 for a folder
/// that is not there or not readable (the resume itself says what is wrong with it).
pub(crate) fn runs_recorded(dir: &std::path::Path) -> u64 {
    let runs_in = |file: PathBuf| -> u64 {
        std::fs::read(&file)
            .ok()
            .and_then(|bytes| serde_json::from_slice::<serde_json::Value>(&bytes).ok())
            .and_then(|doc| {
                doc.get("runs")
                    .and_then(serde_json::Value::as_array)
                    .map(|runs| runs.len() as u64)
            })
            .unwrap_or(0)
    };
    let mut total = runs_in(dir.join("session.json")) + runs_in(dir.join("sheet.json"));
    if let Ok(entries) = std::fs::read_dir(dir) {
        for entry in entries.flatten() {
            if entry.path().is_dir() {
                total += runs_in(entry.path().join("session.json"));
            }
        }
    }
    total
}

impl SimOptions {
    /// The options with their seed settled, as the command line means it: `--seed`, else
    /// `recorded` (a resumed session's), else one drawn for this run, so that two runs of
    /// the same sample are two measurements, not one twice (issue 31).
    pub fn with_seed(mut self, recorded: Option<u64>) -> SimOptions {
        self.seed = self
            .seed_given
            .or(recorded)
            .unwrap_or_else(|| rand::rng().random_range(1..1_000_000));
        self
    }
}

/// The simulator's seed a session or sheet folder recorded (`instrument.simulated_seed` of
/// its `session.json`, or of its first spot's), for `--resume` to continue with.
pub fn recorded_seed(dir: &std::path::Path) -> Option<u64> {
    let seed_in = |file: PathBuf| -> Option<u64> {
        let bytes = std::fs::read(file).ok()?;
        let doc: serde_json::Value = serde_json::from_slice(&bytes).ok()?;
        doc.get("instrument")?.get("simulated_seed")?.as_u64()
    };
    seed_in(dir.join("session.json")).or_else(|| {
        let mut spots: Vec<PathBuf> = std::fs::read_dir(dir)
            .ok()?
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.is_dir())
            .collect();
        spots.sort();
        spots
            .into_iter()
            .find_map(|p| seed_in(p.join("session.json")))
    })
}

/// Longest outage `unplug-at` accepts: a day of device time.
const MAX_UNPLUG_S: f64 = 86_400.0;

/// A bad simulator option.
#[derive(Debug, thiserror::Error)]
pub enum SimOptionError {
    /// Not a sample the simulator knows.
    #[error(
        "unknown sample '{0}': use one of G, SG, PPC, MC, J1, J2, J3, J4, custom:SIGMA,RHO_S,RHO_D,ETA or black-glass (BG)"
    )]
    UnknownSample(String),
    /// The black glass asked for as a sheet (its TSL parameters, a sheet's options).
    #[error("sample '{0}' is the black glass standard, a mirror: it has no sheet's TSL parameters")]
    NotASheet(String),
    /// A sheet's option given with the black glass.
    #[error(
        "--{option} does not apply to sample '{sample}': it is the black glass standard, not a sheet"
    )]
    SheetOption {
        /// The option given.
        option: &'static str,
        /// The sample.
        sample: String,
    },
    /// The black glass with a point detector: it would read nothing but dark.
    #[error(
        "sample '{0}' is a mirror: a point detector (--acceptance 0, or a response of width 0) never meets its beam, which is no wider than the lamp's; give the detector a width"
    )]
    MirrorNeedsWidth(String),
    /// A bad `--response`.
    #[error("bad --response '{spec}': {why}")]
    BadResponse {
        /// What was given.
        spec: String,
        /// What is wrong.
        why: String,
    },
    /// A custom sample with bad parameters.
    #[error("bad custom sample '{spec}': {why}")]
    BadCustom {
        /// What was given.
        spec: String,
        /// What is wrong.
        why: String,
    },
    /// A bad `--faults` item.
    #[error("bad fault '{item}' in --faults: {why}")]
    BadFault {
        /// The item.
        item: String,
        /// What is wrong.
        why: String,
    },
    /// A bad number option.
    #[error("--{option} must be {why}, got {value}")]
    BadOption {
        /// Which option.
        option: &'static str,
        /// What it must be.
        why: &'static str,
        /// What was given.
        value: f64,
    },
    /// Options that do not go together.
    #[error("--{option} does not apply with --{other}: {why}")]
    Conflict {
        /// The option given.
        option: &'static str,
        /// The option it conflicts with.
        other: &'static str,
        /// Why.
        why: &'static str,
    },
    /// A `--departure` item that is not one.
    #[error("bad --departure '{spec}': {why}")]
    BadDeparture {
        /// The item.
        spec: String,
        /// What is wrong.
        why: String,
    },
    /// A sheet option the sample's sheet cannot take (a departure's range, a lobe or a
    /// departure that makes σ wider than the lobe can be).
    #[error("--{option} does not fit sample '{sample}': {why}")]
    SheetRange {
        /// The option, with its value where it has one (`lobe beckmann`).
        option: String,
        /// The sample.
        sample: String,
        /// What is wrong.
        why: String,
    },
    /// A scene file that cannot be replayed.
    #[error("--scene-file {0}")]
    SceneFile(#[from] TableError),
}

/// Whether a sample name is the black glass standard: `black-glass` or `BG`, any case.
pub fn is_black_glass(name: &str) -> bool {
    name.eq_ignore_ascii_case("black-glass") || name.eq_ignore_ascii_case("bg")
}

/// What a sample name puts on the simulated port.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SimSample {
    /// A sheet of paper of these TSL parameters (a reference paper or `custom:`).
    Sheet(Params),
    /// The black glass gloss standard: a mirror.
    BlackGlass,
}

/// What sample `name` is: the black glass, or a sheet ([`sample_params`]).
pub fn parse_sample(name: &str) -> Result<SimSample, SimOptionError> {
    if is_black_glass(name) {
        Ok(SimSample::BlackGlass)
    } else {
        sample_params(name).map(SimSample::Sheet)
    }
}

/// The response `--response` names: `top-hat:WIDTH` (or `tophat:`), `gaussian:FWHM`,
/// `trapezoid:TOP,BASE`, full widths in degrees (0: a point detector).
pub fn parse_response(spec: &str) -> Result<Response, SimOptionError> {
    let bad = |why: &str| SimOptionError::BadResponse {
        spec: spec.to_owned(),
        why: why.to_owned(),
    };
    let shapes = "SHAPE:DEG is top-hat:WIDTH, gaussian:FWHM or trapezoid:TOP,BASE";
    let (shape, widths) = spec.split_once(':').ok_or_else(|| bad(shapes))?;
    let widths: Vec<f64> = widths
        .split(',')
        .map(|w| {
            w.trim()
                .parse::<f64>()
                .map_err(|_| bad(&format!("'{}' is not a number of degrees", w.trim())))
        })
        .collect::<Result<_, _>>()?;
    let response = match (shape.trim().to_ascii_lowercase().as_str(), &widths[..]) {
        ("top-hat" | "tophat", &[width_deg]) => Response::TopHat { width_deg },
        ("gaussian", &[fwhm_deg]) => Response::Gaussian { fwhm_deg },
        ("trapezoid", &[top_deg, base_deg]) => Response::Trapezoid { top_deg, base_deg },
        ("top-hat" | "tophat" | "gaussian", _) => return Err(bad("one width is needed")),
        ("trapezoid", _) => return Err(bad("two widths are needed: TOP,BASE")),
        _ => return Err(bad(shapes)),
    };
    response.validate().map_err(|e| bad(&e.to_string()))?;
    Ok(response)
}

/// The TSL parameters of a sample name: a reference paper (any case) or
/// `custom:SIGMA,RHO_S,RHO_D,ETA` (the black glass has none: [`parse_sample`]).
pub fn sample_params(name: &str) -> Result<Params, SimOptionError> {
    if is_black_glass(name) {
        return Err(SimOptionError::NotASheet(name.to_owned()));
    }
    if let Some(spec) = name.strip_prefix("custom:") {
        let bad = |why: &str| SimOptionError::BadCustom {
            spec: spec.to_owned(),
            why: why.to_owned(),
        };
        let values: Vec<f64> = spec
            .split(',')
            .map(|v| {
                v.trim()
                    .parse::<f64>()
                    .map_err(|_| bad(&format!("'{}' is not a number", v.trim())))
            })
            .collect::<Result<_, _>>()?;
        let [sigma_deg, rho_s, rho_d, eta] = values[..] else {
            return Err(bad("four numbers are needed: SIGMA,RHO_S,RHO_D,ETA"));
        };
        if values.iter().any(|v| !v.is_finite()) {
            return Err(bad("every value must be finite"));
        }
        if !(sigma_deg > 0.0 && sigma_deg <= 90.0) {
            return Err(bad("SIGMA must be in (0, 90] degrees"));
        }
        if rho_s < 0.0 || rho_d < 0.0 {
            return Err(bad("RHO_S and RHO_D must not be negative"));
        }
        if !(1.0..=3.0).contains(&eta) {
            return Err(bad("ETA must be in [1, 3]"));
        }
        return Ok(Params {
            sigma_deg,
            rho_s,
            rho_d,
            eta,
        });
    }
    REFERENCES
        .iter()
        .find(|r| r.name.eq_ignore_ascii_case(name))
        .map(|r| r.params)
        .ok_or_else(|| SimOptionError::UnknownSample(name.to_owned()))
}

fn parse_arm(item: &str, value: &str) -> Result<Arm, SimOptionError> {
    match value.to_ascii_lowercase().as_str() {
        "source" | "i" | "0" => Ok(Arm::Source),
        "detector" | "r" | "1" => Ok(Arm::Detector),
        _ => Err(SimOptionError::BadFault {
            item: item.to_owned(),
            why: "ARM is source or detector".into(),
        }),
    }
}

/// Parse `--faults`.
pub(crate) fn parse_faults(spec: &str) -> Result<Faults, SimOptionError> {
    let mut faults = SimConfig::default().faults;
    for item in spec.split(',').map(str::trim).filter(|i| !i.is_empty()) {
        let bad = |why: &str| SimOptionError::BadFault {
            item: item.to_owned(),
            why: why.to_owned(),
        };
        let (key, value) = item
            .split_once('=')
            .ok_or_else(|| bad("expected KEY=VALUE"))?;
        let number = |v: &str| v.trim().parse::<f64>().ok().filter(|x| x.is_finite());
        match key.trim() {
            "corrupt" | "drop" => {
                let p = number(value)
                    .filter(|p| (0.0..=1.0).contains(p))
                    .ok_or_else(|| bad("a probability in [0, 1]"))?;
                if key.trim() == "corrupt" {
                    faults.corrupt = p
                } else {
                    faults.drop = p
                }
            }
            "unplug-at" => {
                let (at, out) = match value.split_once(':') {
                    Some((at, out)) => (at, Some(out)),
                    None => (value, None),
                };
                let at_s = number(at)
                    .filter(|s| *s >= 0.0)
                    .ok_or_else(|| bad("T is seconds of device time, ≥ 0"))?;
                let for_s = match out {
                    None => DEFAULT_UNPLUG_S,
                    Some(out) => number(out)
                        .filter(|s| *s > 0.0 && *s <= MAX_UNPLUG_S)
                        .ok_or_else(|| {
                            bad("SECONDS (how long the cable stays out) is in (0, 86400]")
                        })?,
                };
                faults.unplugs.push(Unplug::new(at_s, for_s));
            }
            "lose-steps" => {
                let (arm, count) = value
                    .split_once(':')
                    .ok_or_else(|| bad("expected lose-steps=ARM:COUNT"))?;
                let count = count
                    .trim()
                    .parse::<i32>()
                    .ok()
                    .filter(|c| *c > 0)
                    .ok_or_else(|| bad("COUNT is a positive whole number"))?;
                faults.lose_steps = Some((parse_arm(item, arm)?, count));
            }
            "no-switch" => faults.switch_missing = Some(parse_arm(item, value)?),
            "stuck-switch" => faults.switch_stuck = Some(parse_arm(item, value)?),
            "diag-stuck" => faults.diag_stuck = Some(parse_arm(item, value)?),
            "crystal" => {
                let hz = value
                    .trim()
                    .parse::<u32>()
                    .ok()
                    .filter(|hz| (1_000_000..=50_000_000).contains(hz))
                    .ok_or_else(|| bad("HZ is a whole number of hertz in 1000000..=50000000"))?;
                faults.crystal_hz = Some(hz);
            }
            "step-timer" => {
                let pct = number(value)
                    .filter(|p| (-50.0..=100.0).contains(p))
                    .ok_or_else(|| bad("PCT is a percentage in [-50, 100]"))?;
                faults.step_timer_error = pct / 100.0;
            }
            "range-lines" => {
                let range = value
                    .trim()
                    .parse::<u8>()
                    .ok()
                    .ok_or_else(|| bad("N is a range number, 0..=255"))?;
                faults.range_lines = Some(range);
            }
            _ => {
                return Err(bad(
                    "known faults: corrupt, drop, unplug-at, lose-steps, no-switch, stuck-switch, diag-stuck, crystal, step-timer, range-lines",
                ));
            }
        }
    }
    Ok(faults)
}

/// Check a number option against its range.
fn checked(
    option: &'static str,
    value: f64,
    why: &'static str,
    ok: impl Fn(f64) -> bool,
) -> Result<f64, SimOptionError> {
    if value.is_finite() && ok(value) {
        Ok(value)
    } else {
        Err(SimOptionError::BadOption { option, why, value })
    }
}

impl SimOptions {
    /// The instrument errors in force: the `--physics` set with single values overridden.
    pub(crate) fn physics_set(&self) -> PhysicsSet {
        let base = match self.physics {
            Physics::Ideal => IDEAL_PHYSICS,
            Physics::Real => REAL_PHYSICS,
            Physics::Drawn => DRAWN_PHYSICS,
        };
        PhysicsSet {
            gain_error_pct: self.gain_error.unwrap_or(base.gain_error_pct),
            tile_error_pct: self.tile_error.unwrap_or(base.tile_error_pct),
            lamp_drift_pct_per_h: self
                .lamp_drift_pct_per_h
                .unwrap_or(base.lamp_drift_pct_per_h),
            arm_offset_deg: self.arm_offset.unwrap_or(base.arm_offset_deg),
            // An offset given is the offset: nothing drawn on top.
            arm_zero_sd_deg: if self.arm_offset.is_some() {
                0.0
            } else {
                base.arm_zero_sd_deg
            },
        }
    }

    /// The simulated instrument's configuration (everything but the sample).
    pub fn config(&self) -> Result<SimConfig, SimOptionError> {
        checked(
            "acceptance",
            self.acceptance,
            "between 0 and 10 degrees",
            |v| (0.0..=10.0).contains(&v),
        )?;
        checked("noise-scale", self.noise_scale, "a number ≥ 0", |v| {
            v >= 0.0
        })?;
        let set = self.physics_set();
        checked(
            "gain-error",
            set.gain_error_pct,
            "a percentage in [0, 20]",
            |v| (0.0..=20.0).contains(&v),
        )?;
        checked(
            "tile-error",
            set.tile_error_pct,
            "a percentage in [0, 20]",
            |v| (0.0..=20.0).contains(&v),
        )?;
        checked(
            "lamp-drift-pct-per-h",
            set.lamp_drift_pct_per_h,
            "a percentage per hour in [0, 100]",
            |v| (0.0..=100.0).contains(&v),
        )?;
        checked(
            "arm-offset",
            set.arm_offset_deg,
            "between -5 and 5 degrees",
            |v| (-5.0..=5.0).contains(&v),
        )?;
        let drawn = DrawnInstrument::draw(self.seed);
        let is_drawn = self.physics == Physics::Drawn;
        // --acceptance is the top-hat's width: with another response in force it would be
        // silently ignored (the default value is no choice).
        let acceptance_given = self.acceptance != model::DEFAULT_ACCEPTANCE_DEG;
        let response = match &self.response {
            Some(spec) => {
                if acceptance_given {
                    return Err(SimOptionError::Conflict {
                        option: "acceptance",
                        other: "response",
                        why: "--response sets the whole response (--acceptance W is top-hat:W)",
                    });
                }
                parse_response(spec)?
            }
            None if is_drawn => {
                if acceptance_given {
                    return Err(SimOptionError::Conflict {
                        option: "acceptance",
                        other: "physics drawn",
                        why: "the drawn instrument's response is drawn from the seed; --response replaces it",
                    });
                }
                drawn.response
            }
            None => Response::TopHat {
                width_deg: self.acceptance,
            },
        };
        // A zero given is exact; the drawn instrument's otherwise is its uniform draw.
        let (offset_deg, offset_sd_deg) = match (is_drawn, self.arm_offset) {
            (true, None) => (drawn.arm_zero_deg, 0.0),
            _ => (set.arm_offset_deg, set.arm_zero_sd_deg),
        };
        let mut config = SimConfig {
            seed: self.seed,
            power_on: self.power_on,
            faults: parse_faults(&self.faults)?,
            ..SimConfig::default()
        };
        config.detector.response = response;
        config.detector.noise_scale = if is_drawn {
            self.noise_scale * drawn.noise_scale
        } else {
            self.noise_scale
        };
        config.detector.lamp_drift_per_hour = set.lamp_drift_pct_per_h / 100.0;
        config.errors = InstrumentErrors {
            gain_ratio_sd: set.gain_error_pct / 100.0,
            tile_sd: set.tile_error_pct / 100.0,
            theta_r_offset_deg: offset_deg,
            theta_r_offset_sd_deg: offset_sd_deg,
        };
        Ok(config)
    }

    /// What the simulated instrument of these options truly is: the values its run draws
    /// (the same draws, [`SimConfig::truth`]), for tests and studies that check what a
    /// characterization of it finds. The white tile is the reference one.
    pub fn instrument_truth(&self) -> Result<InstrumentTruth, SimOptionError> {
        let truth = self.config()?.truth(WhiteTile::default());
        Ok(InstrumentTruth {
            response: truth.response,
            arm_zero_deg: truth.theta_r_offset_deg,
            noise_scale: truth.noise_scale,
            relative_gains: truth.relative_gains,
            gain_ratio_errors: truth.gain_ratio_factors.iter().map(|f| f - 1.0).collect(),
            tile_factor: truth.tile_factor,
            lamp_drift_per_hour: truth.lamp_drift_per_hour,
        })
    }

    /// The simulated sheet of `sample` with the sheet options (not for `--scene-file`).
    pub fn sheet(&self, sample: &str) -> Result<SheetSpec, SimOptionError> {
        let p = sample_params(sample)?;
        let lobe_weight = checked("lobe-weight", self.lobe_weight, "in [0, 1]", |v| {
            (0.0..=1.0).contains(&v)
        })?;
        if lobe_weight != 1.0 && self.lobe == LobeChoice::Gaussian {
            return Err(SimOptionError::Conflict {
                option: "lobe-weight",
                other: "lobe gaussian",
                why: "it is the share of another lobe's shape in a blend with the Gaussian",
            });
        }
        let departures = Departures {
            lobe_weight,
            ..parse_departures(&self.departure)?
        };
        let spec = SheetSpec {
            stock: Stock {
                sigma_deg: p.sigma_deg,
                rho_s: p.rho_s,
                rho_d: p.rho_d,
                eta: p.eta,
            },
            lobe: self.lobe.into(),
            forward_lobe: checked(
                "forward-lobe",
                self.forward_lobe,
                "a radiance factor in [0, 100]",
                |v| (0.0..=100.0).contains(&v),
            )?,
            specular_bump: checked(
                "specular-bump",
                self.specular_bump,
                "a radiance factor in [0, 100]",
                |v| (0.0..=100.0).contains(&v),
            )?,
            spot_variation: checked(
                "sheet-variation",
                self.sheet_variation,
                "a percentage in [0, 50]",
                |v| (0.0..=50.0).contains(&v),
            )? / 100.0,
            departures: Departures::NONE,
        };
        // Only the lobe's limit on σ can fail here: everything else was checked above.
        spec.validate()
            .map_err(|e: SheetError| SimOptionError::SheetRange {
                option: format!("lobe {}", self.lobe.name()),
                sample: sample.to_owned(),
                why: e.to_string(),
            })?;
        let spec = SheetSpec { departures, ..spec };
        spec.validate().map_err(|e| SimOptionError::SheetRange {
            option: "departure".to_owned(),
            sample: sample.to_owned(),
            why: e.to_string(),
        })?;
        Ok(spec)
    }

    /// What is on the sample port: `sample`'s sheet or the black glass, or the replayed
    /// `--scene-file`.
    pub fn port(&self, sample: &str) -> Result<SamplePort, SimOptionError> {
        let Some(path) = &self.scene_file else {
            if is_black_glass(sample) {
                let sheet_option = [
                    ("lobe", self.lobe != LobeChoice::Gaussian),
                    ("lobe-weight", self.lobe_weight != 1.0),
                    ("departure", !self.departure.is_empty()),
                    ("forward-lobe", self.forward_lobe != 0.0),
                    ("specular-bump", self.specular_bump != 0.0),
                    ("sheet-variation", self.sheet_variation != 0.0),
                ]
                .into_iter()
                .find(|(_, given)| *given);
                if let Some((option, _)) = sheet_option {
                    return Err(SimOptionError::SheetOption {
                        option,
                        sample: sample.to_owned(),
                    });
                }
                return Ok(SamplePort::new(Arc::new(BlackGlass::default())));
            }
            return Ok(SamplePort::with_spots(
                Arc::new(self.sheet(sample)?),
                self.seed,
            ));
        };
        let why = "a replayed table is the whole scene";
        let conflict = |option| {
            Err(SimOptionError::Conflict {
                option,
                other: "scene-file",
                why,
            })
        };
        if self.lobe != LobeChoice::Gaussian {
            return conflict("lobe");
        }
        if self.lobe_weight != 1.0 {
            return conflict("lobe-weight");
        }
        if !self.departure.is_empty() {
            return conflict("departure");
        }
        if self.forward_lobe != 0.0 {
            return conflict("forward-lobe");
        }
        if self.specular_bump != 0.0 {
            return conflict("specular-bump");
        }
        if self.sheet_variation != 0.0 {
            return conflict("sheet-variation");
        }
        Ok(SamplePort::new(Arc::new(TableScene::read(path)?)))
    }

    /// The simulated instrument with `sample` on its port.
    pub fn instrument(&self, sample: &str) -> Result<SimInstrument, SimOptionError> {
        let config = self.config()?;
        let port = self.port(sample)?;
        if port.sample.mirror_index().is_some() && config.detector.response.is_point() {
            return Err(SimOptionError::MirrorNeedsWidth(sample.to_owned()));
        }
        Ok(SimInstrument::new(port, config))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_by_name_and_custom() {
        assert_eq!(sample_params("g").unwrap().sigma_deg, 0.8);
        assert_eq!(sample_params("J4").unwrap().rho_d, 0.346);
        let p = sample_params("custom:2.5,10,0.8,1.5").unwrap();
        assert_eq!(
            (p.sigma_deg, p.rho_s, p.rho_d, p.eta),
            (2.5, 10.0, 0.8, 1.5)
        );
        for bad in [
            "XX",
            "custom:1,2,3",
            "custom:0,1,1,1.5",
            "custom:1,-1,1,1.5",
            "custom:1,1,1,4",
            "custom:1,a,1,2",
            "custom:nan,1,1,2",
        ] {
            assert!(sample_params(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn faults_parse_and_refuse_nonsense() {
        let f = parse_faults(
            "corrupt=0.001, drop=0.002,unplug-at=5,lose-steps=detector:37,no-switch=source",
        )
        .unwrap();
        assert_eq!((f.corrupt, f.drop), (0.001, 0.002));
        assert_eq!(f.unplugs, vec![Unplug::new(5.0, DEFAULT_UNPLUG_S)]);
        assert_eq!(f.lose_steps, Some((Arm::Detector, 37)));
        assert_eq!(f.switch_missing, Some(Arm::Source));
        assert_eq!(parse_faults("").unwrap(), SimConfig::default().faults);
        let f = parse_faults("unplug-at=3:0.25,unplug-at=40:12.5,unplug-at=7").unwrap();
        assert_eq!(
            f.unplugs,
            vec![
                Unplug::new(3.0, 0.25),
                Unplug::new(40.0, 12.5),
                Unplug::new(7.0, 1.0)
            ]
        );
        for bad in [
            "corrupt=2",
            "drop=x",
            "unplug-at=-1",
            "unplug-at=5:0",
            "unplug-at=5:-2",
            "unplug-at=5:x",
            "unplug-at=5:inf",
            "unplug-at=:3",
            "lose-steps=left:3",
            "lose-steps=source:0",
            "melt=1",
            "corrupt",
        ] {
            let error = parse_faults(bad).unwrap_err().to_string();
            assert!(error.contains(bad.split(',').next().unwrap()), "{error}");
        }
    }

    /// `gonio sim SAMPLE [options]` as clap parses it.
    fn parsed(args: &[&str]) -> Result<SimOptions, clap::Error> {
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            options: SimOptions,
        }
        use clap::Parser;
        // As a command settles it: `--seed`, else 1 (what code without one builds with).
        Cli::try_parse_from(std::iter::once("sim").chain(args.iter().copied()))
            .map(|c| c.options.with_seed(Some(1)))
    }

    #[test]
    fn default_options_are_no_options() {
        assert_eq!(parsed(&[]).unwrap(), SimOptions::default());
        assert_eq!(SimOptions::default().physics_set(), IDEAL_PHYSICS);
        let config = SimOptions::default().config().unwrap();
        assert_eq!(config.errors, InstrumentErrors::default());
        assert_eq!(
            config.detector,
            hil_sim::detector::DetectorParams::default()
        );
    }

    #[test]
    fn physics_real_is_the_documented_set_and_each_value_overrides_it() {
        let real = parsed(&["--physics", "real"]).unwrap();
        assert_eq!(real.physics_set(), REAL_PHYSICS);
        let config = real.config().unwrap();
        assert_eq!(
            config.errors,
            InstrumentErrors {
                gain_ratio_sd: 0.01,
                tile_sd: 0.005,
                theta_r_offset_deg: 0.0,
                theta_r_offset_sd_deg: 0.1
            }
        );
        assert_eq!(config.detector.lamp_drift_per_hour, 0.002);
        assert_eq!(
            config.detector.response,
            Response::TopHat { width_deg: 1.0 }
        );
        let mixed = parsed(&[
            "--physics",
            "real",
            "--gain-error",
            "2",
            "--arm-offset",
            "-0.3",
            "--lamp-drift-pct-per-h",
            "0",
        ])
        .unwrap();
        assert_eq!(
            mixed.physics_set(),
            PhysicsSet {
                gain_error_pct: 2.0,
                tile_error_pct: 0.5,
                lamp_drift_pct_per_h: 0.0,
                arm_offset_deg: -0.3,
                arm_zero_sd_deg: 0.0
            }
        );
        let ideal_plus = parsed(&["--tile-error", "1.5"]).unwrap();
        assert_eq!(
            ideal_plus.physics_set(),
            PhysicsSet {
                tile_error_pct: 1.5,
                ..IDEAL_PHYSICS
            }
        );
    }

    #[test]
    fn sheet_options_reach_the_sheet() {
        let o = parsed(&[
            "--lobe",
            "cauchy",
            "--forward-lobe",
            "0.3",
            "--specular-bump",
            "0.1",
            "--sheet-variation",
            "5",
        ])
        .unwrap();
        let spec = o.sheet("J1").unwrap();
        assert_eq!(spec.lobe, Lobe::Cauchy);
        assert_eq!(
            (spec.forward_lobe, spec.specular_bump, spec.spot_variation),
            (0.3, 0.1, 0.05)
        );
        assert_eq!(
            spec.stock,
            Stock {
                sigma_deg: 16.7,
                rho_s: 0.734,
                rho_d: 0.127,
                eta: 3.0
            }
        );
        // The stock's numbers are the host's Table 6, mapped field by field.
        let p = sample_params("SG").unwrap();
        assert_eq!(
            SimOptions::default().sheet("sg").unwrap().stock,
            Stock {
                sigma_deg: p.sigma_deg,
                rho_s: p.rho_s,
                rho_d: p.rho_d,
                eta: p.eta
            }
        );
    }

    #[test]
    fn bad_values_are_refused_naming_option_and_value() {
        let cases: [(&[&str], &str); 12] = [
            (
                &["--gain-error", "25"],
                "--gain-error must be a percentage in [0, 20], got 25",
            ),
            (
                &["--gain-error", "nan"],
                "--gain-error must be a percentage in [0, 20], got NaN",
            ),
            (
                &["--tile-error", "-1"],
                "--tile-error must be a percentage in [0, 20], got -1",
            ),
            (
                &["--lamp-drift-pct-per-h", "inf"],
                "--lamp-drift-pct-per-h must be a percentage per hour in [0, 100], got inf",
            ),
            (
                &["--arm-offset", "7"],
                "--arm-offset must be between -5 and 5 degrees, got 7",
            ),
            (
                &["--forward-lobe", "-0.1"],
                "--forward-lobe must be a radiance factor in [0, 100], got -0.1",
            ),
            (
                &["--specular-bump", "1e9"],
                "--specular-bump must be a radiance factor in [0, 100], got 1000000000",
            ),
            (
                &["--sheet-variation", "60"],
                "--sheet-variation must be a percentage in [0, 50], got 60",
            ),
            (
                &["--acceptance", "-1"],
                "--acceptance must be between 0 and 10 degrees, got -1",
            ),
            (
                &["--lobe", "ggx", "--scene-file", "x.csv"],
                "--lobe does not apply with --scene-file",
            ),
            (
                &["--sheet-variation", "1", "--scene-file", "x.csv"],
                "--sheet-variation does not apply with --scene-file",
            ),
            (
                &["--scene-file", "/nonexistent/x.csv"],
                "--scene-file /nonexistent/x.csv: cannot read",
            ),
        ];
        for (args, expected) in cases {
            let options = parsed(args).unwrap();
            let error = options
                .instrument("G")
                .err()
                .unwrap_or_else(|| panic!("{args:?} accepted"))
                .to_string();
            assert!(
                error.starts_with(expected),
                "{args:?}: {error:?} should start with {expected:?}"
            );
        }
        let wide = parsed(&["--lobe", "ggx"])
            .unwrap()
            .instrument("custom:80,1,1,2")
            .err()
            .unwrap()
            .to_string();
        assert!(
            wide.contains("custom") && wide.contains("ggx") && wide.contains("80"),
            "{wide}"
        );
        for args in [
            &["--lobe", "lorentz"][..],
            &["--physics", "perfect"],
            &["--gain-error", "one"],
        ] {
            let error = parsed(args).unwrap_err().to_string();
            assert!(
                error.contains(args[1]) && error.contains(args[0]),
                "{args:?}: {error}"
            );
        }
    }

    #[test]
    fn departures_reach_the_sheet() {
        let o = parsed(&[
            "--lobe",
            "blinn-phong",
            "--lobe-weight",
            "0.5",
            "--departure",
            "haze:0.03:4",
            "--departure",
            "peak-shift:-0.4",
            "--departure",
            "Asymmetry:1.5",
            "--departure",
            "fresnel-flat:1",
            "--departure",
            "sigma-slope:-0.4",
            "--departure",
            "oren-nayar:20",
            "--departure",
            "grazing:0.3",
            "--departure",
            "retro: 0.5 : 15",
        ])
        .unwrap();
        let spec = o.sheet("G").unwrap();
        assert_eq!(spec.lobe, Lobe::BlinnPhong);
        assert_eq!(
            spec.departures,
            Departures {
                lobe_weight: 0.5,
                haze: 0.03,
                haze_sigma_deg: 4.0,
                peak_shift_deg: -0.4,
                asymmetry: 1.5,
                fresnel_flat: 1.0,
                sigma_slope: -0.4,
                oren_nayar_deg: 20.0,
                grazing: 0.3,
                retro: 0.5,
                retro_width_deg: 15.0,
            }
        );
        assert_eq!(
            spec.equivalent_truth(),
            SimOptions::default().sheet("G").unwrap().stock
        );
        assert!(o.instrument("G").is_ok());
        assert_eq!(
            SimOptions::default().sheet("G").unwrap().departures,
            Departures::NONE
        );
        assert_eq!(
            parsed(&["--lobe", "beckmann"])
                .unwrap()
                .sheet("J1")
                .unwrap()
                .lobe,
            Lobe::Beckmann
        );
    }

    #[test]
    fn bad_departures_are_refused_saying_what_is_wrong() {
        for (args, says) in [
            (
                &["--departure", "fog:0.1"][..],
                "bad --departure 'fog:0.1': no departure 'fog': use haze:FRACTION:SIGMA_DEG",
            ),
            (
                &["--departure", "haze:0.03"],
                "bad --departure 'haze:0.03': haze takes 2 values: haze:FRACTION:SIGMA_DEG",
            ),
            (
                &["--departure", "grazing:0.3:2"],
                "bad --departure 'grazing:0.3:2': grazing takes 1 value: grazing:T",
            ),
            (
                &["--departure", "peak-shift:left"],
                "bad --departure 'peak-shift:left': 'left' is not a number",
            ),
            (
                &["--departure", "grazing:0.3", "--departure", "grazing:0.5"],
                "bad --departure 'grazing:0.5': grazing is given twice",
            ),
            (
                &["--departure", "haze:0.03:0.5"],
                "--departure does not fit sample 'G': haze sigma must be wider than the main lobe's sigma",
            ),
            (
                &["--departure", "sigma-slope:-1"],
                "--departure does not fit sample 'G': sigma slope must be in [-0.9, 0.9]",
            ),
            (
                &["--departure", "retro:0.5:0"],
                "--departure does not fit sample 'G': retro width must be in (0, 90] degrees, got 0",
            ),
            (
                &["--lobe-weight", "0.5"],
                "--lobe-weight does not apply with --lobe gaussian",
            ),
            (
                &["--lobe", "ggx", "--lobe-weight", "2"],
                "--lobe-weight must be in [0, 1], got 2",
            ),
            (
                &["--departure", "grazing:0.3", "--scene-file", "x.csv"],
                "--departure does not apply with --scene-file",
            ),
        ] {
            let error = parsed(args)
                .unwrap()
                .instrument("G")
                .err()
                .unwrap_or_else(|| panic!("{args:?} accepted"))
                .to_string();
            assert!(error.starts_with(says), "{args:?}: {error}");
        }
        let mc = parsed(&["--lobe", "beckmann"])
            .unwrap()
            .instrument("MC")
            .err()
            .unwrap()
            .to_string();
        assert!(
            mc.starts_with("--lobe beckmann does not fit sample 'MC': sigma of a beckmann lobe must be at most 39 degrees"),
            "{mc}"
        );
        for args in [
            &["--departure", "haze:0.03:4"][..],
            &["--lobe-weight", "0.5"],
        ] {
            let error = parsed(args)
                .unwrap()
                .instrument("BG")
                .err()
                .unwrap()
                .to_string();
            assert!(
                error.starts_with(&format!(
                    "{} does not apply to sample 'BG'",
                    args[args.len() - 2]
                )),
                "{args:?}: {error}"
            );
        }
    }

    #[test]
    fn responses_parse_and_refuse_nonsense() {
        assert_eq!(
            parse_response("top-hat:0.5").unwrap(),
            Response::TopHat { width_deg: 0.5 }
        );
        assert_eq!(
            parse_response("Gaussian:2").unwrap(),
            Response::Gaussian { fwhm_deg: 2.0 }
        );
        assert_eq!(
            parse_response("trapezoid:0.2, 0.6").unwrap(),
            Response::Trapezoid {
                top_deg: 0.2,
                base_deg: 0.6
            }
        );
        assert!(parse_response("tophat:0").unwrap().is_point());
        for (bad, says) in [
            ("gaussian", "SHAPE:DEG is top-hat:WIDTH"),
            ("cone:1", "SHAPE:DEG is top-hat:WIDTH"),
            ("gaussian:x", "'x' is not a number of degrees"),
            ("top-hat:1,2", "one width is needed"),
            ("trapezoid:1", "two widths are needed"),
            ("trapezoid:0.8,0.4", "must not be wider than its base"),
            ("gaussian:-1", "in [0, 10] degrees, got -1"),
            ("gaussian:nan", "got NaN"),
            ("top-hat:11", "got 11"),
        ] {
            let error = parse_response(bad).unwrap_err().to_string();
            assert!(
                error.starts_with(&format!("bad --response '{bad}': ")) && error.contains(says),
                "{bad}: {error}"
            );
        }
    }

    #[test]
    fn the_response_is_the_acceptance_the_drawn_one_or_the_one_given() {
        let response = |args: &[&str]| parsed(args).unwrap().config().map(|c| c.detector.response);
        assert_eq!(
            response(&["--acceptance", "0.5"]).unwrap(),
            Response::TopHat { width_deg: 0.5 }
        );
        assert_eq!(
            response(&["--response", "gaussian:2"]).unwrap(),
            Response::Gaussian { fwhm_deg: 2.0 }
        );
        assert_eq!(
            response(&["--physics", "drawn", "--seed", "9"]).unwrap(),
            DrawnInstrument::draw(9).response
        );
        assert_eq!(
            response(&["--physics", "drawn", "--response", "top-hat:1"]).unwrap(),
            Response::TopHat { width_deg: 1.0 }
        );
        let error = response(&["--physics", "drawn", "--acceptance", "2"])
            .unwrap_err()
            .to_string();
        assert!(
            error.starts_with("--acceptance does not apply with --physics drawn"),
            "{error}"
        );
        // Both given on the command line: clap refuses; both set in code: so does config.
        assert!(parsed(&["--acceptance", "2", "--response", "gaussian:1"]).is_err());
        let both = SimOptions {
            acceptance: 2.0,
            response: Some("gaussian:1".into()),
            ..SimOptions::default()
        };
        let error = both.config().unwrap_err().to_string();
        assert!(
            error.starts_with("--acceptance does not apply with --response"),
            "{error}"
        );
    }

    #[test]
    fn the_black_glass_by_name_and_what_does_not_go_with_it() {
        for name in ["black-glass", "BG", "bg", "Black-Glass"] {
            assert_eq!(parse_sample(name).unwrap(), SimSample::BlackGlass, "{name}");
            let error = sample_params(name).unwrap_err().to_string();
            assert!(error.contains("black glass standard, a mirror"), "{error}");
        }
        assert!(matches!(parse_sample("G"), Ok(SimSample::Sheet(p)) if p.sigma_deg == 0.8));
        assert!(
            sample_params("XX")
                .unwrap_err()
                .to_string()
                .contains("black-glass (BG)")
        );
        let port = SimOptions::default().port("BG").unwrap();
        assert_eq!(
            port.sample.mirror_index(),
            Some(hil_sim::scene::BLACK_GLASS_INDEX)
        );
        assert!(port.spots.is_none());
        assert!(SimOptions::default().instrument("black-glass").is_ok());
        for (args, says) in [
            (
                &["--lobe", "ggx"][..],
                "--lobe does not apply to sample 'BG'",
            ),
            (
                &["--sheet-variation", "5"],
                "--sheet-variation does not apply to sample 'BG'",
            ),
            (
                &["--specular-bump", "0.1"],
                "--specular-bump does not apply to sample 'BG'",
            ),
            (
                &["--acceptance", "0"],
                "sample 'BG' is a mirror: a point detector",
            ),
            (&["--response", "gaussian:0"], "sample 'BG' is a mirror"),
        ] {
            let error = parsed(args)
                .unwrap()
                .instrument("BG")
                .err()
                .unwrap_or_else(|| panic!("{args:?} accepted"))
                .to_string();
            assert!(error.starts_with(says), "{args:?}: {error}");
        }
    }

    #[test]
    fn drawn_physics_is_real_with_a_drawn_response_zero_and_noise_each_overridable() {
        let drawn = parsed(&["--physics", "drawn", "--seed", "4"]).unwrap();
        assert_eq!(drawn.physics_set(), DRAWN_PHYSICS);
        let config = drawn.config().unwrap();
        let draw = DrawnInstrument::draw(4);
        let real = parsed(&["--physics", "real", "--seed", "4"])
            .unwrap()
            .config()
            .unwrap();
        assert_eq!(config.errors.gain_ratio_sd, real.errors.gain_ratio_sd);
        assert_eq!(config.errors.tile_sd, real.errors.tile_sd);
        assert_eq!(
            config.detector.lamp_drift_per_hour,
            real.detector.lamp_drift_per_hour
        );
        assert_eq!(
            (
                config.errors.theta_r_offset_deg,
                config.errors.theta_r_offset_sd_deg
            ),
            (draw.arm_zero_deg, 0.0)
        );
        assert_eq!(config.detector.noise_scale, draw.noise_scale);
        assert_eq!(config.detector.response, draw.response);
        // The gains and the tile are the real instrument's draws, of the same seed.
        let truth = drawn.instrument_truth().unwrap();
        let real_truth = real.truth(WhiteTile::default());
        assert_eq!(truth.relative_gains, real_truth.relative_gains);
        assert_eq!(truth.tile_factor, real_truth.tile_factor);
        // Each override replaces its value only.
        let overridden = parsed(&[
            "--physics",
            "drawn",
            "--seed",
            "4",
            "--arm-offset",
            "0.2",
            "--noise-scale",
            "0",
            "--gain-error",
            "2",
        ])
        .unwrap()
        .config()
        .unwrap();
        assert_eq!(
            (
                overridden.errors.theta_r_offset_deg,
                overridden.errors.theta_r_offset_sd_deg
            ),
            (0.2, 0.0)
        );
        assert_eq!(overridden.detector.noise_scale, 0.0);
        assert_eq!(overridden.errors.gain_ratio_sd, 0.02);
        assert_eq!(overridden.detector.response, draw.response);
        let noisier = parsed(&["--physics", "drawn", "--seed", "4", "--noise-scale", "2"])
            .unwrap()
            .config()
            .unwrap();
        assert_eq!(noisier.detector.noise_scale, 2.0 * draw.noise_scale);
    }
}
