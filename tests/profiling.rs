//! The profiling tools' reader on a trace with known answers: `scripts/vehicle-frames.py` takes a
//! `perf sched timehist` of a vehicle run apart frame by frame (scripts/profile-vehicle). No test
//! records a real profile (it needs `perf`, a quiet machine and minutes), so this one writes a
//! timehist in perf's format whose every figure is known and checks what the reader makes of it:
//! the frames it finds, the path's p50 and p99, each service's CPU and scheduling delay in the
//! fastest half and the slowest 5%, the other threads during the path and the kernel monitor's
//! bursts. The reader runs under python3 with a timeout.

use runtime::process::Spawn;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Duration;

/// Long enough for python3 to read a few hundred lines on a loaded 2-core machine.
const TIMEOUT: Duration = Duration::from_secs(60);

/// One stretch a thread ran, times in microseconds from the trace's start.
struct Stretch {
    start_us: u64,
    run_us: u64,
    cpu: u32,
    thread: &'static str,
    tid: u32,
    delay_us: u64,
}

/// `perf sched timehist`'s line for a stretch: switched-out time (s, 6 decimals), CPU, task[tid],
/// wait time, scheduling delay and run time (ms, 3 decimals).
fn line(s: &Stretch) -> String {
    let end = s.start_us + s.run_us;
    format!(
        "{:>15}.{:06} [{:04}]  {}[{}]  {:>9.3}  {:>9.3}  {:>9.3}",
        end / 1_000_000,
        end % 1_000_000,
        s.cpu,
        s.thread,
        s.tid,
        150.0,
        s.delay_us as f64 / 1e3,
        s.run_us as f64 / 1e3,
    )
}

/// A frame's path: (thread, start after the camera's wake-up, run, CPU, scheduling delay), in
/// microseconds; the path ends when the twin's run ends, at 1,000 us.
const PATH: [(&str, u64, u64, u32, u64); 8] = [
    ("camera", 0, 100, 0, 10),
    ("perception", 120, 400, 1, 10),
    ("sway-behaviour", 540, 80, 0, 20),
    ("yaw-behaviour", 540, 80, 1, 20),
    ("surge-controlle", 620, 80, 0, 60),
    ("thruster-alloca", 700, 100, 1, 50),
    ("thruster-driver", 810, 70, 0, 15),
    ("vehicle-twin", 900, 100, 1, 10),
];
/// The frames whose path runs 1.5 times slower (3 of 50: the slowest 5%).
const SLOW: [u64; 3] = [7, 23, 41];
/// The frames during whose path the kernel's memory monitor ran.
const KDAMOND: [u64; 2] = [10, 30];

/// A trace of `frames` frames 200 ms apart, after one more during the twin's start-up (which the
/// reader leaves out: the first 10 s after the twin's first run).
fn trace(frames: u64) -> String {
    let mut stretches = vec![Stretch {
        start_us: 1_000_000,
        run_us: 500,
        cpu: 0,
        thread: "vehicle-twin",
        tid: 900,
        delay_us: 0,
    }];
    for k in 0..=frames {
        let t0 = if k == frames {
            5_000_000
        } else {
            12_000_000 + 200_000 * k
        };
        // Even times scaled by 3/2 stay whole microseconds.
        let f = |us: u64| if SLOW.contains(&k) { us * 3 / 2 } else { us };
        // The twin publishing the frame that wakes the camera: before the path, not its answer.
        stretches.push(Stretch {
            start_us: t0 - 300,
            run_us: 250,
            cpu: 1,
            thread: "vehicle-twin",
            tid: 900,
            delay_us: 10,
        });
        for (i, &(thread, start, run, cpu, delay)) in PATH.iter().enumerate() {
            stretches.push(Stretch {
                start_us: t0 + f(start),
                run_us: f(run),
                cpu,
                thread,
                tid: 1000 + i as u32,
                delay_us: delay,
            });
        }
        // The recorder woken by the setpoints on every frame, an idle CPU, and sometimes kdamond.
        stretches.push(Stretch {
            start_us: t0 + f(760),
            run_us: 40,
            cpu: 0,
            thread: "recorder",
            tid: 950,
            delay_us: 30,
        });
        stretches.push(Stretch {
            start_us: t0 + f(200),
            run_us: 300,
            cpu: 0,
            thread: "<idle>",
            tid: 0,
            delay_us: 0,
        });
        if KDAMOND.contains(&k) {
            stretches.push(Stretch {
                start_us: t0 + 300,
                run_us: 200,
                cpu: 0,
                thread: "kdamond.0",
                tid: 77,
                delay_us: 0,
            });
        }
    }
    stretches.sort_by_key(|s| s.start_us + s.run_us);
    let mut text = String::from(
        "           time    cpu  task name                       wait time  sch delay   run time\n\
         \x20                       [tid/pid]                          (msec)     (msec)     (msec)\n\
         --------------- ------  ------------------------------  ---------  ---------  ---------\n",
    );
    for s in &stretches {
        writeln!(text, "{}", line(s)).unwrap();
    }
    text
}

/// Runs the reader on `timehist`; its exit status, standard output and standard error.
fn read(dir: &Path, timehist: &str) -> (std::process::ExitStatus, String, String) {
    let input = dir.join("timehist.txt");
    std::fs::write(&input, timehist).unwrap();
    let out = dir.join("frames.md");
    let mut child = Spawn::new("python3")
        .arg(testkit::repo_root().join("scripts/vehicle-frames.py"))
        .arg(&input)
        .log(dir.join("stderr.log"))
        .stdout(std::fs::File::create(&out).unwrap())
        .die_with_parent()
        .start()
        .expect("python3 runs (the machine's CPython)");
    let status = child
        .wait_timeout(TIMEOUT)
        .unwrap_or_else(|| panic!("vehicle-frames.py did not finish within {TIMEOUT:?}"));
    (status, std::fs::read_to_string(out).unwrap(), child.log())
}

#[test]
fn vehicle_frames_takes_each_frames_path_apart() {
    let dir = tempfile::tempdir().unwrap();
    let (status, out, err) = read(dir.path(), &trace(50));
    assert!(status.success(), "{status:?}\n{err}\n{out}");
    let has = |want: &str| assert!(out.contains(want), "no `{want}` in:\n{out}");
    // 47 paths of 1.000 ms and 3 of 1.500 ms.
    has("50 frames, path p50 1.000 ms, p99 1.500 ms");
    // Each service's CPU in the fastest half against the slowest 5%, and its scheduling delay.
    has("| camera | 0.100 / 0.150 | 0.010 / 0.010 |");
    has("| perception | 0.400 / 0.600 | 0.010 / 0.010 |");
    has("| sway-behaviour | 0.080 / 0.120 | 0.020 / 0.020 |");
    has("| surge-controlle | 0.080 / 0.120 | 0.060 / 0.060 |");
    has("| thruster-alloca | 0.100 / 0.150 | 0.050 / 0.050 |");
    has("| thruster-driver | 0.070 / 0.105 | 0.015 / 0.015 |");
    // The recorder ran once in every path; an idle CPU is not a thread.
    has("other threads during the path, per frame, slowest 5%: recorder 1.00\n");
    assert!(!out.contains("<idle>"), "{out}");
    // kdamond in two of the fast paths.
    has("kdamond ran during 2 of 50 paths (their p50 1.000 ms); \
         the other paths: p50 1.000 ms, p99 1.500 ms");
}

#[test]
fn vehicle_frames_refuses_too_short_a_trace() {
    let dir = tempfile::tempdir().unwrap();
    let (status, out, err) = read(dir.path(), &trace(12));
    assert!(!status.success(), "{out}");
    assert!(err.contains("only 12 frames found"), "{err}");
}
