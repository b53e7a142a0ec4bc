//! One whole fit (global seeding + local polish + identifiability checks) on 284, 40 and
//! 12 geometries of each Table 6 paper; the data are host/benches/data/bench-*.csv, the
//! same files host/benches/scipy_baseline.py times scipy on (docs/PERFORMANCE.md).
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use host::output::dataset;
use host::analysis::fit::{FitOptions, fit};
use std::hint::black_box;
use std::path::Path;

fn bench_fit(c: &mut Criterion) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/data");
    // The scipy baseline has no acceptance window; compare like with like.
    let options = FitOptions { acceptance_deg: None, ..FitOptions::default() };
    for size in ["284", "40", "12"] {
        let sets = dataset::read_file(&dir.join(format!("bench-{size}.csv"))).expect("bench data (see scipy_baseline.py --write-data)");
        let mut group = c.benchmark_group(format!("fit-{size}"));
        for set in &sets {
            group.bench_with_input(BenchmarkId::from_parameter(&set.sample), &set.observations, |b, obs| {
                b.iter(|| fit(black_box(obs), &options).expect("valid bench data"))
            });
        }
        group.finish();
    }
    // The default options (1° acceptance, modelled for the glossy papers) on the full grid.
    let sets = dataset::read_file(&dir.join("bench-284.csv")).expect("bench data");
    let mut group = c.benchmark_group("fit-284-acceptance");
    for set in sets.iter().filter(|s| s.sample == "G" || s.sample == "SG") {
        group.bench_with_input(BenchmarkId::from_parameter(&set.sample), &set.observations, |b, obs| {
            b.iter(|| fit(black_box(obs), &FitOptions::default()).expect("valid bench data"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_fit);
criterion_main!(benches);
