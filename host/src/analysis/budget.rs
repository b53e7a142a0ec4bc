//! The uncertainty budget, pure (no I/O): the errors a calibration makes common to many
//! readings, as shared terms for the fit, and the report of what each term contributes to
//! the variance of σ, ρs and ρd.
//!
//! A reading's radiance factor is R = (S − D_r)/G_r / ((W − D_w)/G_w) · T: its own counts S
//! on range r, the dark D of a range, the white reading W at its θi (on range w), the gains
//! G (products of the ratios of adjacent ranges) and the tile's certified T. Only S's noise
//! is the reading's own (`Calibration::convert`'s `own_std`); every other error is shared:
//!
//! | term | one ε per | touches | sensitivity (radiance factor per unit ε) |
//! |---|---|---|---|
//! | `white θi=…°` | incidence angle | readings at that θi | −R · u(W)/(W − D_w) |
//! | `dark range r` | range | readings on r, readings whose white is on r, and through a calibrated ratio of r every reading whose gain uses it | u(D_r) · ∂R/∂D_r |
//! | `tile certificate` | calibration | every reading | R · u(T)/T |
//! | `gain ranges r/r+1` | adjacent pair | readings whose range and white's range straddle the pair | ∓R · u(ρ)/ρ |
//! | `lamp drift` | calibration | every reading, by its age | R · u(rate) · age |
//!
//! A reused calibration's age is in each reading's age, so the drift term grows with it.
//!
//! The magnitudes, on the reference instrument at 100 ms, and where they come from:
//!
//! - white, dark: the readings' own standard errors (std/√n), as measured; a white reading
//!   is good to 0.11 % (θi = 20°) – 0.17 % (60°), a dark to 0.02 % of full scale;
//! - tile: the certificate's, `--tile-uncertainty-pct` (default 0.5 %, k = 1: a working
//!   standard certified to ±1 % at k = 2), recorded in calibration.json;
//! - gains: a ratio the session calibrated (`session::gains`: 0.25–0.4 % own noise, the
//!   darks' share through it in the dark terms), else the nominal one at 1 %
//!   (`NOMINAL_GAIN_RATIO_RELATIVE_UNCERTAINTY`, an instrument assumption: the firmware's
//!   configuration announces exact decades without a tolerance);
//! - drift: 0.2 %/h (the reference instrument) times the time since the white readings: nothing within
//!   a session, 0.8 % for a calibration reused 4 h later.

use crate::analysis::calibration::{
    Calibration, CalibrationError, Conversion, standard_error_counts,
};
use crate::analysis::fit::FitResult;
use crate::analysis::model;
use protocol::Reading;
use serde_json::{Value, json};

pub use crate::analysis::fit::{BudgetTerm, SharedError};

/// Name of the fit's independent term (the readings' own noise); the fit adds "(estimated
/// from the residuals)" when the readings carried no uncertainty.
pub(crate) const READING_NOISE: &str = "reading noise";
/// Name of the fit's term for the widening under lack of fit.
pub(crate) const LACK_OF_FIT: &str = "lack of fit";
/// Name of the tile's term.
pub const TILE: &str = "tile certificate";
/// Name of the drift term.
pub const LAMP_DRIFT: &str = "lamp drift";

/// Name of the white reading's term at `theta_i_deg`.
pub(crate) fn white_name(theta_i_deg: f64) -> String {
    format!("white θi={theta_i_deg}°")
}

/// Name of a range's dark term.
pub(crate) fn dark_name(range: u8) -> String {
    format!("dark range {range}")
}

/// Name of the gain term of ranges (r, r + 1).
pub(crate) fn gain_name(lower_range: u8) -> String {
    format!("gain ranges {}/{}", lower_range, u16::from(lower_range) + 1)
}

/// What kind of error a term is, by its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum TermKind {
    /// The readings' own noise.
    ReadingNoise,
    /// A white reading (one term per θi).
    White,
    /// A dark reading (one per range).
    Dark,
    /// The tile's certificate.
    Tile,
    /// A gain ratio (one per pair of adjacent ranges).
    Gain,
    /// The lamp's drift since the white readings.
    Drift,
    /// The detector arm's zero ([`crate::analysis::fit::ARM_ZERO`]), where no offset was fitted.
    ArmZero,
    /// The widening of the intervals when the model does not describe the data.
    LackOfFit,
    /// What the data leave open between shapes of the model (the fit's extension step).
    ModelForm,
    /// Anything else a caller added.
    Other,
}

impl TermKind {
    /// The kind of the term named `name`.
    pub fn of(name: &str) -> TermKind {
        if name.starts_with(READING_NOISE) {
            TermKind::ReadingNoise
        } else if name == LACK_OF_FIT {
            TermKind::LackOfFit
        } else if name.starts_with(crate::analysis::fit::MODEL_FORM) {
            TermKind::ModelForm
        } else if name.starts_with("white ") {
            TermKind::White
        } else if name.starts_with("dark ") {
            TermKind::Dark
        } else if name == TILE {
            TermKind::Tile
        } else if name.starts_with("gain ") {
            TermKind::Gain
        } else if name == LAMP_DRIFT {
            TermKind::Drift
        } else if name == crate::analysis::fit::ARM_ZERO {
            TermKind::ArmZero
        } else {
            TermKind::Other
        }
    }

    /// Its name in the report.
    pub fn name(self) -> &'static str {
        match self {
            TermKind::ReadingNoise => "reading noise",
            TermKind::White => "white readings",
            TermKind::Dark => "dark readings",
            TermKind::Tile => "tile certificate",
            TermKind::Gain => "range gains",
            TermKind::Drift => "lamp drift",
            TermKind::ArmZero => "arm zero",
            TermKind::LackOfFit => "lack of fit",
            TermKind::ModelForm => "model form",
            TermKind::Other => "other",
        }
    }
}

/// One fitted reading as the budget needs it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BudgetReading {
    /// Incidence angle, degrees (selects the white reading).
    pub theta_i_deg: f64,
    /// The raw reading.
    pub reading: Reading,
    /// Time since the white readings of its calibration, seconds (a reused calibration's
    /// age included).
    pub age_s: f64,
}

/// Each reading's time since its calibration's white readings, seconds, from the
/// calibration's age now (`calibration_age_now_s`, wall clock) and the readings' device
/// times: the last reading is taken as now and earlier ones are older by their device-time
/// difference, never younger than their device time since the first reading (which a
/// calibration always precedes). A device clock that restarted (a power cycle) makes the
/// differences meaningless: they are then only clamped to [0, age now].
pub(crate) fn reading_ages_s(calibration_age_now_s: f64, device_times_us: &[u64]) -> Vec<f64> {
    let age_now = calibration_age_now_s.max(0.0);
    let (Some(&first), Some(&last)) = (device_times_us.iter().min(), device_times_us.iter().max())
    else {
        return Vec::new();
    };
    device_times_us
        .iter()
        .map(|&t| {
            let before_last = (last - t) as f64 * 1e-6;
            let since_first = (t - first) as f64 * 1e-6;
            (age_now - before_last).max(since_first).max(0.0)
        })
        .collect()
}

/// The shared errors of `readings` (in the fit's order) under `calibration`. A term that
/// touches none of them is left out.
pub fn shared_errors(
    calibration: &Calibration,
    readings: &[BudgetReading],
) -> Result<Vec<SharedError>, CalibrationError> {
    let conversions = readings
        .iter()
        .map(|r| calibration.convert(r.theta_i_deg, &r.reading))
        .collect::<Result<Vec<_>, _>>()?;
    let n = readings.len();
    // What a multiplicative error scales: the measured value. The fit takes sensitivities
    // per unit of the reading and re-evaluates them at its model's values
    // (`fit::fit_with_shared`), which keeps a reading's own noise out of its covariance
    // (Peelle's puzzle: built from the readings, the tile's term alone put G's ρd 0.25 %,
    // half its interval, low).
    let value: Vec<f64> = conversions.iter().map(|c| c.radiance_factor).collect();
    let ranges = calibration.relative_gains.len();
    let mut terms = Terms(Vec::new());

    white_terms(&mut terms, calibration, &conversions, &value);
    dark_terms(&mut terms, calibration, &conversions, &value)?;

    // The tile: every reading scales with its certified value.
    let u_tile = calibration.white_relative_uncertainty;
    terms.push(
        TILE.to_string(),
        value.iter().map(|r| r * u_tile).collect(),
        Vec::new(),
    );

    // The gain ratio of each pair of adjacent ranges.
    for p in 0..ranges.saturating_sub(1) {
        let (_, relative, _) = calibration.gain_ratio(p as u8)?;
        terms.push(
            gain_name(p as u8),
            conversions
                .iter()
                .zip(&value)
                .map(|(c, r)| r * gain_exponent(p, c) * relative)
                .collect(),
            Vec::new(),
        );
    }

    // The lamp's drift: one unknown rate, times each reading's age.
    let rate_per_s = calibration.lamp_drift_per_hour / 3600.0;
    terms.push(
        LAMP_DRIFT.to_string(),
        value
            .iter()
            .zip(readings)
            .map(|(v, r)| v * rate_per_s * r.age_s.max(0.0))
            .collect(),
        Vec::new(),
    );
    debug_assert!(terms.0.iter().all(|t| t.sensitivity.len() == n));
    Ok(terms.0)
}

/// The shared errors as they are found, each kept only if it touches a reading.
struct Terms(Vec<SharedError>);

impl Terms {
    /// Add a term unless all its sensitivities are 0 (an additive part of zeros is left
    /// empty).
    fn push(&mut self, name: String, sensitivity: Vec<f64>, additive: Vec<f64>) {
        if sensitivity.iter().chain(&additive).any(|s| *s != 0.0) {
            let additive = if additive.iter().any(|s| *s != 0.0) {
                additive
            } else {
                Vec::new()
            };
            self.0.push(SharedError {
                name,
                sensitivity,
                additive,
            });
        }
    }
}

/// d ln R / d ln ρ_p for a reading: its white's gain over its own, where a range's gain
/// contains the ratio of the pair (p, p + 1) when the range is above p.
fn gain_exponent(p: usize, c: &Conversion) -> f64 {
    let uses = |p: usize, range: u8| usize::from(range) > p;
    f64::from(u8::from(uses(p, c.white_range))) - f64::from(u8::from(uses(p, c.range)))
}

/// The white reading at each θi: it scales the readings taken against it.
fn white_terms(
    terms: &mut Terms,
    calibration: &Calibration,
    conversions: &[Conversion],
    value: &[f64],
) {
    for (j, white) in calibration.white.iter().enumerate() {
        let u = standard_error_counts(&white.reading);
        let sensitivity = conversions
            .iter()
            .zip(value)
            .map(|(c, r)| {
                if c.white_index == j {
                    -r * u / c.white_net_counts
                } else {
                    0.0
                }
            })
            .collect();
        terms.push(white_name(white.theta_i_deg), sensitivity, Vec::new());
    }
}

/// The dark of each range: directly, through the white, and through calibrated ratios.
fn dark_terms(
    terms: &mut Terms,
    calibration: &Calibration,
    conversions: &[Conversion],
    value: &[f64],
) -> Result<(), CalibrationError> {
    let ranges = calibration.relative_gains.len();
    for j in 0..ranges {
        let Some(dark) = calibration.dark.get(j) else {
            continue;
        };
        let u = standard_error_counts(dark);
        let mut through_ratios = Vec::new();
        for p in 0..ranges.saturating_sub(1) {
            let Some(g) = calibration.calibrated_ratio(p as u8) else {
                continue;
            };
            // ρ = (U − D_{p+1}) / (L − D_p): d ln ρ / dD.
            let d_ln_rho = if j == p + 1 {
                -1.0 / calibration.net_counts(&g.on_upper)?
            } else if j == p {
                1.0 / calibration.net_counts(&g.on_lower)?
            } else {
                continue;
            };
            // A ratio read at its dark has no derivative to carry (and no ratio either).
            if d_ln_rho.is_finite() {
                through_ratios.push((p, d_ln_rho));
            }
        }
        // The reading's own dark: a fixed offset in counts, T/(G·w) per count, whatever
        // the reading: additive (taken as R/net it was 0/0 on a reading exactly at its
        // dark, a noiseless ρd = 0 sheet's). Through the white and the ratios it scales R.
        let additive: Vec<f64> = conversions
            .iter()
            .map(|c| {
                if usize::from(c.range) == j {
                    // R/net as folders already written computed it (a re-analysis gives
                    // their result to the last bit); per count where that is 0/0.
                    let by_ratio = -c.radiance_factor / c.net_counts * u;
                    if by_ratio.is_finite() {
                        by_ratio
                    } else {
                        -c.per_count * u
                    }
                } else {
                    0.0
                }
            })
            .collect();
        let sensitivity = conversions
            .iter()
            .zip(value)
            .map(|(c, r)| {
                let mut d_ln_r = 0.0;
                if usize::from(c.white_range) == j {
                    d_ln_r += 1.0 / c.white_net_counts;
                }
                for &(p, d_ln_rho) in &through_ratios {
                    d_ln_r += gain_exponent(p, c) * d_ln_rho;
                }
                r * d_ln_r * u
            })
            .collect();
        terms.push(dark_name(j as u8), sensitivity, additive);
    }
    Ok(())
}

/// Indices into a budget term's variance of the parameters the report shares out.
const REPORTED: [(usize, &str); 3] = [
    (model::SIGMA, model::PARAM_NAMES[model::SIGMA]),
    (model::RHO_S, model::PARAM_NAMES[model::RHO_S]),
    (model::RHO_D, model::PARAM_NAMES[model::RHO_D]),
];

/// The variance of σ, ρs, ρd each term of `fit`'s budget contributes; `None` for a
/// parameter the data did not determine (it has no budget to share).
fn reported_variances(fit: &FitResult) -> Vec<(String, [Option<f64>; 3])> {
    let determined: [bool; 3] =
        std::array::from_fn(|i| fit.model.0[REPORTED[i].0] && fit.identified(REPORTED[i].0));
    fit.budget
        .iter()
        .map(|t| {
            (
                t.name.clone(),
                std::array::from_fn(|i| determined[i].then(|| t.variance[REPORTED[i].0].max(0.0))),
            )
        })
        .collect()
}

/// Each variance's share of the column total (`None` where there is none).
fn as_shares(rows: &[[Option<f64>; 3]]) -> Vec<[Option<f64>; 3]> {
    let totals: [f64; 3] = std::array::from_fn(|i| rows.iter().filter_map(|r| r[i]).sum());
    rows.iter()
        .map(|r| std::array::from_fn(|i| r[i].filter(|_| totals[i] > 0.0).map(|v| v / totals[i])))
        .collect()
}

/// Each term's share of the variance of σ, ρs, ρd (`None` for what was not determined).
/// The terms add up to the covariance's diagonal, so the shares add up to 1.
pub fn shares(fit: &FitResult) -> Vec<(String, [Option<f64>; 3])> {
    let rows = reported_variances(fit);
    let shares = as_shares(&rows.iter().map(|(_, v)| *v).collect::<Vec<_>>());
    rows.into_iter()
        .zip(shares)
        .map(|((name, _), share)| (name, share))
        .collect()
}

/// The budget grouped by kind: (kind, variance of σ, ρs, ρd), in the kinds' order.
pub fn by_kind(fit: &FitResult) -> Vec<(TermKind, [Option<f64>; 3])> {
    let mut out: Vec<(TermKind, [Option<f64>; 3])> = Vec::new();
    for (name, v) in reported_variances(fit) {
        let kind = TermKind::of(&name);
        match out.iter_mut().find(|(k, _)| *k == kind) {
            Some((_, sum)) => (0..3).for_each(|i| sum[i] = sum[i].zip(v[i]).map(|(a, b)| a + b)),
            None => out.push((kind, v)),
        }
    }
    out.sort_by_key(|(k, _)| *k);
    out
}

fn per_parameter(values: [Option<f64>; 3]) -> Value {
    let mut m = serde_json::Map::new();
    for (i, (_, key)) in REPORTED.iter().enumerate() {
        m.insert(
            key.to_string(),
            values[i]
                .filter(|s| s.is_finite())
                .map_or(Value::Null, |s| json!(s)),
        );
    }
    Value::Object(m)
}

/// The report's `budget`: every term with its variance and its share of σ's, ρs's and
/// ρd's variance, and the shares grouped by kind (null for a parameter not determined).
pub fn to_json(fit: &FitResult) -> Value {
    let rows = reported_variances(fit);
    let shares = as_shares(&rows.iter().map(|(_, v)| *v).collect::<Vec<_>>());
    let terms: Vec<Value> = rows
        .iter()
        .zip(&shares)
        .map(|((name, variance), share)| {
            json!({
                "name": name,
                "kind": TermKind::of(name).name(),
                "variance": per_parameter(*variance),
                "share": per_parameter(*share),
            })
        })
        .collect();
    let groups = by_kind(fit);
    let group_shares = as_shares(&groups.iter().map(|(_, v)| *v).collect::<Vec<_>>());
    let kinds: Vec<Value> = groups
        .iter()
        .zip(group_shares)
        .map(|((kind, _), share)| json!({ "kind": kind.name(), "share": per_parameter(share) }))
        .collect();
    json!({ "terms": terms, "by_kind": kinds })
}

/// A few lines for the report's table: each kind's share of σ's, ρs's and ρd's variance.
pub fn to_table(fit: &FitResult) -> String {
    let groups = by_kind(fit);
    if groups.len() < 2 {
        return String::new(); // reading noise alone: nothing to share out
    }
    let shares = as_shares(&groups.iter().map(|(_, v)| *v).collect::<Vec<_>>());
    let mut s =
        String::from("  uncertainty budget, share of variance     sigma    rho_s    rho_d\n");
    for ((kind, _), share) in groups.iter().zip(shares) {
        let cell = |i: usize| {
            share[i].map_or_else(
                || format!("{:>8}", "—"),
                |v| format!("{:>6.1} %", 100.0 * v),
            )
        };
        s += &format!(
            "    {:<38} {} {} {}\n",
            kind.name(),
            cell(0),
            cell(1),
            cell(2)
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::calibration::{GainRatio, Tile, WhitePoint};

    fn reading(mean_counts: f32, std_counts: f32, range: u8) -> Reading {
        Reading {
            mean_counts,
            std_counts,
            samples: 100,
            range,
            integration_ms: 100,
            saturated: false,
        }
    }

    /// Darks of 200 counts (σ 130 per sample), whites at 20° and 60° on range 0, and a
    /// calibrated 1/2 ratio.
    fn calibration() -> Calibration {
        let mut c = Calibration::taken_at(
            0,
            "test".into(),
            Tile::default(),
            vec![1.0, 0.1, 0.01],
            vec![
                reading(200.0, 130.0, 0),
                reading(190.0, 130.0, 1),
                reading(210.0, 130.0, 2),
            ],
            vec![
                WhitePoint {
                    theta_i_deg: 20.0,
                    reading: reading(26_400.0, 290.0, 0),
                },
                WhitePoint {
                    theta_i_deg: 60.0,
                    reading: reading(14_200.0, 230.0, 0),
                },
            ],
        );
        let (on_lower, on_upper) = (reading(50_190.0, 400.0, 1), reading(5_240.0, 150.0, 2));
        let (ratio, relative_uncertainty) = c.ratio_from_readings(&on_lower, &on_upper).unwrap();
        c.gain_ratios.push(GainRatio {
            lower_range: 1,
            ratio,
            relative_uncertainty,
            theta_i_deg: 60.0,
            theta_r_deg: 62.0,
            scene: "sample".into(),
            on_lower,
            on_upper,
            device_seconds: 1.0,
        });
        c
    }

    fn readings() -> Vec<BudgetReading> {
        let at = |theta_i_deg: f64, mean: f32, range: u8, age_s: f64| BudgetReading {
            theta_i_deg,
            reading: reading(mean, 200.0, range),
            age_s,
        };
        vec![
            at(20.0, 13_000.0, 0, 0.0),
            at(20.0, 30_000.0, 1, 10.0),
            at(60.0, 9_000.0, 0, 20.0),
            at(60.0, 40_000.0, 1, 30.0),
            at(60.0, 20_000.0, 2, 40.0),
        ]
    }

    fn term<'a>(terms: &'a [SharedError], name: &str) -> &'a SharedError {
        terms
            .iter()
            .find(|t| t.name == name)
            .unwrap_or_else(|| panic!("no term {name}"))
    }

    /// A reading exactly at its range's dark (a noiseless ρd = 0 sheet away from the
    /// peak) has a dark term like any other, and no NaN anywhere (it stopped the session:
    /// "shared error 'dark range 0', reading 0: sensitivity NaN").
    #[test]
    fn a_reading_at_the_dark_has_finite_sensitivities() {
        let c = calibration();
        let mut rs = readings();
        rs[0].reading.mean_counts = 200.0;
        rs[2].reading.mean_counts = 200.0;
        let terms = shared_errors(&c, &rs).unwrap();
        for t in &terms {
            for k in 0..rs.len() {
                assert!(t.total(k).is_finite(), "{}: reading {k}", t.name);
            }
        }
        // The dark's own offset is an offset there too: per count the same as elsewhere
        // on the range, against the same white.
        let dark = term(&terms, "dark range 0");
        assert!(dark.additive[0] < 0.0);
        let bright = c.convert(20.0, &readings()[0].reading).unwrap();
        let u = standard_error_counts(&c.dark[0]);
        assert!((dark.additive[0] + bright.per_count * u).abs() < 1e-15);
    }

    #[test]
    fn each_term_touches_only_its_readings() {
        let c = calibration();
        let terms = shared_errors(&c, &readings()).unwrap();
        let touched = |name: &str| -> Vec<bool> {
            (0..5).map(|k| term(&terms, name).total(k) != 0.0).collect()
        };
        assert_eq!(touched("white θi=20°"), [true, true, false, false, false]);
        assert_eq!(touched("white θi=60°"), [false, false, true, true, true]);
        assert_eq!(touched("tile certificate"), [true; 5]);
        // Range 0/1 straddles every reading on range 1 or 2 (the whites are on 0).
        assert_eq!(touched("gain ranges 0/1"), [false, true, false, true, true]);
        assert_eq!(
            touched("gain ranges 1/2"),
            [false, false, false, false, true]
        );
        // Dark 0: the readings on 0, and every white (on 0).
        assert_eq!(touched("dark range 0"), [true; 5]);
        // Dark 1: readings on 1, and through the calibrated 1/2 ratio the reading on 2.
        assert_eq!(touched("dark range 1"), [false, true, false, true, true]);
        assert_eq!(touched("dark range 2"), [false, false, false, false, true]);
        assert_eq!(touched("lamp drift"), [false, true, true, true, true]);
        // No reading at 30°: no term for it.
        assert!(terms.iter().all(|t| t.sensitivity.len() == 5));
        assert_eq!(terms.len(), 2 + 3 + 1 + 2 + 1);
    }

    #[test]
    fn multiplicative_terms_scale_with_the_reading() {
        let c = calibration();
        let rs = readings();
        let terms = shared_errors(&c, &rs).unwrap();
        for (k, r) in rs.iter().enumerate() {
            let value = c.radiance_factor(r.theta_i_deg, &r.reading).unwrap().0;
            assert!((term(&terms, TILE).sensitivity[k] - value * 0.005).abs() < 1e-15);
            assert!(
                (term(&terms, LAMP_DRIFT).sensitivity[k] - value * 0.002 / 3600.0 * r.age_s).abs()
                    < 1e-15
            );
        }
        // Nominal 0/1 ratio: 1 % of each reading above the white's range, lowering R when the
        // ratio is higher.
        let gain = term(&terms, "gain ranges 0/1");
        let value = c.radiance_factor(20.0, &rs[1].reading).unwrap().0;
        assert!((gain.sensitivity[1] + 0.01 * value).abs() < 1e-12);
    }

    /// Each term's sensitivity is the derivative of the conversion with respect to the
    /// error it names, times that error's standard uncertainty: checked by finite
    /// differences on the calibration itself (the gain ratio recomputed from its readings,
    /// so a dark's path through it is included).
    #[test]
    fn sensitivities_are_the_conversions_derivatives() {
        let c = calibration();
        let rs = readings();
        let terms = shared_errors(&c, &rs).unwrap();
        let values = |c: &Calibration| -> Vec<f64> {
            rs.iter()
                .map(|r| c.radiance_factor(r.theta_i_deg, &r.reading).unwrap().0)
                .collect()
        };
        let base = values(&c);
        let check = |name: &str, perturbed: Calibration, step_in_sigmas: f64| {
            let moved = values(&perturbed);
            for k in 0..rs.len() {
                let numeric = (moved[k] - base[k]) / step_in_sigmas;
                let analytic = term(&terms, name).total(k);
                assert!(
                    (numeric - analytic).abs() <= 1e-3 * analytic.abs() + 1e-12,
                    "{name} reading {k}: {numeric} vs {analytic}"
                );
            }
        };
        let h = 0.01; // a hundredth of a standard error: linear enough
        for j in 0..c.white.len() {
            let mut p = c.clone();
            let u = standard_error_counts(&p.white[j].reading);
            p.white[j].reading.mean_counts += (h * u) as f32;
            check(
                &white_name(c.white[j].theta_i_deg),
                p,
                f64::from(
                    ((h * u) as f32 + c.white[j].reading.mean_counts)
                        - c.white[j].reading.mean_counts,
                ) / u,
            );
        }
        for j in 0..3usize {
            let mut p = c.clone();
            let u = standard_error_counts(&p.dark[j]);
            let before = p.dark[j].mean_counts;
            p.dark[j].mean_counts += (h * u) as f32;
            let step = f64::from(p.dark[j].mean_counts - before) / u;
            let g = p.gain_ratios[0].clone();
            p.gain_ratios[0].ratio = p.ratio_from_readings(&g.on_lower, &g.on_upper).unwrap().0;
            check(&dark_name(j as u8), p, step);
        }
    }

    #[test]
    fn ages_follow_the_device_clock_back_from_now() {
        // A calibration 4 h old at the last reading; readings 10 s apart.
        let ages = reading_ages_s(4.0 * 3600.0, &[0, 10_000_000, 20_000_000]);
        assert_eq!(
            ages,
            [4.0 * 3600.0 - 20.0, 4.0 * 3600.0 - 10.0, 4.0 * 3600.0]
        );
        // Taken in this session in virtual time (wall-clock age ~0): the device clock's.
        assert_eq!(reading_ages_s(0.0, &[5_000_000, 15_000_000]), [0.0, 10.0]);
        assert!(reading_ages_s(1.0, &[]).is_empty());
    }

    #[test]
    fn shares_add_to_one_and_group_by_kind() {
        let obs = [
            (20.0, 0.0, 0.5),
            (20.0, 10.0, 0.51),
            (20.0, 20.0, 0.49),
            (30.0, 30.0, 0.5),
            (45.0, 50.0, 0.505),
            (60.0, 70.0, 0.495),
        ]
        .map(|(ti, tr, r)| crate::analysis::fit::Observation {
            theta_i_deg: ti,
            theta_r_deg: tr,
            radiance_factor: r,
            std: Some(0.01),
            theta_r_span_deg: 0.0,
        });
        // A flat scene: only ρd is fitted, so σ and ρs have no budget.
        let mut fit =
            crate::analysis::fit::fit(&obs, &crate::analysis::fit::FitOptions::default()).unwrap();
        fit.budget = vec![
            BudgetTerm {
                name: READING_NOISE.into(),
                variance: [1.0, 2.0, 1.0, 0.1],
            },
            BudgetTerm {
                name: "white θi=20°".into(),
                variance: [1.0, 1.0, 1.0, 0.1],
            },
            BudgetTerm {
                name: "white θi=60°".into(),
                variance: [2.0, 1.0, 2.0, 0.1],
            },
            BudgetTerm {
                name: TILE.into(),
                variance: [0.0, 4.0, 4.0, 0.0],
            },
        ];
        let shares = shares(&fit);
        let total: f64 = shares.iter().map(|(_, s)| s[2].unwrap()).sum();
        assert!((total - 1.0).abs() < 1e-12);
        assert!(
            shares.iter().all(|(_, s)| s[0].is_none() && s[1].is_none()),
            "σ, ρs not determined: no share"
        );
        let kinds = by_kind(&fit);
        assert_eq!(
            kinds.iter().map(|(k, _)| *k).collect::<Vec<_>>(),
            [TermKind::ReadingNoise, TermKind::White, TermKind::Tile]
        );
        assert_eq!(kinds[1].1, [None, None, Some(3.0)]);
        let table = to_table(&fit);
        assert!(
            table.contains("white readings") && table.contains("37.5 %") && table.contains("—"),
            "{table}"
        );
        let json = to_json(&fit);
        assert_eq!(json["terms"].as_array().unwrap().len(), 4);
        assert_eq!(json["by_kind"][1]["share"]["rho_d"], json!(0.375));
        assert_eq!(json["terms"][0]["share"]["rho_s"], Value::Null);
        assert_eq!(
            TermKind::of("reading noise (estimated from the residuals)"),
            TermKind::ReadingNoise
        );
        assert_eq!(TermKind::of(LACK_OF_FIT), TermKind::LackOfFit);
    }
}
