//! A multi-spot session: one sheet measured at several spots, one [`super::Session`] per
//! spot on one connection. The first spot takes the calibration (homing, dark, white);
//! every later spot reuses it and starts by asking the operator to move the sheet
//! ([`super::Placement::NextSpot`]), so the spots share the calibration's errors as they
//! share its time. Which spots count, and when to measure one more in place of a flagged
//! one, is [`crate::analysis::spots`]'s.
use crate::analysis::spots::{self, SheetSummary, SpotResult};

/// How a sheet is measured.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct SheetPlan {
    /// Clean spots wanted.
    pub spots: u16,
    /// More spots measured, at most, in place of flagged ones.
    pub(crate) replacements: u16,
}

impl SheetPlan {
    /// `spots` clean spots, with [`spots::MAX_REPLACEMENTS`] replacements.
    pub fn new(spots: u16) -> SheetPlan {
        SheetPlan {
            spots,
            replacements: spots::MAX_REPLACEMENTS,
        }
    }
}

/// Measure the spots a sheet still needs after `done` (spots measured before, e.g. by an
/// interrupted run), calling `measure_spot(number, of)` for each (`of`: the spots the sheet
/// will have if no more are flagged) and `decide` with every decision in words. Returns
/// every spot's result and the sheet's; the first error of `measure_spot` ends it.
pub(crate) fn measure_sheet<E>(
    plan: SheetPlan,
    mut done: Vec<SpotResult>,
    mut measure_spot: impl FnMut(u16, u16) -> Result<SpotResult, E>,
    mut decide: impl FnMut(&str),
) -> Result<(Vec<SpotResult>, SheetSummary), E> {
    while let Some(number) = spots::next_spot(plan.spots, plan.replacements, &done) {
        let clean_so_far = done
            .iter()
            .filter(|r| crate::analysis::flags::ok(&r.flags))
            .count() as u16;
        let of = number + plan.spots.saturating_sub(clean_so_far + 1);
        if number > plan.spots {
            decide(&format!(
                "measuring spot {number} in place of a flagged spot ({} of {} replacements)",
                number - plan.spots,
                plan.replacements
            ));
        }
        let result = measure_spot(number, of)?;
        let flagged: Vec<&str> = result
            .flags
            .iter()
            .filter(|f| !f.is_informational())
            .map(|f| f.name())
            .collect();
        if flagged.is_empty() {
            decide(&format!("spot {number}: clean"));
        } else {
            decide(&format!("spot {number}: flagged {}", flagged.join(", ")));
        }
        done.push(result);
    }
    let summary = spots::assess(plan.spots, &done);
    for judged in &summary.verdicts {
        if let spots::SpotVerdict::Excluded { reason } = &judged.verdict {
            decide(&format!("spot {} excluded: {reason}", judged.number));
        }
    }
    for note in &summary.notes {
        decide(note);
    }
    Ok((done, summary))
}
