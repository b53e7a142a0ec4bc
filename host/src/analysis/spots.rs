//! A sheet measured at several spots: which spots its result rests on, how many more to
//! measure, and the sheet's mean parameters with their spot-to-spot (within-sheet)
//! variation. Pure: the session ([`crate::session::multi_spot`]) measures, this decides.
//!
//! The rules, for `planned` spots and at most `replacements` more:
//! - a spot whose result is clean (no flag but informational ones) is accepted;
//! - a flagged spot (lack-of-fit, lost steps, σ not resolved, …) is excluded with its
//!   flags as the reason, and another spot is measured in its place while replacements
//!   remain: one bad area (a crease, a watermark, dust) or one bad run must not decide
//!   the sheet;
//! - when no spot came out clean, the flags are the sheet's and not a spot's: every spot
//!   is kept and the sheet carries their flags, so the result says what it is rather than
//!   resting on nothing.

use crate::analysis::evidence::{ShapeWidening, Sheet, Spot};
use crate::analysis::flags::{self, Flag};
use serde::{Deserialize, Serialize};

/// Spots of a sheet when `gonio measure --spots` is not given: the fewest whose library
/// search ranks a sheet's own stock first in at least 95 % of trials with the whole 95 %
/// interval above it (`gonio forensic`'s spots-per-sheet study, docs/FORENSIC.md: 84.8 %
/// at 1 spot, 94.8 % at 3, 96.9 % (95.8–97.7 %) at 5, for about 11 device seconds a spot).
pub const DEFAULT_SPOTS: u16 = 5;

/// More spots measured, at most, in place of flagged ones.
pub(crate) const MAX_REPLACEMENTS: u16 = 2;

/// What a measured spot contributes to its sheet.
#[derive(Clone, Debug, PartialEq)]
pub struct SpotResult {
    /// Its number in the sheet, from 1, in the order measured.
    pub number: u16,
    /// Its session's flags.
    pub flags: Vec<Flag>,
    /// σ (degrees), ρs, ρd and their covariance, as its session reported them.
    pub spot: Spot,
    /// Its fit's `model form` widening and how far its terms moved it from the paper's
    /// model, which the evidence weighs in the widening's place ([`Spot::weighed`]).
    pub shape_widening: ShapeWidening,
    /// Its own class (`None`: undecided), as its session reported it.
    pub class: Option<String>,
}

/// The number of the next spot to measure, or `None` when the sheet is done: `planned`
/// clean spots, or the replacements spent.
pub(crate) fn next_spot(planned: u16, replacements: u16, results: &[SpotResult]) -> Option<u16> {
    let measured = results.len() as u16;
    let clean = results.iter().filter(|r| flags::ok(&r.flags)).count() as u16;
    let budget = planned.saturating_add(replacements);
    (clean < planned && measured < budget).then_some(measured + 1)
}

/// Whether a spot counts for its sheet.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "verdict", rename_all = "kebab-case")]
pub enum SpotVerdict {
    /// Its parameters are part of the sheet's.
    Accepted,
    /// Left out, and why.
    Excluded {
        /// Why, in words.
        reason: String,
    },
}

/// One spot's verdict.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Judged {
    /// The spot's number.
    pub number: u16,
    /// Whether it counts.
    #[serde(flatten)]
    pub verdict: SpotVerdict,
}

/// The sheet's result from its spots.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SheetSummary {
    /// Each spot's number and verdict, in the order measured.
    pub verdicts: Vec<Judged>,
    /// Spots accepted.
    pub accepted: usize,
    /// The sheet's σ (degrees), ρs, ρd: the geometric mean over the accepted spots (the
    /// spots vary relatively); `None` where a spot did not determine it. Written as
    /// `{sigma_deg, rho_s, rho_d}` (an array in `gonio-sheet/2` and before, still read).
    #[serde(with = "named")]
    pub mean: [Option<f64>; 3],
    /// The spots' relative standard deviation of σ, ρs, ρd about that mean (from the
    /// accepted spots' logs); `None` with fewer than two spots: unknown, not zero. Named
    /// as `mean` is.
    #[serde(with = "named_option")]
    pub within_relative_sd: Option<[f64; 3]>,
    /// The within-sheet covariance of (ln σ, ln ρs, ln ρd) over the accepted spots;
    /// `None` with fewer than two.
    pub(crate) within_log_covariance: Option<[[f64; 3]; 3]>,
    /// The sheet's flags: the informational flags of every spot, and, when no spot was
    /// clean, every spot's flags.
    pub flags: Vec<Flag>,
    /// What a reader must know about the result, in words (empty when nothing).
    pub notes: Vec<String>,
    /// The sheet's answer: its class, confidence and the mean's intervals (`None` in a
    /// sheet written before `gonio-sheet/3`, which did not record one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub answer: Option<SheetAnswer>,
}

/// A 95 % interval, low and high.
pub type Interval = [f64; 2];

/// The sheet's mean's 95 % intervals.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SheetIntervals {
    /// σ, degrees (in log space: exp(mean ± k·u)).
    pub sigma_deg: Option<Interval>,
    /// ρs (in log space, as σ's).
    pub rho_s: Option<Interval>,
    /// ρd (linear: mean ± k·u, u by the delta method from the log's, clipped at 0).
    pub rho_d: Option<Interval>,
}

/// The sheet's answer from its accepted spots: the class of its mean parameters and how
/// sure it is, with the spot-to-spot variation in the uncertainty.
///
/// The mean's covariance in (ln σ, ln ρs, ln ρd) is its sampling covariance from the
/// spots, W/n, widened by (t₀.₉₇₅,ₙ₋₁ / z₀.₉₇₅)² so that with few spots its 95 % reach is
/// Student's and not the normal's, plus the spots' own fit covariance averaged over them,
/// F̄, not divided by n: the spots share one calibration, whose errors (the white tile's,
/// the gain ratios', the arm zero's: most of a fit's covariance on a clean spot) do not
/// average out over the spots, and a spot's covariance does not say which share is the
/// calibration's; taking all of it as shared errs on the wide side, as `gonio compare`'s
/// interval of a sheet does. One spot has no spot-to-spot variation to measure:
/// its fit's covariance alone, and the sheet's notes say so. The class and the confidence
/// are [`crate::analysis::classify::classify_log_mean`]'s (the sampling one spot's are).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SheetAnswer {
    /// The class of the sheet's mean (G, SG, rough-I, rough-II, rough-III); `None` when
    /// undecided.
    pub class: Option<String>,
    /// Glossy or rough, with the class.
    pub group: Option<String>,
    /// The share of the mean's uncertainty region in `class`, 0…1; `None` without a class.
    pub class_confidence: Option<f64>,
    /// Why no class was stated.
    pub undecided: Option<String>,
    /// The mean's 95 % intervals.
    pub ci95: SheetIntervals,
    /// The covariance of the mean's (ln σ, ln ρs, ln ρd) the class and intervals rest on;
    /// `None` when a parameter is not determined at every accepted spot.
    pub mean_log_covariance: Option<[[f64; 3]; 3]>,
    /// The coverage factor of the intervals: z₀.₉₇₅ (the spot-to-spot part's t already in
    /// the covariance).
    pub coverage_factor: f64,
    /// Spots left out of the answer (flagged while a clean spot exists).
    pub excluded: usize,
    /// The answer's flags: the sheet's, and `spots-disagree` when its accepted spots do not
    /// all have one class.
    pub flags: Vec<Flag>,
    /// When the spots disagree in class: which class each spot has, in words.
    pub spots_disagree: Option<String>,
}

/// The normal's 0.975 quantile.
const Z_975: f64 = 1.959_963_984_540_054;

/// When the accepted spots do not all have one class: each class and its spots, in words.
fn disagreement(accepted: &[&SpotResult]) -> Option<String> {
    // Which spots have which class, in the order the classes first appear.
    let mut by_class: Vec<(String, Vec<u16>)> = Vec::new();
    for r in accepted {
        let name = r.class.clone().unwrap_or_else(|| "undecided".into());
        match by_class.iter_mut().find(|(c, _)| *c == name) {
            Some((_, numbers)) => numbers.push(r.number),
            None => by_class.push((name, vec![r.number])),
        }
    }
    (by_class.len() > 1).then(|| {
        let parts: Vec<String> = by_class
            .iter()
            .map(|(class, numbers)| {
                let list: Vec<String> = numbers.iter().map(u16::to_string).collect();
                format!(
                    "{class} at spot{} {}",
                    if numbers.len() == 1 { "" } else { "s" },
                    list.join(", ")
                )
            })
            .collect();
        format!("the accepted spots disagree in class: {}", parts.join("; "))
    })
}

/// The sheet's answer from its accepted spots (`logs`: their (ln σ, ln ρs, ln ρd)) and
/// the within-sheet covariance of those logs (see [`SheetAnswer`]).
fn answer(
    accepted: &[&SpotResult],
    mean_log: [Option<f64>; 3],
    within_log_covariance: Option<[[f64; 3]; 3]>,
    sheet_flags: &[Flag],
    excluded: usize,
) -> SheetAnswer {
    let n = accepted.len();
    let mut flags = sheet_flags.to_vec();
    let spots_disagree = disagreement(accepted);
    if spots_disagree.is_some() {
        flags.push(Flag::SpotsDisagree);
        flags.sort();
        flags.dedup();
    }
    let undetermined = |why: String| SheetAnswer {
        class: None,
        group: None,
        class_confidence: None,
        undecided: Some(why),
        ci95: SheetIntervals::default(),
        mean_log_covariance: None,
        coverage_factor: Z_975,
        excluded,
        flags: flags.clone(),
        spots_disagree: spots_disagree.clone(),
    };
    let Some(mean_log) = mean_log
        .iter()
        .copied()
        .collect::<Option<Vec<f64>>>()
        .and_then(|v| <[f64; 3]>::try_from(v).ok())
    else {
        let missing: Vec<&str> = ["σ", "ρs", "ρd"]
            .iter()
            .zip(mean_log)
            .filter(|(_, m)| m.is_none())
            .map(|(name, _)| *name)
            .collect();
        return undetermined(if n == 0 {
            "no spot measured".to_string()
        } else {
            format!(
                "{} not determined at every accepted spot: no mean to classify",
                missing.join(", ")
            )
        });
    };
    // The spots' own fit covariance of the logs (delta method), averaged.
    let mut fit_mean = [[0.0; 3]; 3];
    for r in accepted {
        let v = r.spot.values.map(|v| v.unwrap_or(f64::NAN));
        for (i, row) in fit_mean.iter_mut().enumerate() {
            for (j, cell) in row.iter_mut().enumerate() {
                let c = r.spot.covariance[i][j] / (v[i] * v[j]);
                *cell += if c.is_finite() { c } else { 0.0 } / n as f64;
            }
        }
    }
    let t_widening = within_log_covariance.map_or(0.0, |_| {
        (crate::analysis::fit::t_quantile_975(n - 1) / Z_975).powi(2)
    });
    let within = within_log_covariance.unwrap_or([[0.0; 3]; 3]);
    let covariance: [[f64; 3]; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|j| within[i][j] * t_widening / n as f64 + fit_mean[i][j])
    });
    let u: [f64; 3] = std::array::from_fn(|i| covariance[i][i].max(0.0).sqrt());
    let log_interval = |i: usize| {
        Some([
            (mean_log[i] - Z_975 * u[i]).exp(),
            (mean_log[i] + Z_975 * u[i]).exp(),
        ])
    };
    let rho_d = mean_log[2].exp();
    let ci95 = SheetIntervals {
        sigma_deg: log_interval(0),
        rho_s: log_interval(1),
        rho_d: Some([
            (rho_d - Z_975 * rho_d * u[2]).max(0.0),
            rho_d + Z_975 * rho_d * u[2],
        ]),
    };
    let (class, confidence) =
        crate::analysis::classify::classify_log_mean(mean_log, &covariance, &flags);
    SheetAnswer {
        class: Some(class.name().to_string()),
        group: Some(class.group().name().to_string()),
        class_confidence: Some(confidence),
        undecided: None,
        ci95,
        mean_log_covariance: Some(covariance),
        coverage_factor: Z_975,
        excluded,
        flags,
        spots_disagree,
    }
}

/// `[a, b, c]` of σ, ρs, ρd written as `{sigma_deg, rho_s, rho_d}`, read from either.
#[derive(Serialize, Deserialize)]
struct Named<T> {
    sigma_deg: T,
    rho_s: T,
    rho_d: T,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum NamedOrArray<T> {
    Named(Named<T>),
    Array([T; 3]),
}

impl<T> NamedOrArray<T> {
    fn into_array(self) -> [T; 3] {
        match self {
            NamedOrArray::Named(n) => [n.sigma_deg, n.rho_s, n.rho_d],
            NamedOrArray::Array(a) => a,
        }
    }
}

fn named_of<T: Copy>(a: &[T; 3]) -> Named<T> {
    Named {
        sigma_deg: a[0],
        rho_s: a[1],
        rho_d: a[2],
    }
}

mod named {
    use super::{NamedOrArray, named_of};
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<S: Serializer>(v: &[Option<f64>; 3], s: S) -> Result<S::Ok, S::Error> {
        named_of(v).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[Option<f64>; 3], D::Error> {
        NamedOrArray::<Option<f64>>::deserialize(d).map(NamedOrArray::into_array)
    }
}

mod named_option {
    use super::{NamedOrArray, named_of};
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<S: Serializer>(v: &Option<[f64; 3]>, s: S) -> Result<S::Ok, S::Error> {
        v.as_ref().map(named_of).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
        Option::<NamedOrArray<f64>>::deserialize(d).map(|v| v.map(NamedOrArray::into_array))
    }
}

impl SheetSummary {
    /// No flag but the informational ones.
    pub fn ok(&self) -> bool {
        flags::ok(&self.flags)
    }

    /// The accepted spots of `results`, as the evidence weighs the sheet
    /// ([`Spot::weighed`]).
    pub fn sheet(&self, results: &[SpotResult]) -> Sheet {
        Sheet {
            spots: self
                .accepted(results)
                .map(|r| r.spot.weighed(r.shape_widening))
                .collect(),
        }
    }

    /// The accepted spots of `results` as their sessions reported them: what their
    /// intervals, and a sheet's shown beside a comparison, are made of.
    pub fn reported(&self, results: &[SpotResult]) -> Sheet {
        Sheet {
            spots: self.accepted(results).map(|r| r.spot.clone()).collect(),
        }
    }

    /// The accepted ones of `results`.
    fn accepted<'r>(&self, results: &'r [SpotResult]) -> impl Iterator<Item = &'r SpotResult> {
        results.iter().filter(|r| {
            self.verdicts
                .iter()
                .any(|j| j.number == r.number && j.verdict == SpotVerdict::Accepted)
        })
    }
}

/// A sheet's spots counted as the terminal, `--json` and the report say them: a flagged
/// spot is never counted as accepted (issue 31: "5 of 3 spots planned accepted" for five
/// flagged spots).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SpotCounts {
    /// Spots planned (`--spots`).
    pub planned: u16,
    /// Spots measured (replacements of flagged spots included).
    pub measured: usize,
    /// Spots whose result is flagged (informational flags apart).
    pub flagged: usize,
    /// Clean spots in the sheet's mean.
    pub accepted: usize,
    /// Flagged spots in the sheet's mean (when no spot came out clean).
    pub flagged_in_mean: usize,
}

impl SpotCounts {
    /// The counts of `summary`'s spots, each spot's flags from `flags_of`.
    pub fn of(planned: u16, summary: &SheetSummary, flags_of: impl Fn(u16) -> Vec<Flag>) -> Self {
        let mut counts = SpotCounts {
            planned,
            measured: summary.verdicts.len(),
            flagged: 0,
            accepted: 0,
            flagged_in_mean: 0,
        };
        for judged in &summary.verdicts {
            let clean = flags::ok(&flags_of(judged.number));
            let in_mean = judged.verdict == SpotVerdict::Accepted;
            counts.flagged += usize::from(!clean);
            counts.accepted += usize::from(clean && in_mean);
            counts.flagged_in_mean += usize::from(!clean && in_mean);
        }
        counts
    }

    /// In words: "5 spots planned, 7 measured: 5 accepted, 2 flagged (excluded)".
    pub fn sentence(&self) -> String {
        let plural = |n: usize| if n == 1 { "" } else { "s" };
        let mut text = format!(
            "{} spot{} planned, {} measured: {} accepted, {} flagged",
            self.planned,
            plural(usize::from(self.planned)),
            self.measured,
            self.accepted,
            self.flagged
        );
        if self.flagged_in_mean > 0 {
            text.push_str(&format!(
                " (no spot came out clean: the sheet's mean is of {} flagged spot{})",
                self.flagged_in_mean,
                plural(self.flagged_in_mean)
            ));
        } else if self.flagged > 0 {
            text.push_str(" (excluded)");
        }
        text
    }

    /// A spot's verdict in words: "accepted", "FLAGGED, in the mean: no spot came out
    /// clean", or "EXCLUDED: reason".
    pub fn verdict_words(verdict: Option<&SpotVerdict>, flags: &[Flag]) -> String {
        match verdict {
            Some(SpotVerdict::Accepted) if flags::ok(flags) => "accepted".to_string(),
            Some(SpotVerdict::Accepted) => {
                "FLAGGED, in the sheet's mean only because no spot came out clean".to_string()
            }
            Some(SpotVerdict::Excluded { reason }) => format!("EXCLUDED: {reason}"),
            None => "?".to_string(),
        }
    }
}

/// The sheet's result from its measured spots (see the module's rules).
pub(crate) fn assess(planned: u16, results: &[SpotResult]) -> SheetSummary {
    let any_clean = results.iter().any(|r| flags::ok(&r.flags));
    let mut sheet_flags: Vec<Flag> = Vec::new();
    let mut notes = Vec::new();
    let verdicts: Vec<Judged> = results
        .iter()
        .map(|r| {
            sheet_flags.extend(r.flags.iter().copied().filter(|f| f.is_informational() || !any_clean));
            let verdict = if flags::ok(&r.flags) || !any_clean {
                SpotVerdict::Accepted
            } else {
                let names: Vec<&str> = r.flags.iter().filter(|f| !f.is_informational()).map(|f| f.name()).collect();
                SpotVerdict::Excluded { reason: format!("flagged {}: this spot's result is not clean, the sheet's rests on its clean spots", names.join(", ")) }
            };
            Judged { number: r.number, verdict }
        })
        .collect();
    sheet_flags.sort();
    sheet_flags.dedup();
    if !results.is_empty() && !any_clean {
        notes.push(format!("no spot of {} came out clean: the sheet's parameters are from flagged spots and carry their flags", results.len()));
    }
    let accepted: Vec<&SpotResult> = results
        .iter()
        .filter(|r| {
            verdicts
                .iter()
                .any(|j| j.number == r.number && j.verdict == SpotVerdict::Accepted)
        })
        .collect();
    if accepted.len() < planned as usize && any_clean {
        notes.push(format!("{} clean spot{} of the {planned} planned: the replacements for flagged spots were spent", accepted.len(), if accepted.len() == 1 { "" } else { "s" }));
    }
    if accepted.len() == 1 {
        notes.push("one spot: the sheet's spot-to-spot variation is unknown; comparisons use the population's".to_string());
    }
    let logs: Vec<[Option<f64>; 3]> = accepted
        .iter()
        .map(|r| {
            r.spot
                .values
                .map(|v| v.filter(|v| *v > 0.0 && v.is_finite()).map(f64::ln))
        })
        .collect();
    let n = logs.len();
    let mean_log: [Option<f64>; 3] = std::array::from_fn(|i| {
        let all: Option<Vec<f64>> = logs.iter().map(|l| l[i]).collect();
        all.filter(|v| !v.is_empty())
            .map(|v| v.iter().sum::<f64>() / v.len() as f64)
    });
    let within_log_covariance = (n >= 2 && mean_log.iter().all(Option::is_some)).then(|| {
        let m = mean_log.map(|v| v.unwrap_or(0.0));
        std::array::from_fn(|r| {
            std::array::from_fn(|c| {
                logs.iter()
                    .map(|l| (l[r].unwrap_or(m[r]) - m[r]) * (l[c].unwrap_or(m[c]) - m[c]))
                    .sum::<f64>()
                    / (n - 1) as f64
            })
        })
    });
    let excluded = results.len() - n;
    let answer = answer(
        &accepted,
        mean_log,
        within_log_covariance,
        &sheet_flags,
        excluded,
    );
    SheetSummary {
        answer: Some(answer),
        verdicts,
        accepted: n,
        mean: mean_log.map(|v| v.map(f64::exp)),
        // exp(s) − 1 is the relative spread a log-normal spread of s means.
        within_relative_sd: within_log_covariance
            .map(|c: [[f64; 3]; 3]| std::array::from_fn(|i| c[i][i].sqrt().exp_m1())),
        within_log_covariance,
        flags: sheet_flags,
        notes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 31: three spots planned, five measured, every one flagged: none accepted.
    #[test]
    fn flagged_spots_are_counted_flagged_never_accepted() {
        let flagged: Vec<SpotResult> = (1..=5)
            .map(|n| result(n, &[Flag::LostSteps], 3.0 + f64::from(n)))
            .collect();
        let summary = assess(3, &flagged);
        let counts = SpotCounts::of(3, &summary, |_| vec![Flag::LostSteps]);
        assert_eq!(
            (
                counts.measured,
                counts.accepted,
                counts.flagged,
                counts.flagged_in_mean
            ),
            (5, 0, 5, 5)
        );
        let text = counts.sentence();
        assert!(
            text.starts_with("3 spots planned, 5 measured: 0 accepted, 5 flagged"),
            "{text}"
        );
        let words =
            SpotCounts::verdict_words(Some(&summary.verdicts[0].verdict), &[Flag::LostSteps]);
        assert!(!words.starts_with("accepted"), "{words}");
        // One flagged among clean ones: excluded, the rest accepted.
        let mixed = [
            result(1, &[], 5.0),
            result(2, &[Flag::LostSteps], 6.0),
            result(3, &[], 5.5),
        ];
        let summary = assess(2, &mixed);
        let counts = SpotCounts::of(2, &summary, |n| mixed[usize::from(n) - 1].flags.clone());
        assert_eq!(
            counts.sentence(),
            "2 spots planned, 3 measured: 2 accepted, 1 flagged (excluded)"
        );
    }

    fn result(number: u16, flags: &[Flag], sigma: f64) -> SpotResult {
        let values = [Some(sigma), Some(0.4), Some(0.41)];
        SpotResult {
            number,
            flags: flags.to_vec(),
            class: Some(if sigma < 0.4 { "G" } else { "rough-II" }.to_string()),
            shape_widening: ShapeWidening::default(),
            spot: Spot {
                values,
                covariance: [[1e-6, 0.0, 0.0], [0.0, 1e-6, 0.0], [0.0, 0.0, 1e-6]],
            },
        }
    }

    #[test]
    fn a_flagged_spot_is_replaced_until_the_replacements_are_spent() {
        let clean = |n| result(n, &[Flag::Resumed], 20.0);
        let flagged = |n| result(n, &[Flag::LackOfFit], 20.0);
        assert_eq!(next_spot(3, 2, &[]), Some(1));
        assert_eq!(next_spot(3, 2, &[clean(1), clean(2)]), Some(3));
        assert_eq!(next_spot(3, 2, &[clean(1), clean(2), clean(3)]), None);
        assert_eq!(next_spot(3, 2, &[clean(1), flagged(2), clean(3)]), Some(4));
        assert_eq!(
            next_spot(3, 2, &[clean(1), flagged(2), clean(3), clean(4)]),
            None
        );
        assert_eq!(
            next_spot(3, 2, &[flagged(1), flagged(2), flagged(3), flagged(4)]),
            Some(5)
        );
        assert_eq!(
            next_spot(
                3,
                2,
                &[flagged(1), flagged(2), flagged(3), flagged(4), flagged(5)]
            ),
            None
        );
        assert_eq!(next_spot(1, 0, &[flagged(1)]), None);
    }

    #[test]
    fn flagged_spots_are_excluded_with_the_reason_while_a_clean_one_exists() {
        let results = [
            result(1, &[], 20.0),
            result(2, &[Flag::LostSteps, Flag::LinkRecovered], 30.0),
            result(3, &[], 21.0),
        ];
        let s = assess(3, &results);
        assert_eq!(s.accepted, 2);
        assert!(
            matches!(&s.verdicts[1].verdict, SpotVerdict::Excluded { reason } if reason.contains("lost-steps") && !reason.contains("link-recovered")),
            "{:?}",
            s.verdicts
        );
        assert_eq!(
            s.flags,
            [Flag::LinkRecovered],
            "informational flags carry to the sheet, the excluded spot's others do not"
        );
        assert!(s.ok());
        let mean = s.mean[0].unwrap();
        assert!(
            (mean - (20.0f64 * 21.0).sqrt()).abs() < 1e-9,
            "geometric mean of the accepted spots: {mean}"
        );
        assert_eq!(s.sheet(&results).spots.len(), 2);
        assert!(
            s.notes
                .iter()
                .any(|n| n.contains("2 clean spots of the 3 planned")),
            "{:?}",
            s.notes
        );
    }

    #[test]
    fn with_no_clean_spot_the_sheet_keeps_every_spot_and_their_flags() {
        let results = [
            result(1, &[Flag::LackOfFit], 20.0),
            result(2, &[Flag::LackOfFit, Flag::SigmaNotResolved], 21.0),
        ];
        let s = assess(2, &results);
        assert_eq!(s.accepted, 2);
        assert_eq!(s.flags, [Flag::LackOfFit, Flag::SigmaNotResolved]);
        assert!(!s.ok());
        assert!(s.notes[0].contains("no spot of 2 came out clean"));
    }

    fn exact(number: u16, class: &str, values: [f64; 3]) -> SpotResult {
        SpotResult {
            number,
            flags: Vec::new(),
            class: Some(class.to_string()),
            shape_widening: ShapeWidening::default(),
            spot: Spot {
                values: values.map(Some),
                covariance: [[0.0; 3]; 3],
            },
        }
    }

    #[test]
    fn the_answer_widens_the_spot_to_spot_part_by_students_t_and_adds_the_fits() {
        // Two spots of a G paper, σ 0.8° and 0.9°, fits without uncertainty: the 95 %
        // interval of ln σ is the mean ± t(0.975, 1) · s/√2, s the spots' sd of ln σ.
        let results = [
            exact(1, "G", [0.8, 57.8, 0.855]),
            exact(2, "G", [0.9, 57.8, 0.855]),
        ];
        let s = assess(2, &results);
        let answer = s.answer.clone().unwrap();
        let logs = [0.8f64.ln(), 0.9f64.ln()];
        let sd = (logs[1] - logs[0]).abs() / 2f64.sqrt();
        let half = 12.706_204_736 * sd / 2f64.sqrt();
        let mean = (logs[0] + logs[1]) / 2.0;
        let [lo, hi] = answer.ci95.sigma_deg.unwrap();
        assert!((lo.ln() - (mean - half)).abs() < 1e-6, "{lo}");
        assert!((hi.ln() - (mean + half)).abs() < 1e-6, "{hi}");
        assert_eq!(answer.class.as_deref(), Some("G"));
        // The σ interval reaches past 1.3°: the confidence in G says so.
        let confidence = answer.class_confidence.unwrap();
        assert!(confidence < 0.99 && confidence > 0.5, "{confidence}");
        // ρs and ρd did not vary and the fits have no uncertainty: zero width.
        assert_eq!(answer.ci95.rho_d, Some([0.855, 0.855]));
        assert!(answer.spots_disagree.is_none() && answer.flags.is_empty());

        // The fits' own covariance, averaged (not divided by n: shared calibration), adds.
        let mut noisy = results.clone();
        for r in &mut noisy {
            r.spot.covariance[2][2] = (0.01f64 * 0.855).powi(2);
        }
        let answer = assess(2, &noisy).answer.unwrap();
        let [lo, hi] = answer.ci95.rho_d.unwrap();
        let half = 1.959_964 * 0.855 * 0.01;
        assert!((hi - lo - 2.0 * half).abs() < 1e-6, "{lo} {hi}");
    }

    #[test]
    fn spots_that_disagree_in_class_are_named_and_flagged() {
        let results = [
            exact(1, "G", [1.2, 57.0, 0.8]),
            exact(2, "SG", [1.4, 57.0, 0.8]),
            exact(3, "G", [1.25, 57.0, 0.8]),
        ];
        let answer = assess(3, &results).answer.unwrap();
        assert_eq!(
            answer.spots_disagree.as_deref(),
            Some("the accepted spots disagree in class: G at spots 1, 3; SG at spot 2")
        );
        assert!(answer.flags.contains(&Flag::SpotsDisagree));
        assert!(Flag::SpotsDisagree.is_informational());
        // Near the 1.3° boundary with the spots on both sides: not a settled class.
        assert!(answer.class_confidence.unwrap() < 0.95, "{answer:?}");
    }

    #[test]
    fn a_sheet_with_a_parameter_not_determined_at_every_spot_has_no_class() {
        let mut results = [
            exact(1, "G", [0.8, 57.8, 0.855]),
            exact(2, "G", [0.8, 57.8, 0.855]),
        ];
        results[1].spot.values[0] = None;
        let answer = assess(2, &results).answer.unwrap();
        assert_eq!(answer.class, None);
        assert!(answer.undecided.unwrap().contains("σ not determined"));
        assert_eq!(answer.ci95.sigma_deg, None);
    }

    #[test]
    fn the_mean_and_spread_are_named_in_the_file_and_arrays_still_read() {
        let s = assess(
            2,
            &[
                exact(1, "G", [0.8, 57.8, 0.855]),
                exact(2, "G", [0.9, 57.8, 0.855]),
            ],
        );
        let v = serde_json::to_value(&s).unwrap();
        assert_eq!(v["mean"]["rho_s"].as_f64(), s.mean[1]);
        assert!(v["within_relative_sd"]["sigma_deg"].as_f64().unwrap() > 0.0);
        let mut old = v.clone();
        old["mean"] = serde_json::json!([s.mean[0], s.mean[1], s.mean[2]]);
        old["within_relative_sd"] = serde_json::json!(s.within_relative_sd);
        old.as_object_mut().unwrap().remove("answer");
        let read: SheetSummary = serde_json::from_value(old).unwrap();
        assert_eq!(
            (read.mean, read.within_relative_sd),
            (s.mean, s.within_relative_sd)
        );
        assert_eq!(read.answer, None);
    }

    #[test]
    fn the_within_sheet_variation_is_unknown_for_one_spot_and_measured_for_more() {
        let one = assess(1, &[result(1, &[], 20.0)]);
        assert_eq!(
            (one.within_relative_sd, one.within_log_covariance),
            (None, None)
        );
        assert!(one.notes.iter().any(|n| n.contains("variation is unknown")));
        let three = assess(
            3,
            &[
                result(1, &[], 20.0),
                result(2, &[], 21.0),
                result(3, &[], 19.0),
            ],
        );
        let sd = three.within_relative_sd.unwrap();
        assert!(sd[0] > 0.04 && sd[0] < 0.06, "{sd:?}");
        assert_eq!(sd[1], 0.0);
    }
}
