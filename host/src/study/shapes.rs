//! Sheets that are not TSL (issue 28): single-spot sessions on simulated sheets that depart
//! from the paper's model in the ways real paper does, each departure at two strengths on
//! the eight papers of Table 6, under the sweep and adaptive policies, on the ideal
//! instrument, with the exact-TSL sheets of the same papers, seeds and policies as the
//! control.
//!
//! The departures are the simulator's own physics ([`hil_sim::sheet::Departures`]): a
//! haze lobe, an off-specular peak shift, GGX, Cauchy, Beckmann and Blinn–Phong lobes
//! (alone and half-blended with the Gaussian), a lobe wider on one side, a Fresnel-flat
//! lobe, σ varying with θi, an Oren–Nayar body, a body rising toward grazing and a
//! retro-reflection surge. Each session is set up through the same `--lobe`,
//! `--lobe-weight` and `--departure` options `gonio measure --sim` takes (the CSV names
//! them, so any row can be run again by hand).
//!
//! **The truth** of every sheet is its [`hil_sim::sheet::SheetSpec::equivalent_truth`]:
//! σ_eq the σ of the Gaussian with the main lobe's half-maximum width (at θi = 45° where σ
//! varies with θi), ρs the main lobe's, ρd the body's radiance factor at 45°/0°; every
//! departure is parametrised so that these are the paper's Table 6 values. The class to
//! expect is the paper's.
//!
//! **What is counted**, per departure, strength and policy: the class right; flagged and
//! wrong (a wrong class or none, with a flag that is not informational: the result says it
//! is not clean); undecided; an unflagged miss (σ outside its own 95 % interval, no flag
//! but the informational ones, class confidence ≥ 0.95: a confident wrong number); σ's
//! interval covering σ_eq (an interval not reported counts as a miss); an extension of
//! the model selected (the informational `model-extended` flag); device time against the
//! exact-TSL control of the same papers and, on exact TSL, against today's
//! ([`TODAY_DEVICE_S`]).
//!
//! **The targets** (issue 28): on sheets that are not TSL, the class right in ≥ 90 % of
//! sessions, flagged-and-wrong ≤ 2 %, σ covered in 90–98 %, no unflagged miss; on exact
//! TSL, an extension selected in ≤ 2 %, σ covered in 90–98 %, device time within 10 % of
//! today's.
//!
//! Every session's seed comes from its paper, policy and index alone: a departure's
//! session and its control share the instrument's noise, and a campaign repeats exactly.

use super::accuracy::{CONFIDENT, COVERAGE_TARGET, wilson95};
use crate::analysis::classify::{Class, REFERENCES};
use crate::analysis::fit::MemberSigma;
use crate::analysis::flags::Flag;
use crate::analysis::model::{ETA, RHO_D, RHO_S, SIGMA};
use crate::instrument::calibration::{DEFAULT_WHITE_RADIANCE_FACTOR, Tile};
use crate::instrument::sim::{IDEAL_PHYSICS, LobeChoice, SimOptions, sample_params};
use crate::session::{Outcome, Policy, PolicyChoice};
use hil_sim::sheet::Stock;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;
use std::fmt::Write as _;

/// The eight papers of Table 6, in its order.
pub const PAPERS: [&str; 8] = super::instruments::PAPERS;

/// The policies the campaign runs unless told otherwise.
pub const DEFAULT_POLICIES: [PolicyChoice; 2] = [PolicyChoice::Sweep, PolicyChoice::Adaptive];

/// Share of sessions on sheets that are not TSL whose class must be right.
pub const CLASS_RIGHT_TARGET: f64 = 0.90;
/// Largest share of such sessions flagged with a wrong class or none.
pub const FLAGGED_WRONG_LIMIT: f64 = 0.02;
/// Largest share of exact-TSL sessions with an extension selected.
pub const EXTENSION_ON_TSL_LIMIT: f64 = 0.02;
/// Largest ratio of the exact-TSL device time to today's.
pub const DEVICE_TIME_LIMIT: f64 = 1.10;

/// Today's mean device seconds on the exact-TSL sheets, (paper, policy, seconds): the
/// campaign's control before the fit's extensions (commit 1b82660, `gonio accuracy
/// --shapes 20 --departures tsl`, ideal physics: the same seeds as every campaign's
/// first 20). The target is to stay within 10 % of these.
pub const TODAY_DEVICE_S: [(&str, PolicyChoice, f64); 16] = [
    ("G", PolicyChoice::Sweep, 7.794),
    ("G", PolicyChoice::Adaptive, 17.333),
    ("SG", PolicyChoice::Sweep, 6.515),
    ("SG", PolicyChoice::Adaptive, 16.829),
    ("PPC", PolicyChoice::Sweep, 4.950),
    ("PPC", PolicyChoice::Adaptive, 9.405),
    ("MC", PolicyChoice::Sweep, 5.163),
    ("MC", PolicyChoice::Adaptive, 9.405),
    ("J1", PolicyChoice::Sweep, 6.486),
    ("J1", PolicyChoice::Adaptive, 9.405),
    ("J2", PolicyChoice::Sweep, 6.482),
    ("J2", PolicyChoice::Adaptive, 9.405),
    ("J3", PolicyChoice::Sweep, 4.950),
    ("J3", PolicyChoice::Adaptive, 9.405),
    ("J4", PolicyChoice::Sweep, 4.950),
    ("J4", PolicyChoice::Adaptive, 9.405),
];

/// A gross miss: σ_eq farther from the estimate than this many times the 95 % interval's
/// half-width (about 3.9 standard errors: an honest interval's own noise does it about once
/// in 10,000 sessions, a model-form bias the interval does not carry does it often).
pub const GROSS_MISS_HALF_WIDTHS: f64 = 2.0;

/// A departure from TSL (the simulator's forms, `hil-sim/src/sheet.rs`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A second, broad Gaussian lobe: fraction of the main peak, σh = 5σ (at most 90°).
    Haze,
    /// The lobe centred at θr = θi + δ, δ a fraction of its FWHM in θr.
    PeakShift,
    /// Another facet distribution of the Gaussian's half-maximum width, half-blended
    /// with the Gaussian (mild) or alone (strong).
    Lobe(LobeChoice),
    /// σ past the peak over σ before it.
    Asymmetry,
    /// The Fresnel factor flattened toward F(45°).
    FresnelFlat,
    /// σ(θi) = σ·(1 + k·(θi − 45°)/45°), narrowing toward grazing.
    SigmaSlope,
    /// An Oren–Nayar body of this roughness.
    OrenNayar,
    /// The body blended with Lommel–Seeliger's.
    Grazing,
    /// The body's surge toward retro-reflection.
    Retro,
}

/// Every departure, in the summary's order.
pub const KINDS: [Kind; 12] = [
    Kind::Haze,
    Kind::PeakShift,
    Kind::Lobe(LobeChoice::Ggx),
    Kind::Lobe(LobeChoice::Cauchy),
    Kind::Lobe(LobeChoice::Beckmann),
    Kind::Lobe(LobeChoice::BlinnPhong),
    Kind::Asymmetry,
    Kind::FresnelFlat,
    Kind::SigmaSlope,
    Kind::OrenNayar,
    Kind::Grazing,
    Kind::Retro,
];

impl Kind {
    /// Its name in the CSV, the summary and `--departures`.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Haze => "haze",
            Kind::PeakShift => "peak-shift",
            Kind::Lobe(lobe) => lobe.name(),
            Kind::Asymmetry => "asymmetry",
            Kind::FresnelFlat => "fresnel-flat",
            Kind::SigmaSlope => "sigma-slope",
            Kind::OrenNayar => "oren-nayar",
            Kind::Grazing => "grazing",
            Kind::Retro => "retro",
        }
    }

    /// The departure named `name` (as [`Kind::name`] spells it).
    pub fn named(name: &str) -> Option<Kind> {
        KINDS
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(name))
    }
}

/// How far a sheet departs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Strength {
    /// A trace a careful look finds.
    Mild,
    /// As marked as real paper shows it (the issue's own examples where it has them).
    Strong,
}

/// A sheet's shape: exact TSL, or one departure at a strength.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// The paper's TSL sheet: the control.
    Tsl,
    /// One departure.
    Departure(Kind, Strength),
}

/// Rounded to 0.01 (a δ or σh written on a command line).
fn centi(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

impl Shape {
    /// Every shape of `kinds`, mild then strong, after the control.
    pub fn all(kinds: &[Kind]) -> Vec<Shape> {
        let mut out = vec![Shape::Tsl];
        for &kind in kinds {
            for strength in [Strength::Mild, Strength::Strong] {
                out.push(Shape::Departure(kind, strength));
            }
        }
        out
    }

    /// Its name in the CSV and the summary: `tsl`, `haze mild`, ….
    pub fn name(self) -> String {
        match self {
            Shape::Tsl => "tsl".into(),
            Shape::Departure(kind, Strength::Mild) => format!("{} mild", kind.name()),
            Shape::Departure(kind, Strength::Strong) => format!("{} strong", kind.name()),
        }
    }

    /// Whether it is a departure from TSL.
    pub fn departs(self) -> bool {
        self != Shape::Tsl
    }

    /// The sheet options that make it on paper `sigma_deg`: the lobe, its weight and the
    /// `--departure` item.
    pub fn sheet_options(self, sigma_deg: f64) -> (LobeChoice, f64, Option<String>) {
        let Shape::Departure(kind, strength) = self else {
            return (LobeChoice::Gaussian, 1.0, None);
        };
        let strong = strength == Strength::Strong;
        let pick = |mild: f64, strong_value: f64| if strong { strong_value } else { mild };
        let fwhm_theta_r_deg = 4.0 * (2.0 * std::f64::consts::LN_2).sqrt() * sigma_deg;
        let item = match kind {
            Kind::Lobe(lobe) => return (lobe, pick(0.5, 1.0), None),
            // The G: 3 % of the peak at σ 4° (= 5σ).
            Kind::Haze => format!(
                "haze:{}:{}",
                pick(0.01, 0.03),
                centi((5.0 * sigma_deg).min(90.0))
            ),
            Kind::PeakShift => format!("peak-shift:{}", centi(pick(0.05, 0.15) * fwhm_theta_r_deg)),
            Kind::Asymmetry => format!("asymmetry:{}", pick(1.3, 2.0)),
            Kind::FresnelFlat => format!("fresnel-flat:{}", pick(0.5, 1.0)),
            // The SG: 2.3° at θi = 20° to 1.6° at 60°, k ≈ −0.4.
            Kind::SigmaSlope => format!("sigma-slope:{}", pick(-0.15, -0.4)),
            Kind::OrenNayar => format!("oren-nayar:{}", pick(15.0, 30.0)),
            Kind::Grazing => format!("grazing:{}", pick(0.3, 1.0)),
            Kind::Retro => format!("retro:{}:15", pick(0.3, 1.0)),
        };
        (LobeChoice::Gaussian, 1.0, Some(item))
    }

    /// The simulator's options of this shape on `paper` with `seed`, ideal physics.
    pub fn sim_options(self, paper: &str, seed: u64) -> SimOptions {
        let sigma_deg = sample_params(paper).map_or(1.0, |p| p.sigma_deg);
        let (lobe, lobe_weight, departure) = self.sheet_options(sigma_deg);
        SimOptions {
            seed,
            lobe,
            lobe_weight,
            departure: departure.into_iter().collect(),
            ..SimOptions::default()
        }
    }

    /// The options as `gonio measure --sim` takes them (empty for the control).
    pub fn command_line(self, paper: &str) -> String {
        let sigma_deg = sample_params(paper).map_or(1.0, |p| p.sigma_deg);
        let (lobe, weight, departure) = self.sheet_options(sigma_deg);
        let mut words = Vec::new();
        if lobe != LobeChoice::Gaussian {
            words.push(format!("--lobe {}", lobe.name()));
        }
        if weight != 1.0 {
            words.push(format!("--lobe-weight {weight}"));
        }
        if let Some(item) = departure {
            words.push(format!("--departure {item}"));
        }
        words.join(" ")
    }
}

/// What a campaign runs.
#[derive(Clone, Debug, PartialEq)]
pub struct Design {
    /// The shapes (the control first).
    pub shapes: Vec<Shape>,
    /// The papers.
    pub papers: Vec<&'static str>,
    /// The policies.
    pub policies: Vec<PolicyChoice>,
    /// Sessions per shape, paper and policy (each its own seed).
    pub seeds: usize,
    /// The index of the first of them: a campaign from index k draws seeds no campaign
    /// from 0 with k sessions did (a figure measured on seeds a change was not tuned on).
    pub first_index: usize,
}

/// One session of the campaign.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionSpec {
    /// The sheet's shape.
    pub shape: Shape,
    /// The paper.
    pub paper: &'static str,
    /// The refinement policy.
    pub policy: PolicyChoice,
    /// The session's number within its shape, paper and policy.
    pub index: usize,
    /// The simulator's seed (the paper's, policy's and index's alone).
    pub seed: u64,
}

/// A shape a paper cannot take (its sheet is refused), with why.
#[derive(Clone, Debug, PartialEq)]
pub struct NotApplicable {
    /// The shape.
    pub shape: Shape,
    /// The paper.
    pub paper: &'static str,
    /// The simulator's refusal.
    pub why: String,
}

fn policy_stream(policy: PolicyChoice) -> u64 {
    match policy {
        PolicyChoice::Adaptive => 0,
        PolicyChoice::Paper => 1,
        PolicyChoice::Sweep => 2,
        PolicyChoice::Mixed => 3,
    }
}

impl Design {
    /// Every departure at both strengths and the control, on the eight papers, `seeds`
    /// sessions each under `policies`.
    pub fn new(seeds: usize, policies: &[PolicyChoice]) -> Design {
        Design {
            shapes: Shape::all(&KINDS),
            papers: PAPERS.to_vec(),
            policies: policies.to_vec(),
            seeds,
            first_index: 0,
        }
    }

    /// The seed of session `index` of `paper` under `policy`: the same for every shape, so
    /// that a departure and its control differ by the sheet alone.
    pub fn seed(paper: &str, policy: PolicyChoice, index: usize) -> u64 {
        let paper_index = PAPERS
            .iter()
            .position(|p| *p == paper)
            .unwrap_or(PAPERS.len());
        let stream = (paper_index as u64) << 40 | policy_stream(policy) << 32 | index as u64;
        ChaCha12Rng::seed_from_u64(0x5a4e_2028 ^ stream.wrapping_mul(0x9e37_79b9_7f4a_7c15))
            .random_range(1..1_000_000_000u64)
    }

    /// Every session, and the shapes a paper cannot take.
    pub fn sessions(&self) -> (Vec<SessionSpec>, Vec<NotApplicable>) {
        let (mut specs, mut refused) = (Vec::new(), Vec::new());
        for &shape in &self.shapes {
            for &paper in &self.papers {
                if let Err(e) = shape.sim_options(paper, 1).sheet(paper) {
                    refused.push(NotApplicable {
                        shape,
                        paper,
                        why: e.to_string(),
                    });
                    continue;
                }
                for &policy in &self.policies {
                    for index in self.first_index..self.first_index + self.seeds {
                        specs.push(SessionSpec {
                            shape,
                            paper,
                            policy,
                            index,
                            seed: Design::seed(paper, policy, index),
                        });
                    }
                }
            }
        }
        (specs, refused)
    }
}

/// What one session gave, against the sheet's equivalent truth.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// What was run.
    pub spec: SessionSpec,
    /// Why it did not finish (`None`: it did).
    pub failure: Option<String>,
    /// The truth: σ_eq, ρs and ρd of the main lobe and body, η nominal.
    pub truth: Option<Stock>,
    /// The class found (`None`: undecided).
    pub class: Option<Class>,
    /// Its confidence.
    pub confidence: f64,
    /// The result's flags.
    pub flags: Vec<Flag>,
    /// Estimates of σ (degrees), ρs, ρd and η; `None` where not determined.
    pub estimates: [Option<f64>; 4],
    /// σ's 95 % interval, degrees.
    pub sigma_ci95: Option<(f64, f64)>,
    /// Whether the 95 % intervals of σ, ρs, ρd cover the truth; `None` where none was
    /// reported.
    pub covered: [Option<bool>; 3],
    /// The goodness-of-fit p-value.
    pub gof_p: Option<f64>,
    /// The arm offset the fit accepted, degrees.
    pub arm_offset_deg: Option<f64>,
    /// Geometries the result rests on.
    pub geometries: usize,
    /// Device seconds measuring the sample.
    pub device_seconds: f64,
    /// Every member of the family the final fit fitted, with σ's own interval (none with
    /// the paper's model alone).
    pub members: Vec<MemberSigma>,
}

impl Row {
    /// The paper's class.
    pub fn expected_class(&self) -> Option<Class> {
        REFERENCES
            .iter()
            .find(|r| r.name == self.spec.paper)
            .map(|r| r.class)
    }

    /// The class found is the paper's.
    pub fn class_right(&self) -> bool {
        self.failure.is_none() && self.class.is_some() && self.class == self.expected_class()
    }

    /// Some flag that is not informational: the result says it is not clean.
    pub fn flagged(&self) -> bool {
        self.flags.iter().any(|f| !f.is_informational())
    }

    /// A wrong class or none, said by a flag that is not informational.
    pub fn flagged_and_wrong(&self) -> bool {
        self.failure.is_none() && !self.class_right() && self.flagged()
    }

    /// σ outside its own 95 % interval, no flag but the informational ones, and a class
    /// confidence ≥ [`CONFIDENT`]: a confident wrong number.
    pub fn unflagged_miss(&self) -> bool {
        self.failure.is_none()
            && self.covered[0] == Some(false)
            && !self.flagged()
            && self.confidence >= CONFIDENT
    }

    /// An unflagged miss by more than [`GROSS_MISS_HALF_WIDTHS`] half-widths of σ's
    /// interval: not the few percent an honest 95 % interval misses, a bias it does not
    /// carry.
    pub fn gross_unflagged_miss(&self) -> bool {
        let (Some(sigma), Some((lo, hi)), Some(truth)) =
            (self.estimates[0], self.sigma_ci95, self.truth)
        else {
            return false;
        };
        self.unflagged_miss()
            && (truth.sigma_deg - sigma).abs() > GROSS_MISS_HALF_WIDTHS * 0.5 * (hi - lo)
    }

    /// A wrong class at confidence ≥ [`CONFIDENT`] with no flag but the informational ones.
    pub fn confidently_wrong(&self) -> bool {
        self.failure.is_none()
            && self.class.is_some()
            && !self.class_right()
            && self.confidence >= CONFIDENT
            && !self.flagged()
    }

    /// The fit extended the model (the informational `model-extended` flag).
    pub fn extended(&self) -> bool {
        self.flags.contains(&Flag::ModelExtended)
    }
}

/// Run one session as `gonio measure --sim` would, in process (the ideal instrument, its
/// tile and arm zero stated exact).
pub fn run_one(spec: &SessionSpec) -> Row {
    let mut row = Row {
        spec: spec.clone(),
        failure: None,
        truth: None,
        class: None,
        confidence: 0.0,
        flags: Vec::new(),
        estimates: [None; 4],
        sigma_ci95: None,
        covered: [None; 3],
        gof_p: None,
        arm_offset_deg: None,
        geometries: 0,
        device_seconds: 0.0,
        members: Vec::new(),
    };
    let options = spec.shape.sim_options(spec.paper, spec.seed);
    let truth = match options.sheet(spec.paper) {
        Ok(sheet) => sheet.equivalent_truth(),
        Err(e) => {
            row.failure = Some(e.to_string());
            return row;
        }
    };
    row.truth = Some(truth);
    let tile = match Tile::new(DEFAULT_WHITE_RADIANCE_FACTOR, IDEAL_PHYSICS.tile_error_pct) {
        Ok(tile) => tile,
        Err(e) => {
            row.failure = Some(e.to_string());
            return row;
        }
    };
    let run = super::SimulatedRun {
        sample: spec.paper,
        options: &options,
        policy: Policy::from(spec.policy),
        integration_ms: None,
    };
    match super::simulated_session(&run, |session| {
        session
            .with_tile(tile)
            .with_arm_zero_uncertainty(IDEAL_PHYSICS.arm_zero_sd_deg)
    }) {
        Ok((outcome, _)) => judge(&mut row, &outcome, &truth),
        Err(e) => row.failure = Some(e.to_string()),
    }
    row
}

fn judge(row: &mut Row, outcome: &Outcome, truth: &Stock) {
    let report = &outcome.report;
    let fit = &report.fit;
    row.class = report.classification.class;
    row.confidence = report.classification.confidence;
    row.flags = outcome.flags.clone();
    let targets = [
        (SIGMA, truth.sigma_deg),
        (RHO_S, truth.rho_s),
        (RHO_D, truth.rho_d),
    ];
    for (k, (index, value)) in targets.into_iter().enumerate() {
        row.estimates[k] = fit.reported(index);
        row.covered[k] = fit.ci95[index].map(|(lo, hi)| lo <= value && value <= hi);
    }
    row.estimates[3] = fit.reported(ETA);
    row.sigma_ci95 = fit.ci95[SIGMA];
    row.gof_p = fit.gof_p;
    row.arm_offset_deg = fit.arm_offset.as_ref().map(|a| a.deg);
    row.geometries = outcome.current_points().count();
    row.device_seconds = outcome.device_seconds;
    row.members = fit
        .extension
        .as_ref()
        .map(|e| e.members.clone())
        .unwrap_or_default();
}

/// A campaign's results.
#[derive(Clone, Debug)]
pub struct Campaign {
    /// What was run.
    pub design: Design,
    /// One row per session, in the order of [`Design::sessions`].
    pub rows: Vec<Row>,
    /// The shapes a paper could not take.
    pub not_applicable: Vec<NotApplicable>,
}

/// Why a campaign could not be completed.
#[derive(Debug, thiserror::Error)]
#[error("{missing} of {of} sessions did not run (a worker panicked)")]
pub struct CampaignError {
    /// How many are missing.
    pub missing: usize,
    /// Of how many.
    pub of: usize,
}

/// Sessions [`run`] runs for `design` (a progress bar's length).
pub fn work(design: &Design) -> usize {
    design.sessions().0.len()
}

/// Run `design` on `threads` threads; `progress` after each session.
pub fn run(
    design: &Design,
    threads: usize,
    progress: &(dyn Fn() + Sync),
) -> Result<Campaign, CampaignError> {
    let (specs, not_applicable) = design.sessions();
    let rows = super::parallel(&specs, threads, progress, run_one);
    if rows.len() != specs.len() {
        return Err(CampaignError {
            missing: specs.len() - rows.len(),
            of: specs.len(),
        });
    }
    Ok(Campaign {
        design: design.clone(),
        rows,
        not_applicable,
    })
}

/// Counts over a set of sessions.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tally {
    /// Sessions run.
    pub sessions: usize,
    /// Sessions that did not finish.
    pub failed: usize,
    /// The paper's class.
    pub class_right: usize,
    /// A wrong class or none, flagged.
    pub flagged_wrong: usize,
    /// … of them a wrong class given (the rest: no class, the honest answer to a flag).
    pub flagged_wrong_class: usize,
    /// No class.
    pub undecided: usize,
    /// σ outside its interval, unflagged, confidence ≥ 0.95.
    pub unflagged_miss: usize,
    /// … by more than [`GROSS_MISS_HALF_WIDTHS`] half-widths of the interval.
    pub gross_unflagged_miss: usize,
    /// A wrong class, unflagged, confidence ≥ 0.95.
    pub confidently_wrong: usize,
    /// σ's interval covers σ_eq.
    pub sigma_covered: usize,
    /// σ reported no interval.
    pub sigma_undetermined: usize,
    /// ρs's and ρd's intervals cover the truth.
    pub rho_covered: [usize; 2],
    /// An extension of the model selected.
    pub extended: usize,
    /// Any flag that is not informational.
    pub flagged: usize,
    /// `lack-of-fit`.
    pub lack_of_fit: usize,
    /// Total device seconds and geometries of the finished sessions.
    pub device_seconds: f64,
    /// Total geometries of the finished sessions.
    pub geometries: usize,
}

impl Tally {
    /// Count `rows`.
    pub fn of<'a>(rows: impl IntoIterator<Item = &'a Row>) -> Tally {
        let mut t = Tally::default();
        for r in rows {
            t.sessions += 1;
            if r.failure.is_some() {
                t.failed += 1;
                continue;
            }
            t.class_right += usize::from(r.class_right());
            t.flagged_wrong += usize::from(r.flagged_and_wrong());
            t.flagged_wrong_class += usize::from(r.flagged_and_wrong() && r.class.is_some());
            t.undecided += usize::from(r.class.is_none());
            t.unflagged_miss += usize::from(r.unflagged_miss());
            t.gross_unflagged_miss += usize::from(r.gross_unflagged_miss());
            t.confidently_wrong += usize::from(r.confidently_wrong());
            t.sigma_covered += usize::from(r.covered[0] == Some(true));
            t.sigma_undetermined += usize::from(r.covered[0].is_none());
            t.rho_covered[0] += usize::from(r.covered[1] == Some(true));
            t.rho_covered[1] += usize::from(r.covered[2] == Some(true));
            t.extended += usize::from(r.extended());
            t.flagged += usize::from(r.flagged());
            t.lack_of_fit += usize::from(r.flags.contains(&Flag::LackOfFit));
            t.device_seconds += r.device_seconds;
            t.geometries += r.geometries;
        }
        t
    }

    /// Sessions that finished.
    pub fn finished(&self) -> usize {
        self.sessions - self.failed
    }

    /// `count` as a share of the finished sessions.
    pub fn share(&self, count: usize) -> f64 {
        count as f64 / self.finished().max(1) as f64
    }

    /// Mean device seconds of the finished sessions.
    pub fn mean_device_seconds(&self) -> f64 {
        self.device_seconds / self.finished().max(1) as f64
    }
}

/// The rows of `shape` (`None`: every departure) under `policy` (`None`: every policy).
fn rows_of(
    campaign: &Campaign,
    shape: Option<Shape>,
    policy: Option<PolicyChoice>,
) -> impl Iterator<Item = &Row> {
    campaign.rows.iter().filter(move |r| {
        shape.map_or(r.spec.shape.departs(), |s| r.spec.shape == s)
            && policy.is_none_or(|p| r.spec.policy == p)
    })
}

/// Today's mean exact-TSL device seconds of `paper` under `policy`, if recorded.
pub fn today_device_seconds(paper: &str, policy: PolicyChoice) -> Option<f64> {
    TODAY_DEVICE_S
        .iter()
        .find(|(p, q, _)| *p == paper && *q == policy)
        .map(|(_, _, s)| *s)
}

/// The exact-TSL sessions' device time under `policy` over today's for the same papers
/// (equal weight per session), with the sessions compared; `None` when today's has none.
pub fn device_time_ratio(campaign: &Campaign, policy: PolicyChoice) -> Option<(f64, usize)> {
    let (mut now, mut today, mut n) = (0.0, 0.0, 0);
    for r in rows_of(campaign, Some(Shape::Tsl), Some(policy)).filter(|r| r.failure.is_none()) {
        if let Some(s) = today_device_seconds(r.spec.paper, policy) {
            now += r.device_seconds;
            today += s;
            n += 1;
        }
    }
    (n > 0 && today > 0.0).then(|| (now / today, n))
}

/// A coverage claim: the count is consistent with 90–98 % (its 95 % Wilson interval meets
/// the target; a campaign of a few seeds cannot show more), with the words saying it.
fn coverage_claim(covered: usize, n: usize) -> (String, bool) {
    let (lo, hi) = wilson95(covered, n);
    (
        format!(
            "{} (95 % CI {:.1}–{:.1} %; target 90–98 %)",
            pct(covered, n),
            100.0 * lo,
            100.0 * hi
        ),
        n > 0 && hi >= COVERAGE_TARGET.0 && lo <= COVERAGE_TARGET.1,
    )
}

fn pct(k: usize, n: usize) -> String {
    if n == 0 {
        "–".to_string()
    } else {
        format!("{:.1} %", 100.0 * k as f64 / n as f64)
    }
}

/// The targets of issue 28, checked: each line names a claim and whether it held.
pub fn verdicts(campaign: &Campaign) -> Vec<(String, bool)> {
    let mut out = Vec::new();
    let failed = campaign.rows.iter().filter(|r| r.failure.is_some()).count();
    out.push((
        format!(
            "every session finished ({failed} of {} did not)",
            campaign.rows.len()
        ),
        failed == 0,
    ));
    let policies: Vec<Option<PolicyChoice>> = std::iter::once(None)
        .chain(campaign.design.policies.iter().copied().map(Some))
        .collect();
    for &policy in &policies {
        let what = policy.map_or("all policies".to_string(), |p| {
            format!("{} policy", p.name())
        });
        let t = Tally::of(rows_of(campaign, None, policy));
        let n = t.finished();
        if n > 0 {
            out.extend(departure_verdicts(&t, &what));
        }
        let c = Tally::of(rows_of(campaign, Some(Shape::Tsl), policy));
        if c.finished() > 0 {
            out.extend(control_verdicts(campaign, &c, policy, &what));
        }
    }
    out
}

/// The targets on sheets that are not TSL, over `t`.
fn departure_verdicts(t: &Tally, what: &str) -> Vec<(String, bool)> {
    let n = t.finished();
    let (coverage, coverage_held) = coverage_claim(t.sigma_covered, n);
    vec![
        (
            format!(
                "not TSL, {what}: class right in {} of {n} sessions (target ≥ 90 %)",
                pct(t.class_right, n)
            ),
            t.share(t.class_right) >= CLASS_RIGHT_TARGET,
        ),
        (
            format!(
                "not TSL, {what}: flagged and wrong in {} ({} sessions: {} a wrong class, {} none; target ≤ 2 %)",
                pct(t.flagged_wrong, n),
                t.flagged_wrong,
                t.flagged_wrong_class,
                t.flagged_wrong - t.flagged_wrong_class
            ),
            t.share(t.flagged_wrong) <= FLAGGED_WRONG_LIMIT,
        ),
        (
            format!("not TSL, {what}: σ's interval covers σ_eq in {coverage}"),
            coverage_held,
        ),
        (
            format!(
                "not TSL, {what}: {} unflagged misses (σ outside its interval at confidence ≥ {CONFIDENT}, no flag; target 0), {} of them by more than {GROSS_MISS_HALF_WIDTHS} half-widths",
                t.unflagged_miss, t.gross_unflagged_miss
            ),
            t.unflagged_miss == 0,
        ),
        (
            format!(
                "not TSL, {what}: {} confidently wrong classes (target 0)",
                t.confidently_wrong
            ),
            t.confidently_wrong == 0,
        ),
    ]
}

/// The targets on exact TSL, over `c` (the control under `policy`, `None`: all).
fn control_verdicts(
    campaign: &Campaign,
    c: &Tally,
    policy: Option<PolicyChoice>,
    what: &str,
) -> Vec<(String, bool)> {
    let n = c.finished();
    let (coverage, coverage_held) = coverage_claim(c.sigma_covered, n);
    let mut out = vec![
        (
            format!(
                "exact TSL, {what}: an extension selected in {} of {n} sessions (target ≤ 2 %)",
                pct(c.extended, n)
            ),
            c.share(c.extended) <= EXTENSION_ON_TSL_LIMIT,
        ),
        (
            format!(
                "exact TSL, {what}: σ's interval covers the truth in {coverage}; {} unflagged misses at confidence ≥ {CONFIDENT} (the few percent an honest interval misses; not a target), {} by more than {GROSS_MISS_HALF_WIDTHS} half-widths",
                c.unflagged_miss, c.gross_unflagged_miss
            ),
            coverage_held,
        ),
        (
            format!(
                "exact TSL, {what}: class right in {}",
                pct(c.class_right, n)
            ),
            c.class_right == n,
        ),
    ];
    if let Some(policy) = policy {
        match device_time_ratio(campaign, policy) {
            Some((ratio, compared)) => out.push((
                format!(
                    "exact TSL, {what}: device time {:+.1} % against today's over {compared} sessions (target within +10 %)",
                    100.0 * (ratio - 1.0)
                ),
                ratio <= DEVICE_TIME_LIMIT,
            )),
            None => out.push((
                format!("exact TSL, {what}: no device time of today's recorded to compare with"),
                true,
            )),
        }
    }
    out
}

fn opt<T: std::fmt::Display>(value: Option<T>) -> String {
    value.map_or(String::new(), |v| v.to_string())
}

/// The CSV header of `sessions.csv`.
pub const CSV_HEADER: &str = "shape,departure,strength,sim_options,paper,policy,index,seed,failure,class,expected_class,class_right,confidence,flags,extended,flagged_and_wrong,unflagged_miss,gross_unflagged_miss,sigma_eq,sigma_deg,sigma_lo,sigma_hi,sigma_covered,rho_s_eq,rho_s,rho_s_covered,rho_d_eq,rho_d,rho_d_covered,eta,gof_p,arm_offset_deg,geometries,device_seconds";

/// `sessions.csv`: one row per session.
pub fn to_csv(campaign: &Campaign) -> String {
    let mut records = Vec::new();
    for r in &campaign.rows {
        let (departure, strength) = match r.spec.shape {
            Shape::Tsl => ("tsl", ""),
            Shape::Departure(kind, Strength::Mild) => (kind.name(), "mild"),
            Shape::Departure(kind, Strength::Strong) => (kind.name(), "strong"),
        };
        let truth = r.truth.as_ref();
        records.push(vec![
            r.spec.shape.name().to_string(),
            departure.to_string(),
            strength.to_string(),
            r.spec.shape.command_line(r.spec.paper).to_string(),
            r.spec.paper.to_string(),
            r.spec.policy.name().to_string(),
            r.spec.index.to_string(),
            r.spec.seed.to_string(),
            r.failure.clone().unwrap_or_default(),
            r.class.map_or("undecided", Class::name).to_string(),
            r.expected_class().map_or("", Class::name).to_string(),
            r.class_right().to_string(),
            format!("{:.4}", r.confidence),
            r.flags
                .iter()
                .map(|f| f.name())
                .collect::<Vec<_>>()
                .join(" "),
            r.extended().to_string(),
            r.flagged_and_wrong().to_string(),
            r.unflagged_miss().to_string(),
            r.gross_unflagged_miss().to_string(),
            opt(truth.map(|t| t.sigma_deg)),
            opt(r.estimates[0]),
            opt(r.sigma_ci95.map(|c| c.0)),
            opt(r.sigma_ci95.map(|c| c.1)),
            opt(r.covered[0]),
            opt(truth.map(|t| t.rho_s)),
            opt(r.estimates[1]),
            opt(r.covered[1]),
            opt(truth.map(|t| t.rho_d)),
            opt(r.estimates[2]),
            opt(r.covered[2]),
            opt(r.estimates[3]),
            opt(r.gof_p),
            opt(r.arm_offset_deg),
            r.geometries.to_string(),
            format!("{:.3}", r.device_seconds),
        ]);
    }
    super::csv_table(CSV_HEADER, &records)
}

/// The CSV header of `members.csv`.
pub const MEMBERS_CSV_HEADER: &str =
    "shape,paper,policy,index,seed,sigma_eq,member,sigma_deg,sigma_lo,sigma_hi,sigma_covered";

/// `members.csv`: one row per member of the family fitted in each session, with σ's own
/// 95 % interval and whether it holds σ_eq (what the reported interval, their union over
/// the members the data do not reject, rests on).
pub fn members_csv(campaign: &Campaign) -> String {
    let mut records = Vec::new();
    for r in &campaign.rows {
        let sigma_eq = r.truth.map(|t| t.sigma_deg);
        for m in &r.members {
            records.push(vec![
                r.spec.shape.name().to_string(),
                r.spec.paper.to_string(),
                r.spec.policy.name().to_string(),
                r.spec.index.to_string(),
                r.spec.seed.to_string(),
                opt(sigma_eq),
                m.label.clone(),
                m.sigma_deg.to_string(),
                opt(m.sigma_ci95.map(|c| c.0)),
                opt(m.sigma_ci95.map(|c| c.1)),
                opt(member_covers(m, sigma_eq)),
            ]);
        }
    }
    super::csv_table(MEMBERS_CSV_HEADER, &records)
}

/// Whether a member's own σ interval holds `sigma_eq` (`None`: no interval or no truth).
fn member_covers(m: &MemberSigma, sigma_eq: Option<f64>) -> Option<bool> {
    let (lo, hi) = m.sigma_ci95?;
    sigma_eq.map(|t| lo <= t && t <= hi)
}

/// The members every extended fit has, whose own coverage the summary gives: the paper's
/// model and its lobe shape (κ free, which holds the glossy microfacet lobes).
const MEMBERS_SUMMARIZED: [&str; 2] = ["TSL", "TSL + lobe shape"];

/// Per shape, paper and policy: how often the reported σ interval holds σ_eq, and how
/// often the paper's model's and the lobe shape's own intervals do. Where one member alone
/// holds a sheet and the others lean one way the reported interval covers about as often
/// as that member's own; its misses are that interval's tail (docs/ACCURACY.md).
fn members_markdown(out: &mut String, campaign: &Campaign) {
    if campaign.rows.iter().all(|r| r.members.is_empty()) {
        return;
    }
    let _ = writeln!(
        out,
        "\n## The members' own σ intervals\n\nσ_eq covered by the reported interval and by each member's own (members.csv has every member of every session).\n"
    );
    let _ = writeln!(
        out,
        "| shape | paper | policy | sessions | reported | {} |",
        MEMBERS_SUMMARIZED.join(" | ")
    );
    let _ = writeln!(
        out,
        "|---|---|---|---:|---:|{}",
        "---:|".repeat(MEMBERS_SUMMARIZED.len())
    );
    for shape in &campaign.design.shapes {
        for paper in &campaign.design.papers {
            for policy in &campaign.design.policies {
                let rows: Vec<&Row> = rows_of(campaign, Some(*shape), Some(*policy))
                    .filter(|r| r.spec.paper == *paper && r.failure.is_none())
                    .collect();
                if rows.is_empty() {
                    continue;
                }
                let t = Tally::of(rows.iter().copied());
                let mut line = format!(
                    "| {} | {paper} | {} | {} | {} |",
                    shape.name(),
                    policy.name(),
                    t.finished(),
                    pct(t.sigma_covered, t.finished())
                );
                for label in MEMBERS_SUMMARIZED {
                    let (mut fitted, mut covered) = (0, 0);
                    for r in &rows {
                        let truth = r.truth.map(|t| t.sigma_deg);
                        if let Some(c) = r
                            .members
                            .iter()
                            .find(|m| m.label == label)
                            .and_then(|m| member_covers(m, truth))
                        {
                            fitted += 1;
                            covered += usize::from(c);
                        }
                    }
                    let _ = write!(line, " {} of {fitted} |", pct(covered, fitted));
                }
                let _ = writeln!(out, "{line}");
            }
        }
    }
}

/// `summary.md`: the targets, the tallies per departure and policy, the class by paper,
/// the unflagged misses and today's device time.
pub fn summary_markdown(campaign: &Campaign) -> String {
    let d = &campaign.design;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# Sheets that are not TSL: {} sessions\n\n{} shapes (the exact-TSL control and {} departures at two strengths) × {} papers × {} seeds × {} ({}), ideal physics.\n",
        campaign.rows.len(),
        d.shapes.len(),
        d.shapes.iter().filter(|s| s.departs()).count() / 2,
        d.papers.len(),
        d.seeds,
        if d.policies.len() == 1 {
            "1 policy".to_string()
        } else {
            format!("{} policies", d.policies.len())
        },
        d.policies
            .iter()
            .map(|p| p.name())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(out, "## Targets\n");
    let verdicts = verdicts(campaign);
    for (claim, held) in &verdicts {
        let _ = writeln!(out, "- {} {claim}", if *held { "✓" } else { "✗" });
    }
    let held = verdicts.iter().filter(|(_, h)| *h).count();
    let _ = writeln!(out, "\n{held} of {} targets held.\n", verdicts.len());
    tallies_markdown(&mut out, campaign);
    by_paper_markdown(&mut out, campaign);
    misses_markdown(&mut out, campaign);
    members_markdown(&mut out, campaign);
    device_time_markdown(&mut out, campaign);
    if !campaign.not_applicable.is_empty() {
        let _ = writeln!(out, "\n## Not applicable\n");
        for n in &campaign.not_applicable {
            let _ = writeln!(out, "- {} on {}: {}", n.shape.name(), n.paper, n.why);
        }
    }
    out
}

/// The table per shape and policy of [`summary_markdown`].
fn tallies_markdown(out: &mut String, campaign: &Campaign) {
    let _ = writeln!(out, "## Per departure and policy\n");
    let _ = writeln!(
        out,
        "Flagged & wrong: a wrong class or none with a flag that is not informational. Unflagged miss: σ outside its 95 % interval, no such flag, confidence ≥ {CONFIDENT} (gross: by more than {GROSS_MISS_HALF_WIDTHS} half-widths of the interval). σ covered: σ's interval holds σ_eq (95 % Wilson interval; no interval is a miss). Device s: mean; vs TSL: against the exact-TSL control of the same papers and policy.\n"
    );
    let _ = writeln!(
        out,
        "| shape | policy | sessions | class right | flagged & wrong | undecided | unflagged miss (gross) | confidently wrong | σ covered | extension | lack-of-fit | geometries | device s | vs TSL |"
    );
    let _ = writeln!(
        out,
        "|---|---|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|"
    );
    for &shape in &campaign.design.shapes {
        for &policy in &campaign.design.policies {
            let rows: Vec<&Row> = rows_of(campaign, Some(shape), Some(policy)).collect();
            if rows.is_empty() {
                continue;
            }
            let t = Tally::of(rows.iter().copied());
            let papers: Vec<&str> = rows.iter().map(|r| r.spec.paper).collect();
            let control = Tally::of(
                rows_of(campaign, Some(Shape::Tsl), Some(policy))
                    .filter(|r| papers.contains(&r.spec.paper)),
            );
            let n = t.finished();
            let (lo, hi) = wilson95(t.sigma_covered, n);
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} | {} | {} | **{}** ({}) | **{}** | {} ({:.0}–{:.0}) | {} | {} | {:.1} | {:.1} | {} |",
                shape.name(),
                policy.name(),
                t.sessions,
                pct(t.class_right, n),
                pct(t.flagged_wrong, n),
                pct(t.undecided, n),
                t.unflagged_miss,
                t.gross_unflagged_miss,
                t.confidently_wrong,
                pct(t.sigma_covered, n),
                100.0 * lo,
                100.0 * hi,
                pct(t.extended, n),
                pct(t.lack_of_fit, n),
                t.geometries as f64 / n.max(1) as f64,
                t.mean_device_seconds(),
                if control.finished() > 0 && shape.departs() {
                    format!(
                        "{:+.0} %",
                        100.0 * (t.mean_device_seconds() / control.mean_device_seconds() - 1.0)
                    )
                } else {
                    "–".to_string()
                }
            );
        }
    }
}

/// The class right per shape and paper of [`summary_markdown`].
fn by_paper_markdown(out: &mut String, campaign: &Campaign) {
    let papers = &campaign.design.papers;
    for &policy in &campaign.design.policies {
        let _ = writeln!(
            out,
            "\n## Class right by paper, {} policy\n\nCells: sessions with the paper's class of those run; a mark after it: u undecided, f flagged and wrong, ! unflagged miss.\n",
            policy.name()
        );
        let _ = writeln!(out, "| shape | {} |", papers.join(" | "));
        let _ = writeln!(out, "|---|{}", "---:|".repeat(papers.len()));
        for &shape in &campaign.design.shapes {
            let cells: Vec<String> = papers
                .iter()
                .map(|paper| {
                    let t = Tally::of(
                        rows_of(campaign, Some(shape), Some(policy))
                            .filter(|r| r.spec.paper == *paper),
                    );
                    if t.sessions == 0 {
                        return "n/a".to_string();
                    }
                    let mut cell = format!("{}/{}", t.class_right, t.sessions);
                    for (count, mark) in [
                        (t.undecided, "u"),
                        (t.flagged_wrong, "f"),
                        (t.unflagged_miss, "!"),
                    ] {
                        if count > 0 {
                            let _ = write!(cell, " {count}{mark}");
                        }
                    }
                    cell
                })
                .collect();
            let _ = writeln!(out, "| {} | {} |", shape.name(), cells.join(" | "));
        }
    }
}

/// The unflagged misses and confidently wrong classes, one line each.
fn misses_markdown(out: &mut String, campaign: &Campaign) {
    let _ = writeln!(out, "\n## Unflagged misses and confidently wrong classes\n");
    let mut any = false;
    for r in campaign
        .rows
        .iter()
        .filter(|r| r.unflagged_miss() || r.confidently_wrong())
    {
        any = true;
        let _ = writeln!(
            out,
            "- {} on {} ({}, seed {}): {} at {:.2}; σ {} [{}] against σ_eq {}; η {}; flags: {}",
            r.spec.shape.name(),
            r.spec.paper,
            r.spec.policy.name(),
            r.spec.seed,
            r.class.map_or("undecided", Class::name),
            r.confidence,
            opt(r.estimates[0].map(|s| format!("{s:.3}"))),
            opt(r.sigma_ci95.map(|(lo, hi)| format!("{lo:.3}, {hi:.3}"))),
            opt(r.truth.map(|t| t.sigma_deg)),
            opt(r.estimates[3].map(|e| format!("{e:.3}"))),
            if r.flags.is_empty() {
                "none".to_string()
            } else {
                r.flags
                    .iter()
                    .map(|f| f.name())
                    .collect::<Vec<_>>()
                    .join(" ")
            }
        );
    }
    if !any {
        let _ = writeln!(out, "None.");
    }
}

/// The exact-TSL device time per paper and policy against today's.
fn device_time_markdown(out: &mut String, campaign: &Campaign) {
    let _ = writeln!(
        out,
        "\n## Exact TSL: device time against today's\n\n| paper | policy | sessions | device s | today's | change |\n|---|---|---:|---:|---:|---:|"
    );
    for &paper in &campaign.design.papers {
        for &policy in &campaign.design.policies {
            let t = Tally::of(
                rows_of(campaign, Some(Shape::Tsl), Some(policy)).filter(|r| r.spec.paper == paper),
            );
            if t.finished() == 0 {
                continue;
            }
            let today = today_device_seconds(paper, policy);
            let _ = writeln!(
                out,
                "| {paper} | {} | {} | {:.2} | {} | {} |",
                policy.name(),
                t.finished(),
                t.mean_device_seconds(),
                opt(today.map(|s| format!("{s:.2}"))),
                opt(today.map(|s| format!("{:+.1} %", 100.0 * (t.mean_device_seconds() / s - 1.0))))
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::classify::class_of;

    #[test]
    fn every_shape_is_a_sheet_the_simulator_takes_but_beckmann_on_mc() {
        let design = Design::new(1, &DEFAULT_POLICIES);
        assert_eq!(design.shapes.len(), 1 + 2 * KINDS.len());
        let (specs, refused) = design.sessions();
        assert_eq!(
            refused
                .iter()
                .map(|n| (n.shape.name(), n.paper))
                .collect::<Vec<_>>(),
            vec![
                ("beckmann mild".to_string(), "MC"),
                ("beckmann strong".to_string(), "MC")
            ]
        );
        assert!(refused[0].why.contains("39 degrees"), "{}", refused[0].why);
        assert_eq!(specs.len(), (design.shapes.len() * 8 - 2) * 2);
        for kind in KINDS {
            assert_eq!(Kind::named(kind.name()), Some(kind));
        }
    }

    #[test]
    fn the_truth_is_the_papers_and_its_class_the_papers_class() {
        for shape in Shape::all(&KINDS) {
            for reference in &REFERENCES {
                let Ok(sheet) = shape.sim_options(reference.name, 1).sheet(reference.name) else {
                    continue;
                };
                let t = sheet.equivalent_truth();
                let p = reference.params;
                assert_eq!(
                    (t.sigma_deg, t.rho_s, t.rho_d, t.eta),
                    (p.sigma_deg, p.rho_s, p.rho_d, p.eta),
                    "{} on {}",
                    shape.name(),
                    reference.name
                );
                assert_eq!(
                    class_of(Some(t.sigma_deg), t.rho_s, t.rho_d),
                    reference.class
                );
            }
        }
    }

    #[test]
    fn a_departure_and_its_control_share_the_seed_and_the_options_name_it() {
        let design = Design {
            shapes: vec![Shape::Tsl, Shape::Departure(Kind::Haze, Strength::Strong)],
            papers: vec!["G", "J1"],
            policies: vec![PolicyChoice::Sweep],
            seeds: 3,
            first_index: 0,
        };
        let (specs, _) = design.sessions();
        assert_eq!(specs.len(), 2 * 2 * 3);
        for s in &specs {
            assert_eq!(s.seed, Design::seed(s.paper, s.policy, s.index));
        }
        assert_ne!(
            Design::seed("G", PolicyChoice::Sweep, 0),
            Design::seed("G", PolicyChoice::Adaptive, 0)
        );
        assert_ne!(
            Design::seed("G", PolicyChoice::Sweep, 0),
            Design::seed("J1", PolicyChoice::Sweep, 0)
        );
        let haze = Shape::Departure(Kind::Haze, Strength::Strong);
        assert_eq!(haze.command_line("G"), "--departure haze:0.03:4");
        assert_eq!(
            Shape::Departure(Kind::Lobe(LobeChoice::Ggx), Strength::Mild).command_line("G"),
            "--lobe ggx --lobe-weight 0.5"
        );
        assert_eq!(
            Shape::Departure(Kind::PeakShift, Strength::Strong).command_line("G"),
            "--departure peak-shift:0.57"
        );
        assert_eq!(Shape::Tsl.command_line("G"), "");
    }

    fn row(shape: Shape, paper: &'static str, class: Option<Class>) -> Row {
        Row {
            spec: SessionSpec {
                shape,
                paper,
                policy: PolicyChoice::Sweep,
                index: 0,
                seed: 1,
            },
            failure: None,
            truth: None,
            class,
            confidence: 1.0,
            flags: Vec::new(),
            estimates: [None; 4],
            sigma_ci95: None,
            covered: [Some(true); 3],
            gof_p: None,
            arm_offset_deg: None,
            geometries: 10,
            device_seconds: 2.0,
            members: Vec::new(),
        }
    }

    #[test]
    fn each_members_own_interval_is_counted_against_the_truth() {
        let member = |label: &str, ci: Option<(f64, f64)>| MemberSigma {
            label: label.to_string(),
            sigma_deg: 1.9,
            sigma_ci95: ci,
        };
        let truth = Stock {
            sigma_deg: 1.9,
            rho_s: 57.1,
            rho_d: 0.795,
            eta: 1.02,
        };
        let mut rows = Vec::new();
        for (k, (paper_model, lobe_shape)) in [
            ((1.89, 1.895), (1.89, 1.91)),
            ((1.895, 1.905), (1.88, 1.899)),
        ]
        .into_iter()
        .enumerate()
        {
            let mut r = row(Shape::Tsl, "SG", Some(Class::SG));
            r.spec.index = k;
            r.truth = Some(truth);
            r.covered[0] = Some(k == 0);
            r.members = vec![
                member("TSL", Some(paper_model)),
                member("TSL + lobe shape", Some(lobe_shape)),
                member("TSL + haze lobe", None),
            ];
            rows.push(r);
        }
        let campaign = Campaign {
            design: Design {
                shapes: vec![Shape::Tsl],
                papers: vec!["SG"],
                policies: vec![PolicyChoice::Sweep],
                seeds: 2,
                first_index: 0,
            },
            rows,
            not_applicable: Vec::new(),
        };
        let csv = members_csv(&campaign);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 1 + 6, "{csv}");
        assert_eq!(lines[0], MEMBERS_CSV_HEADER);
        assert!(lines[1].ends_with(",TSL,1.9,1.89,1.895,false"), "{csv}");
        assert!(
            lines[2].ends_with(",TSL + lobe shape,1.9,1.89,1.91,true"),
            "{csv}"
        );
        assert!(lines[3].ends_with(",TSL + haze lobe,1.9,,,"), "{csv}");
        let summary = summary_markdown(&campaign);
        assert!(
            summary.contains("| tsl | SG | sweep | 2 | 50.0 % | 50.0 % of 2 | 50.0 % of 2 |"),
            "{summary}"
        );
    }

    #[test]
    fn the_tally_counts_what_the_targets_name() {
        let haze = Shape::Departure(Kind::Haze, Strength::Mild);
        let right = row(haze, "G", Some(Class::G));
        let flagged_wrong = Row {
            flags: vec![Flag::LackOfFit],
            confidence: 0.9,
            ..row(haze, "G", Some(Class::RoughII))
        };
        let undecided_flagged = Row {
            flags: vec![Flag::LackOfFit],
            ..row(haze, "G", None)
        };
        let miss = Row {
            covered: [Some(false), Some(true), Some(true)],
            flags: vec![Flag::ModelExtended],
            // 0.2° off an interval of half-width 0.025°: gross.
            estimates: [Some(1.0), None, None, None],
            sigma_ci95: Some((0.95, 1.0)),
            truth: Some(Stock {
                sigma_deg: 1.2,
                rho_s: 57.1,
                rho_d: 0.795,
                eta: 1.02,
            }),
            ..row(haze, "SG", Some(Class::SG))
        };
        let confidently_wrong = row(haze, "SG", Some(Class::G));
        let failed = Row {
            failure: Some("stopped".into()),
            ..row(haze, "SG", None)
        };
        let rows = [
            right,
            flagged_wrong,
            undecided_flagged,
            miss,
            confidently_wrong,
            failed,
        ];
        let t = Tally::of(&rows);
        assert_eq!((t.sessions, t.failed, t.finished()), (6, 1, 5));
        assert_eq!(t.class_right, 2);
        assert_eq!(t.flagged_wrong, 2);
        assert_eq!(t.undecided, 1);
        assert_eq!(t.unflagged_miss, 1, "model-extended is informational");
        assert_eq!(t.gross_unflagged_miss, 1);
        assert_eq!(t.confidently_wrong, 1);
        assert_eq!(t.extended, 1);
        assert_eq!(t.sigma_covered, 4);
        assert_eq!(t.flagged, 2);
        assert_eq!(t.mean_device_seconds(), 2.0);
        let campaign = Campaign {
            design: Design {
                shapes: vec![Shape::Tsl, haze],
                papers: vec!["G", "SG"],
                policies: vec![PolicyChoice::Sweep],
                seeds: 1,
                first_index: 0,
            },
            rows: rows
                .into_iter()
                .chain([row(Shape::Tsl, "G", Some(Class::G))])
                .collect(),
            not_applicable: Vec::new(),
        };
        let verdicts = verdicts(&campaign);
        let held = |start: &str| {
            verdicts
                .iter()
                .find(|(claim, _)| claim.starts_with(start))
                .unwrap_or_else(|| panic!("no claim {start}: {verdicts:?}"))
                .1
        };
        assert!(!held("every session finished"));
        assert!(!held("not TSL, all policies: class right in 40.0 % of 5"));
        assert!(!held("not TSL, all policies: 1 unflagged misses"));
        assert!(held(
            "exact TSL, all policies: an extension selected in 0.0 % of 1"
        ));
        assert!(held("exact TSL, all policies: class right in 100.0 %"));
        let summary = summary_markdown(&campaign);
        assert!(
            summary.contains(
                "| haze mild | sweep | 6 | 40.0 % | 40.0 % | 20.0 % | **1** (1) | **1** |"
            ),
            "{summary}"
        );
        assert!(
            summary.contains("| haze mild | 1/3 1u 2f | 1/3 1! |"),
            "{summary}"
        );
        assert_eq!(to_csv(&campaign).lines().count(), 1 + 7);
    }
}
