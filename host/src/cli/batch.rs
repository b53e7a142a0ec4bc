//! `gonio batch`: a QA run of many sheets against a master stock of the library, each
//! sheet judged pass, fail or undecided, statistics and control limits across the sheets,
//! `batch.json`, `batch.csv` and `batch.html` in the batch folder
//! ([`host::measure::batch`], [`host::output::batch`]).
use anyhow::Context;
use host::analysis::batch::{GlossSpec, LABELS, Verdict, shown_value};
use host::instrument::sim::SimOptions;
use host::measure::MeasureOptions;
use host::measure::batch::{BatchEnd, BatchOptions, DEFAULT_SHEET_TO_SHEET_PCT, run_batch};
use host::output::batch::BatchDoc;
use host::session::{Operator, PolicyChoice, PromptOperator, SessionError, SimulatedOperator};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Spots per sheet when `--spots` is not given: three give the sheet's mean and its
/// spot-to-spot sd (two degrees of freedom) and keep a batch of many sheets short; a
/// gloss meter's QA routine takes three readings a sheet as well.
pub const DEFAULT_BATCH_SPOTS: u16 = 3;

/// Arguments of `gonio batch`.
#[derive(clap::Args)]
pub struct Args {
    /// The master stock: its name in the library (gonio library list). Its sheets give the
    /// values each sheet is judged against and, without --tolerance-*, the tolerances.
    #[arg(
        long,
        value_name = "STOCK",
        required_unless_present = "resume",
        conflicts_with = "resume"
    )]
    pub master: Option<String>,
    /// The library: a file, or a PostgreSQL URL (default: the [library] setting, else
    /// $XDG_DATA_HOME/gonio/library.sqlite).
    #[arg(long, value_name = "FILE|URL", value_parser = crate::cli::library::location_arg())]
    pub library: Option<host::output::library::Location>,
    /// Sheets to measure (1 to 999).
    #[arg(
        long,
        value_name = "N",
        required_unless_present = "resume",
        conflicts_with = "resume"
    )]
    pub sheets: Option<u16>,
    /// Clean spots per sheet (1 to 20; default 3).
    #[arg(long, value_name = "M", conflicts_with = "resume")]
    pub spots: Option<u16>,
    /// Run on the simulated instrument with this paper (G, SG, PPC, MC, J1…J4,
    /// custom:SIGMA,RHO_S,RHO_D,ETA), in process: each sheet drawn about it.
    #[arg(long, value_name = "PAPER", conflicts_with = "port")]
    pub sim: Option<String>,
    #[command(flatten)]
    pub sim_options: SimOptions,
    /// On the simulator, the sheets' spread about the paper: each sheet's σ, ρs and ρd
    /// drawn log-normally with this relative sd, percent (0: every sheet the paper).
    #[arg(long, value_name = "PCT", default_value_t = DEFAULT_SHEET_TO_SHEET_PCT, allow_negative_numbers = true, conflicts_with = "resume")]
    pub sheet_to_sheet_pct: f64,
    /// Serial port of the instrument (default: the one attached instrument, by USB id).
    #[arg(long, value_name = "PATH")]
    pub port: Option<String>,
    /// Name of the sample for the reports and files (default: the simulated paper, or "sample").
    #[arg(long, conflicts_with = "resume")]
    pub sample: Option<String>,
    /// The batch folder: new or empty; a sheet folder per sheet goes into it.
    #[arg(
        long,
        value_name = "DIR",
        required_unless_present = "resume",
        conflicts_with = "resume"
    )]
    pub out: Option<PathBuf>,
    /// Continue an interrupted batch in DIR at the sheet it stopped in: its master,
    /// tolerances and plan are the ones recorded in its batch.json.
    #[arg(long, value_name = "DIR")]
    pub resume: Option<PathBuf>,
    /// Tolerance on σ, percent of the master's (default: 3 × the master's spread, at least 1 %).
    #[arg(
        long,
        value_name = "PCT",
        allow_negative_numbers = true,
        conflicts_with = "resume"
    )]
    pub tolerance_sigma_pct: Option<f64>,
    /// Tolerance on ρs, percent of the master's (default: 3 × the master's spread, at least 1 %).
    #[arg(
        long,
        value_name = "PCT",
        allow_negative_numbers = true,
        conflicts_with = "resume"
    )]
    pub tolerance_rho_s_pct: Option<f64>,
    /// Tolerance on ρd, percent of the master's (default: 3 × the master's spread, at least 1 %).
    #[arg(
        long,
        value_name = "PCT",
        allow_negative_numbers = true,
        conflicts_with = "resume"
    )]
    pub tolerance_rho_d_pct: Option<f64>,
    /// A gloss specification every sheet is judged against besides the master:
    /// GEOMETRY=TARGET±TOLERANCE in gloss units, the geometry by its angle (20, 60, 75 or
    /// 85), e.g. 60=45±3 (+- for ±); repeatable, one per geometry. A sheet with no gloss
    /// there (no instrument profile, or arms that do not reach it) is undecided. On
    /// --resume, only the batch's own (or none: it is kept).
    #[arg(long, value_name = "GEOMETRY=GU±GU", value_parser = GlossSpec::parse)]
    pub gloss_spec: Vec<GlossSpec>,
    /// The instrument's profile (gonio characterize), for every sheet: without one
    /// (given, recorded in the batch or installed for the instrument) no gloss is computed.
    #[arg(long, value_name = "FILE")]
    pub instrument: Option<PathBuf>,
    /// Refinement policy of every sheet (default adaptive; see gonio measure --help).
    #[arg(long, value_enum)]
    pub policy: Option<PolicyChoice>,
    /// The case or job number, recorded in every sheet.
    #[arg(long = "case", value_name = "ID")]
    pub case_id: Option<String>,
    /// Who measures, recorded in every sheet.
    #[arg(long, value_name = "NAME")]
    pub operator: Option<String>,
    /// Print batch.json instead of the summary.
    #[arg(long)]
    pub json: bool,
}

impl Args {
    fn options(&self) -> anyhow::Result<BatchOptions> {
        let library = match &self.library {
            Some(location) => location.clone(),
            None => host::output::library::Location::configured()?,
        };
        Ok(BatchOptions {
            master: self.master.clone(),
            library,
            sheets: self.sheets,
            out: self.out.clone(),
            resume: self.resume.clone(),
            tolerance_pct: [
                self.tolerance_sigma_pct,
                self.tolerance_rho_s_pct,
                self.tolerance_rho_d_pct,
            ],
            sheet_to_sheet_pct: self.sheet_to_sheet_pct,
            gloss_spec: self.gloss_spec.clone(),
            measure: MeasureOptions {
                sim: self.sim.clone(),
                // The seed settled as `gonio measure` settles it: `--seed`, else one drawn for
                // this batch (printed and recorded in batch.json; a resumed batch's sheets
                // take theirs from the recorded plan).
                sim_options: self.sim_options.clone().with_seed(None),
                port: self.port.clone(),
                sample: self.sample.clone(),
                policy: self.policy,
                spots: Some(self.spots.unwrap_or(DEFAULT_BATCH_SPOTS)),
                case_id: self.case_id.clone(),
                operator: self.operator.clone(),
                instrument: self.instrument.clone(),
                ..MeasureOptions::default()
            },
        })
    }
}

/// Run `gonio batch`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let options = args.options()?;
    let interrupted = Arc::new(AtomicBool::new(false));
    let flag = interrupted.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed))
        .context("cannot install the Ctrl-C handler")?;
    let mut operator: Box<dyn Operator> = if args.sim.is_some() {
        Box::new(SimulatedOperator)
    } else {
        Box::new(PromptOperator::new())
    };
    if let (Some(sample), None) = (&args.sim, &args.resume) {
        let seed = options.measure.sim_options.seed;
        eprintln!(
            "simulated instrument, sample {sample}, first sheet's seed {seed} (--seed {seed} repeats this batch; recorded in batch.json)"
        );
    }
    let mut progress = |line: &str| eprintln!("batch: {line}");
    match run_batch(&options, operator.as_mut(), interrupted, &mut progress)? {
        BatchEnd::Finished { dir, doc } => {
            print(&args, &dir, &doc)?;
            Ok(crate::cli::exit::of_result(doc.all_pass()))
        }
        BatchEnd::Stopped { dir, doc, error } => {
            print(&args, &dir, &doc)?;
            eprintln!(
                "batch stopped in sheet {}: {error}; the sheets measured are kept in {}; continue with: {}",
                doc.sheets.len() + 1,
                dir.display(),
                doc.resume_with
                    .as_deref()
                    .unwrap_or("gonio batch --resume DIR")
            );
            Ok(ExitCode::from(
                if matches!(error, SessionError::Interrupted) {
                    crate::cli::exit::INTERRUPTED
                } else {
                    crate::cli::exit::FAILED
                },
            ))
        }
    }
}

fn print(args: &Args, dir: &Path, doc: &BatchDoc) -> anyhow::Result<()> {
    if args.json {
        println!("{}", serde_json::to_string(doc)?);
        return Ok(());
    }
    let shown = host::text::shown;
    let value = |i: usize, v: Option<f64>| match v {
        Some(v) if i == 0 => format!("{v:.3}°"),
        Some(v) => format!("{v:.4}"),
        None => "—".to_string(),
    };
    println!(
        "batch of '{}' against the master stock '{}' ({} sheets, {} spots in the library)",
        shown(&doc.plan.sample),
        shown(&doc.master.stock),
        doc.master.sheets,
        doc.master.spots
    );
    for (i, label) in LABELS.iter().enumerate() {
        println!(
            "  master {} = {}, tolerance ±{:.1} % ({})",
            label,
            value(i, doc.master.values[i]),
            doc.tolerance_pct[i],
            doc.tolerance_basis[i]
        );
    }
    for spec in &doc.plan.gloss_spec {
        println!(
            "  spec {} = {} ± {} GU ({}; --gloss-spec {})",
            spec.label(),
            spec.target_gloss_units,
            spec.tolerance_gloss_units,
            spec.geometry,
            spec.text()
        );
    }
    for s in &doc.sheets {
        let verdict = match &s.verdict {
            Verdict::Pass => "PASS".to_string(),
            Verdict::Fail { .. } => s.verdict.text().replacen("fail", "FAIL", 1),
            Verdict::Undecided { .. } => s.verdict.text().replacen("undecided", "UNDECIDED", 1),
        };
        let gloss: String = s
            .gloss
            .iter()
            .map(|g| format!("  gloss {}° = {:.1} GU", g.angle_deg, g.gloss_units))
            .collect();
        // The verdict whole (its reasons are gonio's own words; a flag or sample name in
        // them is escaped): a QA bench reads why a sheet failed or was not judged.
        println!(
            "  sheet {:>2}: σ = {}  ρs = {}  ρd = {}{gloss}  {}",
            s.number,
            value(0, s.values[0]),
            value(1, s.values[1]),
            value(2, s.values[2]),
            host::text::shown_at_most(&verdict, 1000)
        );
    }
    for st in &doc.statistics {
        let q = st.quantity.as_str();
        println!(
            "  {} over {} clean sheets: mean {}, sd {}, I-MR limits {} … {}{}",
            host::analysis::batch::label(q),
            st.n,
            shown_value(q, Some(st.mean)),
            st.sd.map_or_else(
                || "—".to_string(),
                |sd| format!("{:.2} %", 100.0 * sd / st.mean)
            ),
            shown_value(q, st.lower_control_limit),
            shown_value(q, st.upper_control_limit),
            if st.out_of_control.is_empty() {
                String::new()
            } else {
                format!(
                    "; OUT OF CONTROL: sheets {}",
                    st.out_of_control
                        .iter()
                        .map(u16::to_string)
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }
        );
    }
    let c = doc.counts;
    println!(
        "  result: {} of {} sheets measured: {} pass, {} fail, {} undecided",
        doc.sheets.len(),
        doc.plan.sheets,
        c.pass,
        c.fail,
        c.undecided
    );
    println!(
        "  files: {} (batch.html the report, batch.csv for a spreadsheet, batch.json; each sheet-NN folder verifies on its own)",
        dir.display()
    );
    Ok(())
}
