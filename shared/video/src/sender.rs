//! The twin's camera on a BlueROV2's wire ([`RtpSender`]): each rendered grey frame, scaled to the
//! size a real camera sends, encoded by x264 and sent as RTP/H.264 on UDP, with the frame's
//! metadata in a header extension ([`crate::meta`]) and packets lost on purpose when asked.
//!
//! ```text
//!  GRAY8 w x h ─▶ appsrc ! videoscale ! videoconvert ! I420 W x H
//!               ! x264enc tune=zerolatency speed-preset=ultrafast bitrate key-int-max
//!               ! video/x-h264,profile=... ! appsink ─▶ h264::packetise ─▶ RTP (pt 96) ─▶ UDP
//! ```
//!
//! One frame in, its access unit out, before `send` returns (x264's zero-latency tuning has no
//! look-ahead and no B-frames). `Encoding::Lossless` (x264 at quantizer 0, High 4:4:4 Predictive)
//! gives back every grey level exactly: the conformance rig checks images bit for bit with it.

use crate::gst::{AppPipeline, VideoError};
use crate::h264;
use crate::meta::{self, WireMeta};
use crate::rtp::{self, Header};
use adapters::FrameMeta;
use gstreamer as gst;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::net::{SocketAddr, UdpSocket};
use std::time::Duration;

/// How the frames are compressed.
#[derive(Clone, Debug, PartialEq)]
pub enum Encoding {
    /// Constant bitrate (kbit/s) in an H.264 profile (`constrained-baseline`, `main`, `high`).
    Bitrate { kbps: u32, profile: String },
    /// Every grey level exactly (quantizer 0).
    Lossless,
}

/// What the sender sends, and where.
#[derive(Clone, Debug)]
pub struct SenderConfig {
    pub destination: SocketAddr,
    /// The rendered frames' size.
    pub input: (u32, u32),
    /// The size sent (a BlueROV2's camera: 1920x1080); the input's when `None`.
    pub output: Option<(u32, u32)>,
    /// The nominal frame rate (the encoder's rate control spreads the bitrate over it).
    pub fps: u32,
    pub encoding: Encoding,
    /// Frames between two keyframes.
    pub key_interval: u32,
    /// The largest RTP payload (bytes): 1200 keeps a packet with its header and the metadata
    /// element under a 1500-byte MTU.
    pub max_payload: usize,
    pub payload_type: u8,
    /// The probability that a packet is not sent (a lossy link), drawn from `seed`.
    pub loss: f64,
    /// The SSRC, the first sequence number and the losses come from it.
    pub seed: u64,
}

impl SenderConfig {
    /// Defaults for `input`-sized frames sent unscaled to `destination`: 2 Mbit/s constrained
    /// baseline, a keyframe every 10 frames at 5 frames/s, payloads of 1200 bytes, pt 96, no loss.
    pub fn new(destination: SocketAddr, input: (u32, u32)) -> Self {
        SenderConfig {
            destination,
            input,
            output: None,
            fps: 5,
            encoding: Encoding::Bitrate {
                kbps: 2000,
                profile: "constrained-baseline".into(),
            },
            key_interval: 10,
            max_payload: 1200,
            payload_type: 96,
            loss: 0.0,
            seed: 0,
        }
    }

    fn check(&self) -> Result<(), VideoError> {
        let (w, h) = self.output.unwrap_or(self.input);
        let even = |(w, h): (u32, u32)| w > 0 && h > 0 && w % 2 == 0 && h % 2 == 0;
        if !even(self.input) || !even((w, h)) {
            return Err(VideoError::Config(format!(
                "frame sizes {}x{} -> {w}x{h}: both sides must be even and > 0",
                self.input.0, self.input.1
            )));
        }
        if !(0.0..=1.0).contains(&self.loss) {
            return Err(VideoError::Config(format!(
                "a loss probability of {}: it must be within [0, 1]",
                self.loss
            )));
        }
        if self.max_payload < 3 || self.max_payload > 65000 {
            return Err(VideoError::Config(format!(
                "a max payload of {} bytes: it must be within 3..=65000",
                self.max_payload
            )));
        }
        if self.fps == 0 || self.key_interval == 0 || self.payload_type > 127 {
            return Err(VideoError::Config(format!(
                "fps {}, key interval {}, payload type {}: the first two > 0, the last <= 127",
                self.fps, self.key_interval, self.payload_type
            )));
        }
        if let Encoding::Bitrate { kbps: 0, .. } = self.encoding {
            return Err(VideoError::Config("a bitrate of 0 kbit/s".into()));
        }
        Ok(())
    }

    fn pipeline(&self) -> String {
        let (iw, ih) = self.input;
        let (w, h) = self.output.unwrap_or(self.input);
        let fps = self.fps;
        let (rate, caps) = match &self.encoding {
            Encoding::Bitrate { kbps, profile } => (
                format!("bitrate={kbps}"),
                format!("video/x-h264,profile={profile},stream-format=byte-stream,alignment=au"),
            ),
            Encoding::Lossless => (
                "pass=quant quantizer=0".to_owned(),
                "video/x-h264,stream-format=byte-stream,alignment=au".to_owned(),
            ),
        };
        format!(
            "appsrc name=src is-live=true format=time do-timestamp=false \
               caps=video/x-raw,format=GRAY8,width={iw},height={ih},framerate={fps}/1 \
             ! videoscale ! videoconvert ! video/x-raw,format=I420,width={w},height={h} \
             ! x264enc tune=zerolatency speed-preset=ultrafast {rate} key-int-max={key} \
                 byte-stream=true aud=false \
             ! {caps} ! appsink name=sink sync=false",
            key = self.key_interval
        )
    }
}

/// What one `send` did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Sent {
    /// The access unit's bytes (Annex B).
    pub bytes: usize,
    pub keyframe: bool,
    pub packets: u32,
    /// Packets not sent (the loss asked for).
    pub dropped: u32,
    pub rtp_timestamp: u32,
}

/// The sender's counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SenderStats {
    pub frames: u64,
    pub keyframes: u64,
    pub packets: u64,
    pub dropped: u64,
    pub bytes: u64,
}

/// How long the encoder may take for one frame before the sender gives up on it.
const ENCODE_TIMEOUT: Duration = Duration::from_secs(10);

/// The twin's camera as an RTP/H.264 stream (see the module docs).
pub struct RtpSender {
    config: SenderConfig,
    app: AppPipeline,
    socket: UdpSocket,
    rng: StdRng,
    ssrc: u32,
    seq: u16,
    rtp_base: u32,
    frames: u64,
    packet: Vec<u8>,
    /// The last access unit encoded.
    access_unit: Vec<u8>,
    stats: SenderStats,
}

impl RtpSender {
    pub fn open(config: SenderConfig) -> Result<Self, VideoError> {
        config.check()?;
        let app = AppPipeline::launch(&config.pipeline())?;
        app.play()?;
        let any: SocketAddr = if config.destination.is_ipv4() {
            "0.0.0.0:0".parse().expect("an address")
        } else {
            "[::]:0".parse().expect("an address")
        };
        let socket = UdpSocket::bind(any).map_err(|source| VideoError::Socket {
            what: "cannot open a socket to send to",
            addr: config.destination.to_string(),
            source,
        })?;
        let mut rng = StdRng::seed_from_u64(config.seed);
        let ssrc = rng.random();
        let seq = rng.random();
        let rtp_base = rng.random();
        tracing::info!(
            to = %config.destination,
            ssrc = %format!("{ssrc:08x}"),
            "sending RTP/H.264"
        );
        Ok(RtpSender {
            config,
            app,
            socket,
            rng,
            ssrc,
            seq,
            rtp_base,
            frames: 0,
            packet: Vec::with_capacity(1500),
            access_unit: Vec::new(),
            stats: SenderStats::default(),
        })
    }

    pub fn ssrc(&self) -> u32 {
        self.ssrc
    }

    pub fn stats(&self) -> SenderStats {
        self.stats
    }

    pub fn config(&self) -> &SenderConfig {
        &self.config
    }

    /// The H.264 bytes of the last frame sent (Annex B), as the encoder gave them.
    pub fn last_access_unit(&self) -> &[u8] {
        &self.access_unit
    }

    /// Encodes and sends one grey frame of the input size. With `meta` the frame carries it (the
    /// twin) and its RTP timestamp comes from `meta.time_ns`; without, from the frame count at the
    /// nominal rate (a plain camera).
    pub fn send(&mut self, meta: Option<&FrameMeta>, image: &[u8]) -> Result<Sent, VideoError> {
        self.send_wire(meta.map(WireMeta::of).as_ref(), image)
    }

    /// [`RtpSender::send`] with the metadata as it goes on the wire, consistent or not (tests send
    /// malformed metadata with it).
    pub fn send_wire(&mut self, meta: Option<&WireMeta>, image: &[u8]) -> Result<Sent, VideoError> {
        let (iw, ih) = self.config.input;
        if image.len() != iw as usize * ih as usize {
            return Err(VideoError::Config(format!(
                "an image of {} bytes, the sender takes {iw}x{ih}",
                image.len()
            )));
        }
        let au = self.encode(image)?;
        let clock = match meta {
            Some(m) => m.time_ns as u128 * 90_000 / 1_000_000_000,
            None => self.frames as u128 * 90_000 / self.config.fps as u128,
        };
        let timestamp = self.rtp_base.wrapping_add(clock as u32);
        let element = meta.map(|m| m.encode());
        let payloads = h264::packetise(&au, self.config.max_payload);
        let mut sent = Sent {
            bytes: au.len(),
            keyframe: h264::nal_units(&au).any(|u| h264::nal_type(u[0]) == h264::nal::IDR),
            rtp_timestamp: timestamp,
            ..Sent::default()
        };
        let n = payloads.len();
        for (k, payload) in payloads.iter().enumerate() {
            let header = Header {
                marker: k + 1 == n,
                payload_type: self.config.payload_type,
                seq: self.seq,
                timestamp,
                ssrc: self.ssrc,
            };
            self.seq = self.seq.wrapping_add(1);
            rtp::write(
                &mut self.packet,
                &header,
                element.as_ref().map(|e| (meta::ELEMENT_ID, &e[..])),
                payload,
            );
            sent.packets += 1;
            if self.config.loss > 0.0 && self.rng.random_bool(self.config.loss) {
                sent.dropped += 1;
                continue;
            }
            self.socket
                .send_to(&self.packet, self.config.destination)
                .map_err(|source| VideoError::Socket {
                    what: "cannot send to",
                    addr: self.config.destination.to_string(),
                    source,
                })?;
        }
        self.access_unit = au;
        self.frames += 1;
        self.stats.frames += 1;
        self.stats.keyframes += sent.keyframe as u64;
        self.stats.packets += sent.packets as u64;
        self.stats.dropped += sent.dropped as u64;
        self.stats.bytes += sent.bytes as u64;
        Ok(sent)
    }

    /// One frame through the encoder: its access unit.
    fn encode(&mut self, image: &[u8]) -> Result<Vec<u8>, VideoError> {
        let frame_ns = 1_000_000_000 / self.config.fps as u64;
        let mut buffer = gst::Buffer::from_slice(image.to_vec());
        {
            let b = buffer.get_mut().expect("a new buffer");
            b.set_pts(gst::ClockTime::from_nseconds(self.frames * frame_ns));
            b.set_duration(gst::ClockTime::from_nseconds(frame_ns));
        }
        let failed = |reason: String| VideoError::Failed {
            pipeline: self.app.description.clone(),
            reason,
        };
        self.app
            .src
            .push_buffer(buffer)
            .map_err(|e| failed(format!("the encoder refused a frame: {e:?}")))?;
        let sample = self
            .app
            .sink
            .try_pull_sample(gst::ClockTime::from_nseconds(
                ENCODE_TIMEOUT.as_nanos() as u64
            ))
            .ok_or(VideoError::Encoder(ENCODE_TIMEOUT))?;
        let buffer = sample
            .buffer()
            .ok_or_else(|| failed("a sample without a buffer".into()))?;
        let map = buffer
            .map_readable()
            .map_err(|e| failed(format!("cannot read an access unit: {e}")))?;
        Ok(map.as_slice().to_vec())
    }
}
