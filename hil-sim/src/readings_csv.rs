//! The readings CSV, the file `gonio fit` reads and a [`crate::table::TableScene`]
//! replays: its records with the line each is on, on the `csv` crate. Both readers share
//! these rules, so one function holds them; it lives here, the lowest crate with `std`,
//! and the host's data sets read through it too.
//!
//! The rules: a UTF-8 byte-order mark at the start is ignored (spreadsheets on Windows
//! write one); blank lines and lines starting with `#` (after spaces) are skipped; fields
//! are separated by commas, may be double-quoted (`""` inside quotes is a quote; a quote
//! opens a quoted field at the field's start, RFC 4180's rule) and are trimmed; records
//! may differ in length (each reader says what a wrong count means). Lines end at `\n`;
//! a `\r` before it is trimmed with the last field.

/// A record's fields (index it for a `&str`).
pub use csv::StringRecord;
use csv::{ReaderBuilder, Terminator, Trim};

/// The header of a readings file: its line and its column names, lower-cased.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    /// 1-based line of the header.
    pub line: usize,
    /// The column names in file order, ASCII lower-cased.
    pub names: Vec<String>,
}

impl Header {
    /// The first column called `name` (lower case), if there is one.
    pub fn position(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }
}

/// A readings file's records: the header, then the rows, each with its 1-based line.
pub struct Records {
    reader: csv::Reader<std::io::Cursor<Vec<u8>>>,
    record: StringRecord,
    /// A byte offset in the text read and the 1-based line it is on, counted on from
    /// record to record.
    counted: (usize, usize),
}

impl Records {
    /// Split `text` into records by the rules of the module's documentation.
    pub fn new(text: &str) -> Records {
        Records::with_delimiter(text, b',')
    }

    /// [`Records::new`] with fields separated by `delimiter` instead of commas (a
    /// spreadsheet set to a European locale writes `;` or a tab, its decimal separator
    /// being the comma).
    pub fn with_delimiter(text: &str, delimiter: u8) -> Records {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        // Skipped lines are blanked, not removed (the csv reader passes over empty lines),
        // so a record's line is one more than the line feeds before it.
        let mut kept = String::with_capacity(text.len());
        for line in text.split_inclusive('\n') {
            let body = line.trim();
            if !body.is_empty() && !body.starts_with('#') {
                kept.push_str(line);
            } else if line.ends_with('\n') {
                kept.push('\n');
            }
        }
        let reader = ReaderBuilder::new()
            .delimiter(delimiter)
            .has_headers(false)
            .flexible(true)
            .trim(Trim::All)
            .terminator(Terminator::Any(b'\n'))
            .from_reader(std::io::Cursor::new(kept.into_bytes()));
        Records {
            reader,
            record: StringRecord::new(),
            counted: (0, 1),
        }
    }

    /// The first record as a header, or `None` for a file with no records.
    pub fn header(&mut self) -> Option<Header> {
        self.next().map(|(line, fields)| Header {
            line,
            names: fields.iter().map(str::to_ascii_lowercase).collect(),
        })
    }

    /// The next record's line and fields, or `None` at the end.
    #[allow(clippy::should_implement_trait)] // it lends its buffer: not an `Iterator`
    pub fn next(&mut self) -> Option<(usize, &StringRecord)> {
        // Valid UTF-8 from memory, records of any length: reading cannot fail.
        let more = self
            .reader
            .read_record(&mut self.record)
            .expect("a csv reader over a string in memory does not fail");
        if !more {
            return None;
        }
        // The csv reader's position is where it began looking for the record: before the
        // blanked lines in front of it.
        let start = self.record.position().map_or(0, |p| p.byte());
        let mut start = usize::try_from(start).expect("an offset in memory");
        let (from, line) = self.counted;
        let text = self.reader.get_ref().get_ref();
        while text.get(start) == Some(&b'\n') {
            start += 1;
        }
        let line = line + text[from..start].iter().filter(|&&b| b == b'\n').count();
        self.counted = (start, line);
        Some((line, &self.record))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all(text: &str) -> Vec<(usize, Vec<String>)> {
        let mut records = Records::new(text);
        let mut out = Vec::new();
        while let Some((line, r)) = records.next() {
            out.push((line, r.iter().map(str::to_owned).collect()));
        }
        out
    }

    #[test]
    fn records_keep_their_lines_past_skipped_ones() {
        let text = "\u{feff}# made by hand\nA,B\r\n\n   \n  # indented, \"comment\n1,\"2,5\" \n\"say \"\"hi\"\"\",x";
        assert_eq!(
            all(text),
            [
                (2, vec!["A".into(), "B".into()]),
                (6, vec!["1".into(), "2,5".into()]),
                (7, vec!["say \"hi\"".into(), "x".into()]),
            ]
        );
        let mut records = Records::new("Theta_I, theta_r\n");
        let header = records.header().unwrap();
        assert_eq!(header.line, 1);
        assert_eq!(header.names, ["theta_i", "theta_r"]);
        assert_eq!(header.position("theta_r"), Some(1));
        assert!(records.next().is_none());
        assert!(Records::new("# only a comment\n\n").header().is_none());
    }
}
