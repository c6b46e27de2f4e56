//! Perception through the camera's H.264 path: rendered frames at random poses (the renderer's every
//! effect) sent by the twin's sender (x264, scaled up to a camera's size, packets lost on demand) to
//! the camera's RTP source on loopback, decoded and scaled back to the camera's size, then perceived
//! one by one against the geometric camera's truth. The same frames also go to perception unsent,
//! the uncompressed baseline. Shared by `tests/perception.rs` and `examples/perception.rs`.

#![allow(dead_code)]

use adapters::{Frame, FrameMeta, FrameSource, Read, StepStatus};
use config::Scenario;
use model::wrap_half_pi;
use std::time::{Duration, Instant};
use video::sender::{Encoding, RtpSender, SenderConfig};
use video::source::{RtpSource, SourceConfig};
use vision::sampling::PoseSampler;
use vision::{Perception, Renderer};

/// A rendered frame and the cable's true line in it.
pub struct Truth {
    pub image: Vec<u8>,
    pub theta: f64,
    pub x_g: f64,
}

/// `n` frames of the default scenario at random poses with the cable in view (x_g in [-0.4, 0.4],
/// Theta in [-60, 60] degrees, random velocities for the blur), every image effect on.
pub fn render(n: usize, seed: u64) -> (Scenario, Vec<Truth>) {
    let scenario = Scenario::default();
    let mut renderer = Renderer::from_scenario(&scenario, seed).expect("the default renderer");
    let camera = renderer.camera().clone();
    let cable = *renderer.cable();
    let mut sampler = PoseSampler::new(seed ^ 0x5eed);
    let frames = (0..n)
        .map(|k| {
            let s = sampler.with_cable(&camera, &cable);
            let truth = camera.view(&s.pose, &cable).expect("the cable in view");
            let frame = renderer.render_frame(&s.pose, &s.rate, k as u64);
            Truth {
                image: frame.data().to_vec(),
                theta: truth.theta,
                x_g: truth.x_g,
            }
        })
        .collect();
    (scenario, frames)
}

/// `n` frames of the default scenario along a tracking path, one control period (0.2 s) apart,
/// every image effect on: a dive's sequence as the encoder meets it, each frame much like the one
/// before (the poses of `vision::pace::tracking_path`).
pub fn render_dive(n: usize, seed: u64) -> (Scenario, Vec<Truth>) {
    let scenario = Scenario::default();
    let mut renderer = Renderer::from_scenario(&scenario, seed).expect("the default renderer");
    let camera = renderer.camera().clone();
    let cable = *renderer.cable();
    let path = vision::pace::tracking_path(n, scenario.timing.sample_time_s);
    let frames = path
        .iter()
        .enumerate()
        .map(|(k, (pose, rate))| {
            let truth = camera.view(pose, &cable).expect("the cable in view");
            let frame = renderer.render_frame(pose, rate, k as u64);
            Truth {
                image: frame.data().to_vec(),
                theta: truth.theta,
                x_g: truth.x_g,
            }
        })
        .collect();
    (scenario, frames)
}

/// What perception made of a set of frames.
#[derive(Clone, Debug, Default)]
pub struct Outcome {
    pub frames: usize,
    /// Frames the source handed over (whole or damaged).
    pub handed_over: usize,
    /// Handed over whole (not flagged damaged).
    pub whole: usize,
    /// Whole frames in which the cable was found.
    pub found: usize,
    /// |Theta error| (degrees) and |x_g error| (fraction of the width) of the frames found, sorted.
    pub theta_deg: Vec<f64>,
    pub x_g: Vec<f64>,
    /// Frames with a packet lost in them or in what they reference since the last whole keyframe.
    pub broken: usize,
    /// Of them, handed over without the damaged flag: must be 0.
    pub broken_as_whole: usize,
    /// Packets sent and not sent (the loss asked for), bytes of H.264.
    pub packets: u64,
    pub dropped: u64,
    pub bytes: u64,
}

impl Outcome {
    pub fn detection(&self) -> f64 {
        self.found as f64 / self.frames.max(1) as f64
    }

    pub fn p95_theta(&self) -> f64 {
        stats::percentile(self.theta_deg.iter().copied(), 0.95)
    }

    pub fn p95_x_g(&self) -> f64 {
        stats::percentile(self.x_g.iter().copied(), 0.95)
    }

    fn perceive(
        &mut self,
        perception: &mut Perception,
        image: &[u8],
        t: &Truth,
        w: usize,
        h: usize,
    ) {
        let view = vision::ImageView::new(image, w, h).expect("a frame of the camera's size");
        perception.reset();
        let obs = perception.process(view, 0.2).expect("perception");
        if obs.found {
            self.found += 1;
            self.theta_deg
                .push(wrap_half_pi(obs.theta - t.theta).abs().to_degrees());
            self.x_g.push((obs.x_g - t.x_g).abs());
        }
    }

    fn sort(&mut self) {
        self.theta_deg.sort_by(f64::total_cmp);
        self.x_g.sort_by(f64::total_cmp);
    }
}

/// Perception on the rendered frames themselves.
pub fn uncompressed(scenario: &Scenario, frames: &[Truth]) -> Outcome {
    let (w, h) = (
        scenario.camera.width as usize,
        scenario.camera.height as usize,
    );
    let mut perception = Perception::from_scenario(scenario).expect("perception");
    let mut out = Outcome {
        frames: frames.len(),
        handed_over: frames.len(),
        whole: frames.len(),
        ..Outcome::default()
    };
    for t in frames {
        out.perceive(&mut perception, &t.image, t, w, h);
    }
    out.sort();
    out
}

/// How the frames go over the wire.
#[derive(Clone, Debug)]
pub struct Wire {
    /// The size sent (the frames are scaled up to it, as a camera's).
    pub size: (u32, u32),
    pub encoding: Encoding,
    /// The nominal frame rate the encoder's bitrate is spread over.
    pub fps: u32,
    pub key_interval: u32,
    /// The probability that a packet is not sent.
    pub loss: f64,
    pub seed: u64,
}

impl Wire {
    /// `kbps` in x264's constrained baseline at `size`, 5 frames/s, a keyframe every 10 frames.
    pub fn bitrate(size: (u32, u32), kbps: u32, loss: f64) -> Self {
        Wire {
            size,
            encoding: Encoding::Bitrate {
                kbps,
                profile: "constrained-baseline".into(),
            },
            fps: 5,
            key_interval: 10,
            loss,
            seed: 7,
        }
    }
}

/// How long to wait for a frame's picture before going on without it (a unit whose last packet
/// was lost ends only when the next frame's packets come).
const PICTURE_WITHIN: Duration = Duration::from_secs(2);

/// The frames through the sender and the camera's RTP source, one at a time, each perceived on
/// its own when handed over whole (a damaged one is not looked at: perception coasts on it).
pub fn through_h264(scenario: &Scenario, frames: &[Truth], wire: &Wire) -> Outcome {
    let (w, h) = (scenario.camera.width, scenario.camera.height);
    let source = RtpSource::open(SourceConfig::new("127.0.0.1:0".parse().unwrap(), w, h))
        .expect("an RTP source on loopback");
    let mut config = SenderConfig::new(source.local_addr(), (w, h));
    config.output = Some(wire.size);
    config.encoding = wire.encoding.clone();
    config.fps = wire.fps;
    config.key_interval = wire.key_interval;
    config.loss = wire.loss;
    config.seed = wire.seed;
    let mut sender = RtpSender::open(config).expect("the sender");
    let mut perception = Perception::from_scenario(scenario).expect("perception");
    let mut out = Outcome {
        frames: frames.len(),
        ..Outcome::default()
    };
    let mut broken = vec![false; frames.len()];
    let mut chain_broken = false;
    let mut frame = Frame::default();
    let mut seen = vec![false; frames.len()];
    for (k, t) in frames.iter().enumerate() {
        let meta = FrameMeta {
            seq: k as u64 + 1,
            time_ns: (k as u64 + 1) * 200_000_000,
            width: w,
            height: h,
            trial: 0,
            step: k as u32,
            status: StepStatus::Running,
            truth: None,
            damaged: false,
        };
        let before = source.stats().decoded;
        let sent = sender.send(Some(&meta), &t.image).expect("sent");
        // A frame is broken when it lost a packet, or references one that did since the last
        // keyframe (a keyframe that lost one breaks what follows it too).
        chain_broken = (chain_broken && !sent.keyframe) || sent.dropped > 0;
        broken[k] = chain_broken;
        source.wait_for(PICTURE_WITHIN, |s| s.decoded > before);
        loop {
            match source.read(Instant::now(), &mut frame) {
                Ok(Read::Frame) => {
                    let j = frame.meta.seq as usize - 1;
                    if std::mem::replace(&mut seen[j], true) {
                        continue;
                    }
                    out.handed_over += 1;
                    if frame.meta.damaged {
                        continue;
                    }
                    out.whole += 1;
                    out.broken_as_whole += broken[j] as usize;
                    out.perceive(
                        &mut perception,
                        &frame.image,
                        &frames[j],
                        w as usize,
                        h as usize,
                    );
                }
                Ok(Read::Pending { .. }) => break,
                Ok(_) => {}
                Err(e) => eprintln!("the source: {e}"),
            }
        }
    }
    out.broken = broken.iter().filter(|b| **b).count();
    let s = sender.stats();
    out.packets = s.packets;
    out.dropped = s.dropped;
    out.bytes = s.bytes;
    out.sort();
    out
}

pub const TABLE_HEADER: &str = "| frames | Mbit/s | loss | handed over whole | detected | Theta error p95 (deg) | x_g error p95 | broken | broken handed over as whole |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|";

impl Outcome {
    pub fn row(&self, name: &str, mbps: &str, loss: &str) -> String {
        format!(
            "| {name} | {mbps} | {loss} | {:.1}% | {:.1}% | {:.3} | {:.4} | {} | {} |",
            100.0 * self.whole as f64 / self.frames.max(1) as f64,
            100.0 * self.detection(),
            self.p95_theta(),
            self.p95_x_g(),
            self.broken,
            self.broken_as_whole,
        )
    }
}
