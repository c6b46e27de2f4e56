//! The camera's frame source over RTP/H.264 ([`RtpSource`]): a BlueROV2's camera as BlueOS streams it,
//! or the vehicle twin's camera on the same wire.
//!
//! ```text
//!  UDP ──▶ receive thread: our socket ─▶ stream::Receiver (sessions, loss, access units, damage)
//!                          ─▶ appsrc (video/x-h264, Annex B, one access unit per buffer)
//!          GStreamer:      avdec_h264 ! videoconvert ! videoscale ! GRAY8 WxH ! appsink
//!          appsink thread: the newest decoded frame into the slot (an older unread one is dropped
//!                          and counted) ─▶ eventfd
//!  camera: wakes on the eventfd (adapters::Wake::Readable) ─▶ read(): the slot's frame
//! ```
//!
//! Our own socket and depacketiser (not `udpsrc ! rtph264depay`) because we judge every packet
//! ourselves: loss, garbage, SSRC changes, and which decoded frame is whole. Each access unit enters
//! the decoder with a timestamp that names it, so each decoded picture finds its unit's verdict and
//! metadata again; the units' bytes are exactly what a recorder would keep
//! ([`SourceConfig::access_units`]).
//!
//! **Metadata.** A frame from the twin carries its [`crate::meta`] element: seq, time, trial, step,
//! status and the true line are the twin's (lockstep matches answers by that time). A real camera
//! sends none: the source numbers the access units itself (`seq`, so frames never handed over show
//! as gaps), takes the time from the RTP timestamp (90 kHz, unwrapped, from the first frame;
//! across a new session it goes on from the last time plus the time between on the receiver's
//! clock), trial 0, `step` the count of frames handed over, status running, no true line.
//!
//! **Damage.** A frame whose unit lost a packet, or that references one since the last intact
//! keyframe, or that the decoder marked corrupted, is handed over with `FrameMeta::damaged`; the
//! decoder keeps going (it needs every unit) and the frames after the next keyframe are whole again.

use crate::gst::{AppPipeline, EventFd, VideoError};
use crate::stream::{self, AccessUnit, Event, Receiver, RtpClock, StreamConfig};
use adapters::{AdapterError, Frame, FrameMeta, FrameSource, Read, SeqOrigin, StepStatus, Wake};
use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app as gst_app;
use gstreamer_video as gst_video;
use gstreamer_video::prelude::*;
use std::cell::{Cell, RefCell};
use std::collections::{BTreeMap, VecDeque};
use std::net::{SocketAddr, UdpSocket};
use std::os::fd::AsRawFd;
use std::sync::mpsc::SyncSender;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How the source listens and what it makes.
#[derive(Clone, Debug)]
pub struct SourceConfig {
    /// Where to listen (BlueOS streams to port 5600).
    pub bind: SocketAddr,
    /// The frames handed over: every decoded picture is scaled to this size (the scenario's camera).
    pub width: u32,
    pub height: u32,
    /// H.264's dynamic payload type (96 on BlueOS).
    pub payload_type: u8,
    /// When no packet came for this long, say so (once) and take the stream as stopped.
    pub quiet: Duration,
    /// Units in the decoder not yet out beyond which the source stops feeding it until the next
    /// keyframe (a decoder that cannot keep up must not queue without bound).
    pub max_backlog: u64,
    /// Every access unit given to the decoder, in that order (its H.264 bytes, verdict and
    /// metadata), for a recorder: sent without blocking, so a full channel loses units (counted),
    /// never the stream.
    pub access_units: Option<SyncSender<DecodedUnit>>,
}

impl SourceConfig {
    /// Listening on `bind` for frames of `width x height`, BlueOS's payload type.
    pub fn new(bind: SocketAddr, width: u32, height: u32) -> Self {
        SourceConfig {
            bind,
            width,
            height,
            payload_type: 96,
            quiet: Duration::from_secs(2),
            max_backlog: 30,
            access_units: None,
        }
    }
}

/// An access unit as the decoder got it, for a recorder: fed in the same order to the same
/// decoder ([`crate::decode`]), the units give the same pictures.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodedUnit {
    /// As received; a keyframe without its own SPS or PPS carries the last ones the stream sent
    /// ([`crate::h264::ParameterSets`]).
    pub unit: AccessUnit,
    /// The time of the frame it decodes to: `FrameMeta::time_ns` of that frame (the twin's time
    /// from its metadata, else the RTP clock's).
    pub time_ns: u64,
    /// The decoder was started afresh before this unit (after an error): what it held is gone.
    pub decoder_restarted: bool,
}

/// What the source has seen and done since it opened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SourceStats {
    /// The receiver's counts: datagrams, refused, lost, sessions, access units, damaged, ...
    pub stream: stream::Counts,
    /// Access units given to the decoder.
    pub decoding: u64,
    /// Pictures out of the decoder.
    pub decoded: u64,
    /// Of them, marked corrupted by the decoder.
    pub corrupted: u64,
    /// Decoded pictures replaced by a newer one before they were read.
    pub replaced: u64,
    /// Frames handed over by `read` (repeats not counted).
    pub yielded: u64,
    /// Access units never fed to the decoder: empty, refused metadata, or skipped while the
    /// decoder was behind.
    pub skipped: u64,
    /// Access units lost to a full recorder channel.
    pub tap_lost: u64,
    /// The stream's picture size as last decoded, and how often it changed.
    pub picture: Option<(u32, u32)>,
    pub picture_changes: u64,
    /// Times the decoding pipeline was started again after an error.
    pub pipeline_restarts: u64,
    /// Times the stream went quiet for [`SourceConfig::quiet`] after packets had come.
    pub quiet: u64,
}

/// What the receive thread knows of a unit sent to the decoder.
#[derive(Clone, Copy, Debug)]
struct Unit {
    number: u64,
    session: u64,
    time_ns: u64,
    damaged: bool,
    /// The twin's metadata, checked.
    meta: Option<FrameMeta>,
}

/// A decoded frame waiting to be read.
struct Decoded {
    unit: Unit,
    corrupted: bool,
    image: Vec<u8>,
}

/// Reports for `read` to return, oldest first, at most this many kept.
const MAX_REPORTS: usize = 16;

#[derive(Default)]
struct State {
    slot: Option<Decoded>,
    /// The buffer of the last frame read, reused for the next.
    spare: Vec<u8>,
    /// Units in the decoder, by the timestamp they entered it with.
    in_decoder: BTreeMap<u64, Unit>,
    /// The number of the last unit out of the decoder.
    decoded_number: u64,
    reports: VecDeque<AdapterError>,
    /// Packets refused since the last report: how many, the first one's reason.
    refused: Option<(u64, String)>,
    /// The decoding pipeline posted an error: the receive thread starts it again.
    failed: Option<String>,
    stats: SourceStats,
}

struct Shared {
    describe: String,
    state: Mutex<State>,
    changed: Condvar,
    ready: EventFd,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Wakes the reader (and anyone waiting on the stats).
    fn wake(&self) {
        self.changed.notify_all();
        self.ready.signal();
    }
}

/// The last frame handed over.
struct Last {
    frame: Frame,
    session: u64,
}

/// The camera's frames from an RTP/H.264 stream (see the module docs).
pub struct RtpSource {
    shared: Arc<Shared>,
    local: SocketAddr,
    size: (u32, u32),
    stop: Arc<EventFd>,
    thread: Option<JoinHandle<()>>,
    last: RefCell<Option<Last>>,
    restarts: Cell<u64>,
    device_counts: Cell<bool>,
}

/// The decoding pipeline for frames of `width x height` (also a record's, `crate::decode`).
pub(crate) fn decoder_pipeline(width: u32, height: u32) -> String {
    // Slice threads only: frame threads hold pictures back, and one decoded frame per unit, at
    // once, is the point. videoscale after videoconvert scales one grey plane, not three.
    format!(
        "appsrc name=src is-live=true format=time do-timestamp=false \
           caps=video/x-h264,stream-format=byte-stream,alignment=au \
         ! avdec_h264 name=decoder thread-type=slice output-corrupt=true qos=false \
         ! videoconvert ! videoscale \
         ! video/x-raw,format=GRAY8,width={width},height={height} \
         ! appsink name=sink sync=false qos=false max-buffers=4"
    )
}

impl RtpSource {
    /// Binds the socket, starts the decoder and the receive thread.
    pub fn open(config: SourceConfig) -> Result<Self, VideoError> {
        if config.width == 0
            || config.height == 0
            || config.width % 2 == 1
            || config.height % 2 == 1
        {
            return Err(VideoError::Config(format!(
                "a frame size of {}x{}: both must be even and > 0",
                config.width, config.height
            )));
        }
        let socket = UdpSocket::bind(config.bind).map_err(|source| VideoError::Socket {
            what: "cannot listen on",
            addr: config.bind.to_string(),
            source,
        })?;
        let local = socket.local_addr().map_err(|source| VideoError::Socket {
            what: "cannot read the address of",
            addr: config.bind.to_string(),
            source,
        })?;
        socket
            .set_nonblocking(true)
            .map_err(|source| VideoError::Socket {
                what: "cannot make non-blocking",
                addr: local.to_string(),
                source,
            })?;
        // A 1080p keyframe is hundreds of packets: give the kernel room for a burst (it caps this
        // at net.core.rmem_max).
        set_receive_buffer(&socket, 4 << 20);
        let describe = format!("rtp camera (udp {local})");
        let ready = EventFd::new().map_err(|source| VideoError::Socket {
            what: "cannot create an eventfd for",
            addr: local.to_string(),
            source,
        })?;
        let stop = Arc::new(EventFd::new().map_err(|source| VideoError::Socket {
            what: "cannot create an eventfd for",
            addr: local.to_string(),
            source,
        })?);
        let shared = Arc::new(Shared {
            describe: describe.clone(),
            state: Mutex::new(State::default()),
            changed: Condvar::new(),
            ready,
        });
        let decoder = Decoder::start(&shared, config.width, config.height)?;
        let size = (config.width, config.height);
        let thread = {
            let shared = shared.clone();
            let stop = stop.clone();
            std::thread::Builder::new()
                .name("rtp-receive".into())
                .spawn(move || receive(socket, config, decoder, shared, stop))
                .map_err(|source| VideoError::Socket {
                    what: "cannot start the receive thread for",
                    addr: local.to_string(),
                    source,
                })?
        };
        tracing::info!(addr = %local, "listening for RTP/H.264");
        Ok(RtpSource {
            shared,
            local,
            size,
            stop,
            thread: Some(thread),
            last: RefCell::new(None),
            restarts: Cell::new(0),
            device_counts: Cell::new(false),
        })
    }

    /// The address the source listens on (the port chosen, when bound to port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    pub fn stats(&self) -> SourceStats {
        self.shared.lock().stats
    }

    /// A handle on the source's stats that outlives a borrow of the source (a test rig's, a
    /// recorder's).
    pub fn watch(&self) -> Watch {
        Watch(self.shared.clone())
    }

    /// Blocks until `done` holds for the stats (then the stats) or `timeout` passes (`None`).
    pub fn wait_for(
        &self,
        timeout: Duration,
        done: impl FnMut(&SourceStats) -> bool,
    ) -> Option<SourceStats> {
        self.watch().wait_for(timeout, done)
    }
}

/// The stats of an [`RtpSource`], and a wait on them.
#[derive(Clone)]
pub struct Watch(Arc<Shared>);

impl Watch {
    pub fn stats(&self) -> SourceStats {
        self.0.lock().stats
    }

    /// Blocks until `done` holds for the stats (then the stats) or `timeout` passes (`None`).
    pub fn wait_for(
        &self,
        timeout: Duration,
        mut done: impl FnMut(&SourceStats) -> bool,
    ) -> Option<SourceStats> {
        let deadline = Instant::now() + timeout;
        let mut state = self.0.lock();
        loop {
            if done(&state.stats) {
                return Some(state.stats);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            state = self
                .0
                .changed
                .wait_timeout(state, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

impl RtpSource {
    /// The frame for a decoded picture, and whether it is new, a repeat, or refused; the buffer
    /// given back is the one to reuse.
    fn judge(&self, d: Decoded, out: &mut Frame) -> (Result<Read, AdapterError>, Vec<u8>) {
        let (w, h) = self.size;
        let mut last = self.last.borrow_mut();
        let mut meta = match d.unit.meta {
            Some(m) => {
                self.device_counts.set(true);
                m
            }
            None => FrameMeta {
                seq: d.unit.number,
                time_ns: d.unit.time_ns,
                width: w,
                height: h,
                trial: 0,
                step: self.shared.lock().stats.yielded as u32,
                status: StepStatus::Running,
                truth: None,
                damaged: false,
            },
        };
        meta.damaged = d.unit.damaged || d.corrupted;
        if let Some(l) = last.as_ref() {
            let lm = &l.frame.meta;
            if meta.seq == lm.seq && meta.time_ns == lm.time_ns {
                // The device sent its last frame again (the twin in lockstep): the same frame.
                out.clone_from(&l.frame);
                return (Ok(Read::Repeat), d.image);
            }
            if meta.seq <= lm.seq || meta.time_ns < lm.time_ns {
                if d.unit.session == l.session {
                    return (
                        Err(AdapterError::BadFrame {
                            adapter: self.shared.describe.clone(),
                            seq: meta.seq,
                            reason: format!(
                                "its frame counter or clock went back (seq {} at {} ns after seq {} at {} ns) within one stream",
                                meta.seq, meta.time_ns, lm.seq, lm.time_ns
                            ),
                        }),
                        d.image,
                    );
                }
                // A new stream whose count starts again: the device restarted.
                self.restarts.set(self.restarts.get() + 1);
                tracing::warn!(
                    seq = meta.seq,
                    last = lm.seq,
                    "the camera's frame counter went back with a new stream: the device restarted"
                );
            }
        }
        out.meta = meta;
        let old = std::mem::replace(&mut out.image, d.image);
        let l = last.get_or_insert_with(|| Last {
            frame: Frame::default(),
            session: 0,
        });
        l.frame.clone_from(out);
        l.session = d.unit.session;
        (Ok(Read::Frame), old)
    }
}

impl Drop for RtpSource {
    fn drop(&mut self) {
        self.stop.signal();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl FrameSource for RtpSource {
    fn describe(&self) -> String {
        self.shared.describe.clone()
    }

    fn size(&self) -> (u32, u32) {
        self.size
    }

    fn wake(&self) -> Wake<'_> {
        Wake::Readable(self.shared.ready.fd())
    }

    fn seq_origin(&self) -> SeqOrigin {
        if self.device_counts.get() {
            SeqOrigin::Device
        } else {
            SeqOrigin::Session
        }
    }

    fn restarts(&self) -> u64 {
        self.restarts.get()
    }

    fn read(&self, _now: Instant, out: &mut Frame) -> Result<Read, AdapterError> {
        // Cleared first: whatever is put in after this signals again.
        self.shared.ready.clear();
        let decoded = {
            let mut state = self.shared.lock();
            if let Some(e) = state.reports.pop_front() {
                return Err(e);
            }
            if let Some((count, reason)) = state.refused.take() {
                return Err(AdapterError::BadPacket {
                    adapter: self.shared.describe.clone(),
                    count,
                    reason,
                });
            }
            match state.slot.take() {
                Some(d) => d,
                None => return Ok(Read::Pending { until: None }),
            }
        };
        let (result, spare) = self.judge(decoded, out);
        let mut state = self.shared.lock();
        state.spare = spare;
        if matches!(result, Ok(Read::Frame)) {
            state.stats.yielded += 1;
        }
        result
    }
}

fn set_receive_buffer(socket: &UdpSocket, bytes: i32) {
    // SAFETY: setsockopt with a valid int option value on our socket.
    let r = unsafe {
        libc::setsockopt(
            socket.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_RCVBUF,
            (&bytes as *const i32).cast(),
            std::mem::size_of::<i32>() as libc::socklen_t,
        )
    };
    if r != 0 {
        tracing::debug!(
            "cannot set the receive buffer: {}",
            std::io::Error::last_os_error()
        );
    }
}

/// The decoding pipeline, and what it calls back.
struct Decoder {
    app: AppPipeline,
}

impl Decoder {
    fn start(shared: &Arc<Shared>, width: u32, height: u32) -> Result<Self, VideoError> {
        let app = AppPipeline::launch(&decoder_pipeline(width, height))?;
        let (w, h) = (width as usize, height as usize);
        {
            let shared = shared.clone();
            app.sink.set_callbacks(
                gst_app::AppSinkCallbacks::builder()
                    .new_sample(move |sink| {
                        let sample = sink.pull_sample().map_err(|_| gst::FlowError::Eos)?;
                        on_picture(&shared, &sample, w, h);
                        Ok(gst::FlowSuccess::Ok)
                    })
                    .build(),
            );
        }
        // The stream's own picture size, from the decoder's caps.
        if let Some(pad) = app.element("decoder").and_then(|d| d.static_pad("src")) {
            let shared = shared.clone();
            pad.add_probe(gst::PadProbeType::EVENT_DOWNSTREAM, move |_, info| {
                if let Some(gst::PadProbeData::Event(ev)) = &info.data
                    && let gst::EventView::Caps(c) = ev.view()
                    && let Some(s) = c.caps().structure(0)
                    && let (Ok(w), Ok(h)) = (s.get::<i32>("width"), s.get::<i32>("height"))
                {
                    let now = (w.max(0) as u32, h.max(0) as u32);
                    let mut state = shared.lock();
                    let before = state.stats.picture.replace(now);
                    if before.is_some_and(|b| b != now) {
                        state.stats.picture_changes += 1;
                    }
                    drop(state);
                    match before {
                        Some(b) if b != now => tracing::warn!(
                            from = %format!("{}x{}", b.0, b.1),
                            to = %format!("{}x{}", now.0, now.1),
                            "the stream's picture size changed"
                        ),
                        None => tracing::info!(size = %format!("{}x{}", now.0, now.1), "decoding the stream"),
                        _ => {}
                    }
                }
                gst::PadProbeReturn::Ok
            });
        }
        if let Some(bus) = app.pipeline.bus() {
            let shared = shared.clone();
            bus.set_sync_handler(move |_, msg| {
                match msg.view() {
                    gst::MessageView::Error(e) => {
                        let reason = format!("{} ({})", e.error(), e.debug().unwrap_or_default());
                        tracing::error!("the decoder failed: {reason}");
                        shared.lock().failed = Some(reason);
                        shared.wake();
                    }
                    gst::MessageView::Warning(w) => {
                        tracing::warn!("the decoder: {}", w.error());
                    }
                    _ => {}
                }
                gst::BusSyncReply::Drop
            });
        }
        app.play()?;
        Ok(Decoder { app })
    }

    /// Feeds one access unit, under the timestamp `key`.
    fn push(&self, bytes: Vec<u8>, key: u64) -> Result<(), gst::FlowError> {
        let mut buffer = gst::Buffer::from_slice(bytes);
        {
            let b = buffer.get_mut().expect("a new buffer");
            b.set_pts(gst::ClockTime::from_nseconds(key));
            b.set_dts(gst::ClockTime::from_nseconds(key));
        }
        self.app.src.push_buffer(buffer).map(|_| ())
    }
}

/// A decoded picture: finds its unit, copies the grey plane into the slot, wakes the reader.
fn on_picture(shared: &Shared, sample: &gst::Sample, width: usize, height: usize) {
    let Some(buffer) = sample.buffer() else {
        return;
    };
    let Some(caps) = sample.caps() else {
        return;
    };
    let Ok(info) = gst_video::VideoInfo::from_caps(caps) else {
        return;
    };
    let key = buffer.pts().map_or(u64::MAX, |t| t.nseconds());
    let corrupted = buffer.flags().contains(gst::BufferFlags::CORRUPTED);
    let mut state = shared.lock();
    let Some(unit) = state.in_decoder.remove(&key) else {
        // A unit refused when it arrived (its metadata): already reported.
        state.stats.decoded += 1;
        drop(state);
        shared.changed.notify_all();
        return;
    };
    state.decoded_number = state.decoded_number.max(unit.number);
    // Units that never came out (the decoder dropped them) are forgotten.
    let horizon = unit.number.saturating_sub(64);
    state.in_decoder.retain(|_, u| u.number >= horizon);
    state.stats.corrupted += corrupted as u64;
    let mut image = match state.slot.take() {
        Some(older) => {
            state.stats.replaced += 1;
            older.image
        }
        None => std::mem::take(&mut state.spare),
    };
    drop(state);
    let copied = grey_plane(buffer, &info, width, height, &mut image);
    let mut state = shared.lock();
    // Counted once the picture is in the slot: whoever waits on the count finds it there.
    state.stats.decoded += 1;
    if copied.is_none() {
        tracing::warn!("a decoded picture could not be read");
        state.spare = image;
        drop(state);
        shared.changed.notify_all();
        return;
    }
    state.slot = Some(Decoded {
        unit,
        corrupted,
        image,
    });
    drop(state);
    shared.wake();
}

/// Copies the grey plane of a decoded `width x height` picture into `image` (rows without their
/// padding); `None` when it is not readable or not of that size.
pub(crate) fn grey_plane(
    buffer: &gst::BufferRef,
    info: &gst_video::VideoInfo,
    width: usize,
    height: usize,
    image: &mut Vec<u8>,
) -> Option<()> {
    let frame = gst_video::VideoFrameRef::from_buffer_ref_readable(buffer, info).ok()?;
    let stride = *frame.plane_stride().first()? as usize;
    let data = frame.plane_data(0).ok()?;
    if frame.width() as usize != width || frame.height() as usize != height {
        return None;
    }
    image.clear();
    for row in 0..height {
        image.extend_from_slice(data.get(row * stride..row * stride + width)?);
    }
    Some(())
}

/// The receive thread: the socket through the stream's judgement into the decoder.
fn receive(
    socket: UdpSocket,
    config: SourceConfig,
    mut decoder: Decoder,
    shared: Arc<Shared>,
    stop: Arc<EventFd>,
) {
    let mut receiver = Receiver::new(StreamConfig {
        payload_type: config.payload_type,
        ..StreamConfig::default()
    });
    let mut clock = RtpClock::default();
    let mut events = Vec::new();
    let mut buf = vec![0u8; 65536];
    let mut active = false;
    let mut skipping = false;
    let mut last_key: Option<(u64, u64)> = None;
    let mut notes = Notes::default();
    let mut fed = Fed::default();
    let (w, h) = (config.width, config.height);
    loop {
        let mut fds = [
            libc::pollfd {
                fd: socket.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            },
            libc::pollfd {
                fd: stop.fd().as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            },
        ];
        // Wait for packets without a timeout, except once while a stream runs: its silence is
        // news.
        let timeout = if active {
            config.quiet.as_millis().min(i32::MAX as u128) as i32
        } else {
            -1
        };
        // SAFETY: two valid pollfds.
        let n = unsafe { libc::poll(fds.as_mut_ptr(), 2, timeout) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            tracing::error!("the receive thread cannot wait: {e}");
            return;
        }
        if fds[1].revents != 0 {
            return;
        }
        if n == 0 {
            active = false;
            shared.lock().stats.quiet += 1;
            // The unit in progress will not be completed.
            receiver.flush(&mut events);
            tracing::warn!(
                quiet_s = config.quiet.as_secs_f64(),
                "no packets from the camera: the stream stopped"
            );
        }
        // A decoder that failed is started again; what follows is damaged until a keyframe.
        let failed = shared.lock().failed.take();
        if let Some(reason) = failed {
            match Decoder::start(&shared, w, h) {
                Ok(d) => {
                    decoder = d;
                    let mut state = shared.lock();
                    state.stats.pipeline_restarts += 1;
                    state.in_decoder.clear();
                    drop(state);
                    receiver.damage();
                    fed.restarted = true;
                    tracing::warn!("the decoder was started again after: {reason}");
                }
                Err(e) => tracing::error!("the decoder cannot be started again: {e}"),
            }
        }
        loop {
            match socket.recv_from(&mut buf) {
                Ok((len, _from)) => {
                    if !active {
                        active = true;
                        tracing::info!("packets from the camera");
                    }
                    receiver.push(&buf[..len], Instant::now(), &mut events);
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    tracing::warn!("receiving: {e}");
                    break;
                }
            }
            if events.len() > 64 {
                break;
            }
        }
        for event in events.drain(..) {
            match event {
                Event::Session {
                    session,
                    ssrc,
                    previous,
                    jumped,
                } => {
                    tracing::info!(
                        session,
                        ssrc = %format!("{ssrc:08x}"),
                        previous = ?previous.map(|p| format!("{p:08x}")),
                        jumped,
                        "a new stream session"
                    );
                    skipping = false;
                }
                Event::Lost(n) => notes.lost(n),
                Event::Refused(why) => {
                    notes.refused(&why);
                    let mut state = shared.lock();
                    match state.refused.as_mut() {
                        Some((count, _)) => *count += 1,
                        None => state.refused = Some((1, why.to_string())),
                    }
                    drop(state);
                    shared.wake();
                }
                Event::AccessUnit(unit) => {
                    let key = timestamp_key(&mut clock, &mut last_key, &unit);
                    feed(
                        &shared,
                        &decoder,
                        &config,
                        &mut skipping,
                        &mut fed,
                        unit,
                        key,
                        (w, h),
                    );
                }
            }
        }
        shared.lock().stats.stream = receiver.counts();
        shared.changed.notify_all();
    }
}

/// The unit's time on the RTP clock, and the timestamp it enters the decoder with: that time,
/// made unique (the twin re-sends a frame with the same RTP timestamp).
fn timestamp_key(
    clock: &mut RtpClock,
    last: &mut Option<(u64, u64)>,
    unit: &AccessUnit,
) -> (u64, u64) {
    let time = clock.time_ns(unit.session, unit.timestamp, unit.arrival);
    let key = match *last {
        Some((last_time, last_key)) if time <= last_time => last_key + 1,
        _ => time,
    };
    *last = Some((time.max(last.map_or(0, |l| l.0)), key));
    (time, key)
}

/// What the receive thread keeps about the units it gives the decoder.
#[derive(Default)]
struct Fed {
    parameter_sets: crate::h264::ParameterSets,
    /// The decoder was started again since the last unit fed.
    restarted: bool,
}

/// One access unit to the decoder (or not), remembered under its key.
#[allow(clippy::too_many_arguments)]
fn feed(
    shared: &Shared,
    decoder: &Decoder,
    config: &SourceConfig,
    skipping: &mut bool,
    fed: &mut Fed,
    mut unit: AccessUnit,
    (time_ns, key): (u64, u64),
    (w, h): (u32, u32),
) {
    let meta = match &unit.meta {
        None => Ok(None),
        Some(Err(e)) => Err(e.to_string()),
        Some(Ok(m)) => m.frame_meta(w, h).map(Some),
    };
    let seq = match &unit.meta {
        Some(Ok(m)) => m.seq,
        _ => unit.number,
    };
    let mut state = shared.lock();
    let behind = state.decoding_backlog();
    if unit.keyframe {
        *skipping = false;
    } else if behind > config.max_backlog && !*skipping {
        *skipping = true;
        tracing::warn!(
            behind,
            "the decoder is behind: skipping the stream until its next keyframe"
        );
    }
    let skip = unit.bytes.is_empty() || *skipping;
    let refused = meta.as_ref().err().cloned();
    if let Some(reason) = &refused {
        state.reports.push_back(AdapterError::BadFrame {
            adapter: shared.describe.clone(),
            seq,
            reason: format!("frame metadata: {reason}"),
        });
        while state.reports.len() > MAX_REPORTS {
            state.reports.pop_front();
        }
    }
    if skip || refused.is_some() {
        state.stats.skipped += 1;
    }
    if !skip {
        if let Ok(meta) = &meta {
            let meta = *meta;
            state.in_decoder.insert(
                key,
                Unit {
                    number: unit.number,
                    session: unit.session,
                    time_ns,
                    damaged: unit.damaged,
                    meta,
                },
            );
        }
        state.stats.decoding += 1;
    }
    drop(state);
    if refused.is_some() {
        shared.wake();
    }
    if skip {
        return;
    }
    fed.parameter_sets.complete(&mut unit.bytes);
    let bytes = unit.bytes.clone();
    // The recorder's copy first: the unit is published before the frame it decodes to.
    if let Some(tap) = &config.access_units {
        let frame_time = match &meta {
            Ok(Some(m)) => m.time_ns,
            _ => time_ns,
        };
        let tapped = DecodedUnit {
            unit,
            time_ns: frame_time,
            decoder_restarted: std::mem::take(&mut fed.restarted),
        };
        if tap.try_send(tapped).is_err() {
            shared.lock().stats.tap_lost += 1;
        }
    }
    if let Err(e) = decoder.push(bytes, key) {
        tracing::warn!("the decoder refused an access unit: {e:?}");
    }
}

impl State {
    /// Units given to the decoder after the last one out (those it dropped are passed over).
    fn decoding_backlog(&self) -> u64 {
        self.in_decoder
            .values()
            .filter(|u| u.number > self.decoded_number)
            .count() as u64
    }
}

/// Rate-limited notes about loss and refused packets: at most one line per kind every 5 s.
#[derive(Default)]
struct Notes {
    lost: (u64, Option<Instant>),
    refused: (u64, Option<Instant>),
}

const NOTE_EVERY: Duration = Duration::from_secs(5);

impl Notes {
    fn due(slot: &mut (u64, Option<Instant>), n: u64) -> Option<u64> {
        slot.0 += n;
        let now = Instant::now();
        if slot.1.is_none_or(|t| now.duration_since(t) >= NOTE_EVERY) {
            slot.1 = Some(now);
            return Some(std::mem::take(&mut slot.0));
        }
        None
    }

    fn lost(&mut self, n: u64) {
        if let Some(total) = Self::due(&mut self.lost, n) {
            tracing::warn!(
                packets = total,
                "packets lost (counted since the last note)"
            );
        }
    }

    fn refused(&mut self, why: &stream::Refusal) {
        if let Some(total) = Self::due(&mut self.refused, 1) {
            tracing::warn!(packets = total, "packets refused: {why}");
        }
    }
}
