//! The camera as a process: vehicle states over iceoryx2 in, camera frames out.

use config::{Scenario, derive_seed};
use messages::{
    CableObservationData, CameraFrameHeader, Endpoint, FrameInbox, Stamp, StepStatus,
    VehicleStateMsg, topics,
};
use model::{Cable, Pose, VehicleState, Velocity};
use std::time::{Duration, Instant};
use testkit::{Namespace, Probe, Process};

const T: Duration = Duration::from_secs(10);
const SEED: u64 = 11;

fn scenario() -> Scenario {
    config::load(&testkit::config_dir().join("scenario.toml")).expect("the repository's scenario")
}

/// A vehicle moving over the cable (so the image is blurred and the truth has rates).
fn state(seq: u64) -> VehicleStateMsg {
    let s = VehicleState {
        pose: Pose {
            x: 1.5,
            y: -0.12,
            psi: 0.35,
        },
        velocity: Velocity {
            u: 0.28,
            v: 0.06,
            r: -0.12,
        },
    };
    VehicleStateMsg::new(
        Stamp::new(seq, seq * 200_000_000, 0, seq as u32, StepStatus::Running),
        &s,
        &s.pose_rate(),
    )
}

/// The geometric camera's truth for a state.
fn truth(scenario: &Scenario, st: &VehicleStateMsg) -> CableObservationData {
    let obs = model::Camera::new(&scenario.camera).observe(
        &st.pose(),
        &st.pose_rate(),
        &Cable::new(&scenario.cable),
        &scenario.observation,
    );
    assert!(obs.found, "the test's pose sees the cable");
    CableObservationData::from(&obs)
}

/// Blocks until a frame accepted by `want` arrives (header and a copy of the image).
fn wait_frame(
    probe: &Probe,
    frames: &FrameInbox,
    timeout: Duration,
    mut want: impl FnMut(&CameraFrameHeader) -> bool,
) -> Option<(CameraFrameHeader, Vec<u8>)> {
    let end = Instant::now() + timeout;
    loop {
        while let Some((h, image)) = frames.receive_with(|h, d| (*h, d.to_vec())).unwrap() {
            if want(&h) {
                return Some((h, image));
            }
        }
        let left = end.checked_duration_since(Instant::now())?;
        probe.block_on(frames.listener(), left);
    }
}

/// A camera process and the test's ports, connected.
struct Rig {
    probe: Probe,
    states: messages::Outbox<VehicleStateMsg>,
    frames: FrameInbox,
    camera: Process,
}

fn rig(ns: &Namespace, eyes: &str) -> Rig {
    let probe = testkit::probe(ns, Endpoint::Sim);
    let frames = probe.frame_inbox();
    let states = probe.outbox(&topics::VEHICLE_STATE);
    let seed = SEED.to_string();
    let camera = Process::start(
        ns,
        &testkit::binary("camera"),
        &["--endpoint", "sim", "--seed", &seed, "--eyes", eyes],
    );
    // The camera opens its frame publisher before its state subscriber.
    assert!(
        probe.wait_for_subscribers(&states, 1, T),
        "the camera never came up\n{}",
        camera.log()
    );
    Rig {
        probe,
        states,
        frames,
        camera,
    }
}

#[test]
fn ideal_frames_carry_the_geometric_truth_and_no_image() {
    let ns = Namespace::new("cami");
    let r = rig(&ns, "ideal");
    let st = state(3);
    r.states.send(st).unwrap();
    let (h, image) = wait_frame(&r.probe, &r.frames, T, |_| true)
        .unwrap_or_else(|| panic!("a frame\n{}", r.camera.log()));
    assert_eq!(h.stamp, st.stamp, "the stamp is copied unchanged");
    assert_eq!((h.width, h.height), (320, 240));
    assert_eq!(h.truth, truth(&scenario(), &st));
    assert!(image.is_empty());
}

#[test]
fn images_are_the_renderers_frames_with_the_truth() {
    let ns = Namespace::new("camr");
    let r = rig(&ns, "images");
    let scenario = scenario();
    let mut renderer =
        vision::Renderer::from_scenario(&scenario, derive_seed(SEED, "render")).unwrap();
    for seq in [5, 6] {
        let st = state(seq);
        r.states.send(st).unwrap();
        let (h, image) = wait_frame(&r.probe, &r.frames, T, |h| h.stamp.seq == seq)
            .unwrap_or_else(|| panic!("frame {seq}\n{}", r.camera.log()));
        assert_eq!(h.stamp, st.stamp);
        assert_eq!(h.truth, truth(&scenario, &st));
        // The frames of a run count from 0 at seq 1, as the trainer's do.
        let want = renderer.render_frame(&st.pose(), &st.pose_rate(), seq - 1);
        assert_eq!(image.len(), 320 * 240);
        for row in [0, 77, 120, 239] {
            let span = row * 320..(row + 1) * 320;
            assert_eq!(image[span.clone()], want.data()[span], "row {row}");
        }
        assert!(image == want.data(), "the whole frame");
    }
}

#[test]
fn a_repeated_state_gets_the_same_frame_and_an_older_one_none() {
    let ns = Namespace::new("camo");
    let r = rig(&ns, "images");
    r.states.send(state(8)).unwrap();
    let first = wait_frame(&r.probe, &r.frames, T, |_| true).expect("frame 8");
    assert_eq!(first.0.stamp.seq, 8);
    r.states.send(state(8)).unwrap();
    let again = wait_frame(&r.probe, &r.frames, T, |_| true).expect("frame 8 again");
    assert_eq!(again, first);
    r.states.send(state(7)).unwrap();
    r.states.send(state(9)).unwrap();
    let next = wait_frame(&r.probe, &r.frames, T, |_| true).expect("frame 9");
    assert_eq!(next.0.stamp.seq, 9, "nothing for the older state 7");
}

/// On the vehicle endpoint the camera publishes its frame source's frames: here a recorded dive,
/// paced by its timestamps, each frame with the dive's time, trial, step and status, the camera's
/// own increasing seq (the dive's gaps kept) in an epoch of its own, taken on the vehicle clock,
/// and its image; at the dive's end the camera stops.
#[test]
fn on_the_vehicle_endpoint_a_recorded_dive_is_published_with_its_stamps() {
    use adapters::replay::{DiveWriter, ImageFormat};
    let ns = Namespace::new("camd");
    let tmp = tempfile::tempdir().unwrap();
    let dive = tmp.path().join("dive");
    let frames: Vec<adapters::Frame> = adapters::conformance::sample_frames(320, 240);
    let mut w = DiveWriter::create(&dive, 320, 240, true, ImageFormat::Png).unwrap();
    for f in &frames {
        w.write(&f.meta, &f.image).unwrap();
    }
    w.finish().unwrap();

    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let inbox = probe.frame_inbox();
    let source = format!("replay:{}", dive.display());
    let mut camera = Process::start(
        &ns,
        &testkit::binary("camera"),
        &["--endpoint", "vehicle", "--source", &source, "--speed", "4"],
    );
    let mut got = Vec::new();
    for f in &frames {
        let (h, image) = wait_frame(&probe, &inbox, T, |_| true)
            .unwrap_or_else(|| panic!("frame {}\n{}", f.meta.seq, camera.log()));
        let m = &f.meta;
        assert_eq!(
            (
                h.stamp.time_ns,
                h.stamp.episode,
                h.stamp.step,
                h.stamp.status()
            ),
            (m.time_ns, m.trial, m.step, m.status),
            "frame {}",
            m.seq
        );
        assert_eq!((h.width, h.height), (320, 240));
        assert_eq!(Some(h.truth), m.truth);
        assert!(image == f.image, "frame {}'s image", m.seq);
        got.push(h.stamp);
    }
    // One epoch of the camera's own, every frame taken on the vehicle clock, in order.
    assert_ne!(got[0].epoch, 0);
    assert!(got.iter().all(|s| s.epoch == got[0].epoch && s.is_timed()));
    assert!(got.windows(2).all(|w| w[1].clock_ns >= w[0].clock_ns));
    let got: Vec<u64> = got.iter().map(|s| s.seq).collect();
    for (k, w) in got.windows(2).enumerate() {
        assert_eq!(
            w[1] - w[0],
            frames[k + 1].meta.seq - frames[k].meta.seq,
            "gaps kept"
        );
    }
    assert_eq!(
        got[0], frames[0].meta.seq,
        "the source's count, no wall-clock base"
    );
    let status = camera.wait(T).expect("the camera stops at the dive's end");
    assert!(status.success(), "{}", camera.log());
    assert!(
        camera.log().contains("the source ended"),
        "{}",
        camera.log()
    );
}

#[test]
fn a_missing_dive_and_a_source_on_the_sim_endpoint_are_refused() {
    let ns = Namespace::new("camv");
    let mut camera = Process::start(
        &ns,
        &testkit::binary("camera"),
        &[
            "--endpoint",
            "vehicle",
            "--source",
            "replay:/nonexistent/dive",
        ],
    );
    let status = camera.wait(T).expect("it exits");
    assert!(!status.success());
    assert!(
        camera.log().contains("/nonexistent/dive/index.csv"),
        "a clear error:\n{}",
        camera.log()
    );
    let mut camera = Process::start(
        &ns,
        &testkit::binary("camera"),
        &["--endpoint", "sim", "--source", "twin"],
    );
    let status = camera.wait(T).expect("it exits");
    assert!(!status.success());
    assert!(
        camera.log().contains("`vehicle` endpoint"),
        "{}",
        camera.log()
    );
}

/// Built without the video path, the camera refuses an RTP source and says how to build it.
#[cfg(not(feature = "video"))]
#[test]
fn an_rtp_source_needs_the_video_feature() {
    let ns = Namespace::new("camr");
    let mut camera = Process::start(
        &ns,
        &testkit::binary("camera"),
        &["--endpoint", "vehicle", "--source", "rtp:127.0.0.1:5600"],
    );
    let status = camera.wait(T).expect("it exits");
    assert!(!status.success());
    let log = camera.log();
    assert!(
        log.contains("rtp:127.0.0.1:5600") && log.contains("--features video"),
        "a clear error:\n{log}"
    );
}

/// GStreamer's `videotestsrc ! x264enc ! rtph264pay ! udpsink`, as BlueOS sends, for `frames`
/// frames at 30 frames/s of `w x h`, under `ssrc`: the child reaped when it is done.
#[cfg(feature = "video")]
fn gst_sender(port: u16, ssrc: u32, (w, h): (u32, u32), frames: u32) -> std::process::Child {
    std::process::Command::new("gst-launch-1.0")
        .args(["-q", "videotestsrc", "is-live=true", "pattern=ball"])
        .arg(format!("num-buffers={frames}"))
        .args([
            "!",
            &format!("video/x-raw,width={w},height={h},framerate=30/1"),
        ])
        .args(["!", "x264enc", "tune=zerolatency", "speed-preset=ultrafast"])
        .args(["key-int-max=15", "bitrate=1500"])
        .args(["!", "rtph264pay", "pt=96", "config-interval=-1"])
        .arg(format!("ssrc={ssrc}"))
        .args(["aggregate-mode=zero-latency"])
        .args(["!", "udpsink", "host=127.0.0.1", &format!("port={port}")])
        .stdin(std::process::Stdio::null())
        .spawn()
        .expect("gst-launch-1.0 (scripts/install-gstreamer)")
}

/// The camera on a bad stream, GStreamer's own elements sending: a stream with a burst of garbage
/// amid it, its stop, a restart under a new SSRC at another size. The camera keeps running, says what happened
/// once per event (not once per packet), and publishes the restarted stream's frames.
#[cfg(feature = "video")]
#[test]
fn on_a_bad_rtp_stream_the_camera_says_so_once_per_event_and_picks_it_up_again() {
    let ns = Namespace::new("camb");
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .expect("a free port")
        .port();
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let inbox = probe.frame_inbox();
    let source = format!("rtp:127.0.0.1:{port}");
    let mut camera = Process::start(
        &ns,
        &testkit::binary("camera"),
        &["--endpoint", "vehicle", "--source", &source],
    );
    // The camera publishes once its socket listens. A publisher's arrival is not an event: look
    // again every few milliseconds, up to the deadline.
    let end = Instant::now() + T;
    while inbox.publishers() == 0 {
        assert!(
            Instant::now() < end,
            "the camera never came up\n{}",
            camera.log()
        );
        let _ = probe.node().wait(Duration::from_millis(5));
    }
    for (round, (ssrc, size)) in [(0x1111_u32, (640, 480)), (0x2222, (1280, 720))]
        .into_iter()
        .enumerate()
    {
        let mut sender = gst_sender(port, ssrc, size, 45);
        let (h, image) = wait_frame(&probe, &inbox, T, |h| !h.is_damaged())
            .unwrap_or_else(|| panic!("round {round}: no whole frame\n{}", camera.log()));
        assert_eq!((h.width, h.height, image.len()), (320, 240, 320 * 240));
        if round == 0 {
            // Garbage amid the stream: not RTP, truncated, another payload type.
            let junk = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
            for k in 0..300 {
                let bad: &[u8] = match k % 3 {
                    0 => b"not rtp at all",
                    1 => &[0x80, 96, 0],
                    _ => &[0x80, 33, 0, 1, 0, 0, 0, 0, 0, 0, 0, 9, 0x65],
                };
                junk.send_to(bad, ("127.0.0.1", port)).unwrap();
            }
        }
        let done = sender.wait().expect("gst-launch-1.0 ends");
        assert!(done.success(), "round {round}: the sender failed");
        // The stream stopped: the camera notes it once after its quiet time (2 s).
        let end = Instant::now() + T;
        while camera.log().matches("the stream stopped").count() <= round {
            assert!(
                Instant::now() < end,
                "round {round}: the stop never noted\n{}",
                camera.log()
            );
            // The camera's log is its stderr, read as it grows: a wait on a frame that never
            // comes is the deadline's pace here.
            let _ = wait_frame(&probe, &inbox, Duration::from_millis(200), |_| false);
        }
        assert!(camera.is_running(), "round {round}\n{}", camera.log());
    }
    let log = camera.log();
    let count = |s: &str| log.matches(s).count();
    assert_eq!(count("the stream stopped"), 2, "{log}");
    assert_eq!(count("a new stream session"), 2, "{log}");
    assert_eq!(count("the stream's picture size changed"), 1, "{log}");
    // 300 refused packets within a fraction of a second: reported once, not per packet.
    let refused = log.lines().filter(|l| l.contains("refused")).count();
    assert!(
        (1..=2).contains(&refused),
        "{refused} lines about refused packets\n{log}"
    );
    assert!(!log.contains("panicked"), "{log}");
    assert!(camera.terminate(T).success(), "{}", camera.log());
    // Once stopped it says what the stream gave (what scripts/bench-camera-video divides the
    // camera's CPU by): both rounds' 45 access units each, pictures decoded from them, and the
    // frames handed over, each published once.
    let log = camera.log();
    let line = log
        .lines()
        .find(|l| l.contains("the stream's counts"))
        .unwrap_or_else(|| panic!("no counts once stopped\n{log}"));
    let field = |key: &str| -> u64 {
        line.split_whitespace()
            .find_map(|w| w.strip_prefix(&format!("{key}=")))
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no {key} in `{line}`"))
    };
    assert_eq!(field("access_units"), 90, "{line}");
    let (decoded, handed_over) = (field("decoded"), field("handed_over"));
    assert!(decoded > 0 && decoded <= 90, "{line}");
    assert!(handed_over > 0 && handed_over <= decoded, "{line}");
    assert_eq!(field("published"), handed_over, "{line}");
}
