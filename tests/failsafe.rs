//! The vehicle's failsafe thrust, one system test per path, as processes: the real allocator and
//! thruster driver on the vehicle endpoint, the test playing the behaviours (commands, stamped on the
//! vehicle clock as the camera stamps them) and the twin's thrusters (what reaches them, with its
//! arrival time). The thrusters go to zero, with the cause, within the deadline:
//!
//! - when the commands stop (the step's setpoints go stale: `deadline`);
//! - when the driver gets SIGTERM (`shutdown`), before it exits;
//! - when the allocator is killed (`allocator_dead`), before the setpoints it left would go stale:
//!   the test plays the supervisor's part, removing the dead process's leftovers, which announces the
//!   death on the setpoint topic's event service (the driver does not poll for it);
//! - and a second allocator is refused while the first drives; once the first dies the thrusters
//!   stop, and a new allocator drives them again.
//!
//! Every wait has a timeout and says what it waited for.

use adapters::twin::TwinThrusterPort;
use messages::{
    DofCommand, Endpoint, Outbox, Stamp, StepStatus, StopCause, ThrusterSetpoints, topics,
};
use runtime::VehicleClock;
use std::time::{Duration, Instant};
use testkit::{Namespace, Probe, Process};

/// Long enough for a process to start on a busy machine.
const T: Duration = Duration::from_secs(20);
/// The driver's default deadline at the scenario's 0.2 s sample period (three periods: one missed
/// frame passes, the second stops the thrusters).
fn deadline() -> Duration {
    adapters::failsafe::deadline(Duration::from_millis(200))
}
/// A busy 2-core machine wakes a blocked process late by tens of milliseconds now and then; a stop
/// later than the deadline by more than this is a failure.
const WAKE_MARGIN: Duration = Duration::from_millis(100);

/// The test's side: the behaviours' outboxes and the twin's thrusters.
struct Rig {
    probe: Probe,
    commands: [Outbox<DofCommand>; 3],
    thrusters: TwinThrusterPort,
    clock: VehicleClock,
    epoch: u32,
    seq: u64,
}

/// What reached the thrusters, and when.
struct Arrival {
    msg: ThrusterSetpoints,
    at: Instant,
}

impl Rig {
    fn new(ns: &Namespace) -> Rig {
        let probe = testkit::probe(ns, Endpoint::Vehicle);
        let commands = [
            probe.outbox(&topics::SURGE_COMMAND),
            probe.outbox(&topics::SWAY_COMMAND),
            probe.outbox(&topics::YAW_COMMAND),
        ];
        let thrusters = TwinThrusterPort::open(probe.node()).expect("the twin's thrusters");
        let clock = VehicleClock::system();
        Rig {
            probe,
            commands,
            thrusters,
            epoch: clock.new_epoch(),
            clock,
            seq: 0,
        }
    }

    /// The next arrival at the thrusters, waiting up to `timeout`.
    fn next(&self, timeout: Duration) -> Option<Arrival> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(msg) = self.thrusters.receive().expect("receiving") {
                return Some(Arrival {
                    msg,
                    at: Instant::now(),
                });
            }
            let left = end.checked_duration_since(Instant::now())?;
            self.probe.block_on(self.thrusters.listener(), left);
        }
    }

    /// The next stop at the thrusters (skipping setpoints), waiting up to `timeout`.
    fn stop(&self, timeout: Duration) -> Option<Arrival> {
        let end = Instant::now() + timeout;
        loop {
            let a = self.next(end.checked_duration_since(Instant::now())?)?;
            if a.msg.stop_cause().is_some() {
                return Some(a);
            }
        }
    }

    /// Sends the commands of a new step, stamped now on the vehicle clock, and waits for its
    /// setpoints at the thrusters; a step unanswered for a second (an allocator still starting)
    /// is followed by the next one, as the camera's clock would, for up to [`T`]. Stops arriving
    /// meanwhile are skipped.
    fn step(&mut self, procs: &[&Process]) -> Arrival {
        let end = Instant::now() + T;
        loop {
            self.seq += 1;
            let stamp = Stamp::new(
                self.seq,
                self.seq * 200_000_000,
                0,
                self.seq as u32,
                StepStatus::Running,
            )
            .timed(self.epoch, self.clock.now_ns());
            for (out, value) in self.commands.iter().zip([0.6, 0.2, 0.1]) {
                out.send(DofCommand { stamp, value })
                    .expect("sending a command");
            }
            let this_step = (Instant::now() + Duration::from_secs(1)).min(end);
            while let Some(a) = self.next(this_step.saturating_duration_since(Instant::now())) {
                if a.msg.stop == 0 && a.msg.stamp.seq == self.seq {
                    assert!(
                        a.msg.as_slice().iter().any(|v| *v != 0.0),
                        "thrust, not a stop"
                    );
                    return a;
                }
            }
            assert!(
                Instant::now() < end,
                "no setpoints at the thrusters within {T:?} (step {})\n{}",
                self.seq,
                logs(procs)
            );
        }
    }

    /// Waits until the allocator and the driver are connected: the driver's thrusters at rest
    /// (its start's stop), the allocator's subscribers on every command topic.
    fn wait_until_up(&self, procs: &[&Process]) {
        let start = self.stop(T).unwrap_or_else(|| {
            panic!(
                "the driver never started its thrusters at rest\n{}",
                logs(procs)
            )
        });
        assert_eq!(start.msg.stop_cause(), Some(StopCause::Start));
        assert!(start.msg.as_slice().iter().all(|v| *v == 0.0));
        for out in &self.commands {
            assert!(
                self.probe.wait_for_subscribers(out, 1, T),
                "the allocator never subscribed to the commands\n{}",
                logs(procs)
            );
        }
    }
}

fn logs(procs: &[&Process]) -> String {
    procs
        .iter()
        .map(|p| p.log())
        .collect::<Vec<_>>()
        .join("\n-----\n")
}

fn vehicle(ns: &Namespace, name: &str, extra: &[&str]) -> Process {
    let mut args = vec!["--endpoint", "vehicle"];
    args.extend_from_slice(extra);
    Process::start(ns, &testkit::binary(name), &args)
}

/// What the supervisor does when a service dies: removes the dead process's iceoryx2 leftovers,
/// which announces its death to the listeners of its topics (the driver itself looks only once no
/// setpoints came for the deadline, too late for these tests' bound). iceoryx2 lets one thread of a
/// process clean up at a time and refuses the others: the tests, threads of one process, take turns.
fn remove_the_dead(ns: &Namespace) {
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let iox = ns.iox.config().expect("the namespace's iceoryx2 config");
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    assert!(
        runtime::remove_dead_nodes(&iox) > 0,
        "the killed allocator's leftovers were not found"
    );
}

/// The stop is all zeros for the given cause.
fn assert_stop(a: &Arrival, cause: StopCause, procs: &[&Process]) {
    assert_eq!(a.msg.stop_cause(), Some(cause), "{}", logs(procs));
    assert_eq!(a.msg.count, 3);
    assert!(
        a.msg.as_slice().iter().all(|v| *v == 0.0),
        "a stop is zero thrust"
    );
}

#[test]
fn when_the_commands_stop_the_thrusters_stop_at_the_deadline() {
    let ns = Namespace::new("fsdl");
    let mut rig = Rig::new(&ns);
    let mut driver = vehicle(&ns, "thruster-driver", &["--sink", "twin"]);
    let allocator = vehicle(&ns, "thruster-allocator", &[]);
    rig.wait_until_up(&[&driver, &allocator]);
    for _ in 0..5 {
        rig.step(&[&driver, &allocator]);
    }
    let taken = Instant::now();
    let last = rig.step(&[&driver, &allocator]);
    // No more commands: the last step's setpoints go stale once they are the deadline old.
    let stop = rig.stop(deadline() + WAKE_MARGIN + T).unwrap_or_else(|| {
        panic!(
            "the thrusters never stopped\n{}",
            logs(&[&driver, &allocator])
        )
    });
    assert_stop(&stop, StopCause::Deadline, &[&driver, &allocator]);
    assert_eq!(
        stop.msg.stamp, last.msg.stamp,
        "stamped with the last step written"
    );
    let after = stop.at.duration_since(taken);
    assert!(
        after >= deadline() - Duration::from_millis(5) && after <= deadline() + WAKE_MARGIN,
        "zero thrust {after:?} after the last step was taken, the deadline is {:?}",
        deadline()
    );
    // Commands again: the thrusters are driven again.
    rig.step(&[&driver, &allocator]);
    // The log is complete once the driver has exited.
    let status = driver.terminate(T);
    assert!(status.success(), "{status:?}\n{}", driver.log());
    assert!(
        driver
            .log()
            .contains("no fresh setpoints within the deadline"),
        "the stop is logged with its cause:\n{}",
        driver.log()
    );
}

#[test]
fn sigterm_stops_the_thrusters_before_the_driver_exits() {
    let ns = Namespace::new("fstm");
    let mut rig = Rig::new(&ns);
    let mut driver = vehicle(&ns, "thruster-driver", &["--sink", "twin"]);
    let allocator = vehicle(&ns, "thruster-allocator", &[]);
    rig.wait_until_up(&[&driver, &allocator]);
    for _ in 0..3 {
        rig.step(&[&driver, &allocator]);
    }
    let signalled = Instant::now();
    assert!(driver.signal(libc::SIGTERM), "the driver is running");
    let stop = rig
        .stop(T)
        .unwrap_or_else(|| panic!("no stop after SIGTERM\n{}", logs(&[&driver, &allocator])));
    assert_stop(&stop, StopCause::Shutdown, &[&driver, &allocator]);
    assert!(
        stop.at.duration_since(signalled) < deadline(),
        "stopped {:?} after SIGTERM",
        stop.at.duration_since(signalled)
    );
    let status = driver
        .wait(T)
        .unwrap_or_else(|| panic!("the driver did not exit after SIGTERM\n{}", driver.log()));
    assert!(status.success(), "{status:?}\n{}", driver.log());
    assert!(driver.log().contains("thrusters stopped: the driver stops"));
}

#[test]
fn a_killed_allocator_stops_the_thrusters_within_the_deadline() {
    let ns = Namespace::new("fskl");
    let mut rig = Rig::new(&ns);
    let mut driver = vehicle(&ns, "thruster-driver", &["--sink", "twin"]);
    let mut allocator = vehicle(&ns, "thruster-allocator", &[]);
    rig.wait_until_up(&[&driver, &allocator]);
    for _ in 0..3 {
        rig.step(&[&driver, &allocator]);
    }
    // Setpoints fresh for another deadline; the allocator dies now, with no chance to clean up.
    let fresh = rig.step(&[&driver, &allocator]);
    allocator.kill9();
    remove_the_dead(&ns);
    let stop = rig
        .stop(T)
        .unwrap_or_else(|| panic!("the thrusters never stopped\n{}", driver.log()));
    assert_stop(&stop, StopCause::AllocatorDead, &[&driver]);
    let after = stop.at.duration_since(fresh.at);
    assert!(
        after < deadline(),
        "zero thrust {after:?} after the last setpoints: the allocator's death must be seen before they go stale"
    );
    let status = driver.terminate(T);
    assert!(status.success(), "{status:?}\n{}", driver.log());
    assert!(
        driver.log().contains("the allocator's process is gone"),
        "the stop is logged with its cause:\n{}",
        driver.log()
    );
}

#[test]
fn a_second_allocator_is_refused_and_the_thrusters_stop_when_the_first_dies() {
    let ns = Namespace::new("fs2a");
    let mut rig = Rig::new(&ns);
    let driver = vehicle(&ns, "thruster-driver", &["--sink", "twin"]);
    let mut first = vehicle(&ns, "thruster-allocator", &[]);
    rig.wait_until_up(&[&driver, &first]);
    rig.step(&[&driver, &first]);

    let mut second = vehicle(&ns, "thruster-allocator", &[]);
    let status = second
        .wait(T)
        .unwrap_or_else(|| panic!("the second allocator did not give up\n{}", second.log()));
    assert!(!status.success());
    assert!(
        second.log().contains("one publisher at a time")
            && second.log().contains("`thruster-allocator`"),
        "a clear error naming the live allocator:\n{}",
        second.log()
    );
    // The first one alone drives the thrusters: each step's setpoints arrive once.
    for _ in 0..3 {
        let a = rig.step(&[&driver, &first]);
        assert!(
            rig.next(Duration::ZERO)
                .is_none_or(|b| b.msg.stamp.seq != a.msg.stamp.seq),
            "a step's setpoints arrived twice"
        );
    }

    let fresh = rig.step(&[&driver, &first]);
    first.kill9();
    remove_the_dead(&ns);
    let stop = rig
        .stop(T)
        .unwrap_or_else(|| panic!("the thrusters never stopped\n{}", driver.log()));
    assert_stop(&stop, StopCause::AllocatorDead, &[&driver]);
    assert!(stop.at.duration_since(fresh.at) < deadline());

    // A new allocator after the crash drives them again.
    let third = vehicle(&ns, "thruster-allocator", &[]);
    rig.step(&[&driver, &third]);
}
