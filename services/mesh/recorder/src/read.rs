//! Reading a flight record back: every part in order, every message in file order, decoded into the
//! payloads the mesh sent (the `mcap` crate's streaming reader: it needs no index, so a part cut by
//! a SIGKILL is read up to its last commit, and reported as cut: it ends in the recorder's trailer,
//! not in a summary; a part written before the record was sealed (`crate::seal`) ends at its last
//! complete chunk).

use crate::channels::{Channel, Recorded};
use crate::image::Image;
use crate::keep::Counts;
use crate::writer;
use prost::Message as _;
use std::collections::BTreeMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};

/// The largest record read (bytes): far above any the recorder writes (a 1920x1080 mono8 frame is
/// 2 MB), so that a record's length, which the file states, cannot make the reader allocate
/// without bound before it finds the file too short.
pub const RECORD_LENGTH_LIMIT: usize = 64 << 20;

/// One message of a record.
#[derive(Clone, Debug, PartialEq)]
pub struct Message {
    pub channel: Channel,
    pub log_time: u64,
    pub item: Recorded,
}

/// A part that ended before its end: cut while written (a SIGKILL, a power cut).
#[derive(Clone, Debug, PartialEq)]
pub struct Cut {
    pub path: PathBuf,
    /// Messages read from it before the cut.
    pub messages: u64,
    pub reason: String,
}

/// What a read went through.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReadSummary {
    pub parts: Vec<PathBuf>,
    pub messages: u64,
    pub per_channel: BTreeMap<Channel, u64>,
    pub cut: Vec<Cut>,
    /// Messages of topics this reader does not know (a newer recorder's), by topic.
    pub unknown: BTreeMap<String, u64>,
}

/// Why a record cannot be read; names the file (and topic).
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("no flight record at {}", path.display())]
    NotFound { path: PathBuf },
    #[error("cannot open {}: {source}", path.display())]
    Open {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: not a readable MCAP file: {source}", path.display())]
    Mcap {
        path: PathBuf,
        source: mcap::McapError,
    },
    #[error("{}: the chunk at byte {offset} is corrupt: {reason}", path.display())]
    Chunk {
        path: PathBuf,
        offset: u64,
        reason: String,
    },
    #[error("{}: a message on {topic} cannot be decoded: {reason}", path.display())]
    Decode {
        path: PathBuf,
        topic: String,
        reason: String,
    },
}

fn decode(channel: Channel, data: &[u8]) -> Result<Recorded, String> {
    match channel {
        Channel::Image => {
            let raw =
                foxglove::messages::RawImage::decode(data).map_err(|e| format!("protobuf: {e}"))?;
            Ok(Recorded::Image(
                Image::try_from(raw).map_err(|e| e.to_string())?,
            ))
        }
        Channel::Annotation => Ok(Recorded::Overlay),
        Channel::Video => {
            let v = foxglove::messages::CompressedVideo::decode(data)
                .map_err(|e| format!("protobuf: {e}"))?;
            Ok(Recorded::Video(v.into()))
        }
        _ => Recorded::from_json(channel, data),
    }
}

/// A record's messages, pulled one by one: every part in order, every message in file order. A part
/// cut while written is read up to its last complete chunk and listed in [`ReadSummary::cut`].
pub struct Reader {
    parts: std::vec::IntoIter<PathBuf>,
    current: Option<(
        PathBuf,
        u64,
        mcap::io::MessageReader<BufReader<std::fs::File>>,
    )>,
    summary: ReadSummary,
}

impl Reader {
    pub fn open(path: &Path) -> Result<Reader, ReadError> {
        let parts = writer::parts(path);
        if parts.is_empty() {
            return Err(ReadError::NotFound {
                path: path.to_owned(),
            });
        }
        Ok(Reader {
            summary: ReadSummary {
                parts: parts.clone(),
                ..Default::default()
            },
            parts: parts.into_iter(),
            current: None,
        })
    }

    /// What was read so far (all of it once the reader is exhausted).
    pub fn summary(&self) -> &ReadSummary {
        &self.summary
    }

    fn next_message(&mut self) -> Result<Option<Message>, ReadError> {
        loop {
            let Some((part, read, reader)) = self.current.as_mut() else {
                let Some(part) = self.parts.next() else {
                    return Ok(None);
                };
                let open = |source| ReadError::Open {
                    path: part.clone(),
                    source,
                };
                if let Some((offset, reason)) = chunk_overrun(&part).map_err(open)? {
                    return Err(ReadError::Chunk {
                        path: part,
                        offset,
                        reason,
                    });
                }
                let file = std::fs::File::open(&part).map_err(open)?;
                let reader = mcap::io::MessageReader::new_with_options(
                    BufReader::with_capacity(1 << 20, file),
                    mcap::sans_io::LinearReaderOptions::default()
                        .with_record_length_limit(RECORD_LENGTH_LIMIT),
                );
                self.current = Some((part, 0, reader));
                continue;
            };
            let m = match reader.next() {
                None => {
                    if !closed(part) {
                        self.summary.cut.push(Cut {
                            path: part.clone(),
                            messages: *read,
                            reason:
                                "not closed (no summary): read up to the recorder's last commit"
                                    .to_owned(),
                        });
                    }
                    self.current = None;
                    continue;
                }
                Some(Ok(m)) => m,
                Some(Err(
                    e @ (mcap::McapError::UnexpectedEof | mcap::McapError::UnexpectedEoc),
                )) => {
                    self.summary.cut.push(Cut {
                        path: part.clone(),
                        messages: *read,
                        reason: e.to_string(),
                    });
                    self.current = None;
                    continue;
                }
                Some(Err(source)) => {
                    return Err(ReadError::Mcap {
                        path: part.clone(),
                        source,
                    });
                }
            };
            *read += 1;
            let Some(channel) = Channel::from_topic(&m.channel.topic) else {
                *self
                    .summary
                    .unknown
                    .entry(m.channel.topic.clone())
                    .or_default() += 1;
                continue;
            };
            let item = decode(channel, &m.data).map_err(|reason| ReadError::Decode {
                path: part.clone(),
                topic: m.channel.topic.clone(),
                reason,
            })?;
            self.summary.messages += 1;
            *self.summary.per_channel.entry(channel).or_default() += 1;
            return Ok(Some(Message {
                channel,
                log_time: m.log_time,
                item,
            }));
        }
    }
}

impl Iterator for Reader {
    type Item = Result<Message, ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_message().transpose()
    }
}

const OP_FOOTER: u8 = 0x02;
const OP_CHUNK: u8 = 0x06;
/// A record's opcode and length.
const RECORD_HEAD: u64 = 9;

/// The first uncompressed chunk of the MCAP file at `path` whose records do not fit in it: its
/// offset, and which record runs past its end. The `mcap` crate's streaming reader subtracts each
/// record of an uncompressed chunk from what is left of the chunk without checking that it fits
/// (an overflow: a panic where overflow is checked, else the bytes after the chunk read as its
/// records), so these chunks are walked first, record heads only. What is not an MCAP file, a
/// length beyond any file and a file cut short are left to the `mcap` reader's own errors and to
/// the reading of a cut part: this walk then stops without a finding.
fn chunk_overrun(path: &Path) -> std::io::Result<Option<(u64, String)>> {
    let file = std::fs::File::open(path)?;
    let mut file = Walk {
        len: file.metadata()?.len(),
        file: BufReader::with_capacity(64 << 10, file),
        at: 0,
    };
    let mut magic = [0u8; 8];
    if !file.read(&mut magic)? || magic != crate::seal::MAGIC {
        return Ok(None);
    }
    let mut head = [0u8; RECORD_HEAD as usize];
    loop {
        let start = file.at;
        if !file.read(&mut head)? || head[0] == OP_FOOTER {
            return Ok(None);
        }
        let end = (start + RECORD_HEAD)
            .checked_add(u64::from_le_bytes(head[1..].try_into().expect("8 bytes")));
        if head[0] == OP_CHUNK {
            // Start and end times, uncompressed size and CRC, then the compression's name: none
            // is an uncompressed chunk, whose records' length follows.
            let mut fixed = [0u8; 8 + 8 + 8 + 4 + 4];
            let mut records_len = [0u8; 8];
            if !file.read(&mut fixed)? {
                return Ok(None);
            }
            let uncompressed = fixed[28..] == [0; 4];
            if uncompressed && file.read(&mut records_len)? {
                let mut left = u64::from_le_bytes(records_len);
                while left > 0 {
                    let here = file.at;
                    if left < RECORD_HEAD {
                        return Ok(Some((
                            start,
                            format!(
                                "{left} bytes are left at byte {here}, less than a record's head"
                            ),
                        )));
                    }
                    if !file.read(&mut head)? {
                        return Ok(None);
                    }
                    let len = u64::from_le_bytes(head[1..].try_into().expect("8 bytes"));
                    if len > left - RECORD_HEAD {
                        return Ok(Some((
                            start,
                            format!(
                                "the record at byte {here} (opcode {:#04x}) is {len} bytes long; \
                                 the chunk has {} left",
                                head[0],
                                left - RECORD_HEAD
                            ),
                        )));
                    }
                    left -= RECORD_HEAD + len;
                    if !file.skip_to((here + RECORD_HEAD).checked_add(len))? {
                        return Ok(None);
                    }
                }
            }
        }
        if !file.skip_to(end)? {
            return Ok(None);
        }
    }
}

/// A file read forward, knowing where it stands.
struct Walk {
    file: BufReader<std::fs::File>,
    len: u64,
    at: u64,
}

impl Walk {
    /// Fills `buf`; false at the file's end.
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<bool> {
        use std::io::Read;
        match self.file.read_exact(buf) {
            Ok(()) => {
                self.at += buf.len() as u64;
                Ok(true)
            }
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
            Err(e) => Err(e),
        }
    }

    /// Moves forward to `to`; false when it is behind or past the file's end (`None`: past `u64`).
    fn skip_to(&mut self, to: Option<u64>) -> std::io::Result<bool> {
        let Some(by) = to
            .filter(|&to| to <= self.len)
            .and_then(|to| to.checked_sub(self.at))
            .and_then(|by| i64::try_from(by).ok())
        else {
            return Ok(false);
        };
        self.file.seek_relative(by)?;
        self.at += by as u64;
        Ok(true)
    }
}

/// Whether the part at `path` was closed: it ends in a footer that points to a summary.
fn closed(path: &Path) -> bool {
    use std::io::{Read, Seek, SeekFrom};
    let mut tail = [0u8; crate::seal::FOOTER_LEN as usize];
    let read = std::fs::File::open(path).and_then(|mut f| {
        f.seek(SeekFrom::End(-(tail.len() as i64)))?;
        f.read_exact(&mut tail)
    });
    read.is_ok()
        && crate::seal::ends_in_footer(&tail)
        && u64::from_le_bytes(tail[9..17].try_into().unwrap_or_default()) != 0
}

/// Reads the record at `path` (all its parts), calling `f` with each message in file order.
pub fn read(path: &Path, mut f: impl FnMut(Message)) -> Result<ReadSummary, ReadError> {
    let mut reader = Reader::open(path)?;
    for m in reader.by_ref() {
        f(m?);
    }
    Ok(reader.summary)
}

/// The steps missed over all channels, from the totals a cleanly stopped recorder writes into its
/// last part (`None`: no totals there, the recorder did not stop cleanly).
pub fn holes(path: &Path) -> Result<Option<u64>, ReadError> {
    Ok(totals(path)?.map(|t| t.values().map(|c| c.holes).sum()))
}

/// What the recorder did with each channel's messages (by the channel's topic), from the totals a
/// cleanly stopped recorder writes into its last part (`None`: no totals there, the recorder did
/// not stop cleanly).
pub fn totals(path: &Path) -> Result<Option<BTreeMap<String, Counts>>, ReadError> {
    let Some(last) = writer::parts(path).pop() else {
        return Err(ReadError::NotFound {
            path: path.to_owned(),
        });
    };
    let bytes = std::fs::read(&last).map_err(|source| ReadError::Open {
        path: last.clone(),
        source,
    })?;
    let mcap_error = |source| ReadError::Mcap {
        path: last.clone(),
        source,
    };
    let Some(summary) = mcap::Summary::read(&bytes).map_err(mcap_error)? else {
        return Ok(None);
    };
    let Some(index) = summary
        .metadata_indexes
        .iter()
        .find(|i| i.name == "recorder")
    else {
        return Ok(None);
    };
    let totals = mcap::read::metadata(&bytes, index).map_err(mcap_error)?;
    // Each channel's line: "written N repeats N holes N decimated N".
    let counts = |line: &str| {
        let mut c = Counts::default();
        let mut words = line.split_whitespace();
        while let (Some(key), Some(n)) = (words.next(), words.next()) {
            let n = n.parse::<u64>().ok()?;
            match key {
                "written" => c.written = n,
                "repeats" => c.repeats = n,
                "holes" => c.holes = n,
                "decimated" => c.decimated = n,
                _ => return None,
            }
        }
        Some(c)
    };
    Ok(Some(
        totals
            .metadata
            .iter()
            .filter(|(k, _)| k.starts_with('/'))
            .filter_map(|(k, v)| Some((k.clone(), counts(v)?)))
            .collect(),
    ))
}

/// The record's `cabletrack` metadata (endpoint, seed, what log time is, ...), from its first part:
/// the recorder writes it before the first message.
pub fn metadata(path: &Path) -> Result<BTreeMap<String, String>, ReadError> {
    use std::io::Read;
    let open = |source| ReadError::Open {
        path: path.to_owned(),
        source,
    };
    let mut head = Vec::new();
    std::fs::File::open(path)
        .map_err(open)?
        .take(1 << 20)
        .read_to_end(&mut head)
        .map_err(open)?;
    let records = mcap::read::LinearReader::new(&head).map_err(|source| ReadError::Mcap {
        path: path.to_owned(),
        source,
    })?;
    for record in records {
        match record {
            Ok(mcap::records::Record::Metadata(m)) if m.name == "cabletrack" => {
                return Ok(m.metadata);
            }
            // The first chunk or the end of what was read: the recorder writes it before both.
            Ok(mcap::records::Record::Chunk { .. }) | Err(_) => break,
            Ok(_) => {}
        }
    }
    Ok(BTreeMap::new())
}
