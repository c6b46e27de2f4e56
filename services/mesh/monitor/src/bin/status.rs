//! `status`: watches a running mesh for a moment and prints, per service, its node's state, the age
//! of its last heartbeat and its restarts; per topic, its rate and last stamp; per learner, its gains
//! and last return. Run it beside the mesh (same `--iox-prefix`/`--iox-root`), or on the shore
//! against the topics the shore link brings up (nodes do not cross: they show as absent).

use anyhow::anyhow;
use clap::Parser;
use config::Dof;
use iceoryx2::node::{NodeState as IoxNodeState, NodeView};
use iceoryx2::prelude::*;
use messages::ports::Payload;
use messages::{Inbox, Stamp, Stamped, topics};
use monitor::status::{
    AutopilotStatus, LearnerStatus, NodeState, ServiceStatus, Status, TopicStatus,
};
use runtime::{CommonArgs, Flow, Timer};
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "Shows a running mesh's health: services, heartbeats, restarts, topic rates, learners."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// How long to watch (seconds): rates are counted over this.
    #[arg(long, default_value_t = 2.0)]
    window_s: f64,
    /// The services to report, comma-separated (default: the endpoint's: the simulation mesh's seven
    /// and its monitor; on the vehicle its eight services and the flight recorder).
    #[arg(long, value_delimiter = ',')]
    services: Option<Vec<String>>,
    /// Print JSON instead of the table.
    #[arg(long)]
    json: bool,
}

/// Counts one topic's messages and keeps the last stamp.
struct Count<P: Payload + Stamped> {
    inbox: Inbox<P>,
    messages: u64,
    last: Option<Stamp>,
}

impl<P: Payload + Stamped> Count<P> {
    fn open(rt: &runtime::Runtime, topic: &messages::Topic<P>) -> anyhow::Result<Self> {
        Ok(Count {
            inbox: rt.inbox(topic)?,
            messages: 0,
            last: None,
        })
    }

    /// Drains the inbox; `counting` is false for what the history replays at connection.
    fn take(&mut self, counting: bool) -> anyhow::Result<Option<P>> {
        let mut latest = None;
        for m in self.inbox.drain()? {
            self.messages += counting as u64;
            self.last = Some(*m.stamp());
            latest = Some(m);
        }
        Ok(latest)
    }
}

/// The services `status` reports unless told: the endpoint's, and on the vehicle its flight
/// recorder (a vehicle always keeps a record).
fn endpoint_services(endpoint: topics::Endpoint) -> Vec<String> {
    let observers: &[&str] = match endpoint {
        topics::Endpoint::Sim => &[],
        topics::Endpoint::Vehicle => &["recorder"],
    };
    endpoint
        .services()
        .iter()
        .chain(observers)
        .map(|s| s.to_string())
        .collect()
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("status", &args.common, |rt| {
        let endpoint = rt.endpoint();
        let service_names = args
            .services
            .clone()
            .unwrap_or_else(|| endpoint_services(endpoint));
        let beats = service_names
            .iter()
            .map(|name| {
                messages::ports::open_heartbeat(rt.node(), endpoint, name)?
                    .listener_builder()
                    .create()
                    .map_err(|e| anyhow!("cannot listen to the heartbeat of `{name}`: {e:?}"))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let mut state = Count::open(rt, &topics::VEHICLE_STATE)?;
        let mut observations = Count::open(rt, &topics::CABLE_OBSERVATION)?;
        let mut commands = [
            ("command/surge", Count::open(rt, &topics::SURGE_COMMAND)?),
            ("command/sway", Count::open(rt, &topics::SWAY_COMMAND)?),
            ("command/yaw", Count::open(rt, &topics::YAW_COMMAND)?),
        ];
        let mut setpoints = Count::open(rt, &topics::THRUSTER_SETPOINTS)?;
        let mut learners = [
            (Dof::Sway, Count::open(rt, &topics::SWAY_LEARNING)?, None),
            (Dof::Yaw, Count::open(rt, &topics::YAW_LEARNING)?, None),
        ];
        // The autopilot's telemetry (a driver piloting ArduSub): the latest of each topic.
        let autopilot_state = rt.inbox(&topics::AUTOPILOT_STATE)?;
        let autopilot_depth = rt.inbox(&topics::AUTOPILOT_DEPTH)?;
        let autopilot_servos = rt.inbox(&topics::AUTOPILOT_SERVO_OUTPUTS)?;
        let autopilot_text = rt.inbox(&topics::AUTOPILOT_STATUS_TEXT)?;
        let (mut ap_reports, mut ap_state, mut ap_depth, mut ap_servos, mut ap_text) =
            (0u64, None, None, None, None);
        let frames = rt.frame_inbox()?;
        let (mut frame_count, mut frame_last) = (0u64, None::<Stamp>);
        let mut last_beat: Vec<Option<(Instant, usize)>> = vec![None; beats.len()];

        let start = Instant::now();
        let window = Duration::from_secs_f64(args.window_s.max(0.0));
        let mut first = true;
        // Heartbeats are looked at every heartbeat period: their event ids (restart counts) must be
        // read here, not consumed by the wait loop.
        rt.serve(
            &[],
            Timer::Interval(topics::health::HEARTBEAT_PERIOD),
            |_| {
                let now = Instant::now();
                for (beat, listener) in last_beat.iter_mut().zip(&beats) {
                    let _ = listener.try_wait(|e| *beat = Some((now, e.id.as_value())));
                }
                let counting = !first;
                state.take(counting)?;
                observations.take(counting)?;
                for (_, c) in &mut commands {
                    c.take(counting)?;
                }
                setpoints.take(counting)?;
                for (_, c, latest) in &mut learners {
                    if let Some(s) = c.take(counting)? {
                        *latest = Some(s);
                    }
                }
                for m in autopilot_state.drain()? {
                    ap_reports += counting as u64;
                    ap_state = Some(m);
                }
                ap_depth = autopilot_depth.drain()?.pop().or(ap_depth);
                ap_servos = autopilot_servos.drain()?.pop().or(ap_servos);
                ap_text = autopilot_text.drain()?.pop().or(ap_text);
                while let Some(stamp) = frames.receive_with(|h, _| h.stamp)? {
                    frame_count += counting as u64;
                    frame_last = Some(stamp);
                }
                first = false;
                Ok(if start.elapsed() >= window {
                    Flow::Stop
                } else {
                    Flow::Continue
                })
            },
        )?;
        let window_s = start.elapsed().as_secs_f64();

        let nodes = node_states(rt.iox_config(), &service_names);
        let services = service_names
            .iter()
            .zip(&last_beat)
            .zip(nodes)
            .map(|((name, beat), node)| ServiceStatus {
                name: name.clone(),
                node,
                heartbeat_age_s: beat.map(|(t, _)| t.elapsed().as_secs_f64()),
                restarts: beat.map(|(_, r)| r),
            })
            .collect();
        let mut topics = vec![
            TopicStatus::new(
                "vehicle_state",
                state.messages,
                window_s,
                state.last.as_ref(),
            ),
            TopicStatus::new("camera_frame", frame_count, window_s, frame_last.as_ref()),
            TopicStatus::new(
                "cable_observation",
                observations.messages,
                window_s,
                observations.last.as_ref(),
            ),
        ];
        for (name, c) in &commands {
            topics.push(TopicStatus::new(
                name,
                c.messages,
                window_s,
                c.last.as_ref(),
            ));
        }
        topics.push(TopicStatus::new(
            "thruster_setpoints",
            setpoints.messages,
            window_s,
            setpoints.last.as_ref(),
        ));
        for (dof, c, _) in &learners {
            let name = format!("learning/{dof}");
            topics.push(TopicStatus::new(
                &name,
                c.messages,
                window_s,
                c.last.as_ref(),
            ));
        }
        let status = Status {
            endpoint: endpoint.to_string(),
            window_s,
            services,
            topics,
            learners: learners
                .iter()
                .filter_map(|(dof, _, s)| s.as_ref().map(|s| LearnerStatus::new(*dof, s)))
                .collect(),
            autopilot: AutopilotStatus::new(
                ap_reports,
                ap_state.as_ref(),
                ap_depth.as_ref(),
                ap_servos.as_ref(),
                ap_text.as_ref(),
            ),
        };
        if args.json {
            cli::outln!("{}", serde_json::to_string_pretty(&status)?)?;
        } else {
            cli::outln!("{}", status.table())?;
        }
        Ok(())
    })
}

/// Each service's node state: alive if a live node has its name, dead if only dead ones do.
fn node_states(iox: &iceoryx2::config::Config, names: &[String]) -> Vec<NodeState> {
    let mut states = vec![NodeState::Absent; names.len()];
    let _ = Node::<ipc::Service>::list(iox, |state| {
        let (name, alive) = match &state {
            IoxNodeState::Alive(v) => (v.details().as_ref().map(|d| d.name().to_string()), true),
            IoxNodeState::Dead(v) => (v.details().as_ref().map(|d| d.name().to_string()), false),
            _ => (None, false),
        };
        if let Some(i) = name.and_then(|n| names.iter().position(|s| *s == n)) {
            states[i] = match (alive, states[i]) {
                (true, _) | (false, NodeState::Alive) => NodeState::Alive,
                (false, _) => NodeState::Dead,
            };
        }
        CallbackProgression::Continue
    });
    states
}
