//! A recorded stream decoded as the camera decoded it live: the access units the camera gave its
//! decoder (`source::DecodedUnit`, recorded in the flight record), in the same order, through the
//! same pipeline (`avdec_h264 ! videoconvert ! videoscale` to the camera's grey frames), give the
//! same pictures, byte for byte. Replay takes the frames of a dive from its record this way.
//!
//! ```text
//!  feeder thread: units ─▶ appsrc (blocks when 16 are queued) ─▶ the camera's decoding pipeline
//!  caller: next() ◀─ appsink, one picture at a time, until the units end (EOS)
//! ```

use crate::gst::{AppPipeline, VideoError};
use crate::source::{decoder_pipeline, grey_plane};
use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_video as gst_video;
use std::thread::JoinHandle;
use std::time::Duration;

/// A decoded picture.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Picture {
    /// The key its unit was fed with.
    pub key: u64,
    /// The decoder marked it corrupted (data missing in its unit or its references).
    pub corrupted: bool,
    /// 8-bit grey, `width x height`, row by row.
    pub image: Vec<u8>,
}

/// Decodes a stream of access units into the camera's frames.
pub struct StreamDecoder {
    app: AppPipeline,
    width: usize,
    height: usize,
    feeder: Option<JoinHandle<()>>,
}

impl StreamDecoder {
    /// Starts decoding `units` (each an access unit in Annex B, with the key its picture is to
    /// carry: increasing) into `width x height` grey frames, fed from a thread of its own.
    pub fn start<I>(width: u32, height: u32, units: I) -> Result<Self, VideoError>
    where
        I: IntoIterator<Item = (u64, Vec<u8>)>,
        I::IntoIter: Send + 'static,
    {
        // The camera's pipeline, its appsrc made to block rather than queue a whole record.
        let description = decoder_pipeline(width, height).replace(
            "appsrc name=src is-live=true",
            "appsrc name=src is-live=false block=true max-buffers=16",
        );
        let app = AppPipeline::launch(&description)?;
        app.play()?;
        let src = app.src.clone();
        let units = units.into_iter();
        let feeder = std::thread::Builder::new()
            .name("record-decode".into())
            .spawn(move || {
                for (key, bytes) in units {
                    let mut buffer = gst::Buffer::from_slice(bytes);
                    if let Some(b) = buffer.get_mut() {
                        b.set_pts(gst::ClockTime::from_nseconds(key));
                        b.set_dts(gst::ClockTime::from_nseconds(key));
                    }
                    if src.push_buffer(buffer).is_err() {
                        // The pipeline stopped (an error, or the decoder dropped): `next` says why.
                        return;
                    }
                }
                let _ = src.end_of_stream();
            })
            .map_err(|e| VideoError::Failed {
                pipeline: description.clone(),
                reason: format!("cannot start the feeding thread: {e}"),
            })?;
        Ok(StreamDecoder {
            app,
            width: width as usize,
            height: height as usize,
            feeder: Some(feeder),
        })
    }

    /// The next picture; `None` once every unit is decoded. An error when the pipeline failed, or
    /// nothing came for `timeout` (a stalled pipeline).
    pub fn next(&mut self, timeout: Duration) -> Result<Option<Picture>, VideoError> {
        let failed = |reason: String| VideoError::Failed {
            pipeline: self.app.description.clone(),
            reason,
        };
        let sample = self
            .app
            .sink
            .try_pull_sample(gst::ClockTime::from_nseconds(timeout.as_nanos() as u64));
        let Some(sample) = sample else {
            if self.app.sink.is_eos() {
                self.join();
                return Ok(None);
            }
            return Err(failed(self.bus_error().unwrap_or_else(|| {
                format!("no picture and no end of the stream within {timeout:?}")
            })));
        };
        let buffer = sample
            .buffer()
            .ok_or_else(|| failed("a sample without a buffer".into()))?;
        let info = sample
            .caps()
            .and_then(|c| gst_video::VideoInfo::from_caps(c).ok())
            .ok_or_else(|| failed("a sample without video caps".into()))?;
        let mut image = Vec::with_capacity(self.width * self.height);
        grey_plane(buffer, &info, self.width, self.height, &mut image)
            .ok_or_else(|| failed("a decoded picture could not be read".into()))?;
        Ok(Some(Picture {
            key: buffer.pts().map_or(u64::MAX, |t| t.nseconds()),
            corrupted: buffer.flags().contains(gst::BufferFlags::CORRUPTED),
            image,
        }))
    }

    fn bus_error(&self) -> Option<String> {
        let bus = self.app.pipeline.bus()?;
        while let Some(msg) = bus.pop() {
            if let gst::MessageView::Error(e) = msg.view() {
                return Some(format!("{} ({})", e.error(), e.debug().unwrap_or_default()));
            }
        }
        None
    }

    fn join(&mut self) {
        if let Some(f) = self.feeder.take() {
            let _ = f.join();
        }
    }
}

impl Drop for StreamDecoder {
    fn drop(&mut self) {
        // Stopping the pipeline releases a feeder blocked in `push_buffer`.
        let _ = self.app.pipeline.set_state(gst::State::Null);
        self.join();
    }
}
