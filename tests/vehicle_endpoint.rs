//! The vehicle endpoint over the twin, as processes: the twin's frame reaches perception's topic
//! through the camera (its twin frame source) with the twin's metadata and the camera's epoch and
//! clock, and the allocator's setpoints reach the twin through the thruster driver (its twin
//! thruster sink), and the twin integrates exactly them.

use config::{Scenario, TwinParams};
use messages::{DofCommand, Endpoint, StepStatus, topics};
use runtime::lockstep::{Limits, Lockstep, Reaction};
use std::time::{Duration, Instant};
use testkit::{Namespace, Process};
use thruster_allocator::Allocator;
use vehicle_twin::Twin;

const T: Duration = Duration::from_secs(20);
const SEED: u64 = 6;

fn scenario() -> Scenario {
    config::load(&testkit::config_dir().join("scenario.toml")).unwrap()
}

#[test]
fn twin_frames_reach_perception_and_the_allocators_setpoints_reach_the_twin() {
    let ns = Namespace::new("vtep");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let observations = probe.inbox(&topics::CABLE_OBSERVATION);
    let setpoints = probe.inbox(&topics::THRUSTER_SETPOINTS);
    let commands = [
        probe.outbox(&topics::SURGE_COMMAND),
        probe.outbox(&topics::SWAY_COMMAND),
        probe.outbox(&topics::YAW_COMMAND),
    ];
    let seed = SEED.to_string();
    let vehicle = |name: &str, extra: &[&str]| {
        let mut args = vec!["--endpoint", "vehicle", "--seed", &seed];
        args.extend_from_slice(extra);
        Process::start(&ns, &testkit::binary(name), &args)
    };
    let twin = vehicle("vehicle-twin", &["--lockstep", "--resend-ms", "50"]);
    let camera = vehicle("camera", &["--source", "twin"]);
    let perception = vehicle("perception", &["--eyes", "ideal"]);
    let driver = vehicle("thruster-driver", &["--sink", "twin"]);
    let allocator = vehicle("thruster-allocator", &[]);
    let logs = || {
        [&twin, &camera, &perception, &driver, &allocator]
            .iter()
            .map(|p| p.log())
            .collect::<Vec<_>>()
            .join("\n-----\n")
    };

    // The twin's lockstep, computed here.
    let params: TwinParams = config::load(&testkit::config_dir().join("twin.toml")).unwrap();
    let core = Twin::new(&scenario(), &params, SEED, false).unwrap();
    let limits = Limits::new(Duration::from_millis(50), Duration::from_secs(2));
    let (mut reference, first) = Lockstep::start(core, limits, 0, Instant::now());
    let Reaction::Publish { next: mut want, .. } = first else {
        panic!()
    };
    let allocator_core = Allocator::new(&scenario().thrusters);
    let mut last_seq = 0;
    for k in 0..6 {
        // The frame arrives at perception's output with the twin's metadata.
        let obs = probe
            .wait_for(&observations, T, |m| m.stamp.time_ns == want.time_ns())
            .unwrap_or_else(|| panic!("frame {k} never reached perception\n{}", logs()));
        assert_eq!(
            (obs.stamp.episode, obs.stamp.step, obs.stamp.status()),
            (want.trial, want.step, want.status),
            "frame {k}"
        );
        assert_eq!(
            obs.observation, want.truth,
            "ideal perception passes the twin's truth"
        );
        assert!(obs.stamp.seq > last_seq, "the camera's seq grows");
        assert!(
            obs.stamp.is_timed() && obs.stamp.epoch != 0,
            "stamped on the vehicle clock in the camera's epoch"
        );
        assert_eq!(want.status, StepStatus::Running);
        last_seq = obs.stamp.seq;

        // The behaviours' commands for it (here: the test's), through the allocator to the twin.
        let values = [0.9, 0.4 - 0.1 * k as f64, 0.5];
        for (out, v) in commands.iter().zip(values) {
            out.send(DofCommand {
                stamp: obs.stamp,
                value: v,
            })
            .unwrap();
        }
        let sp = probe
            .wait_for(&setpoints, T, |m| m.stamp.seq == obs.stamp.seq)
            .unwrap_or_else(|| panic!("no setpoints for frame {k}\n{}", logs()));
        let alloc = allocator_core.allocate(model::Forces {
            surge: values[0],
            sway: values[1],
            yaw: values[2],
        });
        assert_eq!(sp.as_slice(), alloc.setpoints.as_slice());
        // The twin integrates exactly these setpoints: its next frame is the reference's.
        let Reaction::Publish { next: shot, .. } =
            reference.on_answer(want.time_ns(), sp.as_slice(), Instant::now())
        else {
            panic!()
        };
        want = shot;
    }
}
