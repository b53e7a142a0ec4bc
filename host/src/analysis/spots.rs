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

use crate::analysis::evidence::{Sheet, Spot};
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
    /// σ (degrees), ρs, ρd and their covariance.
    pub spot: Spot,
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
    /// spots vary relatively); `None` where a spot did not determine it.
    pub mean: [Option<f64>; 3],
    /// The spots' relative standard deviation of σ, ρs, ρd about that mean (from the
    /// accepted spots' logs); `None` with fewer than two spots: unknown, not zero.
    pub within_relative_sd: Option<[f64; 3]>,
    /// The within-sheet covariance of (ln σ, ln ρs, ln ρd) over the accepted spots;
    /// `None` with fewer than two.
    pub(crate) within_log_covariance: Option<[[f64; 3]; 3]>,
    /// The sheet's flags: the informational flags of every spot, and, when no spot was
    /// clean, every spot's flags.
    pub flags: Vec<Flag>,
    /// What a reader must know about the result, in words (empty when nothing).
    pub notes: Vec<String>,
}

impl SheetSummary {
    /// No flag but the informational ones.
    pub fn ok(&self) -> bool {
        flags::ok(&self.flags)
    }

    /// The accepted spots of `results`, as the evidence weighs the sheet.
    pub fn sheet(&self, results: &[SpotResult]) -> Sheet {
        let accepted = |n: u16| {
            self.verdicts
                .iter()
                .any(|j| j.number == n && j.verdict == SpotVerdict::Accepted)
        };
        Sheet {
            spots: results
                .iter()
                .filter(|r| accepted(r.number))
                .map(|r| r.spot.clone())
                .collect(),
        }
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
    SheetSummary {
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
