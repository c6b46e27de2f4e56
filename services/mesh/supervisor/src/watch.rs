//! The supervisor's health watch: a thread that looks at every service's heartbeat every 50 ms and
//! counts the heartbeat's deadlines (`messages::topics::health`) each silence has missed. A missed
//! deadline wakes the supervisor's loop; after [`STUCK_AFTER_MISSES`] in a row
//! ([`OBSERVER_STUCK_AFTER_MISSES`] for an observer) it asks `Node::list` whether the silent
//! service is alive (then it is stuck and is killed, and restarted like one that died) or already dead
//! (its exit follows as SIGCHLD).

use anyhow::{Result, anyhow};
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
/// descheduled for a moment on a loaded machine (or writing a file); two cost 600 ms of silence,
/// and a stuck service is still replaced within a second.
pub const STUCK_AFTER_MISSES: u32 = 2;

/// The same for an observer (the flight recorder): no step waits for it, its work includes the
/// disk's (each commit syncs the file, which a busy disk can hold past a deadline or two), and
/// killing it splits its record into parts. Ten deadlines: 3 s of silence.
pub const OBSERVER_STUCK_AFTER_MISSES: u32 = 10;

/// Whether `misses` deadlines missed in a row make a service (an observer or not) stuck.
pub fn silent_too_long(misses: u32, observer: bool) -> bool {
    misses
        >= if observer {
            OBSERVER_STUCK_AFTER_MISSES
        } else {
            STUCK_AFTER_MISSES
        }
}

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

/// How often the watch looks at the heartbeats (and its stop flag). Looking, rather than waking on
/// every beat, costs the supervisor a wake-up per 50 ms instead of one per beat of every service
/// (a vehicle mesh has ten); a silence is seen at most this late.
const LOOK_EVERY: Duration = Duration::from_millis(50);

/// The deadlines a heartbeat silent for `silence` has missed in a row.
fn silent_deadlines(silence: Duration, deadline: Duration) -> u32 {
    u32::try_from(silence.as_nanos() / deadline.as_nanos().max(1)).unwrap_or(u32::MAX)
}

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
    let deadlines: Vec<Duration> = listeners
        .iter()
        .map(|l| l.deadline().unwrap_or(health::HEARTBEAT_DEADLINE))
        .collect();
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
    let _look = waitset
        .attach_interval(LOOK_EVERY)
        .map_err(|e| anyhow!("cannot attach the health watch's interval: {e:?}"))?;
    let _ = ready.try_send(Ok(()));
    while !flags.stop.load(Ordering::Relaxed) {
        waitset
            .wait_and_process_once(|_| CallbackProgression::Continue)
            .map_err(|e| anyhow!("the health watch's wait: {e:?}"))?;
        let now = Instant::now();
        let mut wake_loop = false;
        if let Ok(mut p) = pulses.lock() {
            for (i, listener) in listeners.iter().enumerate() {
                let mut beat = false;
                let _ = listener.try_wait(|_| beat = true);
                if beat {
                    p[i] = Pulse {
                        last: Some(now),
                        missed: None,
                        misses: 0,
                    };
                } else if let Some(last) = p[i].last {
                    let misses = silent_deadlines(now - last, deadlines[i]);
                    if misses > p[i].misses {
                        p[i].missed = Some(now);
                        p[i].misses = misses;
                        wake_loop = true;
                    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_silence_misses_one_deadline_per_deadline_elapsed() {
        let d = health::HEARTBEAT_DEADLINE;
        assert_eq!(silent_deadlines(Duration::ZERO, d), 0);
        assert_eq!(silent_deadlines(d - Duration::from_millis(1), d), 0);
        assert_eq!(silent_deadlines(d, d), 1);
        assert_eq!(silent_deadlines(2 * d + d / 2, d), 2);
        assert_eq!(
            silent_deadlines(Duration::from_secs(5), Duration::ZERO),
            u32::MAX
        );
    }

    #[test]
    fn an_observer_is_given_longer_than_a_service_of_the_loop() {
        assert!(!silent_too_long(STUCK_AFTER_MISSES - 1, false));
        assert!(silent_too_long(STUCK_AFTER_MISSES, false));
        // Two missed deadlines, a busy disk's commit: the recorder is not killed for it.
        assert!(!silent_too_long(STUCK_AFTER_MISSES, true));
        assert!(!silent_too_long(OBSERVER_STUCK_AFTER_MISSES - 1, true));
        assert!(silent_too_long(OBSERVER_STUCK_AFTER_MISSES, true));
    }
}
