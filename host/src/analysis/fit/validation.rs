//! The fit's first step: the readings and their shared errors checked before anything is
//! computed on them, so that a bad input is refused with its reading named rather than
//! turned into an infinite cost or a NaN interval.
use super::{
    FitError, MAX_SPAN_DEG, N_PARAMS, Observation, RADIANCE_FACTOR_MAX, STD_MAX, STD_MIN,
    SharedError,
};

/// Check the input, naming the first problem: finite numbers, angles in [0°, 90°),
/// 0 ≤ radiance factor ≤ [`RADIANCE_FACTOR_MAX`] (down to [`NEGATIVE_READING_STDS`]
/// standard uncertainties below 0 with one), [`STD_MIN`] ≤ std ≤ [`STD_MAX`],
/// uncertainties for all readings or none, no contradicting repeats, enough geometries.
pub fn validate(observations: &[Observation]) -> Result<(), FitError> {
    let weighted = observations.first().is_some_and(|o| o.std.is_some());
    for (index, o) in observations.iter().enumerate() {
        check_reading(index, o, weighted)?;
    }
    let distinct = distinct_geometries(observations)?;
    if distinct < N_PARAMS {
        return Err(FitError::TooFewGeometries {
            found: distinct,
            needed: N_PARAMS,
        });
    }
    let (lo, hi) = observations
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), o| {
            (lo.min(o.radiance_factor), hi.max(o.radiance_factor))
        });
    if lo == hi {
        return Err(FitError::AllEqual {
            n: observations.len(),
            value: lo,
        });
    }
    Ok(())
}

/// One reading's checks: finite numbers in range, and an uncertainty when the first
/// reading has one (`weighted`) and none otherwise.
fn check_reading(index: usize, o: &Observation, weighted: bool) -> Result<(), FitError> {
    for (what, value) in [("theta_i", o.theta_i_deg), ("theta_r", o.theta_r_deg)] {
        if !value.is_finite() {
            return Err(FitError::NotFinite { index, what });
        }
        if !(0.0..90.0).contains(&value) {
            return Err(FitError::AngleOutOfRange { index, what, value });
        }
    }
    if !(0.0..=MAX_SPAN_DEG).contains(&o.theta_r_span_deg) {
        return Err(FitError::SpanOutOfRange {
            index,
            value: o.theta_r_span_deg,
        });
    }
    if !o.radiance_factor.is_finite() {
        return Err(FitError::NotFinite {
            index,
            what: "radiance_factor",
        });
    }
    if o.radiance_factor > RADIANCE_FACTOR_MAX {
        return Err(FitError::TooLarge {
            index,
            value: o.radiance_factor,
            max: RADIANCE_FACTOR_MAX,
        });
    }
    match o.std {
        Some(s) if !s.is_finite() => return Err(FitError::NotFinite { index, what: "std" }),
        Some(s) if s <= 0.0 => return Err(FitError::BadUncertainty { index, value: s }),
        Some(s) if !(STD_MIN..=STD_MAX).contains(&s) => {
            return Err(FitError::UncertaintyOutOfRange {
                index,
                value: s,
                min: STD_MIN,
                max: STD_MAX,
            });
        }
        None if weighted => return Err(FitError::MixedUncertainties { index }),
        Some(_) if !weighted => {
            // The first reading had none: it is the odd one out.
            return Err(FitError::MixedUncertainties { index: 0 });
        }
        _ => {}
    }
    // A dark-subtracted reading of a dark place scatters about its true value, near zero,
    // and so a little below it: with an uncertainty, a reading down to
    // NEGATIVE_READING_STDS standard uncertainties below zero is a reading (refusing it, or
    // clipping it to 0, would bias the dark parts of the fit upwards). Further below, or
    // negative without an uncertainty to judge it by (a table), it is not a radiance
    // factor.
    if o.radiance_factor < 0.0 {
        return match o.std {
            Some(s) if o.radiance_factor >= -NEGATIVE_READING_STDS * s => Ok(()),
            Some(s) => Err(FitError::NegativeBeyondNoise {
                index,
                value: o.radiance_factor,
                std: s,
                k: NEGATIVE_READING_STDS,
            }),
            None => Err(FitError::Negative {
                index,
                value: o.radiance_factor,
            }),
        };
    }
    Ok(())
}

/// How many standard uncertainties below zero a reading may be (see [`check_reading`]):
/// noise reaches 5 standard deviations once in 3.5 million readings, a sign error or a
/// wrong dark level far more often.
pub const NEGATIVE_READING_STDS: f64 = 5.0;

/// The number of distinct geometries. Repeated readings are fine, contradicting ones are
/// not: without uncertainties "contradicting" means more than 10 % apart; with them, more
/// than 5 σ. Bins read while the arm moved (a θr span) are the instrument's own readings,
/// never a contradiction that stops the fit: a bin of two samples on a steep flank reads
/// where in its span they fell, which its counting uncertainty does not hold (G, θi 20°,
/// θr 21.97°, one bin of 0.125° swept three times on a bad link: 4.67, 4.88, 4.50, each
/// ± 0.035; the session stopped, seed 48291); the fit's goodness of fit judges them.
fn distinct_geometries(observations: &[Observation]) -> Result<usize, FitError> {
    let order = geometry_order(observations);
    let mut distinct = 0;
    for (k, &i) in order.iter().enumerate() {
        let same_as_previous = k > 0 && {
            let (p, o) = (&observations[order[k - 1]], &observations[i]);
            p.theta_i_deg == o.theta_i_deg && p.theta_r_deg == o.theta_r_deg
        };
        if !same_as_previous {
            distinct += 1;
            continue;
        }
        let (first, o) = (order[k - 1], &observations[i]);
        let p = &observations[first];
        if p.theta_r_span_deg > 0.0 && o.theta_r_span_deg > 0.0 {
            continue;
        }
        let diff = (p.radiance_factor - o.radiance_factor).abs();
        let tolerance = match (p.std, o.std) {
            (Some(a), Some(b)) => 5.0 * a.hypot(b),
            _ => 0.1 * p.radiance_factor.max(o.radiance_factor),
        };
        if diff > tolerance {
            return Err(FitError::ConflictingDuplicates {
                first,
                index: i,
                theta_i_deg: o.theta_i_deg,
                theta_r_deg: o.theta_r_deg,
                first_value: p.radiance_factor,
                value: o.radiance_factor,
            });
        }
    }
    Ok(distinct)
}

/// Check the shared errors against the (validated) readings: one finite sensitivity of at
/// most [`RADIANCE_FACTOR_MAX`] per reading, and readings with uncertainties.
pub fn validate_shared(
    observations: &[Observation],
    shared: &[SharedError],
) -> Result<(), FitError> {
    let weighted = observations.first().is_some_and(|o| o.std.is_some());
    for term in shared {
        if !weighted {
            return Err(FitError::SharedErrorWithoutUncertainties {
                name: term.name.clone(),
            });
        }
        if term.sensitivity.len() != observations.len() {
            return Err(FitError::SharedErrorLength {
                name: term.name.clone(),
                found: term.sensitivity.len(),
                expected: observations.len(),
            });
        }
        if !term.additive.is_empty() && term.additive.len() != observations.len() {
            return Err(FitError::SharedErrorLength {
                name: term.name.clone(),
                found: term.additive.len(),
                expected: observations.len(),
            });
        }
        let mut values = term.sensitivity.iter().chain(&term.additive).enumerate();
        if let Some((index, &value)) =
            values.find(|(_, v)| v.is_nan() || v.abs() > RADIANCE_FACTOR_MAX)
        {
            let index = index % observations.len().max(1);
            return Err(FitError::SharedErrorValue {
                name: term.name.clone(),
                index,
                value,
                max: RADIANCE_FACTOR_MAX,
            });
        }
    }
    Ok(())
}

/// The readings' indices in order of θi, then θr, then input order: repeats next to each
/// other, and each incidence's profile in θr.
pub(super) fn geometry_order(observations: &[Observation]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..observations.len()).collect();
    order.sort_by(|&a, &b| {
        let (oa, ob) = (&observations[a], &observations[b]);
        oa.theta_i_deg
            .total_cmp(&ob.theta_i_deg)
            .then(oa.theta_r_deg.total_cmp(&ob.theta_r_deg))
            .then(a.cmp(&b))
    });
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tables_contradicting_repeat_is_refused_and_a_sweeps_bins_are_readings() {
        let mut table = readings(Some(0.01), 0.02);
        let mut repeat = table[1];
        repeat.radiance_factor *= 1.1;
        table.push(repeat);
        assert!(matches!(
            validate(&table),
            Err(FitError::ConflictingDuplicates { .. })
        ));
        // The same numbers as bins of a sweep (0.125° spans): each the instrument's reading.
        let swept: Vec<Observation> = table
            .into_iter()
            .map(|o| Observation {
                theta_r_span_deg: 0.125,
                ..o
            })
            .collect();
        assert!(validate(&swept).is_ok());
    }

    fn readings(std: Option<f64>, dark_value: f64) -> Vec<Observation> {
        let mut out: Vec<Observation> = [
            (20.0, 0.0, 0.4),
            (20.0, 20.0, 3.0),
            (60.0, 60.0, 5.0),
            (60.0, 10.0, 0.3),
        ]
        .iter()
        .map(|&(ti, tr, y)| Observation {
            theta_i_deg: ti,
            theta_r_deg: tr,
            radiance_factor: y,
            std,
            theta_r_span_deg: 0.0,
        })
        .collect();
        out.push(Observation {
            theta_i_deg: 45.0,
            theta_r_deg: 5.0,
            radiance_factor: dark_value,
            std,
            theta_r_span_deg: 0.0,
        });
        out
    }

    /// A dark-subtracted reading a hair below zero is a reading when its uncertainty
    /// allows it (it stopped sessions: "radiance factor −0.0017 is negative"); further
    /// below, or negative without an uncertainty, it is refused with the reading named.
    #[test]
    fn readings_below_zero_within_their_noise_are_readings() {
        assert_eq!(validate(&readings(Some(0.001), -0.0017)), Ok(()));
        assert_eq!(validate(&readings(Some(0.001), -0.0049)), Ok(()));
        assert!(matches!(
            validate(&readings(Some(0.001), -0.0051)),
            Err(FitError::NegativeBeyondNoise { index: 4, .. })
        ));
        assert!(matches!(
            validate(&readings(None, -0.0017)),
            Err(FitError::Negative { index: 4, .. })
        ));
        // And the fit takes them as they are.
        let fit = super::super::fit(&readings(Some(0.001), -0.0017), &Default::default());
        assert!(fit.is_ok(), "{fit:?}");
    }
}
