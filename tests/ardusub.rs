//! The real `thruster-driver --sink ardusub:...` process against an ArduSub played by pymavlink
//! (`tests/ardusub_peer.py`, MAVLink's own Python implementation, installed by
//! `scripts/install-pymavlink`): the test publishes thruster setpoints on the vehicle mesh's topic,
//! as the allocator does, and reads what reached the autopilot, with the autopilot's arrival times
//! (CLOCK_MONOTONIC, the vehicle clock's), and what the driver published of the autopilot.
//!
//! - A companion: heartbeats at 1 Hz with its configured ids; reads the parameters, sets MANUAL and
//!   arms; MANUAL_CONTROL at the configured rate whose axes and signs match each DOF's command
//!   (surge, sway, yaw; both signs) divided by the pilot gain, each step's followed by its
//!   lockstep tag; neutral within the deadline once the commands stop; on SIGTERM neutral, then a
//!   disarm the autopilot acknowledges. The autopilot's telemetry reaches the mesh.
//! - A refusal to arm, naming the parameter and the value to set, when ArduSub would ignore the
//!   driver's MANUAL_CONTROL (ArduSub 4.7's ground-station range, or SYSID_MYGCS before it) or has
//!   its pilot-input failsafe off.
//! - A restarted driver does not arm the vehicle again.
//! - Garbage and frames with broken checksums sent to the driver's port are counted, refused, and
//!   the driver goes on.
//!
//! Every wait has a timeout and says what it waited for.

use messages::{
    AutopilotAttitude, AutopilotDepth, AutopilotState, Endpoint, Outbox, Stamp, StatusText,
    StepStatus, ThrusterSetpoints, topics,
};
use runtime::VehicleClock;
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::time::{Duration, Instant};
use testkit::{Namespace, Probe, Process};

/// Long enough for a process to start on a busy machine.
const T: Duration = Duration::from_secs(20);
/// How late a busy machine may wake the driver past its deadline.
const WAKE_MARGIN: f64 = 0.1;

/// The driver's default deadline, in seconds: the failsafe's rule at the scenario's 5 Hz.
fn deadline() -> f64 {
    adapters::failsafe::deadline(Duration::from_millis(200)).as_secs_f64()
}

/// pymavlink's Python (`scripts/install-pymavlink`; `PYMAVLINK_VENV` says where, as for the script).
fn python() -> PathBuf {
    testkit::venv_python(
        "PYMAVLINK_VENV",
        "pymavlink-venv",
        "scripts/install-pymavlink",
    )
}

/// A message the autopilot received.
#[derive(Clone, Debug)]
struct Record {
    /// Arrival, CLOCK_MONOTONIC seconds.
    t: f64,
    src: (u64, u64),
    kind: String,
    fields: Value,
}

impl Record {
    fn int(&self, key: &str) -> i64 {
        self.fields[key]
            .as_i64()
            .unwrap_or_else(|| panic!("{key} in {self:?}"))
    }

    fn float(&self, key: &str) -> f64 {
        self.fields[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key} in {self:?}"))
    }

    fn is(&self, kind: &str) -> bool {
        self.kind == kind
    }

    /// The (x, y, r) of a MANUAL_CONTROL, after checking its other fields.
    fn axes(&self) -> (i64, i64, i64) {
        assert!(self.is("MANUAL_CONTROL"), "{self:?}");
        assert_eq!(
            (self.int("z"), self.int("buttons"), self.int("target")),
            (500, 0, 1),
            "heave neutral, no buttons, to the autopilot: {self:?}"
        );
        (self.int("x"), self.int("y"), self.int("r"))
    }

    fn tag(&self) -> Option<(String, i64)> {
        self.is("NAMED_VALUE_INT").then(|| {
            (
                self.fields["name"].as_str().unwrap().to_string(),
                self.int("value"),
            )
        })
    }

    fn command(&self) -> Option<(i64, f64, f64)> {
        self.is("COMMAND_LONG").then(|| {
            (
                self.int("command"),
                self.float("param1"),
                self.float("param2"),
            )
        })
    }
}

const ARM_DISARM: i64 = 400;
const SET_MODE: i64 = 176;

/// The pymavlink ArduSub.
struct Peer {
    child: Child,
    lines: Receiver<Value>,
    port: u16,
    records: Vec<Record>,
    events: Vec<Value>,
    exited: bool,
}

impl Peer {
    fn start(args: &[String]) -> Peer {
        let script = testkit::repo_root().join("tests/ardusub_peer.py");
        let mut child = Command::new(python())
            .arg(&script)
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", script.display()));
        let stdout = child.stdout.take().unwrap();
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                let v: Value = serde_json::from_str(&line)
                    .unwrap_or_else(|e| panic!("the peer wrote `{line}`: {e}"));
                if tx.send(v).is_err() {
                    break;
                }
            }
        });
        let mut peer = Peer {
            child,
            lines,
            port: 0,
            records: Vec::new(),
            events: Vec::new(),
            exited: false,
        };
        let listening = peer
            .event(T, "listening")
            .expect("the pymavlink peer never said where it listens");
        peer.port = listening["port"].as_u64().unwrap() as u16;
        peer
    }

    /// Reads one line (waiting until `end`); false when none came.
    fn read(&mut self, end: Instant) -> bool {
        let left = end.saturating_duration_since(Instant::now());
        let Ok(v) = self.lines.recv_timeout(left) else {
            return false;
        };
        if v.get("event").is_some() {
            if v["event"] == "exit" {
                self.exited = true;
            }
            self.events.push(v);
        } else {
            let src = &v["src"];
            self.records.push(Record {
                t: v["t"].as_f64().unwrap(),
                src: (src[0].as_u64().unwrap(), src[1].as_u64().unwrap()),
                kind: v["type"].as_str().unwrap().to_string(),
                fields: v["fields"].clone(),
            });
        }
        true
    }

    /// The first record from index `from` on that `want` accepts, waiting up to `timeout`.
    fn find(
        &mut self,
        from: usize,
        timeout: Duration,
        want: impl Fn(&Record) -> bool,
    ) -> Option<usize> {
        let end = Instant::now() + timeout;
        let mut k = from;
        loop {
            while k < self.records.len() {
                if want(&self.records[k]) {
                    return Some(k);
                }
                k += 1;
            }
            if !self.read(end) {
                return None;
            }
        }
    }

    /// The event named `name`, waiting up to `timeout`.
    fn event(&mut self, timeout: Duration, name: &str) -> Option<Value> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(e) = self.events.iter().find(|e| e["event"] == name) {
                return Some(e.clone());
            }
            if !self.read(end) {
                return None;
            }
        }
    }

    /// Stops the peer and reads everything it received.
    fn stop(&mut self) {
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        assert!(
            self.event(T, "exit").is_some(),
            "the peer did not finish after SIGTERM"
        );
        let _ = self.child.wait();
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        if !self.exited {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// ArduSub's parameters as the tests' vehicle has them: ground stations 250 to 255, the
/// pilot-input failsafe on, pilot gain 0.8.
fn table() -> Vec<(&'static str, f64)> {
    vec![
        ("MAV_GCS_SYSID", 250.0),
        ("MAV_GCS_SYSID_HI", 255.0),
        ("FS_PILOT_INPUT", 2.0),
        ("FS_PILOT_TIMEOUT", 3.0),
        ("JS_GAIN_DEFAULT", 0.8),
        ("JS_GAIN_MIN", 0.25),
        ("JS_GAIN_MAX", 1.0),
        ("JS_GAIN_STEPS", 4.0),
        ("ACRO_YAW_P", 4.5),
    ]
}

fn peer_args(table: &[(&str, f64)], extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> = table
        .iter()
        .flat_map(|(n, v)| ["--param".to_string(), format!("{n}={v}")])
        .collect();
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

fn driver(ns: &Namespace, port: u16, options: &str, env: &[(&str, &str)]) -> Process {
    let sink = format!("ardusub:udpout:127.0.0.1:{port}{options}");
    Process::start_with_env(
        ns,
        &testkit::binary("thruster-driver"),
        &["--endpoint", "vehicle", "--sink", &sink],
        env,
    )
}

/// The test as the allocator: numbered steps on the vehicle clock.
struct Allocator {
    out: Outbox<ThrusterSetpoints>,
    clock: VehicleClock,
    epoch: u32,
    seq: u64,
}

impl Allocator {
    fn new(probe: &Probe) -> Self {
        let clock = VehicleClock::system();
        Allocator {
            out: probe.outbox(&topics::THRUSTER_SETPOINTS),
            epoch: clock.new_epoch(),
            clock,
            seq: 0,
        }
    }

    /// Publishes the next step's setpoints, taken now; returns its stamp.
    fn send(&mut self, values: [f64; 3]) -> Stamp {
        self.seq += 1;
        let stamp = Stamp::new(
            self.seq,
            self.seq * 200_000_000,
            0,
            self.seq as u32,
            StepStatus::Running,
        )
        .timed(self.epoch, self.clock.now_ns());
        let mut m = ThrusterSetpoints {
            stamp,
            count: 3,
            ..Default::default()
        };
        m.values[..3].copy_from_slice(&values);
        self.out.send(m).expect("publishing setpoints");
        stamp
    }
}

/// The index of the MANUAL_CONTROL that answered `step` (the one just before its `ct_step` tag).
fn answer(peer: &mut Peer, from: usize, step: u32, timeout: Duration) -> Option<usize> {
    let tag = peer.find(from, timeout, |r| {
        r.tag() == Some(("ct_step".into(), i64::from(step)))
    })?;
    assert!(
        peer.records[tag - 1].is("MANUAL_CONTROL"),
        "the tag follows its MANUAL_CONTROL: {:?}",
        &peer.records[tag - 1]
    );
    Some(tag - 1)
}

/// Sends steps of `values` until one is answered (the driver may still be settling); returns the
/// answered step's stamp and its MANUAL_CONTROL's index.
fn step(
    peer: &mut Peer,
    alloc: &mut Allocator,
    from: usize,
    values: [f64; 3],
    log: &Process,
) -> (Stamp, usize) {
    let end = Instant::now() + T;
    loop {
        let stamp = alloc.send(values);
        if let Some(k) = answer(peer, from, stamp.step, Duration::from_millis(300)) {
            return (stamp, k);
        }
        assert!(
            Instant::now() < end,
            "step {} never reached the autopilot\n{}",
            stamp.step,
            log.log()
        );
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    assert!(!v.is_empty());
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn secs(ns: i64) -> f64 {
    ns as f64 / 1e9
}

#[test]
fn the_driver_pilots_ardusub_as_a_companion() {
    let ns = Namespace::new("asub");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let state = probe.inbox(&topics::AUTOPILOT_STATE);
    let depth = probe.inbox(&topics::AUTOPILOT_DEPTH);
    let attitude = probe.inbox(&topics::AUTOPILOT_ATTITUDE);
    let mut alloc = Allocator::new(&probe);
    let mut peer = Peer::start(&peer_args(&table(), &[]));
    // A companion of its own ids, at 25 Hz.
    let me = (250, 195);
    let mut driver = driver(&ns, peer.port, "?sysid=250&compid=195&rate=25", &[]);

    // Read, then MANUAL, then armed.
    let arm = peer
        .find(0, T, |r| {
            r.command()
                .is_some_and(|(c, p1, _)| c == ARM_DISARM && p1 == 1.0)
        })
        .unwrap_or_else(|| panic!("the driver never armed\n{}", driver.log()));
    let before = &peer.records[..arm];
    for name in [
        "MAV_GCS_SYSID",
        "MAV_GCS_SYSID_HI",
        "FS_PILOT_INPUT",
        "JS_GAIN_DEFAULT",
    ] {
        assert!(
            before
                .iter()
                .any(|r| r.is("PARAM_REQUEST_READ") && r.fields["param_id"] == name),
            "{name} read before arming"
        );
    }
    assert!(
        before
            .iter()
            .any(|r| r.command() == Some((SET_MODE, 1.0, 19.0))),
        "MANUAL set before arming"
    );
    assert!(
        before.iter().all(|r| r.src == me),
        "everything from system 250, component 195"
    );
    assert!(
        probe.wait_for_subscribers(&alloc.out, 1, T),
        "the driver never subscribed to the setpoints\n{}",
        driver.log()
    );

    // The autopilot's telemetry in the mesh.
    let s = probe
        .wait_for(&state, T, |s: &AutopilotState| s.armed == 1 && s.mode == 19)
        .unwrap_or_else(|| panic!("no armed MANUAL state on the mesh\n{}", driver.log()));
    assert_eq!(s.heartbeat, 1);
    assert_eq!(s.pilot_gain, 0.8f32 as f64);
    let d = probe
        .wait_for(&depth, T, |d: &AutopilotDepth| d.depth_m != 0.0)
        .expect("the depth on the mesh");
    assert_eq!((d.depth_m, d.heading_deg), (2.5, 69.0));
    let a = probe
        .wait_for(&attitude, T, |a: &AutopilotAttitude| a.yaw != 0.0)
        .expect("the attitude on the mesh");
    assert_eq!((a.yaw, a.roll), (1.2f32 as f64, 0.1f32 as f64));
    let s = probe
        .wait_for(&state, T, |s: &AutopilotState| !s.battery_v.is_nan())
        .expect("the battery in the state");
    assert_eq!((s.battery_v, s.battery_remaining), (15.8, 77));

    // Each DOF alone, both signs: the command divided by the pilot gain (0.4 / 0.8 = 500).
    let phases: [([f64; 3], (i64, i64, i64)); 6] = [
        ([0.4, 0.4, 0.0], (500, 0, 0)),
        ([-0.4, -0.4, 0.0], (-500, 0, 0)),
        ([0.0, 0.0, 0.4], (0, 500, 0)),
        ([0.0, 0.0, -0.4], (0, -500, 0)),
        // Port forward, starboard back: the bow turns to starboard, clockwise seen from above.
        ([0.4, -0.4, 0.0], (0, 0, 500)),
        ([-0.4, 0.4, 0.0], (0, 0, -500)),
    ];
    let mut at = arm;
    let mut last = None;
    let drive_start = peer.records.len();
    for (values, want) in phases {
        for _ in 0..2 {
            let (stamp, k) = step(&mut peer, &mut alloc, at, values, &driver);
            assert_eq!(peer.records[k].axes(), want, "the answer to {values:?}");
            // Held at the rate: the next two sticks carry the same axes (within the deadline).
            let held = peer
                .find(k + 2, T, |r| r.is("MANUAL_CONTROL"))
                .and_then(|h| peer.find(h + 1, T, |r| r.is("MANUAL_CONTROL")))
                .expect("the stick held");
            for r in peer.records[k..=held]
                .iter()
                .filter(|r| r.is("MANUAL_CONTROL"))
            {
                if r.t < secs(stamp.clock_ns) + deadline() - 0.05 {
                    assert_eq!(r.axes(), want, "held: {r:?}");
                }
            }
            at = held;
            last = Some(stamp);
        }
    }
    let last = last.unwrap();

    // No more steps: neutral, with a stop tag (cause 2, the deadline), the deadline after the last
    // step was taken (three sample periods: one missed frame passes, the second stops).
    let stop_tag = peer
        .find(at, T, |r| r.tag().is_some_and(|(n, _)| n == "ct_stop"))
        .unwrap_or_else(|| panic!("no stop\n{}", driver.log()));
    assert_eq!(peer.records[stop_tag].tag(), Some(("ct_stop".into(), 2)));
    let neutral = &peer.records[stop_tag - 1];
    assert_eq!(neutral.axes(), (0, 0, 0));
    let after = neutral.t - secs(last.clock_ns);
    assert!(
        (deadline() - 0.005..=deadline() + WAKE_MARGIN).contains(&after),
        "neutral {after:.3} s after the last step was taken, the deadline is {} s",
        deadline()
    );
    // The commands stop when the next step's command is due, one sample period after the last
    // step: from there to neutral is 400 ms at 5 Hz (the second missed frame), whatever the wake-up.
    let since_due = after - 0.2;
    assert!(
        since_due <= 0.4 + WAKE_MARGIN,
        "neutral {since_due:.3} s after the commands stopped (the next step's was due)"
    );
    let drive_end = stop_tag;
    // Held neutral (a second of it: the heartbeats counted below span the whole run).
    let mut k = stop_tag;
    for _ in 0..25 {
        k = peer
            .find(k + 1, T, |r| r.is("MANUAL_CONTROL"))
            .expect("the stick held");
        assert_eq!(peer.records[k].axes(), (0, 0, 0));
    }

    // Driving again, then SIGTERM: neutral first, then a disarm, acknowledged.
    let (_, k) = step(&mut peer, &mut alloc, k, [0.4, 0.4, 0.0], &driver);
    assert!(driver.signal(libc::SIGTERM), "the driver is running");
    let stop_tag = peer
        .find(k, T, |r| r.tag().is_some_and(|(n, _)| n == "ct_stop"))
        .unwrap_or_else(|| panic!("no stop after SIGTERM\n{}", driver.log()));
    assert_eq!(peer.records[stop_tag].tag(), Some(("ct_stop".into(), 3)));
    assert_eq!(peer.records[stop_tag - 1].axes(), (0, 0, 0));
    let disarm = peer
        .find(stop_tag, T, |r| {
            r.command().is_some_and(|(c, _, _)| c == ARM_DISARM)
        })
        .unwrap_or_else(|| panic!("no disarm after SIGTERM\n{}", driver.log()));
    assert_eq!(peer.records[disarm].command(), Some((ARM_DISARM, 0.0, 0.0)));
    let status = driver
        .wait(T)
        .unwrap_or_else(|| panic!("the driver did not exit after SIGTERM\n{}", driver.log()));
    assert!(status.success(), "{status:?}\n{}", driver.log());
    assert!(
        driver.log().contains("ArduSub disarmed"),
        "{}",
        driver.log()
    );
    peer.stop();

    // Heartbeats at 1 Hz, as an onboard controller.
    let beats: Vec<&Record> = peer
        .records
        .iter()
        .filter(|r| r.is("HEARTBEAT") && r.src == me)
        .collect();
    assert!(beats.len() >= 4, "{} heartbeats", beats.len());
    for b in &beats {
        assert_eq!((b.int("type"), b.int("autopilot")), (18, 8), "{b:?}");
    }
    let period = median(beats.windows(2).map(|w| w[1].t - w[0].t).collect());
    assert!(
        (0.9..=1.1).contains(&period),
        "heartbeats every {period:.3} s"
    );
    // MANUAL_CONTROL at 25 Hz while driving: the sticks held between steps (those without a tag)
    // come every 40 ms.
    let drive = &peer.records[drive_start..drive_end];
    let held: Vec<f64> = drive
        .iter()
        .enumerate()
        .filter(|(i, r)| {
            r.is("MANUAL_CONTROL") && drive.get(i + 1).is_none_or(|n| n.tag().is_none())
        })
        .map(|(_, r)| r.t)
        .collect();
    let stick = median(held.windows(2).map(|w| w[1] - w[0]).collect());
    assert!(
        (0.036..=0.044).contains(&stick),
        "the stick held every {stick:.4} s, the rate is 25/s"
    );
    eprintln!(
        "median heartbeat period {period:.4} s ({} beats), median stick period {stick:.4} s ({} held), neutral {after:.4} s after the last step",
        beats.len(),
        held.len()
    );
}

/// Runs a driver against an ArduSub with `table` and the extra peer arguments; returns its log and
/// what the autopilot received, after the driver exited (with failure) or `T` passed.
fn refused_with(table: &[(&str, f64)]) -> (String, Vec<Record>) {
    let ns = Namespace::new("asrf");
    let mut peer = Peer::start(&peer_args(table, &[]));
    let mut driver = driver(&ns, peer.port, "", &[]);
    let status = driver
        .wait(T)
        .unwrap_or_else(|| panic!("the driver did not give up\n{}", driver.log()));
    assert!(!status.success(), "{status:?}\n{}", driver.log());
    peer.stop();
    let armed = peer.records.iter().any(|r| {
        r.command()
            .is_some_and(|(c, p1, _)| c == ARM_DISARM && p1 == 1.0)
    });
    assert!(!armed, "the driver armed an autopilot it refuses");
    (driver.log(), peer.records.clone())
}

#[test]
fn the_driver_refuses_to_arm_when_ardusub_47_ignores_its_system_id() {
    // ArduSub's defaults: ground station 255 only.
    let mut t = table();
    t[0].1 = 255.0;
    t[1].1 = 0.0;
    let (log, _) = refused_with(&t);
    assert!(
        log.contains("ArduSub ignores MANUAL_CONTROL from system 254")
            && log.contains("set MAV_GCS_SYSID to 254 and MAV_GCS_SYSID_HI to 255"),
        "{log}"
    );
}

#[test]
fn the_driver_refuses_to_arm_when_sysid_mygcs_is_not_its_id() {
    // ArduSub before 4.7: SYSID_MYGCS, and no MAV_GCS_SYSID.
    let mut t: Vec<_> = table().into_iter().skip(2).collect();
    t.push(("SYSID_MYGCS", 255.0));
    let (log, records) = refused_with(&t);
    assert!(
        log.contains("SYSID_MYGCS = 255") && log.contains("set SYSID_MYGCS to 254"),
        "{log}"
    );
    assert!(
        records
            .iter()
            .any(|r| r.is("PARAM_REQUEST_READ") && r.fields["param_id"] == "MAV_GCS_SYSID"),
        "the 4.7 name was asked first"
    );
}

#[test]
fn the_driver_refuses_to_arm_with_the_pilot_input_failsafe_off() {
    let mut t = table();
    t[2].1 = 0.0;
    let (log, _) = refused_with(&t);
    assert!(
        log.contains("FS_PILOT_INPUT = 0") && log.contains("set FS_PILOT_INPUT to 2"),
        "{log}"
    );
}

#[test]
fn a_restarted_driver_does_not_arm_the_vehicle_again() {
    let ns = Namespace::new("asrs");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let state = probe.inbox(&topics::AUTOPILOT_STATE);
    let mut peer = Peer::start(&peer_args(&table(), &["--mode", "19"]));
    let mut driver = driver(&ns, peer.port, "", &[("CABLETRACK_RESTARTS", "1")]);
    // It pilots (its stick goes out), but the vehicle stays disarmed.
    peer.find(0, T, |r| r.is("MANUAL_CONTROL"))
        .unwrap_or_else(|| panic!("no stick\n{}", driver.log()));
    let s = probe
        .wait_for(&state, T, |s: &AutopilotState| s.heartbeat == 1)
        .expect("the autopilot's state");
    assert_eq!(s.armed, 0);
    let status = driver.terminate(T);
    assert!(status.success(), "{status:?}\n{}", driver.log());
    peer.stop();
    assert!(
        !peer.records.iter().any(|r| r
            .command()
            .is_some_and(|(c, _, _)| c == ARM_DISARM || c == SET_MODE)),
        "a restarted driver neither arms nor sets the mode"
    );
    assert!(
        driver.log().contains("does not arm it again"),
        "{}",
        driver.log()
    );
}

#[test]
fn garbage_on_the_link_is_counted_and_refused_and_the_driver_goes_on() {
    let ns = Namespace::new("asgb");
    let probe = testkit::probe(&ns, Endpoint::Vehicle);
    let state = probe.inbox(&topics::AUTOPILOT_STATE);
    let texts = probe.inbox(&topics::AUTOPILOT_STATUS_TEXT);
    let mut alloc = Allocator::new(&probe);
    const N: u64 = 5;
    let mut peer = Peer::start(&peer_args(&table(), &["--garbage", &N.to_string()]));
    let mut driver = driver(&ns, peer.port, "", &[]);
    assert!(
        probe.wait_for_subscribers(&alloc.out, 1, T),
        "the driver never subscribed to the setpoints\n{}",
        driver.log()
    );
    // The first step's tag sets the garbage off.
    let (_, k) = step(&mut peer, &mut alloc, 0, [0.2, 0.2, 0.0], &driver);
    let sent = peer.event(T, "garbage").expect("the peer sent its garbage");
    // What came after the garbage is read.
    probe
        .wait_for(&texts, T, |t: &StatusText| t.text() == "after the garbage")
        .unwrap_or_else(|| panic!("the text after the garbage never arrived\n{}", driver.log()));
    // The next heartbeat's state counts the refused frames: at least the broken ones (a broken
    // frame's bytes may hold more false starts).
    let s = probe
        .wait_for(&state, T, |s: &AutopilotState| s.frames_refused >= N)
        .unwrap_or_else(|| panic!("the refused frames were not counted\n{}", driver.log()));
    assert!(s.heartbeat == 1 && s.armed == 1, "{s:?}");
    let log = driver.log();
    assert!(log.contains("MAVLink refused on the link"), "{log}");
    let garbage_bytes = sent["garbage_bytes"].as_u64().unwrap();
    assert!(garbage_bytes > 0);
    // It goes on: a new step is answered, and it stops cleanly.
    let (_, _) = step(&mut peer, &mut alloc, k + 1, [0.0, 0.0, 0.3], &driver);
    let status = driver.terminate(T);
    assert!(status.success(), "{status:?}\n{}", driver.log());
    assert!(!driver.log().contains("panicked"), "{}", driver.log());
    peer.stop();
}
