#![allow(deprecated)] // SET_MODE, which ArduPilot still takes

use super::*;
use mavlink::dialects::ardupilotmega::{
    COMMAND_LONG_DATA, MANUAL_CONTROL_DATA, MavCmd, NAMED_VALUE_INT_DATA, PARAM_REQUEST_LIST_DATA,
    PARAM_REQUEST_READ_DATA, PARAM_SET_DATA, SET_MODE_DATA,
};
use mavlink::{MavlinkVersion, Message};

const MS: Duration = Duration::from_millis(1);
const GCS: u8 = 255;

fn frame_from(sysid: u8, msg: &MavMessage) -> Frame {
    Frame {
        version: MavlinkVersion::V2,
        sequence: 0,
        system_id: sysid,
        component_id: 190,
        message_id: msg.message_id(),
        payload: wire::payload(msg),
    }
}

fn config(edit: impl FnOnce(&mut AutopilotParams)) -> AutopilotParams {
    let mut c = AutopilotParams::default();
    edit(&mut c);
    c
}

fn sub(t0: Instant) -> ArduSub {
    ArduSub::new(&AutopilotParams::default(), Vec::new(), t0)
}

fn manual(x: i16, y: i16, z: i16, r: i16) -> MavMessage {
    MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
        x,
        y,
        z,
        r,
        buttons: 0,
        target: 1,
        ..Default::default()
    })
}

fn command(command: MavCmd, p: [f32; 7]) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        param1: p[0],
        param2: p[1],
        param3: p[2],
        param4: p[3],
        param5: p[4],
        param6: p[5],
        param7: p[6],
        command,
        target_system: 1,
        target_component: 1,
        confirmation: 0,
    })
}

fn arm_cmd(arm: bool) -> MavMessage {
    command(
        MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        [arm as u8 as f32, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    )
}

fn mode_cmd(base: f32, mode: u32) -> MavMessage {
    command(
        MavCmd::MAV_CMD_DO_SET_MODE,
        [base, mode as f32, 0.0, 0.0, 0.0, 0.0, 0.0],
    )
}

fn acks(out: &[Out]) -> Vec<(u16, MavResult)> {
    out.iter()
        .filter_map(|o| match o {
            Out::Ack {
                command, result, ..
            } => Some((*command, *result)),
            _ => None,
        })
        .collect()
}

fn messages(out: &[Out]) -> impl Iterator<Item = &MavMessage> {
    out.iter().filter_map(|o| match o {
        Out::Message(m) => Some(&**m),
        _ => None,
    })
}

fn texts(out: &[Out]) -> Vec<(MavSeverity, String)> {
    messages(out)
        .filter_map(|m| match m {
            MavMessage::STATUSTEXT(t) => Some((t.severity, t.text.to_str().unwrap().to_string())),
            _ => None,
        })
        .collect()
}

fn heartbeats(out: &[Out]) -> Vec<HEARTBEAT_DATA> {
    messages(out)
        .filter_map(|m| match m {
            MavMessage::HEARTBEAT(h) => Some(h.clone()),
            _ => None,
        })
        .collect()
}

fn params(out: &[Out]) -> Vec<(String, f32, u16, u16)> {
    messages(out)
        .filter_map(|m| match m {
            MavMessage::PARAM_VALUE(p) => Some((
                p.param_id.to_str().unwrap().to_string(),
                p.param_value,
                p.param_index,
                p.param_count,
            )),
            _ => None,
        })
        .collect()
}

/// Sends `msg` from `sysid` at `now` and returns what the autopilot says.
fn say(a: &mut ArduSub, now: Instant, sysid: u8, msg: &MavMessage) -> Vec<Out> {
    a.receive(now, &frame_from(sysid, msg));
    a.take_out(now)
}

fn armed_in(mode: Mode, t0: Instant) -> ArduSub {
    let mut a = sub(t0);
    say(&mut a, t0, GCS, &mode_cmd(1.0, mode.number()));
    say(&mut a, t0, GCS, &arm_cmd(true));
    assert!(a.armed() && a.mode() == mode);
    a
}

#[test]
fn heartbeat_at_1_hz_as_an_ardusub_submarine() {
    let t0 = Instant::now();
    let mut a = sub(t0);
    let mut beats = Vec::new();
    for k in 0..=3000 {
        a.on_time(t0 + k * MS);
        beats.extend(heartbeats(&a.take_out(t0 + k * MS)));
    }
    assert_eq!(beats.len(), 4, "at 0, 1, 2 and 3 s");
    let h = &beats[0];
    assert_eq!(h.mavtype, MavType::MAV_TYPE_SUBMARINE);
    assert_eq!(h.autopilot, MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA);
    assert_eq!(h.custom_mode, 19, "MANUAL at boot");
    assert_eq!(h.base_mode.bits(), 16 | 64 | 1);
    let t = t0 + 3001 * MS;
    let out = say(&mut a, t, GCS, &manual(0, 0, 500, 0));
    assert!(out.is_empty());
    say(&mut a, t, GCS, &arm_cmd(true));
    a.on_time(t + 1000 * MS);
    let h = heartbeats(&a.take_out(t + 1000 * MS));
    assert_eq!(h.len(), 1);
    assert_eq!(h[0].base_mode.bits(), 128 | 16 | 64 | 1, "armed");
    assert_eq!(h[0].system_status, MavState::MAV_STATE_ACTIVE);
}

#[test]
fn parameters_by_name_by_index_and_listed() {
    let t0 = Instant::now();
    let c = config(|c| {
        c.params.insert("FS_PILOT_TIMEOUT".into(), 1.5);
        c.params.insert("MAV_GCS_SYSID_HI".into(), 255.0);
    });
    let mut a = ArduSub::new(&c, Vec::new(), t0);
    let read = |name: &str, index: i16| {
        MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
            param_index: index,
            target_system: 1,
            target_component: 1,
            param_id: name.into(),
        })
    };
    let out = params(&say(&mut a, t0, GCS, &read("FS_PILOT_TIMEOUT", -1)));
    let n = c.specs().count() as u16;
    assert_eq!(out.len(), 1);
    assert_eq!(
        (out[0].0.as_str(), out[0].1, out[0].3),
        ("FS_PILOT_TIMEOUT", 1.5, n)
    );
    let by_index = params(&say(&mut a, t0, GCS, &read("", out[0].2 as i16)));
    assert_eq!(by_index, out);
    assert_eq!(
        params(&say(&mut a, t0, GCS, &read("MAV_GCS_SYSID_HI", -1)))[0].1,
        255.0
    );
    assert!(params(&say(&mut a, t0, GCS, &read("NO_SUCH", -1))).is_empty());
    assert!(params(&say(&mut a, t0, GCS, &read("", 999))).is_empty());
    let list = params(&say(
        &mut a,
        t0,
        GCS,
        &MavMessage::PARAM_REQUEST_LIST(PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: 1,
        }),
    ));
    assert_eq!(list.len(), n as usize);
    assert!(
        list.iter()
            .enumerate()
            .all(|(k, p)| p.2 == k as u16 && p.3 == n)
    );
    let names: Vec<&str> = list.iter().map(|p| p.0.as_str()).collect();
    for want in [
        "MAV_GCS_SYSID",
        "MAV_GCS_SYSID_HI",
        "FS_PILOT_INPUT",
        "FS_PILOT_TIMEOUT",
        "JS_GAIN_DEFAULT",
    ] {
        assert!(names.contains(&want), "{want} in {names:?}");
    }
    assert!(!names.contains(&"SYSID_MYGCS"));
    // The older generation has SYSID_MYGCS instead.
    let mut old = ArduSub::new(
        &config(|c| c.generation = ArduSubGeneration::V4_5),
        Vec::new(),
        t0,
    );
    let out = params(&say(&mut old, t0, GCS, &read("SYSID_MYGCS", -1)));
    assert_eq!(out[0].1, 255.0);
    assert!(params(&say(&mut old, t0, GCS, &read("MAV_GCS_SYSID", -1))).is_empty());
    // PARAM_SET: a good value is taken and echoed, a bad one refused (the old value echoed).
    let set = |name: &str, v: f32| {
        MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: v,
            target_system: 1,
            target_component: 1,
            param_id: name.into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        })
    };
    assert_eq!(
        params(&say(&mut a, t0, GCS, &set("FS_PILOT_TIMEOUT", 2.0)))[0].1,
        2.0
    );
    assert_eq!(
        params(&say(&mut a, t0, GCS, &set("FS_PILOT_TIMEOUT", 9.0)))[0].1,
        2.0
    );
}

#[test]
fn manual_control_only_from_a_ground_station_and_for_this_system() {
    let t0 = Instant::now();
    // 4.7 with a range: 250..=255 are ground stations.
    let mut a = ArduSub::new(
        &config(|c| {
            c.params.insert("MAV_GCS_SYSID".into(), 250.0);
            c.params.insert("MAV_GCS_SYSID_HI".into(), 255.0);
        }),
        Vec::new(),
        t0,
    );
    for (sysid, gcs) in [
        (249, false),
        (250, true),
        (252, true),
        (255, true),
        (1, false),
    ] {
        assert_eq!(a.is_gcs(sysid), gcs, "sysid {sysid}");
    }
    say(&mut a, t0, 1, &manual(1000, 0, 500, 0));
    assert_eq!(a.sticks(), Sticks::NEUTRAL, "ignored");
    assert_eq!(a.counters().not_from_gcs, 1);
    let mut other = manual(1000, 0, 500, 0);
    if let MavMessage::MANUAL_CONTROL(m) = &mut other {
        m.target = 7;
    }
    say(&mut a, t0, 252, &other);
    assert_eq!(a.sticks(), Sticks::NEUTRAL);
    assert_eq!(a.counters().not_for_us, 1);
    say(&mut a, t0, 252, &manual(1000, 0, 500, 0));
    assert_eq!(a.sticks().forward, 1700);
    // HI below MAV_GCS_SYSID: only MAV_GCS_SYSID itself (the default, 255).
    let d = sub(t0);
    assert!(d.is_gcs(255) && !d.is_gcs(254));
    // Before 4.7: SYSID_MYGCS alone.
    let old = ArduSub::new(
        &config(|c| {
            c.generation = ArduSubGeneration::V4_5;
            c.params.insert("SYSID_MYGCS".into(), 200.0);
        }),
        Vec::new(),
        t0,
    );
    assert!(old.is_gcs(200) && !old.is_gcs(255));
}

/// joystick.cpp's scaling: 0.4 x gain around 1500 for x, y, r; z's 500 is neutral.
#[test]
fn the_joystick_gain_scales_the_axes_as_ardusub_does() {
    let s = Sticks::from_joystick(1000, -1000, 500, 500, 0.5, 1.0);
    assert_eq!(
        (s.forward, s.lateral, s.throttle, s.yaw),
        (1700, 1300, 1500, 1600)
    );
    let s = Sticks::from_joystick(1000, 250, 1000, -1000, 1.0, 1.0);
    assert_eq!(
        (s.forward, s.lateral, s.throttle, s.yaw),
        (1900, 1600, 1900, 1100)
    );
    // Clamped to 1100..1900 whatever comes in.
    let s = Sticks::from_joystick(i16::MAX, i16::MIN, 0, 0, 1.0, 4.0);
    assert_eq!((s.forward, s.lateral, s.throttle), (1900, 1100, 1100));
    // The gain at boot: the default within [min, max]; a default outside, with steps, the middle
    // setting.
    assert_eq!(boot_gain(0.5, 0.25, 1.0, 4.0), 0.5);
    assert_eq!(boot_gain(0.9, 0.25, 0.8, 1.0), 0.8);
    assert!((boot_gain(0.9, 0.25, 0.8, 4.0) - (0.25 + 0.55 / 3.0)).abs() < 1e-12);
    // Through the autopilot: the configured JS_GAIN_DEFAULT at full forward, MANUAL, armed.
    let t0 = Instant::now();
    for (gain, pwm3) in [(0.5, 1700), (1.0, 1900), (0.25, 1600)] {
        let mut a = ArduSub::new(
            &config(|c| {
                c.params.insert("JS_GAIN_DEFAULT".into(), gain);
            }),
            Vec::new(),
            t0,
        );
        say(&mut a, t0, GCS, &arm_cmd(true));
        say(&mut a, t0, GCS, &manual(1000, 0, 500, 0));
        assert_eq!(a.gain(), gain);
        let p = a.pwm();
        assert_eq!(p[2], pwm3, "gain {gain}");
        assert_eq!(p[0], 3000 - pwm3, "motor 1 runs the other way");
    }
}

#[test]
fn manual_passes_each_axis_through_the_vectored_mixer_only_while_armed() {
    let t0 = Instant::now();
    let mut a = sub(t0);
    say(&mut a, t0, GCS, &manual(1000, 0, 500, 0));
    assert_eq!(a.pwm(), [1500; 6], "disarmed: neutral");
    say(&mut a, t0, GCS, &arm_cmd(true));
    for (axis, msg, signs) in [
        ("forward", manual(1000, 0, 500, 0), [-1, -1, 1, 1, 0, 0]),
        ("lateral", manual(0, 1000, 500, 0), [1, -1, 1, -1, 0, 0]),
        ("yaw", manual(0, 0, 500, 1000), [1, -1, -1, 1, 0, 0]),
        ("down", manual(0, 0, 0, 0), [0, 0, 0, 0, 1, 1]),
    ] {
        say(&mut a, t0, GCS, &msg);
        let p = a.pwm();
        for m in 0..6 {
            let d = p[m] as i32 - 1500;
            assert_eq!(d.signum(), signs[m], "{axis}: motor {} at {}", m + 1, p[m]);
            if signs[m] != 0 {
                assert_eq!(d.abs(), 200, "{axis}: 0.4 x 0.5 x 1000 us");
            }
        }
    }
    // A reversed motor (MOT_3_DIRECTION = -1) runs the other way.
    let mut r = ArduSub::new(
        &config(|c| {
            c.params.insert("MOT_3_DIRECTION".into(), -1.0);
        }),
        Vec::new(),
        t0,
    );
    say(&mut r, t0, GCS, &arm_cmd(true));
    say(&mut r, t0, GCS, &manual(1000, 0, 500, 0));
    assert_eq!(r.pwm()[..4], [1300, 1300, 1300, 1700]);
}

#[test]
fn arming_and_mode_changes_are_acknowledged_as_ardusub_does() {
    let t0 = Instant::now();
    let mut a = sub(t0);
    let out = say(&mut a, t0, GCS, &arm_cmd(true));
    assert_eq!(acks(&out), vec![(400, MavResult::MAV_RESULT_ACCEPTED)]);
    assert_eq!(
        texts(&out),
        vec![(MavSeverity::MAV_SEVERITY_INFO, "Arming motors".into())]
    );
    // Arming again: accepted, nothing said.
    let out = say(&mut a, t0, GCS, &arm_cmd(true));
    assert_eq!(acks(&out), vec![(400, MavResult::MAV_RESULT_ACCEPTED)]);
    assert!(texts(&out).is_empty());
    for (mode, n) in [(Mode::AltHold, 2), (Mode::Stabilize, 0), (Mode::Manual, 19)] {
        let out = say(&mut a, t0, GCS, &mode_cmd(1.0, n));
        assert_eq!(acks(&out), vec![(176, MavResult::MAV_RESULT_ACCEPTED)]);
        assert_eq!(a.mode(), mode);
    }
    // Without the custom-mode flag: denied; a mode ArduSub has but the twin does not fly (GUIDED)
    // or none at all: failed.
    let out = say(&mut a, t0, GCS, &mode_cmd(0.0, 2));
    assert_eq!(acks(&out), vec![(176, MavResult::MAV_RESULT_DENIED)]);
    for n in [4, 99] {
        let out = say(&mut a, t0, GCS, &mode_cmd(1.0, n));
        assert_eq!(acks(&out), vec![(176, MavResult::MAV_RESULT_FAILED)]);
    }
    assert_eq!(a.mode(), Mode::Manual);
    // The SET_MODE message: acknowledged with command 11.
    let set_mode = MavMessage::SET_MODE(SET_MODE_DATA {
        custom_mode: 2,
        target_system: 1,
        base_mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    });
    let out = say(&mut a, t0, GCS, &set_mode);
    assert_eq!(acks(&out), vec![(11, MavResult::MAV_RESULT_ACCEPTED)]);
    assert_eq!(a.mode(), Mode::AltHold);
    // A command the twin does not emulate: unsupported, whatever its number.
    let mut unknown = frame_from(GCS, &arm_cmd(true));
    unknown.payload[28..30].copy_from_slice(&31_000u16.to_le_bytes());
    a.receive(t0, &unknown);
    assert_eq!(
        acks(&a.take_out(t0)),
        vec![(31_000, MavResult::MAV_RESULT_UNSUPPORTED)]
    );
    let out = say(&mut a, t0, GCS, &arm_cmd(false));
    assert_eq!(acks(&out), vec![(400, MavResult::MAV_RESULT_ACCEPTED)]);
    assert_eq!(
        texts(&out),
        vec![(MavSeverity::MAV_SEVERITY_INFO, "Disarming motors".into())]
    );
    assert!(!a.armed());
    // ALT_HOLD without a depth sensor is refused, as ArduSub does.
    let mut blind = ArduSub::new(&config(|c| c.depth_sensor = false), Vec::new(), t0);
    let out = say(&mut blind, t0, GCS, &mode_cmd(1.0, 2));
    assert_eq!(acks(&out), vec![(176, MavResult::MAV_RESULT_FAILED)]);
    assert_eq!(texts(&out)[0].1, "Depth sensor is not connected.");
    assert_eq!(blind.mode(), Mode::Manual);
}

/// failsafe.cpp, fed the time: at FS_PILOT_TIMEOUT without MANUAL_CONTROL, "Lost manual control",
/// neutral controls, and with FS_PILOT_INPUT = 2 a disarm; once per loss.
#[test]
fn the_pilot_input_failsafe_fires_at_its_timeout() {
    for action in [2.0, 1.0, 0.0] {
        let t0 = Instant::now();
        let mut a = ArduSub::new(
            &config(|c| {
                c.params.insert("FS_PILOT_INPUT".into(), action);
                c.params.insert("FS_PILOT_TIMEOUT".into(), 1.0);
            }),
            Vec::new(),
            t0,
        );
        say(&mut a, t0, GCS, &arm_cmd(true));
        let t1 = t0 + 500 * MS;
        say(&mut a, t1, GCS, &manual(800, 0, 500, 0));
        assert_ne!(a.pwm(), [1500; 6]);
        let mut lost_at = None;
        for k in 1..=3000u32 {
            let t = t1 + k * MS;
            a.on_time(t);
            let out = a.take_out(t);
            if texts(&out).iter().any(|x| x.1 == "Lost manual control") {
                assert!(lost_at.is_none(), "once");
                assert_eq!(texts(&out)[0].0, MavSeverity::MAV_SEVERITY_CRITICAL);
                lost_at = Some(k);
            }
        }
        if action == 0.0 {
            assert_eq!(lost_at, None, "disabled");
            assert!(a.armed() && a.pwm() != [1500; 6]);
            continue;
        }
        assert_eq!(
            lost_at,
            Some(1000),
            "action {action}: at the timeout, to the ms"
        );
        assert_eq!(a.sticks(), Sticks::NEUTRAL, "neutral controls");
        assert_eq!(a.pwm(), [1500; 6]);
        assert_eq!(a.armed(), action == 1.0, "disarmed only with action 2");
        assert_eq!(a.counters().failsafes, 1);
        // Pilot input clears it; losing it again fires again.
        let t2 = t1 + 5000 * MS;
        say(&mut a, t2, GCS, &manual(0, 0, 500, 0));
        a.on_time(t2 + 999 * MS);
        assert!(!a.failsafe());
        a.on_time(t2 + 1000 * MS);
        assert!(a.failsafe());
        assert_eq!(a.counters().failsafes, 2);
    }
}

/// A yaw plant (the BlueROV2 scenario's yaw: dr/dt = alpha u - gamma r) under the autopilot.
struct YawPlant {
    psi: f64,
    r: f64,
}

impl YawPlant {
    fn step(&mut self, a: &mut ArduSub, h: f64, disturbance: f64) {
        let v = Vehicle {
            heading: self.psi,
            yaw_rate: self.r,
            ground_speed: 0.0,
        };
        let pwm = a.control(h, v);
        // The yaw moment of the four horizontal thrusters (yaw factors 1, -1, -1, 1).
        let yaw = [1.0, -1.0, -1.0, 1.0]
            .iter()
            .zip(&pwm[..4])
            .map(|(f, &p)| f * mixer::setpoint(p))
            .sum::<f64>()
            / 4.0;
        self.r += h * (119.0 * yaw - 0.25 * self.r + disturbance);
        self.psi += h * self.r;
    }
}

#[test]
fn alt_hold_makes_yaw_a_rate_and_holds_the_heading_when_released() {
    let t0 = Instant::now();
    let mut a = armed_in(Mode::AltHold, t0);
    let mut plant = YawPlant { psi: 0.0, r: 0.0 };
    let h = 0.01;
    // Half yaw stick at gain 0.5: r = 500 -> 1600 us; the dead zone RC4_DZ x gain = 20 us ->
    // 4500 x 80 / 380 = 947 cdeg (integer arithmetic) x ACRO_YAW_P 4.5 = 4261 cdeg/s.
    say(&mut a, t0, GCS, &manual(0, 0, 500, 500));
    let mut heading = Vec::new();
    for _ in 0..300 {
        plant.step(&mut a, h, 0.0);
        heading.push(plant.psi);
    }
    let want = (947.0 * 4.5 / 100.0f64).to_radians();
    assert!(
        (plant.r - want).abs() < 0.01 * want,
        "the yaw rate follows the stick: {} vs {want}",
        plant.r
    );
    // The target heading integrates the stick's rate: the heading keeps up with it, the loop's
    // lag made up (the rate overshoots for a moment).
    let turned = heading[299] - heading[99];
    assert!(
        (turned - 2.0 * want).abs() < 0.01 * 2.0 * want,
        "{turned} vs {}",
        2.0 * want
    );
    assert!(
        heading[299] > 0.99 * 3.0 * want,
        "no lag left: {} vs {}",
        heading[299],
        3.0 * want
    );
    // Released: the turn stops and the heading 250 ms later is held against a disturbance; the
    // proportional loops alone would leave disturbance / (alpha x ATC_RAT_YAW_P x ATC_ANG_YAW_P)
    // = 2 / (119 x 0.18 x 6) = 0.0156 rad, the rate loop's integrator (ATC_RAT_YAW_I) takes it away.
    say(&mut a, t0, GCS, &manual(0, 0, 500, 0));
    for _ in 0..25 {
        plant.step(&mut a, h, 0.0);
    }
    let held = plant.psi;
    for _ in 0..100 {
        plant.step(&mut a, h, 2.0);
    }
    let proportional = 2.0 / (119.0 * 0.18 * 6.0);
    let early = plant.psi - held;
    assert!(
        early > 0.5 * proportional && early < 1.5 * proportional,
        "pushed off by about the proportional error: {early} vs {proportional}"
    );
    // The integrator works slowly (ATC_RAT_YAW_I 0.018) and against the PWM's 1 us steps (a yaw
    // moment of 119 x 0.0025 each): after a minute the error is a quarter of the proportional one
    // (0.0038 rad), and steady.
    let mut errors = Vec::new();
    for _ in 0..6000 {
        plant.step(&mut a, h, 2.0);
        errors.push(plant.psi - held);
    }
    let late = &errors[5000..];
    let mean = late.iter().sum::<f64>() / late.len() as f64;
    assert!(
        mean > 0.0 && mean < proportional / 3.0,
        "held: {mean} off, against {proportional} without the integrator"
    );
    assert!(late.iter().all(|e| (e - mean).abs() < 1e-3), "steady");
    assert!(plant.r.abs() < 0.001, "settled: r = {}", plant.r);
    // In MANUAL the same disturbance turns the vehicle away.
    say(&mut a, t0, GCS, &mode_cmd(1.0, 19));
    let before = plant.psi;
    for _ in 0..500 {
        plant.step(&mut a, h, 2.0);
    }
    assert!(plant.psi - before > 1.0, "no hold in MANUAL");
}

/// The yaw stick's dead zone is RC4_DZ (40 us by default) scaled by the joystick gain: a stick
/// inside it is a release (the heading held), one just outside a slow turn.
#[test]
fn the_yaw_dead_zone_scales_with_the_joystick_gain() {
    assert_eq!(yaw_angle(1520, 20.0), 0.0);
    assert_eq!(yaw_angle(1480, 20.0), 0.0);
    assert_eq!(yaw_angle(1521, 20.0), (4500 / 380) as f64);
    assert_eq!(yaw_angle(1479, 20.0), -((4500 / 380) as f64));
    assert_eq!(yaw_angle(1900, 20.0), 4500.0);
    assert_eq!(yaw_angle(1100, 0.0), -4500.0);
    let t0 = Instant::now();
    for (gain, r, turns) in [(0.5, 100, false), (0.5, 110, true), (1.0, 100, false)] {
        let mut a = ArduSub::new(
            &config(|c| {
                c.params.insert("JS_GAIN_DEFAULT".into(), gain);
            }),
            Vec::new(),
            t0,
        );
        say(&mut a, t0, GCS, &mode_cmd(1.0, Mode::AltHold.number()));
        say(&mut a, t0, GCS, &arm_cmd(true));
        say(&mut a, t0, GCS, &manual(0, 0, 500, r));
        let mut plant = YawPlant { psi: 0.0, r: 0.0 };
        for _ in 0..100 {
            plant.step(&mut a, 0.01, 0.0);
        }
        assert_eq!(
            plant.psi > 0.001,
            turns,
            "gain {gain}, r {r}: {}",
            plant.psi
        );
    }
}

/// The stack's pilot: `pilot` is what MANUAL_CONTROL does, `fly` what the mode and arming
/// commands do, `repositioned` starts the yaw loop again from the new heading.
#[test]
fn the_pilot_interface_is_the_ground_stations() {
    let t0 = Instant::now();
    let mut by_wire = armed_in(Mode::AltHold, t0);
    say(&mut by_wire, t0, GCS, &manual(300, -200, 500, 150));
    let mut direct = sub(t0);
    direct.fly(Mode::AltHold).unwrap();
    assert!(direct.armed() && direct.mode() == Mode::AltHold);
    direct.pilot(
        t0,
        Axes {
            x: 300,
            y: -200,
            z: 500,
            r: 150,
        },
    );
    assert_eq!(direct.sticks(), by_wire.sticks());
    let v = Vehicle {
        heading: 0.2,
        yaw_rate: 0.05,
        ground_speed: 0.1,
    };
    for _ in 0..30 {
        assert_eq!(direct.control(0.01, v), by_wire.control(0.01, v));
    }
    // Put back at another heading and released, the loop holds the new heading, not the old.
    direct.pilot(t0, Axes::NEUTRAL);
    let there = Vehicle {
        heading: -1.0,
        yaw_rate: 0.0,
        ground_speed: 0.0,
    };
    direct.repositioned(there);
    let mut last = [0; MOTORS];
    for _ in 0..100 {
        last = direct.control(0.01, there);
    }
    assert_eq!(&last[..4], &[1500; 4], "nothing to correct");
    // ALT_HOLD needs the depth sensor.
    let mut blind = ArduSub::new(&config(|c| c.depth_sensor = false), Vec::new(), t0);
    assert!(blind.fly(Mode::AltHold).is_err());
    assert!(!blind.armed());
}

#[test]
fn telemetry_streams_at_the_requested_intervals() {
    let t0 = Instant::now();
    let mut a = sub(t0);
    let interval = |id: u32, us: f32| {
        command(
            MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
            [id as f32, us, 0.0, 0.0, 0.0, 0.0, 0.0],
        )
    };
    let out = say(&mut a, t0, GCS, &interval(30, 100_000.0));
    assert_eq!(acks(&out), vec![(511, MavResult::MAV_RESULT_ACCEPTED)]);
    let out = say(&mut a, t0, GCS, &interval(36, -1.0));
    assert_eq!(acks(&out), vec![(511, MavResult::MAV_RESULT_ACCEPTED)]);
    let out = say(&mut a, t0, GCS, &interval(24, 100_000.0));
    assert_eq!(
        acks(&out),
        vec![(511, MavResult::MAV_RESULT_FAILED)],
        "GPS_RAW_INT: no GPS"
    );
    a.observe(Vehicle {
        heading: -0.5,
        yaw_rate: 0.1,
        ground_speed: 0.3,
    });
    let mut count = BTreeMap::<&str, usize>::new();
    let mut last = Vec::new();
    for k in 1..=2000u32 {
        let t = t0 + k * MS;
        a.on_time(t);
        for o in a.take_out(t) {
            if let Out::Message(m) = o {
                *count.entry(m.message_name()).or_default() += 1;
                last.push(*m);
            }
        }
    }
    assert_eq!(count.get("ATTITUDE"), Some(&20), "10 Hz for 2 s");
    assert_eq!(count.get("SERVO_OUTPUT_RAW"), None, "stopped");
    assert_eq!(count.get("VFR_HUD"), Some(&8), "the default 4 Hz");
    assert_eq!(count.get("SYS_STATUS"), Some(&2));
    for m in &last {
        match m {
            MavMessage::ATTITUDE(at) => {
                assert_eq!(
                    (at.yaw, at.yawspeed, at.roll, at.pitch),
                    (-0.5, 0.1, 0.0, 0.0)
                );
            }
            MavMessage::VFR_HUD(v) => {
                assert_eq!(v.heading, 331, "-0.5 rad as 0..360 degrees");
                assert_eq!((v.alt, v.groundspeed, v.throttle), (-1.0, 0.3, 50));
            }
            MavMessage::SYS_STATUS(s) => assert_eq!(s.voltage_battery, 15600),
            _ => {}
        }
    }
}

#[test]
fn the_step_tag_comes_back_from_a_ground_station_only() {
    let t0 = Instant::now();
    let mut a = sub(t0);
    let tag = MavMessage::NAMED_VALUE_INT(NAMED_VALUE_INT_DATA {
        time_boot_ms: 12_400,
        value: 62,
        name: STEP_TAG.into(),
    });
    assert_eq!(
        a.receive(t0, &frame_from(GCS, &tag)),
        Some(StepTag {
            frame_time_ms: 12_400,
            step: 62
        })
    );
    assert_eq!(a.receive(t0, &frame_from(3, &tag)), None);
}

#[test]
fn a_cut_link_carries_nothing_and_a_restart_comes_back_disarmed_in_manual() {
    let t0 = Instant::now();
    let faults = vec![
        "link-cut:2:1".parse::<Fault>().unwrap(),
        "restart:5:2".parse::<Fault>().unwrap(),
    ];
    let mut a = ArduSub::new(&AutopilotParams::default(), faults, t0);
    say(&mut a, t0, GCS, &mode_cmd(1.0, 2));
    say(&mut a, t0, GCS, &arm_cmd(true));
    let mut beats = Vec::new();
    for k in 0..=9000u32 {
        let t = t0 + k * MS;
        // The pilot keeps sending; during the cut nothing arrives.
        if k % 100 == 0 {
            a.receive(t, &frame_from(GCS, &manual(300, 0, 500, 0)));
        }
        a.on_time(t);
        for h in heartbeats(&a.take_out(t)) {
            beats.push((k, h));
        }
    }
    let at: Vec<u32> = beats.iter().map(|(k, _)| *k).collect();
    assert!(!at.contains(&2000), "cut at 2 s: {at:?}");
    assert!(at.contains(&3000), "back at 3 s: {at:?}");
    assert!(
        at.iter().all(|&k| !(5000..7000).contains(&k)),
        "silent while restarting: {at:?}"
    );
    let (_, after) = beats.iter().find(|(k, _)| *k >= 7000).unwrap();
    assert_eq!(after.custom_mode, 19, "MANUAL after the restart");
    assert!(
        !after
            .base_mode
            .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
        "disarmed after the restart"
    );
    assert!(a.counters().dropped_in >= 9 && a.counters().dropped_out > 0);
    assert!("cut:1:2".parse::<Fault>().is_err());
    assert!("link-cut:x:2".parse::<Fault>().is_err());
}

#[test]
fn urls_in_the_mavlink_crates_syntax() {
    assert_eq!(
        "udpin:0.0.0.0:14550".parse::<Url>(),
        Ok(Url::UdpIn("0.0.0.0:14550".parse().unwrap()))
    );
    assert_eq!(
        "udpout:127.0.0.1:14551".parse::<Url>(),
        Ok(Url::UdpOut("127.0.0.1:14551".parse().unwrap()))
    );
    for bad in [
        "tcpin:0.0.0.0:5760",
        "udpin:14550",
        "udpin",
        "serial:/dev/ttyACM0:115200",
    ] {
        assert!(bad.parse::<Url>().is_err(), "{bad}");
    }
}
