//! Perception through H.264: the same rendered frames perceived uncompressed, then sent by the twin's
//! sender (x264, zero-latency tune, scaled up to a camera's size) through the camera's RTP source on
//! loopback at several bitrates, with and without packet loss. Prints a table: frames handed over
//! whole, cable detected, p95 of the Theta and x_g errors against the renderer's truth, frames broken
//! by a lost packet and of them how many were handed over as whole (must be none).
//!
//! ```sh
//! nice cargo run --release -p video --features gstreamer --example perception -- [FRAMES] [WxH] [SEED]
//! ```
//!
//! `rates FRAMES SEED WxH@KBPS...` measures chosen sizes and bitrates without loss instead (the
//! low rates that keep a flight record small), each row beside the same frames uncompressed, with
//! the stream's own bitrate (the encoder's output over the nominal 5 frames/s). `rates --dive ...`
//! sends frames along a tracking path instead of at random poses: a dive's sequence, each frame much
//! like the last, which the encoder predicts (random poses are its worst case).
//!
//! A benchmark, not a test: `tests/perception.rs` holds a handful of frames to the published bound.
//! `spread FRAMES SEEDS` prints, per seed, what that test measures (FRAMES frames at 2.5 Mbit/s,
//! 1280x720, no loss, against the same frames uncompressed): the range its bounds allow for.

#[path = "../tests/util/perceive.rs"]
mod perceive;

use perceive::{TABLE_HEADER, Wire, render, render_dive, through_h264, uncompressed};
use video::sender::Encoding;

fn spread(n: usize, seeds: u64) {
    println!(
        "| seed | detected | Theta p95 | uncompressed | ratio | x_g p95 | uncompressed | ratio |"
    );
    for seed in 1..=seeds {
        let (scenario, frames) = render(n, seed);
        let base = uncompressed(&scenario, &frames);
        let o = through_h264(&scenario, &frames, &Wire::bitrate((1280, 720), 2500, 0.0));
        println!(
            "| {seed} | {:.3} | {:.4} | {:.4} | {:.2} | {:.5} | {:.5} | {:.2} |",
            o.detection(),
            o.p95_theta(),
            base.p95_theta(),
            o.p95_theta() / base.p95_theta(),
            o.p95_x_g(),
            base.p95_x_g(),
            o.p95_x_g() / base.p95_x_g(),
        );
    }
}

/// `WxH@KBPS`.
fn size_rate(s: &str) -> ((u32, u32), u32) {
    let parse = || -> Option<((u32, u32), u32)> {
        let (size, kbps) = s.split_once('@')?;
        let (w, h) = size.split_once('x')?;
        Some(((w.parse().ok()?, h.parse().ok()?), kbps.parse().ok()?))
    };
    parse().unwrap_or_else(|| panic!("`{s}`: expected WxH@KBPS, e.g. 640x360@250"))
}

fn rates(n: usize, seed: u64, dive: bool, wires: &[String]) {
    let (scenario, frames) = if dive {
        render_dive(n, seed)
    } else {
        render(n, seed)
    };
    println!(
        "{n} frames of {}x{} ({}, every image effect, seed {seed}), 5 frames/s, a keyframe every 10, no loss\n",
        scenario.camera.width,
        scenario.camera.height,
        if dive {
            "along a tracking path"
        } else {
            "at random poses"
        }
    );
    println!(
        "| size | kbit/s asked | kbit/s sent | detected | Theta error p95 (deg) | ratio | x_g error p95 | ratio |\n|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    let base = uncompressed(&scenario, &frames);
    println!(
        "| uncompressed | - | - | {:.1}% | {:.3} | 1.00x | {:.5} | 1.00x |",
        100.0 * base.detection(),
        base.p95_theta(),
        base.p95_x_g()
    );
    for spec in wires {
        let (size, kbps) = size_rate(spec);
        let o = through_h264(&scenario, &frames, &Wire::bitrate(size, kbps, 0.0));
        println!(
            "| {}x{} | {kbps} | {:.0} | {:.1}% | {:.3} | {:.2}x | {:.5} | {:.2}x |",
            size.0,
            size.1,
            o.bytes as f64 * 8.0 * 5.0 / n as f64 / 1e3,
            100.0 * o.detection(),
            o.p95_theta(),
            o.p95_theta() / base.p95_theta(),
            o.p95_x_g(),
            o.p95_x_g() / base.p95_x_g(),
        );
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("rates") {
        let dive = args.get(1).map(String::as_str) == Some("--dive");
        let args = &args[1 + dive as usize..];
        let n = args.first().map_or(500, |s| s.parse().expect("FRAMES"));
        let seed = args.get(1).map_or(42, |s| s.parse().expect("SEED"));
        return rates(n, seed, dive, &args[2.min(args.len())..]);
    }
    if args.first().map(String::as_str) == Some("spread") {
        let n = args.get(1).map_or(40, |s| s.parse().expect("FRAMES"));
        return spread(n, args.get(2).map_or(10, |s| s.parse().expect("SEEDS")));
    }
    let n: usize = args.first().map_or(500, |s| s.parse().expect("FRAMES"));
    let size: (u32, u32) = args
        .get(1)
        .and_then(|s| s.split_once('x'))
        .map_or((1280, 720), |(w, h)| {
            (w.parse().expect("W"), h.parse().expect("H"))
        });
    let seed: u64 = args.get(2).map_or(42, |s| s.parse().expect("SEED"));
    let (scenario, frames) = render(n, seed);
    println!(
        "{n} frames of {}x{} (every image effect, seed {seed}), sent at {}x{}, 5 frames/s, a keyframe every 10\n",
        scenario.camera.width, scenario.camera.height, size.0, size.1
    );
    println!("{TABLE_HEADER}");
    let base = uncompressed(&scenario, &frames);
    println!("{}", base.row("uncompressed", "-", "-"));
    let mut lossless = Wire::bitrate(size, 0, 0.0);
    lossless.encoding = Encoding::Lossless;
    let o = through_h264(&scenario, &frames, &lossless);
    println!(
        "{}",
        o.row(
            "lossless H.264 (the scaling alone)",
            &format!("{:.1}", o.bytes as f64 * 8.0 * 5.0 / n as f64 / 1e6),
            "0"
        )
    );
    for loss in [0.0, 0.01] {
        for kbps in [1000, 2500, 5000] {
            let o = through_h264(&scenario, &frames, &Wire::bitrate(size, kbps, loss));
            println!(
                "{}",
                o.row(
                    "H.264",
                    &format!("{}", kbps as f64 / 1000.0),
                    &format!("{}%", loss * 100.0)
                )
            );
            eprintln!(
                "  {kbps} kbit/s, loss {loss}: {:.1} kB a frame, {} packets, {} not sent, handed over {}, theta p95 {:.4} ({:.2}x uncompressed), x_g p95 {:.5} ({:.2}x)",
                o.bytes as f64 / n as f64 / 1e3,
                o.packets,
                o.dropped,
                o.handed_over,
                o.p95_theta(),
                o.p95_theta() / base.p95_theta(),
                o.p95_x_g(),
                o.p95_x_g() / base.p95_x_g(),
            );
        }
    }
}
