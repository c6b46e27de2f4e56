//! The surge controller as a process: cable observations over iceoryx2 in, surge commands out.

use config::Scenario;
use messages::{CableObservationData, CableObservationMsg, Endpoint, Stamp, StepStatus, topics};
use std::time::Duration;
use testkit::{Namespace, Probe, Process};

const T: Duration = Duration::from_secs(10);

fn observation(seq: u64, found: bool, x_g: f64, theta_deg: f64) -> CableObservationMsg {
    CableObservationMsg {
        stamp: Stamp::new(seq, seq * 200_000_000, 0, seq as u32, StepStatus::Running),
        observation: CableObservationData {
            found: found as u8,
            x_g,
            theta: theta_deg.to_radians(),
            ..Default::default()
        },
    }
}

struct Rig {
    probe: Probe,
    process: Process,
    observations: messages::Outbox<CableObservationMsg>,
    commands: messages::Inbox<messages::DofCommand>,
    _ns: Namespace,
}

fn start(label: &str) -> Rig {
    let ns = Namespace::new(label);
    let probe = testkit::probe(&ns, Endpoint::Sim);
    let commands = probe.inbox(&topics::SURGE_COMMAND);
    let observations = probe.outbox(&topics::CABLE_OBSERVATION);
    let process = Process::start(&ns, &testkit::binary("surge-controller"), &[]);
    assert!(
        probe.wait_for_publisher(&commands, T),
        "the surge controller never came up"
    );
    assert!(probe.wait_for_subscribers(&observations, 1, T));
    Rig {
        probe,
        process,
        observations,
        commands,
        _ns: ns,
    }
}

impl Rig {
    fn command(&self, msg: CableObservationMsg) -> f64 {
        self.observations.send(msg).unwrap();
        let seq = msg.stamp.seq;
        self.probe
            .wait_for(&self.commands, T, |c| c.stamp.seq == seq)
            .unwrap_or_else(|| panic!("no command for step {seq}"))
            .value
    }
}

#[test]
fn cruises_at_0_3_m_s_only_while_the_cable_is_centred() {
    let rig = start("sgc");
    let scenario: Scenario = config::load(&testkit::config_dir().join("scenario.toml")).unwrap();
    let surge = scenario.commanded_model().surge;
    let cruise = rig.command(observation(1, true, 0.0, 0.0));
    // The thrust that holds 0.3 m/s in steady state, by the identified model (Table I).
    assert!(
        (surge.steady_velocity(cruise) - 0.3).abs() < 1e-9,
        "thrust {cruise} holds {} m/s",
        surge.steady_velocity(cruise)
    );
    // Centred: |x_g| < 0.15 and |Theta| < 15 degrees.
    for (seq, x_g, theta_deg) in [(2, 0.14, 14.0), (3, -0.14, -14.0), (4, 0.05, -3.0)] {
        assert_eq!(rig.command(observation(seq, true, x_g, theta_deg)), cruise);
    }
    for (seq, x_g, theta_deg) in [
        (5, 0.16, 0.0),
        (6, -0.16, 0.0),
        (7, 0.0, 16.0),
        (8, 0.0, -16.0),
        (9, 0.3, 40.0),
    ] {
        assert_eq!(
            rig.command(observation(seq, true, x_g, theta_deg)),
            0.0,
            "x_g {x_g}, Theta {theta_deg} deg"
        );
    }
    // A frame without the cable is no reason to drive on, whatever its numbers say.
    assert_eq!(rig.command(observation(10, false, 0.0, 0.0)), 0.0);
    assert_eq!(rig.command(observation(11, true, 0.0, 0.0)), cruise);
}

#[test]
fn a_repeated_step_gets_its_first_command_and_a_stale_one_none() {
    let rig = start("sgr");
    let cruise = rig.command(observation(5, true, 0.0, 0.0));
    assert!(cruise > 0.0);
    // Step 5 again, now off-centre: answered as the first time.
    assert_eq!(rig.command(observation(5, true, 0.4, 0.0)), cruise);
    // Step 4 is older: ignored, the next answer is step 6's.
    rig.observations
        .send(observation(4, true, 0.0, 0.0))
        .unwrap();
    rig.observations
        .send(observation(6, true, 0.4, 0.0))
        .unwrap();
    let next = rig.probe.wait_for(&rig.commands, T, |_| true).unwrap();
    assert_eq!((next.stamp.seq, next.value), (6, 0.0));
}

#[test]
fn sigterm_stops_it_cleanly() {
    let mut rig = start("sgs");
    rig.command(observation(1, true, 0.0, 0.0));
    let status = rig.process.terminate(T);
    assert!(status.success(), "exit {status:?}\n{}", rig.process.log());
    assert!(rig.process.log().contains("stopped"));
}
