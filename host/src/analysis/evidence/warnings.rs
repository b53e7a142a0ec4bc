//! What a comparison says when an assumption behind its ratio is contradicted by the data,
//! or was never measured: each warning names the assumption.
use serde::Serialize;
use std::fmt;

/// Which of the two compared sheets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Side {
    /// The first.
    A,
    /// The second.
    B,
}

impl fmt::Display for Side {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Side::A => "A",
            Side::B => "B",
        })
    }
}

/// One warning of a comparison.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Warning {
    /// The population is the demonstration one: assumed figures, not a measured library.
    Demonstration,
    /// The population has no validation behind it (or one made for other contents).
    NotValidated {
        /// Why.
        why: String,
    },
    /// The library shows no stock with two sheets: the sheet-to-sheet variation was taken
    /// equal to the spot-to-spot one.
    SheetLevelAssumed,
    /// A sheet lies further from every stock than the population's density covers.
    OutOfPopulation {
        /// Which sheet.
        side: Side,
        /// Its squared Mahalanobis distance to the nearest stock.
        distance_squared: f64,
        /// The χ² point beyond which a sheet is out.
        threshold: f64,
    },
    /// A sheet's own spots scatter more than the population's spots do.
    Scatter {
        /// Which sheet.
        side: Side,
        /// The parameter.
        parameter: &'static str,
        /// Its spots' relative standard deviation.
        own_relative_sd: f64,
        /// The population's, per spot.
        population_relative_sd: f64,
        /// The χ² test's p-value.
        p_value: f64,
    },
    /// A sheet's result is flagged (lack of fit, lost steps, drift, …).
    Flagged {
        /// Which sheet.
        side: Side,
        /// Its flags.
        flags: Vec<String>,
    },
    /// Both sides are one measurement: the same folder or the same readings.
    SameMeasurement {
        /// What is the same.
        what: String,
    },
    /// The sheets were measured on different instruments.
    DifferentInstruments {
        /// A's instrument.
        a: String,
        /// B's instrument.
        b: String,
    },
}

impl Warning {
    /// Its kind, as its JSON names it (`kind`).
    pub fn kind(&self) -> &'static str {
        match self {
            Warning::Demonstration => "demonstration",
            Warning::NotValidated { .. } => "not-validated",
            Warning::SheetLevelAssumed => "sheet-level-assumed",
            Warning::OutOfPopulation { .. } => "out-of-population",
            Warning::Scatter { .. } => "scatter",
            Warning::Flagged { .. } => "flagged",
            Warning::SameMeasurement { .. } => "same-measurement",
            Warning::DifferentInstruments { .. } => "different-instruments",
        }
    }

    /// As JSON: its fields, `kind` and the sentence a person reads (`message`).
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = serde_json::to_value(self).unwrap_or_else(|_| serde_json::json!({}));
        if let Some(o) = v.as_object_mut() {
            o.insert("message".into(), self.to_string().into());
        }
        v
    }
}

impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::Demonstration => f.write_str(
                "the population is the demonstration one (the eight reference papers with assumed variations): for demonstration, not evidence",
            ),
            Warning::NotValidated { why } => write!(
                f,
                "the population is not validated ({why}): the ratio has no calibration or empirical bounds behind it"
            ),
            Warning::SheetLevelAssumed => f.write_str(
                "the library has no stock with two sheets: how sheets of one stock differ was not measured and is assumed to be as their spots differ",
            ),
            Warning::OutOfPopulation {
                side,
                distance_squared,
                threshold,
            } => write!(
                f,
                "{side} is outside the population (squared distance {distance_squared:.1} to the nearest stock, beyond {threshold:.1}): how rare it is cannot be judged, and it is given no more rarity than a sheet at the population's edge"
            ),
            Warning::Scatter {
                side,
                parameter,
                own_relative_sd,
                population_relative_sd,
                p_value,
            } => write!(
                f,
                "{side}'s spots scatter more in {parameter} ({:.1} %) than the population's spots do ({:.1} %, p = {p_value:.1e}): its own scatter is used",
                100.0 * own_relative_sd,
                100.0 * population_relative_sd
            ),
            Warning::Flagged { side, flags } => write!(
                f,
                "{side}'s result is flagged ({}): its parameters may not describe the sheet",
                flags.join(", ")
            ),
            Warning::SameMeasurement { what } => write!(
                f,
                "both sides are one measurement ({what}): a measurement compared with itself is not evidence that two items share a stock"
            ),
            Warning::DifferentInstruments { a, b } => write!(
                f,
                "the sheets were measured on different instruments ({a} and {b}): differences between instruments are not in the population unless its library holds them"
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kind_is_the_one_the_json_names() {
        for w in [
            Warning::Demonstration,
            Warning::NotValidated { why: "x".into() },
            Warning::SheetLevelAssumed,
            Warning::OutOfPopulation {
                side: Side::A,
                distance_squared: 20.0,
                threshold: 16.3,
            },
            Warning::Scatter {
                side: Side::B,
                parameter: "rho_s",
                own_relative_sd: 0.1,
                population_relative_sd: 0.02,
                p_value: 1e-4,
            },
            Warning::Flagged {
                side: Side::A,
                flags: vec!["lack-of-fit".into()],
            },
            Warning::SameMeasurement { what: "x".into() },
            Warning::DifferentInstruments {
                a: "1".into(),
                b: "2".into(),
            },
        ] {
            assert_eq!(w.to_json()["kind"], w.kind());
        }
    }
}
