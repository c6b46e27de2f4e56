//! The video path against independent implementations and bad streams:
//!
//! - GStreamer's own sender (`videotestsrc ! x264enc ! rtph264pay ! udpsink`, as BlueOS sends) into
//!   our source: frames of the camera's size, one per step, the newest;
//! - our sender into GStreamer's own receiver (`udpsrc ! rtph264depay ! avdec_h264`);
//! - a stream that stops, comes back with a new SSRC at another size, with garbage between;
//! - GStreamer's own encoder and payloader changing the picture size within one SSRC;
//! - 1% packet loss: every frame that lost data, or references one that did, is flagged damaged;
//! - every access unit handed out as received, for a recorder.
//!
//! Every wait has a deadline; the `gst-launch-1.0` child is killed when its test ends.
#![cfg(feature = "gstreamer")]

use adapters::{Frame, FrameMeta, FrameSource, Read, StepStatus, Wake};
use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app as gst_app;
use std::os::fd::AsRawFd;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use video::h264::{self, nal};
use video::sender::{Encoding, RtpSender, SenderConfig};
use video::source::{RtpSource, SourceConfig};

const WITHIN: Duration = Duration::from_secs(30);

/// A child process killed and reaped when dropped.
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn loopback_source(width: u32, height: u32, quiet: Duration) -> RtpSource {
    let mut config = SourceConfig::new("127.0.0.1:0".parse().unwrap(), width, height);
    config.quiet = quiet;
    RtpSource::open(config).expect("an RTP source on loopback")
}

/// Waits (on the source's descriptor, with a deadline) for a read that is not `Pending`.
fn read_next(
    source: &RtpSource,
    out: &mut Frame,
    within: Duration,
) -> Option<Result<Read, String>> {
    let deadline = Instant::now() + within;
    loop {
        match source.read(Instant::now(), out) {
            Ok(Read::Pending { .. }) => {}
            Ok(r) => return Some(Ok(r)),
            Err(e) => return Some(Err(e.to_string())),
        }
        let Wake::Readable(fd) = source.wake() else {
            panic!("the RTP source wakes its reader through a descriptor");
        };
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return None;
        }
        let mut p = libc::pollfd {
            fd: fd.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd.
        unsafe { libc::poll(&mut p, 1, left.as_millis().max(1) as i32) };
    }
}

/// [`cable_image`] with sensor noise of +-16 grey levels, new in every frame (`frame`).
fn noisy_cable_image(w: u32, h: u32, x: u32, frame: u64) -> Vec<u8> {
    let mut state = frame.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    cable_image(w, h, x)
        .into_iter()
        .map(|p| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (p as i32 + (state % 33) as i32 - 16).clamp(0, 255) as u8
        })
        .collect()
}

/// A synthetic camera image: a grey floor with a gradient and a dark cable at column `x`.
fn cable_image(w: u32, h: u32, x: u32) -> Vec<u8> {
    let mut img = Vec::with_capacity((w * h) as usize);
    for r in 0..h {
        for c in 0..w {
            let floor = 90 + (r * 80 / h) as u8;
            img.push(if c.abs_diff(x) < 8 { 20 } else { floor });
        }
    }
    img
}

fn meta(seq: u64, w: u32, h: u32) -> FrameMeta {
    FrameMeta {
        seq,
        time_ns: seq * 200_000_000,
        width: w,
        height: h,
        trial: 3,
        step: seq as u32,
        status: StepStatus::Running,
        truth: None,
        damaged: false,
    }
}

/// BlueOS's sender, as GStreamer's own elements: the source decodes its 720p stream at 30 frames/s
/// into 320x240 frames and, read at a control step's pace, hands over one frame per step, the newest.
#[test]
fn an_independent_sender_is_decoded_one_newest_frame_per_step() {
    let source = loopback_source(320, 240, Duration::from_secs(2));
    let port = source.local_addr().port();
    let _sender = Killed(
        Command::new("gst-launch-1.0")
            .args([
                "-q",
                "videotestsrc",
                "is-live=true",
                "num-buffers=300",
                "pattern=ball",
            ])
            .args(["!", "video/x-raw,width=1280,height=720,framerate=30/1"])
            .args(["!", "x264enc", "tune=zerolatency", "speed-preset=ultrafast"])
            .args(["key-int-max=30", "bitrate=2000"])
            .args(["!", "rtph264pay", "pt=96", "config-interval=-1"])
            .args(["aggregate-mode=zero-latency"])
            .args(["!", "udpsink", "host=127.0.0.1", &format!("port={port}")])
            .stdin(Stdio::null())
            .spawn()
            .expect("gst-launch-1.0 (scripts/install-gstreamer)"),
    );
    let first = source
        .wait_for(WITHIN, |s| s.decoded >= 5)
        .expect("frames decoded from GStreamer's sender");
    assert_eq!(first.picture, Some((1280, 720)), "the stream's own size");
    let mut frame = Frame::default();
    let mut last: Option<FrameMeta> = None;
    let mut replaced = first.replaced;
    for step in 0..4 {
        // A step of a 5 Hz loop lasts six frames of a 30 frames/s stream.
        let before = source.stats().decoded;
        source
            .wait_for(WITHIN, |s| s.decoded >= before + 6)
            .unwrap_or_else(|| panic!("step {step}: the stream stalled: {:?}", source.stats()));
        assert_eq!(
            source.read(Instant::now(), &mut frame).unwrap(),
            Read::Frame,
            "step {step}"
        );
        assert_eq!(
            source.read(Instant::now(), &mut frame.clone()).unwrap(),
            Read::Pending { until: None },
            "step {step}: one frame per read, the rest dropped"
        );
        let m = frame.meta;
        assert_eq!(
            (m.width, m.height, frame.image.len()),
            (320, 240, 320 * 240)
        );
        assert!(!m.damaged, "step {step}: nothing lost on loopback");
        assert_eq!((m.trial, m.status, m.truth), (0, StepStatus::Running, None));
        let (lo, hi) = frame
            .image
            .iter()
            .fold((255u8, 0u8), |(lo, hi), &p| (lo.min(p), hi.max(p)));
        assert!(
            lo < 40 && hi > 200,
            "the ball on black: grey levels {lo}..{hi}"
        );
        if let Some(l) = last {
            assert!(
                m.seq >= l.seq + 5,
                "the newest: seq {} after {}",
                m.seq,
                l.seq
            );
            // The RTP clock: 90 kHz, 3000 ticks a frame at 30 frames/s.
            let want = (m.seq - l.seq) as f64 * 1e9 / 30.0;
            let got = (m.time_ns - l.time_ns) as f64;
            assert!((got - want).abs() < 1e6, "time {got} ns for {want} ns");
            assert_eq!(m.step, l.step + 1, "steps count the frames handed over");
        }
        let s = source.stats();
        assert!(s.replaced >= replaced + 4, "older frames dropped: {s:?}");
        replaced = s.replaced;
        last = Some(m);
    }
    let s = source.stats();
    assert_eq!(
        (s.stream.lost, s.stream.refused, s.stream.sessions),
        (0, 0, 1)
    );
}

/// Our sender into GStreamer's own receiver: `udpsrc ! rtph264depay ! avdec_h264` decodes every frame
/// the twin sends, at the size sent, and it is the image sent.
#[test]
fn an_independent_receiver_decodes_what_the_twin_sends() {
    gst::init().unwrap();
    let pipeline = gst::parse::launch(
        "udpsrc name=udp address=127.0.0.1 port=0 \
           caps=application/x-rtp,media=video,clock-rate=90000,encoding-name=H264,payload=96 \
         ! rtph264depay ! avdec_h264 ! videoconvert ! video/x-raw,format=GRAY8 \
         ! appsink name=sink sync=false",
    )
    .unwrap()
    .downcast::<gst::Pipeline>()
    .unwrap();
    pipeline.set_state(gst::State::Playing).unwrap();
    let port = pipeline.by_name("udp").unwrap().property::<i32>("port");
    assert!(port > 0, "udpsrc bound a port");
    let sink = pipeline
        .by_name("sink")
        .unwrap()
        .downcast::<gst_app::AppSink>()
        .unwrap();
    let (w, h) = (320, 240);
    let mut config = SenderConfig::new(format!("127.0.0.1:{port}").parse().unwrap(), (w, h));
    config.output = Some((640, 480));
    config.encoding = Encoding::Bitrate {
        kbps: 4000,
        profile: "constrained-baseline".into(),
    };
    config.key_interval = 5;
    let mut sender = RtpSender::open(config).unwrap();
    let frames = 12;
    for k in 0..frames {
        let image = cable_image(w, h, 40 + 20 * k);
        sender
            .send(Some(&meta(k as u64 + 1, w, h)), &image)
            .unwrap();
        let sample = sink
            .try_pull_sample(gst::ClockTime::from_seconds(WITHIN.as_secs()))
            .unwrap_or_else(|| panic!("GStreamer's receiver decoded no frame {k}"));
        let caps = sample.caps().unwrap().structure(0).unwrap().to_owned();
        assert_eq!(
            (
                caps.get::<i32>("width").unwrap(),
                caps.get::<i32>("height").unwrap()
            ),
            (640, 480)
        );
        let map = sample.buffer().unwrap().map_readable().unwrap();
        // Back to the sent size (2x2 means) and compared: the cable where it was sent.
        let got = map.as_slice();
        let stride = got.len() / 480;
        let mut err = 0u64;
        for r in 0..h as usize {
            for c in 0..w as usize {
                let at = |dr: usize, dc: usize| got[(2 * r + dr) * stride + 2 * c + dc] as u32;
                let mean = (at(0, 0) + at(0, 1) + at(1, 0) + at(1, 1)).div_ceil(4);
                err += mean.abs_diff(image[r * w as usize + c] as u32) as u64;
            }
        }
        let mae = err as f64 / (w * h) as f64;
        assert!(mae < 4.0, "frame {k}: mean error {mae} grey levels");
    }
    assert_eq!(sender.stats().frames, frames as u64);
    assert!(sender.stats().keyframes >= 3, "{:?}", sender.stats());
    pipeline.set_state(gst::State::Null).unwrap();
}

/// A stream that stops, comes back from a restarted camera (a new SSRC, its count from 1, another
/// size), with garbage between: the source says so, never panics, and picks the stream up again.
#[test]
fn a_stopped_restarted_resized_stream_with_garbage_is_picked_up_again() {
    let source = loopback_source(320, 240, Duration::from_millis(300));
    let to = source.local_addr();
    let (w, h) = (320, 240);
    let mut frame = Frame::default();
    let junk = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    for (round, (size, seed)) in [((640, 480), 1), ((480, 272), 2)].iter().enumerate() {
        let mut config = SenderConfig::new(to, (w, h));
        config.output = Some(*size);
        config.seed = *seed;
        let mut sender = RtpSender::open(config).unwrap();
        let mut got = 0;
        let mut errors = 0;
        for k in 1..=8u64 {
            if k == 4 {
                for g in [
                    &b"not rtp"[..],
                    &[0x80; 3],
                    &[0x80, 33, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 7],
                ] {
                    junk.send_to(g, to).unwrap();
                }
            }
            sender
                .send(
                    Some(&meta(k, w, h)),
                    &cable_image(w, h, 100 + 10 * k as u32),
                )
                .unwrap();
            loop {
                match read_next(&source, &mut frame, WITHIN) {
                    Some(Ok(Read::Frame)) => {
                        assert_eq!(frame.meta.seq, k, "round {round}");
                        assert_eq!(frame.image.len(), (w * h) as usize);
                        got += 1;
                        break;
                    }
                    Some(Ok(other)) => panic!("round {round}: {other:?}"),
                    Some(Err(e)) => {
                        assert!(e.contains("refused"), "{e}");
                        errors += 1;
                    }
                    None => panic!("round {round}: frame {k} never came: {:?}", source.stats()),
                }
            }
        }
        assert_eq!(got, 8, "round {round}");
        assert!(errors >= 1, "round {round}: the garbage was reported");
        drop(sender);
        // The stream stops: the source notices its silence.
        source
            .wait_for(WITHIN, |s| s.quiet > round as u64)
            .expect("the silence noticed");
    }
    let s = source.stats();
    assert_eq!(s.stream.sessions, 2, "a new SSRC, a new session");
    assert_eq!(s.picture, Some((480, 272)));
    assert_eq!(s.picture_changes, 1);
    assert_eq!(s.stream.refused, 6);
    assert_eq!(
        source.restarts(),
        1,
        "the count from 1 again: a restarted camera"
    );
    assert_eq!(s.stream.damaged, 0);
}

/// 1% of the packets lost: every frame handed over that lost data, or references a frame that did
/// since the last whole keyframe, is flagged damaged; whole frames still come through.
#[test]
fn with_packet_loss_damaged_frames_are_flagged_never_handed_over_as_whole() {
    let source = loopback_source(320, 240, Duration::from_secs(2));
    let (w, h) = (320, 240);
    let mut config = SenderConfig::new(source.local_addr(), (w, h));
    config.output = Some((1280, 720));
    config.encoding = Encoding::Bitrate {
        kbps: 3000,
        profile: "constrained-baseline".into(),
    };
    config.key_interval = 10;
    config.loss = 0.01;
    config.seed = 11;
    let frames = 200u64;
    let sending = std::thread::spawn(move || {
        let mut sender = RtpSender::open(config).unwrap();
        (1..=frames)
            .map(|k| {
                let image = noisy_cable_image(w, h, (k * 3 % w as u64) as u32, k);
                sender.send(Some(&meta(k, w, h)), &image).unwrap()
            })
            .collect::<Vec<_>>()
    });
    let mut frame = Frame::default();
    let mut read: Vec<FrameMeta> = Vec::new();
    while read.last().is_none_or(|m| m.seq < frames - 1) {
        match read_next(&source, &mut frame, Duration::from_secs(5)) {
            Some(Ok(Read::Frame)) => read.push(frame.meta),
            Some(Ok(other)) => panic!("{other:?}"),
            Some(Err(e)) => panic!("{e}"),
            None => break,
        }
    }
    let sent = sending.join().unwrap();
    // The sender's truth: frame k lost data, or references a frame that did since the last whole
    // keyframe.
    let mut truth = vec![false; frames as usize + 1];
    let mut broken = false;
    for (k, s) in sent.iter().enumerate() {
        broken = if s.keyframe {
            s.dropped > 0
        } else {
            broken || s.dropped > 0
        };
        truth[k + 1] = broken;
    }
    let lost: u32 = sent.iter().map(|s| s.dropped).sum();
    let packets: u32 = sent.iter().map(|s| s.packets).sum();
    // 1% of thousands of packets: far from 0.5% and 2% (binomial).
    assert!(packets > 5000, "{packets} packets");
    let rate = lost as f64 / packets as f64;
    assert!(
        (0.005..0.02).contains(&rate),
        "{lost} of {packets} packets lost"
    );
    assert!(read.len() > 20, "frames read: {}", read.len());
    for m in &read {
        assert!(
            m.damaged || !truth[m.seq as usize],
            "frame {} lost data (or references lost data) but was handed over whole",
            m.seq
        );
    }
    let whole = read.iter().filter(|m| !m.damaged).count();
    let damaged = read.len() - whole;
    assert!(whole > 0 && damaged > 0, "whole {whole}, damaged {damaged}");
    let s = source.stats();
    assert!(s.stream.lost > 0 && s.stream.damaged > 0, "{s:?}");
}

/// Every access unit goes to a recorder as received: the encoder's NAL units, a keyframe's with
/// its parameter sets (a receiver joining the stream there can decode it).
#[test]
fn access_units_are_handed_out_as_received() {
    let (tx, rx) = std::sync::mpsc::sync_channel(64);
    let mut config = SourceConfig::new("127.0.0.1:0".parse().unwrap(), 320, 240);
    config.access_units = Some(tx);
    let source = RtpSource::open(config).unwrap();
    let mut sc = SenderConfig::new(source.local_addr(), (320, 240));
    sc.key_interval = 3;
    let mut sender = RtpSender::open(sc).unwrap();
    for k in 1..=7u64 {
        let sent = sender
            .send(
                Some(&meta(k, 320, 240)),
                &cable_image(320, 240, 50 + k as u32),
            )
            .unwrap();
        let fed = rx.recv_timeout(WITHIN).expect("the unit handed out");
        assert_eq!(
            fed.time_ns,
            meta(k, 320, 240).time_ns,
            "frame {k}: the frame's time"
        );
        assert!(!fed.decoder_restarted);
        let unit = fed.unit;
        let want: Vec<&[u8]> = h264::nal_units(sender.last_access_unit()).collect();
        let got: Vec<&[u8]> = h264::nal_units(&unit.bytes).collect();
        assert_eq!(got, want, "frame {k}: the encoder's NAL units");
        assert_eq!(unit.keyframe, sent.keyframe);
        assert!(unit.complete && !unit.damaged);
        assert_eq!(unit.meta.unwrap().unwrap().seq, k);
        if unit.keyframe {
            let types: Vec<u8> = got.iter().map(|u| h264::nal_type(u[0])).collect();
            assert!(
                types.contains(&nal::SPS) && types.contains(&nal::PPS),
                "frame {k}: a keyframe carries SPS and PPS: {types:?}"
            );
        }
    }
    assert_eq!(sender.stats().keyframes, 3);
    assert_eq!(source.stats().tap_lost, 0);
}

/// The units handed out, fed to a decoder of their own (`decode::StreamDecoder`, as replay does
/// from a record), give the frames the source handed over, byte for byte: noisy frames sent at
/// 640x480, a keyframe every 4, scaled back to the camera's 320x240.
#[test]
fn the_units_handed_out_decode_again_to_the_same_frames() {
    let (tx, rx) = std::sync::mpsc::sync_channel(64);
    let mut config = SourceConfig::new("127.0.0.1:0".parse().unwrap(), 320, 240);
    config.access_units = Some(tx);
    let source = RtpSource::open(config).unwrap();
    let mut sc = SenderConfig::new(source.local_addr(), (320, 240));
    sc.output = Some((640, 480));
    sc.key_interval = 4;
    let mut sender = RtpSender::open(sc).unwrap();
    let mut live = Vec::new();
    let mut frame = Frame::default();
    for k in 1..=12u64 {
        let image = noisy_cable_image(320, 240, 100 + 5 * k as u32, k);
        sender.send(Some(&meta(k, 320, 240)), &image).unwrap();
        let read = read_next(&source, &mut frame, WITHIN).expect("a frame in time");
        assert_eq!(read, Ok(Read::Frame), "frame {k}");
        assert_eq!(frame.meta.seq, k);
        live.push((frame.meta.time_ns, frame.image.clone()));
    }
    let units: Vec<(u64, Vec<u8>)> = rx.try_iter().map(|u| (u.time_ns, u.unit.bytes)).collect();
    assert_eq!(units.len(), 12, "every unit handed out");
    let mut decoder = video::decode::StreamDecoder::start(320, 240, units).unwrap();
    let mut again = Vec::new();
    while let Some(p) = decoder.next(WITHIN).unwrap() {
        assert!(!p.corrupted);
        again.push((p.key, p.image));
    }
    assert_eq!(again.len(), live.len());
    for ((t, a), (key, b)) in live.iter().zip(&again) {
        assert_eq!(t, key, "the pictures in the units' order");
        assert!(a == b, "the frame at {t} ns decoded again differs");
    }
}

/// GStreamer's own encoder and payloader (`appsrc ! x264enc ! rtph264pay ! udpsink`, one SSRC)
/// change the picture size mid-stream, as a camera switching modes does: one session throughout,
/// the change noted once, every frame before and after handed over whole at the camera's size.
#[test]
fn a_resolution_change_within_one_ssrc_is_followed() {
    gst::init().unwrap();
    let source = loopback_source(320, 240, Duration::from_secs(2));
    let port = source.local_addr().port();
    let (w, h) = (320u32, 240u32);
    let pipeline = gst::parse::launch(&format!(
        "appsrc name=src is-live=true format=time do-timestamp=false \
           caps=video/x-raw,format=GRAY8,width={w},height={h},framerate=5/1 \
         ! videoscale ! videoconvert ! capsfilter name=size caps=video/x-raw,format=I420,width=640,height=480 \
         ! x264enc tune=zerolatency speed-preset=ultrafast bitrate=1000 key-int-max=10 \
         ! rtph264pay pt=96 ssrc=305419896 config-interval=-1 aggregate-mode=zero-latency \
         ! udpsink host=127.0.0.1 port={port} sync=false"
    ))
    .unwrap()
    .downcast::<gst::Pipeline>()
    .unwrap();
    let appsrc = pipeline
        .by_name("src")
        .unwrap()
        .downcast::<gst_app::AppSrc>()
        .unwrap();
    let size = pipeline.by_name("size").unwrap();
    pipeline.set_state(gst::State::Playing).unwrap();
    let mut frame = Frame::default();
    let mut got = 0;
    for k in 0..12u64 {
        if k == 6 {
            size.set_property(
                "caps",
                gst::Caps::builder("video/x-raw")
                    .field("format", "I420")
                    .field("width", 480i32)
                    .field("height", 272i32)
                    .build(),
            );
        }
        let mut buffer = gst::Buffer::from_slice(cable_image(w, h, 100 + 10 * k as u32));
        {
            let b = buffer.get_mut().unwrap();
            b.set_pts(gst::ClockTime::from_mseconds(200 * k));
            b.set_duration(gst::ClockTime::from_mseconds(200));
        }
        appsrc.push_buffer(buffer).unwrap();
        match read_next(&source, &mut frame, WITHIN) {
            Some(Ok(Read::Frame)) => {
                assert_eq!(frame.image.len(), (w * h) as usize, "frame {k}");
                assert!(!frame.meta.damaged, "frame {k}: nothing lost on loopback");
                got += 1;
            }
            other => panic!("frame {k}: {other:?}, {:?}", source.stats()),
        }
    }
    pipeline.set_state(gst::State::Null).unwrap();
    let s = source.stats();
    assert_eq!(got, 12);
    assert_eq!(s.stream.sessions, 1, "one SSRC, one session: {s:?}");
    assert_eq!(s.picture, Some((480, 272)), "the new size decoded");
    assert_eq!(s.picture_changes, 1, "the change noted once");
    assert_eq!(
        (s.stream.lost, s.stream.refused, s.stream.damaged),
        (0, 0, 0)
    );
}
