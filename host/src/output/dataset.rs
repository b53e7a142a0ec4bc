//! Measured data sets from CSV: a header naming `theta_i`, `theta_r` (degrees; also
//! spelled with their unit, `theta_i_deg`, `theta_r_deg`) and `radiance_factor`, optionally
//! `std` (standard uncertainty), `theta_r_span` (or `theta_r_span_deg`: degrees the
//! detector moved while a reading integrated: a sweep's bin, centred on `theta_r`; empty or
//! absent for a still reading) and `sample` (several data sets in one file). Columns may
//! come in any order; the file's lexical rules (a byte-order mark, blank and `#` lines,
//! quoting) are [`hil_sim::readings_csv`]'s, the simulator's table scenes reading the same
//! format. Errors carry the 1-based line number.
//!
//! Fields are separated by commas, or by semicolons or tabs (what a spreadsheet set to a
//! European locale writes): the separator is the one whose split of the header names the
//! required columns. With semicolons or tabs a number may have a decimal comma (`0,5`).
//!
//! gonio's own `.astm` export ([`crate::output::export`]) is read too, recognised by its
//! `VARS` line: angles in radians back to degrees (φs = π: θr = θs; φs = 0: θr = −θs),
//! BRDF back to radiance factor (× π), the sample from `SAMPLE_NAME`. It carries no
//! uncertainties: the fit then estimates the noise from the residuals.
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
    #[error("line {line}: header has no '{column}' column (found {found})")]
    MissingColumn {
        /// Header line.
        line: usize,
        /// Column name.
        column: &'static str,
        /// What the header held, in words: its columns and the separator they were split by.
        found: String,
    },
    /// An `.astm` row that is not a reading in the specular plane, or a header that does
    /// not match its rows.
    #[error("line {line}: {why}")]
    Astm {
        /// Line.
        line: usize,
        /// What is wrong.
        why: String,
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
            | DatasetError::Astm { line, .. }
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
    /// Numbers may have a decimal comma (fields separated by `;` or tabs).
    decimal_comma: bool,
}

/// The names a column goes by: as gonio wrote them first, then with their unit.
const THETA_I: [&str; 2] = ["theta_i", "theta_i_deg"];
const THETA_R: [&str; 2] = ["theta_r", "theta_r_deg"];
const RADIANCE_FACTOR: [&str; 1] = ["radiance_factor"];
const STD: [&str; 1] = ["std"];
const SPAN: [&str; 2] = ["theta_r_span", "theta_r_span_deg"];
const SAMPLE: [&str; 1] = ["sample"];
/// The separators a header is tried with, the comma first.
const DELIMITERS: [(u8, &str); 3] = [(b',', "','"), (b';', "';'"), (b'\t', "tabs")];

/// The first column going by one of `names`.
fn position_of(header: &Header, names: &[&str]) -> Option<usize> {
    header
        .names
        .iter()
        .position(|n| names.contains(&n.as_str()))
}

/// How many of the required columns `header` names.
fn required_found(header: &Header) -> usize {
    [&THETA_I[..], &THETA_R[..], &RADIANCE_FACTOR[..]]
        .iter()
        .filter(|names| position_of(header, names).is_some())
        .count()
}

/// The header's columns in words, for an error: "the columns 'a', 'b' split by ','".
fn found_in_words(header: &Header, separator: &str) -> String {
    let shown: Vec<String> = header
        .names
        .iter()
        .take(8)
        .map(|n| format!("'{}'", crate::text::shown(n)))
        .collect();
    let more = if header.names.len() > 8 { ", …" } else { "" };
    match header.names.len() {
        0 => "an empty header".to_string(),
        1 => format!(
            "one column {}{more}, with no ',', ';' or tab to separate columns",
            shown.join(", ")
        ),
        n => format!(
            "{n} columns {}{more} separated by {separator}",
            shown.join(", ")
        ),
    }
}

impl Columns {
    /// The columns of `header`: no name twice, the three required ones present.
    fn of(header: &Header, separator: &str, decimal_comma: bool) -> Result<Columns, DatasetError> {
        let names = &header.names;
        for (i, n) in names.iter().enumerate() {
            if names[..i].contains(n) {
                return Err(DatasetError::DuplicateColumn {
                    line: header.line,
                    column: n.clone(),
                });
            }
        }
        let required = |names: &[&'static str]| {
            position_of(header, names).ok_or_else(|| DatasetError::MissingColumn {
                line: header.line,
                column: names[0],
                found: found_in_words(header, separator),
            })
        };
        Ok(Columns {
            theta_i: required(&THETA_I)?,
            theta_r: required(&THETA_R)?,
            radiance_factor: required(&RADIANCE_FACTOR)?,
            std: position_of(header, &STD),
            sample: position_of(header, &SAMPLE),
            span: position_of(header, &SPAN),
            count: names.len(),
            decimal_comma,
        })
    }

    /// The reading on `line`.
    fn observation(&self, line: usize, fields: &StringRecord) -> Result<Observation, DatasetError> {
        let number = |col: usize, column: &'static str| {
            let text = &fields[col];
            // A decimal comma (one, and no point) where fields are not comma-separated.
            let decimal =
                (self.decimal_comma && text.matches(',').count() == 1 && !text.contains('.'))
                    .then(|| text.replace(',', "."));
            let value = decimal
                .as_deref()
                .unwrap_or(text)
                .parse::<f64>()
                .map_err(|_| DatasetError::NotANumber {
                    line,
                    column,
                    value: text.to_string(),
                })?;
            // Rust's parser accepts "NaN" and "inf", and "1e999" as infinity.
            if value.is_finite() {
                Ok(value)
            } else {
                Err(out_of_range(line, column, text, Unfittable::NotFinite))
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

/// A header split by one separator: (required columns found, columns), the separator's
/// byte and its name, the records after the header, the header.
type HeaderSplit = ((usize, usize), u8, &'static str, Records, Header);

/// Parse CSV text. Data sets come out in the order their sample first appears;
/// `default_sample` names the one data set of a file without a `sample` column.
pub fn parse_csv(text: &str, default_sample: &str) -> Result<Vec<DataSet>, DatasetError> {
    // The separator whose split of the header names the most required columns (the
    // comma on a tie): the one the file was written with.
    // (Columns found, columns split): on none found, the split into the most columns
    // says best what the header held.
    let mut best: Option<HeaderSplit> = None;
    for (delimiter, separator) in DELIMITERS {
        let mut records = Records::with_delimiter(text, delimiter);
        let header = records.header().ok_or(DatasetError::Empty)?;
        let score = (required_found(&header), header.names.len());
        if best.as_ref().is_none_or(|b| score > b.0) {
            best = Some((score, delimiter, separator, records, header));
        }
    }
    let (_, delimiter, separator, mut records, header) = best.ok_or(DatasetError::Empty)?;
    let columns = Columns::of(&header, separator, delimiter != b',')?;
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

/// Read a CSV file (or an `.astm` export); a file without a `sample` column is named by
/// its stem.
pub fn read_file(path: &Path) -> Result<Vec<DataSet>, DatasetError> {
    read_bytes(path, &std::fs::read(path)?)
}

/// [`read_file`] of the file's bytes, already read.
pub fn read_bytes(path: &Path, bytes: &[u8]) -> Result<Vec<DataSet>, DatasetError> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "not UTF-8 text (byte {}): save it as UTF-8 CSV",
                e.valid_up_to()
            ),
        )
    })?;
    let stem = path.file_stem().map_or_else(
        || path.display().to_string(),
        |s| s.to_string_lossy().into_owned(),
    );
    if is_astm(text) {
        parse_astm(text, &stem)
    } else {
        parse_csv(text, &stem)
    }
}

/// The reading of an `.astm` row: columns (θi, φi, θs, φs, BRDF) by position.
fn astm_observation(
    line: usize,
    fields: &StringRecord,
    [theta_i, phi_i, theta_s, phi_s, brdf]: [usize; 5],
) -> Result<Observation, DatasetError> {
    use std::f64::consts::PI;
    let number = |col: usize, name: &'static str| {
        fields[col]
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| DatasetError::NotANumber {
                line,
                column: name,
                value: fields[col].to_string(),
            })
    };
    let near = |a: f64, b: f64| (a - b).abs() < 1e-6;
    let phi_i_rad = number(phi_i, "phi_i")?;
    let phi_s_rad = number(phi_s, "phi_s")?;
    let theta_s_deg = number(theta_s, "theta_s")?.to_degrees();
    if !near(phi_i_rad, 0.0) {
        return Err(DatasetError::Astm {
            line,
            why: format!(
                "phi_i {phi_i_rad} is not 0: gonio reads readings in the specular plane (source at phi_i = 0)"
            ),
        });
    }
    let theta_r_deg = if near(phi_s_rad, PI) {
        theta_s_deg
    } else if near(phi_s_rad, 0.0) || near(phi_s_rad, 2.0 * PI) {
        -theta_s_deg
    } else {
        return Err(DatasetError::Astm {
            line,
            why: format!(
                "phi_s {phi_s_rad} is neither pi nor 0: the reading is out of the specular plane, which gonio's model describes"
            ),
        });
    };
    let brdf_value = number(brdf, "BRDF")?;
    let radiance_factor = dataset::check_radiance_factor(brdf_value * PI)
        .map_err(|why| out_of_range(line, "BRDF", &fields[brdf], why))?;
    Ok(Observation {
        theta_i_deg: number(theta_i, "theta_i")?.to_degrees(),
        theta_r_deg,
        radiance_factor,
        std: None,
        theta_r_span_deg: 0.0,
    })
}

/// Whether `text` is an `.astm` export: a `VARS` line after keyword lines.
fn is_astm(text: &str) -> bool {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .take_while(|l| {
            l.split_whitespace()
                .next()
                .is_some_and(|w| w.chars().all(|c| c.is_ascii_uppercase() || c == '_'))
        })
        .any(|l| l.starts_with("VARS ") || l.starts_with("VARS\t"))
}

/// Parse gonio's `.astm` export (module docs): one data set.
pub fn parse_astm(text: &str, default_sample: &str) -> Result<Vec<DataSet>, DatasetError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut sample = default_sample.to_string();
    let mut points: Option<(usize, usize)> = None;
    let mut vars: Option<(usize, Vec<String>)> = None;
    // The rows with the header's lines blanked, so that the records keep their lines.
    let mut rows = String::with_capacity(text.len());
    for (k, line) in text.split_inclusive('\n').enumerate() {
        if vars.is_some() {
            rows.push_str(line);
            continue;
        }
        rows.push('\n');
        let body = line.trim();
        let (key, value) = body.split_once(char::is_whitespace).unwrap_or((body, ""));
        match key {
            "SAMPLE_NAME" => sample = value.trim().to_string(),
            "NUM_POINTS" => {
                let n = value.trim().parse().map_err(|_| DatasetError::Astm {
                    line: k + 1,
                    why: format!(
                        "NUM_POINTS '{}' is not a count",
                        crate::text::shown(value.trim())
                    ),
                })?;
                points = Some((k + 1, n));
            }
            "VARS" => {
                vars = Some((
                    k + 1,
                    value
                        .split(',')
                        .map(|v| v.trim().to_ascii_lowercase())
                        .collect(),
                ));
            }
            _ => {}
        }
    }
    let (vars_line, names) = vars.ok_or(DatasetError::Empty)?;
    let header = Header {
        line: vars_line,
        names,
    };
    let column = |name: &'static str| {
        header
            .position(name)
            .ok_or_else(|| DatasetError::MissingColumn {
                line: vars_line,
                column: name,
                found: found_in_words(&header, "','"),
            })
    };
    let [theta_i, phi_i, theta_s, phi_s, brdf] = [
        column("theta_i")?,
        column("phi_i")?,
        column("theta_s")?,
        column("phi_s")?,
        column("brdf")?,
    ];
    let mut set = DataSet {
        sample,
        observations: Vec::new(),
        lines: Vec::new(),
    };
    let mut records = Records::new(&rows);
    let mut last_line = vars_line;
    while let Some((line, fields)) = records.next() {
        last_line = line;
        if fields.len() != header.names.len() {
            return Err(DatasetError::FieldCount {
                line,
                expected: header.names.len(),
                found: fields.len(),
            });
        }
        set.observations.push(astm_observation(
            line,
            fields,
            [theta_i, phi_i, theta_s, phi_s, brdf],
        )?);
        set.lines.push(line);
    }
    if set.observations.is_empty() {
        return Err(DatasetError::NoReadings { line: last_line });
    }
    if let Some((line, n)) = points
        && n != set.observations.len()
    {
        return Err(DatasetError::Astm {
            line,
            why: format!(
                "NUM_POINTS says {n} readings, the file has {} (cut short or edited?)",
                set.observations.len()
            ),
        });
    }
    Ok(vec![set])
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
        assert!(
            e.to_string().contains("'theta_i', 'radiance_factor'"),
            "{e}"
        );
        let e = parse_csv("theta_i,theta_r,radiance_factor\n20,0\n", "f").unwrap_err();
        assert!(matches!(e, DatasetError::FieldCount { line: 2, .. }));
        assert!(matches!(
            parse_csv("", "f").unwrap_err(),
            DatasetError::Empty
        ));
    }
}
