//! The supervisor's health watch: a thread blocked in a WaitSet on every service's heartbeat, each
//! attached with the heartbeat's deadline (`messages::topics::health`). A missed deadline wakes the
//! supervisor's loop; after [`STUCK_AFTER_MISSES`] in a row it asks `Node::list` whether the silent
//! service is alive (then it is stuck and is killed, and restarted like one that died) or already dead
//! (its exit follows as SIGCHLD).

use anyhow::{Context, Result, anyhow};
use iceoryx2::config::Config as IoxConfig;
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use iceoryx2::signal_handling_mode::SignalHandlingMode;
use messages::topics::{health, shore};
use messages::{Endpoint, Inbox, Mission};
use std::io::Write;
use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// What the watch has seen of one service's heartbeat.
#[derive(Clone, Copy, Debug, Default)]
pub struct Pulse {
    /// The last beat.
    pub last: Option<Instant>,
    /// When the deadline was last missed (cleared by the next beat).
    pub missed: Option<Instant>,
    /// Deadlines missed in a row since the last beat.
    pub misses: u32,
}

/// Deadlines a service must miss in a row to be taken for stuck: one miss can be a process
/// descheduled for a moment on a loaded machine (or writing a file); two cost half a second of
/// silence, and a stuck service is still replaced within a second.
pub const STUCK_AFTER_MISSES: u32 = 2;

/// The running watch; stops its thread when dropped.
pub struct Watch {
    pulses: Arc<Mutex<Vec<Pulse>>>,
    /// A stop command came from the shore.
    stop_commanded: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Watch {
    /// Watches the heartbeats of `names` (in this order) on `endpoint`; writes a byte to `wake`
    /// whenever one misses its deadline.
    pub fn start(
        iox: &IoxConfig,
        endpoint: Endpoint,
        names: Vec<String>,
        wake: UnixStream,
    ) -> Result<Watch> {
        let pulses = Arc::new(Mutex::new(vec![Pulse::default(); names.len()]));
        let stop = Arc::new(AtomicBool::new(false));
        let stop_commanded = Arc::new(AtomicBool::new(false));
        let (ready, started) = std::sync::mpsc::sync_channel::<Result<()>>(1);
        let thread = {
            let (iox, pulses, stop) = (iox.clone(), Arc::clone(&pulses), Arc::clone(&stop));
            let commanded = Arc::clone(&stop_commanded);
            std::thread::Builder::new()
                .name("health".into())
                .spawn(move || {
                    let flags = Flags {
                        stop: &stop,
                        stop_commanded: &commanded,
                    };
                    if let Err(e) = watch(&iox, endpoint, &names, &pulses, flags, &wake, &ready) {
                        let _ = ready.try_send(Err(e));
                    }
                })?
        };
        started
            .recv()
            .map_err(|_| anyhow!("the health watch ended before it started"))??;
        Ok(Watch {
            pulses,
            stop_commanded,
            stop,
            thread: Some(thread),
        })
    }

    /// Whether the shore has sent a stop since the supervisor started.
    pub fn stop_commanded(&self) -> bool {
        self.stop_commanded.load(Ordering::Relaxed)
    }

    /// Service `i`'s heartbeat as seen now.
    pub fn pulse(&self, i: usize) -> Pulse {
        self.pulses.lock().map(|p| p[i]).unwrap_or_default()
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// How often the watch looks at its stop flag when no heartbeat arrives.
const POLL: Duration = Duration::from_millis(100);

struct Flags<'a> {
    stop: &'a AtomicBool,
    stop_commanded: &'a AtomicBool,
}

fn watch(
    iox: &IoxConfig,
    endpoint: Endpoint,
    names: &[String],
    pulses: &Mutex<Vec<Pulse>>,
    flags: Flags<'_>,
    mut wake: &UnixStream,
    ready: &std::sync::mpsc::SyncSender<Result<()>>,
) -> Result<()> {
    // The supervisor handles SIGINT/SIGTERM itself: iceoryx2 must not install its own handlers.
    let node = NodeBuilder::new()
        .name(&NodeName::new("supervisor-health").map_err(|e| anyhow!("{e:?}"))?)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .config(iox)
        .create::<ipc::Service>()
        .map_err(|e| anyhow!("cannot create the health watch's node: {e:?}"))?;
    let mut listeners = Vec::with_capacity(names.len());
    for name in names {
        let listener = messages::ports::open_heartbeat(&node, endpoint, name)?
            .listener_builder()
            .create()
            .map_err(|e| anyhow!("cannot listen to the heartbeat of `{name}`: {e:?}"))?;
        listeners.push(listener);
    }
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| anyhow!("cannot create the health watch's WaitSet: {e:?}"))?;
    let mut guards = Vec::with_capacity(listeners.len());
    for (listener, name) in listeners.iter().zip(names) {
        let deadline = listener.deadline().unwrap_or(health::HEARTBEAT_DEADLINE);
        guards.push(
            waitset
                .attach_deadline(listener, deadline)
                .map_err(|e| anyhow!("cannot watch the heartbeat of `{name}`: {e:?}"))
                .context("the health watch")?,
        );
    }
    let mission = Inbox::open_service(
        &node,
        &shore::service_name(&shore::MISSION),
        &shore::MISSION,
    )?;
    // A command kept in the topic's history was meant for an earlier run.
    let _ = mission.drain()?;
    let _commands = waitset
        .attach_notification(mission.listener())
        .map_err(|e| anyhow!("cannot wait for the shore's commands: {e:?}"))?;
    let _poll = waitset
        .attach_interval(POLL)
        .map_err(|e| anyhow!("cannot attach the health watch's interval: {e:?}"))?;
    let _ = ready.try_send(Ok(()));
    while !flags.stop.load(Ordering::Relaxed) {
        let mut beats = vec![false; guards.len()];
        let mut misses = vec![false; guards.len()];
        waitset
            .wait_and_process_once(|id| {
                for (i, g) in guards.iter().enumerate() {
                    beats[i] |= id.has_event_from(g);
                    misses[i] |= id.has_missed_deadline(g);
                }
                CallbackProgression::Continue
            })
            .map_err(|e| anyhow!("the health watch's wait: {e:?}"))?;
        let now = Instant::now();
        let mut wake_loop = false;
        if let Ok(mut p) = pulses.lock() {
            for (i, listener) in listeners.iter().enumerate() {
                let _ = listener.try_wait(|_| {});
                if beats[i] {
                    p[i] = Pulse {
                        last: Some(now),
                        missed: None,
                        misses: 0,
                    };
                } else if misses[i] {
                    p[i].missed = Some(now);
                    p[i].misses += 1;
                    wake_loop = true;
                }
            }
        }
        let _ = mission.listener().try_wait(|_| {});
        for command in mission.drain()? {
            if command.mission() == Some(Mission::Stop) {
                tracing::info!(seq = command.seq, "stop command from the shore");
                flags.stop_commanded.store(true, Ordering::Relaxed);
                wake_loop = true;
            }
        }
        if wake_loop {
            // The supervisor's loop polls the other end; a full pipe already has a wake-up in it.
            let _ = wake.write(&[1]);
        }
    }
    Ok(())
}

/// Whether the iceoryx2 node of the process `pid` is alive now (`Some(false)`: dead; `None`: none
/// found, e.g. it has not created its node yet).
pub fn node_alive(iox: &IoxConfig, pid: u32) -> Option<bool> {
    let mut found = None;
    let of_pid = |id: &iceoryx2::identifiers::UniqueNodeId| {
        id.pid::<ipc::Service>()
            .is_ok_and(|p| u32::try_from(p.value()) == Ok(pid))
    };
    let _ = Node::<ipc::Service>::list(iox, |state| {
        match state {
            NodeState::Alive(view) if of_pid(view.id()) => {
                found = Some(true);
                return CallbackProgression::Stop;
            }
            NodeState::Dead(view) if of_pid(view.id()) => found = Some(false),
            _ => {}
        }
        CallbackProgression::Continue
    });
    found
}
