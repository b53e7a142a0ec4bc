//! The wire schema hash is tied to the protocol version: a message cannot change shape
//! without a new `PROTOCOL_VERSION` (see `protocol::schema`).

use protocol::schema::{SCHEMA_HASH, WIRE_LIMITS, WIRE_TYPES, wire_hash};
use protocol::{PROTOCOL_VERSION, SCHEMA_HISTORY};

#[test]
fn the_schema_hash_is_this_versions_entry_in_the_history() {
    let &(version, hash) = SCHEMA_HISTORY.last().expect("SCHEMA_HISTORY is empty");
    assert!(
        hash == SCHEMA_HASH && version == PROTOCOL_VERSION,
        "the wire schema hash is {SCHEMA_HASH:#018x}, but SCHEMA_HISTORY (protocol/src/lib.rs) ends with \
         ({version}, {hash:#018x}) and PROTOCOL_VERSION is {PROTOCOL_VERSION}.\n\
         If a message changed shape, a peer of version {version} would misread it: set PROTOCOL_VERSION to {next}, \
         append ({next}, {SCHEMA_HASH:#018x}) to SCHEMA_HISTORY, note the change in PROTOCOL_VERSION's history \
         and regenerate the golden file (GONIO_BLESS=1 cargo test -p protocol --test it golden).",
        next = version + 1,
    );
}

#[test]
fn the_history_only_grows() {
    for pair in SCHEMA_HISTORY.windows(2) {
        let [(v0, h0), (v1, h1)] = [pair[0], pair[1]];
        assert!(v1 > v0, "SCHEMA_HISTORY: version {v1} after {v0}");
        assert_ne!(
            h0, h1,
            "SCHEMA_HISTORY: versions {v0} and {v1} have the same schema; no bump was needed"
        );
    }
    for (i, (v, h)) in SCHEMA_HISTORY.iter().enumerate() {
        assert!(
            !SCHEMA_HISTORY[..i].iter().any(|(_, other)| other == h),
            "SCHEMA_HISTORY: version {v} repeats an older schema"
        );
    }
}

#[test]
fn the_hash_covers_both_directions_and_the_limits() {
    // Each part counts: dropping one changes the hash.
    assert_ne!(wire_hash(&WIRE_TYPES[..1], WIRE_LIMITS), SCHEMA_HASH);
    assert_ne!(wire_hash(&WIRE_TYPES[1..], WIRE_LIMITS), SCHEMA_HASH);
    assert_ne!(wire_hash(WIRE_TYPES, &WIRE_LIMITS[1..]), SCHEMA_HASH);
    assert_eq!(wire_hash(WIRE_TYPES, WIRE_LIMITS), SCHEMA_HASH);
}
