//! `gonio report DIR…`: draw (again) the report a person reads, `report.html`, of finished
//! session or sheet folders ([`crate::output::report`]); `--pdf FILE` prints it with a
//! headless Chromium when one is installed.
use crate::output::report;
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `gonio report`.
#[derive(clap::Args)]
pub struct Args {
    /// Finished session or sheet folders.
    #[arg(required = true, value_name = "DIR")]
    pub dirs: Vec<PathBuf>,
    /// Also print the report to this PDF file (one folder only; needs chromium on PATH).
    #[arg(long, value_name = "FILE")]
    pub pdf: Option<PathBuf>,
}

/// A headless Chromium on PATH, if any.
pub fn find_chromium() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .flat_map(|name| std::env::split_paths(&path).map(move |d| d.join(name)))
        .find(|p| p.is_file())
}

/// Run Chromium headless on `page` with `extra` arguments (a fresh profile, no network
/// but the page, as root too).
pub fn headless(
    chromium: &Path,
    page: &Path,
    extra: &[String],
) -> anyhow::Result<std::process::Output> {
    let profile = tempfile::tempdir().context("a temporary profile for chromium")?;
    let url = format!(
        "file://{}",
        std::path::absolute(page)
            .context("the report's path")?
            .display()
    );
    let mut command = std::process::Command::new(chromium);
    command
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .args(extra)
        .arg(url)
        .stdin(std::process::Stdio::null());
    command
        .output()
        .with_context(|| format!("cannot run {}", chromium.display()))
}

/// Run `gonio report`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.pdf.is_some() && args.dirs.len() != 1 {
        bail!("--pdf prints one report: give one folder");
    }
    for dir in &args.dirs {
        let path = report::write_into(dir).map_err(anyhow::Error::msg)?;
        println!("{}", path.display());
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
