//! The bare ring: the mesh's seven processes with their cores taken out.
//!
//! Each node is a service shell and nothing else: the same `runtime` start-up and wait loop, the same
//! `messages` ports and QoS, the same messages in the mesh's pattern (vehicle state → 76,800-byte
//! camera frame → cable observation → surge, sway and yaw commands → thruster setpoints → the next
//! state), each hop a publish, a notification and a WaitSet wake-up. No rendering, perception,
//! learning, allocation or integration: what is left is what the IPC costs a step.
//!
//! Every sender writes its send time (`CLOCK_MONOTONIC`) into the stamp's `time_ns`, so each receiver
//! measures its hop's one-way latency exactly, and the simulator node each step's round trip.

use crate::stats::{Summary, now_ns};
use anyhow::{Context, Result, bail};
use messages::{
    CableObservationMsg, CameraFrameHeader, DofCommand, Stamp, StepStatus, ThrusterSetpoints,
    VehicleStateMsg, topics,
};
use runtime::lockstep::Gather;
use runtime::{Flow, Runtime, Stopped, Timer, Wake};
use serde::{Deserialize, Serialize};
use std::convert::Infallible;
use std::time::Duration;

/// A node of the ring: which process of the mesh it stands in for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum, Serialize, Deserialize)]
pub enum Role {
    Simulator,
    Camera,
    Perception,
    Surge,
    Sway,
    Yaw,
    Allocator,
}

impl Role {
    pub const ALL: [Role; 7] = [
        Role::Simulator,
        Role::Camera,
        Role::Perception,
        Role::Surge,
        Role::Sway,
        Role::Yaw,
        Role::Allocator,
    ];

    /// The node's process name (shown in logs).
    pub fn name(self) -> &'static str {
        match self {
            Role::Simulator => "ring-simulator",
            Role::Camera => "ring-camera",
            Role::Perception => "ring-perception",
            Role::Surge => "ring-surge",
            Role::Sway => "ring-sway",
            Role::Yaw => "ring-yaw",
            Role::Allocator => "ring-allocator",
        }
    }

    /// The input hop it measures.
    pub fn hop(self) -> &'static str {
        match self {
            Role::Simulator => "thruster_setpoints → simulator",
            Role::Camera => "vehicle_state → camera",
            Role::Perception => "camera_frame → perception",
            Role::Surge => "cable_observation → surge-controller",
            Role::Sway => "cable_observation → sway-behaviour",
            Role::Yaw => "cable_observation → yaw-behaviour",
            Role::Allocator => "command/* → thruster-allocator",
        }
    }
}

/// What a node measured, printed as one JSON line on its stdout when it stops.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NodeReport {
    pub role: Role,
    /// The one-way latency of its input(s): reception time minus the sender's send time.
    pub hop: Summary,
    /// The simulator only: each step from its state sent to its setpoints received.
    pub step: Option<Summary>,
    /// The simulator only: steps timed (after the warm-up) and the time they took.
    pub steps: u64,
    pub wall_ns: u64,
}

impl NodeReport {
    /// Closed-loop steps per second (the simulator's report).
    pub fn steps_per_s(&self) -> f64 {
        self.steps as f64 / (self.wall_ns.max(1) as f64 * 1e-9)
    }
}

/// A stamp carrying the send time.
fn restamp(stamp: Stamp) -> Stamp {
    Stamp {
        time_ns: now_ns(),
        ..stamp
    }
}

/// Runs one node until the ring is done (the simulator: after `warmup + steps` steps; the others:
/// SIGTERM). Steps up to `warmup` are not measured.
pub fn run(rt: &Runtime, role: Role, warmup: u64, steps: u64) -> Result<NodeReport> {
    // The clock starts when the last warm-up step is answered: there is at least one.
    let warmup = warmup.max(1);
    let mut hop = Vec::with_capacity(steps as usize * if role == Role::Allocator { 3 } else { 1 });
    let mut note = |seq: u64, sent_ns: u64| {
        if seq > warmup {
            hop.push(now_ns().saturating_sub(sent_ns));
        }
    };
    let mut report = NodeReport {
        role,
        hop: Summary::default(),
        step: None,
        steps: 0,
        wall_ns: 0,
    };
    let stopped = match role {
        Role::Simulator => {
            let (stopped, step, wall_ns) = simulator(rt, warmup, steps, &mut note)?;
            if stopped != Stopped::Done {
                bail!("stopped by a signal before the ring's {steps} steps were done");
            }
            report.step = Some(step);
            report.steps = steps;
            report.wall_ns = wall_ns;
            stopped
        }
        Role::Camera => {
            let states = rt.inbox(&topics::VEHICLE_STATE)?;
            let frames = rt.frame_outbox()?;
            let c = &rt.scenario().camera;
            let (width, height) = (c.width, c.height);
            let len = (width * height) as usize;
            rt.serve(&[states.listener()], Timer::None, |_| {
                // As the camera does: only the newest state matters.
                let Some(s) = states.drain()?.into_iter().max_by_key(|s| s.stamp.seq) else {
                    return Ok(Flow::Continue);
                };
                note(s.stamp.seq, s.stamp.time_ns);
                let header = CameraFrameHeader {
                    stamp: restamp(s.stamp),
                    width,
                    height,
                    truth: Default::default(),
                };
                // The port loans and zero-fills the frame in shared memory; nothing is rendered.
                frames.send_with(header, len, |_| Ok::<(), Infallible>(()))??;
                Ok(Flow::Continue)
            })?
        }
        Role::Perception => {
            let frames = rt.frame_inbox()?;
            let out = rt.outbox(&topics::CABLE_OBSERVATION)?;
            rt.serve(&[frames.listener()], Timer::None, |_| {
                while let Some(stamp) = frames.receive_with(|h, _| h.stamp)? {
                    note(stamp.seq, stamp.time_ns);
                    out.send(CableObservationMsg {
                        stamp: restamp(stamp),
                        observation: Default::default(),
                    })?;
                }
                Ok(Flow::Continue)
            })?
        }
        Role::Surge | Role::Sway | Role::Yaw => {
            let topic = match role {
                Role::Surge => topics::SURGE_COMMAND,
                Role::Sway => topics::SWAY_COMMAND,
                _ => topics::YAW_COMMAND,
            };
            let observations = rt.inbox(&topics::CABLE_OBSERVATION)?;
            let commands = rt.outbox(&topic)?;
            rt.serve(&[observations.listener()], Timer::None, |_| {
                for m in observations.drain()? {
                    note(m.stamp.seq, m.stamp.time_ns);
                    commands.send(DofCommand {
                        stamp: restamp(m.stamp),
                        value: 0.0,
                    })?;
                }
                Ok(Flow::Continue)
            })?
        }
        Role::Allocator => {
            let inputs = [
                rt.inbox(&topics::SURGE_COMMAND)?,
                rt.inbox(&topics::SWAY_COMMAND)?,
                rt.inbox(&topics::YAW_COMMAND)?,
            ];
            let out = rt.outbox(&topics::THRUSTER_SETPOINTS)?;
            let mut gather = Gather::<DofCommand, 3>::new();
            let listeners = inputs.each_ref().map(|i| i.listener());
            rt.serve(&listeners, Timer::None, |_| {
                for (i, inbox) in inputs.iter().enumerate() {
                    for cmd in inbox.drain()? {
                        note(cmd.stamp.seq, cmd.stamp.time_ns);
                        if let Ok(Some((_, all))) = gather.put(
                            i,
                            (cmd.stamp.epoch, cmd.stamp.seq),
                            cmd,
                            std::time::Instant::now(),
                        ) {
                            out.send(ThrusterSetpoints {
                                stamp: restamp(all[0].stamp),
                                count: 4,
                                ..Default::default()
                            })?;
                        }
                    }
                }
                Ok(Flow::Continue)
            })?
        }
    };
    tracing::debug!(?stopped, "ring node done");
    report.hop = Summary::of(&hop);
    Ok(report)
}

/// The ring's driver: publishes step `seq`, waits for its setpoints, publishes `seq + 1`; re-sends
/// while nobody answers (start-up). Returns the step latencies and the time of the measured steps.
fn simulator(
    rt: &Runtime,
    warmup: u64,
    steps: u64,
    note: &mut impl FnMut(u64, u64),
) -> Result<(Stopped, Summary, u64)> {
    let setpoints = rt.inbox(&topics::THRUSTER_SETPOINTS)?;
    let states = rt.outbox(&topics::VEHICLE_STATE)?;
    let per_episode = rt.scenario().timing.max_steps as u64 + 1;
    let state = |seq: u64| {
        let step = ((seq - 1) % per_episode) as u32;
        let status = if step as u64 + 1 == per_episode {
            StepStatus::TimeLimit
        } else {
            StepStatus::Running
        };
        let episode = ((seq - 1) / per_episode) as u32;
        VehicleStateMsg {
            stamp: Stamp::new(seq, now_ns(), episode, step, status),
            ..Default::default()
        }
    };
    let total = warmup + steps;
    let mut seq = 1;
    let mut sent = state(seq);
    states.send(sent)?;
    let mut step_ns = Vec::with_capacity(steps as usize);
    let (mut t_start, mut t_end) = (0, 0);
    let stopped = rt.serve(
        &[setpoints.listener()],
        Timer::Timeout(Duration::from_millis(100)),
        |wake| {
            while let Some(sp) = setpoints.receive()? {
                if sp.stamp.seq != seq {
                    continue;
                }
                note(seq, sp.stamp.time_ns);
                let t = now_ns();
                if seq > warmup {
                    step_ns.push(t.saturating_sub(sent.stamp.time_ns));
                }
                if seq == warmup {
                    t_start = t;
                }
                if seq == total {
                    t_end = t;
                    return Ok(Flow::Stop);
                }
                seq += 1;
                sent = state(seq);
                states.send(sent)?;
            }
            if wake == Wake::Timer {
                // Nobody answered for a while: the ring is still starting; say it again.
                states.send(state(seq))?;
            }
            Ok(Flow::Continue)
        },
    )?;
    Ok((
        stopped,
        Summary::of(&step_ns),
        t_end.saturating_sub(t_start),
    ))
}

/// Reads a node's report from its stdout (the last JSON line).
pub fn parse_report(stdout: &str) -> Result<NodeReport> {
    let line = stdout
        .lines()
        .rev()
        .find(|l| l.starts_with('{'))
        .context("no report on stdout")?;
    serde_json::from_str(line).with_context(|| format!("cannot read the report `{line}`"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reports_round_trip() {
        let r = NodeReport {
            role: Role::Camera,
            hop: Summary::of(&[1, 2, 3]),
            step: None,
            steps: 0,
            wall_ns: 0,
        };
        let out = format!("noise\n{}\n", serde_json::to_string(&r).unwrap());
        assert_eq!(parse_report(&out).unwrap(), r);
        assert!(parse_report("nothing").is_err());
        let sim = NodeReport {
            role: Role::Simulator,
            steps: 1000,
            wall_ns: 500_000_000,
            ..r
        };
        assert_eq!(sim.steps_per_s(), 2000.0);
    }
}
