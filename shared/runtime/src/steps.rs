//! Serving one input topic in lockstep: each step's message goes through the service's core once,
//! a repeated step gets the answer already computed, an older, stale or absurd step is refused
//! (`screen::Screen`). The loop every single-input service (camera, perception, the behaviours,
//! the surge controller) would otherwise write out itself.

use crate::Runtime;
use crate::lockstep::{Once, Outcome};
use crate::wait::{Flow, Stopped, Timer};
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::ipc;
use messages::ports::Payload;
use messages::{CameraFrameHeader, FrameInbox, Inbox, PortError, Stamp, Stamped};

/// An input a service answers step by step.
pub trait StepInput {
    /// What the core sees of one message (for frames: borrowed from shared memory, not copied).
    type Msg<'a>
    where
        Self: 'a;
    /// The listener notified when a message arrives.
    fn listener(&self) -> &Listener<ipc::Service>;
    /// The topic's service name, for logs.
    fn name(&self) -> &str;
    /// Takes the next unread message, if any, and hands it to `f` with its stamp.
    fn next_with<R>(
        &self,
        f: impl FnOnce(&Stamp, Self::Msg<'_>) -> R,
    ) -> Result<Option<R>, PortError>;
}

impl<P: Payload + Stamped> StepInput for Inbox<P> {
    type Msg<'a> = &'a P;

    fn listener(&self) -> &Listener<ipc::Service> {
        Inbox::listener(self)
    }

    fn name(&self) -> &str {
        self.service()
    }

    fn next_with<R>(
        &self,
        f: impl FnOnce(&Stamp, Self::Msg<'_>) -> R,
    ) -> Result<Option<R>, PortError> {
        Ok(self.receive()?.map(|m| f(m.stamp(), &m)))
    }
}

impl StepInput for FrameInbox {
    type Msg<'a> = (&'a CameraFrameHeader, &'a [u8]);

    fn listener(&self) -> &Listener<ipc::Service> {
        FrameInbox::listener(self)
    }

    fn name(&self) -> &str {
        self.service()
    }

    fn next_with<R>(
        &self,
        f: impl FnOnce(&Stamp, Self::Msg<'_>) -> R,
    ) -> Result<Option<R>, PortError> {
        self.receive_with(|header, image| f(&header.stamp, (header, image)))
    }
}

/// A step's answer, to send.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Answer<'a, O> {
    /// A new step: the core just computed it.
    New(&'a O),
    /// The step answered last, asked again (a re-send): the same answer, the core not called.
    Again(&'a O),
}

impl<'a, O> Answer<'a, O> {
    pub fn output(&self) -> &'a O {
        match self {
            Answer::New(o) | Answer::Again(o) => o,
        }
    }
}

impl Runtime {
    /// Serves `input` until a termination signal (or `send` says stop): every message in order,
    /// its stamp judged on the vehicle clock ([`crate::screen::Screen`]); a new step through
    /// `core`, whose output goes to `send` as [`Answer::New`]; the step answered last, again, as
    /// [`Answer::Again`]; an older, stale or absurd step refused (counted and logged). A step whose
    /// core fails ends the loop with the error, unless the core refuses it itself: `Ok(None)` (a
    /// message it cannot use, which it has logged) leaves the step unanswered and unaccepted. `state`
    /// (the service's core, say) is lent to both in turn.
    pub fn serve_steps<I: StepInput, S, O: Clone>(
        &self,
        input: &I,
        state: &mut S,
        mut core: impl FnMut(&mut S, I::Msg<'_>) -> anyhow::Result<Option<O>>,
        mut send: impl FnMut(&mut S, Answer<'_, O>) -> anyhow::Result<Flow>,
    ) -> anyhow::Result<Stopped> {
        let mut once = Once::<O>::new(self.screen(input.name()));
        let clock = *self.clock();
        self.serve(&[input.listener()], Timer::None, |_| {
            loop {
                let answered = input.next_with(|stamp, msg| {
                    let now = clock.now_ns();
                    match once.check(stamp, now) {
                        Err(r) => Ok(Outcome::Refused(r)),
                        Ok(Some(out)) => Ok(Outcome::Repeat(out)),
                        Ok(None) => match core(state, msg) {
                            Ok(Some(out)) => {
                                once.commit(stamp, now, out.clone());
                                Ok(Outcome::Fresh(out))
                            }
                            Ok(None) => Ok(Outcome::Refused(crate::screen::Refusal::Unusable {
                                seq: stamp.seq,
                            })),
                            Err(e) => Err(e),
                        },
                    }
                })?;
                let Some(answered) = answered else {
                    return Ok(Flow::Continue);
                };
                let flow = match answered? {
                    Outcome::Fresh(o) => send(state, Answer::New(&o))?,
                    Outcome::Repeat(o) => send(state, Answer::Again(&o))?,
                    Outcome::Refused(_) => Flow::Continue,
                };
                if flow == Flow::Stop {
                    return Ok(Flow::Stop);
                }
            }
        })
    }
}
