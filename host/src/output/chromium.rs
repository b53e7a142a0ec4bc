//! A headless Chromium, when one is installed: `gonio report --pdf` prints the report
//! with it, and the tests read the report's DOM and screenshot through it.
use anyhow::Context;
use std::path::{Path, PathBuf};

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
