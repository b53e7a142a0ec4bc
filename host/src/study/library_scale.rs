//! Libraries of any size for the search-at-scale benchmark (issue 29) and its test:
//! synthetic `gonio-library/3` exchange files, and a questioned session of one of their
//! stocks.
//!
//! Stocks are drawn about the three kinds of paper the evidence tests use (glossy, rough,
//! between), each parameter 12 % (log-normal) about its kind; sheets 2 % about their
//! stock, spots 2 % about their sheet, each spot's fit 0.3 % (its covariance). These are
//! the spreads of a real library's stocks of one kind, so a search must tell neighbours
//! apart rather than three far-apart clusters.
use crate::output::library::ExchangeRecord;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use std::io::Write;
use std::path::{Path, PathBuf};

/// (σ [deg], ρs, ρd) of the three kinds stocks are drawn about.
const KINDS: [[f64; 3]; 3] = [[0.8, 57.8, 0.855], [21.7, 0.409, 0.414], [11.0, 0.9, 0.6]];
/// Relative spread of stocks about their kind.
const BETWEEN_STOCKS: f64 = 0.12;
/// Relative spread of a stock's sheets about it.
const BETWEEN_SHEETS: f64 = 0.02;
/// Relative spread of a sheet's spots about it.
const BETWEEN_SPOTS: f64 = 0.02;
/// Relative standard deviation of each spot's fit.
const FIT: f64 = 0.003;

/// The shape of a synthetic library.
#[derive(Clone, Copy, Debug)]
pub struct Shape {
    /// Stocks.
    pub stocks: usize,
    /// Sheets of each stock.
    pub sheets: usize,
    /// Spots of each sheet.
    pub spots: usize,
    /// The random seed: the same shape and seed give the same file.
    pub seed: u64,
}

/// A stock's name in a synthetic library.
pub fn stock_name(k: usize) -> String {
    format!("S{k:06}")
}

/// The mean (σ [deg], ρs, ρd) of stock `k` of a library of `shape`.
pub fn stock_mean(shape: &Shape, k: usize) -> [f64; 3] {
    // Each stock from its own stream, so a stock's mean does not depend on the size.
    let mut rng = rand_chacha::ChaCha12Rng::seed_from_u64(shape.seed ^ ((k as u64) << 20));
    let kind = KINDS[k % KINDS.len()];
    std::array::from_fn(|i| {
        let z: f64 = StandardNormal.sample(&mut rng);
        kind[i] * (BETWEEN_STOCKS * z).exp()
    })
}

fn spot_values(mean: &[f64; 3], rng: &mut rand_chacha::ChaCha12Rng, spread: f64) -> [f64; 3] {
    std::array::from_fn(|i| {
        let z: f64 = StandardNormal.sample(rng);
        mean[i] * (spread * z).exp()
    })
}

fn fit_covariance(values: &[f64; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|r| {
        std::array::from_fn(|c| {
            if r == c {
                (values[r] * FIT).powi(2)
            } else {
                0.0
            }
        })
    })
}

/// Write a synthetic library of `shape` to `out` as JSON Lines (one record a spot, in
/// export order); returns the records written.
pub fn write_library(shape: &Shape, out: &mut dyn Write) -> std::io::Result<usize> {
    let mut out = std::io::BufWriter::new(out);
    let mut rng = rand_chacha::ChaCha12Rng::seed_from_u64(shape.seed);
    let mut records = 0;
    for k in 0..shape.stocks {
        let mean = stock_mean(shape, k);
        // Sessions in SHA-256 order within the stock, as an export writes them.
        for sheet in 0..shape.sheets {
            let sheet_mean = spot_values(&mean, &mut rng, BETWEEN_SHEETS);
            for spot in 0..shape.spots {
                let values = spot_values(&sheet_mean, &mut rng, BETWEEN_SPOTS);
                let record = ExchangeRecord {
                    schema: crate::schema::LIBRARY_RECORD.to_string(),
                    stock: stock_name(k),
                    manufacturer: None,
                    stock_notes: None,
                    session_sha256: format!("{:064x}", k * shape.sheets + sheet + 1),
                    sample: format!("{}-{sheet}", stock_name(k)),
                    lot: None,
                    measured_at: None,
                    orientation: None,
                    side: None,
                    instrument_serial: "SIM-0001".to_string(),
                    session_path: format!("synthetic/{k}/{sheet}"),
                    added_at: "2026-12-04T00:00:00.000Z".to_string(),
                    spot,
                    spots: shape.spots,
                    sigma_deg: Some(values[0]),
                    rho_s: Some(values[1]),
                    rho_d: Some(values[2]),
                    covariance: fit_covariance(&values),
                };
                serde_json::to_writer(&mut out, &record)?;
                out.write_all(b"\n")?;
                records += 1;
            }
        }
    }
    out.flush()?;
    Ok(records)
}

/// A questioned session of stock `k` of a library of `shape` (a new sheet of it, drawn
/// with `seed`): the folder `dir/name`, holding its `session.json` as `gonio compare` and
/// `gonio library search` read it.
pub fn write_questioned(
    shape: &Shape,
    k: usize,
    seed: u64,
    dir: &Path,
    name: &str,
) -> std::io::Result<PathBuf> {
    let mut rng = rand_chacha::ChaCha12Rng::seed_from_u64(seed);
    let sheet_mean = spot_values(&stock_mean(shape, k), &mut rng, BETWEEN_SHEETS);
    let v = spot_values(&sheet_mean, &mut rng, BETWEEN_SPOTS);
    let mut covariance = vec![vec![0.0; 4]; 4];
    for i in 0..3 {
        covariance[i][i] = (v[i] * FIT).powi(2);
    }
    covariance[3][3] = 0.01f64.powi(2);
    let session = serde_json::json!({
        "sample": name,
        "device": {"name": "sim"},
        "readings": [],
        "result": {
            "sample": name,
            "sigma_deg": v[0], "rho_s": v[1], "rho_d": v[2], "eta": 1.5,
            "class": "G",
            "covariance": covariance,
            "nmae": 0.01,
        }
    });
    let folder = dir.join(name);
    std::fs::create_dir_all(&folder)?;
    std::fs::write(
        folder.join("session.json"),
        serde_json::to_vec_pretty(&session)?,
    )?;
    Ok(folder)
}
