//! A session whose readings saturated the detector: said as such, with what to change,
//! instead of the fit's "only 0 distinct geometries" and a suggestion to resume (resuming
//! reads the same light and saturates again).
use super::MeasuredPoint;
use crate::instrument::calibration::Calibration;
use std::fmt;

/// Saturated readings that left too few for a fit.
#[derive(Clone, Debug, PartialEq)]
pub struct Saturation {
    /// Readings that saturated (superseded ones left out).
    pub saturated: usize,
    /// Readings taken (superseded ones left out).
    pub readings: usize,
    /// Per detector range, how many saturated on it, most sensitive first.
    pub per_range: Vec<(u8, usize)>,
    /// The instrument's detector ranges.
    pub ranges: usize,
    /// The incidence angles of the saturated readings, degrees.
    pub incidences_deg: Vec<f64>,
    /// The least radiance factor a saturated reading stands for (its full-scale mean
    /// converted as if it were a value: each is at least this), when the calibration
    /// can convert it.
    pub at_least: Option<f64>,
    /// What the fit said.
    pub fit: String,
}

/// The session's saturation when it is why the fit failed: some readings saturated and
/// the fit found too few geometries to fit. `None` otherwise.
pub(crate) fn of(
    points: &[MeasuredPoint],
    calibration: Option<&Calibration>,
    ranges: usize,
    fit: String,
) -> Option<Saturation> {
    let taken: Vec<&MeasuredPoint> = points.iter().filter(|p| !p.superseded).collect();
    let saturated: Vec<&MeasuredPoint> = taken
        .iter()
        .copied()
        .filter(|p| p.reading.saturated)
        .collect();
    if saturated.is_empty() {
        return None;
    }
    let mut per_range: Vec<(u8, usize)> = Vec::new();
    let mut incidences_deg: Vec<f64> = Vec::new();
    let mut at_least: Option<f64> = None;
    for p in &saturated {
        match per_range.iter_mut().find(|(r, _)| *r == p.reading.range) {
            Some((_, count)) => *count += 1,
            None => per_range.push((p.reading.range, 1)),
        }
        if !incidences_deg.contains(&p.theta_i_deg) {
            incidences_deg.push(p.theta_i_deg);
        }
        // Its full-scale mean is a lower bound of what it saw.
        let bound = calibration.and_then(|c| {
            let as_value = protocol::Reading {
                saturated: false,
                ..p.reading
            };
            c.radiance_factor(p.theta_i_deg, &as_value).ok()
        });
        if let Some((value, _)) = bound.filter(|(v, _)| v.is_finite()) {
            at_least = Some(at_least.map_or(value, |a: f64| a.min(value)));
        }
    }
    per_range.sort_unstable();
    incidences_deg.sort_by(f64::total_cmp);
    Some(Saturation {
        saturated: saturated.len(),
        readings: taken.len(),
        per_range,
        ranges,
        incidences_deg,
        at_least,
        fit,
    })
}

impl fmt::Display for Saturation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let least = self.ranges.checked_sub(1).map(|r| r as u8);
        let ranges: Vec<String> = self
            .per_range
            .iter()
            .map(|(r, n)| {
                let which = if Some(*r) == least {
                    format!(", the least sensitive of {}", self.ranges)
                } else {
                    String::new()
                };
                format!("{n} on range {r}{which}")
            })
            .collect();
        let angles: Vec<String> = self
            .incidences_deg
            .iter()
            .map(|t| format!("{t}°"))
            .collect();
        write!(
            f,
            "the readings saturated the detector: {} of {} readings read full scale ({}; at θi = {})",
            self.saturated,
            self.readings,
            ranges.join(", "),
            angles.join(", ")
        )?;
        if let Some(v) = self.at_least {
            write!(f, ", each a radiance factor of at least {v:.0}")?;
        }
        write!(
            f,
            "; too few readings are left for a fit ({}).\nwhat to change: a sheet of paper reads a radiance factor of about 1 off its peak and at most about 60 at a glossy peak, so check what is on the sample port (a mirror, a retro-reflective or fluorescent sample, room light reaching the detector). A shorter integration (--integration-ms) does not help: a reading is the mean of its samples, and each saturated. The instrument chooses its range itself and already read these on its least sensitive one; gonio has no setting for a less sensitive one: a sample this bright needs an attenuator (a neutral-density filter) before the detector and a new white calibration with it. Measuring again or resuming reads the same light and saturates again.",
            self.fit
        )
    }
}
