//! The ArduSub sink passes the thruster-sink conformance suite (`adapters::conformance`), with an
//! autopilot played in this process on loopback UDP: a small ArduSub written with the `mavlink`
//! crate's own parser and serializer (not the sink's framing), which heartbeats as a submarine,
//! answers parameters, acknowledges and obeys mode and arm commands, and records every frame it
//! receives.
//!
//! What arrives on this device is what ArduSub reads: MANUAL_CONTROL's axes, read back as the DOF
//! forces they command (the pilot gain is 1 here), each followed by the lockstep tag (`ct_step`:
//! the step and its time in ms; `ct_stop`: a stop's cause and the last step's time). A
//! MANUAL_CONTROL without a tag is the stick held at the steady rate, not a new arrival. So the rig
//! declares ([`SinkRig::as_arrives`]) that a write arrives as the forces its setpoints make
//! (`model::ThrusterLayout::forces`), within the axes' resolution of 1/1000, and a stamp as its
//! time in ms and its step.

use adapters::conformance::{self, Arrived, SinkRig};
use adapters::{AdapterError, Stamp, StopCause};
use ardusub::pilot::{self, Axes, Reach};
use ardusub::{ArduSubSink, STEP_TAG, STOP_TAG, Spec};
use config::{ThrusterParams, Thrusters};
use mavlink::dialects::ardupilotmega::{
    COMMAND_ACK_DATA, HEARTBEAT_DATA, MavAutopilot, MavCmd, MavMessage, MavModeFlag, MavResult,
    MavState, MavType, PARAM_VALUE_DATA,
};
use mavlink::{MavHeader, MavlinkReader};
use model::ThrusterLayout;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Long enough for anything on a busy machine.
const T: Duration = Duration::from_secs(10);

/// What the autopilot has received, and its state.
struct Seen {
    /// Every frame, with its sender.
    log: Vec<(SocketAddr, MavMessage)>,
    armed: bool,
    mode: u32,
}

/// A small ArduSub on 127.0.0.1.
struct Autopilot {
    address: SocketAddr,
    seen: Arc<(Mutex<Seen>, Condvar)>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

const PARAMS: [(&str, f32); 9] = [
    ("MAV_GCS_SYSID", 254.0),
    ("MAV_GCS_SYSID_HI", 255.0),
    ("FS_PILOT_INPUT", 2.0),
    ("FS_PILOT_TIMEOUT", 3.0),
    ("JS_GAIN_DEFAULT", 1.0),
    ("JS_GAIN_MIN", 0.25),
    ("JS_GAIN_MAX", 1.0),
    ("JS_GAIN_STEPS", 4.0),
    ("ACRO_YAW_P", 4.5),
];

fn send(socket: &UdpSocket, to: SocketAddr, message: &MavMessage) {
    let mut bytes = Vec::new();
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    mavlink::write_v2_msg(&mut bytes, header, message).unwrap();
    socket.send_to(&bytes, to).unwrap();
}

fn heartbeat(armed: bool, mode: u32) -> MavMessage {
    let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
    if armed {
        base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
    }
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: mode,
        mavtype: MavType::MAV_TYPE_SUBMARINE,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode,
        system_status: MavState::MAV_STATE_STANDBY,
        mavlink_version: 3,
    })
}

impl Autopilot {
    fn start() -> Autopilot {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(20)))
            .unwrap();
        let address = socket.local_addr().unwrap();
        let seen = Arc::new((
            Mutex::new(Seen {
                log: Vec::new(),
                armed: false,
                mode: 0,
            }),
            Condvar::new(),
        ));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (seen, stop) = (seen.clone(), stop.clone());
            std::thread::spawn(move || serve(socket, seen, stop))
        };
        Autopilot {
            address,
            seen,
            stop,
            thread: Some(thread),
        }
    }

    /// Frames received from port `from` so far.
    fn count(&self, from: u16) -> usize {
        let seen = self.seen.0.lock().unwrap();
        seen.log.iter().filter(|(a, _)| a.port() == from).count()
    }

    /// Waits until `n` frames from port `from` (on this host) have arrived; returns them all.
    fn wait_for(&self, from: u16, n: u64) -> Vec<MavMessage> {
        let end = Instant::now() + T;
        let (lock, cv) = &*self.seen;
        let mut seen = lock.lock().unwrap();
        loop {
            let got: Vec<MavMessage> = seen
                .log
                .iter()
                .filter(|(a, _)| a.port() == from)
                .map(|(_, m)| m.clone())
                .collect();
            if got.len() as u64 >= n {
                return got;
            }
            let left = end
                .checked_duration_since(Instant::now())
                .unwrap_or_else(|| panic!("{} of {n} frames from {from} arrived", got.len()));
            seen = cv.wait_timeout(seen, left).unwrap().0;
        }
    }
}

impl Drop for Autopilot {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The autopilot's loop: answers what it receives, heartbeats every 100 ms to whoever spoke.
fn serve(socket: UdpSocket, seen: Arc<(Mutex<Seen>, Condvar)>, stop: Arc<AtomicBool>) {
    let mut peers: Vec<SocketAddr> = Vec::new();
    let mut next_beat = Instant::now();
    let mut buf = [0u8; 2048];
    while !stop.load(Ordering::Relaxed) {
        let (armed, mode) = {
            let s = seen.0.lock().unwrap();
            (s.armed, s.mode)
        };
        if Instant::now() >= next_beat {
            for p in &peers {
                send(&socket, *p, &heartbeat(armed, mode));
            }
            next_beat = Instant::now() + Duration::from_millis(100);
        }
        let Ok((n, from)) = socket.recv_from(&mut buf) else {
            continue;
        };
        let mut reader = MavlinkReader::new(&buf[..n]);
        while let Ok((_, message)) = reader.read_any_message::<MavMessage>() {
            if !peers.contains(&from) {
                peers.push(from);
                send(&socket, from, &heartbeat(armed, mode));
            }
            let mut answer = Vec::new();
            {
                let mut s = seen.0.lock().unwrap();
                match &message {
                    MavMessage::PARAM_REQUEST_READ(r) => {
                        let name = r.param_id.to_str().unwrap_or("");
                        if let Some((n, v)) = PARAMS.iter().find(|(n, _)| *n == name) {
                            answer.push(MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
                                param_value: *v,
                                param_id: (*n).into(),
                                ..Default::default()
                            }));
                        }
                    }
                    MavMessage::COMMAND_LONG(c) => {
                        match c.command {
                            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => s.armed = c.param1 == 1.0,
                            MavCmd::MAV_CMD_DO_SET_MODE => s.mode = c.param2 as u32,
                            _ => {}
                        }
                        answer.push(MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                            command: c.command,
                            result: MavResult::MAV_RESULT_ACCEPTED,
                            target_system: 254,
                            target_component: 191,
                            ..Default::default()
                        }));
                        answer.push(heartbeat(s.armed, s.mode));
                    }
                    _ => {}
                }
                s.log.push((from, message));
            }
            seen.1.notify_all();
            for a in answer {
                send(&socket, from, &a);
            }
        }
    }
}

/// A layout of `n` horizontal thrusters: the scenario's three, else thrusters around the centre in
/// every direction (one pushes forward).
fn layout(n: usize) -> ThrusterLayout {
    if n == 3 {
        return ThrusterLayout::default();
    }
    let thruster = (0..n)
        .map(|i| {
            let a = i as f64 * 2.4;
            ThrusterParams {
                name: format!("t{i}"),
                x_m: 0.2 * a.cos(),
                y_m: 0.2 * a.sin(),
                heading_deg: i as f64 * 67.0,
            }
        })
        .collect();
    ThrusterLayout::new(&Thrusters { thruster })
}

struct ArduSubRig {
    autopilot: Autopilot,
    layout: ThrusterLayout,
    /// The current sink's port, and how many of its frames were read already.
    sink: Option<(u16, usize)>,
}

impl ArduSubRig {
    fn new() -> Self {
        ArduSubRig {
            autopilot: Autopilot::start(),
            layout: ThrusterLayout::default(),
            sink: None,
        }
    }
}

/// The forces of `values`, read as the allocator's setpoints of `layout`.
fn forces(layout: &ThrusterLayout, values: &[f64]) -> Vec<f64> {
    let f = layout.forces(values);
    vec![f.surge, f.sway, f.yaw]
}

impl SinkRig for ArduSubRig {
    type Sink = ArduSubSink;

    fn name(&self) -> String {
        "ArduSub thruster sink".into()
    }

    fn open(&mut self, thrusters: usize) -> Result<ArduSubSink, AdapterError> {
        self.layout = layout(thrusters);
        let spec: Spec = format!("udpout:{}", self.autopilot.address)
            .parse()
            .unwrap();
        let sink = ArduSubSink::open(&spec, self.layout.clone(), false, None)?;
        // What opening sent (the neutral stick before arming, the commands) is not an arrival.
        let at = sink
            .local_address()
            .expect("a UDP sink has an address")
            .port();
        self.autopilot.wait_for(at, sink.frames_sent());
        self.sink = Some((at, self.autopilot.count(at)));
        Ok(sink)
    }

    fn received(&mut self, sink: &mut ArduSubSink) -> Option<Vec<Arrived>> {
        let (at, read) = self.sink.as_mut().expect("a sink is open");
        let all = self.autopilot.wait_for(*at, sink.frames_sent());
        let mut out = Vec::new();
        let mut stick: Option<Axes> = None;
        let full = Reach::new(1.0, 1.0);
        for m in &all[*read..] {
            match m {
                MavMessage::MANUAL_CONTROL(mc) => {
                    assert_eq!((mc.z, mc.buttons, mc.target), (500, 0, 1), "{mc:?}");
                    stick = Some(Axes {
                        x: mc.x,
                        y: mc.y,
                        z: mc.z,
                        r: mc.r,
                    });
                }
                MavMessage::NAMED_VALUE_INT(tag) => {
                    let axes = stick.take().expect("a tag follows its MANUAL_CONTROL");
                    let f = pilot::forces(&axes, &full);
                    let time_ns = u64::from(tag.time_boot_ms) * 1_000_000;
                    let name = tag.name.to_str().unwrap();
                    let (stamp, stop) = match name {
                        n if n == STEP_TAG => (
                            Stamp {
                                time_ns,
                                step: tag.value as u32,
                                ..Default::default()
                            },
                            None,
                        ),
                        n if n == STOP_TAG => (
                            Stamp {
                                time_ns,
                                ..Default::default()
                            },
                            Some(StopCause::from_u32(tag.value as u32)),
                        ),
                        other => panic!("unknown tag {other}"),
                    };
                    out.push(Arrived {
                        stamp,
                        values: vec![f.surge, f.sway, f.yaw],
                        stop,
                    });
                }
                _ => {}
            }
        }
        *read = all.len();
        Some(out)
    }

    fn as_arrives(&self, sent: &Arrived) -> Arrived {
        // The tag carries the step's time in whole ms (u32) and, for a write, its step.
        let time_ns = u64::from((sent.stamp.time_ns / 1_000_000) as u32) * 1_000_000;
        Arrived {
            stamp: Stamp {
                time_ns,
                step: if sent.stop.is_none() {
                    sent.stamp.step
                } else {
                    0
                },
                ..Default::default()
            },
            values: forces(&self.layout, &sent.values),
            stop: sent.stop,
        }
    }

    fn resolution(&self) -> f64 {
        // Half a step of the axes' 1/1000, and a little for the float arithmetic.
        0.5e-3 + 1e-12
    }
}

#[test]
fn the_ardusub_thruster_sink_conforms() {
    conformance::thruster_sink(&mut ArduSubRig::new());
}

#[test]
fn the_rig_sees_a_wrong_force_and_a_missing_stop() {
    // The rig's far side is not blind: a write arrives as its forces, a stop with its cause.
    let mut rig = ArduSubRig::new();
    let mut sink = rig.open(3).unwrap();
    let st = Stamp {
        time_ns: 1_400_000_000,
        step: 7,
        ..Default::default()
    };
    use adapters::ThrusterSink;
    sink.write(&st, &[0.5, 0.1, -0.4]).unwrap();
    sink.stop(&st, StopCause::Deadline).unwrap();
    let got = rig.received(&mut sink).unwrap();
    assert_eq!(got.len(), 2);
    assert_eq!(got[0].stamp.step, 7);
    assert_eq!(got[0].stamp.time_ns, 1_400_000_000);
    // port 0.5 and starboard 0.1: surge 0.3, yaw 0.2; lateral -0.4 is sway to port.
    let want = [0.3, -0.4, 0.2];
    for (g, w) in got[0].values.iter().zip(want) {
        assert!((g - w).abs() < 1e-9, "{:?}", got[0].values);
    }
    assert_eq!(got[1].stop, Some(StopCause::Deadline));
    assert_eq!(got[1].values, vec![0.0; 3]);
    sink.close().unwrap();
    // And it disarmed the autopilot on close.
    assert!(!rig.autopilot.seen.0.lock().unwrap().armed);
}
