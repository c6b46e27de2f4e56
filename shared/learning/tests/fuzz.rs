//! Inputs the fuzzer found (`fuzz/`, target `checkpoint`), each kept with its fix: a checkpoint of
//! any bytes must be refused with an error, never a panic.

use learning::checkpoint::{Checkpoint, CheckpointError};
use std::path::Path;

fn load(name: &str) -> Result<Checkpoint, CheckpointError> {
    Checkpoint::load(
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fuzz")
            .join(name),
    )
}

/// A header announcing a payload of u64::MAX - 1 bytes: the size expected (header + payload) no
/// longer fits a u64 and overflowed in the error.
#[test]
fn a_payload_length_near_u64_max_is_a_truncated_file() {
    match load("length-past-u64.ckpt") {
        Err(CheckpointError::Truncated {
            expected, found, ..
        }) => {
            assert_eq!(expected, u64::MAX);
            assert_eq!(found, 100);
        }
        other => panic!("expected a truncated checkpoint, got {other:?}"),
    }
}
