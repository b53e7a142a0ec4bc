//! `gonio compare A B`: how strongly do two measured sheets support "one paper stock" over
//! "different stocks of the relevant population"? The likelihood ratio of
//! [`host::analysis::evidence`], calibrated and bounded by the population's validation,
//! with every warning; A and B are session or sheet folders (or a `session.json`).
use super::exit;
use super::population::PopulationArgs;
use host::analysis::evidence;
use host::output::comparison::{Audit, Comparison};
use host::output::folder::sheet::read_measured;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio compare`.
#[derive(clap::Args)]
pub struct Args {
    /// Print one JSON object instead of the report.
    #[arg(long)]
    pub json: bool,
    /// Also write the report as a self-contained HTML page to FILE.
    #[arg(long, value_name = "FILE")]
    pub report: Option<PathBuf>,
    /// The key (gonio keys list) that signs the --report file (FILE.sig.json); default:
    /// the default or only key.
    #[arg(long, value_name = "NAME", requires = "report")]
    pub key: Option<String>,
    /// First sheet: a session or sheet folder, or a session.json.
    #[arg(value_name = "A")]
    pub a: PathBuf,
    /// Second sheet: a session or sheet folder, or a session.json.
    #[arg(value_name = "B")]
    pub b: PathBuf,
    /// Compare even when the two sheets were measured in different stated orientations
    /// (md/cd) or sides (felt/wire): refused without it, since the difference would be
    /// partly the placement's; with it the result carries `lay_differs` and a warning.
    #[arg(long)]
    pub allow_lay_mismatch: bool,
    #[command(flatten)]
    pub population: PopulationArgs,
}

/// Run `gonio compare`: exit 0 when the ratio was computed and nothing warns, 3 when it was
/// computed with warnings (read them), 1 for an error.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let a = read_measured(&args.a)?;
    let b = read_measured(&args.b)?;
    let known: Vec<String> = host::analysis::specimen::differences(
        host::output::comparison::lay(&a),
        host::output::comparison::lay(&b),
    )
    .into_iter()
    .filter(|d| d.is_known())
    .map(|d| d.to_string())
    .collect();
    if !known.is_empty() && !args.allow_lay_mismatch {
        anyhow::bail!(
            "not compared: {} ({} and {}). Measure both the same way, or give --allow-lay-mismatch to compare with a warning (docs/FORENSIC.md, \"Orientation and side\")",
            known.join("; "),
            args.a.display(),
            args.b.display()
        );
    }
    let population = args.population.load(&[])?;
    let e = evidence::weigh(&a.questioned(), &b.questioned(), &population.population);
    let document = Comparison::new(&a, &b, &e, &population, Audit::now());
    if let Some(path) = &args.report {
        let signer = super::keys::file_signer(args.key.as_deref(), "the report")?;
        std::fs::write(path, document.to_html())
            .map_err(|err| anyhow::anyhow!("{}: cannot write the report: {err}", path.display()))?;
        super::keys::sign_file(signer.as_ref(), path)?;
    }
    if args.json {
        println!("{}", document.to_json());
    } else {
        print!("{}", document.to_text());
    }
    Ok(ExitCode::from(if document.warned() {
        exit::FLAGGED
    } else {
        exit::OK
    }))
}
