//! The flight recorder: every topic of a mesh's endpoint into one MCAP file that the robotics
//! viewers open (Foxglove, Lichtblick), the same channels served live, and the reader of such
//! records (replay, the report, the tests).
//!
//! - [`channels`]: the table of channels, one per topic, each with its schema: the camera's images
//!   as `foxglove.RawImage` (`mono8`), perception's estimate also drawn over them as
//!   `foxglove.ImageAnnotations`, every other payload as the JSON form and JSON Schema it derives
//!   (`messages::json`).
//! - [`keep`]: the pure core: each step's message once, at the stamp's time, frames decimated,
//!   holes counted.
//! - [`writer`]: the file: chunked, zstd, flushed each second, rotated by size into parts
//!   ([`part_path`]), closed with its summary and index; the live view on the same channels.
//! - [`seal`]: the file under the writer, readable by any MCAP reader at every moment: it always
//!   ends in a footer, new chunks are committed behind it and shown by one byte; a failed commit
//!   (a full disk) stops the recording, not the recorder.
//! - [`figure`]: a dive at a glance (a frame with the cable found, the estimate, the commands and
//!   the thrusters against time), drawn from its record with `plot`.
//! - [`read`]: every message back, from every part, a part cut by a SIGKILL up to its last
//!   complete chunk.
//!
//! The process (`main.rs`) subscribes to every topic through `messages::Tap`s (the recorder's own
//! buffer, no listener: a publisher is never slowed or blocked by it), and drains every tap every
//! 10 ms (and on the supervisor's events).

pub mod channels;
pub mod figure;
pub mod image;
pub mod keep;
pub mod read;
pub mod seal;
pub mod writer;

pub use channels::{Channel, CommandDof, Drain, Key, Recorded, taps};
pub use keep::{Counts, Keep, Keeper, Overlay};
pub use read::{Message, ReadError, ReadSummary, Reader, holes, metadata, read, totals};
pub use writer::{FlightRecorder, Options, RecordError, Totals, parts};

use std::path::{Path, PathBuf};

/// The file of part `k` of the record `base`: `base` itself for part 0, then `STEM.k.EXT`
/// (`dive.mcap`, `dive.1.mcap`, `dive.2.mcap`, ...).
pub fn part_path(base: &Path, k: u32) -> PathBuf {
    if k == 0 {
        return base.to_owned();
    }
    let stem = base
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = match base.extension() {
        Some(ext) => format!("{stem}.{k}.{}", ext.to_string_lossy()),
        None => format!("{stem}.{k}"),
    };
    base.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_are_numbered_beside_the_first() {
        let base = Path::new("out/dive.mcap");
        assert_eq!(part_path(base, 0), base);
        assert_eq!(part_path(base, 1), Path::new("out/dive.1.mcap"));
        assert_eq!(part_path(base, 12), Path::new("out/dive.12.mcap"));
        assert_eq!(part_path(Path::new("dive"), 2), Path::new("dive.2"));
    }
}
