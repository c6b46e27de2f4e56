//! The lockstep protocol, written once for every process of the mesh (DESIGN.md, "Lockstep and
//! time"). Plain state machines: no IPC and no clock of their own (every call that needs the time is
//! given `now`), so the protocol is unit-tested here and a service's `main` only binds it to ports.
//!
//! - The **plant's side** ([`Lockstep`] over a [`Plant`]): the simulator, or the vehicle twin with
//!   `--lockstep`, publishes step `t`, waits for the thruster setpoints answering it, integrates one
//!   control period and publishes `t + 1`. It re-publishes an unanswered step every
//!   [`Limits::resend`]; before the mesh ever answered it waits indefinitely; once the mesh runs, a
//!   step unanswered for [`Limits::deadline`] is integrated without an answer, so the mesh never
//!   hangs on one missing message ([`Deadlines`] is that clock).
//! - The **consumers' side**: messages are delivered at least once (a re-sent step, a topic's history
//!   for a restarted process), so every consumer calls its core once per step and answers a repeated
//!   step with the output it already computed ([`Once`]); the thruster allocator collects the three
//!   commands of one step ([`Gather`]) and never mixes two steps. Every stamp is judged first, by
//!   the rule every consumer shares, lockstep or not ([`crate::screen::Screen`]): a restarted
//!   producer's new epoch is followed; an older, stale or absurd step is refused, counted and
//!   logged.

mod clock;
mod consumer;
mod plant;

pub use clock::{Deadlines, Due, Limits, Phase};
pub use consumer::{Gather, Once, Outcome, Partial};
pub use plant::{Advanced, Cause, Closed, Lockstep, Plant, Reaction, Shell};
