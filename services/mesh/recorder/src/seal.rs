//! A flight record that any MCAP reader opens at every moment of its writing: after a SIGKILL, a
//! power cut or a full disk, not only after a clean close.
//!
//! Readers look for an MCAP file's footer in its last bytes: the Python `mcap` package, the `mcap`
//! command-line tool and the viewers read nothing from a file whose end is not a footer, however
//! many complete chunks stand before it. So the recorder keeps its file *sealed*: it always ends in
//! a trailer of [`TRAILER_LEN`] bytes,
//!
//! ```text
//! pad: private record (opcode PAD_OP), length 0   9 bytes
//! DataEnd (no CRC)                              13 bytes
//! Footer (no summary)                           29 bytes
//! magic                                          8 bytes
//! ```
//!
//! which a reader takes as the end of the file: it reads the records up to it and stops at its
//! footer. New records (a second's complete chunks and their message indexes, a metadata record)
//! are held in memory and *committed* together ([`commit_plan`]):
//!
//! 1. a new trailer is written where the new end will be (past the file's end: the file grows with
//!    a hole, and still ends in a trailer);
//! 2. the records are written into the hole, between the two trailers;
//! 3. the file's data is synced;
//! 4. one byte turns the old trailer into padding: its pad record's length becomes the length of
//!    the rest of the old trailer, so a reader skips the old DataEnd, footer and magic and goes on
//!    into the new records.
//!
//! Until step 4 a reader stops at the old trailer's footer and never sees the new bytes, whole or
//! not; step 4 is one byte, which a SIGKILL or a power cut cannot tear; and step 3 puts it after
//! the bytes it makes visible. A file is created whole (a temporary file, synced, renamed). At a
//! clean close the writer's summary (its index) is committed the same way and its footer then
//! written over the last trailer's ([`close_plan`]), so a closed record has a summary like any other
//! MCAP file; the pad records in it are private records, which readers skip.
//!
//! A commit that fails (a full disk) truncates the file back to its last trailer: the record stays
//! readable up to the last commit, and nothing more is written to it ([`SealedFile`] drops what it
//! is given from then on, so the writer above does not fail at every message).

use std::fs::{File, OpenOptions};
use std::io::{self, Seek, SeekFrom, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// The MCAP magic, at both ends of a file.
pub const MAGIC: [u8; 8] = [0x89, b'M', b'C', b'A', b'P', b'0', b'\r', b'\n'];
/// The opcode of the pad records: one of the MCAP specification's private opcodes (0x80 to 0xFF),
/// which readers skip.
pub const PAD_OP: u8 = 0xCA;
const OP_DATA_END: u8 = 0x0F;
const OP_FOOTER: u8 = 0x02;
const PAD_LEN: u64 = 9;
const DATA_END_LEN: u64 = 13;
/// A footer record and the closing magic.
pub const FOOTER_LEN: u64 = 29 + 8;
/// The trailer every sealed file ends in.
pub const TRAILER_LEN: u64 = PAD_LEN + DATA_END_LEN + FOOTER_LEN;

/// The trailer's bytes: a pad record of length 0, a DataEnd without CRC, a footer without summary,
/// the magic.
pub fn trailer() -> [u8; TRAILER_LEN as usize] {
    let mut t = [0u8; TRAILER_LEN as usize];
    t[0] = PAD_OP;
    t[9] = OP_DATA_END;
    t[10..18].copy_from_slice(&4u64.to_le_bytes());
    t[22] = OP_FOOTER;
    t[23..31].copy_from_slice(&20u64.to_le_bytes());
    t[51..59].copy_from_slice(&MAGIC);
    t
}

/// Writes to a file reach it page by page: a SIGKILL can stop a write between two pages, never
/// inside one. No trailer (nor the footer written over one) crosses a multiple of this.
pub const PAGE: u64 = 4096;

/// The padding to put after records ending at `pos`, so that the trailer after them lies within
/// one page: none when it fits, else a pad record (at least [`PAD_LEN`] bytes) up to the next page.
pub fn gap(pos: u64) -> u64 {
    let room = PAGE - pos % PAGE;
    if room >= TRAILER_LEN {
        0
    } else if room >= PAD_LEN {
        room
    } else {
        room + PAD_LEN
    }
}

/// A pad record of `len` bytes in all (at least [`PAD_LEN`]), which readers skip.
pub fn pad_record(len: u64) -> Vec<u8> {
    let mut r = vec![0u8; len as usize];
    r[0] = PAD_OP;
    r[1..9].copy_from_slice(&(len - PAD_LEN).to_le_bytes());
    r
}

/// Whether `bytes` end in an MCAP footer and the magic (what the writer's close ends with).
pub fn ends_in_footer(bytes: &[u8]) -> bool {
    let n = bytes.len();
    n >= FOOTER_LEN as usize
        && bytes[n - 8..] == MAGIC
        && bytes[n - 37] == OP_FOOTER
        && bytes[n - 36..n - 28] == 20u64.to_le_bytes()
}

/// One step of a commit, on a file whose trailer starts at `end`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// Write the new records (the commit's body) at this offset.
    Body { at: u64 },
    /// Write a fresh trailer at this offset.
    Trailer { at: u64 },
    /// Write the closing footer and magic (the last [`FOOTER_LEN`] bytes given) at this offset.
    Footer { at: u64 },
    /// Sync the file's data.
    Sync,
    /// Write the byte `len` at `at`: a pad record's length, so it covers what follows it.
    Pad { at: u64, len: u8 },
}

/// The steps committing `body` bytes to a file whose trailer starts at `end`, and the new `end`.
pub fn commit_plan(end: u64, body: u64) -> (Vec<Step>, u64) {
    let new_end = end + TRAILER_LEN + body;
    (
        vec![
            Step::Trailer { at: new_end },
            Step::Body {
                at: end + TRAILER_LEN,
            },
            Step::Sync,
            Step::Pad {
                at: end + 1,
                len: (DATA_END_LEN + FOOTER_LEN) as u8,
            },
        ],
        new_end,
    )
}

/// The steps of a clean close: `body` bytes (the writer's DataEnd and summary, without its footer)
/// committed, then its footer written over the new trailer's footer, and the new trailer's pad
/// record stretched over its DataEnd. The file then ends in the writer's footer, whose summary
/// section holds one pad record after the writer's own records.
pub fn close_plan(end: u64, body: u64) -> Vec<Step> {
    let (mut steps, new_end) = commit_plan(end, body);
    steps.extend([
        Step::Sync,
        Step::Footer {
            at: new_end + PAD_LEN + DATA_END_LEN,
        },
        Step::Sync,
        Step::Pad {
            at: new_end + 1,
            len: DATA_END_LEN as u8,
        },
        Step::Sync,
    ]);
    steps
}

/// What a sealed file's owner (the recorder) sees of it while the MCAP writer owns it.
#[derive(Debug, Default)]
pub struct Shared {
    /// Bytes written (committed or held), for rotation by size.
    len: AtomicU64,
    /// Bytes committed: what a reader sees.
    committed: AtomicU64,
    /// The next flush is the writer's close: commit its summary and end in its footer.
    closing: AtomicBool,
    /// Why writing stopped: the first failed commit's error.
    failed: Mutex<Option<(io::ErrorKind, String)>>,
}

impl Shared {
    /// Bytes written so far (committed or held).
    pub fn written(&self) -> u64 {
        self.len.load(Ordering::Relaxed)
    }

    pub fn committed(&self) -> u64 {
        self.committed.load(Ordering::Relaxed)
    }

    /// Marks the next flush as the close.
    pub fn closing(&self) {
        self.closing.store(true, Ordering::Relaxed);
    }

    /// The error that stopped the writing, if one did: its kind and message.
    pub fn failed(&self) -> Option<(io::ErrorKind, String)> {
        self.failed.lock().map(|f| f.clone()).unwrap_or_default()
    }
}

/// What a sealed file did to its file, in order: what a crash can interrupt at any point. Kept
/// only when asked ([`SealedFile::journaled`]), by the tests that cut a record at every step.
#[derive(Clone, Debug, PartialEq)]
pub enum Op {
    /// The file appeared with these bytes (renamed into place whole).
    Create(Vec<u8>),
    /// `seal`: a trailer, a footer or a pad byte, what makes bytes visible (never crosses a page);
    /// otherwise records, invisible until a pad byte shows them.
    Write {
        at: u64,
        bytes: Vec<u8>,
        seal: bool,
    },
    Sync,
    /// The file was cut back to this length (after a failed commit).
    Truncate(u64),
}

/// The [`Op`]s of a journaled sealed file.
pub type Journal = Arc<Mutex<Vec<Op>>>;

/// The file under the MCAP writer: holds what it is given until a flush commits it (see the module
/// docs). Created by its first commit; after a failed commit it drops everything.
pub struct SealedFile {
    path: PathBuf,
    file: Option<File>,
    /// Where the trailer starts (once the file exists).
    end: u64,
    pending: Vec<u8>,
    shared: Arc<Shared>,
    journal: Option<Journal>,
}

impl SealedFile {
    /// A record to be created at `path` by the first flush; `path` must not exist.
    pub fn new(path: &Path) -> SealedFile {
        SealedFile {
            path: path.to_owned(),
            file: None,
            end: 0,
            pending: Vec::with_capacity(1 << 20),
            shared: Arc::new(Shared::default()),
            journal: None,
        }
    }

    /// [`SealedFile::new`], keeping a journal of every operation on the file.
    pub fn journaled(path: &Path) -> (SealedFile, Journal) {
        let journal = Journal::default();
        let mut file = SealedFile::new(path);
        file.journal = Some(Arc::clone(&journal));
        (file, journal)
    }

    fn note(journal: Option<&Journal>, op: impl FnOnce() -> Op) {
        if let Some(j) = journal
            && let Ok(mut j) = j.lock()
        {
            j.push(op());
        }
    }

    pub fn shared(&self) -> Arc<Shared> {
        Arc::clone(&self.shared)
    }

    fn position(&self) -> u64 {
        match self.file {
            Some(_) => self.end + TRAILER_LEN + self.pending.len() as u64,
            None => self.pending.len() as u64,
        }
    }

    /// Creates the file whole: the held bytes and a trailer into a temporary file beside it,
    /// synced, renamed, the directory synced.
    fn create(&mut self) -> io::Result<()> {
        let dir = match self.path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let name = self
            .path
            .file_name()
            .map_or_else(|| "record".to_owned(), |n| n.to_string_lossy().into_owned());
        let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
        let made = (|| {
            let mut file = OpenOptions::new()
                .write(true)
                .create(true)
                .truncate(true)
                .open(&tmp)?;
            file.write_all(&self.pending)?;
            file.write_all(&trailer())?;
            file.sync_data()?;
            std::fs::rename(&tmp, &self.path)?;
            durable::sync_dir(dir)?;
            Ok(file)
        })();
        match made {
            Ok(file) => {
                Self::note(self.journal.as_ref(), || {
                    let mut bytes = self.pending.clone();
                    bytes.extend_from_slice(&trailer());
                    Op::Create(bytes)
                });
                self.end = self.pending.len() as u64;
                self.file = Some(file);
                Ok(())
            }
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                Err(e)
            }
        }
    }

    /// Runs `steps` with `body` as the commit's bytes (and, for a close, `footer` as its end).
    fn run(
        file: &File,
        journal: Option<&Journal>,
        steps: &[Step],
        body: &[u8],
        footer: &[u8],
    ) -> io::Result<()> {
        let trailer = trailer();
        for step in steps {
            let (at, bytes, seal) = match *step {
                Step::Body { at } => (at, body, false),
                Step::Trailer { at } => (at, &trailer[..], true),
                Step::Footer { at } => (at, footer, true),
                Step::Pad { at, ref len } => (at, std::slice::from_ref(len), true),
                Step::Sync => {
                    file.sync_data()?;
                    Self::note(journal, || Op::Sync);
                    continue;
                }
            };
            file.write_all_at(bytes, at)?;
            Self::note(journal, || Op::Write {
                at,
                bytes: bytes.to_vec(),
                seal,
            });
        }
        Ok(())
    }

    /// Commits what is held (see the module docs).
    fn commit(&mut self) -> io::Result<()> {
        if self.pending.is_empty() {
            return Ok(());
        }
        let Some(file) = &self.file else {
            return self.create();
        };
        let closing = self.shared.closing.load(Ordering::Relaxed) && ends_in_footer(&self.pending);
        // Padding after the records keeps the next trailer within a page.
        let records = self.pending.len() as u64 - if closing { FOOTER_LEN } else { 0 };
        let gap = gap(self.end + TRAILER_LEN + records);
        if gap > 0 {
            let at = records as usize;
            self.pending.splice(at..at, pad_record(gap));
        }
        let (body, footer) = if closing {
            self.pending
                .split_at(self.pending.len() - FOOTER_LEN as usize)
        } else {
            (&self.pending[..], &[][..])
        };
        let (steps, new_end) = commit_plan(self.end, body.len() as u64);
        let steps = if closing {
            close_plan(self.end, body.len() as u64)
        } else {
            steps
        };
        // Up to the first pad, a failure leaves the file as it was once cut back to its trailer.
        let first_pad = steps
            .iter()
            .position(|s| matches!(s, Step::Pad { .. }))
            .unwrap_or(steps.len());
        let journal = self.journal.as_ref();
        if let Err(e) = Self::run(file, journal, &steps[..first_pad], body, footer) {
            let len = self.end + TRAILER_LEN;
            if file.set_len(len).is_ok() {
                Self::note(journal, || Op::Truncate(len));
            }
            return Err(e);
        }
        Self::run(file, journal, &steps[first_pad..], body, footer)?;
        self.end = new_end;
        Ok(())
    }
}

impl Write for SealedFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if self.shared.failed().is_none() {
            self.pending.extend_from_slice(buf);
            self.shared.len.store(self.position(), Ordering::Relaxed);
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        if let Some((kind, message)) = self.shared.failed() {
            return Err(io::Error::new(kind, message));
        }
        match self.commit() {
            Ok(()) => {
                self.pending.clear();
                self.shared.committed.store(
                    self.end + TRAILER_LEN * u64::from(self.file.is_some()),
                    Ordering::Relaxed,
                );
                self.shared.len.store(self.position(), Ordering::Relaxed);
                Ok(())
            }
            Err(e) => {
                if let Ok(mut f) = self.shared.failed.lock() {
                    *f = Some((e.kind(), e.to_string()));
                }
                self.pending = Vec::new();
                Err(e)
            }
        }
    }
}

impl Seek for SealedFile {
    /// The writer only asks where it is (its chunks are assembled in memory): the offset its next
    /// byte will have in the file.
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        match to {
            SeekFrom::Current(0) | SeekFrom::End(0) => Ok(self.position()),
            _ => Err(io::Error::new(
                io::ErrorKind::Unsupported,
                "a sealed flight record is only appended to",
            )),
        }
    }
}

/// Every state a crash can leave, with the index of the operation it interrupts or follows:
/// after each operation, and inside each write: a write of records anywhere (its first byte,
/// half of it, all but its last byte: stricter than a SIGKILL, which stops a write only between
/// pages), a trailer, footer or pad byte at any page boundary inside it (there must be none);
/// `None` before the file exists. For the tests that read a record cut at every step.
pub fn crash_states(journal: &Journal) -> Vec<(usize, Option<Vec<u8>>)> {
    let mut states = vec![(0, None)];
    let mut image: Option<Vec<u8>> = None;
    for (k, op) in journal.lock().unwrap().iter().enumerate() {
        match op {
            Op::Create(bytes) => image = Some(bytes.clone()),
            Op::Write { at, bytes, seal } => {
                let n = bytes.len();
                let cuts = if *seal {
                    (1..n)
                        .filter(|c| (*at + *c as u64).is_multiple_of(PAGE))
                        .collect()
                } else {
                    vec![1, n / 2, n.saturating_sub(1)]
                };
                assert!(
                    !*seal || cuts.is_empty(),
                    "a seal write crosses a page: {op:?}"
                );
                let at = *at as usize;
                let img = image.as_mut().expect("written after its creation");
                for cut in cuts {
                    if cut == 0 || cut >= n {
                        continue;
                    }
                    let mut torn = img.clone();
                    put(&mut torn, at, &bytes[..cut]);
                    states.push((k, Some(torn)));
                }
                put(img, at, bytes);
            }
            Op::Sync => continue,
            Op::Truncate(len) => image.as_mut().unwrap().truncate(*len as usize),
        }
        states.push((k, image.clone()));
    }
    states
}

fn put(image: &mut Vec<u8>, at: usize, bytes: &[u8]) {
    if image.len() < at + bytes.len() {
        image.resize(at + bytes.len(), 0);
    }
    image[at..at + bytes.len()].copy_from_slice(bytes);
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::collections::BTreeMap;

    /// A record written through a journaled sealed file with the recorder's options: `flushes`
    /// commits of `per_flush` messages (small chunks, so a commit holds several), then a clean
    /// close when `close`. Returns the journal, the messages visible after each commit, and where
    /// in the journal the close begins.
    fn journaled_record(
        dir: &Path,
        flushes: u64,
        per_flush: u64,
        close: bool,
    ) -> (Journal, Vec<u64>, usize) {
        let (sealed, journal) = SealedFile::journaled(&dir.join("dive.mcap"));
        let shared = sealed.shared();
        let mut w = crate::writer::mcap_options(2048, 1).create(sealed).unwrap();
        let schema = w
            .add_schema("cabletrack.Test", "jsonschema", b"{}")
            .unwrap();
        let channel = w
            .add_channel(schema, "/test", "json", &BTreeMap::new())
            .unwrap();
        w.write_metadata(&mcap::records::Metadata {
            name: "cabletrack".into(),
            metadata: BTreeMap::from([("seed".to_owned(), "1".to_owned())]),
        })
        .unwrap();
        w.flush().unwrap();
        let mut visible = vec![0];
        let mut seq = 0u32;
        for _ in 0..flushes {
            for _ in 0..per_flush {
                seq += 1;
                let data = format!(
                    "{{\"seq\":{seq},\"pad\":\"{}\"}}",
                    "x".repeat((seq % 97) as usize)
                );
                let header = mcap::records::MessageHeader {
                    channel_id: channel,
                    sequence: seq,
                    log_time: u64::from(seq) * 1000,
                    publish_time: u64::from(seq) * 1000,
                };
                w.write_to_known_channel(&header, data.as_bytes()).unwrap();
            }
            w.flush().unwrap();
            visible.push(u64::from(seq));
        }
        let close_from = journal.lock().unwrap().len();
        if close {
            shared.closing();
            w.finish().unwrap();
        }
        drop(w);
        (journal, visible, close_from)
    }

    /// The messages the `mcap` crate's streaming reader reads from `bytes`, in order; an error fails.
    fn read_all(bytes: &[u8]) -> Vec<u32> {
        mcap::MessageStream::new(bytes)
            .unwrap()
            .map(|m| m.unwrap().sequence)
            .collect()
    }

    #[test]
    fn a_record_cut_at_any_byte_of_any_commit_reads_up_to_a_commit() {
        let dir = tempfile::tempdir().unwrap();
        let (journal, visible, _) = journaled_record(dir.path(), 6, 40, false);
        let states = crash_states(&journal);
        // Each commit: a trailer, a body, a pad byte; each write cut inside too.
        assert!(states.len() > 6 * 6, "{} states", states.len());
        let mut last = 0;
        for (i, (_, state)) in states.iter().enumerate() {
            let Some(bytes) = state else { continue };
            let read = read_all(bytes);
            let n = read.len() as u64;
            assert!(
                visible.contains(&n),
                "state {i}: {n} messages, not a commit's {visible:?}"
            );
            assert!(n >= last, "state {i}: {n} messages after {last}");
            assert_eq!(read, (1..=n as u32).collect::<Vec<_>>(), "state {i}");
            last = n;
            // Not closed: a footer without a summary, read from the end as readers do.
            let summary = mcap::Summary::read(bytes);
            assert!(matches!(summary, Ok(None)), "state {i}: {summary:?}");
        }
        assert_eq!(last, 240);
    }

    #[test]
    fn a_close_cut_at_any_byte_keeps_every_message_and_ends_with_a_summary() {
        let dir = tempfile::tempdir().unwrap();
        let (journal, visible, close_from) = journaled_record(dir.path(), 3, 30, true);
        let states = crash_states(&journal);
        let total = *visible.last().unwrap();
        let closed = states.last().unwrap().1.as_ref().unwrap();
        let summary = mcap::Summary::read(closed).unwrap().expect("a summary");
        assert_eq!(summary.stats.as_ref().unwrap().message_count, total);
        assert!(!summary.chunk_indexes.is_empty());
        // Read through the index: every chunk where the index says it is.
        let mut indexed = 0;
        for index in &summary.chunk_indexes {
            indexed += summary.stream_chunk(closed, index).unwrap().count() as u64;
        }
        assert_eq!(indexed, total);
        // Every state of the close reads every message.
        let during_close: Vec<_> = states.iter().filter(|(k, _)| *k >= close_from).collect();
        assert!(during_close.len() >= 8, "{} states", during_close.len());
        for (k, state) in during_close {
            let bytes = state.as_ref().unwrap();
            assert_eq!(read_all(bytes).len() as u64, total, "operation {k}");
        }
    }

    #[test]
    fn the_writer_only_asks_where_it_is() {
        let dir = tempfile::tempdir().unwrap();
        let mut f = SealedFile::new(&dir.path().join("a.mcap"));
        f.write_all(b"abc").unwrap();
        assert_eq!(f.stream_position().unwrap(), 3);
        assert!(f.seek(SeekFrom::Start(0)).is_err());
        f.flush().unwrap();
        assert_eq!(f.seek(SeekFrom::End(0)).unwrap(), 3 + TRAILER_LEN);
        assert_eq!(
            std::fs::read(dir.path().join("a.mcap")).unwrap().len() as u64,
            3 + TRAILER_LEN
        );
    }

    #[test]
    fn the_trailer_is_a_pad_a_data_end_a_footer_and_the_magic() {
        let t = trailer();
        assert_eq!(t.len() as u64, TRAILER_LEN);
        assert!(ends_in_footer(&t));
        assert_eq!(t[0], PAD_OP);
        assert_eq!(u64::from_le_bytes(t[1..9].try_into().unwrap()), 0);
        assert_eq!(t[9], OP_DATA_END);
        assert_eq!(t[22], OP_FOOTER);
        // No summary: a reader reads the records in order.
        assert!(t[31..51].iter().all(|&b| b == 0));
    }

    #[test]
    fn a_trailer_never_crosses_a_page() {
        for pos in 0..3 * PAGE {
            let g = gap(pos);
            assert!(g == 0 || g >= PAD_LEN, "{pos}: {g}");
            let at = pos + g;
            assert_eq!(at / PAGE, (at + TRAILER_LEN - 1) / PAGE, "{pos}: {g}");
            assert!(g < PAGE, "{pos}: {g}");
        }
        let pad = pad_record(20);
        assert_eq!(pad.len(), 20);
        assert_eq!(u64::from_le_bytes(pad[1..9].try_into().unwrap()), 11);
    }

    #[test]
    fn a_commit_writes_its_trailer_first_and_shows_its_records_last_by_one_byte() {
        let (steps, end) = commit_plan(100, 1000);
        assert_eq!(end, 100 + TRAILER_LEN + 1000);
        assert_eq!(
            steps,
            [
                Step::Trailer { at: end },
                Step::Body {
                    at: 100 + TRAILER_LEN
                },
                Step::Sync,
                Step::Pad {
                    at: 101,
                    len: (TRAILER_LEN - PAD_LEN) as u8
                },
            ]
        );
    }
}
