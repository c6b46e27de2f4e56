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

/// An uncompressed chunk whose first record (a channel of 61 bytes) is longer than the 11 bytes of
/// records the chunk states: the `mcap` reader's count of what is left of the chunk overflowed (a
/// panic with overflow checks on); now the chunk is refused, named by its offset.
#[test]
fn a_record_running_past_its_uncompressed_chunk_is_refused() {
    let path = input("chunk-overrun.mcap");
    let bytes = std::fs::read(&path).unwrap();
    match recorder::read(&path, |_| {}) {
        Err(ReadError::Chunk {
            path: p,
            offset,
            reason,
        }) => {
            assert_eq!(p, path);
            assert_eq!(bytes[offset as usize], 0x06, "not a chunk at byte {offset}");
            assert!(reason.contains("opcode 0x03"), "{reason}");
        }
        other => panic!("expected the chunk refused, got {other:?}"),
    }
}

/// A record of uncompressed chunks (what the `mcap` crate's writer makes without compression)
/// reads whole; with its chunk's records length one byte short, the chunk is refused.
#[test]
fn uncompressed_chunks_read_whole_and_one_a_byte_short_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("uncompressed.mcap");
    let messages = 20u32;
    {
        let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let mut writer = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(256))
            .create(file)
            .unwrap();
        let channel = writer
            .add_channel(0, "/uncompressed", "json", &Default::default())
            .unwrap();
        for sequence in 0..messages {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence,
                log_time: u64::from(sequence),
                publish_time: u64::from(sequence),
            };
            let data = format!("{{\"seq\":{sequence}}}");
            writer
                .write_to_known_channel(&header, data.as_bytes())
                .unwrap();
        }
        writer.finish().unwrap();
    }
    let summary = recorder::read(&path, |_| {}).unwrap();
    assert_eq!(summary.unknown["/uncompressed"], u64::from(messages));
    assert!(summary.cut.is_empty(), "{:?}", summary.cut);

    // The first chunk's records length: after its opcode and length, the start and end times,
    // the uncompressed size and CRC, and the compression's name (empty).
    let mut bytes = std::fs::read(&path).unwrap();
    let chunk = first_chunk(&bytes);
    let at = chunk + 9 + 8 + 8 + 8 + 4;
    assert_eq!(bytes[at..at + 4], [0; 4], "an uncompressed chunk");
    let field = at + 4..at + 12;
    let records_len = u64::from_le_bytes(bytes[field.clone()].try_into().unwrap());
    bytes[field].copy_from_slice(&(records_len - 1).to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    match recorder::read(&path, |_| {}) {
        Err(ReadError::Chunk { offset, .. }) => assert_eq!(offset, chunk as u64),
        other => panic!("expected the chunk refused, got {other:?}"),
    }
}

/// The offset of the first chunk record of an MCAP file, walking its records from the magic.
fn first_chunk(bytes: &[u8]) -> usize {
    let mut at = 8;
    while bytes[at] != 0x06 {
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap());
        at += 9 + len as usize;
    }
    at
}
