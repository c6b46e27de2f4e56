//! Watching a running mesh from outside, over its own topics.
//!
//! - [`Probe`]: one more subscriber (and listener) on every topic of the loop, blocked in a WaitSet;
//!   it notes when each step's message appears on each topic ([`Timeline`]). It wakes on every
//!   message, so it costs the mesh a little (measured: the runs with and without it).
//! - [`Progress`]: a subscriber to the vehicle states without a listener: it is never woken, and
//!   only tells, when asked, which step the mesh is at.

use crate::timeline::{Point, Timeline};
use anyhow::{Context, Result, anyhow};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::waitset::WaitSetRunResult;
use messages::{
    CableObservationMsg, DofCommand, Endpoint, FrameInbox, Inbox, Stamp, ThrusterSetpoints,
    VehicleStateMsg, topics,
};
use runtime::clock::monotonic_ns;
use stats::Summary;
use std::time::Duration;

type Ipc = ipc::Service;

/// The bench's own node in a mesh's namespace.
pub fn node(iox: &runtime::IoxSettings, name: &str) -> Result<Node<Ipc>> {
    let cfg = iox.config()?;
    let node = NodeBuilder::new()
        .name(&NodeName::new(name).map_err(|e| anyhow!("node name `{name}`: {e:?}"))?)
        .config(&cfg)
        .create::<Ipc>()
        .map_err(|e| anyhow!("cannot create the node `{name}`: {e:?}"))?;
    // Install iceoryx2's SIGINT/SIGTERM handler now (it is installed lazily otherwise).
    let _ = node.wait(Duration::ZERO);
    Ok(node)
}

/// Runs the calling thread at real-time priority (`SCHED_FIFO`, priority `fifo`) or, with `None`,
/// at the normal one again.
pub fn set_realtime(fifo: Option<i32>) -> Result<()> {
    let (policy, priority) = match fifo {
        Some(p) => (libc::SCHED_FIFO, p),
        None => (libc::SCHED_OTHER, 0),
    };
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pthread_setschedparam on the calling thread with a valid parameter.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), policy, &param) };
    if rc != 0 {
        anyhow::bail!(
            "cannot set the probe's scheduling policy: {}",
            std::io::Error::from_raw_os_error(rc)
        );
    }
    Ok(())
}

/// What the probe saw.
#[derive(Debug, Default)]
pub struct Observed {
    pub timeline: Timeline,
    /// For each message, its `seq` and the probe's reception time minus the `time_ns` of its stamp.
    /// In the bare ring every sender stamps its send time there, so this is the probe's own wake-up
    /// delay; in the mesh `time_ns` is simulated time and this is meaningless.
    pub delay_ns: Vec<(u64, u64)>,
    /// The probe's wake-ups, and its thread's time on a CPU.
    pub wakeups: u64,
    pub cpu_ns: u64,
}

/// A subscriber on every topic of the loop.
pub struct Probe {
    state: Inbox<VehicleStateMsg>,
    frame: FrameInbox,
    observation: Inbox<CableObservationMsg>,
    commands: [(Point, Inbox<DofCommand>); 3],
    setpoints: Inbox<ThrusterSetpoints>,
}

impl Probe {
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint) -> Result<Probe> {
        Ok(Probe {
            state: Inbox::open(node, endpoint, &topics::VEHICLE_STATE)?,
            frame: FrameInbox::open(node, endpoint)?,
            observation: Inbox::open(node, endpoint, &topics::CABLE_OBSERVATION)?,
            commands: [
                (
                    Point::Surge,
                    Inbox::open(node, endpoint, &topics::SURGE_COMMAND)?,
                ),
                (
                    Point::Sway,
                    Inbox::open(node, endpoint, &topics::SWAY_COMMAND)?,
                ),
                (
                    Point::Yaw,
                    Inbox::open(node, endpoint, &topics::YAW_COMMAND)?,
                ),
            ],
            setpoints: Inbox::open(node, endpoint, &topics::THRUSTER_SETPOINTS)?,
        })
    }

    /// Records every message until `done()` says stop (asked about every `poll`) or a termination
    /// signal arrives.
    pub fn run(&self, poll: Duration, mut done: impl FnMut() -> bool) -> Result<Observed> {
        let waitset = WaitSetBuilder::new()
            .create::<Ipc>()
            .map_err(|e| anyhow!("cannot create the probe's WaitSet: {e:?}"))?;
        let listeners = [
            self.state.listener(),
            self.frame.listener(),
            self.observation.listener(),
            self.commands[0].1.listener(),
            self.commands[1].1.listener(),
            self.commands[2].1.listener(),
            self.setpoints.listener(),
        ];
        let mut guards = Vec::new();
        for l in listeners {
            guards.push(
                waitset
                    .attach_notification(l)
                    .map_err(|e| anyhow!("cannot attach a listener: {e:?}"))?,
            );
        }
        let mut seen = Observed::default();
        let cpu0 = crate::procfs::thread_cpu_ns();
        // Whatever arrived before the WaitSet existed.
        self.drain(&mut seen, &[true; 7])?;
        let mut asked = monotonic_ns();
        loop {
            // Only the topics that were notified are looked at: a wake-up costs one `try_wait` and
            // one receive per message, not seven.
            let mut fired = [false; 7];
            let result = waitset
                .wait_and_process_once_with_timeout(
                    |id| {
                        for (k, g) in guards.iter().enumerate() {
                            fired[k] |= id.has_event_from(g);
                        }
                        CallbackProgression::Continue
                    },
                    poll,
                )
                .map_err(|e| anyhow!("the probe's wait: {e:?}"))?;
            if matches!(
                result,
                WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest
            ) {
                anyhow::bail!("interrupted");
            }
            if fired.iter().any(|&f| f) {
                seen.wakeups += 1;
            }
            // Level-triggered: consume the notifications first; later data notifies again.
            for (l, _) in listeners.iter().zip(fired).filter(|(_, f)| *f) {
                let _ = l.try_wait(|_| {});
            }
            self.drain(&mut seen, &fired)?;
            if monotonic_ns().saturating_sub(asked) >= poll.as_nanos() as u64 {
                asked = monotonic_ns();
                if done() {
                    break;
                }
            }
        }
        drop(guards);
        seen.cpu_ns = crate::procfs::thread_cpu_ns().saturating_sub(cpu0);
        Ok(seen)
    }

    /// Takes every unread message of the topics marked in `which` (in the order of [`Point::ALL`]),
    /// in the loop's order, each timed as soon as it is taken (never earlier than its publication).
    fn drain(&self, seen: &mut Observed, which: &[bool; 7]) -> Result<()> {
        let mut steps: Vec<Stamp> = Vec::new();
        let mut note = |point: Point, stamp: &Stamp, t: u64| {
            seen.timeline.record(point, stamp.seq, t);
            seen.delay_ns
                .push((stamp.seq, t.saturating_sub(stamp.time_ns)));
        };
        if which[Point::State as usize] {
            while let Some(m) = self.state.receive()? {
                note(Point::State, &m.stamp, monotonic_ns());
                steps.push(m.stamp);
            }
        }
        if which[Point::Frame as usize] {
            while let Some((stamp, t)) =
                self.frame.receive_with(|h, _| (h.stamp, monotonic_ns()))?
            {
                note(Point::Frame, &stamp, t);
            }
        }
        if which[Point::Observation as usize] {
            while let Some(m) = self.observation.receive()? {
                note(Point::Observation, &m.stamp, monotonic_ns());
            }
        }
        for (point, inbox) in &self.commands {
            if which[*point as usize] {
                while let Some(m) = inbox.receive()? {
                    note(*point, &m.stamp, monotonic_ns());
                }
            }
        }
        if which[Point::Setpoints as usize] {
            while let Some(m) = self.setpoints.receive()? {
                note(Point::Setpoints, &m.stamp, monotonic_ns());
            }
        }
        for s in steps {
            seen.timeline.record_step(s.seq, s.episode, s.step);
        }
        Ok(())
    }
}

impl Observed {
    /// The probe's wake-up delays for the steps from `first` on (meaningful in the bare ring only,
    /// see [`Observed::delay_ns`]).
    pub fn delay(&self, first: u64) -> Summary {
        let d: Vec<u64> = self
            .delay_ns
            .iter()
            .filter(|(seq, _)| *seq >= first)
            .map(|(_, d)| *d)
            .collect();
        Summary::of(&d)
    }
}

/// Which step the mesh is at, without ever being woken.
pub struct Progress {
    _factory: PortFactory<Ipc, VehicleStateMsg, ()>,
    subscriber: Subscriber<Ipc, VehicleStateMsg, ()>,
    latest: u64,
}

impl Progress {
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint) -> Result<Progress> {
        let topic = topics::VEHICLE_STATE;
        let name = topic.service_name(endpoint);
        // The topic's own QoS (from `messages`), in case this opens it first; no listener: never woken.
        let factory = messages::ports::open_topic::<VehicleStateMsg>(node, &name, &topic.qos)?;
        let subscriber = factory
            .subscriber_builder()
            .create()
            .map_err(|e| anyhow!("cannot subscribe to {name}: {e:?}"))
            .context("the progress subscriber")?;
        Ok(Progress {
            _factory: factory,
            subscriber,
            latest: 0,
        })
    }

    /// The newest step published so far (0 before the first).
    pub fn latest_seq(&mut self) -> Result<u64> {
        while let Some(s) = self
            .subscriber
            .receive()
            .map_err(|e| anyhow!("receiving vehicle states: {e:?}"))?
        {
            self.latest = self.latest.max(s.stamp.seq);
        }
        Ok(self.latest)
    }
}
