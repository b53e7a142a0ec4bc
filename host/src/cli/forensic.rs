//! `gonio forensic`: the forensic validation study on the simulated instrument
//! (docs/FORENSIC.md).
use crate::study::forensic::{self, Design};
use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio forensic`.
#[derive(clap::Args)]
pub struct Args {
    /// Folder for summary.md, pairs.csv and tippett.svg.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Stocks drawn about each of the eight reference papers besides the paper itself.
    #[arg(long, default_value_t = Design::FULL.drawn_per_paper)]
    pub drawn_per_paper: usize,
    /// Sheets of each stock in the library.
    #[arg(long, default_value_t = Design::FULL.library_sheets)]
    pub library_sheets: usize,
    /// Sheets of each stock held out for the pairs.
    #[arg(long, default_value_t = Design::FULL.held_out_sheets)]
    pub held_out_sheets: usize,
    /// Spots per sheet.
    #[arg(long, default_value_t = Design::FULL.spots)]
    pub spots: usize,
    /// Worker threads (default: one per core).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Run `gonio forensic`: exit 0 when every claim held, 3 when any did not.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.library_sheets == 0 || args.held_out_sheets < 2 || args.spots == 0 {
        bail!("the study needs at least 1 library sheet, 2 held-out sheets and 1 spot per sheet");
    }
    if args.spots < 2 && args.library_sheets < 2 {
        bail!("the library needs two spots of a stock (--spots 2 or --library-sheets 2) to estimate the within-stock variation");
    }
    let threads = args.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())).max(1);
    let design = Design { drawn_per_paper: args.drawn_per_paper, library_sheets: args.library_sheets, held_out_sheets: args.held_out_sheets, spots: args.spots };
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let stocks = forensic::stocks(&design);
    let bar = ProgressBar::new(forensic::plan(&design, &stocks).len() as u64);
    bar.set_style(ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} spots, {elapsed} ({eta} left)").unwrap_or_else(|_| ProgressStyle::default_bar()).progress_chars("=> "));
    bar.set_message("simulated sheets of the population");
    let sheets = forensic::measure_all(&design, &stocks, threads, &|| bar.inc(1)).map_err(anyhow::Error::msg)?;
    bar.finish_and_clear();
    let (population, pairs) = forensic::pairs(&stocks, &sheets)?;
    let search = forensic::search_rank_one(&stocks, &sheets, &population);
    let figures = forensic::figures(&stocks, &sheets, &pairs, search);
    let mut csv = String::from("stock_a,stock_b,class_a,class_b,same_stock,log10_lr\n");
    for p in &pairs {
        let (a, b) = (&stocks[p.stock_a], &stocks[p.stock_b]);
        csv += &format!("{},{},{},{},{},{:.4}\n", a.name, b.name, a.class.name(), b.class.name(), p.stock_a == p.stock_b, p.log10_lr);
    }
    let csv_path = args.out.join("pairs.csv");
    std::fs::write(&csv_path, csv).with_context(|| format!("cannot write {}", csv_path.display()))?;
    let svg = args.out.join("tippett.svg");
    forensic::tippett_svg(&pairs, &svg).map_err(anyhow::Error::msg)?;
    let summary = forensic::summary_markdown(&figures);
    let md = args.out.join("summary.md");
    std::fs::write(&md, &summary).with_context(|| format!("cannot write {}", md.display()))?;
    print!("{summary}");
    eprintln!("wrote {}, {} and {}", md.display(), csv_path.display(), svg.display());
    let held = forensic::claims(&figures).iter().all(|(_, held)| *held);
    Ok(if held { ExitCode::SUCCESS } else { ExitCode::from(crate::cli::exit::FLAGGED) })
}
