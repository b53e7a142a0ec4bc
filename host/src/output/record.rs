//! The session folder as the record: every reading appended as it arrives, the
//! calibration, and progress on the terminal.
use crate::instrument::calibration::Calibration;
use crate::session::{MeasuredPoint, Progress, Recorder};
use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Appends every reading to the session folder as it arrives; shows progress.
pub struct FileRecorder {
    dir: PathBuf,
    readings_csv: File,
    points_jsonl: File,
    /// The progress bar.
    pub bar: ProgressBar,
    /// Every decision, in order.
    pub decisions: Vec<String>,
}

impl FileRecorder {
    /// Open (or create) the session folder `dir` for appending.
    pub fn open(dir: &Path) -> std::io::Result<FileRecorder> {
        std::fs::create_dir_all(dir)?;
        let append = |name: &str| OpenOptions::new().create(true).append(true).open(dir.join(name));
        let mut readings_csv = append("readings.csv")?;
        if readings_csv.metadata()?.len() == 0 {
            writeln!(readings_csv, "theta_i,theta_r,radiance_factor,std")?;
        }
        let bar = ProgressBar::new(0);
        bar.set_style(
            ProgressStyle::with_template("{msg:40} [{bar:30}] {pos}/{len} geometries, {prefix} device s left")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        Ok(FileRecorder { dir: dir.to_path_buf(), readings_csv, points_jsonl: append("points.jsonl")?, bar, decisions: Vec::new() })
    }
}

impl Recorder for FileRecorder {
    fn calibration(&mut self, calibration: &Calibration) -> std::io::Result<()> {
        std::fs::write(self.dir.join("calibration.json"), serde_json::to_vec_pretty(calibration)?)
    }

    fn point(&mut self, point: &MeasuredPoint) -> std::io::Result<()> {
        writeln!(self.points_jsonl, "{}", serde_json::to_string(point)?)?;
        self.points_jsonl.flush()?;
        if let (Some(r), Some(u)) = (point.radiance_factor, point.std) {
            writeln!(self.readings_csv, "{},{},{r},{u}", point.theta_i_deg, point.theta_r_deg)?;
            self.readings_csv.flush()?;
        }
        Ok(())
    }

    fn stage(&mut self, what: &str, planned: usize) {
        self.bar.set_message(what.to_string());
        self.bar.set_length(planned as u64);
        self.bar.set_position(0);
        self.bar.set_prefix("?");
    }

    fn progress(&mut self, progress: Progress) {
        self.bar.set_position(progress.done as u64);
        self.bar.set_prefix(format!("{:.1}", progress.remaining.as_secs_f64()));
    }

    fn decision(&mut self, text: &str) {
        self.bar.println(format!("  {text}"));
        self.decisions.push(text.to_string());
    }
}

/// Every reading recorded in `dir/points.jsonl`.
pub fn read_points(dir: &Path) -> anyhow::Result<Vec<MeasuredPoint>> {
    let path = dir.join("points.jsonl");
    let text = std::fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?;
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    let mut points = Vec::new();
    for (k, line) in lines.iter().enumerate() {
        match serde_json::from_str(line) {
            Ok(point) => points.push(point),
            // A crash can cut the last line short; anything else is damage worth a stop.
            Err(_) if k + 1 == lines.len() => {}
            Err(e) => bail!("{}:{}: {e}", path.display(), k + 1),
        }
    }
    Ok(points)
}

