//! Writing a flight record: one foxglove `Context` holds the channels and feeds the MCAP file (and,
//! when asked, the live view's WebSocket server, which so serves exactly the file's channels). The
//! file is chunked and zstd-compressed, each chunk assembled in memory, and committed on request (a
//! flush closes the open chunk and commits it: what a SIGKILL can lose is what came since), sealed
//! at every moment so that any MCAP reader opens it (`crate::seal`), rotated to a new part when it
//! reaches its size limit, and closed with its summary and index. A write that fails (a full disk)
//! stops the recording, once: the record stays readable up to its last commit.

use crate::channels::{Channel, Key, Recorded};
use crate::keep::{Keep, Keeper, Overlay};
use crate::seal::{SealedFile, Shared};
use crate::{image, part_path};
use foxglove::messages::{CompressedVideo, ImageAnnotations, RawImage};
use foxglove::{
    Context, FoxgloveError, McapCompression, McapWriteOptions, McapWriterHandle, PartialMetadata,
    RawChannel, Schema, WebSocketServerHandle,
};
use messages::{CableObservationMsg, CameraFrameHeader, RecorderStatus, VideoUnit};
use runtime::clock::unix_ns;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// How a record is written.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// The record's file: its first part (the next parts are `part_path(path, k)`).
    pub path: PathBuf,
    /// A part reaching this size is closed and the next one started.
    pub rotate_bytes: u64,
    /// The uncompressed size at which a chunk is closed.
    pub chunk_bytes: u64,
    /// zstd's level (1: the fastest of its standard levels).
    pub zstd_level: u32,
    /// Keep the image of every `frame_every`-th step (see `crate::keep`).
    pub frame_every: u32,
    /// Keep the image of every `video_frame_every`-th step of the frames the record's compressed
    /// stream gives (0: none; see `crate::keep`).
    pub video_frame_every: u32,
}

impl Options {
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Options {
            path: path.into(),
            rotate_bytes: 1 << 30,
            chunk_bytes: 1 << 20,
            zstd_level: 1,
            frame_every: 1,
            video_frame_every: 25,
        }
    }
}

/// Why a record cannot be written; names the file or address.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("cannot create the flight record {}: {source}", path.display())]
    Create {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("writing the flight record {}: {source}", path.display())]
    Write {
        path: PathBuf,
        source: FoxgloveError,
    },
    #[error("cannot serve the live view on {addr}: {source}")]
    Live {
        addr: SocketAddr,
        source: FoxgloveError,
    },
    #[error("channel {topic}: {source}")]
    Channel {
        topic: &'static str,
        source: FoxgloveError,
    },
    #[error("bad option: {0}")]
    Option(String),
    /// Writing failed (a full disk): the record ends at its last commit and nothing more is written
    /// to it.
    #[error(
        "the flight record {} stops here{}: {reason}; it holds {kept} messages, readable; the recorder goes on without recording",
        path.display(), if *.disk_full { " (the disk is full)" } else { "" }
    )]
    Stopped {
        path: PathBuf,
        disk_full: bool,
        reason: String,
        kept: u64,
    },
}

impl RecordError {
    /// Whether the record could not be created or written because the disk is full.
    pub fn is_disk_full(&self) -> bool {
        match self {
            RecordError::Stopped { disk_full, .. } => *disk_full,
            RecordError::Create { source, .. } => durable::is_disk_full(source),
            _ => false,
        }
    }
}

/// The MCAP writer's options for a flight record: chunks of `chunk_bytes` (uncompressed), zstd at
/// `level`, each chunk assembled in memory, for a [`SealedFile`].
pub fn mcap_options(chunk_bytes: u64, level: u32) -> McapWriteOptions {
    McapWriteOptions::new()
        .compression(Some(McapCompression::Zstd))
        .compression_level(level)
        // zstd's own worker threads would be hidden load on a 2-core vehicle computer.
        .compression_threads(0)
        .chunk_size(Some(chunk_bytes))
        // Each chunk is assembled in memory and reaches the file whole (`crate::seal`): the
        // writer never seeks back to fill in a chunk's length.
        .disable_seeking(true)
        // The sealed file's pad records lie between the writer's records, so the CRCs of the
        // data and summary sections (optional in MCAP: 0 means none) would not match; each
        // chunk keeps its own CRC.
        .calculate_data_section_crc(false)
        .calculate_summary_section_crc(false)
}

/// The flight recorder's totals at its close.
#[derive(Clone, Debug, PartialEq)]
pub struct Totals {
    pub parts: Vec<PathBuf>,
    pub messages: u64,
    pub bytes: u64,
    pub counts: BTreeMap<Channel, crate::keep::Counts>,
    /// Why the recording stopped before the close (a full disk), if it did.
    pub stopped: Option<String>,
}

/// The part being written: the MCAP writer over its sealed file, and what the recorder sees of the
/// file.
struct Part {
    handle: McapWriterHandle<SealedFile>,
    file: Arc<Shared>,
}

/// A flight record being written.
pub struct FlightRecorder {
    opts: Options,
    ctx: Arc<Context>,
    json: BTreeMap<Channel, Arc<RawChannel>>,
    image: foxglove::Channel<RawImage>,
    overlay: foxglove::Channel<ImageAnnotations>,
    video: foxglove::Channel<CompressedVideo>,
    file: Option<Part>,
    part: u32,
    parts: Vec<PathBuf>,
    closed_bytes: u64,
    /// Why the recording stopped (a full disk): nothing is written any more.
    stopped: Option<String>,
    messages: u64,
    flushed_messages: u64,
    status_seq: u64,
    metadata: BTreeMap<String, String>,
    keeper: Keeper,
    frame_size: Option<(u32, u32)>,
    /// Estimates whose frame is not recorded yet (their overlay waits for its image).
    waiting: std::collections::VecDeque<CableObservationMsg>,
    buf: Vec<u8>,
    live: Option<WebSocketServerHandle>,
}

impl FlightRecorder {
    /// Starts a record at `opts.path`; when that file exists (a restarted recorder, a second dive to
    /// the same record), at its first part that does not. `metadata` goes into every part
    /// (`cabletrack` metadata record), with the part's number and start time.
    pub fn create(
        opts: Options,
        metadata: BTreeMap<String, String>,
    ) -> Result<FlightRecorder, RecordError> {
        if opts.frame_every == 0 || opts.rotate_bytes == 0 || opts.chunk_bytes == 0 {
            return Err(RecordError::Option(format!(
                "frame_every ({}), rotate_bytes ({}) and chunk_bytes ({}) must be at least 1",
                opts.frame_every, opts.rotate_bytes, opts.chunk_bytes
            )));
        }
        let ctx = Context::new();
        let mut json = BTreeMap::new();
        for c in Channel::ALL {
            let Some(schema) = c.json_schema() else {
                continue;
            };
            let channel = ctx
                .channel_builder(c.topic())
                .message_encoding("json")
                .schema(Schema::new(
                    c.schema_name(),
                    "jsonschema",
                    schema.to_string().into_bytes(),
                ))
                .build_raw()
                .map_err(|source| RecordError::Channel {
                    topic: c.topic(),
                    source,
                })?;
            json.insert(c, channel);
        }
        let image = ctx
            .channel_builder(Channel::Image.topic())
            .build::<RawImage>();
        let overlay = ctx
            .channel_builder(Channel::Annotation.topic())
            .build::<ImageAnnotations>();
        let video = ctx
            .channel_builder(Channel::Video.topic())
            .build::<CompressedVideo>();
        let first = (0u32..)
            .find(|&k| !part_path(&opts.path, k).exists())
            .unwrap_or(0);
        if first > 0 {
            tracing::info!(
                path = %opts.path.display(),
                part = first,
                "the record exists: continuing it with a new part"
            );
        }
        let mut rec = FlightRecorder {
            keeper: Keeper::new(opts.frame_every).with_video_frame_every(opts.video_frame_every),
            opts,
            ctx,
            json,
            image,
            overlay,
            video,
            file: None,
            part: first,
            parts: Vec::new(),
            closed_bytes: 0,
            stopped: None,
            messages: 0,
            flushed_messages: 0,
            status_seq: 0,
            metadata,
            frame_size: None,
            waiting: std::collections::VecDeque::new(),
            buf: Vec::with_capacity(512),
            live: None,
        };
        rec.file = Some(rec.open_part()?);
        Ok(rec)
    }

    fn write_options(&self) -> McapWriteOptions {
        mcap_options(self.opts.chunk_bytes, self.opts.zstd_level)
    }

    fn open_part(&mut self) -> Result<Part, RecordError> {
        let path = part_path(&self.opts.path, self.part);
        let create = |source| RecordError::Create {
            path: path.clone(),
            source,
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(create)?;
        }
        if path.exists() {
            return Err(create(std::io::Error::from(
                std::io::ErrorKind::AlreadyExists,
            )));
        }
        let sealed = SealedFile::new(&path);
        let file = sealed.shared();
        let write = |source| RecordError::Write {
            path: path.clone(),
            source,
        };
        let handle = self
            .ctx
            .mcap_writer_with_options(self.write_options())
            .create(sealed)
            .map_err(write)?;
        let mut meta = self.metadata.clone();
        meta.insert("part".into(), self.part.to_string());
        meta.insert("part_started_unix_ns".into(), unix_ns().to_string());
        meta.insert("frame_every".into(), self.opts.frame_every.to_string());
        meta.insert(
            "video_frame_every".into(),
            self.opts.video_frame_every.to_string(),
        );
        handle.write_metadata("cabletrack", meta).map_err(write)?;
        // The first commit creates the file, whole.
        if let Err(e) = handle.flush() {
            let source = match file.failed() {
                Some((kind, message)) => std::io::Error::new(kind, message),
                None => std::io::Error::other(e.to_string()),
            };
            return Err(create(source));
        }
        tracing::info!(path = %path.display(), part = self.part, "recording");
        self.parts.push(path);
        Ok(Part { handle, file })
    }

    /// Stops the recording after a failed write: the part's writer is dropped (what it still
    /// holds goes nowhere), the channels lose their file sink, the live view goes on.
    fn stop(&mut self, path: PathBuf, error: Option<(std::io::ErrorKind, String)>) -> RecordError {
        let (kind, reason) =
            error.unwrap_or((std::io::ErrorKind::Other, "the writer failed".to_owned()));
        let disk_full = durable::is_disk_full(&std::io::Error::from(kind));
        if let Some(part) = self.file.take() {
            self.closed_bytes += part.file.committed();
            drop(part.handle);
        }
        self.stopped = Some(reason.clone());
        RecordError::Stopped {
            path,
            disk_full,
            reason,
            kept: self.flushed_messages,
        }
    }

    fn path(&self) -> PathBuf {
        self.parts.last().cloned().unwrap_or_default()
    }

    /// Serves the record's channels live on `addr` (a viewer connects with the foxglove WebSocket
    /// protocol); returns the port (`addr`'s, or the one chosen for port 0).
    pub fn serve_live(&mut self, addr: SocketAddr) -> Result<u16, RecordError> {
        let server = self
            .ctx
            .websocket_server()
            .name("cabletrack flight recorder")
            .bind(addr.ip().to_string(), addr.port())
            .start_blocking()
            .map_err(|source| RecordError::Live { addr, source })?;
        let port = server.port();
        self.live = Some(server);
        Ok(port)
    }

    /// Writes `item` as JSON on its channel unless it was written before; its log time when written.
    fn write_json(&mut self, item: &Recorded) -> Option<u64> {
        let channel = item.channel();
        let keep = match item.key()? {
            Key::EachStep(stamp) | Key::Stamped(stamp) => self.keeper.stamped(channel, &stamp),
            Key::Seq(seq) => self.keeper.unstamped(channel, seq),
        };
        let Keep::Write { log_time } = keep else {
            return None;
        };
        self.buf.clear();
        // Serialising a payload into a Vec cannot fail.
        if item.write_json(&mut self.buf)
            && let Some(ch) = self.json.get(&channel)
        {
            ch.log_with_meta(&self.buf, PartialMetadata::with_log_time(log_time));
            self.messages += 1;
        }
        Some(log_time)
    }

    /// A message of the mesh, on its channel, once; perception's estimate also drawn over its
    /// frame's image once that is written. Images and overlays are written with their frame
    /// ([`FlightRecorder::frame`]): passed here, they are ignored.
    pub fn log(&mut self, item: &Recorded) {
        if self.write_json(item).is_some()
            && let Recorded::Observation(o) = item
        {
            self.draw(o);
        }
    }

    /// A camera frame: its header, and its image unless decimated.
    pub fn frame(&mut self, header: &CameraFrameHeader, pixels: &[u8]) {
        let Some(log_time) = self.write_json(&Recorded::FrameHeader(*header)) else {
            return;
        };
        let raw = image::raw_image(header, pixels);
        if self.keeper.image(&header.stamp, raw.is_some())
            && let Some(raw) = raw
        {
            self.frame_size = Some((header.width, header.height));
            self.image.log_with_time(&raw, log_time);
            self.messages += 1;
        }
        for o in std::mem::take(&mut self.waiting) {
            self.draw(&o);
        }
    }

    /// A unit of the camera's compressed stream: its header as JSON and the unit as
    /// `foxglove.CompressedVideo`, both at its frame's time, once.
    pub fn video(&mut self, unit: &VideoUnit, bytes: &[u8]) {
        if !self.keeper.video(unit) {
            return;
        }
        self.buf.clear();
        if Recorded::VideoHeader(*unit).write_json(&mut self.buf)
            && let Some(ch) = self.json.get(&Channel::VideoHeader)
        {
            ch.log_with_meta(&self.buf, PartialMetadata::with_log_time(unit.time_ns));
            self.messages += 1;
        }
        self.video
            .log_with_time(&image::compressed_video(unit, bytes), unit.time_ns);
        self.messages += 1;
    }

    /// Perception's overlay of `o`, drawn once its frame's image is written.
    fn draw(&mut self, o: &CableObservationMsg) {
        match self.keeper.overlay(&o.stamp) {
            Overlay::Draw => {
                if let Some((w, h)) = self.frame_size {
                    self.overlay
                        .log_with_time(&image::estimate_overlay(o, w, h), o.stamp.time_ns);
                    self.messages += 1;
                }
            }
            Overlay::Later => {
                // A few steps of slack; an estimate whose frame never comes is given up.
                if self.waiting.len() >= 64 {
                    self.waiting.pop_front();
                }
                self.waiting.push_back(*o);
            }
            Overlay::Never => {}
        }
    }

    /// Bytes written so far, every part.
    pub fn bytes(&self) -> u64 {
        self.closed_bytes + self.file.as_ref().map_or(0, |p| p.file.written())
    }

    /// Why the recording stopped before its close (a full disk), if it did.
    pub fn stopped(&self) -> Option<&str> {
        self.stopped.as_deref()
    }

    pub fn messages(&self) -> u64 {
        self.messages
    }

    pub fn keeper(&self) -> &Keeper {
        &self.keeper
    }

    /// Closes the open chunk and commits everything to the file: a SIGKILL or a power cut after
    /// this keeps it all. A failure stops the recording (one error, then nothing: later calls do
    /// nothing).
    pub fn flush(&mut self) -> Result<(), RecordError> {
        let Some(part) = &self.file else {
            return Ok(());
        };
        if part.handle.flush().is_err() {
            let failed = part.file.failed();
            return Err(self.stop(self.path(), failed));
        }
        self.flushed_messages = self.messages;
        Ok(())
    }

    /// Starts the next part when this one has reached its size limit; `true` when it did. A failure
    /// stops the recording, as [`FlightRecorder::flush`]'s does.
    pub fn rotate_if_due(&mut self) -> Result<bool, RecordError> {
        let Some(old) = &self.file else {
            return Ok(false);
        };
        if old.file.written() < self.opts.rotate_bytes {
            return Ok(false);
        }
        let old_path = self.path();
        self.part += 1;
        // The new part first, then the old one closed: nothing is logged in between (one thread),
        // so every message lands in exactly one part.
        let new = match self.open_part() {
            Ok(new) => new,
            Err(e) => {
                let error = match &e {
                    RecordError::Create { source, .. } => Some((source.kind(), source.to_string())),
                    _ => Some((std::io::ErrorKind::Other, e.to_string())),
                };
                return Err(self.stop(part_path(&self.opts.path, self.part), error));
            }
        };
        let Some(old) = self.file.replace(new) else {
            return Ok(false);
        };
        old.file.closing();
        let closed = old.handle.close();
        let old_len = old.file.committed();
        self.closed_bytes += old_len;
        if closed.is_err() {
            // The old part stays readable up to its last commit, without its index.
            let failed = old.file.failed();
            return Err(self.stop(old_path, failed));
        }
        self.flushed_messages = self.messages;
        tracing::info!(closed = %old_path.display(), bytes = old_len, "rotated");
        Ok(true)
    }

    /// The recorder's progress now, also written to the record's status channel.
    pub fn status(&mut self) -> RecorderStatus {
        self.status_seq += 1;
        let mut s = RecorderStatus {
            seq: self.status_seq,
            wall_time_ns: unix_ns(),
            messages: self.messages,
            flushed_messages: self.flushed_messages,
            bytes: self.bytes(),
            holes: self.keeper.holes(),
            repeats: self.keeper.repeats(),
            part: self.part,
            _reserved: 0,
        };
        if self.write_json(&Recorded::Status(s)).is_some() {
            s.messages = self.messages;
        }
        s
    }

    /// Writes the totals as the `recorder` metadata record, closes the file with its summary and
    /// index, and stops the live view.
    pub fn close(mut self) -> Result<Totals, RecordError> {
        self.keeper.finish();
        let counts = self.keeper.counts().clone();
        if let Some(part) = self.file.take() {
            let path = self.path();
            let mut meta = BTreeMap::new();
            meta.insert("messages".to_owned(), self.messages.to_string());
            meta.insert("closed_unix_ns".to_owned(), unix_ns().to_string());
            for (c, n) in &counts {
                meta.insert(
                    c.topic().to_owned(),
                    format!(
                        "written {} repeats {} holes {} decimated {}",
                        n.written, n.repeats, n.holes, n.decimated
                    ),
                );
            }
            part.handle
                .write_metadata("recorder", meta)
                .map_err(|source| RecordError::Write {
                    path: path.clone(),
                    source,
                })?;
            // The close's summary is committed, synced, and its footer ends the file.
            part.file.closing();
            let closed = part.handle.close();
            self.closed_bytes += part.file.committed();
            if let Err(source) = closed {
                return Err(match part.file.failed() {
                    Some(failed) => self.stop(path, Some(failed)),
                    None => RecordError::Write { path, source },
                });
            }
        }
        if let Some(live) = self.live.take() {
            live.stop().wait_blocking();
        }
        Ok(Totals {
            parts: self.parts.clone(),
            messages: self.messages,
            bytes: self.bytes(),
            counts,
            stopped: self.stopped.clone(),
        })
    }
}

/// The record's parts that exist, in order: `path`, then `part_path(path, 1)`, ... up to the first
/// missing one.
pub fn parts(path: &Path) -> Vec<PathBuf> {
    (0u32..)
        .map(|k| part_path(path, k))
        .take_while(|p| p.exists())
        .collect()
}
