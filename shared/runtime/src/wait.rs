//! The wait loop: block in an iceoryx2 WaitSet on the inputs' listeners and a timer.

use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use iceoryx2_bb_posix::file_descriptor::{FileDescriptor, FileDescriptorBased};
use iceoryx2_bb_posix::file_descriptor_set::SynchronousMultiplexing;
use messages::Heartbeat;
use messages::topics::health;
use std::os::fd::{AsRawFd, BorrowedFd};
use std::time::{Duration, Instant};

/// What a wait loop blocks on.
#[derive(Clone, Copy, Debug)]
pub enum Input<'a> {
    /// An iceoryx2 listener: its notifications are consumed by the loop.
    Listener(&'a Listener<ipc::Service>),
    /// A file descriptor that becomes readable when there is input (an eventfd a device's thread
    /// signals). The handler must clear it (read it) on each wake-up, or the loop wakes again at
    /// once.
    Readable(BorrowedFd<'a>),
}

/// A borrowed descriptor as the WaitSet attaches it (it never closes it).
#[derive(Debug)]
struct Readable(FileDescriptor);

impl FileDescriptorBased for Readable {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.0
    }
}

impl SynchronousMultiplexing for Readable {}

/// When to wake without input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Timer {
    /// Only on input.
    None,
    /// After this long without input (deadlines, re-sends).
    Timeout(Duration),
    /// At this period, input or not (the vehicle's 5 Hz camera).
    Interval(Duration),
}

/// Why the loop woke.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wake {
    /// At least one input was notified.
    Input,
    /// The timer fired.
    Timer,
}

/// What the loop does next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    Continue,
    Stop,
}

/// Why the loop ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stopped {
    /// The handler said stop.
    Done,
    /// SIGINT or SIGTERM.
    Signal,
}

pub(crate) fn serve(
    inputs: &[Input<'_>],
    timer: Timer,
    heartbeat: &Heartbeat,
    mut on_wake: impl FnMut(Wake) -> anyhow::Result<Flow>,
) -> anyhow::Result<Stopped> {
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("cannot create a WaitSet: {e:?}"))?;
    // The descriptors are borrowed for the whole loop: the WaitSet only polls them.
    let readables = inputs
        .iter()
        .filter_map(|i| match i {
            Input::Readable(fd) => Some(
                FileDescriptor::non_owning_new(fd.as_raw_fd())
                    .map(Readable)
                    .ok_or_else(|| anyhow::anyhow!("not a valid file descriptor: {fd:?}")),
            ),
            Input::Listener(_) => None,
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut guards = Vec::with_capacity(inputs.len());
    for input in inputs {
        if let Input::Listener(listener) = input {
            guards.push(
                waitset
                    .attach_notification(*listener)
                    .map_err(|e| anyhow::anyhow!("cannot wait on a listener: {e:?}"))?,
            );
        }
    }
    for readable in &readables {
        guards.push(
            waitset
                .attach_notification(readable)
                .map_err(|e| anyhow::anyhow!("cannot wait on {:?}: {e:?}", readable.0))?,
        );
    }
    let listeners: Vec<&Listener<ipc::Service>> = inputs
        .iter()
        .filter_map(|i| match i {
            Input::Listener(l) => Some(*l),
            Input::Readable(_) => None,
        })
        .collect();
    // An interval timer is an attachment of its own; a timeout is counted here, from the last call
    // of `on_wake`, because a heartbeat that falls due wakes the WaitSet in between.
    let (period, timeout) = match timer {
        Timer::Interval(p) => (Some(p), None),
        Timer::Timeout(t) => (None, Some(t)),
        Timer::None => (None, None),
    };
    let tick = match period {
        Some(p) => Some(
            waitset
                .attach_interval(p)
                .map_err(|e| anyhow::anyhow!("cannot attach a {p:?} interval: {e:?}"))?,
        ),
        None => None,
    };
    // The heartbeat beats from this loop, so a process stuck anywhere (stopped, or inside one wake)
    // falls silent.
    let mut pulse = Pulse::start(heartbeat)?;
    // A message sent before this process's listener existed announced itself to nobody (a topic's
    // history, a producer faster than our start-up): look at the inputs once before the first wait.
    if !inputs.is_empty() && on_wake(Wake::Input)? == Flow::Stop {
        return Ok(Stopped::Done);
    }
    let mut last_wake = Instant::now();
    loop {
        let mut input = false;
        let mut ticked = false;
        let mut handle = |id: WaitSetAttachmentId<ipc::Service>| {
            input |= guards.iter().any(|g| id.has_event_from(g));
            ticked |= tick.as_ref().is_some_and(|t| id.has_event_from(t));
            CallbackProgression::Continue
        };
        let wait = match timeout {
            Some(t) => t.saturating_sub(last_wake.elapsed()).min(pulse.due_in()),
            None => pulse.due_in(),
        };
        let result = waitset
            .wait_and_process_once_with_timeout(&mut handle, wait)
            .map_err(|e| anyhow::anyhow!("waiting: {e:?}"))?;
        match result {
            WaitSetRunResult::TerminationRequest => return Ok(Stopped::Signal),
            // Any signal interrupts a blocked wait (SIGCONT after a stall, SIGCHLD, ...). Wait
            // again: a termination request is seen by the WaitSet before it blocks.
            WaitSetRunResult::Interrupt => continue,
            WaitSetRunResult::StopRequest | WaitSetRunResult::AllEventsHandled => {}
        }
        pulse.beat_if_due()?;
        // Notifications are level-triggered: consume them, or the WaitSet wakes again at once. Data
        // that arrives after this is announced by a new notification, so nothing is missed.
        for listener in &listeners {
            let _ = listener.try_wait(|_| {});
        }
        let timed_out = timeout.is_some_and(|t| last_wake.elapsed() >= t);
        let wake = if input {
            Wake::Input
        } else if ticked || timed_out {
            Wake::Timer
        } else {
            // Only the heartbeat falling due: nothing for the service.
            continue;
        };
        last_wake = Instant::now();
        if on_wake(wake)? == Flow::Stop {
            return Ok(Stopped::Done);
        }
    }
}

/// Why a watched loop woke ([`crate::Runtime::serve_watched`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Watch {
    /// The watched input was notified: `data` arrived and/or a publisher's process `died`.
    Input { data: bool, publisher_died: bool },
    /// Nothing was notified on the watched input for its deadline (iceoryx2's deadline attachment).
    Missed,
    /// The time the handler asked to be woken at.
    Tick,
}

/// Serves one watched input (a watchdog): wakes when it is notified, when it was not notified for
/// `deadline`, and at the latest after the time `on_wake` returns; until `on_wake` returns `None`
/// or a termination signal arrives.
pub(crate) fn serve_watched(
    input: &Listener<ipc::Service>,
    deadline: Duration,
    heartbeat: &Heartbeat,
    mut on_wake: impl FnMut(Watch) -> anyhow::Result<Option<Duration>>,
) -> anyhow::Result<Stopped> {
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("cannot create a WaitSet: {e:?}"))?;
    let watched = waitset.attach_deadline(input, deadline).map_err(|e| {
        anyhow::anyhow!("cannot watch a listener with a {deadline:?} deadline: {e:?}")
    })?;
    // The heartbeat, as in `serve`.
    let mut pulse = Pulse::start(heartbeat)?;
    // What arrived before the watch began (a topic's history) is looked at first.
    let mut next = match on_wake(Watch::Input {
        data: true,
        publisher_died: false,
    })? {
        Some(t) => t,
        None => return Ok(Stopped::Done),
    };
    let mut asked_at = Instant::now();
    loop {
        let (mut notified, mut missed) = (false, false);
        let mut handle = |id: WaitSetAttachmentId<ipc::Service>| {
            if id.has_missed_deadline(&watched) {
                missed = true;
            } else if id.has_event_from(&watched) {
                notified = true;
            }
            CallbackProgression::Continue
        };
        let result = waitset
            .wait_and_process_once_with_timeout(
                &mut handle,
                next.saturating_sub(asked_at.elapsed()).min(pulse.due_in()),
            )
            .map_err(|e| anyhow::anyhow!("waiting: {e:?}"))?;
        match result {
            WaitSetRunResult::TerminationRequest => return Ok(Stopped::Signal),
            // Not a request to stop (see `serve`): wait again.
            WaitSetRunResult::Interrupt => continue,
            WaitSetRunResult::StopRequest | WaitSetRunResult::AllEventsHandled => {}
        }
        pulse.beat_if_due()?;
        if !(notified || missed) && asked_at.elapsed() < next {
            // Only the heartbeat falling due: nothing for the handler yet.
            continue;
        }
        let wake = if notified {
            let n = messages::ports::take_notifications(input);
            Watch::Input {
                data: n.data,
                publisher_died: n.publisher_died,
            }
        } else if missed {
            Watch::Missed
        } else {
            Watch::Tick
        };
        match on_wake(wake)? {
            Some(t) => next = t,
            None => return Ok(Stopped::Done),
        }
        asked_at = Instant::now();
    }
}

/// A process's heartbeat, beaten from its wait loop: any wake-up beats once half a
/// [`health::HEARTBEAT_PERIOD`] has passed since the last beat, and the loop's wait ends when a full
/// period has. A process with work (the vehicle's 5 Hz steps, 200 ms apart, are shorter than a
/// period) beats from that work and never wakes for the heartbeat alone; one woken thousands of
/// times a second notifies its listeners a few times a second; only an idle process wakes for it.
struct Pulse<'a> {
    heartbeat: &'a Heartbeat,
    last: Instant,
}

impl<'a> Pulse<'a> {
    fn start(heartbeat: &'a Heartbeat) -> anyhow::Result<Self> {
        heartbeat.beat()?;
        Ok(Pulse {
            heartbeat,
            last: Instant::now(),
        })
    }

    /// How long the loop may wait before it must beat (zero if it is late).
    fn due_in(&self) -> Duration {
        health::HEARTBEAT_PERIOD.saturating_sub(self.last.elapsed())
    }

    fn beat_if_due(&mut self) -> anyhow::Result<()> {
        if self.last.elapsed() >= health::HEARTBEAT_PERIOD / 2 {
            self.heartbeat.beat()?;
            self.last = Instant::now();
        }
        Ok(())
    }
}
