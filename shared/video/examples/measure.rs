//! What the RTP source costs: a moving SMPTE pattern at WxH, F frames/s, S seconds, encoded by x264
//! beforehand (so the encoder's cost is not in the figures), then sent as RTP on loopback at F
//! frames/s; the source decodes it into 320x240 frames, read at a 5 Hz step's pace. Prints the
//! pictures decoded per second and this process's CPU time (user + system, every thread: receive,
//! decoder, scaler, and the small cost of sending the packets) per decoded picture, the median of
//! R runs.
//!
//! ```sh
//! cargo run --release -p video --features gstreamer --example measure -- 1920x1080 30 10 3
//! ```

use adapters::{Frame, FrameSource, Read};
use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app as gst_app;
use std::time::{Duration, Instant};
use video::source::{RtpSource, SourceConfig};

fn cpu_s() -> f64 {
    // SAFETY: getrusage fills a zeroed struct.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

/// `count` access units of a moving SMPTE pattern at WxH, encoded before the measurement.
fn encode(w: u32, h: u32, fps: u32, count: u32) -> Vec<Vec<u8>> {
    gst::init().unwrap();
    let kbps = (w as u64 * h as u64 * fps as u64 / 15_000).clamp(500, 8000);
    let pipeline = gst::parse::launch(&format!(
        "videotestsrc num-buffers={count} pattern=smpte horizontal-speed=4 \
         ! video/x-raw,width={w},height={h},framerate={fps}/1 \
         ! x264enc tune=zerolatency speed-preset=ultrafast bitrate={kbps} key-int-max={fps} \
         ! video/x-h264,stream-format=byte-stream,alignment=au ! appsink name=sink sync=false"
    ))
    .unwrap()
    .downcast::<gst::Pipeline>()
    .unwrap();
    let sink = pipeline
        .by_name("sink")
        .unwrap()
        .downcast::<gst_app::AppSink>()
        .unwrap();
    pipeline.set_state(gst::State::Playing).unwrap();
    let mut units = Vec::new();
    while let Ok(sample) = sink.pull_sample() {
        units.push(sample.buffer().unwrap().map_readable().unwrap().to_vec());
    }
    pipeline.set_state(gst::State::Null).unwrap();
    units
}

/// Sends the units as RTP at `fps`, paced by the clock (a measurement, not a test).
fn stream(units: &[Vec<u8>], fps: u32, to: std::net::SocketAddr) {
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let t0 = Instant::now();
    let mut seq = 0u16;
    let mut packet = Vec::new();
    for (k, au) in units.iter().enumerate() {
        let due = t0 + Duration::from_secs_f64(k as f64 / fps as f64);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let payloads = video::h264::packetise(au, 1200);
        for (i, p) in payloads.iter().enumerate() {
            let header = video::rtp::Header {
                marker: i + 1 == payloads.len(),
                payload_type: 96,
                seq,
                timestamp: (k as u32).wrapping_mul(90_000 / fps),
                ssrc: 0x5EED,
            };
            seq = seq.wrapping_add(1);
            video::rtp::write(&mut packet, &header, None, p);
            socket.send_to(&packet, to).unwrap();
        }
    }
}

fn run(units: &[Vec<u8>], (w, h): (u32, u32), fps: u32) -> (f64, f64, u64) {
    let source =
        RtpSource::open(SourceConfig::new("127.0.0.1:0".parse().unwrap(), 320, 240)).unwrap();
    let to = source.local_addr();
    let (t0, c0) = (Instant::now(), cpu_s());
    let mut frame = Frame::default();
    let mut read = 0;
    let mut last = t0;
    std::thread::scope(|scope| {
        let sender = scope.spawn(|| stream(units, fps, to));
        // At 5 Hz: one frame per step of fps/5 pictures, until the stream has been quiet.
        loop {
            let before = source.stats().decoded;
            let step = (fps / 5).max(1) as u64;
            if source
                .wait_for(Duration::from_secs(3), |s| s.decoded >= before + step)
                .is_none()
            {
                break;
            }
            last = Instant::now();
            if matches!(source.read(Instant::now(), &mut frame), Ok(Read::Frame)) {
                read += 1;
            }
        }
        sender.join().unwrap();
    });
    let s = source.stats();
    let (wall, cpu) = (last.duration_since(t0).as_secs_f64(), cpu_s() - c0);
    eprintln!(
        "{w}x{h}@{fps}: decoded {} in {wall:.2} s, cpu {cpu:.2} s, read {read}, replaced {}, skipped {}, lost {}, damaged {}",
        s.decoded, s.replaced, s.skipped, s.stream.lost, s.stream.damaged
    );
    (
        s.decoded as f64 / wall,
        cpu / s.decoded as f64 * 1e3,
        s.decoded,
    )
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (w, h) = args
        .first()
        .and_then(|s| s.split_once('x'))
        .map(|(w, h)| (w.parse().unwrap(), h.parse().unwrap()))
        .unwrap_or((320, 240));
    let fps: u32 = args.get(1).map_or(30, |s| s.parse().unwrap());
    let seconds: u32 = args.get(2).map_or(10, |s| s.parse().unwrap());
    let runs: usize = args.get(3).map_or(3, |s| s.parse().unwrap());
    let units = encode(w, h, fps, fps * seconds);
    let mut results: Vec<(f64, f64, u64)> = (0..runs).map(|_| run(&units, (w, h), fps)).collect();
    let median = |f: &dyn Fn(&(f64, f64, u64)) -> f64, r: &mut Vec<(f64, f64, u64)>| {
        r.sort_by(|a, b| f(a).total_cmp(&f(b)));
        f(&r[r.len() / 2])
    };
    let rate = median(&|r| r.0, &mut results);
    let cpu = median(&|r| r.1, &mut results);
    println!(
        "{w}x{h} at {fps} frames/s, {runs} runs of {seconds} s: median {rate:.1} pictures decoded/s, {cpu:.2} ms CPU per picture ({:.0}% of a core)",
        cpu * rate / 10.0
    );
}
