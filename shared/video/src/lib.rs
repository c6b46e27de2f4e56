//! The camera's video path: H.264 over RTP on UDP, as a BlueROV2's camera sends it (BlueOS's camera
//! manager: payload type 96, port 5600 by default). See the crate's README for the wire.
//!
//! The RTP core is plain Rust, functions of bytes and state machines fed arrival times (no socket,
//! no GStreamer), so it is unit-tested here and can be fuzzed:
//!
//! - [`rtp`]: RTP packets (RFC 3550) and their header extensions (RFC 8285), read and written;
//! - [`h264`]: H.264 RTP payloads (RFC 6184): the packetiser (single NAL units, FU-A) and the
//!   depacketiser (also STAP-A);
//! - [`stream`]: a stream judged as it arrives: sessions (SSRC), loss, access units, which frames
//!   are damaged (a lost packet in them or in what they reference since the last keyframe);
//! - [`meta`]: the twin's per-frame metadata in a header extension.
//!
//! Behind the `gstreamer` feature (GStreamer 1.22, `scripts/install-gstreamer`):
//!
//! - `source::RtpSource`: the camera's [`adapters::FrameSource`] over a UDP port: our socket, the
//!   core above, then GStreamer's H.264 decoder scaling every frame to the camera's size; one frame
//!   per read, the newest;
//! - `sender::RtpSender`: the twin's camera on the same wire: x264 through GStreamer, our
//!   packetiser, UDP, with packet loss injected on demand;
//! - `decode::StreamDecoder`: recorded access units through the source's own decoding pipeline,
//!   giving the frames the camera decoded live (replay).

pub mod h264;
pub mod meta;
pub mod rtp;
pub mod stream;

#[cfg(feature = "gstreamer")]
pub mod decode;
#[cfg(feature = "gstreamer")]
pub mod gst;
#[cfg(feature = "gstreamer")]
pub mod sender;
#[cfg(feature = "gstreamer")]
pub mod source;
