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
//! # Gloss
//!
//! The library keeps no gloss, so the master gives none: gloss is judged against a
//! specification given with the batch ([`GlossSpec`], `--gloss-spec 60=45±3`: a geometry,
//! a target and a tolerance in GU, as a gloss meter's specification sheet gives them). A
//! sheet's gloss at a geometry is the mean of its accepted spots' ([`SheetGloss`]); it
//! exists only where an instrument profile was in force and the arms reach the geometry's
//! receptor ([`crate::analysis::gloss::arms_reach`]). A sheet without it at a specified
//! geometry is undecided for that quantity, with the reason: never a silent pass. The
//! sheet fails when any quantity (σ, ρs, ρd or a specified gloss) is beyond its tolerance,
//! is undecided when none is but one could not be judged, and passes when every one is
//! within.
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

/// A gloss specification: at one geometry, a target and a tolerance, gloss units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GlossSpec {
    /// The geometry as the gloss values name it ("ISO 2813 / ASTM D523 60°").
    pub geometry: String,
    /// Its angle, degrees.
    pub angle_deg: f64,
    /// The target, GU.
    pub target_gloss_units: f64,
    /// The tolerance either side of the target, GU.
    pub tolerance_gloss_units: f64,
}

/// The largest gloss a specification may name, GU (a perfect mirror reads 384 GU on the
/// TAPPI 75° scale, about 2000 at ISO 2813 20°).
pub const MAX_GLOSS_UNITS: f64 = 2500.0;

/// The geometry of [`GLOSS_GEOMETRIES`](crate::analysis::gloss::GLOSS_GEOMETRIES) that
/// `key` names: its angle ("60", "60°") or its name as the gloss values give it
/// ("ISO 2813 / ASTM D523 60°").
fn gloss_geometry(key: &str) -> Option<&'static crate::analysis::gloss::GlossGeometry> {
    let key = key.trim();
    let angle = key.trim_end_matches('°').trim_end_matches("deg").trim();
    crate::analysis::gloss::GLOSS_GEOMETRIES.iter().find(|g| {
        angle.parse::<f64>().is_ok_and(|a| a == g.angle_deg)
            || key.eq_ignore_ascii_case(&format!("{} {}", g.standard, g.name))
    })
}

/// The number `text` (a decimal comma taken as a point), finite.
fn gloss_number(text: &str) -> Option<f64> {
    text.trim()
        .replace(',', ".")
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
}

impl GlossSpec {
    /// Read `GEOMETRY=TARGET±TOLERANCE` (`+-` or `+/-` for ±): "60=45±3".
    pub fn parse(text: &str) -> Result<GlossSpec, String> {
        let known = || {
            crate::analysis::gloss::GLOSS_GEOMETRIES
                .iter()
                .map(|g| format!("{:.0}", g.angle_deg))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let Some((key, rest)) = text.split_once('=') else {
            return Err(format!(
                "'{text}' is not GEOMETRY=TARGET±TOLERANCE in GU (e.g. 60=45±3; +- for ±)"
            ));
        };
        let geometry = gloss_geometry(key).ok_or_else(|| {
            format!(
                "'{}' is not a gloss geometry gonio computes (the angle of one of: {})",
                key.trim(),
                known()
            )
        })?;
        let (target, tolerance) = ["±", "+/-", "+-"]
            .iter()
            .find_map(|sep| rest.split_once(sep))
            .ok_or_else(|| {
                format!("'{text}' gives no tolerance: GEOMETRY=TARGET±TOLERANCE in GU (e.g. 60=45±3; +- for ±)")
            })?;
        let target = gloss_number(target)
            .filter(|t| (0.0..=MAX_GLOSS_UNITS).contains(t))
            .ok_or_else(|| {
                format!(
                    "the target '{}' is not a gloss from 0 to {MAX_GLOSS_UNITS} GU",
                    target.trim()
                )
            })?;
        let tolerance = gloss_number(tolerance)
            .filter(|t| *t > 0.0 && *t <= MAX_GLOSS_UNITS)
            .ok_or_else(|| {
                format!(
                    "the tolerance '{}' is not a gloss above 0 and at most {MAX_GLOSS_UNITS} GU",
                    tolerance.trim()
                )
            })?;
        Ok(GlossSpec {
            geometry: format!("{} {}", geometry.standard, geometry.name),
            angle_deg: geometry.angle_deg,
            target_gloss_units: target,
            tolerance_gloss_units: tolerance,
        })
    }

    /// As given on the command line: "60=45±3".
    pub fn text(&self) -> String {
        format!(
            "{}={}±{}",
            self.angle_deg, self.target_gloss_units, self.tolerance_gloss_units
        )
    }

    /// The quantity as a person reads it: "gloss 60°".
    pub fn label(&self) -> String {
        gloss_label(self.angle_deg)
    }
}

/// "gloss 60°".
pub fn gloss_label(angle_deg: f64) -> String {
    format!("gloss {angle_deg}°")
}

impl std::str::FromStr for GlossSpec {
    type Err = String;
    fn from_str(text: &str) -> Result<GlossSpec, String> {
        GlossSpec::parse(text)
    }
}

/// One spot's gloss at one geometry, as its result gives it.
#[derive(Clone, Debug, PartialEq)]
pub struct SpotGloss {
    /// The geometry ("ISO 2813 / ASTM D523 60°").
    pub geometry: String,
    /// Its angle, degrees.
    pub angle_deg: f64,
    /// Gloss, GU.
    pub gloss_units: f64,
    /// Its standard uncertainty from the fit, GU.
    pub u_gloss_units: f64,
}

/// A sheet's gloss at one geometry: the mean over its accepted spots that have it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SheetGloss {
    /// The geometry ("ISO 2813 / ASTM D523 60°").
    pub geometry: String,
    /// Its angle, degrees.
    pub angle_deg: f64,
    /// The spots' mean, GU.
    pub gloss_units: f64,
    /// Standard uncertainty of the mean from the spots' own (their fits'), GU.
    pub u_gloss_units: f64,
    /// The spots' sd about their mean, GU (`null`: fewer than two spots).
    pub spot_to_spot_sd_gloss_units: Option<f64>,
    /// Spots it rests on.
    pub spots: usize,
}

/// The gloss of a sheet from its accepted spots' (`None`: the spot had no gloss computed,
/// no instrument profile being in force), by geometry in order of angle.
pub fn sheet_gloss(spots: &[Option<Vec<SpotGloss>>]) -> Vec<SheetGloss> {
    let mut angles: Vec<f64> = spots
        .iter()
        .flatten()
        .flatten()
        .map(|g| g.angle_deg)
        .collect();
    angles.sort_by(f64::total_cmp);
    angles.dedup();
    angles
        .into_iter()
        .filter_map(|angle| {
            let at: Vec<&SpotGloss> = spots
                .iter()
                .flatten()
                .flatten()
                .filter(|g| g.angle_deg == angle && g.gloss_units.is_finite())
                .collect();
            let first = at.first()?;
            let values: Vec<f64> = at.iter().map(|g| g.gloss_units).collect();
            let n = values.len() as f64;
            Some(SheetGloss {
                geometry: first.geometry.clone(),
                angle_deg: angle,
                gloss_units: mean(&values),
                u_gloss_units: at
                    .iter()
                    .map(|g| g.u_gloss_units.powi(2))
                    .sum::<f64>()
                    .sqrt()
                    / n,
                spot_to_spot_sd_gloss_units: sd(&values),
                spots: at.len(),
            })
        })
        .collect()
}

/// Why a sheet has no gloss at a geometry: no spot had gloss computed (no instrument
/// profile), or they had it at other geometries only (the arms do not reach this one's).
pub fn no_gloss_why(any_spot_had_gloss: bool, spec: &GlossSpec) -> String {
    if any_spot_had_gloss {
        format!(
            "no gloss at {}: the instrument's arms do not reach its receptor (gloss is computed only where they do)",
            spec.geometry
        )
    } else {
        "no gloss: no instrument profile was in force (gloss rests on the detector response measured on the black glass: gonio characterize, then --instrument FILE)".to_string()
    }
}

/// A sheet's gloss against one specification.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GlossJudgement {
    /// The geometry ("ISO 2813 / ASTM D523 60°").
    pub geometry: String,
    /// Its angle, degrees.
    pub angle_deg: f64,
    /// The sheet's gloss, GU (`null`: none at this geometry).
    pub gloss_units: Option<f64>,
    /// The specification's target, GU.
    pub target_gloss_units: f64,
    /// Its tolerance, GU.
    pub tolerance_gloss_units: f64,
    /// The sheet's gloss less the target, GU.
    pub deviation_gloss_units: Option<f64>,
    /// `pass`, `fail` or `undecided`.
    pub verdict: String,
    /// How far beyond the tolerance, GU, when it fails.
    pub beyond_gloss_units: Option<f64>,
    /// Why it is undecided.
    pub why: Option<String>,
}

impl GlossJudgement {
    /// The judgement of `gloss` (the sheet's, at the spec's geometry) against `spec`;
    /// `why_none` is why there is none, when there is none.
    pub fn of(spec: &GlossSpec, gloss: Option<f64>, why_none: impl FnOnce() -> String) -> Self {
        let deviation = gloss.map(|g| g - spec.target_gloss_units);
        let beyond = deviation
            .map(|d| d.abs() - spec.tolerance_gloss_units)
            .filter(|b| *b > 0.0);
        let (verdict, why) = match (gloss, beyond) {
            (None, _) => ("undecided", Some(why_none())),
            (Some(_), Some(_)) => ("fail", None),
            (Some(_), None) => ("pass", None),
        };
        GlossJudgement {
            geometry: spec.geometry.clone(),
            angle_deg: spec.angle_deg,
            gloss_units: gloss,
            target_gloss_units: spec.target_gloss_units,
            tolerance_gloss_units: spec.tolerance_gloss_units,
            deviation_gloss_units: deviation,
            verdict: verdict.to_string(),
            beyond_gloss_units: beyond,
            why,
        }
    }

    /// "gloss 60° 49.1 GU (spec 45 ± 3, 1.1 beyond)".
    pub fn text(&self) -> String {
        let label = gloss_label(self.angle_deg);
        match (self.gloss_units, self.beyond_gloss_units, &self.why) {
            (Some(g), Some(b), _) => format!(
                "{label} {g:.1} GU (spec {} ± {}, {b:.1} beyond)",
                self.target_gloss_units, self.tolerance_gloss_units
            ),
            (Some(g), None, _) => format!(
                "{label} {g:.1} GU (spec {} ± {})",
                self.target_gloss_units, self.tolerance_gloss_units
            ),
            (None, _, why) => format!("{label}: {}", why.as_deref().unwrap_or("no gloss")),
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
    /// These quantities beyond theirs.
    Fail {
        /// Each parameter beyond its tolerance.
        exceeded: Vec<Exceedance>,
        /// Each gloss beyond its specification (none in a batch of `gonio-batch/2`).
        #[serde(default)]
        gloss_exceeded: Vec<GlossJudgement>,
        /// The quantities that could not be judged, each with why: a sheet failing on one
        /// quantity says what it was not judged on as well.
        #[serde(default)]
        undecided: Vec<String>,
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
            Verdict::Fail {
                exceeded,
                gloss_exceeded,
                undecided,
            } => {
                let mut parts: Vec<String> = exceeded
                    .iter()
                    .map(|e| {
                        format!(
                            "{} {:+.1} % (tolerance ±{:.1} %, {:.1} % beyond)",
                            label(&e.parameter),
                            e.deviation_pct,
                            e.tolerance_pct,
                            e.beyond_pct
                        )
                    })
                    .collect();
                parts.extend(gloss_exceeded.iter().map(GlossJudgement::text));
                let mut text = format!("fail: {}", parts.join("; "));
                if !undecided.is_empty() {
                    text.push_str(&format!("; not judged: {}", undecided.join("; ")));
                }
                text
            }
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

/// A value of `quantity` ([`PARAMETERS`] or a [`gloss_label`]) as the batch's summary and
/// report write it: σ to 0.001°, ρs and ρd to 4 decimals, gloss to 0.1 GU.
pub fn shown_value(quantity: &str, v: Option<f64>) -> String {
    match v {
        None => "—".to_string(),
        Some(v) if quantity == PARAMETERS[0] => format!("{v:.3}°"),
        Some(v) if quantity.starts_with("gloss") => format!("{v:.1} GU"),
        Some(v) => format!("{v:.4}"),
    }
}

/// The relative deviation of `value` from `master`, percent.
pub fn deviation_pct(value: Option<f64>, master: Option<f64>) -> Option<f64> {
    match (value, master) {
        (Some(v), Some(m)) if m > 0.0 && v.is_finite() => Some(100.0 * (v / m - 1.0)),
        _ => None,
    }
}

/// The verdict of a sheet of `values` (σ, ρs, ρd) against `master` with `tolerance_pct`,
/// and of its gloss against the specifications (`gloss`, one judgement per
/// specification); `flags` are its result's flags that are not informational (any:
/// undecided, its gloss judgements included).
pub fn judge(
    values: [Option<f64>; 3],
    master: &Master,
    tolerance_pct: [f64; 3],
    flags: &[String],
    gloss: &[GlossJudgement],
) -> Verdict {
    if !flags.is_empty() {
        return Verdict::Undecided {
            why: format!("the sheet's result is flagged ({})", flags.join(", ")),
        };
    }
    let mut undecided = Vec::new();
    let missing: Vec<&str> = (0..3)
        .filter(|&i| master.values[i].is_some() && values[i].is_none())
        .map(|i| LABELS[i])
        .collect();
    if !missing.is_empty() {
        undecided.push(format!(
            "the sheet did not determine {} (the master did)",
            missing.join(", ")
        ));
    }
    undecided.extend(
        gloss
            .iter()
            .filter(|g| g.verdict == "undecided")
            .map(GlossJudgement::text),
    );
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
    let gloss_exceeded: Vec<GlossJudgement> = gloss
        .iter()
        .filter(|g| g.verdict == "fail")
        .cloned()
        .collect();
    if !exceeded.is_empty() || !gloss_exceeded.is_empty() {
        Verdict::Fail {
            exceeded,
            gloss_exceeded,
            undecided,
        }
    } else if !undecided.is_empty() {
        Verdict::Undecided {
            why: undecided.join("; "),
        }
    } else {
        Verdict::Pass
    }
}

/// One quantity's statistics across the sheets, and its I-MR chart.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Statistics {
    /// The quantity ([`PARAMETERS`], or a gloss geometry's [`gloss_label`], "gloss 60°").
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
        assert_eq!(judge(v, &m, [2.0; 3], &[], &[]), Verdict::Pass);
        let off = [v[0].map(|s| s * 1.05), v[1], v[2]];
        match judge(off, &m, [2.0; 3], &[], &[]) {
            Verdict::Fail { exceeded, .. } => {
                assert_eq!(exceeded.len(), 1);
                assert_eq!(exceeded[0].parameter, "sigma_deg");
                assert!((exceeded[0].deviation_pct - 5.0).abs() < 1e-9);
                assert!((exceeded[0].beyond_pct - 3.0).abs() < 1e-9);
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            judge(off, &m, [2.0; 3], &["lack-of-fit".into()], &[]),
            Verdict::Undecided { .. }
        ));
        assert!(matches!(
            judge([v[0], None, v[2]], &m, [2.0; 3], &[], &[]),
            Verdict::Undecided { .. }
        ));
    }

    #[test]
    fn a_gloss_spec_reads_as_a_gloss_meter_s_sheet_writes_it_and_bad_ones_say_why() {
        let spec = GlossSpec::parse("60=45±3").unwrap();
        assert_eq!(spec.geometry, "ISO 2813 / ASTM D523 60°");
        assert_eq!(
            (
                spec.angle_deg,
                spec.target_gloss_units,
                spec.tolerance_gloss_units
            ),
            (60.0, 45.0, 3.0)
        );
        assert_eq!(spec.text(), "60=45±3");
        assert_eq!(GlossSpec::parse("60°=45+-3").unwrap(), spec);
        assert_eq!(GlossSpec::parse(" 60 = 45 +/- 3 ").unwrap(), spec);
        assert_eq!(
            GlossSpec::parse("75=21,5±1,5").unwrap().target_gloss_units,
            21.5
        );
        assert_eq!(
            GlossSpec::parse("ISO 2813 / ASTM D523 20°=80±4")
                .unwrap()
                .angle_deg,
            20.0
        );
        for (bad, says) in [
            ("60", "not GEOMETRY=TARGET±TOLERANCE"),
            ("45=45±3", "'45' is not a gloss geometry"),
            ("60=45", "gives no tolerance"),
            ("60=x±3", "the target 'x'"),
            ("60=-1±3", "the target '-1'"),
            ("60=45±0", "the tolerance '0'"),
            ("60=45±NaN", "the tolerance 'NaN'"),
        ] {
            let e = GlossSpec::parse(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn a_sheet_beyond_its_gloss_spec_fails_naming_it_and_one_without_gloss_is_undecided() {
        let m = master();
        let v = m.values.array();
        let spec = GlossSpec::parse("60=45±3").unwrap();
        let within = GlossJudgement::of(&spec, Some(47.0), || unreachable!());
        assert_eq!(within.verdict, "pass");
        assert_eq!(judge(v, &m, [2.0; 3], &[], &[within]), Verdict::Pass);
        let beyond = GlossJudgement::of(&spec, Some(49.1), || unreachable!());
        assert_eq!(beyond.verdict, "fail");
        assert!((beyond.beyond_gloss_units.unwrap() - 1.1).abs() < 1e-9);
        let verdict = judge(v, &m, [2.0; 3], &[], std::slice::from_ref(&beyond));
        assert_eq!(
            verdict.text(),
            "fail: gloss 60° 49.1 GU (spec 45 ± 3, 1.1 beyond)"
        );
        // No gloss: undecided with the reason, never a pass; beside a failure, named too.
        let none = GlossJudgement::of(&spec, None, || no_gloss_why(false, &spec));
        let verdict = judge(v, &m, [2.0; 3], &[], std::slice::from_ref(&none));
        assert_eq!(verdict.name(), "undecided");
        assert!(
            verdict
                .text()
                .contains("gloss 60°: no gloss: no instrument profile"),
            "{}",
            verdict.text()
        );
        let unreached = GlossJudgement::of(&spec, None, || no_gloss_why(true, &spec));
        assert!(
            unreached.text().contains("arms do not reach"),
            "{}",
            unreached.text()
        );
        let text = judge(v, &m, [2.0; 3], &[], &[beyond, none]).text();
        assert!(
            text.starts_with("fail: gloss 60° 49.1 GU")
                && text.contains("not judged: gloss 60°: no gloss"),
            "{text}"
        );
    }

    #[test]
    fn a_sheet_s_gloss_is_its_spots_mean_at_each_geometry() {
        let g = |angle: f64, gu: f64| SpotGloss {
            geometry: format!("at {angle}"),
            angle_deg: angle,
            gloss_units: gu,
            u_gloss_units: 0.3,
        };
        let sheet = sheet_gloss(&[
            Some(vec![g(20.0, 10.0), g(60.0, 40.0)]),
            None,
            Some(vec![g(60.0, 44.0)]),
        ]);
        assert_eq!(sheet.len(), 2);
        assert_eq!((sheet[0].angle_deg, sheet[0].spots), (20.0, 1));
        assert_eq!((sheet[1].gloss_units, sheet[1].spots), (42.0, 2));
        assert!((sheet[1].spot_to_spot_sd_gloss_units.unwrap() - 8f64.sqrt()).abs() < 1e-12);
        assert!((sheet[1].u_gloss_units - 0.18f64.sqrt() / 2.0).abs() < 1e-12);
        assert!(sheet_gloss(&[None, None]).is_empty());
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
