//! Measured data sets from CSV: a header naming `theta_i`, `theta_r` (degrees) and
//! `radiance_factor`, optionally `std` (standard uncertainty) and `sample` (several data
//! sets in one file). Columns may come in any order; blank lines and lines starting with
//! `#` are skipped. Errors carry the 1-based line number.
use crate::analysis::fit::Observation;
use std::path::Path;
use thiserror::Error;

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
        self.observations.iter().map(|o| (o.theta_i_deg, o.theta_r_deg)).collect()
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
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim_end_matches('\r'))).filter(|(_, l)| !is_skipped(l));
    let (header_line, header) = lines.next().ok_or(DatasetError::Empty)?;
    let names: Vec<String> = split_fields(header).into_iter().map(|s| s.to_ascii_lowercase()).collect();
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            return Err(DatasetError::DuplicateColumn { line: header_line, column: n.clone() });
        }
    }
    let find = |c: &str| names.iter().position(|n| n == c);
    let required = |c: &'static str| find(c).ok_or(DatasetError::MissingColumn { line: header_line, column: c });
    let (col_ti, col_tr, col_rf) = (required("theta_i")?, required("theta_r")?, required("radiance_factor")?);
    let (col_std, col_sample) = (find("std"), find("sample"));

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
            fields.extend(text.split(',').map(|f| std::borrow::Cow::Borrowed(f.trim())));
        }
        if fields.len() != names.len() {
            return Err(DatasetError::FieldCount { line, expected: names.len(), found: fields.len() });
        }
        let number = |col: usize, column: &'static str| {
            // Rust's parser accepts "NaN" and "inf"; those reach the fit's own checks.
            fields[col].parse::<f64>().map_err(|_| DatasetError::NotANumber { line, column, value: fields[col].to_string() })
        };
        let std = match col_std {
            Some(c) if !fields[c].is_empty() => Some(number(c, "std")?),
            _ => None,
        };
        let observation = Observation {
            theta_i_deg: number(col_ti, "theta_i")?,
            theta_r_deg: number(col_tr, "theta_r")?,
            radiance_factor: number(col_rf, "radiance_factor")?,
            std,
        };
        let sample = col_sample.map_or(default_sample, |c| &*fields[c]);
        // Files list one sample after another: look at the last set first.
        let index = match sets.last() {
            Some(last) if last.sample == sample => sets.len() - 1,
            _ => match index_of.get(sample) {
                Some(&i) => i,
                None => {
                    sets.push(DataSet { sample: sample.to_string(), observations: Vec::new(), lines: Vec::new() });
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
    Ok(sets)
}

/// Read a CSV file; a file without a `sample` column is named by its stem.
pub fn read_file(path: &Path) -> Result<Vec<DataSet>, DatasetError> {
    let text = std::fs::read_to_string(path)?;
    let stem = path.file_stem().map_or_else(|| path.display().to_string(), |s| s.to_string_lossy().into_owned());
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
    fn errors_name_the_line() {
        let e = parse_csv("theta_i,theta_r,radiance_factor\n20,0,0.5\n20,x,0.5\n", "f").unwrap_err();
        assert_eq!(e.line(), Some(3));
        assert!(e.to_string().contains("theta_r 'x'"), "{e}");
        let e = parse_csv("theta_i,radiance_factor\n20,0.5\n", "f").unwrap_err();
        assert!(matches!(e, DatasetError::MissingColumn { column: "theta_r", .. }));
        let e = parse_csv("theta_i,theta_r,radiance_factor\n20,0\n", "f").unwrap_err();
        assert!(matches!(e, DatasetError::FieldCount { line: 2, .. }));
        assert!(matches!(parse_csv("", "f").unwrap_err(), DatasetError::Empty));
    }
}
