//! The vehicle's hardware adapters: what the vehicle endpoint's camera reads and what its thruster
//! driver writes (DESIGN.md, "Endpoints"). Everything above them (perception, the behaviours, the
//! surge controller, the allocator's core) is the same code on the `sim` and `vehicle` endpoints.
//!
//! - [`FrameSource`]: the camera's frames, each with its image, size, time and the trial, step and
//!   status the vehicle side knows ([`FrameMeta`]). Implementations:
//!   [`twin::TwinFrameSource`] (the vehicle twin's camera, over its iceoryx2 topic) and
//!   [`replay::ReplaySource`] (a recorded dive: a folder of PGM/PNG frames and an index of times,
//!   written by [`replay::DiveWriter`]; the format is in [`replay`]).
//! - [`ThrusterSink`]: the thrusters' setpoints, and their failsafe stop. Implementations:
//!   [`twin::TwinThrusterSink`] (the twin's thrusters), [`record::RecordSink`] (a file of setpoints
//!   with their times) and [`record::NullSink`] (discards them). [`failsafe::Failsafe`] drives any
//!   sink: it stops the thrusters when fresh setpoints stop coming within the deadline.
//! - [`conformance`]: one suite per trait. Every implementation, and any later one (a real camera
//!   driver, a real thruster board), passes the same suite: `tests/conformance.rs` runs it for each.
//!
//! The twin's side of its wire ([`twin::TwinCameraPort`], [`twin::TwinThrusterPort`]) is here too,
//! so the protocol between the twin and its adapters is written once.

pub mod conformance;
pub mod failsafe;
pub mod record;
pub mod replay;
pub mod twin;

use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::ipc;
pub use messages::{CableObservationData, Stamp, StepStatus, StopCause};
use model::bounds::Fixes;
use std::os::fd::BorrowedFd;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// What the vehicle side knows of a frame besides its image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameMeta {
    /// The source's frame counter: it grows with every frame the device makes, so a gap means frames
    /// were lost on the way. Strictly increasing in what a source yields, except across a device
    /// restart ([`FrameSource::restarts`]).
    pub seq: u64,
    /// The source's clock when the frame was taken (ns): the vehicle's clock (the twin's time, which
    /// runs faster than real time when the twin is accelerated), or the recorded time of a dive.
    pub time_ns: u64,
    pub width: u32,
    pub height: u32,
    /// The trial (the behaviours' episode) and the step within it, 0 at the trial's start.
    pub trial: u32,
    pub step: u32,
    /// Whether the trial goes on, or ended with this frame (cable lost, time limit).
    pub status: StepStatus,
    /// The cable's true line in this frame, where the source knows it (the twin does; a dive when it
    /// was recorded from the twin); `None` otherwise.
    pub truth: Option<CableObservationData>,
    /// The image is not whole: a compressed video frame decoded with data missing (a lost packet in
    /// it, or in a frame it references since the last keyframe) or with a decoder error. The rest of
    /// the metadata is sound; the image must not be trusted (perception does not track on it).
    pub damaged: bool,
}

impl Default for FrameMeta {
    fn default() -> Self {
        FrameMeta {
            seq: 0,
            time_ns: 0,
            width: 0,
            height: 0,
            trial: 0,
            step: 0,
            status: StepStatus::Running,
            truth: None,
            damaged: false,
        }
    }
}

impl FrameMeta {
    /// The image's length in bytes.
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A frame: its metadata and its 8-bit grey image, row by row. Sources fill a caller's frame, so a
/// camera reuses one buffer.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Frame {
    pub meta: FrameMeta,
    pub image: Vec<u8>,
}

/// What [`FrameSource::read`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Read {
    /// A new frame is in the caller's frame.
    Frame,
    /// The device sent its last frame again (the twin in lockstep does, when nobody answered it):
    /// the caller's frame holds it again; publish it again so that whoever missed it can answer.
    Repeat,
    /// No frame yet: read again after `until` (a paced recording), or when the source's listener is
    /// notified or its descriptor readable ([`Wake::Listener`], [`Wake::Readable`]: `until` is
    /// `None`).
    Pending { until: Option<Instant> },
    /// The source has no more frames (the end of a recording). Live sources never end.
    End,
}

/// How a reader waits for a source's next frame without spinning.
pub enum Wake<'a> {
    /// Block on this listener: it is notified when a frame arrives.
    Listener(&'a Listener<ipc::Service>),
    /// Read again at this period (the source's pace); frames due within half a period are yielded.
    Every(Duration),
    /// Block until this file descriptor is readable: the source's own thread signals it (an
    /// eventfd) when a frame or an error is ready. `read` clears it, so a reader reads after every
    /// wake-up, until `Pending`.
    Readable(BorrowedFd<'a>),
}

/// Where a source's frame counter comes from, which tells a reader how to keep its own sequence
/// numbers increasing when it restarts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeqOrigin {
    /// The device counts (the twin, a camera's hardware counter): a reader that restarts sees the
    /// count go on.
    Device,
    /// The source counts from its own start (a recording replayed from the beginning).
    Session,
}

/// A camera: frames in time order, with what the vehicle side knows of each.
///
/// The contract ([`conformance::frame_source`] checks it): frames come in time order (seq strictly
/// increasing, time non-decreasing, within a device session); every frame has the source's
/// [`FrameSource::size`] and a well-formed metadata; with no frame available `read` returns
/// [`Read::Pending`] at once (it never blocks), at the end of a recording [`Read::End`], again and
/// again; malformed input (a broken file, a corrupt message) is a typed [`AdapterError`], never a
/// panic, and the source goes on with the next frame after it.
pub trait FrameSource {
    /// What the source is, for logs and errors (e.g. `twin camera`, `dive /data/dive-3`).
    fn describe(&self) -> String;
    /// The size of every frame (width, height).
    fn size(&self) -> (u32, u32);
    /// How to wait for the next frame.
    fn wake(&self) -> Wake<'_>;
    /// Where the frame counter comes from.
    fn seq_origin(&self) -> SeqOrigin;
    /// How often the device restarted while read (its counter went back); each restart starts a new
    /// session whose frames are in order again.
    fn restarts(&self) -> u64 {
        0
    }
    /// Reads the next frame into `out` if one is due at `now`. It takes `&self` (implementations
    /// keep their position in cells) so that a reader can block on the source's
    /// [`Wake::Listener`] and read from the same source in its wake-up handler.
    fn read(&self, now: Instant, out: &mut Frame) -> Result<Read, AdapterError>;
}

/// The setpoints as written: each under the rule for bad values, and what the rule changed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Applied {
    pub values: [f64; config::MAX_THRUSTERS],
    pub count: usize,
    /// Setpoints that were not finite (made 0) or out of [-1, 1] (clamped).
    pub fixes: Fixes,
}

impl Applied {
    pub fn as_slice(&self) -> &[f64] {
        &self.values[..self.count]
    }
}

/// A setpoint as a thruster may receive it, under the rule for bad values (`model::bounds`): within
/// [-1, 1]; NaN and infinities become 0 (a broken computation must not run a thruster at full
/// power).
pub fn make_safe(value: f64) -> f64 {
    model::bounds::unit(value).0
}

/// The error of a write or flush after `close`, naming the sink.
pub fn closed(sink: &(impl ThrusterSink + ?Sized)) -> AdapterError {
    AdapterError::Closed {
        adapter: sink.describe(),
    }
}

/// Checks the count against the thrusters and puts every setpoint under the rule (see
/// [`make_safe`]), counting what it changed.
pub fn apply(adapter: &str, thrusters: usize, values: &[f64]) -> Result<Applied, AdapterError> {
    if values.len() != thrusters {
        return Err(AdapterError::Count {
            adapter: adapter.to_owned(),
            expected: thrusters,
            got: values.len(),
        });
    }
    let mut out = Applied {
        values: [0.0; config::MAX_THRUSTERS],
        count: thrusters,
        fixes: Fixes::default(),
    };
    for (o, &v) in out.values.iter_mut().zip(values) {
        *o = out.fixes.note(model::bounds::unit(v));
    }
    Ok(out)
}

/// Checks a thruster count when a sink is opened.
pub fn check_thrusters(adapter: &str, thrusters: usize) -> Result<(), AdapterError> {
    if (1..=config::MAX_THRUSTERS).contains(&thrusters) {
        Ok(())
    } else {
        Err(AdapterError::Count {
            adapter: adapter.to_owned(),
            expected: config::MAX_THRUSTERS,
            got: thrusters,
        })
    }
}

/// The thrusters: setpoints in [-1, 1], one per thruster of the layout, each with the stamp of the
/// step it answers; and their failsafe stop.
///
/// The contract ([`conformance::thruster_sink`] checks it): values out of [-1, 1] are clipped and
/// NaN or infinite ones become 0 before they reach a thruster; a wrong number of setpoints is an
/// error and nothing is written; what is written arrives in order; `flush` pushes everything out.
/// `stop` drives every thruster to 0 at once, marked as a stop with its cause (so a device matching
/// answers to its frames never takes it for one), before any write as after; `close` stops the
/// thrusters (unless the last thing sent was a stop) and releases the device, is idempotent, and
/// writing after it is an error. Driven by [`failsafe::Failsafe`], a sink's thrusters stop within
/// the deadline once fresh setpoints stop coming (the suite checks that with every sink too).
pub trait ThrusterSink {
    /// What the sink is, for logs and errors.
    fn describe(&self) -> String;
    /// How many setpoints each write carries.
    fn thrusters(&self) -> usize;
    /// Writes the setpoints answering the step of `stamp`.
    fn write(&mut self, stamp: &Stamp, setpoints: &[f64]) -> Result<Applied, AdapterError>;
    /// Drives every thruster to 0 now, marked as a stop for `cause`, stamped with `stamp` (the last
    /// step written, or an empty stamp before any).
    fn stop(&mut self, stamp: &Stamp, cause: StopCause) -> Result<(), AdapterError>;
    /// Pushes out what is buffered.
    fn flush(&mut self) -> Result<(), AdapterError>;
    /// Stops the thrusters ([`StopCause::Shutdown`]) unless the last thing sent was a stop, flushes
    /// and releases the device; later writes are refused.
    fn close(&mut self) -> Result<(), AdapterError>;
    /// Periodic work of a device that needs some between writes (a link's own heartbeat, a command
    /// repeated at a fixed rate, replies to read): done now, at `now`; returns when to be serviced
    /// next (`None`: only when written to). Called from the thread that writes, so a writer that
    /// hangs stops the device's traffic too. Nothing by default.
    fn service(&mut self, _now: Instant) -> Result<Option<Instant>, AdapterError> {
        Ok(None)
    }
}

/// A sink chosen at run time (`Box<dyn ThrusterSink>`) is a sink.
impl<S: ThrusterSink + ?Sized> ThrusterSink for Box<S> {
    fn describe(&self) -> String {
        (**self).describe()
    }
    fn thrusters(&self) -> usize {
        (**self).thrusters()
    }
    fn write(&mut self, stamp: &Stamp, setpoints: &[f64]) -> Result<Applied, AdapterError> {
        (**self).write(stamp, setpoints)
    }
    fn stop(&mut self, stamp: &Stamp, cause: StopCause) -> Result<(), AdapterError> {
        (**self).stop(stamp, cause)
    }
    fn flush(&mut self) -> Result<(), AdapterError> {
        (**self).flush()
    }
    fn close(&mut self) -> Result<(), AdapterError> {
        (**self).close()
    }
    fn service(&mut self, now: Instant) -> Result<Option<Instant>, AdapterError> {
        (**self).service(now)
    }
}

/// What a sink has sent last, to know whether `close` must stop the thrusters first.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LastSent {
    pub stamp: Stamp,
    pub stopped: bool,
}

impl LastSent {
    /// Records a write (`stopped = false`) or a stop.
    pub fn sent(&mut self, stamp: &Stamp, stopped: bool) {
        *self = LastSent {
            stamp: *stamp,
            stopped,
        };
    }
}

/// Why an adapter could not do its job. Every variant names the adapter, file or frame concerned.
#[derive(Debug, thiserror::Error)]
pub enum AdapterError {
    #[error(transparent)]
    Port(#[from] messages::PortError),
    /// A live source received a frame it cannot use (the frame is skipped).
    #[error("{adapter}: bad frame (seq {seq}): {reason}")]
    BadFrame {
        adapter: String,
        seq: u64,
        reason: String,
    },
    /// A live source received packets it cannot use (not its protocol, truncated, another
    /// stream's): `count` of them since the last report, the first one's `reason`.
    #[error("{adapter}: {count} packet(s) refused: {reason}")]
    BadPacket {
        adapter: String,
        count: u64,
        reason: String,
    },
    /// A frame of another size than the source's.
    #[error(
        "{adapter}: frame {seq} is {got_width}x{got_height}, the source's frames are {width}x{height}"
    )]
    Size {
        adapter: String,
        seq: u64,
        width: u32,
        height: u32,
        got_width: u32,
        got_height: u32,
    },
    #[error("cannot read {}: {source}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot write {}: {source}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A line of a dive's index or of a record file that cannot be used.
    #[error("{}, line {line}: {reason}", file.display())]
    Format {
        file: PathBuf,
        line: usize,
        reason: String,
    },
    /// A dive's frame file that cannot be read or decoded.
    #[error("dive frame {seq}: {source}")]
    Image {
        seq: u64,
        #[source]
        source: vision::FrameError,
    },
    #[error("{adapter}: {got} setpoints, expected {expected}")]
    Count {
        adapter: String,
        expected: usize,
        got: usize,
    },
    #[error("{adapter}: closed")]
    Closed { adapter: String },
    /// A device's own failure (a link that broke, a controller that refused a command), with its
    /// typed error.
    #[error("{adapter}: {source}")]
    Device {
        adapter: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unsafe_setpoints_are_made_safe() {
        let fixes = |non_finite, clamped| Fixes {
            non_finite,
            clamped,
        };
        assert_eq!(make_safe(0.3), 0.3);
        assert_eq!(make_safe(1.0), 1.0);
        assert_eq!(make_safe(1.7), 1.0);
        assert_eq!(make_safe(-2.0), -1.0);
        assert_eq!(make_safe(f64::NAN), 0.0);
        assert_eq!(make_safe(f64::INFINITY), 0.0);
        assert_eq!(make_safe(f64::NEG_INFINITY), 0.0);
        let a = apply("t", 3, &[0.5, 2.0, f64::NAN]).unwrap();
        assert_eq!(a.as_slice(), &[0.5, 1.0, 0.0]);
        assert_eq!(a.fixes, fixes(1, 1));
        assert!(matches!(
            apply("t", 3, &[0.0; 2]),
            Err(AdapterError::Count {
                expected: 3,
                got: 2,
                ..
            })
        ));
        assert!(check_thrusters("t", 0).is_err());
        assert!(check_thrusters("t", config::MAX_THRUSTERS + 1).is_err());
        assert!(check_thrusters("t", 3).is_ok());
    }
}
