//! The recorder on a full disk: its record on a tmpfs of 2 MiB of the test's own (in a mount
//! namespace of the test's thread, so nothing outside sees it and it goes with the test), filled by
//! frames that do not compress. The recorder must say once, clearly, that the disk is full, go on
//! running (its status keeps coming while the steps do: a recorder that exited would be restarted
//! again and again and take the mesh down), exit cleanly, and leave a record that the MCAP project's
//! Python reader opens, holding exactly what the recorder reported committed.

use messages::{
    CableObservationData, CableObservationMsg, CameraFrameHeader, Endpoint, Stamp, StepStatus,
    ThrusterSetpoints, topics,
};
use serde_json::Value;
use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use testkit::{Namespace, Process};

const T: Duration = Duration::from_secs(60);

/// Puts the calling thread (and the processes it starts) in a mount namespace of its own with a
/// tmpfs of `kib` KiB on `dir`.
fn own_tmpfs(dir: &Path, kib: u64) {
    let c = |s: &str| CString::new(s).unwrap();
    let (root, target) = (c("/"), c(&dir.display().to_string()));
    let (fs, opts) = (c("tmpfs"), c(&format!("size={kib}k")));
    // SAFETY: system calls with valid NUL-terminated strings. A mount namespace is unshared per
    // thread: only this test's thread and its children see the tmpfs.
    unsafe {
        assert_eq!(
            libc::unshare(libc::CLONE_NEWNS),
            0,
            "cannot make a mount namespace: {} (the test needs root or CAP_SYS_ADMIN)",
            std::io::Error::last_os_error()
        );
        let flags = libc::MS_REC | libc::MS_PRIVATE;
        let none = std::ptr::null();
        assert_eq!(
            libc::mount(none, root.as_ptr(), none, flags, std::ptr::null()),
            0
        );
        assert_eq!(
            libc::mount(
                fs.as_ptr(),
                target.as_ptr(),
                fs.as_ptr(),
                0,
                opts.as_ptr().cast()
            ),
            0,
            "cannot mount a tmpfs: {}",
            std::io::Error::last_os_error()
        );
    }
}

fn python() -> PathBuf {
    testkit::venv_python("MCAP_VENV", "mcap-venv", "scripts/install-mcap-py")
}

/// Publishes a step whose frame is noise (zstd cannot shrink it), its estimate and its setpoints.
fn step(
    frames: &messages::FrameOutbox,
    observations: &messages::Outbox<CableObservationMsg>,
    setpoints: &messages::Outbox<ThrusterSetpoints>,
    k: u64,
    (width, height): (u32, u32),
) {
    let stamp = Stamp::new(k, k * 200_000_000, 0, k as u32, StepStatus::Running);
    let header = CameraFrameHeader {
        stamp,
        width,
        height,
        ..Default::default()
    };
    let mut x = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    frames
        .send_with(header, (width * height) as usize, |img| {
            for p in img.iter_mut() {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                *p = x as u8;
            }
            Ok::<_, std::convert::Infallible>(())
        })
        .unwrap()
        .unwrap();
    let observation = CableObservationData {
        found: 1,
        x_g: 0.03,
        ..Default::default()
    };
    observations
        .send(CableObservationMsg { stamp, observation })
        .unwrap();
    setpoints
        .send(ThrusterSetpoints {
            stamp,
            count: 3,
            ..Default::default()
        })
        .unwrap();
}

#[test]
fn a_full_disk_stops_the_record_once_readable_and_the_recorder_goes_on() {
    let ns = Namespace::new("rful");
    let dir = tempfile::tempdir().unwrap();
    own_tmpfs(dir.path(), 2048);
    let record = dir.path().join("dive.mcap");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let status = probe.inbox(&topics::RECORDER_STATUS);
    let camera = config::load::<config::Scenario>(&testkit::config_dir().join("scenario.toml"))
        .unwrap()
        .camera;
    let size = (camera.width, camera.height);
    let frames = probe.frame_outbox((size.0 * size.1) as usize);
    let observations = probe.outbox(&topics::CABLE_OBSERVATION);
    let setpoints = probe.outbox(&topics::THRUSTER_SETPOINTS);
    let mut recorder = Process::start(
        &ns,
        &testkit::binary("recorder"),
        &[
            "--endpoint",
            "vehicle",
            "--out",
            &record.display().to_string(),
            "--flush-ms",
            "50",
        ],
    );
    let said = |log: &str| log.matches("the disk is full").count();
    // Steps until the recorder says the disk is full, then on for 20 more of its status reports.
    let end = Instant::now() + T;
    let (mut k, mut after) = (0u64, Vec::new());
    let mut last = None;
    while after.len() < 20 {
        assert!(
            Instant::now() < end,
            "no disk-full error in time:\n{}",
            recorder.log()
        );
        for _ in 0..5 {
            k += 1;
            step(&frames, &observations, &setpoints, k, size);
        }
        if let Some(s) = probe.wait_for(&status, Duration::from_millis(500), |_| true) {
            if said(&recorder.log()) > 0 {
                after.push(s);
            } else {
                last = Some(s);
            }
        }
    }
    assert!(
        recorder.is_running(),
        "the recorder exited:\n{}",
        recorder.log()
    );
    let before = last.expect("status reports before the disk was full");
    assert!(before.flushed_messages > 0);
    // Nothing more is committed once the disk is full, and the reports keep coming.
    let kept = after[0].flushed_messages;
    assert!(
        after.iter().all(|s| s.flushed_messages == kept),
        "{after:?}"
    );
    assert!(after.windows(2).all(|w| w[1].seq > w[0].seq));
    assert!(kept >= before.flushed_messages);
    let status = recorder.terminate(Duration::from_secs(10));
    let log = recorder.log();
    assert!(status.success(), "{status:?}:\n{log}");
    assert_eq!(said(&log), 1, "said once:\n{log}");
    assert!(log.contains("No space left on device"), "{log}");
    assert!(
        log.contains(&record.display().to_string()),
        "names the record:\n{log}"
    );

    // The Python reader opens the record and reads exactly what was committed.
    let out = dir.path().join("read.json");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/read_cut_records.py");
    let mut child = runtime::process::Spawn::new(python())
        .arg(&script)
        .arg(&out)
        .arg(&record)
        .log(ns.scratch().join("python.log"))
        .die_with_parent()
        .start()
        .unwrap();
    let done = child
        .wait_timeout(Duration::from_secs(120))
        .expect("the Python reader finishes");
    assert!(done.success(), "{}", child.log());
    let read: Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let r = &read[record.display().to_string()];
    assert_eq!(r["messages"].as_u64(), Some(kept), "{r}");
    assert_eq!(r["summary"], Value::Bool(false), "cut short: no index");
    // The `mcap` crate's streaming reader reads the same, without an error.
    let bytes = std::fs::read(&record).unwrap();
    let mut n = 0u64;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        m.unwrap();
        n += 1;
    }
    assert_eq!(n, kept);
}
