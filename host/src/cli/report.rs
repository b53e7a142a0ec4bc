//! `gonio report DIR…`: draw (again) the report a person reads, `report.html`, of finished
//! session or sheet folders ([`host::output::report`]); `--pdf FILE` prints it with a
//! headless Chromium when one is installed. A folder that does not verify is refused, or
//! with `--unverified` reported with a mark saying so (issue 30, D7).
use anyhow::{Context, bail};
use host::output::chromium::{find_chromium, headless};
use host::output::report;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio report`.
#[derive(clap::Args)]
pub struct Args {
    /// Finished session or sheet folders.
    #[arg(required = true, value_name = "DIR")]
    pub dirs: Vec<PathBuf>,
    /// Draw the report of a folder that does not verify (as `gonio verify` checks it) too,
    /// marked at its top "this folder does not verify" with every problem; without it such
    /// a folder is refused.
    #[arg(long)]
    pub unverified: bool,
    /// Also print the report to this PDF file (one folder only; needs chromium on PATH).
    #[arg(long, value_name = "FILE")]
    pub pdf: Option<PathBuf>,
}

/// Run `gonio report`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.pdf.is_some() && args.dirs.len() != 1 {
        bail!("--pdf prints one report: give one folder");
    }
    for dir in &args.dirs {
        let (path, problems) =
            report::write_verified(dir, args.unverified).map_err(anyhow::Error::msg)?;
        println!("{}", path.display());
        if !problems.is_empty() {
            eprintln!(
                "warning: {} does not verify; its report is marked so:",
                dir.display()
            );
            for p in &problems {
                eprintln!("  {p}");
            }
        }
        if let Some(pdf) = &args.pdf {
            let chromium = find_chromium().context("--pdf needs a Chromium on PATH (chromium, chromium-browser or google-chrome; on Debian: apt-get install chromium); report.html prints to PDF from any browser")?;
            let out = headless(
                &chromium,
                &path,
                &[
                    format!("--print-to-pdf={}", std::path::absolute(pdf)?.display()),
                    "--no-pdf-header-footer".into(),
                ],
            )?;
            if !pdf.is_file() {
                bail!(
                    "chromium did not write {}: {}",
                    pdf.display(),
                    String::from_utf8_lossy(&out.stderr)
                        .lines()
                        .last()
                        .unwrap_or("")
                );
            }
            println!("{}", pdf.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}
