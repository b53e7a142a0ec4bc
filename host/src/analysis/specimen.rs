//! How a sheet lay on the port: its orientation (the paper's machine direction along the
//! plane of incidence, or across it) and which side faced the instrument (felt or wire).
//! A real paper's fibres lie mostly along the machine direction and its two sides are
//! made differently, so the specular-plane reflectance of one sheet differs between its
//! orientations and sides: two sheets are compared as measured the same way, or the
//! comparison says it is not (docs/FORENSIC.md, "Orientation and side"). Pure.
use serde::{Deserialize, Serialize};
use std::fmt;

/// The sheet's machine direction relative to the plane of incidence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Orientation {
    /// Machine direction (MD) in the plane of incidence.
    Md,
    /// Cross direction (CD) in the plane of incidence.
    Cd,
}

/// The side of the sheet that faced the instrument.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// The felt (top) side.
    Felt,
    /// The wire side.
    Wire,
}

impl Orientation {
    /// As the files spell it.
    pub fn name(self) -> &'static str {
        match self {
            Orientation::Md => "md",
            Orientation::Cd => "cd",
        }
    }
}

impl Side {
    /// As the files spell it.
    pub fn name(self) -> &'static str {
        match self {
            Side::Felt => "felt",
            Side::Wire => "wire",
        }
    }
}

/// "md", "cd" or "unknown" (`None`).
pub fn orientation_text(o: Option<Orientation>) -> &'static str {
    o.map_or("unknown", Orientation::name)
}

/// "felt", "wire" or "unknown" (`None`).
pub fn side_text(s: Option<Side>) -> &'static str {
    s.map_or("unknown", Side::name)
}

/// How a sheet lay: each `None` when not stated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SheetLay {
    /// Its orientation.
    pub orientation: Option<Orientation>,
    /// Its side.
    pub side: Option<Side>,
}

/// What differs between how two sheets lay.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Difference {
    /// Both stated and different: the sheets were not measured the same way.
    Differs {
        /// "orientation" or "side".
        what: &'static str,
        /// A's.
        a: &'static str,
        /// B's.
        b: &'static str,
    },
    /// One stated, the other not: whether they were measured the same way is unknown.
    Unknown {
        /// "orientation" or "side".
        what: &'static str,
        /// A's ("unknown" when not stated).
        a: &'static str,
        /// B's.
        b: &'static str,
    },
}

impl Difference {
    /// Whether both were stated and differ.
    pub fn is_known(&self) -> bool {
        matches!(self, Difference::Differs { .. })
    }
}

impl fmt::Display for Difference {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Difference::Differs { what, a, b } => write!(
                f,
                "A and B were measured in different {what}s (A {a}, B {b}): a paper's specular-plane reflectance changes with its {what}, so their difference is partly the placement's, not the stock's"
            ),
            Difference::Unknown { what, a, b } => write!(
                f,
                "the {what} is known for one sheet only (A {a}, B {b}): whether they were measured the same way is unknown"
            ),
        }
    }
}

/// What differs between `a` and `b`: nothing when both are stated alike or neither is.
pub fn differences(a: SheetLay, b: SheetLay) -> Vec<Difference> {
    let mut out = Vec::new();
    let mut compare =
        |what: &'static str, x: Option<&'static str>, y: Option<&'static str>| match (x, y) {
            (Some(x), Some(y)) if x != y => out.push(Difference::Differs { what, a: x, b: y }),
            (Some(_), None) | (None, Some(_)) => out.push(Difference::Unknown {
                what,
                a: x.unwrap_or("unknown"),
                b: y.unwrap_or("unknown"),
            }),
            _ => {}
        };
    compare(
        "orientation",
        a.orientation.map(Orientation::name),
        b.orientation.map(Orientation::name),
    );
    compare("side", a.side.map(Side::name), b.side.map(Side::name));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_differences_unknown_ones_and_none() {
        let md_felt = SheetLay {
            orientation: Some(Orientation::Md),
            side: Some(Side::Felt),
        };
        let cd_felt = SheetLay {
            orientation: Some(Orientation::Cd),
            ..md_felt
        };
        assert!(differences(md_felt, md_felt).is_empty());
        assert!(differences(SheetLay::default(), SheetLay::default()).is_empty());
        let d = differences(md_felt, cd_felt);
        assert_eq!(d.len(), 1);
        assert!(
            d[0].is_known() && d[0].to_string().contains("A md, B cd"),
            "{d:?}"
        );
        let d = differences(md_felt, SheetLay::default());
        assert_eq!(d.len(), 2);
        assert!(d.iter().all(|x| !x.is_known()), "{d:?}");
    }
}
