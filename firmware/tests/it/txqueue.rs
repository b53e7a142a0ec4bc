//! The TX drop policy: frames are queued whole or dropped whole, whatever the pattern of
//! pushes, USB reads of any size, and disconnects (property test over random schedules).

use firmware::txqueue::{DROP_LOG_PERIOD_US, DropLog, Dropped, FrameQueue};
use proptest::prelude::*;

const N: usize = 1024;

#[derive(Clone, Debug)]
enum Op {
    /// The device queues a frame of this length (its bytes are its number, then the
    /// delimiter).
    Push(usize),
    /// The USB task takes up to this many bytes for one transfer.
    Pop(usize),
    /// The host went away.
    Clear,
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        6 => (2usize..300).prop_map(Op::Push),
        1 => (N - 10..N + 300).prop_map(Op::Push),
        5 => (0usize..300).prop_map(Op::Pop),
        1 => Just(Op::Clear),
    ]
}

/// Frame `id` of `len` bytes: `len - 1` bytes that name it (never 0), then 0.
fn frame(id: u32, len: usize) -> Vec<u8> {
    let mut bytes: Vec<u8> = (0..len - 1)
        .map(|k| 1 + ((id as usize * 7 + k) % 255) as u8)
        .collect();
    bytes.push(0);
    bytes
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    #[test]
    fn frames_go_whole_or_not_at_all(ops in proptest::collection::vec(op(), 1..300)) {
        let mut queue: FrameQueue<N> = FrameQueue::new();
        // What the host receives since the last disconnect, and the frames accepted since.
        let mut received: Vec<u8> = Vec::new();
        let mut accepted: Vec<Vec<u8>> = Vec::new();
        let mut dropped = 0u32;
        let mut out = [0u8; N + 300];
        for (id, op) in ops.into_iter().enumerate() {
            match op {
                Op::Push(len) => {
                    let bytes = frame(id as u32, len);
                    let free = N - queue.len();
                    match queue.push_frame(&bytes) {
                        Ok(()) => accepted.push(bytes),
                        Err(Dropped) => {
                            // Dropped only when it did not fit.
                            prop_assert!(len > free, "a {len}-byte frame dropped with {free} free");
                            dropped += 1;
                        }
                    }
                }
                Op::Pop(n) => {
                    let got = queue.pop(&mut out[..n]);
                    received.extend_from_slice(&out[..got]);
                }
                Op::Clear => {
                    // Whatever was received before must be whole frames up to the last
                    // delimiter; a transfer cut by the disconnect may leave a tail.
                    queue.clear();
                    check(&received, &accepted, true)?;
                    received.clear();
                    accepted.clear();
                }
            }
            prop_assert!(queue.len() <= N);
        }
        let got = queue.pop(&mut out);
        received.extend_from_slice(&out[..got]);
        prop_assert!(queue.is_empty());
        check(&received, &accepted, false)?;
        prop_assert_eq!(queue.take_dropped(), dropped);
        prop_assert_eq!(queue.take_dropped(), 0);
    }
}

/// `received` is the accepted frames, in order, each whole (a prefix of them when the
/// queue was cleared, the last possibly cut where the disconnect came).
fn check(received: &[u8], accepted: &[Vec<u8>], cleared: bool) -> Result<(), TestCaseError> {
    let all: Vec<u8> = accepted.concat();
    if cleared {
        prop_assert!(
            all.starts_with(received),
            "bytes the device never queued, or out of order"
        );
    } else {
        prop_assert_eq!(received, &all[..], "lost or reordered bytes");
    }
    Ok(())
}

#[test]
fn a_full_queue_drops_the_new_frame_and_keeps_the_old() {
    let mut queue: FrameQueue<8> = FrameQueue::new();
    assert_eq!(queue.push_frame(&[1, 2, 3, 0]), Ok(()));
    assert_eq!(queue.push_frame(&[4, 5, 6, 7, 0]), Err(Dropped));
    assert_eq!(queue.push_frame(&[8, 9, 10, 0]), Ok(()));
    let mut out = [0u8; 16];
    let n = queue.pop(&mut out);
    assert_eq!(&out[..n], [1, 2, 3, 0, 8, 9, 10, 0]);
    assert_eq!(queue.take_dropped(), 1);
}

proptest! {
    /// The drop log over random schedules of 1 ms polls with 0-3 drops each: logs at least
    /// a period apart, every drop in exactly one log, none waiting longer than a period
    /// (asked every poll), the first drop after a quiet period logged at once.
    #[test]
    fn dropped_frames_are_logged_at_most_once_a_period(
        drops in prop::collection::vec(prop_oneof![4 => Just(0u32), 1 => 1u32..4], 1..6000),
    ) {
        let mut log = DropLog::new();
        let mut logged_at: Vec<u64> = Vec::new();
        let (mut total, mut logged) = (0u64, 0u64);
        // When the oldest drop not yet logged happened.
        let mut oldest_pending: Option<u64> = None;
        let end = drops.len() as u64 * 1000 + DROP_LOG_PERIOD_US;
        for (poll, now_us) in (0..end).step_by(1000).enumerate() {
            let n = drops.get(poll).copied().unwrap_or(0);
            log.count(n);
            total += u64::from(n);
            if n > 0 && oldest_pending.is_none() {
                oldest_pending = Some(now_us);
            }
            let quiet = logged_at.last().is_none_or(|&t| now_us - t >= DROP_LOG_PERIOD_US);
            match log.due(now_us) {
                Some(count) => {
                    prop_assert!(count > 0);
                    prop_assert!(quiet, "a log within a period of the last");
                    logged += u64::from(count);
                    logged_at.push(now_us);
                    oldest_pending = None;
                }
                None => {
                    prop_assert!(!(quiet && oldest_pending.is_some()), "a due count kept back");
                }
            }
            if let Some(since) = oldest_pending {
                prop_assert!(now_us - since < DROP_LOG_PERIOD_US, "a drop unlogged for a period");
            }
        }
        prop_assert_eq!(logged, total, "drops lost or logged twice");
    }
}

/// A host that stops reading for 10 s: one drop per 1 ms poll, eleven logs, not 10,000.
#[test]
fn a_host_that_stops_reading_is_logged_once_a_second() {
    let mut log = DropLog::new();
    let mut logs = Vec::new();
    for ms in 0..10_000u64 {
        log.count(1);
        logs.extend(log.due(ms * 1000));
    }
    // The host reads again: the rest is logged a period after the last log.
    for ms in 10_000..11_000u64 {
        logs.extend(log.due(ms * 1000));
    }
    assert_eq!(logs.len(), 11);
    assert_eq!(logs[0], 1, "the first drop at once");
    assert_eq!(logs.iter().sum::<u32>(), 10_000);
}

proptest! {
    /// The board's IN transfers (`write_transfer`): the packets tile the frame in order,
    /// every one but the last is full, and the last is short (empty when the frame is a
    /// whole number of packets), so the host's driver sees the transfer end.
    #[test]
    fn a_transfer_is_full_packets_and_a_short_end(len in 0usize..1_000, max_packet in prop_oneof![Just(64usize), 1usize..80]) {
        let packets: Vec<_> = firmware::txqueue::transfer_packets(len, max_packet).collect();
        let mut at = 0;
        for packet in &packets {
            prop_assert_eq!(packet.start, at);
            at = packet.end;
        }
        prop_assert_eq!(at, len);
        let (last, full) = packets.split_last().unwrap();
        prop_assert!(full.iter().all(|p| p.len() == max_packet));
        prop_assert!(last.len() < max_packet);
        prop_assert_eq!(last.is_empty(), len % max_packet == 0);
    }
}

#[test]
fn a_frame_of_64_bytes_ends_with_a_zero_length_packet() {
    let packets: Vec<_> = firmware::txqueue::transfer_packets(64, 64).collect();
    assert_eq!(packets, vec![0..64, 64..64]);
    let packets: Vec<_> = firmware::txqueue::transfer_packets(65, 64).collect();
    assert_eq!(packets, vec![0..64, 64..65]);
}
