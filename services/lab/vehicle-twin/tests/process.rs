//! The `vehicle-twin` binary as a process: its frames on the twin's camera topic, paced by its clock
//! or in lockstep with whoever answers them, its dive recorded; clean stops.

use adapters::replay::{Pacing, ReplaySource};
use adapters::twin::{TwinFrameSource, TwinThrusterSink};
use adapters::{Frame, FrameSource, Read, Stamp, StepStatus, ThrusterSink};
use config::{Scenario, TwinParams};
use messages::Endpoint;
use runtime::lockstep::{Limits, Lockstep, Reaction};
use std::path::Path;
use std::time::{Duration, Instant};
use testkit::{Namespace, Probe, Process};
use vehicle_twin::Twin;

const T: Duration = Duration::from_secs(20);

fn scenario() -> Scenario {
    config::load(&testkit::config_dir().join("scenario.toml")).unwrap()
}

fn twin_params() -> TwinParams {
    config::load(&testkit::config_dir().join("twin.toml")).unwrap()
}

/// A twin config with short trials, written for the process.
fn short_trials(dir: &Path, duration_s: f64) -> std::path::PathBuf {
    let text = std::fs::read_to_string(testkit::config_dir().join("twin.toml")).unwrap();
    let text = text.replace("duration_s = 90.0", &format!("duration_s = {duration_s}"));
    let path = dir.join("twin.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// Blocks until the twin's next frame (or `None` after the timeout).
fn next_frame(probe: &Probe, source: &TwinFrameSource, out: &mut Frame) -> Option<Read> {
    let end = Instant::now() + T;
    loop {
        match source.read(Instant::now(), out).expect("a good frame") {
            Read::Pending { .. } => {}
            r => return Some(r),
        }
        let adapters::Wake::Listener(l) = source.wake() else {
            unreachable!()
        };
        probe.block_on(l, end.checked_duration_since(Instant::now())?);
    }
}

/// Real time, accelerated: one frame per period of wall time, counted and timed by the twin, the
/// trial's last frame a time limit; the dive it records replays as it was published.
#[test]
fn the_clock_paces_the_frames_and_the_dive_is_recorded() {
    let ns = Namespace::new("vtrt");
    let tmp = tempfile::tempdir().unwrap();
    let config = short_trials(tmp.path(), 1.0);
    let dive = tmp.path().join("dive");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let source = TwinFrameSource::open(probe.node(), 320, 240).unwrap();
    let speed = 10.0;
    let mut twin = Process::start(
        &ns,
        &testkit::binary("vehicle-twin"),
        &[
            "--endpoint",
            "vehicle",
            "--seed",
            "3",
            "--speed",
            &speed.to_string(),
            "--trials",
            "2",
            "--twin-config",
            config.to_str().unwrap(),
            "--record",
            dive.to_str().unwrap(),
        ],
    );
    let mut frames: Vec<(Instant, Frame)> = Vec::new();
    let mut out = Frame::default();
    while let Some(r) = next_frame(&probe, &source, &mut out) {
        assert_eq!(r, Read::Frame);
        frames.push((Instant::now(), out.clone()));
        if out.meta.trial == 1 && out.meta.status.is_terminal() {
            break;
        }
    }
    let status = twin.wait(T).expect("the twin stops after its trials");
    assert!(status.success(), "{}", twin.log());
    assert!(twin.log().contains("trial ended"), "{}", twin.log());

    // The twin's frames: its own count and clock, two trials of 5 steps; dropped frames are gaps.
    let metas: Vec<_> = frames.iter().map(|(_, f)| f.meta).collect();
    assert!(metas.len() >= 8, "{} frames", metas.len());
    for w in metas.windows(2) {
        assert!(w[1].seq > w[0].seq);
        let periods = w[1].seq - w[0].seq;
        assert_eq!(w[1].time_ns - w[0].time_ns, periods * 200_000_000);
    }
    let ends: Vec<_> = metas.iter().filter(|m| m.status.is_terminal()).collect();
    assert_eq!(ends.len(), 2);
    assert!(
        ends.iter()
            .all(|m| m.step == 5 && m.status == StepStatus::TimeLimit)
    );
    // Nobody answered: the first trial's frames are those of a twin whose thrusters stay idle.
    let mut reference = Twin::new(
        &scenario(),
        &{
            let mut t = twin_params();
            t.trials.duration_s = 1.0;
            t
        },
        3,
        false,
    )
    .unwrap();
    let mut shot = reference.start();
    for m in metas.iter().take_while(|m| m.trial == 0) {
        while shot.seq < m.seq {
            shot = reference.advance(None).0;
        }
        assert_eq!((shot.step, shot.status), (m.step, m.status));
        assert_eq!(Some(shot.truth), m.truth, "frame {}", m.seq);
    }
    // Paced by the clock: 0.2 s / 10 per period (loosely: a loaded machine runs late, never early).
    let (t0, f0) = (&frames[0].0, &frames[0].1.meta);
    let (t1, f1) = (&frames.last().unwrap().0, &frames.last().unwrap().1.meta);
    let periods = (f1.seq - f0.seq) as f64;
    let wall = t1.duration_since(*t0).as_secs_f64();
    assert!(
        wall >= 0.8 * periods * 0.2 / speed,
        "{periods} periods in {wall} s"
    );

    // The recorded dive is what was published.
    let replay = ReplaySource::open(&dive, Pacing::Unpaced).unwrap();
    assert_eq!(replay.index().entries.len(), frames.len());
    let mut r = Frame::default();
    for (_, f) in &frames {
        assert_eq!(replay.read(Instant::now(), &mut r).unwrap(), Read::Frame);
        assert_eq!(r.meta, f.meta);
        assert!(r.image == f.image, "frame {}", f.meta.seq);
    }
    assert_eq!(replay.read(Instant::now(), &mut r).unwrap(), Read::End);
}

/// Lockstep: the twin waits for the setpoints answering its frame (matched by the frame's time),
/// integrates them exactly as the core does, and re-sends a frame nobody answered.
#[test]
fn lockstep_waits_for_the_answer_and_integrates_it() {
    let ns = Namespace::new("vtls");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let source = TwinFrameSource::open(probe.node(), 320, 240).unwrap();
    let mut sink = TwinThrusterSink::open(probe.node(), 3).unwrap();
    let mut twin = Process::start(
        &ns,
        &testkit::binary("vehicle-twin"),
        &[
            "--endpoint",
            "vehicle",
            "--seed",
            "4",
            "--lockstep",
            "--resend-ms",
            "50",
        ],
    );
    let limits = Limits::new(Duration::from_millis(50), Duration::from_secs(2));
    let core = Twin::new(&scenario(), &twin_params(), 4, false).unwrap();
    let (mut reference, first) = Lockstep::start(core, limits, 0, Instant::now());
    let Reaction::Publish { next: mut want, .. } = first else {
        panic!()
    };
    let mut out = Frame::default();
    assert_eq!(next_frame(&probe, &source, &mut out), Some(Read::Frame));
    assert_eq!(out.meta.seq, want.seq);
    // Unanswered, the frame comes again.
    assert_eq!(next_frame(&probe, &source, &mut out), Some(Read::Repeat));
    assert_eq!(out.meta.seq, want.seq);
    for k in 0..20 {
        let sp = [0.6, 0.2 + 0.01 * k as f64, -0.3];
        // Setpoints for another frame's time are ignored.
        sink.write(
            &Stamp::new(9, want.time_ns() + 1, 0, 0, StepStatus::Running),
            &sp,
        )
        .unwrap();
        sink.write(
            &Stamp::new(9, want.time_ns(), want.trial, want.step, want.status),
            &sp,
        )
        .unwrap();
        let Reaction::Publish { next: shot, .. } =
            reference.on_answer(want.time_ns(), &sp, Instant::now())
        else {
            panic!()
        };
        want = shot;
        loop {
            assert!(
                next_frame(&probe, &source, &mut out).is_some(),
                "{}",
                twin.log()
            );
            if out.meta.seq == want.seq {
                break;
            }
        }
        assert_eq!(out.meta, want.meta(320, 240), "step {k}");
    }
    let status = twin.terminate(T);
    assert!(status.success(), "{}", twin.log());
    assert!(twin.log().contains("stopped"));
}

#[test]
fn a_bad_twin_config_is_refused_by_name() {
    let ns = Namespace::new("vtbc");
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("twin.toml");
    std::fs::write(&path, "[thrusters.dead_band]\nsetpoint = 2.0\n").unwrap();
    let mut twin = Process::start(
        &ns,
        &testkit::binary("vehicle-twin"),
        &["--twin-config", path.to_str().unwrap()],
    );
    let status = twin.wait(T).expect("it exits");
    assert!(!status.success());
    assert!(
        twin.log().contains("thrusters.dead_band.setpoint"),
        "{}",
        twin.log()
    );
}

/// Built without the video path, the twin refuses `--video` and says how to build it; a malformed
/// destination is refused by name either way.
#[test]
fn video_options_are_checked() {
    let ns = Namespace::new("vtvo");
    for (args, want) in [
        (
            &["--video", "udp:127.0.0.1:5600"][..],
            "expected rtp:HOST:PORT",
        ),
        (&["--video", "rtp:127.0.0.1"][..], "not a HOST:PORT"),
        (
            &["--video", "rtp:127.0.0.1:5600", "--video-size", "big"][..],
            "--video-size big",
        ),
    ] {
        let mut twin = Process::start(&ns, &testkit::binary("vehicle-twin"), args);
        let status = twin.wait(T).expect("it exits");
        assert!(!status.success());
        assert!(twin.log().contains(want), "{args:?}:\n{}", twin.log());
    }
    #[cfg(not(feature = "video"))]
    {
        let mut twin = Process::start(
            &ns,
            &testkit::binary("vehicle-twin"),
            &["--video", "rtp:127.0.0.1:5600"],
        );
        let status = twin.wait(T).expect("it exits");
        assert!(!status.success());
        assert!(twin.log().contains("--features video"), "{}", twin.log());
    }
}
