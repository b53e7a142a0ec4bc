//! The schedule generators against the paper's tables (copied into tests/data from the
//! method's shared vectors).

use protocol::Geometry;
use protocol::schedules::{strategy1, strategy2};

fn parse_rows(csv: &str) -> Vec<Vec<i32>> {
    csv.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            l.split(',')
                .map(|f| f.trim().parse().expect("integer field"))
                .collect()
        })
        .collect()
}

#[test]
fn strategy1_m12_is_exactly_the_table() {
    let expected: Vec<Geometry> = parse_rows(include_str!("../data/strategy1-m12.csv"))
        .into_iter()
        .map(|r| Geometry::from_whole_deg(r[0], r[1]))
        .collect();
    assert_eq!(expected.len(), 12);
    assert_eq!(strategy1(12).unwrap().as_slice(), expected.as_slice());
}

#[test]
fn strategy2_is_exactly_the_table_for_every_delta() {
    let rows = parse_rows(include_str!("../data/strategy2.csv"));
    let expected_sizes = [91, 51, 42, 34, 27, 26, 26, 26, 26, 19];
    for delta in 1..=10u8 {
        let expected: Vec<Geometry> = rows
            .iter()
            .filter(|r| r[0] == i32::from(delta))
            .map(|r| Geometry::from_whole_deg(r[1], r[2]))
            .collect();
        assert_eq!(
            expected.len(),
            expected_sizes[usize::from(delta) - 1],
            "table size at δ = {delta}"
        );
        assert_eq!(
            strategy2(delta).unwrap().as_slice(),
            expected.as_slice(),
            "δ = {delta}"
        );
    }
}
