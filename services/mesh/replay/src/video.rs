//! A record's compressed stream decoded as the camera decoded it during the dive: the units the
//! camera gave its decoder (`/camera_video`, in their order), through the camera's own decoding
//! pipeline (`video::decode`), give the frames the mesh saw, byte for byte. Replay publishes
//! those where the record keeps only some images or none (`recorder --video-frame-every`), and
//! checks them against the images it does keep.
//!
//! A picture is found by its frame's time (`VideoUnit::time_ns`, the `Stamp::time_ns` of the frame
//! it became). Pictures the camera decoded but never published (a newer one replaced it before it
//! was read) are passed over. A frame the source sent again has several units of its time: the
//! camera published the first picture of them, or a later one when the copies came before it read
//! the frame; the recorder then keeps the frame's image, which says which.
//!
//! A picture whose unit the record does not decode as the camera did ([`Decoded::decodable`],
//! `recorder::keep::Continuity`: before the record's first keyframe, after a unit missing from the
//! record, after the camera's decoder started afresh, up to the next keyframe) is not the frame
//! the mesh saw: the camera's decoder held units the record's does not. The recorder keeps those
//! frames' images, and replay takes them from there.
use messages::VideoUnit;
use recorder::keep::Continuity;
use recorder::{Reader, Recorded};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::time::Duration;
use video::decode::StreamDecoder;

/// The longest the decoder may take for one picture before replay calls it stalled.
const PICTURE_WITHIN: Duration = Duration::from_secs(60);

/// A frame decoded from the record's stream.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Decoded {
    pub unit: VideoUnit,
    /// Whether the record's units decode to this frame as the camera's did (see the module docs).
    pub decodable: bool,
    pub corrupted: bool,
    pub image: Vec<u8>,
    /// The pictures of the units of the same time after it (the source sent the frame again): the
    /// camera may have published one of those instead, when it read the frame after they came.
    pub again: Vec<Vec<u8>>,
}

/// Why the record's stream cannot be decoded; names the file.
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    #[error("{}: decoding its video: {source}", path.display())]
    Decode {
        path: PathBuf,
        source: video::gst::VideoError,
    },
    #[error("{}: a picture came out of the decoder for no unit fed to it (key {key})", path.display())]
    Unknown { path: PathBuf, key: u64 },
}

/// The record's video, decoded one picture at a time.
pub struct VideoFrames {
    path: PathBuf,
    decoder: StreamDecoder,
    /// Each unit fed, with its key and whether it decodes as it did, in order (from the feeding
    /// thread).
    fed: Receiver<Fed>,
    waiting: VecDeque<Fed>,
    /// A picture read past the frame asked for: the next frame's, perhaps.
    ahead: Option<Decoded>,
    /// Units decoded so far.
    pub units: u64,
}

/// A unit given to the decoder: its key, its header, whether it decodes as it did on the vehicle.
type Fed = (u64, VideoUnit, bool);

/// The units of a record's stream in file order, with the keys they are fed under: their order.
fn units(path: PathBuf, fed: SyncSender<Fed>) -> impl Iterator<Item = (u64, Vec<u8>)> + Send {
    let mut reader = Reader::open(&path).ok();
    let mut header: Option<VideoUnit> = None;
    let mut continuity = Continuity::default();
    let mut key = 0u64;
    std::iter::from_fn(move || {
        let reader = reader.as_mut()?;
        loop {
            // A record that cannot be read ends the stream here; the frames' reader reports it.
            let m = reader.next()?.ok()?;
            match m.item {
                Recorded::VideoHeader(h) => header = Some(h),
                Recorded::Video(v) => {
                    let Some(h) = header.take().filter(|h| h.time_ns == v.time_ns) else {
                        continue;
                    };
                    key += 1;
                    fed.send((key, h, continuity.next(&h))).ok()?;
                    return Some((key, v.data));
                }
                _ => {}
            }
        }
    })
}

impl VideoFrames {
    /// Starts decoding the stream of the record at `path` into `width x height` frames. A record
    /// without a stream gives no frame.
    pub fn open(path: &Path, width: u32, height: u32) -> Result<Self, VideoError> {
        // The decoder's queue and the pictures in flight: the channel never fills before them.
        let (tx, fed) = sync_channel(1024);
        let decoder =
            StreamDecoder::start(width, height, units(path.to_owned(), tx)).map_err(|source| {
                VideoError::Decode {
                    path: path.to_owned(),
                    source,
                }
            })?;
        Ok(VideoFrames {
            path: path.to_owned(),
            decoder,
            fed,
            waiting: VecDeque::new(),
            ahead: None,
            units: 0,
        })
    }

    /// The next picture in the stream's order; `None` at its end.
    pub fn next_picture(&mut self) -> Result<Option<Decoded>, VideoError> {
        if let Some(d) = self.ahead.take() {
            return Ok(Some(d));
        }
        let picture = self
            .decoder
            .next(PICTURE_WITHIN)
            .map_err(|source| VideoError::Decode {
                path: self.path.clone(),
                source,
            })?;
        let Some(picture) = picture else {
            return Ok(None);
        };
        self.waiting.extend(self.fed.try_iter());
        // Units the decoder dropped (no picture) are passed over.
        while let Some(&(key, unit, decodable)) = self.waiting.front() {
            self.waiting.pop_front();
            self.units += 1;
            if key == picture.key {
                return Ok(Some(Decoded {
                    unit,
                    decodable,
                    corrupted: picture.corrupted,
                    image: picture.image,
                    again: Vec::new(),
                }));
            }
        }
        Err(VideoError::Unknown {
            path: self.path.clone(),
            key: picture.key,
        })
    }

    /// The picture of the frame at `time_ns` (with those of the same time after it, `again`):
    /// pictures before it are passed over; `None` when the stream ends or goes past that time
    /// without it.
    pub fn frame_at(&mut self, time_ns: u64) -> Result<Option<Decoded>, VideoError> {
        let mut found = loop {
            let Some(d) = self.next_picture()? else {
                return Ok(None);
            };
            if d.unit.time_ns == time_ns {
                break d;
            }
            if d.unit.time_ns > time_ns {
                self.ahead = Some(d);
                return Ok(None);
            }
        };
        while let Some(d) = self.next_picture()? {
            if d.unit.time_ns != time_ns {
                self.ahead = Some(d);
                break;
            }
            found.again.push(d.image);
        }
        Ok(Some(found))
    }
}
