//! The ADC decimation and the sample ring on a model of the board's DMA: conversions at a
//! fixed rate into a circular buffer, the decimation serviced at random times (sometimes
//! late), the ADC overrunning now and then, the ring drained at random times.
//!
//! Properties over random timings:
//! - every sample is the sum of one whole block of consecutive conversions (never mixed
//!   from two laps of the buffer), blocks in order;
//! - every gap in the blocks (conversions lost to a late service, an ADC overrun or a full
//!   ring) is reported by a drain between the samples on either side of it;
//! - timely services and drains report nothing and lose nothing.

use firmware::sampling::*;
use proptest::prelude::*;
use std::cell::RefCell;

/// The board's: 96 MHz / 250 k conversions per second.
const CYCLES_PER_CONVERSION: u64 = 384;
const BLOCK: u64 = OVERSAMPLE as u64;
/// What one raw load and add of the decimation loop takes (opt-level "z", by the
/// disassembly: ~6 cycles), doubled: the DMA writes on meanwhile (and the test shows that
/// it cannot overtake the summing).
const CYCLES_PER_READ: u64 = 12;
/// The same with the summing preempted: the board sums outside its critical section, so
/// the step interrupts (P0, ≲ 500 cycles each) run in the middle of it. A block's sum is
/// ~3,000 cycles, in which each arm steps at most once at full speed (a step every
/// 20,000 cycles): ≲ 4,000 cycles a block, 16 a read. 100 a read (25,600 a block) is six
/// times that.
const PREEMPTED_CYCLES_PER_READ: u64 = 100;

/// A conversion's value: 12 bits that depend on its index, so a mixed block sums wrong.
fn value(n: u64) -> u16 {
    let mut x = n.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    x ^= x >> 29;
    (x & 0x0fff) as u16
}

/// The ADC and its DMA: conversion `base + k` completes at `start + (k + 1) · cpc` into
/// slot `k % RAW_LEN`.
struct Dma {
    start: u64,
    base: u64,
}

impl Dma {
    fn completed(&self, now: u64) -> u64 {
        (now - self.start) / CYCLES_PER_CONVERSION
    }

    fn write_slot(&self, now: u64) -> usize {
        (self.completed(now) % RAW_LEN as u64) as usize
    }

    /// The index of the conversion in `slot` at `now` (None: not written yet).
    fn in_slot(&self, slot: usize, now: u64) -> Option<u64> {
        let done = self.completed(now);
        if done == 0 {
            return None;
        }
        let last = done - 1;
        let back = (last + RAW_LEN as u64 - slot as u64) % RAW_LEN as u64;
        last.checked_sub(back).map(|k| self.base + k)
    }
}

#[derive(Clone, Copy, Debug)]
struct Step {
    /// Cycles until the next decimation service.
    gap: u64,
    /// The ADC overran just before it.
    overrun: bool,
    /// The device drains the ring after it.
    drain: bool,
}

struct Outcome {
    /// The first conversion of each block delivered, with the drain that delivered it.
    blocks: Vec<(u64, usize)>,
    /// The drains that reported a loss.
    loss_drains: Vec<usize>,
    losses: usize,
}

fn simulate(steps: &[Step]) -> Outcome {
    simulate_with(steps, CYCLES_PER_READ)
}

/// [`simulate`] with each raw read taking `cycles_per_read`.
fn simulate_with(steps: &[Step], cycles_per_read: u64) -> Outcome {
    let mut now: u64 = 1_000;
    let mut dma = Dma {
        start: now,
        base: 0,
    };
    let mut decimator = Decimator::new(CYCLES_PER_CONVERSION as u32, now as u32);
    let mut ring = SampleRing::new();
    // The conversions each sample summed, in the order the decimator read them.
    let reads: RefCell<Vec<u64>> = RefCell::new(Vec::new());
    // The first conversion of each block in the ring, and the service that found it.
    let mut sample_blocks: std::collections::VecDeque<(u64, usize)> = Default::default();
    let mut outcome = Outcome {
        blocks: Vec::new(),
        loss_drains: Vec::new(),
        losses: 0,
    };
    for (drain_index, step) in steps.iter().enumerate() {
        now += step.gap;
        let before = ring.len();
        let restart = decimator.service(
            dma.write_slot(now),
            step.overrun,
            now as u32,
            |slot| {
                // The DMA goes on while the decimation sums: each read a few cycles later.
                let at = now + reads.borrow().len() as u64 * cycles_per_read;
                let n = dma.in_slot(slot, at).expect("read a slot never written");
                reads.borrow_mut().push(n);
                value(n)
            },
            // The detector arm's count: the service's number, to check the stamps.
            drain_index as i32,
            &mut ring,
        );
        // Check the reads: whole blocks of consecutive conversions, aligned to the lap.
        let read: Vec<u64> = reads.borrow_mut().drain(..).collect();
        assert_eq!(read.len() % OVERSAMPLE, 0);
        let pushed = read.len() / OVERSAMPLE;
        for block in read.chunks(OVERSAMPLE) {
            let first = block[0];
            assert_eq!((first - dma.base) % BLOCK, 0, "block not aligned: {first}");
            for (k, &n) in block.iter().enumerate() {
                assert_eq!(
                    n,
                    first + k as u64,
                    "a block mixed from two laps: {block:?}"
                );
            }
            sample_blocks.push_back((first, drain_index));
        }
        // What did not fit in the ring was dropped (and must be reported).
        let kept = ring.len() - before;
        for _ in kept..pushed {
            sample_blocks.pop_back();
        }
        if restart {
            // The board restarts the conversions and the DMA from slot 0.
            dma = Dma {
                start: now,
                base: dma.base + dma.completed(now) + 10 * BLOCK,
            };
            decimator.restart(now as u32);
        }
        if step.drain {
            let loss = ring.take_loss();
            let mut out = [firmware::Sample {
                counts: 0,
                detector_steps: 0,
            }; RING_LEN];
            let n = ring.pop_into(&mut out);
            for &sample in &out[..n] {
                let (first, service) = sample_blocks.pop_front().expect("a sample for every block");
                let expected: u32 = (first..first + BLOCK)
                    .map(|k| u32::from(value(k)))
                    .sum::<u32>()
                    >> 4;
                assert_eq!(sample.counts, expected);
                assert_eq!(
                    sample.detector_steps, service as i32,
                    "stamped by the service that found it"
                );
                outcome.blocks.push((first, drain_index));
            }
            if loss.is_some() {
                outcome.loss_drains.push(drain_index);
                outcome.losses += 1;
            }
        }
    }
    outcome
}

/// Every gap between consecutive blocks is reported by a drain from the one that
/// delivered the block before the gap to the one that delivered the block after it.
fn check_gaps(outcome: &Outcome) -> Result<(), TestCaseError> {
    for pair in outcome.blocks.windows(2) {
        let [(a, drain_a), (b, drain_b)] = [pair[0], pair[1]];
        prop_assert!(b > a, "blocks out of order");
        if b != a + BLOCK {
            prop_assert!(
                outcome
                    .loss_drains
                    .iter()
                    .any(|&d| d >= drain_a && d <= drain_b),
                "conversions {}..{} lost without a report (drains {}..={})",
                a + BLOCK,
                b,
                drain_a,
                drain_b
            );
        }
    }
    Ok(())
}

fn step(
    max_gap_cycles: u64,
    overrun_weight: u32,
    skip_drain_weight: u32,
) -> impl Strategy<Value = Step> {
    (
        1u64..max_gap_cycles,
        prop::bool::weighted(f64::from(overrun_weight) / 1000.0),
        prop::bool::weighted(1.0 - f64::from(skip_drain_weight) / 1000.0),
    )
        .prop_map(|(gap, overrun, drain)| Step {
            gap,
            overrun,
            drain,
        })
}

/// 1 ms services, some a little late, some very late (the decimation held up).
fn jittery_step() -> impl Strategy<Value = Step> {
    prop_oneof![
        8 => (96_000u64..116_000).prop_map(|gap| Step { gap, overrun: false, drain: true }),
        1 => step(600_000, 30, 200),
        1 => step(3_000_000, 30, 500),
        // Near the lap, where the summing itself races the DMA.
        2 => ((RAW_LEN as u64 - 300) * CYCLES_PER_CONVERSION..RAW_LEN as u64 * CYCLES_PER_CONVERSION)
            .prop_map(|gap| Step { gap, overrun: false, drain: true }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn every_loss_is_reported_and_no_block_is_mixed(steps in proptest::collection::vec(jittery_step(), 1..400)) {
        let outcome = simulate(&steps);
        check_gaps(&outcome)?;
    }

    #[test]
    fn preempted_summing_mixes_no_block(steps in proptest::collection::vec(jittery_step(), 1..400)) {
        let outcome = simulate_with(&steps, PREEMPTED_CYCLES_PER_READ);
        check_gaps(&outcome)?;
    }

    #[test]
    fn timely_services_lose_nothing(steps in proptest::collection::vec(
        // Up to 1.5 ms apart (the 1 kHz interrupt held up by half a period), drained each time.
        (1u64..(CYCLES_PER_CONVERSION * 384)).prop_map(|gap| Step { gap, overrun: false, drain: true }), 1..400)) {
        let outcome = simulate(&steps);
        prop_assert_eq!(outcome.losses, 0);
        // From the first block on, all of them.
        for (k, &(first, _)) in outcome.blocks.iter().enumerate() {
            prop_assert_eq!(first, k as u64 * BLOCK);
        }
        let elapsed: u64 = steps.iter().map(|s| s.gap).sum();
        let whole_blocks = elapsed / CYCLES_PER_CONVERSION / BLOCK;
        prop_assert!(outcome.blocks.len() as u64 + 1 >= whole_blocks, "{} of {} blocks", outcome.blocks.len(), whole_blocks);
    }
}

#[test]
fn a_late_service_is_a_lap_an_adc_overrun_a_restart_a_full_ring_a_loss_in_a_reading() {
    let on_time = Step {
        gap: 96_000,
        overrun: false,
        drain: true,
    };
    // 3 ms late: the DMA has come round to unread data.
    let outcome = simulate(&[
        on_time,
        on_time,
        Step {
            gap: 3 * 96_000 + 50_000,
            ..on_time
        },
        on_time,
        on_time,
        on_time,
    ]);
    assert_eq!(outcome.loss_drains, [2]);
    let mut ring = SampleRing::new();
    let mut decimator = Decimator::new(384, 0);
    assert!(
        decimator.service(0, true, 1000, |_| 0, 0, &mut ring),
        "an ADC overrun asks for a restart"
    );
    // A range change empties the ring, never of an overrun: both the drain and the
    // device's fault check hear of it, each once.
    ring.clear();
    assert_eq!(ring.take_loss(), Some(SampleLoss::AdcOverrun));
    assert_eq!(ring.take_loss(), None, "reported once");
    assert_eq!(ring.take_fault(), Some(SampleLoss::AdcOverrun));
    assert_eq!(ring.take_fault(), None);
    // A full ring between readings is of samples nobody wanted: a range change forgets it;
    // within a reading the drain reports it; it is never an ADC fault.
    for _ in 0..RING_LEN + 1 {
        ring.push(7, 0);
    }
    assert_eq!(ring.take_fault(), None);
    ring.clear();
    assert_eq!(ring.take_loss(), None);
    for _ in 0..RING_LEN + 1 {
        ring.push(7, 0);
    }
    assert_eq!(ring.take_loss(), Some(SampleLoss::RingFull));
    assert_eq!(
        [
            SampleLoss::AdcOverrun,
            SampleLoss::DmaLapped,
            SampleLoss::RingFull
        ]
        .map(SampleLoss::detail),
        [1, 2, 3]
    );
}

/// A sink that records what the decimation hands it, in order.
#[derive(Default)]
struct Recorder {
    events: Vec<Result<(u16, i32), SampleLoss>>,
}

impl SampleSink for Recorder {
    fn push(&mut self, sample: u16, detector_steps: i32) {
        self.events.push(Ok((sample, detector_steps)));
    }

    fn mark_loss(&mut self, loss: SampleLoss) {
        self.events.push(Err(loss));
    }
}

#[test]
fn any_sink_gets_what_the_ring_gets() {
    // Two services: two whole blocks, then a lap (3 ms late); the board's sink is its
    // locked ring, handed each sample after its sum.
    let raw = |i: usize| (i % 4096) as u16;
    let mut ring = SampleRing::new();
    let mut recorder = Recorder::default();
    let mut a = Decimator::new(384, 0);
    let mut b = a;
    let t1 = 2 * 256 * 384 + 100;
    assert!(!a.service(512, false, t1, raw, 5, &mut ring));
    assert!(!b.service(512, false, t1, raw, 5, &mut recorder));
    let t2 = t1 + 4 * 256 * 384;
    assert!(!a.service(600, false, t2, raw, 6, &mut ring));
    assert!(!b.service(600, false, t2, raw, 6, &mut recorder));
    let block =
        |first: usize| ((first..first + 256).map(|i| u32::from(raw(i))).sum::<u32>() >> 4) as u16;
    assert_eq!(
        recorder.events,
        [
            Ok((block(0), 5)),
            Ok((block(256), 5)),
            Err(SampleLoss::DmaLapped)
        ]
    );
    let mut out = [firmware::Sample {
        counts: 0,
        detector_steps: 0,
    }; 4];
    assert_eq!(ring.pop_into(&mut out), 2);
    assert_eq!(
        out[..2]
            .iter()
            .map(|s| (s.counts as u16, s.detector_steps))
            .collect::<Vec<_>>(),
        [(block(0), 5), (block(256), 5)]
    );
    assert_eq!(ring.take_loss(), Some(SampleLoss::DmaLapped));
}
