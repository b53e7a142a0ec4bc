//! `gonio flash [IMAGE]`: put firmware on the instrument through a debug probe.
//!
//! Checks the image first ([`host::instrument::firmware_image`]; `--check` stops there and
//! says what the image is), then through probe-rs: finds the probe, attaches to the
//! STM32F411, erases and programs with a progress bar, verifies, resets, and waits for the
//! instrument to come up on USB and answer the handshake with the version just written.
//!
//! Without IMAGE: the image built into this release (`GONIO_FIRMWARE_IMAGE` at build time,
//! README "Flashing the firmware"), if there is one.
use anyhow::{Context, bail};
use host::instrument::firmware_image::FirmwareImage;
use host::instrument::flash::{FlashOptions, FlashProgress, FlashStep, flash};
use host::instrument::probe::ProbeRsFlasher;
use host::instrument::serial::{SerialTransport, find_instrument};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

mod built_in {
    include!(concat!(env!("OUT_DIR"), "/firmware_image.rs"));
}

/// Arguments of `gonio flash`.
#[derive(clap::Args)]
#[command(
    after_help = "Exit codes: 0 the image is written, verified and the instrument answered (with --check: the image passed); 1 it was refused or flashing failed (the message says what and where); 2 a wrong command line."
)]
pub struct Args {
    /// The board's firmware ELF (firmware/board/target/thumbv7em-none-eabihf/release/gonio-board).
    /// Default: the image built into this release, if it has one.
    #[arg(value_name = "IMAGE")]
    pub image: Option<PathBuf>,
    /// Only check the image and say what it is; no probe is touched.
    #[arg(long)]
    pub check: bool,
    /// Which debug probe, when several are attached (the index the error lists).
    #[arg(long, value_name = "N")]
    pub probe: Option<usize>,
    /// How long to wait for the instrument on USB after the reset, seconds.
    #[arg(long, value_name = "S", default_value_t = 10.0)]
    pub wait_s: f64,
}

/// The image's name for messages and its bytes: the file, or the built-in one.
fn load(image: Option<&PathBuf>) -> anyhow::Result<(String, Vec<u8>)> {
    match image {
        Some(path) => {
            let bytes = std::fs::read(path)
                .with_context(|| format!("{}: cannot read the firmware image", path.display()))?;
            Ok((path.display().to_string(), bytes))
        }
        None => match built_in::BUILT_IN {
            Some((path, bytes)) => Ok((
                format!("the built-in firmware image ({path})"),
                bytes.to_vec(),
            )),
            None => bail!(
                "this gonio has no firmware image built in: pass the image to flash, `gonio flash IMAGE` (the board's ELF, firmware/board/target/thumbv7em-none-eabihf/release/gonio-board after `cargo build --release` in firmware/board)"
            ),
        },
    }
}

/// Run `gonio flash`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if !(args.wait_s.is_finite() && args.wait_s > 0.0 && args.wait_s <= 600.0) {
        bail!(
            "--wait-s must be a number of seconds above 0 and at most 600, not {}",
            args.wait_s
        );
    }
    let (name, bytes) = load(args.image.as_ref())?;
    let image = FirmwareImage::check(&bytes)
        .with_context(|| format!("{name}: not a firmware image gonio can flash"))?;
    print!("{name}:\n{}", image.describe());
    if args.check {
        println!("image checked: it can be flashed (nothing was written)");
        return Ok(ExitCode::from(crate::cli::exit::OK));
    }

    let options = FlashOptions {
        probe: args.probe,
        enumerate_timeout: Duration::from_secs_f64(args.wait_s),
        ..FlashOptions::default()
    };
    let mut bars = Bars::default();
    let mut find = || match find_instrument() {
        Ok(Some(path)) => SerialTransport::open(&path)
            .map(Some)
            .map_err(|e| format!("{path}: {e}")),
        Ok(None) => Ok(None),
        Err(e) => Err(e.to_string()),
    };
    let flashed = flash(
        &mut ProbeRsFlasher::new(),
        &image,
        options,
        &mut |p| bars.report(p),
        &mut find,
    );
    bars.finish();
    let flashed = flashed?;
    println!(
        "flashed through {}; the instrument is at {}: firmware {}, board {}, protocol version {}",
        flashed.probe,
        flashed.port,
        flashed.device.firmware_version,
        flashed.device.board,
        flashed.device.protocol_version
    );
    Ok(ExitCode::from(crate::cli::exit::OK))
}

/// One indicatif bar per step (erase, program, verify), as probe-rs reports them.
#[derive(Default)]
struct Bars {
    current: Option<(FlashStep, ProgressBar)>,
}

impl Bars {
    fn report(&mut self, progress: FlashProgress) {
        match progress {
            FlashProgress::Started { step, total_bytes } => {
                self.finish();
                let bar = ProgressBar::new(total_bytes.unwrap_or(0));
                bar.set_style(
                    ProgressStyle::with_template(
                        "{msg:>12} [{bar:40}] {bytes}/{total_bytes} ({bytes_per_sec})",
                    )
                    .expect("a valid template")
                    .progress_chars("=> "),
                );
                bar.set_message(step.name());
                self.current = Some((step, bar));
            }
            FlashProgress::Advanced { step, bytes } => {
                if let Some((current, bar)) = &self.current
                    && *current == step
                {
                    bar.inc(bytes);
                }
            }
            FlashProgress::Finished(step) | FlashProgress::Failed(step) => {
                if let Some((current, bar)) = &self.current
                    && *current == step
                {
                    if matches!(progress, FlashProgress::Failed(_)) {
                        bar.abandon_with_message(format!("{} FAILED", step.name()));
                    } else {
                        bar.finish();
                    }
                    self.current = None;
                }
            }
        }
    }

    fn finish(&mut self) {
        if let Some((_, bar)) = self.current.take() {
            bar.finish();
        }
    }
}
