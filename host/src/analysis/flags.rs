//! Conditions that make a result less than clean, as stable strings for `--json`,
//! `session.json` and scripts. A result is `ok` when no flag but the informational ones is
//! raised; `gonio measure` then exits 0 (the exit codes are in the binary's `cli::exit`).
//!
//! The strings never change meaning once released; new conditions get new strings.
use serde::{Deserialize, Serialize};

/// One condition of a result.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Flag {
    /// An arm lost steps during the session and the readings it affected could not all be
    /// measured again: geometries may be off.
    LostSteps,
    /// The white check at the end drifted beyond its limit.
    WhiteDrift,
    /// The calibration used is older than the recommended age.
    CalibrationStale,
    /// The model does not describe the data at the stated level (goodness of fit).
    LackOfFit,
    /// σ ≤ σ_l at the end: the sampling was not fine enough for the fitted peak.
    SigmaNotResolved,
    /// A parameter the class or a comparison needs was not determined by the data.
    NotIdentified,
    /// Informational: the link failed and was recovered; nothing was lost.
    LinkRecovered,
    /// Informational: the session was resumed from an interrupted one.
    Resumed,
    /// Informational: no instrument profile was in force (none found, or older than the
    /// lab's limit): the fit took the detector's response and the arm zero as the firmware
    /// declares them (a 1° top-hat, a zero good to its stated uncertainty), never measured
    /// on this instrument. `gonio characterize` measures them.
    InstrumentDeclared,
    /// Without an instrument profile, the class changes within the bound on the
    /// detector's response that no measurement narrowed (top-hats of the widths of
    /// [`DECLARED_RESPONSE_BOUND_DEG`], 0 a point detector): the result rests on the declared response, which
    /// this instrument may not have.
    InstrumentSensitive,
    /// Informational: the paper's TSL model did not describe the readings and the fit added
    /// a term the data called for (a heavy-tailed lobe, a haze lobe, σ varying with θi, a
    /// non-Lambertian body, a lobe wider on one side, …), each named with its test in the
    /// result; the main lobe's σ, ρs, ρd, η are still the reported and classified
    /// quantities.
    ModelExtended,
    /// A reading lies so far from the fit that it is taken for a gross error (an outlier
    /// test on the residuals at a stated false-alarm rate); the reading is named.
    Outlier,
    /// Too few readings beyond the fitted parameters to judge the fit or to state a
    /// class confidence.
    FewDegreesOfFreedom,
    /// The input cannot be a paper measured in degrees and radiance factors as it stands:
    /// radiance factors in percent, angles in radians, or values outside the population of
    /// papers (the note says which; [`crate::analysis::plausibility`]).
    ImplausibleInput,
    /// Informational, a sheet's only: its accepted spots do not all have one class (each
    /// named in the sheet's notes). The sheet's class and confidence are its mean's, whose
    /// uncertainty holds the spot-to-spot variation; a reader sees that the spots straddle
    /// a class boundary (or the sheet is not one paper) rather than a class alone.
    SpotsDisagree,
}

/// The detector responses an uncharacterized instrument is analysed again with, full
/// widths of top-hats, degrees: from a point detector (no response can be narrower) to one
/// three times as wide as the declared 1° (what a built instrument's acceptance and source
/// divergence together may be before anyone measured them).
pub const DECLARED_RESPONSE_BOUND_DEG: [f64; 2] = [0.0, 3.0];

impl Flag {
    /// Every flag, in a stable order.
    pub const ALL: [Flag; 15] = [
        Flag::LostSteps,
        Flag::WhiteDrift,
        Flag::CalibrationStale,
        Flag::LackOfFit,
        Flag::SigmaNotResolved,
        Flag::NotIdentified,
        Flag::LinkRecovered,
        Flag::Resumed,
        Flag::InstrumentDeclared,
        Flag::InstrumentSensitive,
        Flag::ModelExtended,
        Flag::Outlier,
        Flag::FewDegreesOfFreedom,
        Flag::ImplausibleInput,
        Flag::SpotsDisagree,
    ];

    /// The stable string (as serialized).
    pub const fn name(self) -> &'static str {
        match self {
            Flag::LostSteps => "lost-steps",
            Flag::WhiteDrift => "white-drift",
            Flag::CalibrationStale => "calibration-stale",
            Flag::LackOfFit => "lack-of-fit",
            Flag::SigmaNotResolved => "sigma-not-resolved",
            Flag::NotIdentified => "not-identified",
            Flag::LinkRecovered => "link-recovered",
            Flag::Resumed => "resumed",
            Flag::InstrumentDeclared => "instrument-declared",
            Flag::InstrumentSensitive => "instrument-sensitive",
            Flag::ModelExtended => "model-extended",
            Flag::Outlier => "outlier",
            Flag::FewDegreesOfFreedom => "few-degrees-of-freedom",
            Flag::ImplausibleInput => "implausible-input",
            Flag::SpotsDisagree => "spots-disagree",
        }
    }

    /// Informational flags say what happened without making the result less clean.
    pub const fn is_informational(self) -> bool {
        matches!(
            self,
            Flag::LinkRecovered
                | Flag::Resumed
                | Flag::InstrumentDeclared
                | Flag::ModelExtended
                | Flag::SpotsDisagree
        )
    }
}

impl std::fmt::Display for Flag {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Whether a result with these flags is clean.
pub fn ok(flags: &[Flag]) -> bool {
    flags.iter().all(|f| f.is_informational())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_the_serialized_strings() {
        for flag in Flag::ALL {
            assert_eq!(
                serde_json::to_value(flag).unwrap(),
                serde_json::Value::from(flag.name())
            );
        }
        assert!(ok(&[Flag::LinkRecovered, Flag::Resumed]));
        assert!(!ok(&[Flag::Resumed, Flag::LackOfFit]));
    }
}
