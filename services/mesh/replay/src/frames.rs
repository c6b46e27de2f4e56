//! A record's camera frames, in the order taken, pulled one at a time (a dive's images do not fit in
//! memory), with the mesh's recorded outputs collected on the way.

use crate::compare::Outputs;
use messages::CameraFrameHeader;
use recorder::{ReadError, ReadSummary, Reader, Recorded};
use std::path::{Path, PathBuf};

/// A frame to publish: its header as recorded (the camera's stamp) and its image.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub header: CameraFrameHeader,
    /// Empty when the record has no images (a mesh with ideal perception: the header's truth is
    /// the observation).
    pub image: Vec<u8>,
}

/// Why a record cannot be replayed; names the file and the frame.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error(
        "{}: the frame of step seq {seq} (episode {episode}, step {step}) has no image, though the record has images: it was recorded with --frame-every above 1, and a replay needs every frame (a record with the camera's compressed stream, /camera_video, replays its frames from the stream with a replay built with `--features video`)",
        path.display()
    )]
    Decimated {
        path: PathBuf,
        seq: u64,
        episode: u32,
        step: u32,
    },
    #[error(
        "{}: the frame of step seq {seq} (episode {episode}, step {step}) has no image, and the record's stream gives no picture of it (its unit is not in the record)",
        path.display()
    )]
    NotInStream {
        path: PathBuf,
        seq: u64,
        episode: u32,
        step: u32,
    },
    #[error(
        "{}: the image at {time_ns} ns follows no frame header of that time",
        path.display()
    )]
    Orphan { path: PathBuf, time_ns: u64 },
    #[error(
        "{}: the frame of step seq {seq} is {got_width}x{got_height}, its header says {width}x{height}",
        path.display()
    )]
    Size {
        path: PathBuf,
        seq: u64,
        width: u32,
        height: u32,
        got_width: u32,
        got_height: u32,
    },
    #[cfg(feature = "video")]
    #[error(transparent)]
    Video(#[from] crate::video::VideoError),
    #[error(
        "{}: the frame of step seq {seq} at {time_ns} ns decoded from the record's stream differs from its recorded image",
        path.display()
    )]
    VideoDiffers {
        path: PathBuf,
        seq: u64,
        time_ns: u64,
    },
    #[error("{}: frame seq {seq} does not follow seq {previous}", path.display())]
    Order {
        path: PathBuf,
        seq: u64,
        previous: u64,
    },
}

/// The frames of a record.
pub struct Frames {
    path: PathBuf,
    reader: Reader,
    /// A header read, its image not yet (it follows its header).
    pending: Option<CameraFrameHeader>,
    /// Whether the record's frames carry images (decided by the first frame).
    images: Option<bool>,
    last_seq: Option<u64>,
    frames: u64,
    /// The mesh's outputs as recorded, collected while reading.
    pub recorded: Outputs,
    /// The record's compressed stream, decoded (opened at the first frame, of its size).
    #[cfg(feature = "video")]
    video: Option<crate::video::VideoFrames>,
    /// Frames taken from the stream, and of them those checked against a recorded image.
    pub from_stream: u64,
    pub checked: u64,
    /// Frames taken from the stream though the record does not decode them as the camera did
    /// (`video::Decoded::decodable`), for want of an image: they may differ from the dive's.
    pub undecodable: u64,
}

impl Frames {
    pub fn open(path: &Path) -> Result<Frames, ReplayError> {
        Ok(Frames {
            path: path.to_owned(),
            reader: Reader::open(path)?,
            pending: None,
            images: None,
            last_seq: None,
            frames: 0,
            recorded: Outputs::default(),
            #[cfg(feature = "video")]
            video: None,
            from_stream: 0,
            checked: 0,
            undecodable: 0,
        })
    }

    /// Frames yielded so far.
    pub fn yielded(&self) -> u64 {
        self.frames
    }

    fn emit(
        &mut self,
        header: CameraFrameHeader,
        image: Option<recorder::image::Image>,
    ) -> Result<Frame, ReplayError> {
        let seq = header.stamp.seq;
        if let Some(previous) = self.last_seq.filter(|&p| seq <= p) {
            return Err(ReplayError::Order {
                path: self.path.clone(),
                seq,
                previous,
            });
        }
        self.last_seq = Some(seq);
        #[cfg(feature = "video")]
        let image = self.image_of_stream(&header, image)?;
        let has = *self.images.get_or_insert(image.is_some());
        if has && image.is_none() {
            return Err(ReplayError::Decimated {
                path: self.path.clone(),
                seq,
                episode: header.stamp.episode,
                step: header.stamp.step,
            });
        }
        let image = match image {
            Some(i) => {
                if (i.width, i.height) != (header.width, header.height) {
                    return Err(ReplayError::Size {
                        path: self.path.clone(),
                        seq,
                        width: header.width,
                        height: header.height,
                        got_width: i.width,
                        got_height: i.height,
                    });
                }
                i.data
            }
            None => Vec::new(),
        };
        self.frames += 1;
        Ok(Frame { header, image })
    }

    /// The frame's image from the record's stream where it gives it (checked against the image
    /// recorded, if any), else the image recorded.
    #[cfg(feature = "video")]
    fn image_of_stream(
        &mut self,
        header: &CameraFrameHeader,
        image: Option<recorder::image::Image>,
    ) -> Result<Option<recorder::image::Image>, ReplayError> {
        if header.width == 0 || header.height == 0 {
            return Ok(image);
        }
        let video = match &mut self.video {
            Some(v) => v,
            None => self.video.insert(crate::video::VideoFrames::open(
                &self.path,
                header.width,
                header.height,
            )?),
        };
        let decoded = video.frame_at(header.stamp.time_ns)?;
        let stream = video.units > 0;
        let seq = header.stamp.seq;
        let image = match (decoded, image) {
            (Some(d), Some(recorded)) if !d.decodable => {
                // The record does not decode this frame as the camera did: its image is the frame.
                return Ok(Some(recorded));
            }
            (Some(d), Some(recorded)) => {
                // Of several pictures of this time (the source sent the frame again), the image
                // says which one the camera published.
                if recorded.data != d.image && !d.again.contains(&recorded.data) {
                    return Err(ReplayError::VideoDiffers {
                        path: self.path.clone(),
                        seq,
                        time_ns: header.stamp.time_ns,
                    });
                }
                self.checked += 1;
                recorded.data
            }
            (Some(d), None) => {
                if !d.decodable {
                    self.undecodable += 1;
                }
                d.image
            }
            (None, None) if stream => {
                return Err(ReplayError::NotInStream {
                    path: self.path.clone(),
                    seq,
                    episode: header.stamp.episode,
                    step: header.stamp.step,
                });
            }
            (None, recorded) => return Ok(recorded),
        };
        self.from_stream += 1;
        Ok(Some(recorder::image::Image {
            time_ns: header.stamp.time_ns,
            width: header.width,
            height: header.height,
            data: image,
        }))
    }

    /// The next frame, or `None` at the end of the record.
    pub fn next_frame(&mut self) -> Result<Option<Frame>, ReplayError> {
        loop {
            let Some(m) = self.reader.next().transpose()? else {
                return match self.pending.take() {
                    Some(h) => self.emit(h, None).map(Some),
                    None => Ok(None),
                };
            };
            match m.item {
                Recorded::FrameHeader(h) => {
                    if let Some(previous) = self.pending.replace(h) {
                        return self.emit(previous, None).map(Some);
                    }
                }
                Recorded::Image(image) => match self.pending.take() {
                    Some(h) if h.stamp.time_ns == image.time_ns => {
                        return self.emit(h, Some(image)).map(Some);
                    }
                    _ => {
                        return Err(ReplayError::Orphan {
                            path: self.path.clone(),
                            time_ns: image.time_ns,
                        });
                    }
                },
                other => {
                    self.recorded.add(&other);
                    if let Some(h) = self.pending.take() {
                        return self.emit(h, None).map(Some);
                    }
                }
            }
        }
    }

    /// Reads the rest of the record (the outputs recorded after the last frame) and returns the
    /// recorded outputs and what the read went through.
    pub fn finish(mut self) -> Result<(Outputs, ReadSummary), ReplayError> {
        while self.next_frame()?.is_some() {}
        Ok((self.recorded, self.reader.summary().clone()))
    }
}
