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
    /// A sheet's stated orientation or side differs from that of every sheet of these
    /// stocks: its ratio against them is partly the placement's.
    StockLayDiffers {
        /// Which sheet.
        side: Side,
        /// "orientation" or "side".
        what: &'static str,
        /// The sheet's (`md`, `cd`, `felt`, `wire`).
        sheet_lay: &'static str,
        /// The stocks' sheets'.
        stock_lay: &'static str,
        /// The stocks, by name.
        stocks: Vec<String>,
    },
    /// The sheets of these stocks were measured in more than one orientation or side, or
    /// some of them with none recorded: a stock's mean mixes placements.
    StockLayMixed {
        /// Which sheet is weighed against them.
        side: Side,
        /// "orientation" or "side".
        what: &'static str,
        /// The sheet's (`unknown` when not recorded).
        sheet_lay: &'static str,
        /// Each stock with its sheets' counts.
        stocks: Vec<StockLays>,
    },
    /// A sheet's orientation or side is stated, and none is recorded for the sheets of these
    /// stocks: whether they were measured the same way is unknown.
    StockLayUnknown {
        /// Which sheet.
        side: Side,
        /// "orientation" or "side".
        what: &'static str,
        /// The sheet's.
        sheet_lay: &'static str,
        /// The stocks, by name.
        stocks: Vec<String>,
    },
    /// A sheet's orientation or side is not recorded: whether it was measured as the
    /// library's stocks were is unknown (never taken for a match).
    SheetLayUnknown {
        /// Which sheet.
        side: Side,
        /// "orientation" or "side".
        what: &'static str,
    },
}

/// A stock whose sheets lay in more than one way, with how many lay each way.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct StockLays {
    /// The stock.
    pub stock: String,
    /// Its sheets' counts, as "2 md, 1 unknown".
    pub lays: String,
}

/// Whether a sheet was measured as a library's stocks were: for each of orientation and
/// side, a stock whose sheets all lay otherwise than `sheet` ([`Warning::StockLayDiffers`]),
/// lay in more than one way ([`Warning::StockLayMixed`], whatever the sheet's) or have none
/// recorded ([`Warning::StockLayUnknown`]); a sheet with none recorded is
/// [`Warning::SheetLayUnknown`] against them all. `stocks` are (name, its sheets' lays);
/// a stock of no sheets says nothing. One warning per kind and lay, naming its stocks: a
/// library of thousands of stocks measured one way gives one warning, not thousands.
pub fn stock_lay_warnings(
    side: Side,
    sheet: crate::analysis::specimen::SheetLay,
    stocks: &[(String, Vec<crate::analysis::specimen::SheetLay>)],
) -> Vec<Warning> {
    use crate::analysis::specimen::{Orientation, SheetLay, Side as PaperSide};
    type Pick = fn(&SheetLay) -> Option<&'static str>;
    let picks: [(&'static str, Pick); 2] = [
        ("orientation", |l| l.orientation.map(Orientation::name)),
        ("side", |l| l.side.map(PaperSide::name)),
    ];
    let mut out = Vec::new();
    for (what, pick) in picks {
        let sheet_lay = pick(&sheet);
        let mut differs: std::collections::BTreeMap<&'static str, Vec<String>> = Default::default();
        let (mut mixed, mut unknown) = (Vec::new(), Vec::new());
        for (stock, lays) in stocks {
            let mut counts: std::collections::BTreeMap<&'static str, usize> = Default::default();
            for lay in lays {
                *counts.entry(pick(lay).unwrap_or("unknown")).or_default() += 1;
            }
            match (counts.len(), counts.keys().next(), sheet_lay) {
                (0, _, _) | (1, _, None) => {}
                (1, Some(&"unknown"), Some(_)) => unknown.push(stock.clone()),
                (1, Some(&lay), Some(own)) if lay != own => {
                    differs.entry(lay).or_default().push(stock.clone());
                }
                (1, _, _) => {}
                _ => mixed.push(StockLays {
                    stock: stock.clone(),
                    lays: counts
                        .iter()
                        .map(|(lay, n)| format!("{n} {lay}"))
                        .collect::<Vec<_>>()
                        .join(", "),
                }),
            }
        }
        let Some(own) = sheet_lay else {
            out.push(Warning::SheetLayUnknown { side, what });
            if !mixed.is_empty() {
                out.push(Warning::StockLayMixed {
                    side,
                    what,
                    sheet_lay: "unknown",
                    stocks: mixed,
                });
            }
            continue;
        };
        out.extend(
            differs
                .into_iter()
                .map(|(stock_lay, stocks)| Warning::StockLayDiffers {
                    side,
                    what,
                    sheet_lay: own,
                    stock_lay,
                    stocks,
                }),
        );
        if !mixed.is_empty() {
            out.push(Warning::StockLayMixed {
                side,
                what,
                sheet_lay: own,
                stocks: mixed,
            });
        }
        if !unknown.is_empty() {
            out.push(Warning::StockLayUnknown {
                side,
                what,
                sheet_lay: own,
                stocks: unknown,
            });
        }
    }
    out
}

/// How many stocks a warning's sentence names before "and N more" (its JSON has them all).
const NAMED_STOCKS: usize = 10;

/// "stock X" or "the 3 stocks X, Y, Z" (at most [`NAMED_STOCKS`] named).
fn stocks_text(names: impl ExactSizeIterator<Item = String>) -> String {
    let n = names.len();
    let mut shown: Vec<String> = names
        .take(NAMED_STOCKS)
        .map(|s| format!("'{}'", crate::text::shown(&s)))
        .collect();
    if n > NAMED_STOCKS {
        shown.push(format!("and {} more", n - NAMED_STOCKS));
    }
    if n == 1 {
        format!("stock {}", shown.concat())
    } else {
        format!("the {n} stocks {}", shown.join(", "))
    }
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
            Warning::StockLayDiffers { .. } => "stock-lay-differs",
            Warning::StockLayMixed { .. } => "stock-lay-mixed",
            Warning::StockLayUnknown { .. } => "stock-lay-unknown",
            Warning::SheetLayUnknown { .. } => "sheet-lay-unknown",
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
            Warning::StockLayDiffers {
                side,
                what,
                sheet_lay,
                stock_lay,
                stocks,
            } => write!(
                f,
                "{side} was measured in {what} {sheet_lay}, every sheet of {} in {stock_lay}: a paper's specular-plane reflectance changes with its {what}, so {side}'s ratio against {} is partly the placement's, not the stock's",
                stocks_text(stocks.iter().cloned()),
                if stocks.len() == 1 { "it" } else { "them" }
            ),
            Warning::StockLayMixed {
                side,
                what,
                sheet_lay,
                stocks,
            } => write!(
                f,
                "the sheets of {} were measured in more than one {what} or with none recorded ({}): such a stock's mean mixes placements, and {side} ({what} {sheet_lay}) is weighed against it as against one",
                stocks_text(stocks.iter().map(|s| s.stock.clone())),
                stocks
                    .iter()
                    .take(NAMED_STOCKS)
                    .map(|s| format!("'{}': {}", crate::text::shown(&s.stock), s.lays))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
            Warning::StockLayUnknown {
                side,
                what,
                sheet_lay,
                stocks,
            } => write!(
                f,
                "{side} was measured in {what} {sheet_lay}, and no {what} is recorded for the sheets of {}: whether they were measured the same way is unknown",
                stocks_text(stocks.iter().cloned())
            ),
            Warning::SheetLayUnknown { side, what } => write!(
                f,
                "{side}'s {what} was not recorded: whether it was measured as the library's stocks were is unknown (a paper's specular-plane reflectance changes with its {what})"
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::specimen::{Orientation, SheetLay, Side as PaperSide};

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
            Warning::StockLayDiffers {
                side: Side::A,
                what: "orientation",
                sheet_lay: "cd",
                stock_lay: "md",
                stocks: vec!["X".into()],
            },
            Warning::StockLayMixed {
                side: Side::A,
                what: "side",
                sheet_lay: "felt",
                stocks: vec![StockLays {
                    stock: "X".into(),
                    lays: "1 felt, 1 wire".into(),
                }],
            },
            Warning::StockLayUnknown {
                side: Side::B,
                what: "side",
                sheet_lay: "felt",
                stocks: vec!["X".into()],
            },
            Warning::SheetLayUnknown {
                side: Side::A,
                what: "orientation",
            },
        ] {
            assert_eq!(w.to_json()["kind"], w.kind());
        }
    }

    fn lay(orientation: Option<Orientation>, side: Option<PaperSide>) -> SheetLay {
        SheetLay { orientation, side }
    }

    #[test]
    fn a_stock_measured_otherwise_mixed_or_unrecorded_is_said_and_unknown_is_no_match() {
        use Orientation::{Cd, Md};
        use PaperSide::{Felt, Wire};
        let stocks = vec![
            ("MD-felt".to_string(), vec![lay(Some(Md), Some(Felt)); 2]),
            ("CD-felt".to_string(), vec![lay(Some(Cd), Some(Felt))]),
            (
                "mixed".to_string(),
                vec![lay(Some(Md), Some(Felt)), lay(Some(Cd), Some(Felt))],
            ),
            ("old".to_string(), vec![lay(None, None)]),
            ("none".to_string(), vec![]),
        ];
        let w = stock_lay_warnings(Side::A, lay(Some(Cd), Some(Wire)), &stocks);
        let kinds: Vec<&str> = w.iter().map(Warning::kind).collect();
        assert_eq!(
            kinds,
            [
                "stock-lay-differs",
                "stock-lay-mixed",
                "stock-lay-unknown",
                "stock-lay-differs",
                "stock-lay-unknown"
            ],
            "{w:#?}"
        );
        // The CD sheet against the MD stock: both named, and the stock.
        let text = w[0].to_string();
        assert!(
            text.contains("A was measured in orientation cd, every sheet of stock 'MD-felt' in md"),
            "{text}"
        );
        assert!(w[1].to_string().contains("'mixed': 1 cd, 1 md"), "{}", w[1]);
        assert!(w[2].to_string().contains("stock 'old'"), "{}", w[2]);
        // Every stock but the empty one is felt: one warning names them all.
        assert!(
            matches!(&w[3], Warning::StockLayDiffers { what: "side", stocks, .. } if stocks.len() == 3),
            "{w:#?}"
        );
        // A sheet laid as its stocks were: nothing said of them.
        let same = stock_lay_warnings(Side::B, lay(Some(Md), Some(Felt)), &stocks[..1]);
        assert!(same.is_empty(), "{same:#?}");
        // A sheet of unknown lay is never a match: said once per lay, mixed stocks still said.
        let unknown = stock_lay_warnings(Side::A, SheetLay::default(), &stocks[..1]);
        let kinds: Vec<&str> = unknown.iter().map(Warning::kind).collect();
        assert_eq!(kinds, ["sheet-lay-unknown", "sheet-lay-unknown"]);
        let unknown = stock_lay_warnings(Side::A, SheetLay::default(), &stocks[2..3]);
        let kinds: Vec<&str> = unknown.iter().map(Warning::kind).collect();
        assert_eq!(
            kinds,
            ["sheet-lay-unknown", "stock-lay-mixed", "sheet-lay-unknown"]
        );
    }

    #[test]
    fn a_long_list_of_stocks_is_cut_in_the_sentence_and_whole_in_the_json() {
        let stocks: Vec<(String, Vec<SheetLay>)> = (0..25)
            .map(|k| (format!("S{k:02}"), vec![lay(Some(Orientation::Md), None)]))
            .collect();
        let w = stock_lay_warnings(Side::A, lay(Some(Orientation::Cd), None), &stocks);
        let text = w[0].to_string();
        assert!(
            text.contains("the 25 stocks 'S00'") && text.contains("and 15 more"),
            "{text}"
        );
        assert!(!text.contains("'S10'"), "{text}");
        assert_eq!(w[0].to_json()["stocks"].as_array().map(Vec::len), Some(25));
    }
}
