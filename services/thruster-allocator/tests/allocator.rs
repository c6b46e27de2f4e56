//! The thruster allocator as a process: DOF commands over iceoryx2 in, setpoints out.

use config::Scenario;
use messages::{DofCommand, Endpoint, Stamp, StepStatus, topics};
use model::ThrusterLayout;
use std::time::{Duration, Instant};
use testkit::{Namespace, Process};

const T: Duration = Duration::from_secs(10);

fn command(seq: u64, value: f64) -> DofCommand {
    DofCommand {
        stamp: Stamp::new(seq, seq * 200_000_000, 0, seq as u32, StepStatus::Running),
        value,
    }
}

#[test]
fn three_commands_give_setpoints_that_map_back_to_them() {
    let ns = Namespace::new("alc");
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let setpoints = probe.inbox(&topics::THRUSTER_SETPOINTS);
    let (surge, sway, yaw) = (
        probe.outbox(&topics::SURGE_COMMAND),
        probe.outbox(&topics::SWAY_COMMAND),
        probe.outbox(&topics::YAW_COMMAND),
    );
    let _allocator = Process::start(
        &ns,
        &testkit::binary("thruster-allocator"),
        &["--endpoint", "sim"],
    );
    assert!(
        probe.wait_for_publisher(&setpoints, T),
        "the allocator never came up"
    );
    assert!(probe.wait_for_subscribers(&yaw, 1, T));

    let layout = ThrusterLayout::new(&Scenario::default().thrusters);
    for (seq, (u, v, r)) in [
        (1, (0.4, -0.2, 0.3)),
        (2, (0.0, 0.5, -0.5)),
        (3, (1.0, 0.5, 1.0)),
    ] {
        surge.send(command(seq, u)).unwrap();
        sway.send(command(seq, v)).unwrap();
        yaw.send(command(seq, r)).unwrap();
        let out = probe
            .wait_for(&setpoints, T, |m| m.stamp.seq == seq)
            .expect("setpoints for the step");
        assert_eq!(out.missing, 0);
        assert_eq!(out.count, 3);
        let f = layout.forces(out.as_slice());
        // Saturation scales the whole command: the direction is kept.
        assert!(
            (f.surge - u * out.scale).abs() < 1e-12,
            "surge {} vs {u}",
            f.surge
        );
        assert!(
            (f.sway - v * out.scale).abs() < 1e-12,
            "sway {} vs {v}",
            f.sway
        );
        assert!(
            (f.yaw - r * out.scale).abs() < 1e-12,
            "yaw {} vs {r}",
            f.yaw
        );
        assert!(out.as_slice().iter().all(|s| s.abs() <= 1.0 + 1e-12));
    }
}

#[test]
fn a_missing_command_counts_as_zero_after_the_deadline() {
    let ns = Namespace::new("ald");
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let setpoints = probe.inbox(&topics::THRUSTER_SETPOINTS);
    let (surge, sway) = (
        probe.outbox(&topics::SURGE_COMMAND),
        probe.outbox(&topics::SWAY_COMMAND),
    );
    let alloc = Process::start(
        &ns,
        &testkit::binary("thruster-allocator"),
        &["--deadline-ms", "100"],
    );
    assert!(probe.wait_for_publisher(&setpoints, T));
    assert!(probe.wait_for_subscribers(&sway, 1, T));
    surge.send(command(7, 0.2)).unwrap();
    sway.send(command(7, 0.3)).unwrap();
    let out = probe
        .wait_for(&setpoints, T, |m| m.stamp.seq == 7)
        .expect("setpoints despite the missing yaw");
    assert_eq!(out.missing, 0b100, "yaw is reported missing");
    let f = ThrusterLayout::new(&Scenario::default().thrusters).forces(out.as_slice());
    assert!((f.surge - 0.2).abs() < 1e-12 && (f.sway - 0.3).abs() < 1e-12 && f.yaw.abs() < 1e-12);
    assert!(
        alloc.log().contains("deadline passed"),
        "the miss is logged:\n{}",
        alloc.log()
    );
}

#[test]
fn a_re_sent_step_gets_the_same_setpoints_and_a_stale_one_nothing() {
    let ns = Namespace::new("alr");
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let setpoints = probe.inbox(&topics::THRUSTER_SETPOINTS);
    let outs = [
        probe.outbox(&topics::SURGE_COMMAND),
        probe.outbox(&topics::SWAY_COMMAND),
        probe.outbox(&topics::YAW_COMMAND),
    ];
    let _alloc = Process::start(&ns, &testkit::binary("thruster-allocator"), &[]);
    assert!(probe.wait_for_publisher(&setpoints, T));
    assert!(probe.wait_for_subscribers(&outs[2], 1, T));
    for o in &outs {
        o.send(command(4, 0.1)).unwrap();
    }
    let first = probe.wait_for(&setpoints, T, |m| m.stamp.seq == 4).unwrap();
    // The sway behaviour re-sends its step 4 with another value: the step is answered as before.
    outs[1].send(command(4, 0.9)).unwrap();
    let again = probe.wait_for(&setpoints, T, |m| m.stamp.seq == 4).unwrap();
    assert_eq!(first, again);
    // A step older than the last answered is ignored; the next step is answered normally.
    outs[0].send(command(3, 0.5)).unwrap();
    for o in &outs {
        o.send(command(5, 0.0)).unwrap();
    }
    let next = probe.wait_for(&setpoints, T, |_| true).unwrap();
    assert_eq!(next.stamp.seq, 5, "nothing for the stale step 3");
}

#[test]
fn sigterm_stops_it_cleanly() {
    let ns = Namespace::new("als");
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let setpoints = probe.inbox(&topics::THRUSTER_SETPOINTS);
    let mut alloc = Process::start(&ns, &testkit::binary("thruster-allocator"), &[]);
    assert!(probe.wait_for_publisher(&setpoints, T));
    let status = alloc.terminate(T);
    assert!(status.success(), "exit status {status:?}\n{}", alloc.log());
    assert!(alloc.log().contains("stopped"));
}

/// One allocator at a time: a second one refuses to start while the first is alive, with an error
/// naming it, and the first goes on answering; once the first is killed (SIGKILL: no clean-up), a
/// new one takes its place.
#[test]
fn a_second_allocator_is_refused_while_the_first_is_alive() {
    let ns = Namespace::new("al2");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let setpoints = probe.inbox(&topics::THRUSTER_SETPOINTS);
    let outs = [
        probe.outbox(&topics::SURGE_COMMAND),
        probe.outbox(&topics::SWAY_COMMAND),
        probe.outbox(&topics::YAW_COMMAND),
    ];
    let allocator = || {
        Process::start(
            &ns,
            &testkit::binary("thruster-allocator"),
            &["--endpoint", "vehicle"],
        )
    };
    // A step's commands, sent again every second until answered (as a producer that hears nothing
    // back does): a new allocator may subscribe only after the first send, and a dead one's
    // subscriptions count until they are removed.
    let step = |seq: u64| {
        let end = Instant::now() + T;
        while Instant::now() < end {
            for o in &outs {
                o.send(command(seq, 0.1)).unwrap();
            }
            let got = probe.wait_for(&setpoints, Duration::from_secs(1), |m| m.stamp.seq == seq);
            if got.is_some() {
                return got;
            }
        }
        None
    };
    let mut first = allocator();
    assert!(
        probe.wait_for_publisher(&setpoints, T),
        "the first allocator never came up:\n{}",
        first.log()
    );
    assert!(probe.wait_for_subscribers(&outs[2], 1, T));
    assert!(step(1).is_some(), "{}", first.log());

    let mut second = allocator();
    let status = second
        .wait(T)
        .unwrap_or_else(|| panic!("the second allocator did not give up:\n{}", second.log()));
    assert!(!status.success());
    let log = second.log();
    assert!(
        log.contains("one publisher at a time") && log.contains("`thruster-allocator`"),
        "a clear error naming the live allocator:\n{log}"
    );
    assert!(step(2).is_some(), "the first goes on:\n{}", first.log());

    first.kill9();
    let mut third = allocator();
    // Its subscribers show it is up; the dead one's place was freed.
    assert!(
        probe.wait_for_subscribers(&outs[2], 1, T),
        "the new allocator never came up:\n{}",
        third.log()
    );
    assert!(
        step(3).is_some(),
        "the new allocator answers:\n{}",
        third.log()
    );
    assert!(third.terminate(T).success(), "{}", third.log());
}
