//! The session's refinements after its first stage, by the plan's policy: the paper's
//! Strategy 2 with decreasing δ, and the adaptive policy's batches (with, for the mixed
//! policy, sweeps across the peak as candidates). The sweep policy's rounds are in
//! [`super::sweep_policy`]; the designs themselves are [`super::adaptive`]'s and
//! [`crate::analysis::sweep_design`]'s.
use super::adaptive::{self, AdaptiveTargets};
use super::{
    FitStep, Policy, Refinement, Session, SessionError, lack_of_fit_evidence, sigma_l_text,
    sweep_policy,
};
use crate::analysis::fit::Observation;
use crate::analysis::result::{Report, to_json};
use crate::analysis::sweep_design;
use crate::instrument::link::Transport;
use protocol::Geometry;
use protocol::schedules::strategy2;
use std::collections::BTreeSet;

/// How the reason of a batch taken for a lack-of-fit flag begins (a batch taken to test an
/// extended model's terms is recorded as a lack-of-fit batch too, with its own reason).
const LACK_OF_FIT_REASON: &str = "lack-of-fit";

/// Where the adaptive policy stands after a fit.
#[derive(Clone)]
struct Standing {
    /// The fit is flagged lack-of-fit.
    flagged: bool,
    /// σ > σ_l.
    sigma_ok: bool,
    /// The class confidence is at its target.
    settled: bool,
    /// Lack-of-fit batches taken so far.
    taken: usize,
    /// The flag outlived its batches: the model does not describe this sheet, and the
    /// class cannot settle under it (its confidence is capped), so the only target left
    /// is the paper's σ > σ_l.
    confirmed: bool,
    /// The model an unflagged fit was extended to, in words, while batches to test it off
    /// the peak remain (they count as lack-of-fit batches).
    extension: Option<String>,
}

/// What the adaptive policy measures next.
enum Next {
    /// A batch of point readings (`None` or empty: nothing left that would help), why,
    /// and whether it samples for a lack-of-fit flag.
    Batch(Option<Vec<Geometry>>, String, bool),
    /// A round of sweeps: its stage's name, why, the sweeps.
    Sweeps(String, String, Vec<sweep_design::SweepPlan>),
}

/// What a round's design starts from: the usable readings, the geometries measured, where
/// the arms are.
struct Design {
    observations: Vec<Observation>,
    measured: BTreeSet<Geometry>,
    here: Geometry,
}

impl<T: Transport> Session<'_, T> {
    /// Refinements by the plan's policy, from `report`.
    pub(super) fn refine(
        &mut self,
        report: &mut Report,
        fits: &mut Vec<FitStep>,
        refinements: &mut Vec<Refinement>,
    ) -> Result<(), SessionError> {
        let (targets, sweeps) = match self.plan.policy.clone() {
            Policy::Paper => return self.refine_like_the_paper(report, fits, refinements),
            Policy::Sweep(targets) => {
                return self.refine_by_sweeps(targets, report, fits, refinements);
            }
            Policy::Fixed(_) => return Ok(()),
            Policy::Adaptive(targets) => (targets, None),
            Policy::Mixed(targets, sweeps) => (targets, Some(sweeps)),
        };
        self.refine_adaptively(targets, sweeps, report, fits, refinements)?;
        // Never below the paper's criterion: if the batches did not get σ > σ_l, the
        // paper's policy finishes the job.
        self.refine_like_the_paper(report, fits, refinements)
    }

    /// The paper's policy: Strategy 2 with decreasing δ until σ > σ_l, sending only
    /// geometries not measured yet.
    fn refine_like_the_paper(
        &mut self,
        report: &mut Report,
        fits: &mut Vec<FitStep>,
        refinements: &mut Vec<Refinement>,
    ) -> Result<(), SessionError> {
        for delta in (1..=10u8).rev() {
            let check = report.check;
            if check.is_some_and(|c| c.sigma_ok) {
                break;
            }
            let schedule: Vec<Geometry> = strategy2(delta).map(|s| s.to_vec()).unwrap_or_default();
            let measured = self.measured();
            let added = schedule.iter().filter(|g| !measured.contains(g)).count();
            if added == 0 {
                continue;
            }
            let reason = match (report.fit.sigma_deg(), check) {
                (Some(sigma), Some(c)) => format!(
                    "σ = {sigma:.3}° ≤ σ_l = {:.3}° (δ = {:.1}°)",
                    c.sigma_l_deg, c.delta_deg
                ),
                (None, _) => "σ not resolved by the geometries measured".to_string(),
                (Some(sigma), None) => {
                    format!("σ = {sigma:.3}° but no δ: no neighbours of the specular direction")
                }
            };
            self.decide(&format!(
                "refine with Strategy 2 at δ = {delta}° ({added} new geometries): {reason}"
            ));
            refinements.push(Refinement {
                delta_deg: Some(delta),
                added,
                reason,
                lack_of_fit: false,
            });
            self.measure(
                &format!("strategy 2, δ = {delta}° ({added} new geometries)"),
                &schedule,
            )?;
            *report = self.analyse()?;
            fits.push(FitStep {
                after: format!("strategy2 δ={delta}°"),
                report: to_json(report),
            });
        }
        Ok(())
    }

    /// The adaptive policy ([`crate::session::adaptive`]): batches where they shrink σ's
    /// uncertainty most per device second, until the targets are met. Rough papers whose
    /// Strategy 1 already passes σ_l stop at once: their class rests on ρs and ρd, which
    /// Strategy 1 measures, and more readings near the peak would not move it.
    ///
    /// Except when the fit is flagged lack-of-fit: then no paper stops while lack-of-fit
    /// batches remain ([`adaptive::LACK_OF_FIT_BATCHES`], within `max_batches`). Each samples
    /// the tails and the whole θr range, so the flag either goes (a false alarm: the policy
    /// carries on as without it) or stays with more evidence behind it. A flag that outlives
    /// the budget ends the batches and the result keeps it: the class cannot settle under it
    /// (its confidence is capped), so only a σ ≤ σ_l still gets batches, designed over the
    /// whole θr range, until σ > σ_l.
    fn refine_adaptively(
        &mut self,
        targets: AdaptiveTargets,
        sweeps: Option<sweep_policy::SweepTargets>,
        report: &mut Report,
        fits: &mut Vec<FitStep>,
        refinements: &mut Vec<Refinement>,
    ) -> Result<(), SessionError> {
        let adaptive_batches = refinements.iter().filter(|r| r.delta_deg.is_none()).count();
        for batch_number in adaptive_batches + 1..=targets.max_batches {
            // The readings the fit saw: the standing judges σ's spread over θi on them, and
            // the next batch is designed from them.
            let observations: Vec<Observation> = self.usable_points().map(|(_, o)| o).collect();
            let Some(standing) =
                self.adaptive_standing(&targets, report, refinements, &observations)
            else {
                return Ok(());
            };
            let design = Design {
                observations,
                measured: self.measured(),
                here: self.arm_position()?,
            };
            let flagged = standing.flagged;
            let next = self.next_adaptive(&targets, sweeps, standing, &design, report);
            let name = format!("adaptive round {batch_number}");
            let (batch, reason, for_lack_of_fit) = match next {
                Next::Sweeps(stage, reason, plans) => {
                    self.sweep_round(
                        &name,
                        &format!("{name} {stage}"),
                        reason,
                        false,
                        &plans,
                        report,
                        fits,
                        refinements,
                    )?;
                    continue;
                }
                Next::Batch(batch, reason, for_lack_of_fit) => (batch, reason, for_lack_of_fit),
            };
            let Some(batch) = batch.filter(|b| !b.is_empty()) else {
                let flag = if flagged {
                    "; the result keeps the lack-of-fit flag"
                } else {
                    ""
                };
                self.decide(&format!("adaptive: no geometry left that would help; the paper's policy takes over if σ ≤ σ_l{flag}"));
                return Ok(());
            };
            self.decide(&format!(
                "adaptive batch {batch_number} ({} geometries): {reason}",
                batch.len()
            ));
            refinements.push(Refinement {
                delta_deg: None,
                added: batch.len(),
                reason,
                lack_of_fit: for_lack_of_fit,
            });
            self.measure(
                &format!("adaptive batch {batch_number} ({} geometries)", batch.len()),
                &batch,
            )?;
            *report = self.analyse()?;
            fits.push(FitStep {
                after: format!("adaptive batch {batch_number}"),
                report: to_json(report),
            });
        }
        if report.fit.lack_of_fit {
            self.decide(&format!(
                "adaptive: the {} batches are spent and lack-of-fit ({}) remains: the result keeps the flag",
                targets.max_batches,
                lack_of_fit_evidence(&report.fit)
            ));
        }
        Ok(())
    }

    /// Where the adaptive policy stands after the last fit, with its decisions said;
    /// `None` when it is done (the targets met, or a confirmed lack-of-fit with σ > σ_l).
    fn adaptive_standing(
        &mut self,
        targets: &AdaptiveTargets,
        report: &Report,
        refinements: &[Refinement],
        observations: &[Observation],
    ) -> Option<Standing> {
        let flagged = report.fit.lack_of_fit;
        let sigma_ok = report.check.is_some_and(|c| c.sigma_ok);
        let rough = report.classification.group == Some(crate::analysis::classify::Group::Rough);
        let precise = adaptive::sigma_rel_half_width(&report.fit)
            .is_some_and(|w| w <= targets.sigma_rel_half_width)
            && adaptive::sigma_rel_half_width_over_theta_i(&report.fit, observations)
                .is_none_or(|w| w <= targets.sigma_rel_half_width);
        let settled = report.classification.confidence >= targets.class_confidence;
        let taken = refinements.iter().filter(|r| r.lack_of_fit).count();
        let confirmed = flagged && taken >= adaptive::LACK_OF_FIT_BATCHES;
        let extended = super::extended_model(&report.fit);
        let extension = extended
            .clone()
            .filter(|_| !flagged && taken < adaptive::LACK_OF_FIT_BATCHES);
        if confirmed && sigma_ok {
            self.decide(&format!(
                "adaptive: lack-of-fit ({}) persists after {taken} lack-of-fit batches: the model does not describe this sheet; no more batches, the result keeps the flag",
                lack_of_fit_evidence(&report.fit)
            ));
            return None;
        }
        let after_flag = refinements
            .last()
            .is_some_and(|r| r.lack_of_fit && r.reason.starts_with(LACK_OF_FIT_REASON));
        if !flagged && after_flag {
            let why = extended.map_or_else(
                || "a false alarm; the policy goes on as without it".to_string(),
                |model| format!("{model} describes the sheet"),
            );
            self.decide(&format!(
                "adaptive: lack-of-fit gone with the readings of {taken} lack-of-fit batch{} ({}): {why}",
                if taken == 1 { "" } else { "es" },
                lack_of_fit_evidence(&report.fit)
            ));
        }
        if !flagged && extension.is_none() && sigma_ok && (rough || (precise && settled)) {
            return None;
        }
        Some(Standing {
            flagged,
            sigma_ok,
            settled,
            taken,
            confirmed,
            extension,
        })
    }

    /// The adaptive policy's next round: the probe while σ is not resolved (for the mixed
    /// policy, slow sweeps across the peak and back), a lack-of-fit batch while the flag
    /// is not confirmed, else the batch (or, for the mixed policy, the sweeps) that
    /// shrinks σ's uncertainty most per device second.
    fn next_adaptive(
        &self,
        targets: &AdaptiveTargets,
        sweeps: Option<sweep_policy::SweepTargets>,
        standing: Standing,
        design: &Design,
        report: &Report,
    ) -> Next {
        let Standing {
            flagged,
            confirmed,
            taken,
            ref extension,
            ..
        } = standing;
        let Design {
            observations,
            measured,
            here,
        } = design;
        let resolved = adaptive::sigma_resolved(&report.fit);
        // A flag on a fit that has not seen the peak says little about the lobe: the
        // probe comes first, the tails after it if the flag stays.
        let probe = (!resolved)
            .then(|| adaptive::probe(observations, measured))
            .filter(|b| !b.is_empty());
        if let (Some(sweep_targets), Some(_)) = (sweeps, probe.as_ref())
            && let Some(next) = self.probe_sweeps(sweep_targets, design, report)
        {
            return next;
        }
        if let Some(probe) = probe {
            Next::Batch(
                Some(probe),
                "σ not resolved: probe around the strongest specular peak".to_string(),
                false,
            )
        } else if (flagged && !confirmed) || extension.is_some() {
            let batch = adaptive::lack_of_fit_batch(
                &report.fit,
                observations,
                measured,
                *here,
                &self.motion,
                u32::from(self.plan.integration_ms),
                targets.batch,
            );
            let why = match extension {
                Some(model) if !flagged => model.clone(),
                _ => format!(
                    "{LACK_OF_FIT_REASON} ({})",
                    lack_of_fit_evidence(&report.fit)
                ),
            };
            let reason = format!(
                "{why}: sampling the tails and the whole θr range (lack-of-fit batch {} of {})",
                taken + 1,
                adaptive::LACK_OF_FIT_BATCHES
            );
            Next::Batch(Some(batch), reason, true)
        } else if resolved {
            self.best_round(targets, sweeps, standing, design, report)
        } else {
            Next::Batch(None, String::new(), false)
        }
    }

    /// The mixed policy's probe: a slow sweep across the specular direction where
    /// Strategy 1 read the strongest peak, there and back: a lobe narrower than its
    /// spacing is then read at every 0.05° in a second, where the probe's points take
    /// several. `None` when no such sweep fits.
    fn probe_sweeps(
        &self,
        sweep_targets: sweep_policy::SweepTargets,
        design: &Design,
        report: &Report,
    ) -> Option<Next> {
        let max_speed = sweep_targets
            .pass_speed_deg_per_s
            .min(f64::from(self.info.max_speed_deg_per_s));
        let strongest = design
            .observations
            .iter()
            .filter(|o| (o.theta_r_deg - o.theta_i_deg).abs() < 0.5)
            .max_by(|a, b| a.radiance_factor.total_cmp(&b.radiance_factor))
            .map_or(60.0, |o| o.theta_i_deg);
        // There and back: what a sweep's direction does to its bins' angles (the
        // amplifier's lag, the arm's dwell) then cancels in the peak's position
        // rather than leaning on σ.
        let plans: Vec<sweep_design::SweepPlan> = sweep_design::peak_candidates(
            0.25,
            report.fit.acceptance_deg,
            max_speed,
            self.block_s(),
            design.here.theta_r.deg(),
        )
        .into_iter()
        .filter(|p| p.theta_i_deg == strongest && p.speed_deg_per_s == 15.0_f64.min(max_speed))
        .take(1)
        .flat_map(|p| {
            [
                p,
                sweep_design::SweepPlan {
                    from_deg: p.to_deg,
                    to_deg: p.from_deg,
                    ..p
                },
            ]
        })
        .collect();
        (!plans.is_empty()).then(|| {
            let reason = format!(
                "σ not resolved: slow sweeps across the specular direction and back at θi = {strongest}°, where Strategy 1 read the strongest peak"
            );
            Next::Sweeps(
                "(sweeps across the specular direction and back)".to_string(),
                reason,
                plans,
            )
        })
    }

    /// The round for a resolved σ: the batch of point readings that shrinks σ's
    /// uncertainty most per device second or, for the mixed policy (not under a flag), a
    /// round of sweeps across the peak when predicted to shrink σ's variance faster.
    fn best_round(
        &self,
        targets: &AdaptiveTargets,
        sweeps: Option<sweep_policy::SweepTargets>,
        standing: Standing,
        design: &Design,
        report: &Report,
    ) -> Next {
        let Standing {
            flagged,
            sigma_ok,
            settled,
            taken,
            confirmed,
            ..
        } = standing;
        // Under a flag the model's idea of where σ is measured is not to be trusted:
        // the design looks over the whole θr range.
        let span = if flagged {
            adaptive::CandidateSpan::Whole
        } else {
            adaptive::CandidateSpan::Lobe
        };
        // Where σ at the reference θi is all the session waits on (its own interval, the
        // class and σ_l met, no flag), the batch ends once the design predicts that closed.
        let waits_on_sigma_alone = !flagged
            && sigma_ok
            && settled
            && adaptive::sigma_rel_half_width_of_readings(&report.fit)
                .is_some_and(|w| w <= targets.sigma_rel_half_width);
        let scored = adaptive::next_batch_scored(
            &report.fit,
            &design.observations,
            &design.measured,
            design.here,
            &self.motion,
            u32::from(self.plan.integration_ms),
            targets.batch,
            span,
            waits_on_sigma_alone.then_some(targets.sigma_rel_half_width),
        );
        // Sweeps as candidates (the mixed policy): a round of sweeps across the
        // peak, designed as the sweep policy designs them, when it is predicted to
        // shrink σ's variance more per device second than the batch. Not under a
        // flag: there the batches look over the whole θr range, which a sweep
        // across the peak does not.
        if let Some(sweep_targets) = sweeps.filter(|_| !flagged) {
            let batch_rate = scored
                .as_ref()
                .map_or(0.0, |b| per_second(b.sigma_variance_drop, b.seconds));
            if let Some(next) =
                self.peak_sweeps_round(targets, sweep_targets, sigma_ok, batch_rate, design, report)
            {
                return next;
            }
        }
        let batch = scored.map(|b| b.geometries);
        let width = adaptive::sigma_rel_half_width(&report.fit).unwrap_or(f64::INFINITY);
        let mut reason = format!(
            "σ = {:.3}° ± {:.1} % (95 %), class {} at {:.2}{}",
            report.fit.sigma_deg().unwrap_or(f64::NAN),
            100.0 * width,
            report.classification.class_name(),
            report.classification.confidence,
            if sigma_ok {
                String::new()
            } else {
                sigma_l_text(report)
            }
        );
        if confirmed {
            reason.push_str(&format!(
                "; lack-of-fit ({}) persists after {taken} lack-of-fit batches: the result keeps the flag, the batches go on over the whole θr range only until σ > σ_l",
                lack_of_fit_evidence(&report.fit)
            ));
        }
        Next::Batch(batch, reason, false)
    }

    /// The mixed policy's sweeps across the peak, designed as the sweep policy designs
    /// them, when they beat `batch_rate` (σ's variance shrunk per device second by the
    /// best batch) or σ ≤ σ_l.
    fn peak_sweeps_round(
        &self,
        targets: &AdaptiveTargets,
        sweep_targets: sweep_policy::SweepTargets,
        sigma_ok: bool,
        batch_rate: f64,
        design: &Design,
        report: &Report,
    ) -> Option<Next> {
        let max_speed = sweep_targets
            .pass_speed_deg_per_s
            .min(f64::from(self.info.max_speed_deg_per_s));
        let per_block = self.per_block_variance();
        // σ ≤ σ_l is a matter of spacing, which any sweep across the peak settles
        // (its bins are 0.1° apart or closer): the best single sweep then, else
        // the sweep policy's round against the batch.
        let (target, most) = if sigma_ok {
            (targets.sigma_rel_half_width, sweep_targets.sweeps_per_round)
        } else {
            (0.0, 1)
        };
        let peak = sweep_design::design_peak_sweeps(
            &report.fit,
            &design.observations,
            design.here,
            &self.motion,
            max_speed,
            self.block_s(),
            &per_block,
            target,
            most,
        );
        let sweep_rate = per_second(peak.sigma_variance_drop, peak.seconds);
        let faster = !peak.plans.is_empty() && (!sigma_ok || sweep_rate > batch_rate);
        if !faster {
            return None;
        }
        let width = adaptive::sigma_rel_half_width(&report.fit).unwrap_or(f64::INFINITY);
        let reason = format!(
            "σ = {:.3}° ± {:.1} % (95 %), class {} at {:.2}{}: {} across the peak predicted to bring it to ± {:.1} % in {:.1} device s, {:.1}× the information per second of the best batch of point readings",
            report.fit.sigma_deg().unwrap_or(f64::NAN),
            100.0 * width,
            report.classification.class_name(),
            report.classification.confidence,
            if sigma_ok {
                String::new()
            } else {
                sigma_l_text(report)
            },
            sweep_policy::sweeps_text(peak.plans.len()),
            100.0 * peak.predicted_rel_half_width,
            peak.seconds,
            if batch_rate > 0.0 {
                sweep_rate / batch_rate
            } else {
                f64::INFINITY
            }
        );
        let stage = format!(
            "({} across the peak)",
            sweep_policy::sweeps_text(peak.plans.len())
        );
        Some(Next::Sweeps(stage, reason, peak.plans))
    }
}

/// Drop of a variance per device second (0 for no time).
fn per_second(drop: f64, seconds: f64) -> f64 {
    if seconds > 0.0 { drop / seconds } else { 0.0 }
}
