//! A tabulated scene: measured (or made) radiance factors over (θi, θr), replayed.
//!
//! The file is the CSV that `gonio fit` reads: a header naming `theta_i`, `theta_r`
//! (degrees) and `radiance_factor`, in any order and any case; other columns (`std`,
//! `sample`, …) are ignored, except that a `sample` column must name one sample only (a
//! scene is one sheet). Blank lines and lines starting with `#` are skipped, fields may be
//! double-quoted, a UTF-8 byte-order mark is allowed. A geometry given more than once
//! (repeated readings) is tabulated as the mean of its values.
//!
//! Interpolation: at each tabulated θi, monotone cubic (Fritsch–Carlson, "PCHIP") in θr
//! through that row's nodes, so a peak is never overshot (no ringing, no negative values
//! between positive nodes) and the nodes are reproduced exactly; between two tabulated θi,
//! linear in θi between the two rows' values at that θr. For a table at 1° in θr, between
//! the nodes the replay is within 0.5 % of the scene it was made from for every paper of
//! Table 6 but the glossy ones (SG 0.7 %, G 3 %: its lobe has 1.6° standard deviation in
//! θr, barely two nodes). Between tabulated θi it is a blend, not the scene: a specular
//! peak does not move with θi there (a rough paper's table is within 5 % midway between
//! rows 10–15° apart; a glossy one is not usable): replay at the table's θi, and see
//! [`TableScene::evaluations_between_rows`].
//!
//! Outside the table: θi is clamped to the table's range (the first or last row is
//! used). In θr, the detector's acceptance and an arm offset reach a little past any
//! table's nodes (θr = −0.5° and 70.5° for a detector at 0° and 70°): up to
//! [`OUTSIDE_TOLERANCE_DEG`] past a row's end the row is continued along its end slope
//! (never below 0), farther out that value is held, and such evaluations are counted
//! ([`TableScene::evaluations_outside`]), so a caller can tell that the session went where
//! the table has no data.
//!
//! The replayed values are seen through the simulated detector like any scene, so its
//! acceptance window smooths them once more: replay a table taken with a window of its own
//! with the acceptance set to 0.

use crate::readings_csv::Records;
use crate::scene::Scene;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

/// How far outside the table an evaluation may fall without being counted, degrees.
pub const OUTSIDE_TOLERANCE_DEG: f64 = 1.0;

/// What is wrong with a scene file: the message names the file and the line.
#[derive(Debug, thiserror::Error)]
#[error("{file}{}: {problem}", line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct TableError {
    /// The file (as given).
    pub file: String,
    /// 1-based line; none when the file cannot be read at all.
    pub line: Option<usize>,
    /// What is wrong.
    pub problem: TableProblem,
}

/// What is wrong in a scene file, at its [`TableError::line`].
#[derive(Debug, thiserror::Error)]
pub enum TableProblem {
    /// The file could not be read.
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    /// No header line.
    #[error("empty file: expected a header with theta_i, theta_r, radiance_factor")]
    Empty,
    /// A required column is missing from the header.
    #[error("the header has no '{0}' column")]
    MissingColumn(&'static str),
    /// A required column appears twice in the header.
    #[error("column '{0}' appears twice in the header")]
    DuplicateColumn(&'static str),
    /// A row with the wrong number of fields.
    #[error("{found} fields, the header has {expected}")]
    FieldCount {
        /// Fields in the header.
        expected: usize,
        /// Fields in the row.
        found: usize,
    },
    /// A field that is not a number.
    #[error("{column} '{value}' is not a number")]
    NotANumber {
        /// Column name.
        column: &'static str,
        /// The text.
        value: String,
    },
    /// A number that is infinite or NaN.
    #[error("{column} '{value}' is not finite")]
    NotFinite {
        /// Column name.
        column: &'static str,
        /// The text.
        value: String,
    },
    /// θi outside [0, 90).
    #[error("theta_i {0} is outside [0, 90) degrees")]
    ThetaIOutside(f64),
    /// θr outside (−90, 90).
    #[error("theta_r {0} is outside (-90, 90) degrees")]
    ThetaROutside(f64),
    /// A negative radiance factor.
    #[error("radiance_factor {0} is negative")]
    NegativeRadianceFactor(f64),
    /// A second sample in the `sample` column.
    #[error(
        "sample '{sample}' here, '{first}' on line {first_line}: a scene file holds one sample"
    )]
    SecondSample {
        /// The sample on this line.
        sample: String,
        /// The file's first sample.
        first: String,
        /// The line it is on.
        first_line: usize,
    },
    /// A header but no readings.
    #[error("no readings after the header")]
    NoReadings,
    /// A tabulated θi with a single θr.
    #[error("theta_i {0} has one theta_r only: a row needs two to interpolate")]
    OneThetaR(f64),
}

/// One tabulated θi: its θr nodes, ascending, the values and the PCHIP slopes.
#[derive(Clone, Debug, PartialEq)]
struct Row {
    theta_i_deg: f64,
    theta_r_deg: Vec<f64>,
    value: Vec<f64>,
    slope: Vec<f64>,
}

/// A tabulated radiance factor, interpolated (see the module's documentation).
#[derive(Debug)]
pub struct TableScene {
    rows: Vec<Row>,
    outside: AtomicU64,
    between: AtomicU64,
}

impl TableScene {
    /// Read and check `path`.
    pub fn read(path: &Path) -> Result<TableScene, TableError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| TableError {
            file: name.clone(),
            line: None,
            problem: TableProblem::Io(e),
        })?;
        TableScene::parse(&text, &name)
    }

    /// Parse CSV text; `file` names it in errors.
    pub fn parse(text: &str, file: &str) -> Result<TableScene, TableError> {
        let (nodes, last_line) = read_nodes(text).map_err(|(line, problem)| TableError {
            file: file.to_owned(),
            line: Some(line),
            problem,
        })?;
        let error = |line: usize, problem: TableProblem| TableError {
            file: file.to_owned(),
            line: Some(line),
            problem,
        };
        if nodes.is_empty() {
            return Err(error(last_line, TableProblem::NoReadings));
        }
        let mut rows: Vec<Row> = Vec::new();
        let mut first_line_of_row = Vec::new();
        for ((theta_i, theta_r), (sum, count, line)) in nodes {
            if rows.last().is_none_or(|r| r.theta_i_deg != theta_i.0) {
                rows.push(Row {
                    theta_i_deg: theta_i.0,
                    theta_r_deg: Vec::new(),
                    value: Vec::new(),
                    slope: Vec::new(),
                });
                first_line_of_row.push(line);
            }
            let row = rows.last_mut().expect("pushed");
            row.theta_r_deg.push(theta_r.0);
            row.value.push(sum / f64::from(count));
        }
        for (row, line) in rows.iter_mut().zip(first_line_of_row) {
            if row.theta_r_deg.len() < 2 {
                return Err(error(line, TableProblem::OneThetaR(row.theta_i_deg)));
            }
            row.slope = pchip_slopes(&row.theta_r_deg, &row.value);
        }
        Ok(TableScene {
            rows,
            outside: AtomicU64::new(0),
            between: AtomicU64::new(0),
        })
    }

    /// The tabulated θi, ascending.
    pub fn theta_i_deg(&self) -> Vec<f64> {
        self.rows.iter().map(|r| r.theta_i_deg).collect()
    }

    /// The θr range of the row at tabulated θi `theta_i_deg`, if there is one.
    pub fn theta_r_range_deg(&self, theta_i_deg: f64) -> Option<(f64, f64)> {
        self.rows
            .iter()
            .find(|r| r.theta_i_deg == theta_i_deg)
            .map(|r| (r.theta_r_deg[0], *r.theta_r_deg.last().expect("≥ 2 nodes")))
    }

    /// How many evaluations fell more than [`OUTSIDE_TOLERANCE_DEG`] outside the table.
    pub fn evaluations_outside(&self) -> u64 {
        self.outside.load(Ordering::Relaxed)
    }

    /// How many evaluations fell between two tabulated θi (interpolated in θi).
    pub fn evaluations_between_rows(&self) -> u64 {
        self.between.load(Ordering::Relaxed)
    }

    fn note_outside(&self, by_deg: f64) {
        if by_deg > OUTSIDE_TOLERANCE_DEG {
            self.outside.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn row_value(&self, row: &Row, theta_r_deg: f64) -> f64 {
        let last = row.theta_r_deg.len() - 1;
        let (lo, hi) = (row.theta_r_deg[0], row.theta_r_deg[last]);
        self.note_outside((lo - theta_r_deg).max(theta_r_deg - hi));
        // Past an end: along the end's slope for up to the tolerance, then held.
        let (edge, node) = if theta_r_deg < lo {
            ((theta_r_deg - lo).max(-OUTSIDE_TOLERANCE_DEG), 0)
        } else if theta_r_deg > hi {
            ((theta_r_deg - hi).min(OUTSIDE_TOLERANCE_DEG), last)
        } else {
            return pchip(&row.theta_r_deg, &row.value, &row.slope, theta_r_deg);
        };
        (row.value[node] + row.slope[node] * edge).max(0.0)
    }
}

impl Scene for TableScene {
    fn radiance_factor(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        let first = &self.rows[0];
        let last = self.rows.last().expect("≥ 1 row");
        self.note_outside((first.theta_i_deg - theta_i_deg).max(theta_i_deg - last.theta_i_deg));
        if theta_i_deg <= first.theta_i_deg {
            return self.row_value(first, theta_r_deg);
        }
        if theta_i_deg >= last.theta_i_deg {
            return self.row_value(last, theta_r_deg);
        }
        let k = self.rows.partition_point(|r| r.theta_i_deg <= theta_i_deg);
        let (below, above) = (&self.rows[k - 1], &self.rows[k]);
        if below.theta_i_deg == theta_i_deg {
            return self.row_value(below, theta_r_deg);
        }
        let t = (theta_i_deg - below.theta_i_deg) / (above.theta_i_deg - below.theta_i_deg);
        self.between.fetch_add(1, Ordering::Relaxed);
        (1.0 - t) * self.row_value(below, theta_r_deg) + t * self.row_value(above, theta_r_deg)
    }
}

/// The tabulated nodes: (θi, θr) → (sum of values, count, first line).
type Nodes = std::collections::BTreeMap<(OrdF64, OrdF64), (f64, u32, usize)>;

/// The nodes of a scene file, θ keyed in exact bits after normalising −0, and the last
/// line read; or the line of the first problem and the problem.
fn read_nodes(text: &str) -> Result<(Nodes, usize), (usize, TableProblem)> {
    let mut records = Records::new(text);
    let header = records.header().ok_or((1, TableProblem::Empty))?;
    let column = |wanted: &'static str| {
        let mut found = header
            .names
            .iter()
            .enumerate()
            // gonio's readings.csv names the angles with their unit (`theta_i_deg`).
            .filter(|(_, n)| {
                n.as_str() == wanted || n.strip_suffix("_deg").is_some_and(|n| n == wanted)
            })
            .map(|(i, _)| i);
        match (found.next(), found.next()) {
            (Some(i), None) => Ok(i),
            (None, _) => Err((header.line, TableProblem::MissingColumn(wanted))),
            (Some(_), Some(_)) => Err((header.line, TableProblem::DuplicateColumn(wanted))),
        }
    };
    let (col_i, col_r, col_f) = (
        column("theta_i")?,
        column("theta_r")?,
        column("radiance_factor")?,
    );
    let col_sample = header.position("sample");

    let mut nodes = Nodes::new();
    let mut sample: Option<(String, usize)> = None;
    let mut last_line = header.line;
    while let Some((line, fields)) = records.next() {
        last_line = line;
        let problem = |problem| (line, problem);
        if fields.len() != header.names.len() {
            return Err(problem(TableProblem::FieldCount {
                expected: header.names.len(),
                found: fields.len(),
            }));
        }
        let number = |col: usize, column: &'static str| {
            let text = &fields[col];
            match text.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                Ok(_) => Err(problem(TableProblem::NotFinite {
                    column,
                    value: text.to_owned(),
                })),
                Err(_) => Err(problem(TableProblem::NotANumber {
                    column,
                    value: text.to_owned(),
                })),
            }
        };
        let theta_i = number(col_i, "theta_i")?;
        let theta_r = number(col_r, "theta_r")?;
        let value = number(col_f, "radiance_factor")?;
        if !(0.0..90.0).contains(&theta_i) {
            return Err(problem(TableProblem::ThetaIOutside(theta_i)));
        }
        if !(-90.0 < theta_r && theta_r < 90.0) {
            return Err(problem(TableProblem::ThetaROutside(theta_r)));
        }
        if value < 0.0 {
            return Err(problem(TableProblem::NegativeRadianceFactor(value)));
        }
        if let Some(c) = col_sample {
            match &sample {
                None => sample = Some((fields[c].to_owned(), line)),
                Some((first, first_line)) if *first != fields[c] => {
                    return Err(problem(TableProblem::SecondSample {
                        sample: fields[c].to_owned(),
                        first: first.clone(),
                        first_line: *first_line,
                    }));
                }
                Some(_) => {}
            }
        }
        let entry = nodes
            .entry((OrdF64::new(theta_i), OrdF64::new(theta_r)))
            .or_insert((0.0, 0, line));
        entry.0 += value;
        entry.1 += 1;
    }
    Ok((nodes, last_line))
}

/// An f64 with a total order, −0 taken as 0 (angles from a file: finite).
#[derive(Clone, Copy, Debug, PartialEq)]
struct OrdF64(f64);

impl OrdF64 {
    fn new(x: f64) -> OrdF64 {
        OrdF64(if x == 0.0 { 0.0 } else { x })
    }
}

impl Eq for OrdF64 {}

impl PartialOrd for OrdF64 {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for OrdF64 {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// Fritsch–Carlson slopes of the monotone piecewise cubic through (x, y), x ascending,
/// at least two nodes: the weighted harmonic mean of the neighbouring secants inside,
/// zero at a local extremum, the one-sided three-point formula (limited) at the ends.
fn pchip_slopes(x: &[f64], y: &[f64]) -> Vec<f64> {
    let n = x.len();
    let h: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).collect();
    let secant: Vec<f64> = (0..n - 1).map(|k| (y[k + 1] - y[k]) / h[k]).collect();
    if n == 2 {
        return vec![secant[0]; 2];
    }
    let mut d = vec![0.0; n];
    for k in 1..n - 1 {
        let (a, b) = (secant[k - 1], secant[k]);
        if a * b > 0.0 {
            let (w1, w2) = (2.0 * h[k] + h[k - 1], h[k] + 2.0 * h[k - 1]);
            d[k] = (w1 + w2) / (w1 / a + w2 / b);
        }
    }
    let end = |h0: f64, h1: f64, s0: f64, s1: f64| {
        let d = ((2.0 * h0 + h1) * s0 - h0 * s1) / (h0 + h1);
        if d * s0 <= 0.0 {
            0.0
        } else if s0 * s1 <= 0.0 && d.abs() > 3.0 * s0.abs() {
            3.0 * s0
        } else {
            d
        }
    };
    d[0] = end(h[0], h[1], secant[0], secant[1]);
    d[n - 1] = end(h[n - 2], h[n - 3], secant[n - 2], secant[n - 3]);
    d
}

/// The monotone cubic through the nodes at `t` (inside [x₀, xₙ₋₁]).
fn pchip(x: &[f64], y: &[f64], d: &[f64], t: f64) -> f64 {
    let k = x.partition_point(|&xk| xk <= t).clamp(1, x.len() - 1) - 1;
    let h = x[k + 1] - x[k];
    let s = (t - x[k]) / h;
    let (s2, s3) = (s * s, s * s * s);
    let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
    let h10 = s3 - 2.0 * s2 + s;
    let h01 = -2.0 * s3 + 3.0 * s2;
    let h11 = s3 - s2;
    h00 * y[k] + h10 * h * d[k] + h01 * y[k + 1] + h11 * h * d[k + 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nodes_come_back_exactly_and_a_peak_is_not_overshot() {
        let text =
            "theta_i,theta_r,radiance_factor\n20,0,1\n20,10,1.2\n20,20,5\n20,30,1.2\n20,40,1\n";
        let t = TableScene::parse(text, "t.csv").unwrap();
        for (r, v) in [
            (0.0, 1.0),
            (10.0, 1.2),
            (20.0, 5.0),
            (30.0, 1.2),
            (40.0, 1.0),
        ] {
            assert_eq!(t.radiance_factor(20.0, r), v);
        }
        let between: Vec<f64> = (0..=400)
            .map(|k| t.radiance_factor(20.0, f64::from(k) * 0.1))
            .collect();
        assert!(
            between.iter().all(|v| (1.0..=5.0).contains(v)),
            "monotone between nodes"
        );
        assert_eq!(t.evaluations_outside(), 0);
        // A peak's flat ends are held flat outside; θi past the last row uses the last row.
        assert_eq!(t.radiance_factor(20.0, 40.5), 1.0);
        assert_eq!(t.evaluations_outside(), 0);
        assert_eq!(t.radiance_factor(25.0, 20.0), 5.0);
        assert_eq!(t.evaluations_outside(), 1);
    }

    #[test]
    fn past_a_row_end_the_end_slope_is_followed_for_a_degree_then_held_and_counted() {
        let text = "theta_i,theta_r,radiance_factor\n20,0,1\n20,10,2\n20,20,4\n20,30,7\n20,40,11\n";
        let t = TableScene::parse(text, "t.csv").unwrap();
        let (first, last) = (t.rows[0].slope[0], t.rows[0].slope[4]);
        assert!(first > 0.0 && last > 0.0);
        assert_eq!(t.radiance_factor(20.0, 40.5), 11.0 + 0.5 * last);
        assert_eq!(t.radiance_factor(20.0, -0.5), 1.0 - 0.5 * first);
        assert_eq!(t.evaluations_outside(), 0);
        assert_eq!(t.radiance_factor(20.0, 45.0), 11.0 + last);
        assert_eq!(t.radiance_factor(20.0, -30.0), (1.0 - first).max(0.0));
        assert_eq!(t.evaluations_outside(), 2);
    }

    #[test]
    fn linear_in_theta_i_between_rows_and_repeats_averaged() {
        let text = "\u{feff}# made by hand\nSample,Theta_R,Radiance_Factor,Theta_I,std\nX,0,1,20,0.1\nX,70,3,20,\nX,0,2,30,\nX,70,4,30,\nX,70,6,30,\n";
        let t = TableScene::parse(text, "t.csv").unwrap();
        assert_eq!(t.theta_i_deg(), vec![20.0, 30.0]);
        assert_eq!(t.radiance_factor(30.0, 70.0), 5.0);
        assert!((t.radiance_factor(25.0, 0.0) - 1.5).abs() < 1e-12);
        assert!((t.radiance_factor(22.5, 70.0) - (0.75 * 3.0 + 0.25 * 5.0)).abs() < 1e-12);
    }

    #[test]
    fn bad_files_name_the_file_and_line() {
        let cases = [
            ("", "t.csv:1: empty file"),
            (
                "theta_i,radiance_factor\n20,1\n",
                "t.csv:1: the header has no 'theta_r' column",
            ),
            (
                "theta_i,theta_r,theta_r,radiance_factor\n",
                "t.csv:1: column 'theta_r' appears twice",
            ),
            ("theta_i,theta_r,radiance_factor\n", "t.csv:1: no readings"),
            (
                "theta_i,theta_r,radiance_factor\n20,0,1\n20,x,1\n",
                "t.csv:3: theta_r 'x' is not a number",
            ),
            (
                "theta_i,theta_r,radiance_factor\n20,0,1\n\n20,1\n",
                "t.csv:4: 2 fields, the header has 3",
            ),
            (
                "theta_i,theta_r,radiance_factor\n90,0,1\n",
                "t.csv:2: theta_i 90 is outside",
            ),
            (
                "theta_i,theta_r,radiance_factor\n20,0,-1\n",
                "t.csv:2: radiance_factor -1 is negative",
            ),
            (
                "theta_i,theta_r,radiance_factor\n20,0,inf\n",
                "t.csv:2: radiance_factor 'inf' is not finite",
            ),
            (
                "theta_i,theta_r,radiance_factor\n20,0,1\n20,5,1\n30,0,1\n",
                "t.csv:4: theta_i 30 has one theta_r only",
            ),
            (
                "sample,theta_i,theta_r,radiance_factor\nA,20,0,1\nB,20,5,1\n",
                "t.csv:3: sample 'B' here, 'A' on line 2",
            ),
        ];
        for (text, expected) in cases {
            let message = TableScene::parse(text, "t.csv").unwrap_err().to_string();
            assert!(
                message.starts_with(expected),
                "{message:?} should start with {expected:?}"
            );
        }
        let missing = TableScene::read(Path::new("/nonexistent/scene.csv"))
            .unwrap_err()
            .to_string();
        assert!(
            missing.starts_with("/nonexistent/scene.csv: cannot read"),
            "{missing}"
        );
    }
}
