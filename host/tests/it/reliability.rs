//! Sessions of the fault campaign (`gonio reliability`, docs/RELIABILITY.md) that once
//! failed, each with its spec as drawn then (a draw depends on the fault-free sessions'
//! durations, so the index alone does not repeat it once those change).

use host::session::PolicyChoice;
use host::study::reliability::{self, FaultKind, Spec};

/// Session 512: SG by the adaptive policy, the cable pulled at 37.1 s for 1.9 s, during
/// strategy 1. The instrument took its fail-safe stop (heartbeat lost) mid-move just as the
/// cable came back; its status read `Stopped` while the arms still ramped down, and every
/// `Home` was refused `Busy`: the recovery read the state again at once, eight times within
/// a few milliseconds, and gave up ("could not be brought to a known state in 8 attempts").
#[test]
fn session_512_stopped_mid_move_by_a_short_unplug_survives() {
    let spec = Spec {
        index: 512,
        sample: "SG",
        policy: PolicyChoice::Adaptive,
        seed: 31977,
        kind: FaultKind::Unplug,
        unplug: Some((37.10630512546945, 1.9133087813577891)),
        corrupt: 0.0,
        drop: 0.0,
        operator_s: 9.292653986821545,
    };
    let rows = reliability::run_all(std::slice::from_ref(&spec), false, 1, &|| {});
    let row = &rows[0];
    assert!(row.survived(), "{spec:?}: {:?}", row.failure);
    // Still the case it was: a fail-safe stop that lost the homing.
    assert!(
        row.recoveries.stops == 1 && row.recoveries.rehomings >= 1,
        "{:?}",
        row.recoveries
    );
}
