//! A QA batch of sheets against a master stock (`gonio batch`), pure: the master's values
//! and spread from its sheets, the default tolerances, each sheet's verdict, and the
//! statistics across the sheets with their control-chart limits.
//!
//! # The master
//!
//! The master stock's value of σ, ρs and ρd is the geometric mean of its sheets' means,
//! each sheet's mean the geometric mean of its spots (the parameters vary relatively, as
//! [`crate::analysis::spots`] has them). Its spread is measured three ways, each relative
//! (standard deviation of the logs): between its sheets (two sheets or more), between the
//! spots of one sheet (pooled over its sheets), and the spots' own standard uncertainty
//! from their fits' covariances (root mean square over the spots).
//!
//! # The default tolerance
//!
//! [`DEFAULT_COVERAGE`] (3) times the larger of the master's sheet-to-sheet spread and its
//! spots' own standard uncertainty, and never below [`MIN_DEFAULT_TOLERANCE_PCT`]. The
//! sheet-to-sheet spread is what sheets of the stock do differ by; estimated from the
//! library's few sheets it can come out far too small by chance (from two sheets it has one
//! degree of freedom), and a sheet cannot be judged more finely than it is measured, so
//! the measurement's own uncertainty bounds it from below. Three standard deviations is the
//! Shewhart convention: a sheet of the master stock falls outside about 3 times in 1000
//! per parameter where the spread is the sheets' true one.
//!
//! # The verdict
//!
//! A sheet is judged only when its own result is clean (no flag but informational ones)
//! and it determined every parameter the master has: else it is undecided, with the
//! reason. A judged sheet passes when every parameter's relative deviation from the master
//! is within its tolerance, and fails naming every parameter beyond it and by how much.
//!
//! # The statistics
//!
//! Over the clean sheets, in the order measured: mean, standard deviation (n − 1), least
//! and greatest, and an individuals and moving-range (I-MR) chart: the individuals' centre
//! line is the mean and their limits mean ± 3 σ̂ with σ̂ = MR̄ / d₂ (d₂ = 1.128, the moving
//! range of two), the moving range's upper limit D₄ · MR̄ (D₄ = 3.267). I-MR rather than
//! mean ± 3 sd: its σ̂ comes from consecutive sheets, so a drift or a step across the batch
//! widens the sd but not σ̂, and the sheets it moves fall outside the limits.
use serde::{Deserialize, Serialize};

/// The parameters judged, as the documents name them.
pub const PARAMETERS: [&str; 3] = ["sigma_deg", "rho_s", "rho_d"];
/// Their names as a person reads them.
pub const LABELS: [&str; 3] = ["σ", "ρs", "ρd"];

/// Multiplier of the master's spread that gives the default tolerance.
pub const DEFAULT_COVERAGE: f64 = 3.0;
/// The least default tolerance, percent.
pub const MIN_DEFAULT_TOLERANCE_PCT: f64 = 1.0;
/// d₂ of a moving range of two: the mean moving range over σ of normal individuals.
pub const D2: f64 = 1.128;
/// D₄ of a moving range of two: its upper control limit over its mean.
pub const D4: f64 = 3.267;

/// σ, ρs and ρd by name, as the documents hold them (no unnamed arrays); indexed as
/// [`PARAMETERS`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Named<T> {
    /// σ, degrees.
    pub sigma_deg: T,
    /// ρs.
    pub rho_s: T,
    /// ρd.
    pub rho_d: T,
}

impl<T: Copy> Named<T> {
    /// From [σ, ρs, ρd].
    pub fn of(a: [T; 3]) -> Named<T> {
        Named {
            sigma_deg: a[0],
            rho_s: a[1],
            rho_d: a[2],
        }
    }

    /// As [σ, ρs, ρd].
    pub fn array(&self) -> [T; 3] {
        [self.sigma_deg, self.rho_s, self.rho_d]
    }
}

impl<T> std::ops::Index<usize> for Named<T> {
    type Output = T;
    fn index(&self, i: usize) -> &T {
        match i {
            0 => &self.sigma_deg,
            1 => &self.rho_s,
            _ => &self.rho_d,
        }
    }
}

/// One measured sheet as the batch sees it: its spots' values and covariances.
#[derive(Clone, Debug, PartialEq)]
pub struct SpotValues {
    /// σ (degrees), ρs, ρd; `None` where the fit did not determine it.
    pub values: [Option<f64>; 3],
    /// Their standard uncertainties (from the fit's covariance).
    pub uncertainties: [Option<f64>; 3],
}

/// The master stock's values and spread.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Master {
    /// The stock's name in the library.
    pub stock: String,
    /// Its sheets in the library.
    pub sheets: usize,
    /// Their spots.
    pub spots: usize,
    /// σ (degrees), ρs, ρd: the geometric mean of the sheets' geometric means; `null`
    /// where no sheet determined it.
    pub values: Named<Option<f64>>,
    /// Relative standard deviation of the sheets' means (`null`: fewer than two sheets).
    pub sheet_to_sheet_relative_sd: Named<Option<f64>>,
    /// Relative standard deviation of the spots about their sheet's mean, pooled over the
    /// sheets (`null`: no sheet of two spots).
    pub spot_to_spot_relative_sd: Named<Option<f64>>,
    /// The spots' own relative standard uncertainty, root mean square over the spots.
    pub spot_relative_uncertainty: Named<Option<f64>>,
}

/// Why no master can be made of a stock's sheets.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MasterError {
    /// No sheet, or no sheet that determined any parameter.
    #[error("the master stock '{0}' has no sheet with σ, ρs or ρd determined")]
    NoValues(String),
}

fn mean(xs: &[f64]) -> f64 {
    xs.iter().sum::<f64>() / xs.len() as f64
}

/// Sample standard deviation (n − 1); `None` below two values.
fn sd(xs: &[f64]) -> Option<f64> {
    (xs.len() >= 2).then(|| {
        let m = mean(xs);
        (xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (xs.len() - 1) as f64).sqrt()
    })
}

/// The logs of parameter `i` of `spots` that are determined and positive.
fn logs(spots: &[SpotValues], i: usize) -> Vec<f64> {
    spots
        .iter()
        .filter_map(|s| s.values[i].filter(|v| *v > 0.0 && v.is_finite()))
        .map(f64::ln)
        .collect()
}

/// A relative sd from the sd of logs: exp(s) − 1 is the factor one sd moves a value by.
fn relative(log_sd: f64) -> f64 {
    log_sd.exp_m1()
}

impl Master {
    /// The master of `stock` from its sheets (each its spots).
    pub fn of_sheets(stock: &str, sheets: &[Vec<SpotValues>]) -> Result<Master, MasterError> {
        let mut values = [None; 3];
        let mut between = [None; 3];
        let mut within = [None; 3];
        let mut own = [None; 3];
        for i in 0..3 {
            let sheet_means: Vec<f64> = sheets
                .iter()
                .map(|spots| logs(spots, i))
                .filter(|l| !l.is_empty())
                .map(|l| mean(&l))
                .collect();
            if sheet_means.is_empty() {
                continue;
            }
            values[i] = Some(mean(&sheet_means).exp());
            between[i] = sd(&sheet_means).map(relative);
            // Pooled within-sheet variance: Σ squared deviations over Σ (n − 1).
            let (mut squares, mut dof) = (0.0, 0usize);
            for spots in sheets {
                let l = logs(spots, i);
                if l.len() >= 2 {
                    let m = mean(&l);
                    squares += l.iter().map(|x| (x - m).powi(2)).sum::<f64>();
                    dof += l.len() - 1;
                }
            }
            within[i] = (dof > 0).then(|| relative((squares / dof as f64).sqrt()));
            let relative_u: Vec<f64> = sheets
                .iter()
                .flatten()
                .filter_map(|s| match (s.values[i], s.uncertainties[i]) {
                    (Some(v), Some(u)) if v > 0.0 && u.is_finite() && u >= 0.0 => Some(u / v),
                    _ => None,
                })
                .collect();
            own[i] = (!relative_u.is_empty()).then(|| {
                (relative_u.iter().map(|r| r * r).sum::<f64>() / relative_u.len() as f64).sqrt()
            });
        }
        if values.iter().all(Option::is_none) {
            return Err(MasterError::NoValues(stock.to_string()));
        }
        Ok(Master {
            stock: stock.to_string(),
            sheets: sheets.len(),
            spots: sheets.iter().map(Vec::len).sum(),
            values: Named::of(values),
            sheet_to_sheet_relative_sd: Named::of(between),
            spot_to_spot_relative_sd: Named::of(within),
            spot_relative_uncertainty: Named::of(own),
        })
    }

    /// The default tolerance of parameter `i`, percent, and what it rests on in words
    /// (the module's documentation says why).
    pub fn default_tolerance(&self, i: usize) -> (f64, String) {
        let sheets = self.sheets;
        // The spreads it may rest on; the spot-to-spot one only when the sheet-to-sheet one
        // is unknown (one sheet), as what a sheet of the stock may differ by at least.
        let mut candidates: Vec<(f64, String)> = Vec::new();
        match self.sheet_to_sheet_relative_sd[i] {
            Some(b) => candidates.push((b, format!("sheet-to-sheet sd over {sheets} sheets"))),
            None => {
                if let Some(w) = self.spot_to_spot_relative_sd[i] {
                    candidates.push((
                        w,
                        "spot-to-spot sd (one sheet: its sheet-to-sheet sd is unknown)".into(),
                    ));
                }
            }
        }
        if let Some(u) = self.spot_relative_uncertainty[i] {
            candidates.push((u, "spots' own standard uncertainty".into()));
        }
        let Some(largest) = candidates
            .iter()
            .cloned()
            .max_by(|a, b| a.0.total_cmp(&b.0))
        else {
            return (
                MIN_DEFAULT_TOLERANCE_PCT,
                format!(
                    "no spread of the master is known: the least default of {MIN_DEFAULT_TOLERANCE_PCT} %"
                ),
            );
        };
        let others: Vec<String> = candidates
            .iter()
            .filter(|c| c.1 != largest.1)
            .map(|c| format!("its {} is {:.2} %", c.1, 100.0 * c.0))
            .collect();
        let (spread, basis) = (
            largest.0,
            format!(
                "{DEFAULT_COVERAGE} × the master's {} ({:.2} %){}",
                largest.1,
                100.0 * largest.0,
                if others.is_empty() {
                    String::new()
                } else {
                    format!("; {}", others.join(", "))
                }
            ),
        );
        let pct = 100.0 * DEFAULT_COVERAGE * spread;
        if pct < MIN_DEFAULT_TOLERANCE_PCT {
            (
                MIN_DEFAULT_TOLERANCE_PCT,
                format!("{basis}, raised to the least default of {MIN_DEFAULT_TOLERANCE_PCT} %"),
            )
        } else {
            // Rounded up to 0.1 %, as a tolerance is written.
            ((pct * 10.0).ceil() / 10.0, basis)
        }
    }
}

/// A parameter beyond its tolerance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Exceedance {
    /// The parameter ([`PARAMETERS`]).
    pub parameter: String,
    /// The sheet's relative deviation from the master, percent.
    pub deviation_pct: f64,
    /// The tolerance, percent.
    pub tolerance_pct: f64,
    /// How far beyond the tolerance, percent (|deviation| − tolerance).
    pub beyond_pct: f64,
}

/// A sheet's verdict against the master.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "verdict", rename_all = "kebab-case")]
pub enum Verdict {
    /// Every parameter within its tolerance.
    Pass,
    /// These parameters beyond theirs.
    Fail {
        /// Each parameter beyond its tolerance.
        exceeded: Vec<Exceedance>,
    },
    /// Not judged.
    Undecided {
        /// Why.
        why: String,
    },
}

impl Verdict {
    /// "pass", "fail" or "undecided".
    pub fn name(&self) -> &'static str {
        match self {
            Verdict::Pass => "pass",
            Verdict::Fail { .. } => "fail",
            Verdict::Undecided { .. } => "undecided",
        }
    }

    /// The verdict in words: "fail: σ −57.9 % (tolerance ±3.0 %, 54.9 % beyond)".
    pub fn text(&self) -> String {
        match self {
            Verdict::Pass => "pass".to_string(),
            Verdict::Fail { exceeded } => format!(
                "fail: {}",
                exceeded
                    .iter()
                    .map(|e| format!(
                        "{} {:+.1} % (tolerance ±{:.1} %, {:.1} % beyond)",
                        label(&e.parameter),
                        e.deviation_pct,
                        e.tolerance_pct,
                        e.beyond_pct
                    ))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
            Verdict::Undecided { why } => format!("undecided: {why}"),
        }
    }
}

/// The label of a parameter's document name ("sigma_deg" → "σ").
pub fn label(parameter: &str) -> &str {
    PARAMETERS
        .iter()
        .position(|p| *p == parameter)
        .map_or(parameter, |i| LABELS[i])
}

/// The relative deviation of `value` from `master`, percent.
pub fn deviation_pct(value: Option<f64>, master: Option<f64>) -> Option<f64> {
    match (value, master) {
        (Some(v), Some(m)) if m > 0.0 && v.is_finite() => Some(100.0 * (v / m - 1.0)),
        _ => None,
    }
}

/// The verdict of a sheet of `values` (σ, ρs, ρd) against `master` with `tolerance_pct`;
/// `flags` are its result's flags that are not informational (any: undecided).
pub fn judge(
    values: [Option<f64>; 3],
    master: &Master,
    tolerance_pct: [f64; 3],
    flags: &[String],
) -> Verdict {
    if !flags.is_empty() {
        return Verdict::Undecided {
            why: format!("the sheet's result is flagged ({})", flags.join(", ")),
        };
    }
    let missing: Vec<&str> = (0..3)
        .filter(|&i| master.values[i].is_some() && values[i].is_none())
        .map(|i| LABELS[i])
        .collect();
    if !missing.is_empty() {
        return Verdict::Undecided {
            why: format!(
                "the sheet did not determine {} (the master did)",
                missing.join(", ")
            ),
        };
    }
    let exceeded: Vec<Exceedance> = (0..3)
        .filter_map(|i| {
            let d = deviation_pct(values[i], master.values[i])?;
            (d.abs() > tolerance_pct[i]).then(|| Exceedance {
                parameter: PARAMETERS[i].to_string(),
                deviation_pct: d,
                tolerance_pct: tolerance_pct[i],
                beyond_pct: d.abs() - tolerance_pct[i],
            })
        })
        .collect();
    if exceeded.is_empty() {
        Verdict::Pass
    } else {
        Verdict::Fail { exceeded }
    }
}

/// One quantity's statistics across the sheets, and its I-MR chart.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Statistics {
    /// The quantity ([`PARAMETERS`], or a gloss geometry's "gloss ISO 2813 60°").
    pub quantity: String,
    /// Sheets it rests on.
    pub n: usize,
    /// Their mean.
    pub mean: f64,
    /// Their standard deviation (n − 1); `null` below two sheets.
    pub sd: Option<f64>,
    /// The least.
    pub min: f64,
    /// The greatest.
    pub max: f64,
    /// The mean moving range of consecutive sheets; `null` below two sheets.
    pub moving_range_mean: Option<f64>,
    /// σ̂ = MR̄ / d₂; `null` below two sheets.
    pub sigma_hat: Option<f64>,
    /// Individuals' lower control limit, mean − 3 σ̂.
    pub lower_control_limit: Option<f64>,
    /// Individuals' upper control limit, mean + 3 σ̂.
    pub upper_control_limit: Option<f64>,
    /// Moving range's upper control limit, D₄ · MR̄.
    pub moving_range_upper_limit: Option<f64>,
    /// Sheets (numbers) outside the individuals' limits or after a moving range beyond its
    /// limit.
    pub out_of_control: Vec<u16>,
}

/// The statistics of `points` (sheet number, value), in the order measured; `None`
/// without any.
pub fn statistics(quantity: &str, points: &[(u16, f64)]) -> Option<Statistics> {
    if points.is_empty() {
        return None;
    }
    let xs: Vec<f64> = points.iter().map(|p| p.1).collect();
    let m = mean(&xs);
    let ranges: Vec<f64> = xs.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    let mr = (!ranges.is_empty()).then(|| mean(&ranges));
    let sigma_hat = mr.map(|r| r / D2);
    let limits = sigma_hat.map(|s| (m - 3.0 * s, m + 3.0 * s));
    let mr_limit = mr.map(|r| D4 * r);
    let mut out_of_control = Vec::new();
    for (k, &(number, x)) in points.iter().enumerate() {
        let outside = limits.is_some_and(|(lo, hi)| x < lo || x > hi);
        let jump = k > 0 && mr_limit.is_some_and(|l| ranges[k - 1] > l);
        if outside || jump {
            out_of_control.push(number);
        }
    }
    Some(Statistics {
        quantity: quantity.to_string(),
        n: xs.len(),
        mean: m,
        sd: sd(&xs),
        min: xs.iter().copied().fold(f64::INFINITY, f64::min),
        max: xs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        moving_range_mean: mr,
        sigma_hat,
        lower_control_limit: limits.map(|l| l.0),
        upper_control_limit: limits.map(|l| l.1),
        moving_range_upper_limit: mr_limit,
        out_of_control,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spot(values: [f64; 3], relative_u: f64) -> SpotValues {
        SpotValues {
            values: values.map(Some),
            uncertainties: values.map(|v| Some(v * relative_u)),
        }
    }

    fn master() -> Master {
        Master::of_sheets(
            "SG",
            &[
                vec![
                    spot([1.9, 57.0, 0.80], 0.01),
                    spot([1.92, 58.0, 0.79], 0.01),
                ],
                vec![spot([1.88, 57.5, 0.80], 0.01)],
            ],
        )
        .expect("a master")
    }

    #[test]
    fn the_master_is_the_geometric_mean_of_its_sheets() {
        let m = master();
        let sheet1 = (1.9f64 * 1.92).sqrt();
        let want = (sheet1 * 1.88).sqrt();
        assert!((m.values[0].unwrap() - want).abs() < 1e-12);
        let between = relative(sd(&[sheet1.ln(), 1.88f64.ln()]).unwrap());
        assert!((m.sheet_to_sheet_relative_sd[0].unwrap() - between).abs() < 1e-12);
        assert!((m.spot_relative_uncertainty[0].unwrap() - 0.01).abs() < 1e-12);
        assert_eq!((m.sheets, m.spots), (2, 3));
    }

    #[test]
    fn the_default_tolerance_is_three_spreads_and_never_below_the_floor() {
        let m = master();
        let (pct, basis) = m.default_tolerance(0);
        let spread = m.sheet_to_sheet_relative_sd[0]
            .unwrap()
            .max(m.spot_relative_uncertainty[0].unwrap());
        assert!(
            pct >= 300.0 * spread && pct < 300.0 * spread + 0.1 + 1e-9,
            "{pct} {basis}"
        );
        let tight = Master::of_sheets("T", &[vec![spot([1.0, 1.0, 1.0], 0.0001)]]).unwrap();
        let (pct, basis) = tight.default_tolerance(1);
        assert_eq!(pct, MIN_DEFAULT_TOLERANCE_PCT);
        assert!(basis.contains("least default"), "{basis}");
    }

    #[test]
    fn a_sheet_beyond_a_tolerance_fails_naming_it_and_a_flagged_one_is_undecided() {
        let m = master();
        let v = m.values.array();
        assert_eq!(judge(v, &m, [2.0; 3], &[]), Verdict::Pass);
        let off = [v[0].map(|s| s * 1.05), v[1], v[2]];
        match judge(off, &m, [2.0; 3], &[]) {
            Verdict::Fail { exceeded } => {
                assert_eq!(exceeded.len(), 1);
                assert_eq!(exceeded[0].parameter, "sigma_deg");
                assert!((exceeded[0].deviation_pct - 5.0).abs() < 1e-9);
                assert!((exceeded[0].beyond_pct - 3.0).abs() < 1e-9);
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            judge(off, &m, [2.0; 3], &["lack-of-fit".into()]),
            Verdict::Undecided { .. }
        ));
        assert!(matches!(
            judge([v[0], None, v[2]], &m, [2.0; 3], &[]),
            Verdict::Undecided { .. }
        ));
    }

    #[test]
    fn the_individuals_chart_flags_a_step_that_the_sd_only_widens() {
        let mut points: Vec<(u16, f64)> = (1..=10)
            .map(|k| (k, 1.0 + 0.01 * if k % 2 == 0 { 1.0 } else { -1.0 }))
            .collect();
        let s = statistics("x", &points).unwrap();
        assert!(s.out_of_control.is_empty(), "{s:?}");
        assert!((s.sigma_hat.unwrap() - 0.02 / D2).abs() < 1e-12);
        points.push((11, 1.2));
        let s = statistics("x", &points).unwrap();
        assert_eq!(s.out_of_control, vec![11], "{s:?}");
        assert!(statistics("x", &[]).is_none());
        let one = statistics("x", &[(1, 2.0)]).unwrap();
        assert_eq!((one.sd, one.upper_control_limit), (None, None));
    }
}
