//! The vehicle twin's devices and their adapters, over the hardware topics of
//! [`messages::topics::hardware`]:
//!
//! ```text
//!  vehicle-twin ──TwinCameraPort──▶ cabletrack/twin/frame ──▶ TwinFrameSource (the camera service)
//!  vehicle-twin ◀─TwinThrusterPort── cabletrack/twin/thrusters ◀── TwinThrusterSink (the thruster driver)
//! ```
//!
//! A frame is a [`CameraFrameHeader`] (the twin's stamp: its frame counter as `seq`, its clock as
//! `time_ns`, the trial as `episode`, the step and status; the size; the true line) and the image.
//! Setpoints are a [`ThrusterSetpoints`] whose stamp is the one of the step they answer: the twin
//! matches them to its frame by the stamp's time, which the vehicle side copies unchanged (its `seq`
//! is the camera's own). A failsafe stop is a [`ThrusterSetpoints`] of zeros with its cause in
//! `stop`: never an answer to a frame.

use crate::{
    AdapterError, Applied, Frame, FrameMeta, FrameSource, LastSent, Read, SeqOrigin, StopCause,
    ThrusterSink, Wake, apply, check_thrusters,
};
use iceoryx2::prelude::*;
use messages::topics::hardware::{self, TWIN, TWIN_FRAME, TWIN_THRUSTERS};
use messages::{
    CameraFrameHeader, FrameInbox, FrameOutbox, Inbox, Outbox, Stamp, StepStatus, ThrusterSetpoints,
};
use std::cell::Cell;
use std::time::Instant;

type Ipc = ipc::Service;

/// The header a frame travels with.
pub fn header(meta: &FrameMeta) -> CameraFrameHeader {
    CameraFrameHeader {
        stamp: Stamp::new(meta.seq, meta.time_ns, meta.trial, meta.step, meta.status),
        width: meta.width,
        height: meta.height,
        flags: if meta.damaged {
            CameraFrameHeader::DAMAGED
        } else {
            0
        },
        truth: meta.truth.unwrap_or_default(),
        ..Default::default()
    }
}

/// The twin's camera: publishes its frames on `cabletrack/twin/frame`.
pub struct TwinCameraPort {
    out: FrameOutbox,
}

impl TwinCameraPort {
    /// A publisher of frames of at most `max_len` bytes.
    pub fn open(node: &Node<Ipc>, max_len: usize) -> Result<Self, AdapterError> {
        let service = hardware::service_name(TWIN, &TWIN_FRAME);
        Ok(TwinCameraPort {
            out: FrameOutbox::open_service(node, &service, &TWIN_FRAME, max_len)?,
        })
    }

    /// Sends a frame: `fill` writes the `meta.len()` bytes of its image in place.
    pub fn send(&self, meta: &FrameMeta, fill: impl FnOnce(&mut [u8])) -> Result<(), AdapterError> {
        self.send_raw(header(meta), meta.len(), |image| {
            fill(image);
            Ok::<_, std::convert::Infallible>(())
        })
        .map(|_| ())
    }

    /// Sends a header and `len` bytes as they are, consistent or not (tests feed malformed frames
    /// with it).
    pub fn send_raw<E>(
        &self,
        header: CameraFrameHeader,
        len: usize,
        fill: impl FnOnce(&mut [u8]) -> Result<(), E>,
    ) -> Result<Result<(), E>, AdapterError> {
        Ok(self.out.send_with(header, len, fill)?)
    }

    /// Frame sources connected now.
    pub fn subscribers(&self) -> usize {
        self.out.subscribers()
    }
}

/// The twin's thrusters: receives the setpoints written by [`TwinThrusterSink`].
pub struct TwinThrusterPort {
    inbox: Inbox<ThrusterSetpoints>,
}

impl TwinThrusterPort {
    pub fn open(node: &Node<Ipc>) -> Result<Self, AdapterError> {
        let service = hardware::service_name(TWIN, &TWIN_THRUSTERS);
        Ok(TwinThrusterPort {
            inbox: Inbox::open_service(node, &service, &TWIN_THRUSTERS)?,
        })
    }

    /// The next unread setpoints, if any.
    pub fn receive(&self) -> Result<Option<ThrusterSetpoints>, AdapterError> {
        Ok(self.inbox.receive()?)
    }

    /// Notified when setpoints arrive.
    pub fn listener(&self) -> &iceoryx2::port::listener::Listener<Ipc> {
        self.inbox.listener()
    }

    /// Thruster sinks connected now.
    pub fn writers(&self) -> usize {
        self.inbox.publishers()
    }
}

/// The last frame a source yielded.
#[derive(Clone, Copy, Debug)]
struct Last {
    seq: u64,
    time_ns: u64,
}

/// The twin's camera as the vehicle's camera service reads it.
pub struct TwinFrameSource {
    inbox: FrameInbox,
    width: u32,
    height: u32,
    last: Cell<Option<Last>>,
    restarts: Cell<u64>,
}

impl TwinFrameSource {
    /// A reader of the twin's frames, which must be `width x height`.
    pub fn open(node: &Node<Ipc>, width: u32, height: u32) -> Result<Self, AdapterError> {
        let service = hardware::service_name(TWIN, &TWIN_FRAME);
        Ok(TwinFrameSource {
            inbox: FrameInbox::open_service(node, &service, &TWIN_FRAME)?,
            width,
            height,
            last: Cell::new(None),
            restarts: Cell::new(0),
        })
    }

    /// Whether the twin's camera is connected.
    pub fn connected(&self) -> bool {
        self.inbox.publishers() > 0
    }
}

const ADAPTER: &str = "twin camera";

/// Checks a received frame and copies it into `out`: the read's outcome, or an error for a frame that
/// cannot be used.
fn accept(
    (width, height): (u32, u32),
    last: &Cell<Option<Last>>,
    restarts: &Cell<u64>,
    h: &CameraFrameHeader,
    data: &[u8],
    out: &mut Frame,
) -> Result<Read, AdapterError> {
    let seq = h.stamp.seq;
    let bad = |reason: String| AdapterError::BadFrame {
        adapter: ADAPTER.into(),
        seq,
        reason,
    };
    let Some(status) = StepStatus::from_u8(h.stamp.status) else {
        return Err(bad(format!("unknown status {}", h.stamp.status)));
    };
    if (h.width, h.height) != (width, height) {
        return Err(AdapterError::Size {
            adapter: ADAPTER.into(),
            seq,
            width,
            height,
            got_width: h.width,
            got_height: h.height,
        });
    }
    let len = width as usize * height as usize;
    if data.len() != len {
        return Err(bad(format!(
            "{} image bytes, a {width}x{height} frame has {len}",
            data.len()
        )));
    }
    let read = match last.get() {
        Some(l) if seq == l.seq && h.stamp.time_ns == l.time_ns => Read::Repeat,
        Some(l) if seq <= l.seq || h.stamp.time_ns < l.time_ns => {
            // One twin publishes in order: a count or a clock that goes back means the twin started
            // again (a new session).
            restarts.set(restarts.get() + 1);
            tracing::warn!(
                seq,
                last = l.seq,
                time_ns = h.stamp.time_ns,
                last_time_ns = l.time_ns,
                "the twin's frame counter or clock went back: the twin restarted"
            );
            Read::Frame
        }
        _ => Read::Frame,
    };
    last.set(Some(Last {
        seq,
        time_ns: h.stamp.time_ns,
    }));
    out.meta = FrameMeta {
        seq,
        time_ns: h.stamp.time_ns,
        width,
        height,
        trial: h.stamp.episode,
        step: h.stamp.step,
        status,
        truth: Some(h.truth),
        damaged: h.is_damaged(),
    };
    out.image.clear();
    out.image.extend_from_slice(data);
    Ok(read)
}

impl FrameSource for TwinFrameSource {
    fn describe(&self) -> String {
        format!("twin camera ({})", self.inbox.service())
    }

    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn wake(&self) -> Wake<'_> {
        Wake::Listener(self.inbox.listener())
    }

    fn seq_origin(&self) -> SeqOrigin {
        SeqOrigin::Device
    }

    fn restarts(&self) -> u64 {
        self.restarts.get()
    }

    fn read(&self, _now: Instant, out: &mut Frame) -> Result<Read, AdapterError> {
        let size = (self.width, self.height);
        match self
            .inbox
            .receive_with(|h, data| accept(size, &self.last, &self.restarts, h, data, out))?
        {
            Some(result) => result,
            None => Ok(Read::Pending { until: None }),
        }
    }
}

/// The twin's thrusters as the vehicle's thruster driver writes them.
pub struct TwinThrusterSink {
    out: Outbox<ThrusterSetpoints>,
    thrusters: usize,
    last: LastSent,
    closed: bool,
}

impl TwinThrusterSink {
    pub fn open(node: &Node<Ipc>, thrusters: usize) -> Result<Self, AdapterError> {
        check_thrusters("twin thrusters", thrusters)?;
        let service = hardware::service_name(TWIN, &TWIN_THRUSTERS);
        Ok(TwinThrusterSink {
            out: Outbox::open_service(node, &service, &TWIN_THRUSTERS)?,
            thrusters,
            last: LastSent::default(),
            closed: false,
        })
    }

    /// Whether the twin is listening.
    pub fn connected(&self) -> bool {
        self.out.subscribers() > 0
    }
}

impl ThrusterSink for TwinThrusterSink {
    fn describe(&self) -> String {
        format!("twin thrusters ({})", self.out.service())
    }

    fn thrusters(&self) -> usize {
        self.thrusters
    }

    fn write(&mut self, stamp: &Stamp, setpoints: &[f64]) -> Result<Applied, AdapterError> {
        if self.closed {
            return Err(crate::closed(self));
        }
        let applied = apply("twin thrusters", self.thrusters, setpoints)?;
        self.out.send(ThrusterSetpoints {
            stamp: *stamp,
            count: applied.count as u32,
            values: applied.values,
            scale: 1.0,
            ..Default::default()
        })?;
        self.last.sent(stamp, false);
        Ok(applied)
    }

    fn stop(&mut self, stamp: &Stamp, cause: StopCause) -> Result<(), AdapterError> {
        if self.closed {
            return Err(crate::closed(self));
        }
        self.out.send(ThrusterSetpoints {
            stamp: *stamp,
            count: self.thrusters as u32,
            stop: cause as u32,
            scale: 1.0,
            ..Default::default()
        })?;
        self.last.sent(stamp, true);
        Ok(())
    }

    fn flush(&mut self) -> Result<(), AdapterError> {
        if self.closed {
            return Err(crate::closed(self));
        }
        // Every write is sent at once.
        Ok(())
    }

    fn close(&mut self) -> Result<(), AdapterError> {
        if self.closed {
            return Ok(());
        }
        if !self.last.stopped {
            let stamp = self.last.stamp;
            self.stop(&stamp, StopCause::Shutdown)?;
        }
        self.closed = true;
        Ok(())
    }
}
