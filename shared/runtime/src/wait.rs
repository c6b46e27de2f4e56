//! The wait loop: block in an iceoryx2 WaitSet on the inputs' listeners and a timer.

use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use std::time::Duration;

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
    inputs: &[&Listener<ipc::Service>],
    timer: Timer,
    mut on_wake: impl FnMut(Wake) -> anyhow::Result<Flow>,
) -> anyhow::Result<Stopped> {
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("cannot create a WaitSet: {e:?}"))?;
    let mut guards = Vec::with_capacity(inputs.len());
    for listener in inputs {
        guards.push(
            waitset
                .attach_notification(*listener)
                .map_err(|e| anyhow::anyhow!("cannot wait on a listener: {e:?}"))?,
        );
    }
    // An interval timer is an attachment of its own. A loop with a timeout but no input has nothing
    // to attach (a WaitSet refuses to wait on nothing): its timeout becomes an interval.
    let (period, timeout) = match timer {
        Timer::Interval(p) => (Some(p), None),
        Timer::Timeout(t) if inputs.is_empty() => (Some(t), None),
        Timer::Timeout(t) => (None, Some(t)),
        Timer::None => (None, None),
    };
    let _tick = match period {
        Some(p) => Some(
            waitset
                .attach_interval(p)
                .map_err(|e| anyhow::anyhow!("cannot attach a {p:?} interval: {e:?}"))?,
        ),
        None => None,
    };
    // A message sent before this process's listener existed announced itself to nobody (a topic's
    // history, a producer faster than our start-up): look at the inputs once before the first wait.
    if !inputs.is_empty() && on_wake(Wake::Input)? == Flow::Stop {
        return Ok(Stopped::Done);
    }
    loop {
        let mut input = false;
        let mut handle = |id: WaitSetAttachmentId<ipc::Service>| {
            input |= guards.iter().any(|g| id.has_event_from(g));
            CallbackProgression::Continue
        };
        let result = match timeout {
            Some(t) => waitset.wait_and_process_once_with_timeout(&mut handle, t),
            None => waitset.wait_and_process_once(&mut handle),
        }
        .map_err(|e| anyhow::anyhow!("waiting: {e:?}"))?;
        match result {
            WaitSetRunResult::TerminationRequest => return Ok(Stopped::Signal),
            // Any signal interrupts a blocked wait (SIGCONT after a stall, SIGCHLD, ...). Wait
            // again: a termination request is seen by the WaitSet before it blocks.
            WaitSetRunResult::Interrupt => continue,
            WaitSetRunResult::StopRequest | WaitSetRunResult::AllEventsHandled => {}
        }
        // Notifications are level-triggered: consume them, or the WaitSet wakes again at once. Data
        // that arrives after this is announced by a new notification, so nothing is missed.
        for listener in inputs {
            let _ = listener.try_wait(|_| {});
        }
        // Without input, the timeout passed (reported as AllEventsHandled) or the interval fired.
        let wake = if input { Wake::Input } else { Wake::Timer };
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
    mut on_wake: impl FnMut(Watch) -> anyhow::Result<Option<Duration>>,
) -> anyhow::Result<Stopped> {
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("cannot create a WaitSet: {e:?}"))?;
    let watched = waitset.attach_deadline(input, deadline).map_err(|e| {
        anyhow::anyhow!("cannot watch a listener with a {deadline:?} deadline: {e:?}")
    })?;
    // What arrived before the watch began (a topic's history) is looked at first.
    let mut next = match on_wake(Watch::Input {
        data: true,
        publisher_died: false,
    })? {
        Some(t) => t,
        None => return Ok(Stopped::Done),
    };
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
            .wait_and_process_once_with_timeout(&mut handle, next)
            .map_err(|e| anyhow::anyhow!("waiting: {e:?}"))?;
        match result {
            WaitSetRunResult::TerminationRequest => return Ok(Stopped::Signal),
            // Not a request to stop (see `serve`): wait again.
            WaitSetRunResult::Interrupt => continue,
            WaitSetRunResult::StopRequest | WaitSetRunResult::AllEventsHandled => {}
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
    }
}
