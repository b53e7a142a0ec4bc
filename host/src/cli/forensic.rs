//! `gonio forensic`: the forensic validation study on the simulated instrument
//! (docs/FORENSIC.md).
use anyhow::{Context, bail};
use host::study::forensic::{self, Design};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio forensic`.
#[derive(clap::Args)]
pub struct Args {
    /// Folder for summary.md, pairs.csv and tippett.svg.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Independent draws of the population of stocks (each its own seed).
    #[arg(long, default_value_t = Design::FULL.draws)]
    pub draws: usize,
    /// The number of the first draw: draws from it on (their seeds follow from it). The
    /// default study is draws 0–9; `--first-draw 10` confirms its figures on draws it never used.
    #[arg(long, default_value_t = 0)]
    pub first_draw: usize,
    /// Stocks drawn about each of the eight reference papers besides the paper itself.
    #[arg(long, default_value_t = Design::FULL.drawn_per_paper)]
    pub drawn_per_paper: usize,
    /// Sheets of each stock in the library.
    #[arg(long, default_value_t = Design::FULL.library_sheets)]
    pub library_sheets: usize,
    /// Sheets of each stock held out for the pairs.
    #[arg(long, default_value_t = Design::FULL.held_out_sheets)]
    pub held_out_sheets: usize,
    /// Clean spots planned per sheet for the claims (as `gonio measure --spots`).
    #[arg(long, default_value_t = Design::FULL.spots)]
    pub spots: usize,
    /// Numbers of spots per sheet to compare, the same sheets measured with each
    /// (comma-separated; give only --spots' number to skip the comparison).
    #[arg(long, value_delimiter = ',', default_values_t = forensic::SPOTS_STUDY)]
    pub spots_study: Vec<usize>,
    /// How each spot is measured, as `gonio measure --policy` (default adaptive, the
    /// policy of docs/FORENSIC.md's figures; docs/TRADE.md has the study with sweeps).
    #[arg(long, value_enum, default_value_t = host::session::PolicyChoice::Adaptive)]
    pub policy: host::session::PolicyChoice,
    /// The simulated world: how spots, sheets and stocks vary (as-today, spots-1pct,
    /// spots-6pct, stocks-5pct, stocks-20pct, near-twins, sheets-3pct, heavy-tailed,
    /// second-instrument, extensions: as-today with the model's extensions tested, shapes:
    /// every stock a shape of its own, the extensions tested), or `all` (each into its own
    /// folder of --out, and
    /// campaign.md); the evidence is never told, it estimates its population from the
    /// study's library.
    #[arg(long, default_value = "as-today", value_name = "NAME")]
    pub scenario: String,
    /// Validate this stock library (its own sheets) as the population `compare --library`
    /// weighs against, instead of running the simulated study: the pairs, calibrator,
    /// bounds, Cllr, Tippett and ECE plots of the lab's own data.
    #[arg(long, value_name = "FILE|URL", value_parser = crate::cli::library::location_arg())]
    pub library: Option<host::output::library::Location>,
    /// Worker threads (default: one per core).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Run `gonio forensic`: exit 0 when every claim held, 3 when any did not.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if let Some(library) = &args.library {
        return run_library(library, &args.out);
    }
    if args.draws == 0 || args.library_sheets == 0 || args.held_out_sheets < 2 {
        bail!("the study needs at least 1 draw, 1 library sheet and 2 held-out sheets");
    }
    if args.first_draw + args.draws > 100_000 {
        bail!("draws are numbered below 100000 (each sheet's seed is made of its draw's number)");
    }
    if args.library_sheets + args.held_out_sheets > 999 || args.drawn_per_paper > 999 {
        bail!(
            "at most 999 sheets per stock and 999 stocks drawn per paper (each sheet's seed is made of them)"
        );
    }
    let scenarios: Vec<forensic::Scenario> = if args.scenario == "all" {
        forensic::Scenario::ALL.to_vec()
    } else {
        vec![forensic::Scenario::named(&args.scenario).ok_or_else(|| {
            anyhow::anyhow!(
                "no scenario '{}': the scenarios are all, {}",
                args.scenario,
                forensic::Scenario::ALL
                    .iter()
                    .map(|s| s.name)
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })?]
    };
    let mut campaign = Vec::new();
    for scenario in scenarios {
        let out = if args.scenario == "all" {
            args.out.join(scenario.name)
        } else {
            args.out.clone()
        };
        campaign.push(run_scenario(&args, scenario, &out)?);
    }
    if args.scenario == "all" {
        let table = forensic::campaign_markdown(&campaign);
        let md = args.out.join("campaign.md");
        std::fs::write(&md, &table).with_context(|| format!("cannot write {}", md.display()))?;
        print!("{table}");
        eprintln!("wrote {}", md.display());
    }
    let held = campaign
        .iter()
        .all(|f| forensic::claims(f).iter().all(|(_, held)| *held));
    Ok(if held {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(crate::cli::exit::FLAGGED)
    })
}

/// One scenario's study into `out`: its summary, its pairs and its Tippett plot.
fn run_scenario(
    args: &Args,
    scenario: forensic::Scenario,
    out: &std::path::Path,
) -> anyhow::Result<forensic::Figures> {
    let design = Design {
        scenario,
        draws: args.draws,
        first_draw: args.first_draw,
        drawn_per_paper: args.drawn_per_paper,
        library_sheets: args.library_sheets,
        held_out_sheets: args.held_out_sheets,
        spots: args.spots,
        policy: args.policy,
    };
    let counts = forensic::spot_counts_of(&design, &args.spots_study);
    if counts.iter().any(|&n| n == 0 || n > 20) {
        bail!("spots per sheet must be 1 to 20");
    }
    if counts[0] < 2 && args.library_sheets < 2 {
        bail!(
            "the library needs two spots of a stock (--spots 2 or --library-sheets 2, for every number of --spots-study) to estimate the within-stock variation"
        );
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .max(1);
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let bar = ProgressBar::new(forensic::plan(&design, &counts).len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} sheets, {elapsed} ({eta} left)")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(format!(
        "{}: simulated sheets of {} population draws",
        scenario.name, design.draws
    ));
    let campaign = forensic::measure_all(&design, &counts, threads, &|| bar.inc(1))?;
    bar.finish_and_clear();
    let (figures, pairs) = forensic::figures(&campaign, design.spots, threads)?;
    let mut study = Vec::new();
    if counts.len() > 1 {
        for &n in &counts {
            study.push(if n == design.spots {
                figures.clone()
            } else {
                forensic::figures(&campaign, n, threads)?.0
            });
        }
    }
    let csv_path = out.join("pairs.csv");
    let write_csv = || -> Result<(), csv::Error> {
        let mut csv = csv::Writer::from_path(&csv_path)?;
        csv.write_record([
            "draw",
            "stock_a",
            "stock_b",
            "class_a",
            "class_b",
            "same_stock",
            "log10_lr",
            "raw_log10_lr",
            "warnings",
        ])?;
        for p in &pairs {
            let (a, b) = (
                &campaign.stocks[p.draw][p.stock_a],
                &campaign.stocks[p.draw][p.stock_b],
            );
            csv.write_record([
                p.draw.to_string(),
                a.name.clone(),
                b.name.clone(),
                a.class.name().to_string(),
                b.class.name().to_string(),
                (p.stock_a == p.stock_b).to_string(),
                format!("{:.4}", p.log10_lr),
                format!("{:.4}", p.raw_log10_lr),
                p.warnings.join(" "),
            ])?;
        }
        csv.flush()?;
        Ok(())
    };
    write_csv().with_context(|| format!("cannot write {}", csv_path.display()))?;
    let svg = out.join("tippett.svg");
    forensic::tippett_svg(&pairs, design.draws, &svg)?;
    let summary = format!(
        "{}\nEvery spot measured with `--policy {}`.\n",
        forensic::summary_markdown(&figures, &study).trim_end(),
        args.policy.name()
    );
    let md = out.join("summary.md");
    std::fs::write(&md, &summary).with_context(|| format!("cannot write {}", md.display()))?;
    if args.scenario != "all" {
        print!("{summary}");
    }
    eprintln!(
        "wrote {}, {} and {}",
        md.display(),
        csv_path.display(),
        svg.display()
    );
    Ok(figures)
}

/// `gonio forensic --library FILE --out DIR`: the library validated, its figures and plots
/// written to DIR.
fn run_library(
    path: &host::output::library::Location,
    out: &std::path::Path,
) -> anyhow::Result<ExitCode> {
    use host::output::library::{Library, OpenMode};
    use host::study::library_validation;
    let mut library = Library::open(path, OpenMode::Existing)?;
    let sheets: Vec<_> = library
        .sheets()?
        .into_iter()
        .map(|(_, sheet)| sheet)
        .collect();
    let population = library_validation::run(&sheets)
        .with_context(|| format!("{path}: cannot validate the library"))?;
    // Recorded in the library, whole (stocks, variance components with their degrees of
    // freedom, kernel and bandwidth, counts, calibrator, bounds, Cllr): comparisons against
    // this population (this library's contents as they are now) then carry no "not
    // validated" warning.
    let recorded = serde_json::to_value(&population)?;
    library.record_validation(
        &host::analysis::evidence::population::contents_identity(&sheets),
        &recorded,
    )?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let summary = library_validation::summary_markdown(path, &population);
    let summary_path = out.join("summary.md");
    std::fs::write(&summary_path, &summary)
        .with_context(|| format!("cannot write {}", summary_path.display()))?;
    if let Some(v) = &population.validation {
        forensic::tippett_svg_of(
            &v.same,
            &v.different,
            "Tippett plot: the library's pairs, validated",
            &out.join("tippett.svg"),
        )?;
        library_validation::ece_svg(&v.same, &v.different, &out.join("ece.svg"))?;
    }
    print!("{summary}");
    println!("wrote {}, tippett.svg and ece.svg", summary_path.display());
    Ok(ExitCode::from(crate::cli::exit::OK))
}
