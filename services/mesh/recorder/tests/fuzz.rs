//! Inputs the fuzzer found (`fuzz/`, target `mcap_replay`), each kept with its fix: a flight record
//! of any bytes must be read or refused with an error, never abort.

use recorder::ReadError;
use std::path::{Path, PathBuf};

fn input(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz")
        .join(name)
}

/// A channel record stating a length of 50 PB: the reader allocated it before reading and the
/// process aborted; now a record over the limit is refused.
#[test]
fn a_record_longer_than_the_limit_is_refused_before_it_is_allocated() {
    let path = input("record-length.mcap");
    match recorder::read(&path, |_| {}) {
        Err(ReadError::Mcap { path: p, source }) => {
            assert_eq!(p, path);
            assert!(
                matches!(source, mcap::McapError::RecordTooLarge { opcode: 3, len } if len > 1 << 50),
                "{source}"
            );
        }
        other => panic!("expected the record refused, got {other:?}"),
    }
}
