//! Measured data sets from CSV: a header naming `theta_i`, `theta_r` (degrees) and
//! `radiance_factor`, optionally `std` (standard uncertainty), `theta_r_span` (degrees the
//! detector moved while a reading integrated: a sweep's bin, centred on `theta_r`; empty or
//! absent for a still reading) and `sample` (several data sets in one file). Columns may
//! come in any order; the file's lexical rules (a byte-order mark, blank and `#` lines,
//! quoting) are [`hil_sim::readings_csv`]'s, the simulator's table scenes reading the same
//! format. Errors carry the 1-based line number.
//!
//! Numbers are checked against what the fit can represent
//! ([`crate::analysis::dataset`]'s limits), so that a typo gives an error at its line.
use crate::analysis::dataset::{self, DataSet, StdSpread, Unfittable};
use crate::analysis::fit::Observation;
use hil_sim::readings_csv::{Header, Records, StringRecord};
use std::path::Path;
use thiserror::Error;

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
    #[error("line {line}: column '{}' appears twice in the header", crate::text::shown(.column))]
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
    #[error("line {line}: {column} '{}' is not a number", crate::text::shown(.value))]
    NotANumber {
        /// Line.
        line: usize,
        /// Column name.
        column: &'static str,
        /// The text (shown escaped and cut: [`crate::text::shown`]).
        value: String,
    },
    /// A number the fit cannot represent.
    #[error("line {line}: {column} {} is {why}", crate::text::shown(.value))]
    OutOfRange {
        /// Line.
        line: usize,
        /// Column name.
        column: &'static str,
        /// The value as read.
        value: String,
        /// What is wrong with it.
        why: Unfittable,
    },
    /// Uncertainties of one data set too far apart to weigh them together.
    #[error(transparent)]
    StdSpread(#[from] StdSpread),
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
            | DatasetError::StdSpread(StdSpread { line, .. })
            | DatasetError::NoReadings { line } => Some(*line),
        }
    }
}

/// The columns of a data set file, by position.
struct Columns {
    theta_i: usize,
    theta_r: usize,
    radiance_factor: usize,
    std: Option<usize>,
    sample: Option<usize>,
    span: Option<usize>,
    count: usize,
}

impl Columns {
    /// The columns of `header`: no name twice, the three required ones present.
    fn of(header: &Header) -> Result<Columns, DatasetError> {
        let names = &header.names;
        for (i, n) in names.iter().enumerate() {
            if names[..i].contains(n) {
                return Err(DatasetError::DuplicateColumn {
                    line: header.line,
                    column: n.clone(),
                });
            }
        }
        let required = |column: &'static str| {
            header.position(column).ok_or(DatasetError::MissingColumn {
                line: header.line,
                column,
            })
        };
        Ok(Columns {
            theta_i: required("theta_i")?,
            theta_r: required("theta_r")?,
            radiance_factor: required("radiance_factor")?,
            std: header.position("std"),
            sample: header.position("sample"),
            span: header.position("theta_r_span"),
            count: names.len(),
        })
    }

    /// The reading on `line`.
    fn observation(&self, line: usize, fields: &StringRecord) -> Result<Observation, DatasetError> {
        let number = |col: usize, column: &'static str| {
            let value = fields[col]
                .parse::<f64>()
                .map_err(|_| DatasetError::NotANumber {
                    line,
                    column,
                    value: fields[col].to_string(),
                })?;
            // Rust's parser accepts "NaN" and "inf", and "1e999" as infinity.
            if value.is_finite() {
                Ok(value)
            } else {
                Err(out_of_range(
                    line,
                    column,
                    &fields[col],
                    Unfittable::NotFinite,
                ))
            }
        };
        // A number, then the limit it must be within.
        let checked = |col: usize, column: &'static str, limit: fn(f64) -> Result<f64, _>| {
            limit(number(col, column)?).map_err(|why| out_of_range(line, column, &fields[col], why))
        };
        let optional = |col: Option<usize>| col.filter(|&c| !fields[c].is_empty());
        let std = optional(self.std)
            .map(|c| checked(c, "std", dataset::check_std))
            .transpose()?;
        let radiance_factor = checked(
            self.radiance_factor,
            "radiance_factor",
            dataset::check_radiance_factor,
        )?;
        let theta_r_span_deg = optional(self.span)
            .map(|c| checked(c, "theta_r_span", dataset::check_span))
            .transpose()?
            .unwrap_or(0.0);
        Ok(Observation {
            theta_i_deg: number(self.theta_i, "theta_i")?,
            theta_r_deg: number(self.theta_r, "theta_r")?,
            radiance_factor,
            std,
            theta_r_span_deg,
        })
    }
}

fn out_of_range(line: usize, column: &'static str, value: &str, why: Unfittable) -> DatasetError {
    DatasetError::OutOfRange {
        line,
        column,
        value: value.to_string(),
        why,
    }
}

/// Parse CSV text. Data sets come out in the order their sample first appears;
/// `default_sample` names the one data set of a file without a `sample` column.
pub fn parse_csv(text: &str, default_sample: &str) -> Result<Vec<DataSet>, DatasetError> {
    let mut records = Records::new(text);
    let header = records.header().ok_or(DatasetError::Empty)?;
    let columns = Columns::of(&header)?;
    let mut sets: Vec<DataSet> = Vec::new();
    // Sample name → index in `sets`, for files with many data sets.
    let mut index_of: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
    let mut last_line = header.line;
    while let Some((line, fields)) = records.next() {
        last_line = line;
        if fields.len() != columns.count {
            return Err(DatasetError::FieldCount {
                line,
                expected: columns.count,
                found: fields.len(),
            });
        }
        let observation = columns.observation(line, fields)?;
        let sample = columns.sample.map_or(default_sample, |c| &fields[c]);
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
        set.check_std_spread()?;
    }
    Ok(sets)
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
                DatasetError::StdSpread(StdSpread {
                    line: 2,
                    other_line: 3,
                    ..
                })
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
