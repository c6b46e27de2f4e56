//! The twin's camera over the wire a BlueROV2 uses: `vehicle-twin --video rtp:...` sends
//! RTP/H.264, `camera --source rtp:...` decodes it and publishes on the vehicle's camera topic,
//! and the lockstep runs through both (the camera copies the twin's time from the frames'
//! metadata; the test answers as the mesh would). Needs both binaries built with
//! `--features video` (CI builds them before this test).
#![cfg(feature = "video")]

use adapters::twin::TwinThrusterSink;
use adapters::{Stamp, ThrusterSink};
use config::{Scenario, TwinParams};
use messages::{CameraFrameHeader, Endpoint, FrameInbox};
use runtime::lockstep::{Limits, Lockstep, Reaction};
use std::time::{Duration, Instant};
use testkit::{Namespace, Probe, Process};
use vehicle_twin::Twin;

const T: Duration = Duration::from_secs(30);

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

/// A free UDP port on loopback (taken from the kernel, released for the camera to bind).
fn free_port() -> u16 {
    testkit::free_udp_port()
}

/// Twenty lockstep steps through RTP/H.264 at 1280x720: every step's frame reaches the camera
/// topic with the twin's time, trial, step, status and true line, its image the twin's rendering
/// (lossy: close, not equal), and the twin integrates the answers as the reference does.
#[test]
fn the_twin_streams_rtp_and_the_camera_runs_the_lockstep() {
    let ns = Namespace::new("vtvid");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let frames = probe.frame_inbox();
    let mut sink = TwinThrusterSink::open(probe.node(), 3).unwrap();
    let port = free_port();
    let rtp = format!("rtp:127.0.0.1:{port}");
    let camera = Process::start(
        &ns,
        &testkit::binary("camera"),
        &["--endpoint", "vehicle", "--source", &rtp],
    );
    let mut twin = Process::start(
        &ns,
        &testkit::binary("vehicle-twin"),
        &[
            "--endpoint",
            "vehicle",
            "--seed",
            "4",
            "--lockstep",
            "--video",
            &rtp,
            "--video-size",
            "1280x720",
            "--video-kbps",
            "6000",
        ],
    );
    let scenario: Scenario = config::load(&testkit::config_dir().join("scenario.toml")).unwrap();
    let params: TwinParams = config::load(&testkit::config_dir().join("twin.toml")).unwrap();
    let limits = Limits::new(Duration::from_millis(100), Duration::from_secs(2));
    let core = Twin::new(&scenario, &params, 4, true).unwrap();
    let (mut reference, first) = Lockstep::start(core, limits, 0, Instant::now());
    let Reaction::Publish { next: mut want, .. } = first else {
        panic!()
    };
    let mut rendered = vec![0u8; 320 * 240];
    let mut damaged = 0;
    for k in 0..20 {
        let (h, image) = wait_frame(&probe, &frames, T, |h| h.stamp.time_ns == want.time_ns())
            .unwrap_or_else(|| panic!("step {k}\n{}\n{}", camera.log(), twin.log()));
        let m = want.meta(320, 240);
        assert_eq!(
            (h.stamp.episode, h.stamp.step, h.stamp.status(), h.truth),
            (m.trial, m.step, m.status, m.truth.unwrap()),
            "step {k}"
        );
        assert_eq!((h.width, h.height, image.len()), (320, 240, 320 * 240));
        damaged += h.is_damaged() as u32;
        reference.plant_mut().render(&mut rendered).unwrap();
        let mae = image
            .iter()
            .zip(&rendered)
            .map(|(a, b)| a.abs_diff(*b) as u64)
            .sum::<u64>() as f64
            / image.len() as f64;
        // Up to 1280x720, compressed, and back: the twin's noise is not kept, the scene is.
        assert!(mae < 12.0, "step {k}: mean error {mae} grey levels");
        let sp = [0.6, 0.2 + 0.01 * k as f64, -0.3];
        sink.write(
            &Stamp::new(9, want.time_ns(), want.trial, want.step, want.status),
            &sp,
        )
        .unwrap();
        let Reaction::Publish { next, .. } =
            reference.on_answer(want.time_ns(), &sp, Instant::now())
        else {
            panic!()
        };
        want = next;
    }
    assert_eq!(damaged, 0, "nothing is lost on loopback");
    let status = twin.terminate(T);
    assert!(status.success(), "{}", twin.log());
    let mut camera = camera;
    let status = camera.terminate(T);
    assert!(status.success(), "{}", camera.log());
    assert!(
        camera.log().contains("listening for RTP/H.264"),
        "{}",
        camera.log()
    );
}
