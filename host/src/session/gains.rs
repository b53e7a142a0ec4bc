//! The session's gain calibration: the ratio of two adjacent detector ranges measured by
//! reading one scene, at one position, on both ranges (`TakeReading { range: Some(..) }`),
//! for exactly the pairs of ranges the session's readings use.
//!
//! The scene. A ratio G(r + 1)/G(r) is best measured where the scene reads high on range r
//! without saturating it: on r + 1 it then reads a tenth of that, and read noise (0.02 % of
//! full scale at 100 ms) is what limits the ratio. The white tile is no choice for the
//! ranges 1/2 (it reads 4 % of full scale on range 1) and only a poor one for 0/1 (40 % →
//! 4 %), and it needs the operator. The sample itself has every level between its diffuse
//! part and its specular peak: where readings went to range r + 1, the peak's flank has a
//! spot at 30–85 % of range r's full scale. So the session takes it from its own readings
//! when one is already at that level, else searches along θr from the brightest reading
//! away from the specular direction (bisection with short auto-ranged probes), and reads
//! that spot on both ranges: first at the session's integration time, then, if the ratio
//! is not yet within [`TARGET_RELATIVE_UNCERTAINTY`] or the error the calibration's darks
//! put into it (whichever is larger: [`own_noise_target`]), once more as long as needed
//! (capped at [`MAX_INTEGRATION_MS`]); the readings are pooled.
//!
//! The darks' errors are not in the ratio's uncertainty: `analysis::budget` follows each
//! dark through the ratio into every reading it touches.
//!
//! The cost, in device time, is recorded with each ratio ([`GainRatio::device_seconds`]).
//! Without a calibrated ratio (a firmware that cannot force a range, no usable spot) the
//! nominal ratio is carried with its stated uncertainty, and the session says so.

use super::{Session, SessionError};
use crate::analysis::budget::{self, BudgetReading, SharedError};
use crate::analysis::calibration::{Calibration, GainRatio, pool, standard_error_counts};
use crate::instrument::link::{LinkError, Transport};
use protocol::{Command, ErrorCode, Geometry, Reading, Reply, Target};

/// Lowest level on range r of a usable spot, fraction of full scale: on r + 1 it reads 3 %
/// (0.7 % noise at 100 ms: about 5 s of integration for the target).
pub(crate) const LEVEL_LOW: f64 = 0.30;
/// Lowest level of a good spot, taken without searching for a better one: on r + 1 it reads
/// 5 % (0.5 % at 100 ms, 2.5 s for the target). A search costs a few short probes.
pub(crate) const LEVEL_GOOD: f64 = 0.50;
/// Highest level on range r of a usable spot: below it neither a gain a few percent off its
/// nominal nor the spread of the samples (the saturation test uses the largest sample, at
/// 0.98 of full scale) saturates range r.
pub(crate) const LEVEL_HIGH: f64 = 0.85;
/// The level aimed at among usable spots.
pub(crate) const LEVEL_AIM: f64 = 0.70;
/// Relative standard uncertainty a ratio is measured to: a tenth of the nominal ratio's
/// assumed 1 % and a fifth of the tile's 0.5 %, below which a gain no longer matters in the
/// budget.
pub(crate) const TARGET_RELATIVE_UNCERTAINTY: f64 = 0.001;
/// Longest forced reading taken for a ratio, ms.
pub(crate) const MAX_INTEGRATION_MS: u16 = 5_000;
/// Probes of the search along θr.
pub(crate) const MAX_PROBES: usize = 12;
/// A calibrated ratio this far (relative) from the nominal is refused: the scene or the
/// detector changed between the two readings.
pub(crate) const MAX_DEVIATION_FROM_NOMINAL: f64 = 0.10;

/// Pairs of adjacent ranges (r, r + 1), by r, that the conversions of `readings` (θi and
/// raw reading) use and `calibration` has not calibrated: a reading on range k whose white
/// is on range w uses every pair between them.
pub fn pairs_needed<'a>(
    calibration: &Calibration,
    readings: impl IntoIterator<Item = (f64, &'a Reading)>,
) -> Vec<u8> {
    let mut needed = std::collections::BTreeSet::new();
    for (theta_i_deg, reading) in readings {
        let Ok(c) = calibration.convert(theta_i_deg, reading) else {
            continue;
        };
        let (a, b) = (c.range.min(c.white_range), c.range.max(c.white_range));
        needed.extend(a..b);
    }
    needed
        .into_iter()
        .filter(|&p| calibration.calibrated_ratio(p).is_none())
        .collect()
}

/// The level `reading` would read on `range`, fraction of `full_scale_counts`, by the
/// gains the calibration has now; infinite for a saturated reading.
pub(crate) fn level_on(
    calibration: &Calibration,
    reading: &Reading,
    range: u8,
    full_scale_counts: f64,
) -> Option<f64> {
    if reading.saturated {
        return Some(f64::INFINITY);
    }
    let net = calibration.net_counts(reading).ok()?;
    let there = net / calibration.gain(reading.range).ok()? * calibration.gain(range).ok()?;
    Some(there / full_scale_counts)
}

/// Among (geometry, level) pairs, the spot at or above `lowest` (and at most
/// [`LEVEL_HIGH`]) nearest [`LEVEL_AIM`].
pub(crate) fn choose_spot(levels: &[(Geometry, f64)], lowest: f64) -> Option<(Geometry, f64)> {
    levels
        .iter()
        .copied()
        .filter(|(_, level)| (lowest..=LEVEL_HIGH).contains(level))
        .min_by(|a, b| (a.1 - LEVEL_AIM).abs().total_cmp(&(b.1 - LEVEL_AIM).abs()))
}

/// What the ratio's own noise is measured to: [`TARGET_RELATIVE_UNCERTAINTY`], or the
/// relative error the calibration's darks put into the ratio (`dark_relative`) if larger —
/// integrating beyond the darks' share buys nothing.
pub fn own_noise_target(dark_relative: f64) -> f64 {
    if dark_relative.is_finite() {
        dark_relative.max(TARGET_RELATIVE_UNCERTAINTY)
    } else {
        TARGET_RELATIVE_UNCERTAINTY
    }
}

/// The relative error the darks of ranges r and r + 1 put into a ratio measured with net
/// counts `on_lower` and `on_upper`.
pub fn dark_relative(
    calibration: &Calibration,
    lower_range: u8,
    on_lower: f64,
    on_upper: f64,
) -> f64 {
    let sem = |range: u8| {
        calibration
            .dark
            .get(usize::from(range))
            .map_or(f64::NAN, standard_error_counts)
    };
    (sem(lower_range) / on_lower).hypot(sem(lower_range + 1) / on_upper)
}

/// Integration time of the second pair of readings when the first, at `first_ms`, gave a
/// ratio of relative uncertainty `relative`: long enough that the pooled ratio reaches
/// `target` (noise falls as 1/√T), within [`MAX_INTEGRATION_MS`] and the device's
/// `max_ms`; `None` when the first pair is already good enough.
pub fn second_integration_ms(
    relative: f64,
    target: f64,
    first_ms: u16,
    min_ms: u16,
    max_ms: u16,
) -> Option<u16> {
    let factor = (relative / target).powi(2) - 1.0;
    if factor.is_nan() || factor <= 0.0 {
        return None;
    }
    let ms = (f64::from(first_ms) * factor)
        .ceil()
        .min(f64::from(MAX_INTEGRATION_MS.min(max_ms)));
    Some((ms as u16).max(min_ms))
}

/// θr of a bisection midpoint, on the arm's microstep grid.
fn midpoint(a: f64, b: f64) -> f64 {
    let resolution = protocol::Angle::RESOLUTION_DEG;
    (0.5 * (a + b) / resolution).round() * resolution
}

/// How far from the bright reading the search reaches along θr, degrees.
pub(crate) const SEARCH_SPAN_DEG: f64 = 25.0;

fn level_of(levels: &[(Geometry, f64)], g: Geometry) -> f64 {
    levels
        .iter()
        .find(|(h, _)| *h == g)
        .map_or(f64::NAN, |(_, l)| *l)
}

/// What a flank search found (θr and level), and every probe (θr, level).
pub(crate) type FlankSearch = (Option<(f64, f64)>, Vec<(f64, f64)>);

/// Search the flank of a lobe along θr for a level in [[`LEVEL_GOOD`], [`LEVEL_HIGH`]]:
/// from `bright_theta_r` (level `bright_level` > [`LEVEL_HIGH`]) towards `far` (θr and its
/// level if known, NaN if it must be probed first). `probe(θr)` reads the level there.
///
/// The far end reads the diffuse base b. While the outer end of the bracket is at the base
/// (below 2b) it says nothing of the lobe's width, and the next probe halves the bracket
/// in ln |offset|; once both ends are on the lobe, false position (Illinois) on
/// ln((level − b)/(aim − b)) against the squared offset, a straight line for a Gaussian
/// lobe, lands in one or two more. The bracket keeps it safe on any lobe.
/// Returns the spot found, if any, and every probe (θr, level).
pub(crate) fn search_flank<E>(
    probe: &mut dyn FnMut(f64) -> Result<Option<f64>, E>,
    bright_theta_r: f64,
    bright_level: f64,
    far: (f64, f64),
) -> Result<FlankSearch, E> {
    let good = |l: f64| (LEVEL_GOOD..=LEVEL_HIGH).contains(&l);
    let mut probed = Vec::new();
    let (far_theta_r, mut far_level) = far;
    if far_level.is_nan() {
        let Some(l) = probe(far_theta_r)? else {
            return Ok((None, probed));
        };
        probed.push((far_theta_r, l));
        far_level = l;
    }
    if good(far_level) {
        return Ok((Some((far_theta_r, far_level)), probed));
    }
    if far_level.is_nan() || far_level >= LEVEL_GOOD {
        return Ok((None, probed)); // bright all the way
    }
    let base = 0.8 * far_level.max(0.0);
    let informative = |l: f64| l > 2.0 * far_level.max(0.0) + 1e-6;
    let f = |l: f64| ((l - base).max(1e-12) / (LEVEL_AIM - base)).ln();
    let sign = (far_theta_r - bright_theta_r).signum();
    // Offsets from the bright reading, with the level there: inside above the aim, outside below.
    let bright_level = if bright_level.is_finite() {
        bright_level
    } else {
        1e3
    };
    let (mut inside, mut outside) = (
        (0.0f64, bright_level),
        ((far_theta_r - bright_theta_r).abs(), far_level),
    );
    // The smallest offset the geometric halving starts from: a lobe is never narrower.
    let min_offset = 0.5;
    let mut retained: i8 = 0;
    let mut f_scale = (1.0, 1.0);
    for _ in 0..MAX_PROBES {
        if outside.0 - inside.0 < 2.0 * protocol::Angle::RESOLUTION_DEG {
            break;
        }
        let (xi, xo) = (inside.0 * inside.0, outside.0 * outside.0);
        let mut offset = if informative(outside.1) && inside.0 > 0.0 {
            let (fi, fo) = (f_scale.0 * f(inside.1), f_scale.1 * f(outside.1));
            (xi - fi * (xo - xi) / (fo - fi)).max(0.0).sqrt()
        } else {
            (inside.0.max(min_offset) * outside.0).sqrt()
        };
        if !(offset > inside.0 && offset < outside.0) {
            offset = 0.5 * (inside.0 + outside.0);
        }
        let theta_r = midpoint(
            bright_theta_r + sign * offset,
            bright_theta_r + sign * offset,
        );
        let Some(l) = probe(theta_r)? else { break };
        probed.push((theta_r, l));
        if good(l) {
            return Ok((Some((theta_r, l)), probed));
        }
        let point = ((theta_r - bright_theta_r).abs(), l);
        if l > LEVEL_HIGH {
            inside = point;
            // Illinois: an end kept twice in a row counts half.
            f_scale = if retained == 1 {
                (1.0, 0.5 * f_scale.1)
            } else {
                (1.0, 1.0)
            };
            retained = 1;
        } else {
            outside = point;
            f_scale = if retained == -1 {
                (0.5 * f_scale.0, 1.0)
            } else {
                (1.0, 1.0)
            };
            retained = -1;
        }
    }
    Ok((None, probed))
}

/// Why a ratio was not calibrated.
enum Skip {
    /// The firmware cannot force a range.
    NotSupported,
    /// No spot, or the readings were not usable.
    Unusable(String),
}

impl<T: Transport> Session<'_, T> {
    /// Calibrate the gain ratios the readings so far use and the calibration lacks, then
    /// convert every reading again with them. The call site: after every measured stage.
    pub(super) fn calibrate_gains(&mut self) -> Result<(), SessionError> {
        let Some(calibration) = self.calibration.as_ref() else {
            return Ok(());
        };
        let needed = pairs_needed(
            calibration,
            self.points.iter().map(|p| (p.theta_i_deg, &p.reading)),
        );
        if needed.is_empty() {
            return Ok(());
        }
        let mut changed = false;
        for pair in needed {
            match self.calibrate_pair(pair)? {
                Ok(ratio) => {
                    self.recorder.decision(&format!(
                        "gain ranges {}/{} calibrated on the {} at ({:.2}°, {:.2}°): {:.5} ± {:.3} % (nominal {:.5}), {:.2} device s",
                        pair,
                        u16::from(pair) + 1,
                        ratio.scene,
                        ratio.theta_i_deg,
                        ratio.theta_r_deg,
                        ratio.ratio,
                        100.0 * ratio.relative_uncertainty,
                        self.calibration.as_ref().and_then(|c| c.gain_ratio(pair).ok()).map_or(f64::NAN, |g| g.0),
                        ratio.device_seconds
                    ));
                    if let Some(c) = self.calibration.as_mut() {
                        c.gain_ratios.push(ratio);
                    }
                    changed = true;
                }
                Err(Skip::NotSupported) => {
                    let u = self
                        .calibration
                        .as_ref()
                        .map_or(f64::NAN, |c| c.nominal_gain_ratio_relative_uncertainty);
                    self.recorder.decision(&format!(
                        "the instrument cannot force a detector range (its firmware refuses): nominal gain ratios carried with ±{:.1} %",
                        100.0 * u
                    ));
                    break;
                }
                Err(Skip::Unusable(why)) => {
                    self.recorder.decision(&format!(
                        "gain ranges {}/{} not calibrated ({why}): nominal ratio carried",
                        pair,
                        u16::from(pair) + 1
                    ));
                }
            }
        }
        if changed {
            self.convert_again()?;
        }
        Ok(())
    }

    /// Every reading converted again with the calibration as it is now.
    fn convert_again(&mut self) -> Result<(), SessionError> {
        let Some(calibration) = self.calibration.as_ref() else {
            return Ok(());
        };
        self.recorder
            .calibration(calibration)
            .map_err(SessionError::record)?;
        for point in &mut self.points {
            point.convert_with(calibration);
        }
        Ok(())
    }

    /// One forced-range reading where the arms are. A failure of the link or a stop is
    /// recovered from (the instrument brought back to a known state) and ends this ratio's
    /// calibration: the readings on the two ranges must be taken in one stand of the arms
    /// and one lamp.
    fn forced_reading(
        &mut self,
        range: u8,
        integration_ms: u16,
    ) -> Result<Result<Reading, Skip>, SessionError> {
        let reading = match self.client.request(Command::TakeReading {
            integration_ms,
            target: Target::Sample,
            range: Some(range),
        }) {
            Ok(Reply::Reading(reading)) => reading,
            Ok(other) => {
                return Err(LinkError::UnexpectedReply {
                    command: "TakeReading",
                    reply: Box::new(other),
                }
                .into());
            }
            Err(LinkError::Device { error, .. }) if error.code == ErrorCode::NotSupported => {
                return Ok(Err(Skip::NotSupported));
            }
            Err(error) => {
                return match self.link_failed(error) {
                    super::StepError::Failure(failure) => {
                        self.recover(failure)?;
                        Ok(Err(Skip::Unusable(
                            "the link or the instrument failed during the gain calibration".into(),
                        )))
                    }
                    super::StepError::Fatal(SessionError::Refused { error, .. }) => Ok(Err(
                        Skip::Unusable(format!("the instrument refused a forced reading: {error}")),
                    )),
                    super::StepError::Fatal(fatal) => Err(fatal),
                };
            }
        };
        // A reading in the dark (a stop the host did not hear) is no reading of the scene.
        if let Some(failure) = self.lamp_went_out()? {
            self.recover(failure)?;
            return Ok(Err(Skip::Unusable(
                "the lamp went off during the gain calibration".into(),
            )));
        }
        Ok(Ok(reading))
    }

    /// Device time now, µs.
    fn uptime_us(&mut self) -> Result<u64, SessionError> {
        Ok(self.status()?.uptime_us)
    }

    /// An auto-ranged probe at `geometry` and its level on `range`.
    fn probe_level(
        &mut self,
        geometry: Geometry,
        range: u8,
        full_scale: f64,
    ) -> Result<Option<f64>, SessionError> {
        self.retrying(Command::MoveTo(geometry))?;
        let integration_ms = self.info.min_integration_ms.max(1);
        let Reply::Reading(reading) = self.retrying(Command::TakeReading {
            integration_ms,
            target: Target::Sample,
            range: None,
        })?
        else {
            return Ok(None);
        };
        Ok(self
            .calibration
            .as_ref()
            .and_then(|c| level_on(c, &reading, range, full_scale)))
    }

    /// A spot on the sample for the pair (r, r + 1): from the readings, else by searching.
    fn find_spot(
        &mut self,
        pair: u8,
        full_scale: f64,
    ) -> Result<Result<(Geometry, f64), Skip>, SessionError> {
        let Some(calibration) = self.calibration.as_ref() else {
            return Ok(Err(Skip::Unusable("no calibration".into())));
        };
        let levels: Vec<(Geometry, f64)> = self
            .points
            .iter()
            .filter_map(|p| {
                Some((
                    p.geometry()?,
                    level_on(calibration, &p.reading, pair, full_scale)?,
                ))
            })
            .collect();
        if let Some(spot) = choose_spot(&levels, LEVEL_GOOD) {
            return Ok(Ok(spot));
        }
        let mut usable = levels.clone();
        let fallback =
            |usable: &[(Geometry, f64)], why: String| match choose_spot(usable, LEVEL_LOW) {
                Some(spot) => Ok(Ok(spot)),
                None => Ok(Err(Skip::Unusable(why))),
            };
        let Some((bright, _)) = levels
            .iter()
            .copied()
            .filter(|(_, l)| *l > LEVEL_HIGH)
            .max_by(|a, b| a.1.total_cmp(&b.1))
        else {
            return fallback(
                &usable,
                format!(
                    "no reading brighter than {:.0} % of range {pair}'s full scale",
                    100.0 * LEVEL_HIGH
                ),
            );
        };
        // Away from the specular direction the lobe falls: search between the bright reading
        // and a point far down its flank, a reading already taken if there is one.
        let (theta_i, theta_r) = (bright.theta_i.deg(), bright.theta_r.deg());
        let (arm_min, arm_max) = (self.info.arm_min.deg(), self.info.arm_max.deg());
        let low_limit = arm_min.max(self.info.collision_min_sum.deg() - theta_i);
        let mut away = if theta_r >= theta_i { 1.0 } else { -1.0 };
        if ((theta_r + away * SEARCH_SPAN_DEG).clamp(low_limit, arm_max) - theta_r).abs() < 1.0 {
            away = -away;
        }
        let far = (theta_r + away * SEARCH_SPAN_DEG).clamp(low_limit, arm_max);
        let known_far = levels
            .iter()
            .filter(|(g, l)| {
                g.theta_i == bright.theta_i
                    && *l < LEVEL_LOW
                    && (g.theta_r.deg() - theta_r) * away > 0.0
            })
            .map(|(g, l)| (g.theta_r.deg(), *l))
            .min_by(|a, b| (a.0 - theta_r).abs().total_cmp(&(b.0 - theta_r).abs()));
        let at = |theta_r: f64| Geometry::from_deg(theta_i, theta_r);
        let mut probe = |theta_r: f64| -> Result<Option<f64>, SessionError> {
            match at(theta_r) {
                Some(g) => self.probe_level(g, pair, full_scale),
                None => Ok(None),
            }
        };
        let (found, probed) = search_flank(
            &mut probe,
            theta_r,
            level_of(&levels, bright),
            known_far.unwrap_or((far, f64::NAN)),
        )?;
        usable.extend(probed.iter().filter_map(|&(t, l)| Some((at(t)?, l))));
        if let Some((t, l)) = found
            && let Some(g) = at(t)
        {
            return Ok(Ok((g, l)));
        }
        fallback(
            &usable,
            format!(
                "no spot between {:.0} % and {:.0} % of range {pair}'s full scale found",
                100.0 * LEVEL_LOW,
                100.0 * LEVEL_HIGH
            ),
        )
    }

    /// Calibrate the ratio G(pair + 1)/G(pair) on the sample.
    fn calibrate_pair(&mut self, pair: u8) -> Result<Result<GainRatio, Skip>, SessionError> {
        let started_us = self.uptime_us()?;
        // A firmware that cannot force a range says so at once, before any search.
        let cheapest = self.info.min_integration_ms.max(1);
        if let Err(skip) = self.forced_reading(pair, cheapest)? {
            return Ok(Err(skip));
        }
        let upper = pair + 1;
        let Some(full_scale) = self
            .info
            .detector_ranges
            .get(usize::from(pair))
            .map(|r| f64::from(r.full_scale_counts))
        else {
            return Ok(Err(Skip::Unusable(format!("no range {pair}"))));
        };
        let (spot, _) = match self.find_spot(pair, full_scale)? {
            Ok(spot) => spot,
            Err(skip) => return Ok(Err(skip)),
        };
        self.retrying(Command::MoveTo(spot))?;
        let mut on_lower = Vec::new();
        let mut on_upper = Vec::new();
        let mut integration_ms = self.plan.integration_ms;
        let Some(calibration) = self.calibration.clone() else {
            return Ok(Err(Skip::Unusable("no calibration".into())));
        };
        let first_us = self.uptime_us()?;
        for round in 0..2 {
            let lower = match self.forced_reading(pair, integration_ms)? {
                Ok(r) => r,
                Err(skip) => return Ok(Err(skip)),
            };
            let upper_reading = match self.forced_reading(upper, integration_ms)? {
                Ok(r) => r,
                Err(skip) => return Ok(Err(skip)),
            };
            if lower.saturated || upper_reading.saturated {
                return Ok(Err(Skip::Unusable(format!(
                    "the spot saturated range {}",
                    if lower.saturated { pair } else { upper }
                ))));
            }
            on_lower.push(lower);
            on_upper.push(upper_reading);
            let (Some(l), Some(u)) = (pool(&on_lower), pool(&on_upper)) else {
                break;
            };
            let (_, relative) = match calibration.ratio_from_readings(&l, &u) {
                Ok(x) => x,
                Err(e) => return Ok(Err(Skip::Unusable(e.to_string()))),
            };
            let (net_lower, net_upper) = (calibration.net_counts(&l)?, calibration.net_counts(&u)?);
            let target = own_noise_target(dark_relative(&calibration, pair, net_lower, net_upper));
            match second_integration_ms(
                relative,
                target,
                integration_ms,
                self.info.min_integration_ms,
                self.info.max_integration_ms,
            ) {
                Some(ms) if round == 0 => integration_ms = ms,
                _ => break,
            }
        }
        let (Some(l), Some(u)) = (pool(&on_lower), pool(&on_upper)) else {
            return Ok(Err(Skip::Unusable("no readings".into())));
        };
        let (ratio, relative) = match calibration.ratio_from_readings(&l, &u) {
            Ok(x) => x,
            Err(e) => return Ok(Err(Skip::Unusable(e.to_string()))),
        };
        let done_us = self.uptime_us()?;
        // The lamp drifts between the readings on the two ranges: at most the rate times
        // the time they took.
        let drift = calibration.lamp_drift_per_hour / 3600.0
            * done_us.saturating_sub(first_us) as f64
            * 1e-6;
        let relative = relative.hypot(drift);
        let nominal = calibration
            .relative_gains
            .get(usize::from(upper))
            .copied()
            .unwrap_or(f64::NAN)
            / calibration
                .relative_gains
                .get(usize::from(pair))
                .copied()
                .unwrap_or(f64::NAN);
        let deviation = (ratio / nominal - 1.0).abs();
        if deviation.is_nan() || deviation > MAX_DEVIATION_FROM_NOMINAL {
            return Ok(Err(Skip::Unusable(format!(
                "measured ratio {ratio:.5} is more than {:.0} % from the nominal {nominal:.5}",
                100.0 * MAX_DEVIATION_FROM_NOMINAL
            ))));
        }
        Ok(Ok(GainRatio {
            lower_range: pair,
            ratio,
            relative_uncertainty: relative,
            theta_i_deg: spot.theta_i.deg(),
            theta_r_deg: spot.theta_r.deg(),
            scene: "sample".into(),
            on_lower: l,
            on_upper: u,
            device_seconds: done_us.saturating_sub(started_us) as f64 * 1e-6,
        }))
    }
}

/// The errors `calibration` shares among `points` (white per θi, darks, tile, gain ratios,
/// lamp drift as of `now_unix_s`).
pub(super) fn shared_errors(
    calibration: &Calibration,
    points: &[&super::MeasuredPoint],
    now_unix_s: u64,
) -> Result<Vec<SharedError>, crate::instrument::calibration::CalibrationError> {
    let age_now_s = now_unix_s.saturating_sub(calibration.taken_unix_s) as f64;
    let ages = budget::reading_ages_s(
        age_now_s,
        &points.iter().map(|p| p.device_time_us).collect::<Vec<_>>(),
    );
    let readings: Vec<BudgetReading> = points
        .iter()
        .zip(ages)
        .map(|(p, age_s)| BudgetReading {
            theta_i_deg: p.theta_i_deg,
            reading: p.reading,
            age_s,
        })
        .collect();
    budget::shared_errors(calibration, &readings)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::instrument::calibration::{Tile, WhitePoint};

    fn reading(mean_counts: f32, range: u8) -> Reading {
        Reading {
            mean_counts,
            std_counts: 100.0,
            samples: 100,
            range,
            integration_ms: 100,
            saturated: false,
        }
    }

    fn calibration() -> Calibration {
        Calibration::new(
            "test".into(),
            Tile::default(),
            vec![1.0, 0.1, 0.01],
            vec![reading(200.0, 0), reading(200.0, 1), reading(200.0, 2)],
            vec![
                WhitePoint {
                    theta_i_deg: 20.0,
                    reading: reading(26_400.0, 0),
                },
                WhitePoint {
                    theta_i_deg: 60.0,
                    reading: reading(14_200.0, 0),
                },
            ],
        )
    }

    #[test]
    fn only_the_pairs_the_readings_use() {
        let c = calibration();
        let on = |m: f32, r: u8| reading(m, r);
        let (r0, r1, r2) = (on(10_000.0, 0), on(10_000.0, 1), on(10_000.0, 2));
        assert!(pairs_needed(&c, [(20.0, &r0)]).is_empty());
        assert_eq!(pairs_needed(&c, [(20.0, &r0), (60.0, &r1)]), [0]);
        assert_eq!(pairs_needed(&c, [(60.0, &r2)]), [0, 1]);
        // A reading that cannot be converted (no white at 45°) needs nothing.
        assert!(pairs_needed(&c, [(45.0, &r2)]).is_empty());
        let mut calibrated = c.clone();
        calibrated.gain_ratios.push(GainRatio {
            lower_range: 0,
            ratio: 0.1,
            relative_uncertainty: 0.001,
            theta_i_deg: 60.0,
            theta_r_deg: 63.0,
            scene: "sample".into(),
            on_lower: on(45_000.0, 0),
            on_upper: on(4_700.0, 1),
            device_seconds: 1.0,
        });
        assert_eq!(pairs_needed(&calibrated, [(60.0, &r2)]), [1]);
    }

    #[test]
    fn levels_and_spots() {
        let c = calibration();
        let fs = 65_535.0;
        // 20 200 counts on range 1 are 20 000 net: 200 000 on range 0 (3.05 FS), 2 000 on 2.
        let r = reading(20_200.0, 1);
        assert!((level_on(&c, &r, 0, fs).unwrap() - 200_000.0 / fs).abs() < 1e-12);
        assert!((level_on(&c, &r, 2, fs).unwrap() - 2_000.0 / fs).abs() < 1e-12);
        assert_eq!(
            level_on(
                &c,
                &Reading {
                    saturated: true,
                    ..r
                },
                1,
                fs
            ),
            Some(f64::INFINITY)
        );
        let g = |t: f64| Geometry::from_deg(60.0, t).unwrap();
        assert_eq!(
            choose_spot(
                &[
                    (g(60.0), 30.0),
                    (g(62.0), 0.9),
                    (g(63.0), 0.5),
                    (g(64.0), 0.8)
                ],
                LEVEL_GOOD
            ),
            Some((g(64.0), 0.8))
        );
        assert_eq!(
            choose_spot(&[(g(60.0), 30.0), (g(70.0), 0.1)], LEVEL_LOW),
            None
        );
        assert_eq!(
            choose_spot(&[(g(60.0), 30.0), (g(0.0), 0.35)], LEVEL_GOOD),
            None
        );
        assert_eq!(
            choose_spot(&[(g(60.0), 30.0), (g(0.0), 0.35)], LEVEL_LOW),
            Some((g(0.0), 0.35))
        );
    }

    /// A Gaussian lobe on a diffuse base, as a level on range r.
    fn lobe(peak: f64, width_deg: f64, base: f64) -> impl Fn(f64) -> f64 {
        move |offset: f64| base + peak * (-(offset / width_deg).powi(2) / 2.0).exp()
    }

    #[test]
    fn the_flank_search_finds_a_spot_in_a_few_probes() {
        // Peaks a reading on the next range up or two can have (up to ~20 × full scale), the
        // glossy papers' widths in θr and diffuse bases.
        for (peak, width, base) in [
            (8.0, 1.6, 0.02),
            (20.0, 1.6, 0.18),
            (1.3, 1.6, 0.02),
            (3.0, 3.8, 0.1),
            (1.2, 6.0, 0.01),
            (15.0, 1.0, 0.3),
        ] {
            let level = lobe(peak, width, base);
            let mut probe =
                |theta_r: f64| -> Result<Option<f64>, ()> { Ok(Some(level(theta_r - 60.0))) };
            let (found, probed) =
                search_flank(&mut probe, 60.0, peak + base, (85.0, f64::NAN)).unwrap();
            let (theta_r, l) = found.unwrap_or_else(|| panic!("lobe {peak}, {width}°: {probed:?}"));
            assert!(
                (LEVEL_GOOD..=LEVEL_HIGH).contains(&l) && theta_r > 60.0,
                "{theta_r} {l}"
            );
            assert!((l - level(theta_r - 60.0)).abs() < 1e-12);
            assert!(
                probed.len() <= 6,
                "lobe {peak}, {width}°: {} probes {probed:?}",
                probed.len()
            );
        }
        // A known far reading saves the first probe; a lobe bright everywhere gives up at once.
        let level = lobe(8.0, 1.6, 0.02);
        let mut probe =
            |theta_r: f64| -> Result<Option<f64>, ()> { Ok(Some(level(theta_r - 60.0))) };
        let (found, probed) = search_flank(&mut probe, 60.0, 8.02, (70.0, level(10.0))).unwrap();
        assert!(found.is_some() && probed.iter().all(|(t, _)| *t != 70.0));
        let mut bright = |_: f64| -> Result<Option<f64>, ()> { Ok(Some(5.0)) };
        assert_eq!(
            search_flank(&mut bright, 60.0, 8.0, (85.0, f64::NAN)).unwrap(),
            (None, vec![(85.0, 5.0)])
        );
    }

    #[test]
    fn a_second_reading_as_long_as_the_target_needs() {
        // 0.3 % at 100 ms: 3² − 1 = 8 → 800 ms more.
        let t = TARGET_RELATIVE_UNCERTAINTY;
        assert_eq!(second_integration_ms(0.003, t, 100, 10, 10_000), Some(800));
        assert_eq!(second_integration_ms(0.0009, t, 100, 10, 10_000), None);
        assert_eq!(
            second_integration_ms(0.05, t, 100, 10, 10_000),
            Some(MAX_INTEGRATION_MS)
        );
        assert_eq!(second_integration_ms(0.05, t, 100, 10, 2_000), Some(2_000));
        assert_eq!(second_integration_ms(f64::NAN, t, 100, 10, 2_000), None);
        // Darks good to 0.3 %: no point in more than that.
        assert_eq!(own_noise_target(0.003), 0.003);
        assert_eq!(own_noise_target(0.0002), t);
        assert_eq!(
            second_integration_ms(0.0025, own_noise_target(0.003), 100, 10, 10_000),
            None
        );
    }
}
