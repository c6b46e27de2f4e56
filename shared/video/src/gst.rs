//! What the source and the sender share about GStreamer: initialisation, launching a pipeline with
//! an `appsrc` and an `appsink`, the bus, the eventfd that wakes a reader.

use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app as gst_app;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, FromRawFd, OwnedFd};
use std::sync::OnceLock;

/// Why the video path could not be set up or went wrong.
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    #[error("GStreamer could not be initialised: {0}")]
    Init(String),
    /// A pipeline that cannot be built: usually a missing plugin (scripts/install-gstreamer).
    #[error("cannot build the GStreamer pipeline `{pipeline}`: {reason}")]
    Pipeline { pipeline: String, reason: String },
    #[error("the GStreamer pipeline `{pipeline}` failed: {reason}")]
    Failed { pipeline: String, reason: String },
    #[error("{what} {addr}: {source}")]
    Socket {
        what: &'static str,
        addr: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}")]
    Config(String),
    #[error("the encoder gave no access unit within {0:?}")]
    Encoder(std::time::Duration),
}

/// Initialises GStreamer once per process.
pub fn init() -> Result<(), VideoError> {
    static INIT: OnceLock<Result<(), String>> = OnceLock::new();
    INIT.get_or_init(|| gst::init().map_err(|e| e.to_string()))
        .clone()
        .map_err(VideoError::Init)
}

/// A running pipeline with its `appsrc` named `src` and `appsink` named `sink`; stopped (NULL) on drop.
pub struct AppPipeline {
    pub pipeline: gst::Pipeline,
    pub src: gst_app::AppSrc,
    pub sink: gst_app::AppSink,
    pub description: String,
}

impl AppPipeline {
    /// Parses `description` (which names an `appsrc` `src` and an `appsink` `sink`).
    pub fn launch(description: &str) -> Result<Self, VideoError> {
        init()?;
        let bad = |reason: String| VideoError::Pipeline {
            pipeline: description.to_owned(),
            reason,
        };
        let element = gst::parse::launch(description).map_err(|e| bad(e.to_string()))?;
        let pipeline = element
            .downcast::<gst::Pipeline>()
            .map_err(|_| bad("not a pipeline".into()))?;
        let by_name = |name: &str| {
            pipeline
                .by_name(name)
                .ok_or_else(|| bad(format!("no element named `{name}`")))
        };
        let src = by_name("src")?
            .downcast::<gst_app::AppSrc>()
            .map_err(|_| bad("`src` is not an appsrc".into()))?;
        let sink = by_name("sink")?
            .downcast::<gst_app::AppSink>()
            .map_err(|_| bad("`sink` is not an appsink".into()))?;
        Ok(AppPipeline {
            pipeline,
            src,
            sink,
            description: description.to_owned(),
        })
    }

    /// Sets the pipeline playing.
    pub fn play(&self) -> Result<(), VideoError> {
        self.pipeline
            .set_state(gst::State::Playing)
            .map(|_| ())
            .map_err(|e| VideoError::Failed {
                pipeline: self.description.clone(),
                reason: format!("cannot start: {e}"),
            })
    }

    /// The element named `name`.
    pub fn element(&self, name: &str) -> Option<gst::Element> {
        self.pipeline.by_name(name)
    }
}

impl Drop for AppPipeline {
    fn drop(&mut self) {
        let _ = self.pipeline.set_state(gst::State::Null);
    }
}

/// An eventfd: one thread signals, another blocks on it (a WaitSet, poll) and clears it.
pub struct EventFd(OwnedFd);

impl EventFd {
    pub fn new() -> std::io::Result<Self> {
        // SAFETY: eventfd returns a new descriptor or -1.
        let fd = unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) };
        if fd < 0 {
            return Err(std::io::Error::last_os_error());
        }
        // SAFETY: `fd` is a descriptor we own from here on.
        Ok(EventFd(unsafe { OwnedFd::from_raw_fd(fd) }))
    }

    /// Makes the descriptor readable.
    pub fn signal(&self) {
        let one: u64 = 1;
        // SAFETY: writes 8 bytes from a valid u64 to our descriptor; a full counter (EAGAIN) is
        // still readable, which is all a signal needs.
        unsafe {
            libc::write(
                self.0.as_raw_fd(),
                (&one as *const u64).cast(),
                std::mem::size_of::<u64>(),
            );
        }
    }

    /// Clears it; whether it was signalled.
    pub fn clear(&self) -> bool {
        let mut count: u64 = 0;
        // SAFETY: reads 8 bytes into a valid u64 from our non-blocking descriptor.
        let n = unsafe {
            libc::read(
                self.0.as_raw_fd(),
                (&mut count as *mut u64).cast(),
                std::mem::size_of::<u64>(),
            )
        };
        n == std::mem::size_of::<u64>() as isize && count > 0
    }

    pub fn fd(&self) -> BorrowedFd<'_> {
        self.0.as_fd()
    }
}
