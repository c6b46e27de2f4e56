//! A dive at a glance, drawn from its flight record: one camera frame with the cable as perception
//! found it (the overlay a viewer draws over the frame), and perception's x_g and Theta, the three
//! commands and the thruster setpoints against time. For the README and for a record opened
//! without a viewer.

use crate::CommandDof;
use crate::Recorded;
use crate::image::estimate_overlay;
use crate::read::{ReadError, Reader};
use messages::CableObservationMsg;
use plot::{Figure, LineChart, Panel, Picture, Series};
use std::collections::BTreeMap;
use std::path::Path;

/// The figure and what its frame is.
pub struct DiveFigure {
    pub figure: Figure,
    /// The frame shown: its step's `seq`, its trial (episode) and step, seconds after the first.
    pub frame: Option<(u64, u32, u32, f64)>,
    /// Steps plotted (observations read).
    pub steps: usize,
}

/// The colour of the cable found (the overlay's green).
const FOUND: [u8; 3] = [0x1a, 0xf2, 0x33];

fn seconds(t: u64, t0: u64) -> f64 {
    t.saturating_sub(t0) as f64 * 1e-9
}

/// Draws the record at `path`; the frame shown is the recorded image nearest `at_s` seconds after
/// the first frame (`None`: the middle of the record).
pub fn dive(path: &Path, at_s: Option<f64>) -> Result<DiveFigure, ReadError> {
    // First pass: the time series and the frames that have an image.
    let mut t0 = None;
    let mut obs: Vec<(f64, CableObservationMsg)> = Vec::new();
    let mut commands: BTreeMap<CommandDof, Vec<(f64, f64)>> = BTreeMap::new();
    let mut thrusters: Vec<(f64, Vec<f64>)> = Vec::new();
    let mut imaged: Vec<(f64, u64)> = Vec::new();
    let mut header_seq = BTreeMap::new();
    for m in Reader::open(path)? {
        let m = m?;
        match &m.item {
            Recorded::FrameHeader(h) => {
                t0.get_or_insert(h.stamp.time_ns);
                header_seq.insert(h.stamp.time_ns, h.stamp.seq);
                // Only the latest headers are needed to pair an image with its step.
                if header_seq.len() > 64 {
                    header_seq.pop_first();
                }
            }
            Recorded::Image(i) => {
                if let (Some(t0), Some(seq)) = (t0, header_seq.get(&i.time_ns)) {
                    imaged.push((seconds(i.time_ns, t0), *seq));
                }
            }
            Recorded::Observation(o) => {
                let t = seconds(o.stamp.time_ns, t0.unwrap_or(o.stamp.time_ns));
                obs.push((t, *o));
            }
            Recorded::Command(d, c) => {
                let t = seconds(c.stamp.time_ns, t0.unwrap_or(c.stamp.time_ns));
                commands.entry(*d).or_default().push((t, c.value));
            }
            Recorded::Setpoints(s) => {
                let t = seconds(s.stamp.time_ns, t0.unwrap_or(s.stamp.time_ns));
                thrusters.push((t, s.as_slice().to_vec()));
            }
            _ => {}
        }
    }
    let end = obs.last().map_or(0.0, |o| o.0);
    let want = at_s.unwrap_or(end / 2.0);
    let chosen = imaged
        .iter()
        .min_by(|a, b| (a.0 - want).abs().total_cmp(&(b.0 - want).abs()))
        .copied();

    // Second pass: the chosen frame's image.
    let mut picture = Picture {
        title: "camera frame and the cable found (the recorded overlay)".to_owned(),
        ..Default::default()
    };
    let mut frame = None;
    if let Some((t, seq)) = chosen {
        let mut header = None;
        for m in Reader::open(path)? {
            match m?.item {
                Recorded::FrameHeader(h) if h.stamp.seq == seq => header = Some(h),
                Recorded::Image(i) if header.is_some_and(|h| h.stamp.time_ns == i.time_ns) => {
                    let h = header.expect("checked");
                    picture.width = i.width;
                    picture.height = i.height;
                    picture.grey = i.data;
                    frame = Some((seq, h.stamp.episode, h.stamp.step, t));
                    break;
                }
                _ => {}
            }
        }
        if let Some((_, o)) = obs.iter().find(|(_, o)| o.stamp.seq == seq) {
            let overlay = estimate_overlay(o, picture.width, picture.height);
            for p in &overlay.points {
                for pair in p.points.chunks_exact(2) {
                    picture
                        .segments
                        .push(([pair[0].x, pair[0].y], [pair[1].x, pair[1].y], FOUND));
                }
            }
            picture.title = format!(
                "frame of trial {}, step {} ({:.1} s): the cable found, x_g {:+.3}, Theta {:+.1} deg",
                o.stamp.episode,
                o.stamp.step,
                t,
                o.observation.x_g,
                o.observation.theta.to_degrees()
            );
        }
    }

    let found: Vec<_> = obs
        .iter()
        .filter(|(_, o)| o.observation.found != 0)
        .collect();
    let mut estimate = LineChart::new("perception's estimate", "time (s)", "");
    estimate.series.push(Series::new(
        "x_g",
        found.iter().map(|o| o.0).collect(),
        found.iter().map(|o| o.1.observation.x_g).collect(),
    ));
    estimate.series.push(Series::new(
        "Theta (rad)",
        found.iter().map(|o| o.0).collect(),
        found.iter().map(|o| o.1.observation.theta).collect(),
    ));
    let mut command_chart = LineChart::new("commands", "time (s)", "");
    for (d, v) in &commands {
        command_chart.series.push(Series::new(
            format!("{d:?}").to_lowercase(),
            v.iter().map(|p| p.0).collect(),
            v.iter().map(|p| p.1).collect(),
        ));
    }
    let mut thruster_chart = LineChart::new("thruster setpoints", "time (s)", "");
    let n = thrusters.iter().map(|t| t.1.len()).max().unwrap_or(0);
    for k in 0..n {
        thruster_chart.series.push(Series::new(
            format!("thruster {}", k + 1),
            thrusters.iter().map(|t| t.0).collect(),
            thrusters
                .iter()
                .map(|t| t.1.get(k).copied().unwrap_or(f64::NAN))
                .collect(),
        ));
    }
    let panels: Vec<Panel> = vec![
        picture.into(),
        estimate.into(),
        command_chart.into(),
        thruster_chart.into(),
    ];
    Ok(DiveFigure {
        figure: Figure::new(panels, 2),
        frame,
        steps: obs.len(),
    })
}
