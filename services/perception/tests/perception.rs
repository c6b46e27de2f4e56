//! Perception as a process: camera frames over iceoryx2 in, cable observations out.

use config::Scenario;
use messages::{
    CableObservationData, CableObservationMsg, CameraFrameHeader, Endpoint, FrameOutbox, Inbox,
    Stamp, StepStatus, topics,
};
use model::{Cable, Camera, Pose, PoseRate};
use std::time::Duration;
use testkit::{Namespace, Probe, Process};

const T: Duration = Duration::from_secs(10);
const W: usize = 320;
const H: usize = 240;

fn scenario() -> Scenario {
    config::load(&testkit::config_dir().join("scenario.toml")).expect("the repository's scenario")
}

fn stamp(seq: u64, step: u32) -> Stamp {
    Stamp::new(seq, seq * 200_000_000, 0, step, StepStatus::Running)
}

fn header(seq: u64, step: u32, truth: CableObservationData) -> CameraFrameHeader {
    CameraFrameHeader {
        stamp: stamp(seq, step),
        width: W as u32,
        height: H as u32,
        truth,
        ..Default::default()
    }
}

/// A perception process and the test's ports, connected.
struct Rig {
    probe: Probe,
    frames: FrameOutbox,
    observations: Inbox<CableObservationMsg>,
    perception: Process,
}

fn rig(ns: &Namespace, eyes: &str) -> Rig {
    let probe = testkit::probe(ns, Endpoint::Sim);
    let frames = probe.frame_outbox(W * H);
    let observations = probe.inbox(&topics::CABLE_OBSERVATION);
    let perception = Process::start(
        ns,
        &testkit::binary("perception"),
        &["--endpoint", "sim", "--eyes", eyes],
    );
    // Perception subscribes to frames before it opens its observation publisher.
    assert!(
        probe.wait_for_publisher(&observations, T),
        "perception never came up\n{}",
        perception.log()
    );
    Rig {
        probe,
        frames,
        observations,
        perception,
    }
}

impl Rig {
    fn send(&self, header: CameraFrameHeader, image: &[u8]) {
        self.frames
            .send_with(header, image.len(), |buf| {
                buf.copy_from_slice(image);
                Ok::<_, ()>(())
            })
            .unwrap()
            .unwrap();
    }

    fn observation(&self, seq: u64) -> CableObservationMsg {
        self.probe
            .wait_for(&self.observations, T, |m| m.stamp.seq == seq)
            .unwrap_or_else(|| panic!("observation {seq}\n{}", self.perception.log()))
    }
}

/// A rendered frame of the cable seen at (x_g, theta), and the geometric camera's line there.
fn rendered(scenario: &Scenario, x_g: f64, theta: f64) -> (Vec<u8>, model::CableLine) {
    let camera = Camera::new(&scenario.camera);
    let cable = Cable::new(&scenario.cable);
    let pose: Pose =
        vision::sampling::pose_for_line(&camera, &cable, x_g, theta, 0.7).expect("a pose");
    let mut renderer = vision::Renderer::from_scenario(scenario, 5).unwrap();
    let frame = renderer.render_frame(&pose, &PoseRate::default(), 0);
    (frame.data().to_vec(), camera.view(&pose, &cable).unwrap())
}

#[test]
fn images_give_the_line_the_geometric_camera_sees() {
    let ns = Namespace::new("pcim");
    let r = rig(&ns, "images");
    let scenario = scenario();
    for (seq, (x_g, theta_deg)) in [(1, (0.12, 20.0)), (2, (-0.2, -35.0))] {
        let (image, line) = rendered(&scenario, x_g, f64::to_radians(theta_deg));
        // No truth in the header: the line must come from the image.
        let h = header(seq, 0, CableObservationData::default());
        r.send(h, &image);
        let obs = r.observation(seq);
        assert_eq!(obs.stamp, h.stamp, "the stamp is copied unchanged");
        let o = obs.observation;
        assert_eq!(o.found, 1, "{o:?}");
        assert!(
            (o.theta - line.theta).abs() < 1f64.to_radians(),
            "Theta {} vs {}",
            o.theta.to_degrees(),
            line.theta.to_degrees()
        );
        assert!(
            (o.x_g - line.x_g).abs() < 0.01,
            "x_g {} vs {}",
            o.x_g,
            line.x_g
        );
    }
}

#[test]
fn ideal_eyes_pass_the_truth_on() {
    let ns = Namespace::new("pcid");
    let r = rig(&ns, "ideal");
    let truth = CableObservationData {
        found: 1,
        rho: -12.5,
        theta: 0.25,
        x_g: 0.1,
        y_g: 0.02,
        x_g_rate: -0.05,
        theta_rate: 0.3,
        confidence: 1.0,
        ..Default::default()
    };
    let h = header(4, 3, truth);
    r.send(h, &[]);
    let obs = r.observation(4);
    assert_eq!(obs.stamp, h.stamp);
    assert_eq!(obs.observation, truth);
}

/// A truncated frame is refused (logged, no observation) and does not take its step: the same step
/// sent intact is perceived; perception goes on.
#[test]
fn a_bad_frame_is_refused_and_perception_goes_on() {
    let ns = Namespace::new("pcbd");
    let mut r = rig(&ns, "images");
    let scenario = scenario();
    // Shorter than width * height.
    r.send(header(1, 0, CableObservationData::default()), &[128; 100]);
    let (image, line) = rendered(&scenario, 0.05, 0.1);
    r.send(header(1, 0, CableObservationData::default()), &image);
    // The first observation is the intact frame's: none came for the truncated one.
    let good = r
        .probe
        .wait_for(&r.observations, T, |_| true)
        .unwrap_or_else(|| panic!("no observation\n{}", r.perception.log()));
    assert_eq!(good.stamp.seq, 1);
    assert_eq!(good.observation.found, 1);
    assert!((good.observation.x_g - line.x_g).abs() < 0.01);
    let log = r.perception.log();
    assert!(
        log.contains("WARN") && log.contains("bad frame refused"),
        "the bad frame is logged:\n{log}"
    );
    assert!(r.perception.is_running());

    // A step is perceived once: its frame again, even broken, gets the same observation.
    r.send(header(1, 0, CableObservationData::default()), &[0; 10]);
    assert_eq!(r.observation(1), good);
    assert!(r.perception.is_running());
}

/// A service stalled and resumed (SIGSTOP, SIGCONT: a debugger, a supervisor's stall check) goes on
/// serving: the signal that wakes its blocked wait is not a request to stop; SIGTERM still is.
#[test]
fn a_stalled_and_resumed_service_goes_on_and_stops_on_sigterm() {
    let ns = Namespace::new("pcsc");
    let mut r = rig(&ns, "ideal");
    let truth = CableObservationData {
        found: 1,
        x_g: 0.1,
        confidence: 1.0,
        ..Default::default()
    };
    r.send(header(1, 0, truth), &[]);
    r.observation(1);
    assert!(r.perception.signal(libc::SIGSTOP) && r.perception.signal(libc::SIGCONT));
    r.send(header(2, 1, truth), &[]);
    r.observation(2);
    let status = r.perception.terminate(T);
    assert!(status.success(), "{status:?}\n{}", r.perception.log());
}
