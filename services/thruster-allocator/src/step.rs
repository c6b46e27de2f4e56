//! The allocator in the mesh's lockstep, as a plain state machine fed the time (the
//! `thruster-allocator` binary binds it to its four ports): the surge, sway and yaw commands of one
//! step in, that step's thruster setpoints out, computed once. Every command's stamp is judged first
//! (`runtime::screen::Screen`: a stale, older or absurd step is refused; a restarted producer's new
//! epoch is followed). A step whose commands do not all arrive within the deadline of its first is
//! allocated with the missing ones as 0 (their bits set in `ThrusterSetpoints::missing`); an
//! incomplete step overtaken by a newer one is dropped; a command of a step already answered (a
//! re-send) gets the same setpoints again.

use crate::Allocator;
use messages::{DofCommand, Stamp, ThrusterSetpoints};
use model::bounds::Fixes;
use runtime::lockstep::{Gather, Once, Partial};
use runtime::screen::{Refusal, Screen};
use std::time::{Duration, Instant};

/// The allocator's inputs, in the order of the `missing` bits of `ThrusterSetpoints`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Input {
    Surge = 0,
    Sway = 1,
    Yaw = 2,
}

impl Input {
    pub const ALL: [Input; 3] = [Input::Surge, Input::Sway, Input::Yaw];

    pub fn name(self) -> &'static str {
        match self {
            Input::Surge => "surge",
            Input::Sway => "sway",
            Input::Yaw => "yaw",
        }
    }
}

/// What a command or the passing of time led to.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// Nothing to send yet.
    Idle,
    /// Send these setpoints (a step completed, or a re-sent step answered again); `fixes`: the
    /// commands the rule for bad values changed (none for a re-send).
    Send {
        setpoints: ThrusterSetpoints,
        fixes: Fixes,
    },
    /// A newer step arrived before this one was complete: it is dropped.
    Overtaken(Partial<DofCommand, 3>),
    /// The step's deadline passed: allocated with the missing commands as 0.
    Overdue {
        partial: Partial<DofCommand, 3>,
        setpoints: ThrusterSetpoints,
        fixes: Fixes,
    },
    /// The command's stamp was refused (already counted and logged by the screen).
    Refused(Refusal),
}

/// The inputs a partial step lacks, by name.
pub fn missing(partial: &Partial<DofCommand, 3>) -> Vec<&'static str> {
    Input::ALL
        .iter()
        .zip(&partial.values)
        .filter(|(_, v)| v.is_none())
        .map(|(i, _)| i.name())
        .collect()
}

/// The allocator in lockstep with the mesh.
pub struct StepAllocator {
    allocator: Allocator,
    deadline: Duration,
    gather: Gather<DofCommand, 3>,
    once: Once<ThrusterSetpoints>,
}

impl StepAllocator {
    /// The allocator answering commands judged by `screen`, allocating an incomplete step
    /// `deadline` after its first command.
    pub fn new(allocator: Allocator, deadline: Duration, screen: Screen) -> Self {
        StepAllocator {
            allocator,
            deadline,
            gather: Gather::new(),
            once: Once::new(screen),
        }
    }

    pub fn deadline(&self) -> Duration {
        self.deadline
    }

    /// The commands' judge.
    pub fn screen(&self) -> &Screen {
        self.once.screen()
    }

    /// A command from `input` arrived at `now` (`clock_ns` on the vehicle clock).
    pub fn on_command(
        &mut self,
        input: Input,
        cmd: DofCommand,
        now: Instant,
        clock_ns: i64,
    ) -> Event {
        match self.once.check(&cmd.stamp, clock_ns) {
            Err(refusal) => return Event::Refused(refusal),
            // A step already answered: the same setpoints again for a re-send.
            Ok(Some(setpoints)) => {
                return Event::Send {
                    setpoints,
                    fixes: Fixes::default(),
                };
            }
            Ok(None) => {}
        }
        let key = (cmd.stamp.epoch, cmd.stamp.seq);
        match self.gather.put(input as usize, key, cmd, now) {
            Ok(Some((_, all))) => self.answer(all[0].stamp, all.map(|c| Some(c.value)), clock_ns),
            Ok(None) => Event::Idle,
            Err(overtaken) => Event::Overtaken(overtaken),
        }
    }

    /// Time passed: a step waiting longer than the deadline is allocated without its missing
    /// commands.
    pub fn on_time(&mut self, now: Instant, clock_ns: i64) -> Event {
        let Some(partial) = self.gather.take_overdue(self.deadline, now) else {
            return Event::Idle;
        };
        let stamp = partial
            .values
            .iter()
            .flatten()
            .next()
            .map(|c| c.stamp)
            .expect("a step being gathered has a command");
        match self.answer(stamp, partial.values.map(|c| c.map(|c| c.value)), clock_ns) {
            Event::Send { setpoints, fixes } => Event::Overdue {
                partial,
                setpoints,
                fixes,
            },
            other => other,
        }
    }

    /// The setpoints of step `stamp`, computed once (its commands were judged on arrival).
    fn answer(&mut self, stamp: Stamp, values: [Option<f64>; 3], clock_ns: i64) -> Event {
        let (msg, fixes) = setpoints(&self.allocator, stamp, values);
        self.once.commit(&stamp, clock_ns, msg);
        Event::Send {
            setpoints: msg,
            fixes,
        }
    }
}

/// The setpoints message of one step (a missing command counts as 0), and the commands the rule for
/// bad values changed.
pub fn setpoints(
    allocator: &Allocator,
    stamp: Stamp,
    values: [Option<f64>; 3],
) -> (ThrusterSetpoints, Fixes) {
    let [surge, sway, yaw] = values.map(|v| v.unwrap_or(0.0));
    let allocation = allocator.allocate(model::Forces { surge, sway, yaw });
    let s = allocation.setpoints.as_slice();
    let mut msg = ThrusterSetpoints {
        stamp,
        count: s.len() as u32,
        missing: values
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_none())
            .map(|(k, _)| 1 << k)
            .sum(),
        scale: allocation.scale,
        ..Default::default()
    };
    msg.values[..s.len()].copy_from_slice(s);
    (msg, allocation.fixes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::{Scenario, StepStatus};

    const MS: Duration = Duration::from_millis(1);

    fn allocator() -> StepAllocator {
        StepAllocator::new(
            Allocator::new(&Scenario::default().thrusters),
            100 * MS,
            Screen::new("commands", runtime::screen::ScreenLimits::control(0.2)),
        )
    }

    /// The vehicle clock in these tests: untimed stamps ignore it.
    const NOW: i64 = 1;

    fn cmd(seq: u64, value: f64) -> DofCommand {
        DofCommand {
            stamp: Stamp::new(seq, seq * 200_000_000, 0, seq as u32, StepStatus::Running),
            value,
        }
    }

    fn sent(e: Event) -> ThrusterSetpoints {
        match e {
            Event::Send { setpoints, .. } => setpoints,
            other => panic!("expected setpoints, got {other:?}"),
        }
    }

    #[test]
    fn a_complete_step_is_allocated_once_and_a_resend_gets_the_same_setpoints() {
        let mut a = allocator();
        let t0 = Instant::now();
        assert_eq!(a.on_command(Input::Sway, cmd(1, 0.2), t0, NOW), Event::Idle);
        assert_eq!(a.on_command(Input::Yaw, cmd(1, -0.1), t0, NOW), Event::Idle);
        let s = sent(a.on_command(Input::Surge, cmd(1, 0.5), t0, NOW));
        let alone = Allocator::new(&Scenario::default().thrusters).allocate(model::Forces {
            surge: 0.5,
            sway: 0.2,
            yaw: -0.1,
        });
        assert_eq!(s.as_slice(), alone.setpoints.as_slice());
        assert_eq!((s.stamp.seq, s.missing), (1, 0));
        // A re-send of step 1: the same setpoints; an older step: nothing.
        assert_eq!(sent(a.on_command(Input::Yaw, cmd(1, 0.9), t0, NOW)), s);
        assert!(matches!(
            a.on_command(Input::Yaw, cmd(0, 0.9), t0, NOW),
            Event::Refused(Refusal::Older { seq: 0, last: 1 })
        ));
    }

    #[test]
    fn an_overdue_step_is_allocated_with_its_missing_commands_as_zero() {
        let mut a = allocator();
        let t0 = Instant::now();
        a.on_command(Input::Surge, cmd(4, 0.5), t0, NOW);
        a.on_command(Input::Yaw, cmd(4, 0.3), t0 + 10 * MS, NOW);
        assert_eq!(a.on_time(t0 + 99 * MS, NOW), Event::Idle);
        match a.on_time(t0 + 100 * MS, NOW) {
            Event::Overdue {
                partial, setpoints, ..
            } => {
                assert_eq!(missing(&partial), vec!["sway"]);
                assert_eq!(setpoints.missing, 0b010);
                let want = Allocator::new(&Scenario::default().thrusters).allocate(model::Forces {
                    surge: 0.5,
                    sway: 0.0,
                    yaw: 0.3,
                });
                assert_eq!(setpoints.as_slice(), want.setpoints.as_slice());
            }
            other => panic!("{other:?}"),
        }
        // The late command of the step answered without it gets those setpoints again.
        assert!(matches!(
            a.on_command(Input::Sway, cmd(4, 0.7), t0 + 200 * MS, NOW),
            Event::Send { setpoints: s, .. } if s.missing == 0b010
        ));
    }

    #[test]
    fn an_incomplete_step_overtaken_by_a_newer_one_is_dropped() {
        let mut a = allocator();
        let t0 = Instant::now();
        a.on_command(Input::Surge, cmd(7, 0.5), t0, NOW);
        match a.on_command(Input::Surge, cmd(8, 0.5), t0, NOW) {
            Event::Overtaken(p) => {
                assert_eq!(p.seq, 7);
                assert_eq!(missing(&p), vec!["sway", "yaw"]);
            }
            other => panic!("{other:?}"),
        }
        a.on_command(Input::Sway, cmd(8, 0.0), t0, NOW);
        assert_eq!(
            sent(a.on_command(Input::Yaw, cmd(8, 0.0), t0, NOW))
                .stamp
                .seq,
            8
        );
    }
}
