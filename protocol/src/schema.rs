//! The wire schema of the contract as one number, computed at compile time.
//!
//! Every type on the wire derives [`postcard_schema::Schema`] (a description of its
//! postcard data model, made by the compiler from the type itself, so it cannot drift
//! from the code). [`SCHEMA_HASH`] folds the description of the two message types that
//! cross the wire ([`WIRE_TYPES`]) and the limits both sides size their buffers by
//! ([`WIRE_LIMITS`]) into a 64-bit FNV-1a hash, and [`crate::SCHEMA_HISTORY`] ties each
//! hash to its [`crate::PROTOCOL_VERSION`]: `tests/it/schema.rs` fails when the hash is not
//! the last entry's under the current version, so a message cannot change shape without a
//! new version, and `tests/it/golden.rs` pins the encoding of one instance of each message as
//! a second, byte-level lock (with the hash in the golden file, which cannot be rewritten
//! under an unchanged version).
//!
//! The hash is of the ENCODING, not of the source: postcard writes a struct as its fields
//! one after the other, a newtype as what it wraps, a unit as nothing, an enum as the
//! variant's index then its content, so the hash is made of exactly that. Renaming a type,
//! a field or a variant changes nothing on the wire and nothing here; reordering fields,
//! changing a field's type, adding or moving a variant, or wrapping a field in an
//! `Option` does change it. Two descriptions hash alike only when postcard encodes them
//! alike (containers are bracketed, so `Option<(A, B)>` and `(Option<A>, B)` differ).
//!
//! Adding a message type: put its schema in [`WIRE_TYPES`] (or make it part of
//! [`crate::Request`] or [`crate::DeviceMessage`], which is how every message so far is
//! carried) and a golden instance in `tests/it/golden.rs`.

use crate::messages::{
    BOARD_NAME_LEN, DeviceMessage, FIRMWARE_VERSION_LEN, MAX_RANGES, MAX_SWEEP_BINS, Request,
    SCHEDULE_CHUNK_LEN, SERIAL_NUMBER_LEN,
};
use postcard_schema::Schema;
use postcard_schema::schema::{DataModelType, DataModelVariant, NamedType, NamedValue};

/// The message types that cross the wire: what the host sends, what the device sends.
pub const WIRE_TYPES: &[&NamedType] = &[Request::SCHEMA, DeviceMessage::SCHEMA];

/// Capacities that the schema cannot see (a `heapless::Vec<T, N>` is a sequence of any
/// length to postcard) but a peer must share: a longer chunk or string than the other
/// side holds fails to decode there.
pub const WIRE_LIMITS: &[(&str, usize)] = &[
    ("MAX_FRAME_LEN", crate::MAX_FRAME_LEN),
    ("SCHEDULE_CHUNK_LEN", SCHEDULE_CHUNK_LEN),
    ("MAX_RANGES", MAX_RANGES),
    ("FIRMWARE_VERSION_LEN", FIRMWARE_VERSION_LEN),
    ("BOARD_NAME_LEN", BOARD_NAME_LEN),
    ("SERIAL_NUMBER_LEN", SERIAL_NUMBER_LEN),
    // Not a buffer, but a limit a host plans by: a change must not go unnoticed.
    ("MAX_SWEEP_BINS", MAX_SWEEP_BINS as usize),
];

/// The hash of [`WIRE_TYPES`] and [`WIRE_LIMITS`] (see the module doc).
pub const SCHEMA_HASH: u64 = wire_hash(WIRE_TYPES, WIRE_LIMITS);

const FNV_BASIS: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

const fn update(mut state: u64, bytes: &[u8]) -> u64 {
    let mut i = 0;
    while i < bytes.len() {
        state ^= bytes[i] as u64;
        state = state.wrapping_mul(FNV_PRIME);
        i += 1;
    }
    state
}

// One byte per element of the encoding; `OPEN`/`CLOSE` bracket what a container holds.
const OPEN: u8 = b'(';
const CLOSE: u8 = b')';

/// The hash of `types` in order, then of each limit's value (its name only labels it).
pub const fn wire_hash(types: &[&NamedType], limits: &[(&str, usize)]) -> u64 {
    let mut state = FNV_BASIS;
    let mut i = 0;
    while i < types.len() {
        state = update(state, &[OPEN]);
        state = named(state, types[i]);
        state = update(state, &[CLOSE]);
        i += 1;
    }
    let mut i = 0;
    while i < limits.len() {
        state = update(state, &(limits[i].1 as u64).to_le_bytes());
        i += 1;
    }
    state
}

const fn named(state: u64, ty: &NamedType) -> u64 {
    model(state, ty.ty)
}

/// Fields one after the other, with no mark of their own: postcard writes a struct, a
/// tuple and a tuple struct as nothing but their fields.
const fn product(mut state: u64, items: &[&NamedType]) -> u64 {
    let mut i = 0;
    while i < items.len() {
        state = named(state, items[i]);
        i += 1;
    }
    state
}

const fn fields(mut state: u64, items: &[&NamedValue]) -> u64 {
    let mut i = 0;
    while i < items.len() {
        state = named(state, items[i].ty);
        i += 1;
    }
    state
}

/// What an enum variant or an option holds, bracketed.
const fn bracketed_variant(state: u64, variant: &DataModelVariant) -> u64 {
    let state = update(state, &[OPEN]);
    let state = match variant {
        DataModelVariant::UnitVariant => state,
        DataModelVariant::NewtypeVariant(ty) => named(state, ty),
        DataModelVariant::TupleVariant(items) => product(state, items),
        DataModelVariant::StructVariant(items) => fields(state, items),
    };
    update(state, &[CLOSE])
}

const fn model(state: u64, ty: &DataModelType) -> u64 {
    match ty {
        DataModelType::Bool => update(state, b"b"),
        DataModelType::I8 => update(state, b"i1"),
        DataModelType::U8 => update(state, b"u1"),
        // Varints: each width has its own range (a u32 where a u16 was reads values the
        // old peer cannot), so they are told apart although small values encode alike.
        DataModelType::I16 => update(state, b"i2"),
        DataModelType::I32 => update(state, b"i4"),
        DataModelType::I64 => update(state, b"i8"),
        DataModelType::I128 => update(state, b"iG"),
        DataModelType::U16 => update(state, b"u2"),
        DataModelType::U32 => update(state, b"u4"),
        DataModelType::U64 => update(state, b"u8"),
        DataModelType::U128 => update(state, b"uG"),
        DataModelType::Usize => update(state, b"uz"),
        DataModelType::Isize => update(state, b"iz"),
        DataModelType::F32 => update(state, b"f4"),
        DataModelType::F64 => update(state, b"f8"),
        DataModelType::Char => update(state, b"c"),
        DataModelType::String => update(state, b"s"),
        DataModelType::ByteArray => update(state, b"y"),
        DataModelType::Option(inner) => {
            let state = update(state, &[b'?', OPEN]);
            let state = named(state, inner);
            update(state, &[CLOSE])
        }
        // Zero bytes on the wire.
        DataModelType::Unit | DataModelType::UnitStruct => state,
        DataModelType::NewtypeStruct(inner) => named(state, inner),
        DataModelType::Seq(inner) => {
            let state = update(state, &[b'*', OPEN]);
            let state = named(state, inner);
            update(state, &[CLOSE])
        }
        DataModelType::Tuple(items) | DataModelType::TupleStruct(items) => product(state, items),
        DataModelType::Map { key, val } => {
            let state = update(state, &[b'm', OPEN]);
            let state = named(state, key);
            let state = named(state, val);
            update(state, &[CLOSE])
        }
        DataModelType::Struct(items) => fields(state, items),
        DataModelType::Enum(variants) => {
            let mut state = update(state, &[b'e', OPEN]);
            let mut i = 0;
            while i < variants.len() {
                state = bracketed_variant(state, variants[i].ty);
                i += 1;
            }
            update(state, &[CLOSE])
        }
        DataModelType::Schema => update(state, b"S"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::{Deserialize, Serialize};

    fn hash_of<T: Schema>() -> u64 {
        wire_hash(&[T::SCHEMA], &[])
    }

    #[derive(Serialize, Deserialize, Schema)]
    struct Inner {
        a: u8,
        b: u16,
    }
    #[derive(Serialize, Deserialize, Schema)]
    struct Nested {
        inner: Inner,
        c: bool,
    }
    #[derive(Serialize, Deserialize, Schema)]
    struct Flat {
        x: u8,
        y: u16,
        z: bool,
    }
    #[derive(Serialize, Deserialize, Schema)]
    struct Swapped {
        y: u16,
        x: u8,
        z: bool,
    }
    #[derive(Serialize, Deserialize, Schema)]
    struct Wider {
        x: u8,
        y: u32,
        z: bool,
    }
    #[derive(Serialize, Deserialize, Schema)]
    struct OptionOfPair(Option<(u8, u8)>);
    #[derive(Serialize, Deserialize, Schema)]
    struct PairWithOption(Option<u8>, u8);
    #[derive(Serialize, Deserialize, Schema)]
    enum Two {
        A,
        B(u8),
    }
    #[derive(Serialize, Deserialize, Schema)]
    enum TwoRenamed {
        First,
        Second { value: u8 },
    }
    #[derive(Serialize, Deserialize, Schema)]
    enum Three {
        A,
        B(u8),
        C,
    }
    #[derive(Serialize, Deserialize, Schema)]
    enum TwoSwapped {
        B(u8),
        A,
    }

    /// The premise: two types hash alike exactly when postcard writes their values alike.
    fn encodes_alike<A: Serialize, B: Serialize>(a: &A, b: &B) -> bool {
        let (mut buf_a, mut buf_b) = ([0u8; 64], [0u8; 64]);
        postcard::to_slice(a, &mut buf_a).unwrap() == postcard::to_slice(b, &mut buf_b).unwrap()
    }

    #[test]
    fn names_and_nesting_do_not_count_the_encoding_does() {
        // Nesting and names: same bytes, same hash.
        assert!(encodes_alike(
            &Nested {
                inner: Inner { a: 1, b: 300 },
                c: true
            },
            &Flat {
                x: 1,
                y: 300,
                z: true
            }
        ));
        assert_eq!(hash_of::<Nested>(), hash_of::<Flat>());
        assert_eq!(hash_of::<Two>(), hash_of::<TwoRenamed>());
        // Field order, width, an added or moved variant, a bracket moved: different hashes.
        assert!(!encodes_alike(
            &Flat {
                x: 1,
                y: 300,
                z: true
            },
            &Swapped {
                y: 300,
                x: 1,
                z: true
            }
        ));
        assert_ne!(hash_of::<Flat>(), hash_of::<Swapped>());
        assert_ne!(hash_of::<Flat>(), hash_of::<Wider>());
        assert_ne!(hash_of::<Two>(), hash_of::<Three>());
        assert_ne!(hash_of::<Two>(), hash_of::<TwoSwapped>());
        assert!(!encodes_alike(
            &OptionOfPair(None),
            &PairWithOption(None, 0)
        ));
        assert_ne!(hash_of::<OptionOfPair>(), hash_of::<PairWithOption>());
    }

    #[test]
    fn limits_count() {
        assert_ne!(
            wire_hash(WIRE_TYPES, &[("N", 16)]),
            wire_hash(WIRE_TYPES, &[("N", 32)])
        );
        // Only the value: the label documents it.
        assert_eq!(
            wire_hash(WIRE_TYPES, &[("N", 16)]),
            wire_hash(WIRE_TYPES, &[("M", 16)])
        );
    }
}
