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
//!
//! In the vehicle's shape ([`Shape::Vehicle`]) the ring is the vehicle endpoint's path with its cores
//! taken out: the simulator node stands in for the twin (a frame on the twin's camera topic, the
//! setpoints back on its thruster topic), the camera copies the frame as the camera service does, and
//! a thruster driver node forwards the setpoints. Paced at the vehicle's period, it is the latency the
//! vehicle's processes and IPC cost a frame before any perceiving: the vehicle's limit.

use anyhow::{Context, Result, bail};
use messages::topics::hardware;
use messages::{
    CableObservationMsg, CameraFrameHeader, DofCommand, FrameInbox, FrameOutbox, Inbox, Outbox,
    Stamp, StepStatus, ThrusterSetpoints, VehicleStateMsg, topics,
};
use records::latency::{HEADER, Sample, write_sample};
use runtime::clock::monotonic_ns;
use runtime::lockstep::Gather;
use runtime::{Flow, Runtime, Stopped, Timer, Wake};
use serde::{Deserialize, Serialize};
use stats::Summary;
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
    /// The vehicle's shape only: the thruster driver between the allocator and the thrusters.
    Driver,
}

/// Which path the ring takes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
pub enum Shape {
    /// The simulation mesh's loop: state → camera → ... → allocator → setpoints → simulator.
    #[default]
    Mesh,
    /// The vehicle endpoint's: twin frame → camera → ... → allocator → thruster driver → twin.
    Vehicle,
}

impl Shape {
    /// The nodes of this shape.
    pub fn roles(self) -> &'static [Role] {
        match self {
            Shape::Mesh => &Role::ALL[..7],
            Shape::Vehicle => &Role::ALL,
        }
    }
}

/// How a ring runs: its shape, its steps and its pace.
#[derive(Clone, Debug, PartialEq)]
pub struct RingOptions {
    pub shape: Shape,
    /// Steps not measured at the start (at least one).
    pub warmup: u64,
    /// Steps measured.
    pub steps: u64,
    /// A new step every `period` (the vehicle's camera clock); `None`: each step as soon as the last
    /// one is answered.
    pub period: Option<Duration>,
    /// Where the simulator node keeps every timed step's latency (the vehicle's latency CSV), if
    /// anywhere.
    pub latencies: Option<std::path::PathBuf>,
}

impl Role {
    /// Every node: the mesh's seven, then the vehicle's thruster driver.
    pub const ALL: [Role; 8] = [
        Role::Simulator,
        Role::Camera,
        Role::Perception,
        Role::Surge,
        Role::Sway,
        Role::Yaw,
        Role::Allocator,
        Role::Driver,
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
            Role::Driver => "ring-driver",
        }
    }

    /// The input hop it measures in the ring of `shape`.
    pub fn hop_in(self, shape: Shape) -> &'static str {
        match (shape, self) {
            (Shape::Vehicle, Role::Simulator) => "twin/thrusters → twin",
            (Shape::Vehicle, Role::Camera) => "twin/frame → camera",
            _ => self.hop(),
        }
    }

    /// The input hop it measures in the mesh's shape.
    pub fn hop(self) -> &'static str {
        match self {
            Role::Simulator => "thruster_setpoints → simulator",
            Role::Camera => "vehicle_state → camera",
            Role::Perception => "camera_frame → perception",
            Role::Surge => "cable_observation → surge-controller",
            Role::Sway => "cable_observation → sway-behaviour",
            Role::Yaw => "cable_observation → yaw-behaviour",
            Role::Allocator => "command/* → thruster-allocator",
            Role::Driver => "thruster_setpoints → thruster-driver",
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
    /// The simulator only: the step latency's p99 95% confidence interval (see
    /// [`crate::vehicle::p99_interval`]).
    #[serde(default)]
    pub step_p99_interval: Option<[u64; 2]>,
    /// The simulator only, paced: timed steps not answered before the next one was due.
    #[serde(default)]
    pub missed: u64,
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
        time_ns: monotonic_ns(),
        ..stamp
    }
}

/// Runs one node until the ring is done (the simulator: after `warmup + steps` steps; the others:
/// SIGTERM). Steps up to `warmup` are not measured.
pub fn run(rt: &Runtime, role: Role, options: &RingOptions) -> Result<NodeReport> {
    // The clock starts when the last warm-up step is answered: there is at least one.
    let warmup = options.warmup.max(1);
    let steps = options.steps;
    let mut hop = Vec::with_capacity(steps as usize * if role == Role::Allocator { 3 } else { 1 });
    let mut note = |seq: u64, sent_ns: u64| {
        if seq > warmup {
            hop.push(monotonic_ns().saturating_sub(sent_ns));
        }
    };
    let mut report = NodeReport {
        role,
        hop: Summary::default(),
        step: None,
        steps: 0,
        wall_ns: 0,
        step_p99_interval: None,
        missed: 0,
    };
    let vehicle = options.shape == Shape::Vehicle;
    let stopped = match role {
        Role::Simulator => {
            let ports = if vehicle {
                SimulatorPorts::twin(rt)?
            } else {
                SimulatorPorts::mesh(rt)?
            };
            let run = simulator(rt, &ports, options, &mut note)?;
            if run.stopped != Stopped::Done {
                bail!("stopped by a signal before the ring's {steps} steps were done");
            }
            let step_ns: Vec<u64> = run
                .samples
                .iter()
                .map(|s| s.latency.as_nanos() as u64)
                .collect();
            report.step = Some(Summary::of(&step_ns));
            report.step_p99_interval = crate::vehicle::p99_interval(&step_ns);
            if let Some(path) = &options.latencies {
                write_latencies(path, &run.samples)?;
            }
            report.steps = steps;
            report.wall_ns = run.wall_ns;
            report.missed = run.missed;
            run.stopped
        }
        Role::Camera if vehicle => {
            // As the vehicle's camera service does: the twin's frame copied into the camera's own.
            let service = hardware::service_name(hardware::TWIN, &hardware::TWIN_FRAME);
            let twin = FrameInbox::open_service(rt.node(), &service, &hardware::TWIN_FRAME)?;
            let frames = rt.frame_outbox()?;
            rt.serve(&[twin.listener()], Timer::None, |_| {
                while let Some(sent) = twin.receive_with(|h, image| {
                    note(h.stamp.seq, h.stamp.time_ns);
                    let header = CameraFrameHeader {
                        stamp: restamp(h.stamp),
                        ..*h
                    };
                    frames
                        .send_with(header, image.len(), |out| {
                            out.copy_from_slice(image);
                            Ok::<(), Infallible>(())
                        })
                        .map(|_| ())
                })? {
                    sent?;
                }
                Ok(Flow::Continue)
            })?
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
                    ..Default::default()
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
        Role::Driver => {
            let setpoints = rt.inbox(&topics::THRUSTER_SETPOINTS)?;
            let service = hardware::service_name(hardware::TWIN, &hardware::TWIN_THRUSTERS);
            let thrusters = Outbox::open_service(rt.node(), &service, &hardware::TWIN_THRUSTERS)?;
            rt.serve(&[setpoints.listener()], Timer::None, |_| {
                for sp in setpoints.drain()? {
                    note(sp.stamp.seq, sp.stamp.time_ns);
                    thrusters.send(ThrusterSetpoints {
                        stamp: restamp(sp.stamp),
                        ..sp
                    })?;
                }
                Ok(Flow::Continue)
            })?
        }
    };
    tracing::debug!(?stopped, "ring node done");
    report.hop = Summary::of(&hop);
    Ok(report)
}

/// Where the simulator node sends a step and hears its answer.
enum SimulatorPorts {
    /// The mesh: a vehicle state out, thruster setpoints back.
    Mesh {
        states: Outbox<VehicleStateMsg>,
        setpoints: Inbox<ThrusterSetpoints>,
    },
    /// The twin: a camera frame out, the driver's setpoints back on the thruster topic; the state
    /// too, after the frame, for the bench that follows the ring's progress (nobody is woken by it).
    Twin {
        camera: Box<FrameOutbox>,
        thrusters: Inbox<ThrusterSetpoints>,
        /// The frame's width and height (the scenario's camera).
        size: (u32, u32),
        states: Outbox<VehicleStateMsg>,
    },
}

impl SimulatorPorts {
    fn mesh(rt: &Runtime) -> Result<Self> {
        Ok(SimulatorPorts::Mesh {
            states: rt.outbox(&topics::VEHICLE_STATE)?,
            setpoints: rt.inbox(&topics::THRUSTER_SETPOINTS)?,
        })
    }

    fn twin(rt: &Runtime) -> Result<Self> {
        let c = &rt.scenario().camera;
        let frame = hardware::service_name(hardware::TWIN, &hardware::TWIN_FRAME);
        let thrusters = hardware::service_name(hardware::TWIN, &hardware::TWIN_THRUSTERS);
        Ok(SimulatorPorts::Twin {
            camera: Box::new(FrameOutbox::open_service(
                rt.node(),
                &frame,
                &hardware::TWIN_FRAME,
                (c.width * c.height) as usize,
            )?),
            thrusters: Inbox::open_service(rt.node(), &thrusters, &hardware::TWIN_THRUSTERS)?,
            size: (c.width, c.height),
            states: rt.outbox(&topics::VEHICLE_STATE)?,
        })
    }

    fn listener(&self) -> &iceoryx2::port::listener::Listener<iceoryx2::prelude::ipc::Service> {
        match self {
            SimulatorPorts::Mesh { setpoints, .. } => setpoints.listener(),
            SimulatorPorts::Twin { thrusters, .. } => thrusters.listener(),
        }
    }

    fn send(&self, state: VehicleStateMsg) -> Result<()> {
        match self {
            SimulatorPorts::Mesh { states, .. } => {
                states.send(state)?;
            }
            SimulatorPorts::Twin {
                camera,
                size: (width, height),
                states,
                ..
            } => {
                let header = CameraFrameHeader {
                    stamp: state.stamp,
                    width: *width,
                    height: *height,
                    ..Default::default()
                };
                let len = (*width * *height) as usize;
                camera.send_with(header, len, |_| Ok::<(), Infallible>(()))??;
                states.send(state)?;
            }
        }
        Ok(())
    }

    fn receive(&self) -> Result<Option<ThrusterSetpoints>> {
        Ok(match self {
            SimulatorPorts::Mesh { setpoints, .. } => setpoints.receive()?,
            SimulatorPorts::Twin { thrusters, .. } => thrusters.receive()?,
        })
    }
}

/// What the simulator node measured.
struct SimulatorRun {
    stopped: Stopped,
    /// Each timed step from its state sent to its setpoints received.
    samples: Vec<Sample>,
    /// The timed steps' wall time.
    wall_ns: u64,
    missed: u64,
}

/// The ring's driver: publishes step `seq`, waits for its setpoints, publishes `seq + 1` (paced: at
/// the next period, answered or not); re-sends while nobody answers (start-up).
fn simulator(
    rt: &Runtime,
    ports: &SimulatorPorts,
    options: &RingOptions,
    note: &mut impl FnMut(u64, u64),
) -> Result<SimulatorRun> {
    let warmup = options.warmup.max(1);
    let steps = options.steps;
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
            stamp: Stamp::new(seq, monotonic_ns(), episode, step, status),
            ..Default::default()
        }
    };
    let total = warmup + steps;
    let mut seq = 1;
    let mut sent = state(seq);
    ports.send(sent)?;
    let mut answered = false;
    let mut next_due = std::time::Instant::now() + options.period.unwrap_or_default();
    let mut run = SimulatorRun {
        stopped: Stopped::Signal,
        samples: Vec::with_capacity(steps as usize),
        wall_ns: 0,
        missed: 0,
    };
    let (mut t_start, mut t_end) = (0, 0);
    let timer = match options.period {
        Some(p) => Timer::Interval(p),
        None => Timer::Timeout(Duration::from_millis(100)),
    };
    run.stopped = rt.serve(&[ports.listener()], timer, |wake| {
        while let Some(sp) = ports.receive()? {
            if sp.stamp.seq != seq || answered {
                continue;
            }
            answered = true;
            note(seq, sp.stamp.time_ns);
            let t = monotonic_ns();
            if seq > warmup {
                run.samples.push(Sample {
                    seq,
                    trial: sent.stamp.episode,
                    step: sent.stamp.step,
                    time_ns: sent.stamp.time_ns,
                    sent_ns: sent.stamp.time_ns,
                    latency: Duration::from_nanos(t.saturating_sub(sent.stamp.time_ns)),
                });
            }
            if seq == warmup {
                t_start = t;
            }
            if seq == total {
                t_end = t;
                return Ok(Flow::Stop);
            }
            if options.period.is_none() {
                seq += 1;
                sent = state(seq);
                ports.send(sent)?;
                answered = false;
            }
        }
        match options.period {
            // Paced: the next step when it is due, whether this one was answered or not (the camera's
            // clock does not wait); unanswered at start-up, the same step again.
            Some(period) => {
                // The interval's tick may come a hair before the step is due: half a period of
                // slack, and the schedule kept on the period's grid.
                let now = std::time::Instant::now();
                if now + period / 2 >= next_due {
                    next_due = (next_due + period).max(now + period / 2);
                    if answered || seq > warmup {
                        if !answered {
                            run.missed += 1;
                        }
                        if seq >= total {
                            t_end = monotonic_ns();
                            return Ok(Flow::Stop);
                        }
                        seq += 1;
                    }
                    sent = state(seq);
                    ports.send(sent)?;
                    answered = false;
                }
            }
            None => {
                if wake == Wake::Timer {
                    // Nobody answered for a while: the ring is still starting; say it again.
                    ports.send(state(seq))?;
                }
            }
        }
        Ok(Flow::Continue)
    })?;
    run.wall_ns = t_end.saturating_sub(t_start);
    Ok(run)
}

/// Writes the steps' latencies as the vehicle twin writes its frames' (`mesh-bench latencies` reads
/// both).
fn write_latencies(path: &std::path::Path, samples: &[Sample]) -> Result<()> {
    use std::io::Write as _;
    let mut out = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    );
    writeln!(out, "{HEADER}")?;
    for s in samples {
        write_sample(&mut out, s)?;
    }
    out.flush()
        .with_context(|| format!("writing {}", path.display()))
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
            step_p99_interval: None,
            missed: 0,
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
