//! `gonio compare A B`: how strongly do two measured sheets support "the same paper stock"
//! over "different stocks"? A likelihood ratio from a two-level model
//! ([`host::analysis::evidence`]), weighed against a population of stocks. A and B are
//! session folders (or their `session.json`) of `gonio measure`.
use host::analysis::evidence::{
    self, Evidence, PARAM_LABELS, Population, PopulationSource, Support,
};
use host::output::sheet_folder::{MeasuredSheet, read_measured};
use serde_json::json;
use std::path::PathBuf;
use std::process::ExitCode;

/// Exit code: the evidence supports the same stock (log10 LR ≥ 1).
pub const EXIT_SAME: u8 = 0;
/// Exit code: the evidence supports different stocks (log10 LR ≤ −1).
pub const EXIT_DIFFERENT: u8 = 1;
/// Exit code: a file could not be read or the command line was wrong.
pub const EXIT_ERROR: u8 = 2;
/// Exit code: inconclusive (LR between 1/10 and 10).
pub const EXIT_INCONCLUSIVE: u8 = 3;

/// Arguments of `gonio compare`.
#[derive(clap::Args)]
pub struct Args {
    /// Print one JSON object instead of the report.
    #[arg(long)]
    pub json: bool,
    /// First sheet: a session folder or its session.json.
    #[arg(value_name = "A")]
    pub a: PathBuf,
    /// Second sheet: a session folder or its session.json.
    #[arg(value_name = "B")]
    pub b: PathBuf,
    /// The stock library whose stocks make the population (default: the user's library,
    /// `gonio library`, when it exists; else the documented default population).
    #[arg(long, value_name = "FILE")]
    pub library: Option<PathBuf>,
}

/// The population to weigh against: the library's stocks (given, or the user's default
/// library when it exists), else the default population; with a note on which and why.
fn population_of(library: Option<&PathBuf>) -> anyhow::Result<(Population, Option<String>)> {
    use host::output::library::{self, Library, OpenMode};
    let path = match library {
        Some(path) => path.clone(),
        None => match library::default_path().filter(|p| p.is_file()) {
            Some(path) => path,
            None => return Ok((Population::default_population(), None)),
        },
    };
    let sheets = Library::open(&path, OpenMode::Existing)?.sheets()?;
    let labelled: Vec<(String, evidence::Sheet)> = sheets
        .into_iter()
        .map(|(stock, _, sheet)| (stock, sheet))
        .collect();
    Ok(match Population::from_sheets(&labelled) {
        Ok(population) => (population, Some(format!("the library {}", path.display()))),
        Err(e) => (
            Population::default_population(),
            Some(format!(
                "the library {} cannot make a population ({e}): the default population is used",
                path.display()
            )),
        ),
    })
}

fn population_json(population: &Population) -> serde_json::Value {
    json!({
        "source": population.source,
        "stocks": population.stocks.iter().map(|(name, _)| name).collect::<Vec<_>>(),
    })
}

/// The JSON object of `--json`.
pub fn to_json(
    a: &MeasuredSheet,
    b: &MeasuredSheet,
    e: &Evidence,
    population: &Population,
) -> serde_json::Value {
    let side = |r: &MeasuredSheet| {
        json!({
            "file": r.path.display().to_string(),
            "sample": r.sample,
            "class": r.classes.first().cloned().flatten(),
            "spot_classes": r.classes,
            "n_spots": r.sheet.spots.len(),
            "within_relative_sd": r.summary.as_ref().and_then(|s| s.within_relative_sd),
            "values": evidence::PARAMS.iter().enumerate().map(|(i, name)| (name.to_string(), json!(value(r, i)))).collect::<serde_json::Map<_, _>>(),
            "ci95": evidence::PARAMS.iter().enumerate().map(|(i, name)| (name.to_string(), json!(interval(r, i)))).collect::<serde_json::Map<_, _>>(),
        })
    };
    json!({
        "schema": host::schema::COMPARE,
        "log10_lr": e.log10_lr,
        "verbal": e.verbal,
        "support": e.support,
        "population": population_json(population),
        "n_spots": [e.n_spots.0, e.n_spots.1],
        "within_sheet_variation_known": [e.within_known.0, e.within_known.1],
        "parameters": e.parameters,
        "left_out": e.left_out.iter().map(|(p, why)| json!({"parameter": p, "why": why})).collect::<Vec<_>>(),
        "contributions": e.contributions.iter().map(|(p, v)| json!({"parameter": p, "log10_lr": v})).collect::<Vec<_>>(),
        "a": side(a),
        "b": side(b),
    })
}

/// Parameter `i` of a sheet: one spot's value, or the geometric mean of its spots.
fn value(r: &MeasuredSheet, i: usize) -> Option<f64> {
    match &r.summary {
        Some(summary) => summary.mean[i],
        None => r.sheet.spots.first().and_then(|s| s.values[i]),
    }
}

/// A 95 % interval of parameter `i` of the sheet's mean, if determined: ±1.96 standard
/// uncertainties of one spot's fit; for several spots, in log space from the spots' own
/// scatter over √n and their fits' mean relative variance (the calibration's share does
/// not average out).
fn interval(r: &MeasuredSheet, i: usize) -> Option<(f64, f64)> {
    let v = value(r, i)?;
    let spots = &r.sheet.spots;
    if spots.len() == 1 {
        let var = spots[0].covariance[i][i];
        return (var >= 0.0 && var.is_finite())
            .then(|| (v - 1.96 * var.sqrt(), v + 1.96 * var.sqrt()));
    }
    let fit_relative_var = spots
        .iter()
        .map(|s| s.values[i].map_or(f64::NAN, |x| s.covariance[i][i] / (x * x)))
        .sum::<f64>()
        / spots.len() as f64;
    let scatter = r
        .summary
        .as_ref()
        .and_then(|s| s.within_log_covariance)
        .map_or(0.0, |c| c[i][i] / spots.len() as f64);
    let half = 1.96 * (fit_relative_var + scatter).sqrt();
    half.is_finite()
        .then(|| (v * (-half).exp(), v * half.exp()))
}

fn cell(r: &MeasuredSheet, i: usize) -> String {
    match (value(r, i), interval(r, i)) {
        (Some(v), Some((lo, hi))) => format!("{v:.4} [{lo:.4}, {hi:.4}]"),
        (Some(v), None) => format!("{v:.4}"),
        _ => "not determined".to_string(),
    }
}

/// The report for a person.
pub fn to_table(
    a: &MeasuredSheet,
    b: &MeasuredSheet,
    e: &Evidence,
    population: &Population,
) -> String {
    let side = |name: &str, r: &MeasuredSheet| {
        let spots = r.sheet.spots.len();
        format!(
            "{name}  {}  sample {}  {spots} spot{}  class {}\n",
            r.path.display(),
            r.sample,
            if spots == 1 { "" } else { "s" },
            r.class_text()
        )
    };
    let mut s = side("A", a) + &side("B", b);
    s += &format!(
        "  {:<10} {:>34} {:>34}\n",
        "parameter", "A: value [95 % interval]", "B: value [95 % interval]"
    );
    for (i, label) in PARAM_LABELS.iter().enumerate() {
        s += &format!("  {label:<10} {:>34} {:>34}\n", cell(a, i), cell(b, i));
    }
    s += &format!(
        "  likelihood ratio (same stock : different stocks): LR = 10^{:.2}  (log10 LR = {:+.2})\n",
        e.log10_lr, e.log10_lr
    );
    s += &format!("  {}\n", e.verbal);
    let contributors: Vec<String> = e
        .contributions
        .iter()
        .map(|(p, v)| format!("{p} {v:+.2}"))
        .collect();
    if !contributors.is_empty() {
        s += &format!(
            "  each parameter alone, log10 LR: {} (correlated: they do not add up to the whole)\n",
            contributors.join(", ")
        );
    }
    for (p, why) in &e.left_out {
        s += &format!("  {p} left out: {why}\n");
    }
    match population.source {
        PopulationSource::Default => {
            s += &format!(
                "  population: the default ({} reference papers of Akao et al. Table 6, within-stock variation {} % per spot, an assumption: a library of your own stocks replaces it)\n",
                population.len(),
                100.0 * evidence::DEFAULT_WITHIN_RELATIVE_SD[0]
            )
        }
        PopulationSource::Sheets {
            stocks,
            sheets,
            spots,
        } => s += &format!("  population: {stocks} stocks, {sheets} sheets, {spots} spots\n"),
    }
    for (name, n, known) in [
        ("A", e.n_spots.0, e.within_known.0),
        ("B", e.n_spots.1, e.within_known.1),
    ] {
        if !known {
            s += &format!(
                "  {name}: {n} spot: its own within-sheet variation is unknown; the population's within-stock variation stands for it\n"
            );
        }
    }
    s += "  classes are shown for information: the evidence weighs the parameters, not the class boundaries\n";
    s
}

fn exit_of(e: &Evidence) -> u8 {
    match e.support {
        Support::SameStock => EXIT_SAME,
        Support::DifferentStocks => EXIT_DIFFERENT,
        Support::Inconclusive => EXIT_INCONCLUSIVE,
    }
}

/// Run `gonio compare`: exit 0 when the evidence supports the same stock, 1 different
/// stocks, 3 inconclusive, 2 for an error.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let read = |path: &PathBuf| read_measured(path);
    let (a, b) = match (read(&args.a), read(&args.b)) {
        (Ok(a), Ok(b)) => (a, b),
        (Err(e), _) | (_, Err(e)) => {
            eprintln!("error: {e}");
            return Ok(ExitCode::from(EXIT_ERROR));
        }
    };
    let (population, note) = match population_of(args.library.as_ref()) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("error: {e:#}");
            return Ok(ExitCode::from(EXIT_ERROR));
        }
    };
    let e = evidence::likelihood_ratio(&a.sheet, &b.sheet, &population);
    if args.json {
        let mut v = to_json(&a, &b, &e, &population);
        v["population"]["note"] = json!(note);
        println!("{v}");
    } else {
        print!("{}", to_table(&a, &b, &e, &population));
        if let Some(note) = note {
            println!("  population from {note}");
        }
    }
    Ok(ExitCode::from(exit_of(&e)))
}
