//! The TX drop policy: frames are queued whole or dropped whole, whatever the pattern of
//! pushes, USB reads of any size, and disconnects (property test over random schedules).

use firmware::txqueue::{Dropped, FrameQueue};
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
