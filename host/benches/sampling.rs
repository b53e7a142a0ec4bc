//! The measured δ (host::analysis::sampling::measured_delta_deg) on data sets where every
//! reading has its own θi, the worst case of the quadratic version it replaced (kept here,
//! as `quadratic`, to show the difference): n = 10³ … 10⁶ readings.
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use host::analysis::sampling::measured_delta_deg;
use std::hint::black_box;

/// The replaced version: one pass over every reading per incidence angle, O(n · distinct θi).
fn quadratic(geometries: &[(f64, f64)]) -> Option<f64> {
    let mut incidences: Vec<f64> = geometries.iter().map(|g| g.0).collect();
    incidences.sort_by(f64::total_cmp);
    incidences.dedup();
    incidences
        .iter()
        .filter_map(|&ti| {
            let (mut below, mut above) = (None::<f64>, None::<f64>);
            for &(t, tr) in geometries {
                if t != ti {
                    continue;
                }
                if tr < ti {
                    below = Some(below.map_or(tr, |b| b.max(tr)));
                } else if tr > ti {
                    above = Some(above.map_or(tr, |a| a.min(tr)));
                }
            }
            match (below, above) {
                (Some(b), Some(a)) => Some((ti - b).max(a - ti)),
                (Some(b), None) => Some(ti - b),
                (None, Some(a)) => Some(a - ti),
                (None, None) => None,
            }
        })
        .min_by(f64::total_cmp)
}

/// n readings at n distinct θi in a scrambled order, each with a θr beside the specular.
fn distinct_incidences(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let k = i * 7919 % n;
            let ti = 5.0 + 80.0 * k as f64 / n as f64;
            (
                ti,
                if k.is_multiple_of(2) {
                    ti - 1.0
                } else {
                    ti + 2.0
                },
            )
        })
        .collect()
}

fn bench_delta(c: &mut Criterion) {
    let mut group = c.benchmark_group("measured_delta");
    group.sample_size(10);
    for n in [1_000, 10_000, 100_000, 1_000_000] {
        let set = distinct_incidences(n);
        group.bench_with_input(BenchmarkId::new("n-log-n", n), &set, |b, set| {
            b.iter(|| measured_delta_deg(black_box(set)))
        });
        // 10⁵ readings already take the quadratic version minutes.
        if n <= 10_000 {
            group.bench_with_input(BenchmarkId::new("quadratic", n), &set, |b, set| {
                b.iter(|| quadratic(black_box(set)))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_delta);
criterion_main!(benches);
