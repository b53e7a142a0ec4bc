//! The visiting-order planner: exact where it says so (against all permutations), its
//! lower bound below the optimum, Strategy 1 and Strategy 2 within 2 % of the best.

use firmware::config::InstrumentConfig;
use firmware::schedule::STRATEGY1_ORDER;
use host::session::order::{
    EXACT_MAX, Motion, OrderError, PlannedOrder, REFERENCE_HOME, device_us, plan, plan_with, study,
    study_markdown,
};
use proptest::prelude::*;
use protocol::schedules::{strategy1, strategy2};
use protocol::{Angle, Geometry};

/// Where the built-in Strategy 1 order ends (60°, 0°): where the refinements start.
fn after_strategy1() -> Geometry {
    *STRATEGY1_ORDER.last().unwrap()
}

fn sorted(list: &[Geometry]) -> Vec<Geometry> {
    let mut list = list.to_vec();
    list.sort();
    list
}

/// The least travel over all orders of `list`, by trying every permutation (Heap's).
fn brute_force_us(motion: &Motion, start: Geometry, list: &[Geometry]) -> u64 {
    let mut order = list.to_vec();
    let n = order.len();
    let mut best = motion.travel_us(start, &order);
    let mut c = vec![0; n];
    let mut i = 0;
    while i < n {
        if c[i] < i {
            if i % 2 == 0 {
                order.swap(0, i)
            } else {
                order.swap(c[i], i)
            }
            best = best.min(motion.travel_us(start, &order));
            c[i] += 1;
            i = 0;
        } else {
            c[i] = 0;
            i += 1;
        }
    }
    best
}

/// The promises every plan keeps, whatever the method.
fn check_consistent(motion: &Motion, start: Geometry, list: &[Geometry], planned: &PlannedOrder) {
    assert_eq!(
        sorted(&planned.order),
        sorted(list),
        "the order is a permutation of the list"
    );
    assert_eq!(planned.travel_us, motion.travel_us(start, &planned.order));
    assert_eq!(planned.given_order_travel_us, motion.travel_us(start, list));
    assert!(planned.lower_bound_us <= planned.travel_us);
    assert!(
        planned.travel_us <= planned.given_order_travel_us,
        "never worse than the order given"
    );
    if planned.exact {
        assert_eq!(planned.best_travel_us, planned.travel_us);
        assert_eq!(planned.lower_bound_us, planned.travel_us);
    }
}

/// Angles on a coarse 5° grid (so that lists repeat geometries) or anywhere in 0…85°.
fn angle() -> impl Strategy<Value = Angle> {
    prop_oneof![
        (0..=17i32).prop_map(|k| Angle::from_whole_deg(5 * k)),
        (0..=85 * 80).prop_map(Angle::from_ticks)
    ]
}

fn geometry() -> impl Strategy<Value = Geometry> {
    (angle(), angle()).prop_map(|(i, r)| Geometry::new(i, r))
}

fn start() -> impl Strategy<Value = Geometry> {
    prop_oneof![Just(REFERENCE_HOME), geometry()]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn small_lists_are_planned_exactly(start in start(), list in prop::collection::vec(geometry(), 0..=7)) {
        let motion = Motion::reference();
        let planned = plan(&motion, start, &list);
        check_consistent(&motion, start, &list, &planned);
        prop_assert!(planned.exact);
        prop_assert_eq!(planned.travel_us, brute_force_us(&motion, start, &list));
    }

    #[test]
    fn heuristic_and_bound_bracket_the_optimum(start in start(), list in prop::collection::vec(geometry(), 2..=12)) {
        let motion = Motion::reference();
        let optimum = plan(&motion, start, &list);
        prop_assert!(optimum.exact);
        let heuristic = plan_with(&motion, start, &list, 0);
        check_consistent(&motion, start, &list, &heuristic);
        prop_assert!(heuristic.lower_bound_us <= optimum.travel_us, "bound {} above the optimum {}", heuristic.lower_bound_us, optimum.travel_us);
        prop_assert!(heuristic.travel_us >= optimum.travel_us);
        prop_assert!(heuristic.travel_us as f64 <= 1.02 * optimum.travel_us as f64, "heuristic {} vs optimum {}", heuristic.travel_us, optimum.travel_us);
        if heuristic.exact {
            prop_assert_eq!(heuristic.travel_us, optimum.travel_us);
        }
    }
}

#[test]
fn strategy1_from_home_is_the_firmware_order() {
    let motion = Motion::reference();
    let list = strategy1(12).unwrap().to_vec();
    let planned = plan(&motion, REFERENCE_HOME, &list);
    check_consistent(&motion, REFERENCE_HOME, &list, &planned);
    assert!(planned.exact);
    assert_eq!(
        planned.travel_us,
        motion.travel_us(REFERENCE_HOME, &STRATEGY1_ORDER)
    );
    // 6.98 s against 13.60 s in the paper's order (firmware/src/schedule.rs).
    assert!(planned.travel_ratio_to_given() < 0.6);
}

#[test]
fn strategy2_lists_are_within_two_percent_of_the_bound() {
    let motion = Motion::reference();
    for start in [REFERENCE_HOME, after_strategy1()] {
        for delta in 1..=10u8 {
            let list = strategy2(delta).unwrap().to_vec();
            let planned = plan(&motion, start, &list);
            check_consistent(&motion, start, &list, &planned);
            let ratio = planned.travel_ratio_to_best();
            assert!(
                ratio <= 1.02,
                "δ = {delta}° from {start}: planned/best {ratio:.4}"
            );
            assert!(
                planned.travel_us < planned.given_order_travel_us,
                "δ = {delta}° from {start}: not faster than the paper's order"
            );
            assert!(planned.exact || list.len() > EXACT_MAX);
        }
    }
}

#[test]
fn the_study_covers_strategy1_and_every_refinement() {
    let motion = Motion::reference();
    let rows = study(&motion, 100);
    // Strategy 1, ten whole Strategy 2 lists, ten refinements.
    assert_eq!(rows.len(), 21);
    assert_eq!(rows[0].n, 12);
    assert!(rows[0].exact);
    assert_eq!(
        rows[1..11].iter().map(|r| r.n).max(),
        Some(strategy2(1).unwrap().len())
    );
    // The refinements add up, with Strategy 1, to everything Strategy 2 at δ = 1..10 holds.
    let mut all: Vec<Geometry> = strategy1(12).unwrap().to_vec();
    for delta in 1..=10 {
        all.extend(strategy2(delta).unwrap().iter().copied());
    }
    all.sort();
    all.dedup();
    assert_eq!(
        12 + rows[11..].iter().map(|r| r.n).sum::<usize>(),
        all.len()
    );
    for row in &rows {
        assert!(
            row.travel_ratio_best >= 1.0 && row.travel_ratio_best <= 1.02,
            "{}: {}",
            row.name,
            row.travel_ratio_best
        );
        assert!(
            row.travel_ratio_paper <= 1.0,
            "{}: {}",
            row.name,
            row.travel_ratio_paper
        );
        // Time at the geometries dilutes the travel's share of device time.
        assert!(row.device_ratio_best >= 1.0 && row.device_ratio_best <= row.travel_ratio_best);
        assert!(row.device_ratio_paper >= row.travel_ratio_paper && row.device_ratio_paper <= 1.0);
    }
    let table = study_markdown(&rows);
    assert_eq!(table.lines().count(), 2 + rows.len());
    assert!(table.contains("Strategy 1 (M = 12), from home | 12 |"));
}

#[test]
fn empty_and_single_lists() {
    let motion = Motion::reference();
    let empty = plan(&motion, REFERENCE_HOME, &[]);
    assert!(empty.order.is_empty() && empty.exact);
    assert_eq!(
        (
            empty.travel_us,
            empty.lower_bound_us,
            empty.given_order_travel_us
        ),
        (0, 0, 0)
    );
    assert_eq!(empty.travel_ratio_to_best(), 1.0);
    assert_eq!(empty.device_ratio_to_given(205_000), 1.0);

    let g = Geometry::from_whole_deg(45, 45);
    let one = plan(&motion, REFERENCE_HOME, &[g]);
    assert_eq!(one.order, [g]);
    assert!(one.exact);
    assert_eq!(one.travel_us, motion.move_us(REFERENCE_HOME, g));
    assert!(one.travel_us > 0);

    let here = plan(&motion, g, &[g, g, g]);
    assert_eq!(here.order, [g, g, g]);
    assert_eq!(here.travel_us, 0);
}

#[test]
fn repeated_geometries_are_visited_back_to_back() {
    let motion = Motion::reference();
    // Above EXACT_MAX distinct geometries, so the heuristic handles the repeats.
    let distinct = strategy2(5).unwrap().to_vec();
    let mut list = distinct.clone();
    list.extend(distinct.iter().rev().step_by(3).copied());
    let planned = plan(&motion, after_strategy1(), &list);
    check_consistent(&motion, after_strategy1(), &list, &planned);
    assert_eq!(
        planned.travel_us,
        plan(&motion, after_strategy1(), &distinct).travel_us
    );
    let mut seen = Vec::new();
    for pair in planned.order.chunk_by(|a, b| a == b) {
        assert!(!seen.contains(&pair[0]), "{} visited twice apart", pair[0]);
        seen.push(pair[0]);
    }
    assert_eq!(seen.len(), distinct.len());
}

#[test]
fn plans_are_deterministic() {
    let motion = Motion::reference();
    let list = strategy2(8).unwrap().to_vec();
    assert_eq!(
        plan(&motion, REFERENCE_HOME, &list),
        plan(&motion, REFERENCE_HOME, &list)
    );
}

#[test]
fn absurd_positions_do_not_panic() {
    let motion = Motion::reference();
    let far = [
        Geometry::new(Angle::from_ticks(i32::MAX), Angle::from_ticks(i32::MIN)),
        Geometry::new(Angle::from_ticks(i32::MIN), Angle::from_ticks(i32::MAX)),
        Geometry::from_whole_deg(20, 0),
    ];
    let planned = plan(
        &motion,
        Geometry::new(Angle::from_ticks(i32::MIN), Angle::ZERO),
        &far,
    );
    assert_eq!(planned.order.len(), 3);
    assert!(planned.travel_us > 0);
}

#[test]
fn motion_comes_from_the_device_info() {
    let info = InstrumentConfig::REFERENCE.device_info("");
    assert_eq!(Motion::from_info(&info), Ok(Motion::reference()));
    assert_eq!(Motion::reference().settle_us(), 100_000);
    assert_eq!(
        Motion::reference().per_geometry_us(100),
        100_000 + 100_000 + host::session::order::READING_OVERHEAD_US
    );
    let mut bad = info.clone();
    bad.max_speed_deg_per_s = f32::NAN;
    assert!(matches!(
        Motion::from_info(&bad),
        Err(OrderError::BadSpeed(_))
    ));
    let mut bad = info;
    bad.accel_deg_per_s2 = 0.0;
    assert_eq!(Motion::from_info(&bad), Err(OrderError::BadAccel(0.0)));
    // A slower instrument takes longer for the same move.
    let slow = Motion::new(30.0, 180.0, 100).unwrap();
    let (a, b) = (
        Geometry::from_whole_deg(20, 0),
        Geometry::from_whole_deg(60, 70),
    );
    assert!(slow.move_us(a, b) > Motion::reference().move_us(a, b));
    assert_eq!(
        Motion::reference().move_us(a, b),
        Motion::reference().move_us(b, a)
    );
}

#[test]
fn device_time_adds_the_time_at_each_geometry() {
    assert_eq!(device_us(1_000_000, 12, 205_000), 1_000_000 + 12 * 205_000);
    assert_eq!(device_us(u64::MAX, 2, u64::MAX), u64::MAX);
    let planned = PlannedOrder {
        order: vec![Geometry::from_whole_deg(20, 0); 4],
        travel_us: 1_100,
        best_travel_us: 1_100,
        lower_bound_us: 1_000,
        exact: false,
        given_order_travel_us: 2_000,
    };
    assert_eq!(planned.reference_us(), 1_000);
    assert!((planned.travel_ratio_to_best() - 1.1).abs() < 1e-12);
    assert!((planned.travel_ratio_to_given() - 0.55).abs() < 1e-12);
    assert!((planned.device_ratio_to_best(100) - 1_500.0 / 1_400.0).abs() < 1e-12);
    assert!((planned.device_ratio_to_given(100) - 1_500.0 / 2_400.0).abs() < 1e-12);
}

#[test]
fn lists_longer_than_a_device_holds_keep_their_order() {
    let motion = Motion::reference();
    let list: Vec<Geometry> = (0..=host::session::order::SEARCH_MAX as i32)
        .map(|k| Geometry::new(Angle::from_ticks(k * 17 % 6800), Angle::from_ticks(k * 23)))
        .collect();
    let planned = plan(&motion, REFERENCE_HOME, &list);
    assert_eq!(planned.order, list);
    assert!(!planned.exact);
    assert_eq!(planned.lower_bound_us, 0);
    assert_eq!(planned.travel_us, planned.given_order_travel_us);
}
