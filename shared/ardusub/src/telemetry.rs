//! The autopilot's telemetry, decoded into the mesh's payloads (`messages::Autopilot*`), and the
//! requests that make the autopilot send it.
//!
//! ArduSub sends at the rates of its stream parameters (SRn_*) unless asked otherwise: the companion
//! asks, with MAV_CMD_SET_MESSAGE_INTERVAL, for ATTITUDE at 10 Hz, VFR_HUD and SERVO_OUTPUT_RAW at
//! 5 Hz and SYS_STATUS at 1 Hz. STATUSTEXT comes as the autopilot has something to say. The payloads'
//! `seq` and `clock_ns` are filled where they are published.

use crate::autopilot::Address;
use mavlink::dialects::ardupilotmega::{
    ATTITUDE_DATA, COMMAND_LONG_DATA, MavCmd, MavMessage, SERVO_OUTPUT_RAW_DATA, STATUSTEXT_DATA,
    SYS_STATUS_DATA, VFR_HUD_DATA,
};
use messages::{AutopilotAttitude, AutopilotDepth, ServoOutputs, StatusText};

/// One decoded telemetry message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Telemetry {
    Attitude(AutopilotAttitude),
    Depth(AutopilotDepth),
    Servos(ServoOutputs),
    Text(StatusText),
}

/// The messages requested, and their intervals (microseconds).
pub const REQUESTED: [(u32, f32); 4] = [
    (30, 100_000.0),  // ATTITUDE, 10 Hz
    (74, 200_000.0),  // VFR_HUD, 5 Hz
    (36, 200_000.0),  // SERVO_OUTPUT_RAW, 5 Hz
    (1, 1_000_000.0), // SYS_STATUS, 1 Hz
];

/// The MAV_CMD_SET_MESSAGE_INTERVAL commands for [`REQUESTED`].
pub fn requests(target: Address) -> Vec<MavMessage> {
    REQUESTED
        .iter()
        .map(|&(id, interval_us)| {
            MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                param1: id as f32,
                param2: interval_us,
                command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
                target_system: target.system,
                target_component: target.component,
                ..Default::default()
            })
        })
        .collect()
}

/// The attitude.
pub fn attitude(m: &ATTITUDE_DATA) -> AutopilotAttitude {
    AutopilotAttitude {
        roll: m.roll.into(),
        pitch: m.pitch.into(),
        yaw: m.yaw.into(),
        roll_rate: m.rollspeed.into(),
        pitch_rate: m.pitchspeed.into(),
        yaw_rate: m.yawspeed.into(),
        boot_ms: m.time_boot_ms,
        ..Default::default()
    }
}

/// Depth and heading: ArduSub's VFR_HUD `alt` is its altitude above the surface, so depth is its
/// negation.
pub fn depth(m: &VFR_HUD_DATA) -> AutopilotDepth {
    AutopilotDepth {
        depth_m: -f64::from(m.alt),
        heading_deg: m.heading.into(),
        climb_m_s: m.climb.into(),
        throttle_pct: m.throttle.into(),
        ..Default::default()
    }
}

pub fn servos(m: &SERVO_OUTPUT_RAW_DATA) -> ServoOutputs {
    let pwm = [
        m.servo1_raw,
        m.servo2_raw,
        m.servo3_raw,
        m.servo4_raw,
        m.servo5_raw,
        m.servo6_raw,
        m.servo7_raw,
        m.servo8_raw,
        m.servo9_raw,
        m.servo10_raw,
        m.servo11_raw,
        m.servo12_raw,
        m.servo13_raw,
        m.servo14_raw,
        m.servo15_raw,
        m.servo16_raw,
    ];
    // A MAVLink 1 frame, or a MAVLink 2 one without the extension, carries 8 channels (the rest
    // read 0).
    let count = if pwm[8..].iter().any(|&p| p != 0) {
        16
    } else {
        8
    };
    ServoOutputs {
        time_us: m.time_usec,
        port: m.port,
        count,
        pwm_us: pwm,
        ..Default::default()
    }
}

pub fn text(m: &STATUSTEXT_DATA) -> StatusText {
    let bytes: &[u8] = &m.text[..];
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    StatusText::new(m.severity as u8, &String::from_utf8_lossy(&bytes[..end]))
}

/// The battery as SYS_STATUS reports it: volts, amperes (NaN when unknown), percent left (-1 when
/// unknown).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Battery {
    pub volts: f64,
    pub amperes: f64,
    pub remaining: i8,
}

impl Default for Battery {
    fn default() -> Self {
        Battery {
            volts: f64::NAN,
            amperes: f64::NAN,
            remaining: -1,
        }
    }
}

pub fn battery(m: &SYS_STATUS_DATA) -> Battery {
    Battery {
        // UINT16_MAX: not sent.
        volts: if m.voltage_battery == u16::MAX {
            f64::NAN
        } else {
            f64::from(m.voltage_battery) / 1000.0
        },
        // -1: not measured; centiamperes otherwise.
        amperes: if m.current_battery == -1 {
            f64::NAN
        } else {
            f64::from(m.current_battery) / 100.0
        },
        remaining: m.battery_remaining,
    }
}

/// The telemetry a message from the autopilot carries, if any.
pub fn decode(message: &MavMessage) -> Option<Telemetry> {
    match message {
        MavMessage::ATTITUDE(m) => Some(Telemetry::Attitude(attitude(m))),
        MavMessage::VFR_HUD(m) => Some(Telemetry::Depth(depth(m))),
        MavMessage::SERVO_OUTPUT_RAW(m) => Some(Telemetry::Servos(servos(m))),
        MavMessage::STATUSTEXT(m) => Some(Telemetry::Text(text(m))),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega::MavSeverity;

    #[test]
    fn depth_is_the_negated_altitude_and_angles_pass_unchanged() {
        let d = depth(&VFR_HUD_DATA {
            alt: -2.5,
            heading: 271,
            climb: 0.25,
            throttle: 50,
            ..Default::default()
        });
        assert_eq!(
            (d.depth_m, d.heading_deg, d.climb_m_s, d.throttle_pct),
            (2.5, 271.0, 0.25, 50.0)
        );
        let a = attitude(&ATTITUDE_DATA {
            time_boot_ms: 1234,
            roll: 0.5,
            pitch: -0.25,
            yaw: 1.5,
            yawspeed: -0.125,
            ..Default::default()
        });
        assert_eq!(
            (a.roll, a.pitch, a.yaw, a.yaw_rate, a.boot_ms),
            (0.5, -0.25, 1.5, -0.125, 1234)
        );
    }

    #[test]
    fn texts_batteries_and_servos_decode() {
        let t = text(&STATUSTEXT_DATA {
            severity: MavSeverity::MAV_SEVERITY_CRITICAL,
            text: "Lost manual control".into(),
            ..Default::default()
        });
        assert_eq!(
            (t.severity, t.text()),
            (2, "Lost manual control".to_string())
        );
        let b = battery(&SYS_STATUS_DATA {
            voltage_battery: 15_800,
            current_battery: 1234,
            battery_remaining: 77,
            ..Default::default()
        });
        assert_eq!((b.volts, b.amperes, b.remaining), (15.8, 12.34, 77));
        let unknown = battery(&SYS_STATUS_DATA {
            voltage_battery: u16::MAX,
            current_battery: -1,
            battery_remaining: -1,
            ..Default::default()
        });
        assert!(unknown.volts.is_nan() && unknown.amperes.is_nan());
        let s = servos(&SERVO_OUTPUT_RAW_DATA {
            servo1_raw: 1500,
            servo8_raw: 1900,
            ..Default::default()
        });
        assert_eq!(
            (s.count, s.pwm_us[0], s.pwm_us[7], s.pwm_us[8]),
            (8, 1500, 1900, 0)
        );
        match &requests(Address {
            system: 1,
            component: 1,
        })[0]
        {
            MavMessage::COMMAND_LONG(c) => {
                assert_eq!(c.command, MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL);
                assert_eq!((c.param1, c.param2), (30.0, 100_000.0));
            }
            other => panic!("{other:?}"),
        }
    }
}
