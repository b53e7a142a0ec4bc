//! Sweeps on the fake hardware (the device end to end, polled every millisecond like the
//! board) and the auto-ranging and binning on their own, over random sweeps, scenes and
//! timings:
//! - the bins tile the sweep exactly (the first starts at `from`, each where the one before
//!   ended, the last ends at `to`), as many as planned, in order, each closed by the first
//!   block whose end reached its nominal end;
//! - a bin's angles are where the detector arm truly was at its blocks' ends, and its mean
//!   is the mean of its blocks;
//! - after a range switch the blocks within the new range's settling time are never kept
//!   (whenever the switch lands within the block after the one that asked for it), no
//!   blanked block decides a switch, and a bin never mixes ranges;
//! - a saturated bin on the least sensitive range is flagged and its mean not clipped by
//!   the firmware; on a more sensitive range the clipped block is dropped;
//! - every refusal comes before anything moves, with the limit as its detail;
//! - an abort, a lost heartbeat or a driver fault ends the sweep with no bin after it and no
//!   `SweepDone`, the arms ramped to rest within the path, the lamp off on a fault.

use crate::common;

use common::Bench;
use firmware::config::InstrumentConfig;
use firmware::hardware::Sample;
use firmware::sweep::{AutoRange, Binner, BlockClass, check_sweep, min_bin_ticks, sweep_profile};
use firmware::testing::Scene;
use proptest::prelude::*;
use protocol::*;

const CONFIG: InstrumentConfig = InstrumentConfig::REFERENCE;
const BLOCK_US: u64 = CONFIG.detector_block_us as u64;

/// A diffuse level and a Gaussian peak in θr (counts on the most sensitive range).
#[derive(Clone, Copy, Debug)]
struct Peak {
    base: f32,
    height: f32,
    center_deg: f32,
    width_deg: f32,
}

impl Scene for Peak {
    fn signal_counts(&self, _theta_i_deg: f32, theta_r_deg: f32) -> f32 {
        let x = (theta_r_deg - self.center_deg) / self.width_deg;
        self.base + self.height * (-0.5 * x * x).exp()
    }
}

/// A level below `edge_deg` and another above it.
#[derive(Clone, Copy, Debug)]
struct Step {
    below: f32,
    above: f32,
    edge_deg: f32,
}

impl Scene for Step {
    fn signal_counts(&self, _theta_i_deg: f32, theta_r_deg: f32) -> f32 {
        if theta_r_deg < self.edge_deg {
            self.below
        } else {
            self.above
        }
    }
}

fn homed<S: Scene>(scene: S) -> Bench<S> {
    let mut bench = Bench::seeing(scene);
    bench.home();
    assert_eq!(bench.ask(Command::SetLamp { on: true }), Ok(Reply::Ack));
    bench
}

fn sweep(
    theta_i: i32,
    from: i32,
    to: i32,
    speed_mdeg_per_s: u32,
    bin_ticks: u16,
    range: Option<u8>,
) -> Sweep {
    Sweep {
        sweep_id: 5,
        theta_i: Angle::from_ticks(theta_i),
        from: Angle::from_ticks(from),
        to: Angle::from_ticks(to),
        speed_mdeg_per_s,
        bin_ticks,
        range,
        target: Target::Sample,
    }
}

fn bins_of<S: Scene>(bench: &Bench<S>, from: usize, sweep_id: u16) -> Vec<SweepBin> {
    bench
        .messages_since(from)
        .iter()
        .filter_map(|m| match m {
            DeviceMessage::SweepBin(bin) if bin.sweep_id == sweep_id => Some(*bin),
            _ => None,
        })
        .collect()
}

fn done_of<S: Scene>(bench: &Bench<S>, from: usize, sweep_id: u16) -> Option<u16> {
    bench.messages_since(from).iter().find_map(|m| match m {
        DeviceMessage::SweepDone { sweep_id: id, bins } if *id == sweep_id => Some(*bins),
        _ => None,
    })
}

/// Run a sweep to its end: the plan, the bins, the SweepDone's count.
fn run<S: Scene>(bench: &mut Bench<S>, sweep: Sweep) -> (SweepPlan, Vec<SweepBin>, u16) {
    let from = bench.messages.len();
    let Ok(Reply::Sweep(plan)) = bench.ask(Command::Sweep(sweep)) else {
        panic!("sweep refused: {sweep:?}")
    };
    let started_us = bench.now_us;
    while done_of(bench, from, sweep.sweep_id).is_none() {
        assert!(
            bench.now_us - started_us < u64::from(plan.duration_ms) * 1000 + 1_000_000,
            "no SweepDone: {sweep:?}"
        );
        bench.tick();
    }
    // Planned to the block: the plan is what the host waits for.
    let took_us = bench.now_us - started_us;
    assert!(
        took_us <= u64::from(plan.duration_ms) * 1000 + 10 * BLOCK_US,
        "took {took_us} µs, planned {plan:?}"
    );
    (
        plan,
        bins_of(bench, from, sweep.sweep_id),
        done_of(bench, from, sweep.sweep_id).unwrap(),
    )
}

/// Bin `k`'s nominal end, ticks.
fn nominal_end(sweep: &Sweep, bins: u16, k: u16) -> i32 {
    let (from, to) = (sweep.from.ticks(), sweep.to.ticks());
    if k + 1 == bins {
        to
    } else {
        from + (to - from).signum() * (i32::from(k) + 1) * i32::from(sweep.bin_ticks)
    }
}

/// A sweep the device accepts: θi, from and to in range and clear of the guard, a speed, a
/// bin length from the shortest up to the whole travel (within the bin count); at most
/// 2.5 s of travel at the top speed, so that a case runs in a few ms.
fn valid_sweep() -> impl Strategy<Value = Sweep> {
    (
        0i32..=6800,
        0i32..=6800,
        any::<bool>(),
        100u32..=60_000,
        0.0f64..1.0,
        0.0f64..1.0,
        proptest::option::of(0u8..3),
    )
        .prop_filter_map(
            "a valid sweep",
            |(theta_i, from, up, speed, length, bin_at, range)| {
                let room = if up { 6800 - from } else { from };
                let longest = (f64::from(speed) * 0.08 * 2.5) as i32;
                // Short sweeps often: a triangular profile, a few bins.
                let travel = (f64::from(room.min(longest)) * length.powi(2)) as i32;
                let to = if up { from + travel } else { from - travel };
                let shortest = min_bin_ticks(&CONFIG, speed)
                    .max((travel as u32).div_ceil(u32::from(MAX_SWEEP_BINS)));
                if (travel as u32) < shortest || theta_i + from.min(to) < 800 {
                    return None;
                }
                // Mostly short bins, the interesting ones.
                let bin = shortest + ((travel as u32 - shortest) as f64 * bin_at.powi(4)) as u32;
                Some(sweep(theta_i, from, to, speed, bin as u16, range))
            },
        )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// The bins tile the sweep, are as many as planned, each closed by the first block that
    /// reached its nominal end, at the arm's true angles; on a forced range with no noise
    /// each mean is exactly its blocks' mean.
    #[test]
    fn bins_tile_the_sweep_exactly_at_the_true_angles(sweep in valid_sweep(), height in 0.0f32..600_000.0, center in 0.0f32..85.0) {
        let scene = Peak { base: 3_000.0, height, center_deg: center, width_deg: 1.6 };
        let mut bench = homed(scene);
        bench.hw_mut().noise_counts = 0.0;
        let (plan, bins, done) = run(&mut bench, sweep);
        let expected = check_sweep(&CONFIG, &sweep).unwrap();
        prop_assert_eq!(plan.bins, expected);
        prop_assert_eq!(done, expected);
        prop_assert_eq!(bins.len(), usize::from(expected));
        let direction = (sweep.to.ticks() - sweep.from.ticks()).signum();
        let hw = bench.hw();
        let mut start = sweep.from;
        let mut previous_us = None;
        for (k, bin) in bins.iter().enumerate() {
            let k = k as u16;
            prop_assert_eq!(bin.index, k);
            prop_assert_eq!(bin.start, start, "bin {} starts where the one before ended", k);
            start = bin.end;
            // Closed by its last block, whose end reached the nominal end...
            let nominal = nominal_end(&sweep, expected, k);
            prop_assert!(direction * (bin.end.ticks() - nominal) >= 0, "bin {} ends short: {:?}", k, bin);
            // ...which is where the arm truly was then, and the block before had not.
            let t = bin.device_time_us;
            prop_assert_eq!(hw.true_geometry_at(t).theta_r, bin.end);
            prop_assert_eq!(hw.true_geometry_at(t).theta_i, sweep.theta_i);
            prop_assert!(direction * (hw.true_geometry_at(t - BLOCK_US).theta_r.ticks() - nominal) < 0, "bin {} closed late", k);
            // One bin per block at most.
            prop_assert!(previous_us.is_none_or(|p| t >= p + BLOCK_US));
            if let (Some(range), Some(p)) = (sweep.range, previous_us) {
                // Forced: every block kept, the mean exactly theirs.
                let gain = CONFIG.detector_ranges[usize::from(range)].relative_gain;
                let values: Vec<f64> = (1..=(t - p) / BLOCK_US).map(|j| {
                    let at = hw.true_geometry_at(p + j * BLOCK_US);
                    let counts = hw.dark_counts + scene.signal_counts(at.theta_i.deg() as f32, at.theta_r.deg() as f32) * gain;
                    f64::from(counts.clamp(0.0, 65_535.0) as u32)
                }).collect();
                prop_assert_eq!(usize::from(bin.blocks), values.len());
                let mean = values.iter().sum::<f64>() / values.len() as f64;
                prop_assert!((f64::from(bin.mean_counts) - mean).abs() <= 1e-4 * mean.max(1.0), "bin {}: {} vs {}", k, bin.mean_counts, mean);
                prop_assert_eq!(bin.range, range);
                prop_assert_eq!(bin.flags & !SweepBin::SATURATED, 0);
                prop_assert_eq!(bin.is_saturated(), values.iter().any(|&v| v >= 0.98 * 65_535.0));
            }
            previous_us = Some(t);
        }
        prop_assert_eq!(start, sweep.to, "the last bin ends at `to`");
        prop_assert_eq!(hw.true_geometry(), Geometry::new(sweep.theta_i, sweep.to));
        prop_assert_eq!(hw.profiles_over_limits, 0);
        prop_assert_eq!(bench.stopped_reasons(), Vec::<ErrorCode>::new());
    }

    /// Every sweep the checks refuse is refused before anything moves or switches, with the
    /// right code; every other one is accepted.
    #[test]
    fn refusals_come_before_any_motion(
        theta_i in -100i32..7000, from in -100i32..7000, to in -100i32..7000,
        speed in prop_oneof![0u32..200_000, 50u32..150, 59_900u32..60_100],
        bin in prop_oneof![0u16..20, any::<u16>()],
        range in proptest::option::of(0u8..5),
        sweep_id in prop_oneof![Just(0u16), 1u16..10],
    ) {
        let mut bench = homed(Peak { base: 3_000.0, height: 0.0, center_deg: 0.0, width_deg: 1.0 });
        let command = Sweep { sweep_id, ..sweep(theta_i, from, to, speed, bin, range) };
        let started = bench.hw().profiles_started;
        let switches = bench.hw().range_log.len();
        let expected = model_check(&command);
        let answer = bench.ask(Command::Sweep(command));
        match expected {
            Err(error) => {
                prop_assert_eq!(answer, Err(error));
                bench.run_ms(50);
                prop_assert_eq!(bench.hw().profiles_started, started, "nothing moved");
                prop_assert_eq!(bench.hw().range_log.len(), switches, "nothing switched");
                prop_assert!(bench.device.is_idle());
            }
            Ok(bins) => {
                prop_assert!(matches!(answer, Ok(Reply::Sweep(SweepPlan { bins: b, .. })) if b == bins), "{:?}", answer);
                prop_assert_eq!(bench.ask(Command::Abort), Ok(Reply::Ack));
            }
        }
    }

    /// A stop at any moment (abort, heartbeat loss, driver fault) ends the sweep: no bin
    /// after it, no SweepDone, the arms at rest within the path, the outputs safe.
    #[test]
    fn a_stop_ends_the_sweep_with_the_outputs_safe(
        sweep in valid_sweep(),
        after_ms in 0u64..2_500,
        how in 0u8..3,
    ) {
        let mut bench = homed(Peak { base: 3_000.0, height: 100_000.0, center_deg: 40.0, width_deg: 1.6 });
        let from = bench.messages.len();
        let Ok(Reply::Sweep(plan)) = bench.ask(Command::Sweep(sweep)) else { panic!("refused") };
        let stop_ms = after_ms.min(u64::from(plan.duration_ms).saturating_sub(5));
        bench.run_ms(stop_ms);
        prop_assume!(done_of(&bench, from, sweep.sweep_id).is_none());
        let before = bins_of(&bench, from, sweep.sweep_id).len();
        match how {
            0 => prop_assert_eq!(bench.ask(Command::Abort), Ok(Reply::Ack)),
            1 => {
                bench.heartbeat_every_ms = None;
                let limit = bench.now_us + 3_000_000;
                while bench.stopped_reasons().is_empty() && bench.now_us < limit {
                    bench.tick();
                }
                prop_assert_eq!(bench.stopped_reasons(), vec![ErrorCode::HeartbeatLost]);
                bench.heartbeat_every_ms = Some(500);
            }
            _ => {
                bench.hw_mut().arms[1].driver_fault = true;
                bench.tick();
                prop_assert_eq!(bench.stopped_reasons(), vec![ErrorCode::HardwareFault]);
            }
        }
        let stopped_at = bench.messages.len();
        // Done before the stop came (a silent host takes 2 s to lose): nothing to stop.
        prop_assume!(done_of(&bench, from, sweep.sweep_id).is_none());
        bench.wait_at_rest();
        bench.run_ms(500);
        prop_assert!(done_of(&bench, from, sweep.sweep_id).is_none(), "no SweepDone after a stop");
        prop_assert!(bins_of(&bench, stopped_at, sweep.sweep_id).is_empty(), "no bin after the stop");
        let bins = bins_of(&bench, from, sweep.sweep_id);
        prop_assert!(bins.len() >= before);
        let mut start = sweep.from;
        for (k, bin) in bins.iter().enumerate() {
            prop_assert_eq!((usize::from(bin.index), bin.start), (k, start));
            start = bin.end;
        }
        let hw = bench.hw();
        prop_assert!(!hw.arms.iter().any(|a| a.step_timer_running()));
        let (lo, hi) = (sweep.from.min(sweep.to).ticks(), sweep.from.max(sweep.to).ticks());
        let r = hw.true_geometry().theta_r.ticks();
        // On the path, or on the way to its start (a stop during the approach).
        prop_assert!(hw.true_geometry().theta_i.ticks() + r >= CONFIG.collision_min_sum.ticks());
        if !bins.is_empty() {
            prop_assert!(r >= lo - 1 && r <= hi + 1, "θr {} off the path {}..{}", r, lo, hi);
        }
        prop_assert_eq!(hw.lamp_on(), how == 0, "a fault puts the lamp off; an abort keeps it");
        let status = bench.status();
        prop_assert!(status.state != DeviceState::Sweeping && status.schedule.is_none());
    }
}

/// The refusals as `protocol::Sweep` documents them, in their order (busy, drivers and
/// homing are the device's own and pass here).
fn model_check(sweep: &Sweep) -> Result<u16, DeviceError> {
    let invalid = |detail: i64| {
        Err(DeviceError::with_detail(
            ErrorCode::InvalidArgument,
            detail as i32,
        ))
    };
    if sweep.sweep_id == 0 {
        return invalid(0);
    }
    if sweep.range.is_some_and(|r| r >= 3) {
        return invalid(3);
    }
    if !(0..=6800).contains(&sweep.theta_i.ticks()) {
        return Err(DeviceError::with_detail(ErrorCode::OutOfRange, 0));
    }
    if !(0..=6800).contains(&sweep.from.ticks()) || !(0..=6800).contains(&sweep.to.ticks()) {
        return Err(DeviceError::with_detail(ErrorCode::OutOfRange, 1));
    }
    if sweep.theta_i.ticks() + sweep.from.ticks().min(sweep.to.ticks()) < 800 {
        return Err(DeviceError::new(ErrorCode::CollisionGuard));
    }
    if sweep.speed_mdeg_per_s < 100 {
        return invalid(100);
    }
    if sweep.speed_mdeg_per_s > 60_000 {
        return invalid(60_000);
    }
    // One block (1 ms) at the speed, in ticks (80 a degree), rounded up, plus one.
    let shortest = (u64::from(sweep.speed_mdeg_per_s) * 80).div_ceil(1_000_000) as u32 + 1;
    if u32::from(sweep.bin_ticks) < shortest {
        return invalid(i64::from(shortest));
    }
    let travel = (sweep.to.ticks() - sweep.from.ticks()).unsigned_abs();
    if u32::from(sweep.bin_ticks) > travel {
        return invalid(i64::from(travel));
    }
    let bins = travel.div_ceil(u32::from(sweep.bin_ticks));
    if bins > 4096 {
        return invalid(4096);
    }
    Ok(bins as u16)
}

#[test]
fn the_device_refuses_a_sweep_while_busy_unhomed_or_faulted() {
    let mut bench = Bench::seeing(Peak {
        base: 3_000.0,
        height: 0.0,
        center_deg: 0.0,
        width_deg: 1.0,
    });
    let ok = sweep(2400, 800, 4000, 60_000, 8, None);
    assert_eq!(
        bench.ask(Command::Sweep(ok)),
        Err(DeviceError::new(ErrorCode::NotHomed))
    );
    assert_eq!(bench.hw().profiles_started, 0);
    bench.home();
    // Refused while DIAG is high (before the poll that takes the stop and disables it).
    bench.hw_mut().arms[0].driver_fault = true;
    let started = bench.hw().profiles_started;
    assert_eq!(
        bench.ask(Command::Sweep(ok)),
        Err(DeviceError::with_detail(ErrorCode::HardwareFault, 0))
    );
    bench.hw_mut().arms[0].driver_fault = false;
    bench.home();
    let seq = bench.send(Command::MoveTo(Geometry::from_whole_deg(50, 50)));
    let started_move = bench.hw().profiles_started;
    assert_eq!(
        bench.ask(Command::Sweep(ok)),
        Err(DeviceError::new(ErrorCode::Busy))
    );
    assert!(
        started_move >= started && bench.hw().profiles_started == started_move,
        "the busy refusal moved nothing"
    );
    assert_eq!(bench.wait_reply(seq), Ok(Reply::Ack));
    // And one running sweep at a time.
    assert!(matches!(bench.ask(Command::Sweep(ok)), Ok(Reply::Sweep(_))));
    assert_eq!(
        bench.ask(Command::Sweep(Sweep { sweep_id: 6, ..ok })),
        Err(DeviceError::new(ErrorCode::Busy))
    );
    let status = bench.status();
    assert_eq!(
        (status.state, status.schedule.map(|s| s.0)),
        (DeviceState::Sweeping, Some(5))
    );
    // The lamp cannot go on mid-sweep (it would spoil the bins); off always can.
    assert_eq!(
        bench.ask(Command::SetLamp { on: true }),
        Err(DeviceError::new(ErrorCode::Busy))
    );
}

#[test]
fn the_reference_limits() {
    // 60 °/s for 1 ms is 4.8 ticks: 5, and one for the count's quantisation.
    assert_eq!(min_bin_ticks(&CONFIG, 60_000), 6);
    // The board's 1.024 ms blocks: 4.9 ticks, also 6.
    let board = InstrumentConfig {
        detector_block_us: 1024,
        ..CONFIG
    };
    assert_eq!(min_bin_ticks(&board, 60_000), 6);
    assert_eq!(min_bin_ticks(&CONFIG, 100), 2);
    // A 70° sweep at 60 °/s: 70/60 s plus one ramp time (1/3 s).
    let profile = sweep_profile(&CONFIG, 0, 5600, 60_000);
    assert!((profile.duration_s() - (70.0 / 60.0 + 1.0 / 3.0)).abs() < 1e-4);
}

/// A forward and a backward sweep across an edge between two flat levels, noise off, the
/// amplifier's settling made visible (the fake hardware reads a marker value in every block
/// that overlaps a settling): every bin reads one of the two true levels exactly, so no
/// marker ever went into one; the switches are the scene's, so no marker decided one.
#[test]
fn no_block_within_a_settling_goes_into_a_bin_or_decides_a_switch() {
    // 30 % of full scale on range 0 below 40°; 5 times that above (range 1, 15 %).
    let scene = Step {
        below: 0.3 * 65_535.0,
        above: 1.5 * 65_535.0,
        edge_deg: 40.0,
    };
    for (from, to, switches) in [(20.0, 60.0, [0u8, 1]), (60.0, 20.0, [1, 0])] {
        let mut bench = homed(scene);
        bench.hw_mut().noise_counts = 0.0;
        let marker = 1_000;
        bench.hw_mut().settling_counts = Some(marker);
        let dark = bench.hw().dark_counts;
        let level = |counts: f32| (dark + counts) as u32 as f32;
        let (r0_low, r1_high) = (level(scene.below), level(scene.above * 0.1));
        bench.hw_mut().range_log.clear();
        let command = sweep(
            3200,
            (from * 80.0) as i32,
            (to * 80.0) as i32,
            60_000,
            8,
            None,
        );
        let (_, bins, _) = run(&mut bench, command);
        let ranges: Vec<u8> = bench.hw().range_log.iter().map(|&(_, r)| r).collect();
        // Selected at the start (the last range: 0), ranged on the way from the home
        // position (87.5°: above the edge) to `from`, then the edge; no switch that the
        // marker (1.5 % of full scale) would have asked for.
        let expected_log: &[u8] = if switches[0] == 0 {
            &[0, 1, 0, 1]
        } else {
            &[0, 1, 0]
        };
        assert_eq!(ranges, expected_log);
        let r1_low = level(scene.below * 0.1);
        let mut blanked = 0;
        for bin in &bins {
            if bin.is_empty() {
                blanked += 1;
                continue;
            }
            let (n, sum) = (
                f64::from(bin.blocks),
                f64::from(bin.mean_counts) * f64::from(bin.blocks),
            );
            if bin.range == 0 {
                assert_eq!(bin.mean_counts, r0_low, "{bin:?}");
            } else {
                // Blocks of the two true levels on range 1 and nothing else: a whole number of
                // the lower one.
                let (hi, lo) = (f64::from(r1_high), f64::from(r1_low));
                let low_blocks = (n * hi - sum) / (hi - lo);
                assert!(
                    (low_blocks - low_blocks.round()).abs() < 1e-3
                        && (0.0..=n).contains(&low_blocks.round()),
                    "{bin:?}"
                );
            }
            blanked += usize::from(bin.is_blanked());
        }
        // The edge costs a few bins, not the sweep.
        assert!((1..=6).contains(&blanked), "{blanked} bins blanked");
    }
}

/// A scene that saturates even the least sensitive range: flagged, the mean kept.
#[test]
fn a_bin_saturated_on_the_least_sensitive_range_is_flagged() {
    let mut bench = homed(Peak {
        base: 3_000.0,
        height: 1e9,
        center_deg: 45.0,
        width_deg: 1.0,
    });
    let (_, bins, _) = run(&mut bench, sweep(3600, 3200, 4000, 30_000, 8, None));
    let saturated: Vec<&SweepBin> = bins.iter().filter(|b| b.is_saturated()).collect();
    assert!(!saturated.is_empty());
    for bin in &saturated {
        assert_eq!(bin.range, 2, "{bin:?}");
        assert!(bin.blocks > 0, "kept, not dropped: {bin:?}");
    }
    // Where every block saturates, the bin reads what the ADC gave: full scale, a lower bound.
    assert!(
        saturated
            .iter()
            .any(|b| b.mean_counts == 65_535.0 && b.std_counts == 0.0),
        "{saturated:?}"
    );
    // The same on a forced sensitive range: flagged there.
    let mut bench = homed(Peak {
        base: 3_000.0,
        height: 1e5,
        center_deg: 45.0,
        width_deg: 1.0,
    });
    let (_, bins, _) = run(&mut bench, sweep(3600, 3200, 4000, 30_000, 8, Some(0)));
    assert!(bins.iter().any(|b| b.is_saturated() && b.range == 0));
    assert!(bins.iter().all(|b| b.range == 0 && !b.is_blanked()));
}

/// A sweep with a dead detector stops instead of waiting for ever.
#[test]
fn a_dead_detector_stops_the_sweep() {
    let mut bench = homed(Peak {
        base: 3_000.0,
        height: 0.0,
        center_deg: 0.0,
        width_deg: 1.0,
    });
    assert!(matches!(
        bench.ask(Command::Sweep(sweep(2400, 800, 4000, 60_000, 8, None))),
        Ok(Reply::Sweep(_))
    ));
    bench.run_ms(300);
    bench.hw_mut().detector_dead = true;
    bench.run_ms(100);
    assert_eq!(bench.stopped_reasons(), [ErrorCode::HardwareFault]);
    bench.wait_at_rest();
    assert!(!bench.hw().lamp_on());
}

/// A sweep already at its start still settles and finds its range there.
#[test]
fn a_sweep_from_where_the_arms_are_finds_the_range_at_rest() {
    let scene = Peak {
        base: 1.5 * 65_535.0,
        height: 0.0,
        center_deg: 0.0,
        width_deg: 1.0,
    };
    let mut bench = homed(scene);
    assert_eq!(
        bench.ask(Command::MoveTo(Geometry::from_whole_deg(30, 20))),
        Ok(Reply::Ack)
    );
    bench.hw_mut().range_log.clear();
    let (plan, bins, _) = run(&mut bench, sweep(2400, 1600, 2400, 60_000, 8, None));
    assert!(plan.duration_ms >= u32::from(CONFIG.settle_ms));
    assert!(
        bins.iter()
            .all(|b| b.range == 1 && !b.is_blanked() && !b.is_empty()),
        "{bins:?}"
    );
}

// The auto-ranging and the binning on their own, on a model of the board's timing: block j
// ends at j·P; a switch decided on block j reaches the amplifier δ after that (the device
// polls asynchronously to the blocks: 0 ≤ δ < P). The amplifier is unsettled from then for
// the new range's settle_us; a block overlapping that is poisoned.

#[derive(Clone, Debug)]
struct BlockRecord {
    poisoned: bool,
    class: BlockClass,
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn switches_blank_for_the_settling_time_and_bins_never_mix_ranges(
        levels in proptest::collection::vec((1.0f32..2e7, 1usize..40), 1..12),
        lags in proptest::collection::vec(0.0f64..1.0, 16),
        block_us in prop_oneof![Just(1000u32), Just(1024u32)],
        bin_blocks in 1usize..8,
    ) {
        let config = InstrumentConfig { detector_block_us: block_us, ..CONFIG };
        let p = f64::from(block_us);
        // The signal (counts on range 0) of each block: flat levels of random lengths.
        let signal: Vec<f32> = levels.iter().flat_map(|&(level, n)| std::iter::repeat_n(level, n)).collect();
        let blocks = signal.len();
        // Bins of `bin_blocks` blocks' worth of steps (the arm moves one step a block... 10).
        let step = 10;
        let total = (blocks * step) as i32;
        let sweep = Sweep { sweep_id: 1, theta_i: Angle::from_ticks(3000), from: Angle::from_ticks(0), to: Angle::from_ticks(total),
            speed_mdeg_per_s: 1000, bin_ticks: (bin_blocks * step) as u16, range: None, target: Target::Sample };
        let bins = (total as u32).div_ceil((bin_blocks * step) as u32) as u16;
        let mut ranging = AutoRange::new(&config, 0, false);
        let mut binner = Binner::new(&sweep, bins);
        let mut amplifier_range = ranging.take_switch().unwrap();
        // Unsettled until (µs); the start's own settling is over before the sweep.
        let mut unsettled_until = f64::NEG_INFINITY;
        let mut switch_at: Option<f64> = None;
        let mut records: Vec<BlockRecord> = Vec::new();
        let mut in_bin: Vec<usize> = Vec::new();
        let mut emitted = Vec::new();
        for j in 0..blocks {
            let (begin, end) = (j as f64 * p, (j + 1) as f64 * p);
            // The switch decided at the end of the last block reaches the amplifier now.
            if let Some(at) = switch_at.take() {
                let settle = f64::from(config.detector_ranges[usize::from(amplifier_range)].settle_us);
                unsettled_until = at + settle;
            }
            let range = config.detector_ranges[usize::from(amplifier_range)];
            let poisoned = begin < unsettled_until;
            let counts = if poisoned { 0 } else { (signal[j] * range.relative_gain).min(65_535.0) as u32 };
            let class = ranging.block(&config, counts);
            if let BlockClass::Kept { range: r, .. } = class {
                prop_assert!(!poisoned, "block {} kept within a settling", j);
                prop_assert_eq!(r, amplifier_range, "kept on the range it was taken on");
            }
            let sample = Sample { counts, detector_steps: ((j + 1) * step) as i32 };
            records.push(BlockRecord { poisoned, class });
            in_bin.push(j);
            if let Some(bin) = binner.block(sample, class, ranging.range(), end as u64) {
                // A bin's kept blocks: all on its range; its mean theirs.
                let kept: Vec<(u8, u32)> = in_bin.iter().filter_map(|&i| match records[i].class {
                    BlockClass::Kept { range, .. } => Some((range, if records[i].poisoned { 0 } else { (signal[i] * config.detector_ranges[usize::from(range)].relative_gain).min(65_535.0) as u32 })),
                    BlockClass::Dropped => None,
                }).collect();
                let first = kept.first().map(|&(r, _)| r);
                let same: Vec<u32> = kept.iter().filter(|&&(r, _)| Some(r) == first).map(|&(_, c)| c).collect();
                prop_assert_eq!(usize::from(bin.blocks), same.len());
                prop_assert_eq!(bin.is_blanked(), same.len() < in_bin.len());
                prop_assert_eq!(bin.is_empty(), same.is_empty());
                if let Some(r) = first {
                    prop_assert_eq!(bin.range, r);
                    let mean = same.iter().map(|&c| f64::from(c)).sum::<f64>() / same.len() as f64;
                    prop_assert!((f64::from(bin.mean_counts) - mean).abs() <= 1e-3 * mean.max(1.0));
                }
                in_bin.clear();
                emitted.push(bin);
            }
            if let Some(next) = ranging.take_switch() {
                // At the board: up to a block after this block's end, at a random lag.
                switch_at = Some(end + lags[j % lags.len()] * p);
                amplifier_range = next;
            }
        }
        prop_assert_eq!(emitted.len(), usize::from(bins));
        // Nothing kept a block that overlapped a settling, and after every switch the blocks
        // dropped cover at least the settling time.
        let kept_poisoned = records.iter().filter(|r| r.poisoned && matches!(r.class, BlockClass::Kept { .. })).count();
        prop_assert_eq!(kept_poisoned, 0);
    }
}
