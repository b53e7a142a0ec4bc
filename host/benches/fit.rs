//! One whole fit (global seeding, local polish, identifiability checks, arm-offset test,
//! goodness of fit, covariance) on 284, 40 and 12 geometries of each Table 6 paper; the
//! data are host/benches/data/bench-*.csv, the same files host/benches/scipy_baseline.py
//! times scipy on (docs/PERFORMANCE.md).
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use host::analysis::fit::{FitOptions, Observation, SharedError, fit, fit_with_shared};
use host::output::dataset;
use std::hint::black_box;
use std::path::Path;

fn bench_fit(c: &mut Criterion) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/data");
    // The scipy baseline has no acceptance window; compare like with like.
    let options = FitOptions {
        acceptance_deg: None,
        ..FitOptions::default()
    };
    for size in ["284", "40", "12"] {
        let sets = dataset::read_file(&dir.join(format!("bench-{size}.csv")))
            .expect("bench data (see scipy_baseline.py --write-data)");
        let mut group = c.benchmark_group(format!("fit-{size}"));
        for set in &sets {
            group.bench_with_input(
                BenchmarkId::from_parameter(&set.sample),
                &set.observations,
                |b, obs| b.iter(|| fit(black_box(obs), &options).expect("valid bench data")),
            );
        }
        group.finish();
    }
    // The default options (the whole model over the 1° window, at every σ) on the full grid.
    let sets = dataset::read_file(&dir.join("bench-284.csv")).expect("bench data");
    let mut group = c.benchmark_group("fit-284-acceptance");
    for set in &sets {
        group.bench_with_input(
            BenchmarkId::from_parameter(&set.sample),
            &set.observations,
            |b, obs| {
                b.iter(|| fit(black_box(obs), &FitOptions::default()).expect("valid bench data"))
            },
        );
    }
    group.finish();
    // With per-reading uncertainties (1 % + 0.003) and five shared errors (the white reading
    // at each θi, 0.5 %; the tile, 1 %): generalised least squares through Woodbury.
    let mut group = c.benchmark_group("fit-284-shared");
    for set in sets
        .iter()
        .filter(|s| ["G", "PPC"].contains(&s.sample.as_str()))
    {
        let obs: Vec<Observation> = set
            .observations
            .iter()
            .map(|o| Observation {
                std: Some((0.01 * o.radiance_factor).hypot(0.003)),
                ..*o
            })
            .collect();
        let mut shared: Vec<SharedError> = [20.0, 30.0, 45.0, 60.0]
            .iter()
            .map(|&ti| SharedError {
                name: format!("white θi = {ti}°"),
                sensitivity: obs
                    .iter()
                    .map(|o| {
                        if o.theta_i_deg == ti {
                            0.005 * o.radiance_factor
                        } else {
                            0.0
                        }
                    })
                    .collect(),
                additive: Vec::new(),
            })
            .collect();
        shared.push(SharedError {
            name: "tile certificate".into(),
            sensitivity: obs.iter().map(|o| 0.01 * o.radiance_factor).collect(),
            additive: Vec::new(),
        });
        group.bench_with_input(
            BenchmarkId::from_parameter(&set.sample),
            &(obs, shared),
            |b, (obs, shared)| {
                b.iter(|| {
                    fit_with_shared(black_box(obs), shared, &FitOptions::default())
                        .expect("valid bench data")
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench_fit);
criterion_main!(benches);
