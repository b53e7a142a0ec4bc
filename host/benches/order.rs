//! Planning the visiting order (host::session::order): Strategy 1 from home (exact), the largest
//! exact case (15 geometries), Strategy 2 lists whose bound does not meet the order found
//! (26, the whole search budget) and the longest Strategy 2 list (91).
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use host::session::order::{Motion, REFERENCE_HOME, plan};
use protocol::Geometry;
use protocol::schedules::{strategy1, strategy2};
use std::hint::black_box;

fn bench_plan(c: &mut Criterion) {
    let motion = Motion::reference();
    let after_strategy1 = Geometry::from_whole_deg(60, 0);
    let s2 = |delta| strategy2(delta).expect("δ in 1..=10").to_vec();
    let cases: [(&str, Geometry, Vec<Geometry>); 5] = [
        (
            "strategy1-12-home",
            REFERENCE_HOME,
            strategy1(12).expect("M = 12").to_vec(),
        ),
        ("exact-15-home", REFERENCE_HOME, s2(1)[..15].to_vec()),
        ("strategy2-d8-26-home", REFERENCE_HOME, s2(8)),
        ("strategy2-d1-91-home", REFERENCE_HOME, s2(1)),
        ("strategy2-d1-91-after-s1", after_strategy1, s2(1)),
    ];
    let mut group = c.benchmark_group("plan");
    for (name, start, list) in &cases {
        group.bench_with_input(BenchmarkId::from_parameter(name), list, |b, list| {
            b.iter(|| plan(&motion, *start, black_box(list)))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_plan);
criterion_main!(benches);
