//! Measured data sets from CSV: a header naming `theta_i`, `theta_r` (degrees) and
//! `radiance_factor`, optionally `std` (standard uncertainty), `theta_r_span` (degrees the
//! detector moved while a reading integrated: a sweep's bin, centred on `theta_r`; empty or
//! absent for a still reading) and `sample` (several data sets in one file). Columns may come in any order; blank lines and lines starting with
//! `#` are skipped; a UTF-8 byte-order mark at the start is ignored. Errors carry the
//! 1-based line number.
//!
//! Numbers are checked against what the fit can represent, so that a typo gives an error
//! at its line instead of an infinite or NaN result: every number finite;
//! |radiance factor| ≤ [`MAX_RADIANCE_FACTOR`] (10⁶: far above any paper's specular peak
//! seen through the detector's window, and its square, weighted, stays far from overflow);
//! a `std` in [[`MIN_STD`], [`MAX_STD`]] (10⁻⁹ … 10⁶: its weight 1/std² stays finite), and
//! within one data set the largest `std` at most [`MAX_STD_RATIO`] (10⁶) times the smallest
//! (weights within 10¹² of each other, inside the 16 digits of an f64: beyond it the
//! lighter readings would vanish from the sums). The angles' range (0…90°) and negative
//! radiance factors are the fit's own checks.
use crate::analysis::fit::Observation;
use std::path::Path;
use thiserror::Error;

/// The largest |radiance factor| read.
pub const MAX_RADIANCE_FACTOR: f64 = 1e6;
/// The smallest standard uncertainty read.
pub const MIN_STD: f64 = 1e-9;
/// The largest standard uncertainty read.
pub use crate::analysis::fit::STD_MAX as MAX_STD;
/// The largest ratio of the largest to the smallest `std` in one data set.
pub const MAX_STD_RATIO: f64 = 1e6;

/// One data set: the readings of one sample, with the line each came from.
#[derive(Clone, Debug, PartialEq)]
pub struct DataSet {
    /// Sample name (the `sample` column, or the name given for files without one).
    pub sample: String,
    /// Readings in file order.
    pub observations: Vec<Observation>,
    /// 1-based line of each reading.
    pub lines: Vec<usize>,
}

impl DataSet {
    /// The (θi, θr) pairs, degrees.
    pub fn geometries(&self) -> Vec<(f64, f64)> {
        self.observations
            .iter()
            .map(|o| (o.theta_i_deg, o.theta_r_deg))
            .collect()
    }
}

/// What is wrong with a CSV file.
#[derive(Debug, Error)]
pub enum DatasetError {
    /// The file could not be read.
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    /// No header line.
    #[error("line 1: empty file (expected a header with theta_i, theta_r, radiance_factor)")]
    Empty,
    /// A required column is missing from the header.
    #[error("line {line}: header has no '{column}' column")]
    MissingColumn {
        /// Header line.
        line: usize,
        /// Column name.
        column: &'static str,
    },
    /// A column appears twice in the header.
    #[error("line {line}: column '{column}' appears twice in the header")]
    DuplicateColumn {
        /// Header line.
        line: usize,
        /// Column name.
        column: String,
    },
    /// A row with the wrong number of fields.
    #[error("line {line}: {found} fields, the header has {expected}")]
    FieldCount {
        /// Line.
        line: usize,
        /// Fields in the header.
        expected: usize,
        /// Fields in the row.
        found: usize,
    },
    /// A field that is not a number.
    #[error("line {line}: {column} '{value}' is not a number")]
    NotANumber {
        /// Line.
        line: usize,
        /// Column name.
        column: &'static str,
        /// The text.
        value: String,
    },
    /// A number the fit cannot represent.
    #[error("line {line}: {column} {value} is {why}")]
    OutOfRange {
        /// Line.
        line: usize,
        /// Column name.
        column: &'static str,
        /// The value as read.
        value: String,
        /// The limit, in words.
        why: String,
    },
    /// Uncertainties of one data set too far apart to weigh them together.
    #[error(
        "line {line}: std {value:?} is more than {MAX_STD_RATIO:e} times the std {other:?} of line {other_line} (sample '{sample}'): weights that far apart cannot be fitted together; check the units"
    )]
    StdSpread {
        /// Line of the largest std.
        line: usize,
        /// The largest std.
        value: f64,
        /// Line of the smallest std.
        other_line: usize,
        /// The smallest std.
        other: f64,
        /// The data set.
        sample: String,
    },
    /// A header but no readings.
    #[error("line {line}: no readings after the header")]
    NoReadings {
        /// Last line.
        line: usize,
    },
}

impl DatasetError {
    /// The 1-based line the error is about, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            DatasetError::Io(_) => None,
            DatasetError::Empty => Some(1),
            DatasetError::MissingColumn { line, .. }
            | DatasetError::DuplicateColumn { line, .. }
            | DatasetError::FieldCount { line, .. }
            | DatasetError::NotANumber { line, .. }
            | DatasetError::OutOfRange { line, .. }
            | DatasetError::StdSpread { line, .. }
            | DatasetError::NoReadings { line } => Some(*line),
        }
    }
}

/// Split a CSV line on commas, honouring double quotes ("" inside quotes is a quote).
fn split_fields(line: &str) -> Vec<String> {
    let mut fields = Vec::new();
    let mut field = String::new();
    let mut in_quotes = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '"' if in_quotes && chars.peek() == Some(&'"') => {
                field.push('"');
                chars.next();
            }
            '"' => in_quotes = !in_quotes,
            ',' if !in_quotes => fields.push(std::mem::take(&mut field).trim().to_string()),
            _ => field.push(c),
        }
    }
    fields.push(field.trim().to_string());
    fields
}

fn is_skipped(line: &str) -> bool {
    let t = line.trim();
    t.is_empty() || t.starts_with('#')
}

/// Parse CSV text. Data sets come out in the order their sample first appears;
/// `default_sample` names the one data set of a file without a `sample` column.
pub fn parse_csv(text: &str, default_sample: &str) -> Result<Vec<DataSet>, DatasetError> {
    // Spreadsheets on Windows start their UTF-8 with a byte-order mark.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_end_matches('\r')))
        .filter(|(_, l)| !is_skipped(l));
    let (header_line, header) = lines.next().ok_or(DatasetError::Empty)?;
    let names: Vec<String> = split_fields(header)
        .into_iter()
        .map(|s| s.to_ascii_lowercase())
        .collect();
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            return Err(DatasetError::DuplicateColumn {
                line: header_line,
                column: n.clone(),
            });
        }
    }
    let find = |c: &str| names.iter().position(|n| n == c);
    let required = |c: &'static str| {
        find(c).ok_or(DatasetError::MissingColumn {
            line: header_line,
            column: c,
        })
    };
    let (col_ti, col_tr, col_rf) = (
        required("theta_i")?,
        required("theta_r")?,
        required("radiance_factor")?,
    );
    let (col_std, col_sample, col_span) = (find("std"), find("sample"), find("theta_r_span"));

    let mut sets: Vec<DataSet> = Vec::new();
    // Sample name → index in `sets`, for files with many data sets.
    let mut index_of: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
    let mut last_line = header_line;
    let mut fields: Vec<std::borrow::Cow<str>> = Vec::with_capacity(names.len());
    for (line, text) in lines {
        last_line = line;
        fields.clear();
        if text.contains('"') {
            fields.extend(split_fields(text).into_iter().map(std::borrow::Cow::Owned));
        } else {
            // No quoting: split in place, without a String per field.
            fields.extend(
                text.split(',')
                    .map(|f| std::borrow::Cow::Borrowed(f.trim())),
            );
        }
        if fields.len() != names.len() {
            return Err(DatasetError::FieldCount {
                line,
                expected: names.len(),
                found: fields.len(),
            });
        }
        let number = |col: usize, column: &'static str| {
            let value = fields[col]
                .parse::<f64>()
                .map_err(|_| DatasetError::NotANumber {
                    line,
                    column,
                    value: fields[col].to_string(),
                })?;
            // Rust's parser accepts "NaN" and "inf", and "1e999" as infinity.
            if !value.is_finite() {
                return Err(DatasetError::OutOfRange {
                    line,
                    column,
                    value: fields[col].to_string(),
                    why: "not a finite number".into(),
                });
            }
            Ok(value)
        };
        let within = |value: f64, column: &'static str, col: usize, ok: bool, why: &str| {
            if ok {
                Ok(value)
            } else {
                Err(DatasetError::OutOfRange {
                    line,
                    column,
                    value: fields[col].to_string(),
                    why: why.to_string(),
                })
            }
        };
        let std = match col_std {
            Some(c) if !fields[c].is_empty() => {
                let u = number(c, "std")?;
                // 0 and negative values are the fit's BadUncertainty, named there.
                Some(within(
                    u,
                    "std",
                    c,
                    u <= 0.0 || (MIN_STD..=MAX_STD).contains(&u),
                    &format!("outside {MIN_STD:e} … {MAX_STD:e}, what the fit can weigh"),
                )?)
            }
            _ => None,
        };
        let radiance_factor = number(col_rf, "radiance_factor")?;
        let radiance_factor = within(
            radiance_factor,
            "radiance_factor",
            col_rf,
            radiance_factor.abs() <= MAX_RADIANCE_FACTOR,
            &format!(
                "beyond ±{MAX_RADIANCE_FACTOR:e}, what the fit can represent (a paper's specular peak is below 10⁴)"
            ),
        )?;
        let theta_r_span_deg = match col_span {
            Some(c) if !fields[c].is_empty() => {
                let span = number(c, "theta_r_span")?;
                within(
                    span,
                    "theta_r_span",
                    c,
                    (0.0..=crate::analysis::fit::MAX_SPAN_DEG).contains(&span),
                    &format!(
                        "outside 0 … {}°, the detector's travel a bin can have",
                        crate::analysis::fit::MAX_SPAN_DEG
                    ),
                )?
            }
            _ => 0.0,
        };
        let observation = Observation {
            theta_i_deg: number(col_ti, "theta_i")?,
            theta_r_deg: number(col_tr, "theta_r")?,
            radiance_factor,
            std,
            theta_r_span_deg,
        };
        let sample = col_sample.map_or(default_sample, |c| &*fields[c]);
        // Files list one sample after another: look at the last set first.
        let index = match sets.last() {
            Some(last) if last.sample == sample => sets.len() - 1,
            _ => match index_of.get(sample) {
                Some(&i) => i,
                None => {
                    sets.push(DataSet {
                        sample: sample.to_string(),
                        observations: Vec::new(),
                        lines: Vec::new(),
                    });
                    index_of.insert(sample.to_string(), sets.len() - 1);
                    sets.len() - 1
                }
            },
        };
        sets[index].observations.push(observation);
        sets[index].lines.push(line);
    }
    if sets.is_empty() {
        return Err(DatasetError::NoReadings { line: last_line });
    }
    for set in &sets {
        check_std_spread(set)?;
    }
    Ok(sets)
}

/// The positive uncertainties of a data set within [`MAX_STD_RATIO`] of each other.
fn check_std_spread(set: &DataSet) -> Result<(), DatasetError> {
    let positive = set
        .observations
        .iter()
        .zip(&set.lines)
        .filter_map(|(o, &line)| o.std.filter(|u| *u > 0.0).map(|u| (u, line)));
    // (std, line) of the smallest and of the largest.
    let mut low: Option<(f64, usize)> = None;
    let mut high: Option<(f64, usize)> = None;
    for (u, line) in positive {
        if low.is_none_or(|(l, _)| u < l) {
            low = Some((u, line));
        }
        if high.is_none_or(|(h, _)| u > h) {
            high = Some((u, line));
        }
    }
    match (low, high) {
        (Some((l, l_line)), Some((h, h_line))) if h > l * MAX_STD_RATIO => {
            Err(DatasetError::StdSpread {
                line: h_line,
                value: h,
                other_line: l_line,
                other: l,
                sample: set.sample.clone(),
            })
        }
        _ => Ok(()),
    }
}

/// Read a CSV file; a file without a `sample` column is named by its stem.
pub fn read_file(path: &Path) -> Result<Vec<DataSet>, DatasetError> {
    let text = std::fs::read_to_string(path)?;
    let stem = path.file_stem().map_or_else(
        || path.display().to_string(),
        |s| s.to_string_lossy().into_owned(),
    );
    parse_csv(&text, &stem)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_samples_and_optional_columns() {
        let text = "sample,theta_i,theta_r,radiance_factor,std\nA,20,0,0.5,0.01\n# comment\n\nB,20,0,0.4,\"0.02\"\nA,20,20,3,0.1\n";
        let sets = parse_csv(text, "file").unwrap();
        assert_eq!(sets.len(), 2);
        assert_eq!(sets[0].sample, "A");
        assert_eq!(sets[0].lines, [2, 6]);
        assert_eq!(sets[1].observations[0].std, Some(0.02));
    }

    #[test]
    fn a_bins_travel_is_read_from_its_column() {
        let text = "theta_i,theta_r,radiance_factor,std,theta_r_span\n60,59.5,40,0.1,0.25\n60,60,50,0.1,\n";
        let sets = parse_csv(text, "f").unwrap();
        assert_eq!(
            sets[0]
                .observations
                .iter()
                .map(|o| o.theta_r_span_deg)
                .collect::<Vec<_>>(),
            [0.25, 0.0]
        );
        for (bad, why) in [
            ("-0.1", "outside 0"),
            ("25", "outside 0"),
            ("x", "not a number"),
        ] {
            let text = format!("theta_i,theta_r,radiance_factor,theta_r_span\n60,59.5,40,{bad}\n");
            let err = parse_csv(&text, "f").unwrap_err().to_string();
            assert!(
                err.contains("line 2") && err.contains("theta_r_span") && err.contains(why),
                "{bad}: {err}"
            );
        }
    }

    #[test]
    fn a_byte_order_mark_is_ignored() {
        let sets = parse_csv("\u{feff}theta_i,theta_r,radiance_factor\n20,0,0.5\n", "f").unwrap();
        assert_eq!(sets[0].observations.len(), 1);
        assert_eq!(sets[0].lines, [2]);
    }

    #[test]
    fn numbers_the_fit_cannot_represent_are_refused_at_their_line() {
        let header = "theta_i,theta_r,radiance_factor,std\n20,0,0.5,0.01\n";
        for (row, column, value) in [
            ("20,20,1e308,0.1", "radiance_factor", "1e308"),
            ("20,20,-2e6,0.1", "radiance_factor", "-2e6"),
            ("20,20,NaN,0.1", "radiance_factor", "NaN"),
            ("20,20,1e999,0.1", "radiance_factor", "1e999"),
            ("20,20,3,1e-300", "std", "1e-300"),
            ("20,20,3,inf", "std", "inf"),
            ("20,20,3,1e7", "std", "1e7"),
            ("inf,20,3,0.1", "theta_i", "inf"),
        ] {
            let e = parse_csv(&format!("{header}{row}\n"), "f").unwrap_err();
            assert_eq!(e.line(), Some(3), "{row}: {e}");
            let message = e.to_string();
            assert!(
                message.contains(column) && message.contains(value),
                "{row}: {message}"
            );
        }
        // At the limits (|R| = 10⁶; std 10⁻⁸ against the first row's 10⁻²: 10⁶ apart): read.
        parse_csv(&format!("{header}20,20,1e6,1e-3\n20,25,3,1e-8\n"), "f").unwrap();
        parse_csv(&format!("{header}20,20,1e6,1e-3\n20,25,3,0.9e-8\n"), "f").unwrap_err();
        // Uncertainties 10⁶ apart: refused, naming both lines.
        let e = parse_csv(&format!("{header}20,20,3,1e-9\n"), "f").unwrap_err();
        assert!(
            matches!(
                e,
                DatasetError::StdSpread {
                    line: 2,
                    other_line: 3,
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn errors_name_the_line() {
        let e =
            parse_csv("theta_i,theta_r,radiance_factor\n20,0,0.5\n20,x,0.5\n", "f").unwrap_err();
        assert_eq!(e.line(), Some(3));
        assert!(e.to_string().contains("theta_r 'x'"), "{e}");
        let e = parse_csv("theta_i,radiance_factor\n20,0.5\n", "f").unwrap_err();
        assert!(matches!(
            e,
            DatasetError::MissingColumn {
                column: "theta_r",
                ..
            }
        ));
        let e = parse_csv("theta_i,theta_r,radiance_factor\n20,0\n", "f").unwrap_err();
        assert!(matches!(e, DatasetError::FieldCount { line: 2, .. }));
        assert!(matches!(
            parse_csv("", "f").unwrap_err(),
            DatasetError::Empty
        ));
    }
}
