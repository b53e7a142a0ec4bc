//! `gonio characterize`: measure the instrument with the lab's black glass and white tile,
//! and write its profile (`instrument.json`) and a characterization report, which
//! `gonio measure --instrument FILE` then uses instead of the declared values.
use anyhow::Context;
use host::instrument::link::{Client, RetryPolicy, Transport};
use host::instrument::profile::{self, BlackGlass, Standards, WhiteTile};
use host::instrument::sim::SimOptions;
use host::session::characterize::{self, Options};
use host::session::operator::{Operator, PromptOperator, SimulatedOperator};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio characterize`.
#[derive(clap::Args)]
pub struct Args {
    /// The instrument's serial port (default: the one instrument attached).
    #[arg(long, value_name = "PATH", conflicts_with = "sim")]
    pub port: Option<String>,
    /// Characterize the simulated instrument (its true response, arm zero and noise with
    /// --physics drawn and the options below; the standards are placed by themselves).
    #[arg(long)]
    pub sim: bool,
    /// Where the profile is written.
    #[arg(long, value_name = "FILE", default_value = "instrument.json")]
    pub out: PathBuf,
    /// Where the report is written [default: the profile's name with .html].
    #[arg(long, value_name = "FILE")]
    pub report: Option<PathBuf>,
    /// Also put the profile where sessions on this instrument find it without
    /// --instrument ($XDG_DATA_HOME/gonio/instruments/SERIAL.json).
    #[arg(long)]
    pub install: bool,
    /// The black glass standard's identification (its certificate).
    #[arg(long, value_name = "ID", default_value = "black glass")]
    pub black_glass_id: String,
    /// Its refractive index (the ISO 2813 primary standard's is 1.567).
    #[arg(long, value_name = "N", default_value_t = 1.567)]
    pub black_glass_index: f64,
    /// Its certified gloss units, ANGLE=GU pairs (e.g. 20=93.4,60=96.1,85=99.5).
    #[arg(long, value_name = "LIST", default_value = "")]
    pub black_glass_gu: String,
    /// The white tile's identification.
    #[arg(long, value_name = "ID", default_value = "white tile")]
    pub tile_id: String,
    /// The white tile's certified radiance factor.
    #[arg(long, value_name = "R", default_value_t = 0.99)]
    pub tile_radiance_factor: f64,
    /// Times the arms are homed again to measure the homing's repeatability.
    #[arg(long, value_name = "N", default_value_t = 3)]
    pub rehomes: usize,
    /// How long the lamp's drift is followed on the white tile, seconds of device time.
    #[arg(long, value_name = "S", default_value_t = 20.0)]
    pub lamp_s: f64,
    /// Print the profile as JSON on standard output.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub sim_options: SimOptions,
}

fn certified_gu(list: &str) -> anyhow::Result<Vec<(f64, f64)>> {
    list.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|item| {
            let parsed = item.split_once('=').and_then(|(a, g)| {
                Some((a.trim().parse::<f64>().ok()?, g.trim().parse::<f64>().ok()?))
            });
            match parsed {
                Some((a, g)) if (0.0..90.0).contains(&a) && g.is_finite() && g > 0.0 && g <= 200.0 => {
                    Ok((a, g))
                }
                _ => anyhow::bail!(
                    "--black-glass-gu: '{item}' is not ANGLE=GU (an angle in [0, 90) degrees and gloss units in (0, 200])"
                ),
            }
        })
        .collect()
}

/// Run `gonio characterize`: exit 0 with the profile written.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(
        args.black_glass_index.is_finite() && (1.3..=2.0).contains(&args.black_glass_index),
        "--black-glass-index must be a refractive index in [1.3, 2.0], not {}",
        args.black_glass_index
    );
    anyhow::ensure!(
        args.tile_radiance_factor.is_finite()
            && args.tile_radiance_factor > 0.0
            && args.tile_radiance_factor <= 1.2,
        "--tile-radiance-factor must be in (0, 1.2], not {}",
        args.tile_radiance_factor
    );
    anyhow::ensure!(
        args.lamp_s.is_finite() && (3.0..=3600.0).contains(&args.lamp_s),
        "--lamp-s must be between 3 and 3600 seconds, not {}",
        args.lamp_s
    );
    anyhow::ensure!(
        (1..=20).contains(&args.rehomes),
        "--rehomes must be between 1 and 20, not {}",
        args.rehomes
    );
    let options = Options {
        standards: Standards {
            black_glass: BlackGlass {
                id: args.black_glass_id.clone(),
                refractive_index: args.black_glass_index,
                certified_gu: certified_gu(&args.black_glass_gu)?,
            },
            white_tile: WhiteTile {
                id: args.tile_id.clone(),
                radiance_factor: args.tile_radiance_factor,
            },
        },
        rehomes: args.rehomes,
        lamp_s: args.lamp_s,
    };
    let result = if args.sim {
        let instrument = args
            .sim_options
            .clone()
            .with_seed(Some(1))
            .instrument("black-glass")?;
        measure(
            Client::new(instrument, RetryPolicy::default()),
            &mut SimulatedOperator,
            &options,
        )?
    } else {
        let transport = host::measure::open_port(args.port.as_deref())?;
        measure(
            Client::new(transport, RetryPolicy::default()),
            &mut PromptOperator::new(),
            &options,
        )?
    };
    let report = args
        .report
        .clone()
        .unwrap_or_else(|| args.out.with_extension("html"));
    let sha = host::output::characterization::write(&result, &args.out, &report)?;
    let p = &result.profile;
    eprintln!(
        "instrument {}: response FWHM {:.3} ± {:.3}° (declared {}° top-hat), arm zero {} ; {:.0} s of device time",
        p.serial_number,
        p.response.fwhm_deg.value,
        p.response.fwhm_deg.u,
        p.response.declared_acceptance_deg,
        p.incidences
            .iter()
            .map(|i| format!("{:+.3}° at {}°", i.arm_zero_deg.value, i.theta_i_deg))
            .collect::<Vec<_>>()
            .join(", "),
        p.device_seconds
    );
    eprintln!(
        "profile {} (SHA-256 {}), report {}",
        args.out.display(),
        &sha[..16],
        report.display()
    );
    if args.install {
        let place = profile::default_path(&p.serial_number).with_context(|| {
            format!(
                "no place for the profile of instrument '{}': neither XDG_DATA_HOME nor HOME is set, or the serial is not a file name",
                p.serial_number
            )
        })?;
        if let Some(dir) = place.parent() {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
        }
        std::fs::copy(&args.out, &place)
            .with_context(|| format!("cannot copy the profile to {}", place.display()))?;
        eprintln!("installed as {}", place.display());
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(p)?);
    }
    Ok(ExitCode::SUCCESS)
}

fn measure<T: Transport>(
    mut client: Client<T>,
    operator: &mut dyn Operator,
    options: &Options,
) -> anyhow::Result<characterize::Characterization> {
    let info = client.hello().context("no handshake with the instrument")?;
    eprintln!(
        "characterizing {} (firmware {}): black glass sweeps at {:?}°, {} re-homings, the white tile and the lamp for {} s",
        info.serial_number,
        info.firmware_version,
        characterize::INCIDENCES_DEG,
        options.rehomes,
        options.lamp_s
    );
    characterize::run(&mut client, &info, operator, options)
        .context("the characterization did not finish")
}
