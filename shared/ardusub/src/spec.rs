//! What the thruster driver's `--sink ardusub:URL?OPTIONS` says: where the autopilot is, and how to
//! pilot it.
//!
//! ```text
//! ardusub:udpout:192.168.2.2:14550                  send to the vehicle's MAVLink router
//! ardusub:udpin:0.0.0.0:14660?sysid=253&rate=25     wait for the router to send here
//! ardusub:tcpout:192.168.2.2:5777?mode=alt_hold&arm=manual
//! ```
//!
//! Options (`?key=value&...`): `sysid` (this companion's MAVLink system, 1 to 254, default 254),
//! `compid` (its component, default 191, MAV_COMP_ID_ONBOARD_COMPUTER), `rate` (MANUAL_CONTROL per
//! second, default 20), `mode` (`manual`, `stabilize` or `alt_hold`, default `manual`), `arm`
//! (`auto`: the driver arms at a fresh start, never after a restart; `manual`: the pilot arms from a
//! ground station; default `auto`).

use std::fmt;
use std::time::Duration;

/// How the adapter reaches the autopilot (the `mavlink` crate's address syntax).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Url {
    /// Send to HOST:PORT from a port of our own, and read the answers there.
    UdpOut(String),
    /// Listen on ADDR:PORT; answer whoever sent last (a router's `udpout` endpoint).
    UdpIn(String),
    /// Connect to HOST:PORT (reconnecting when the connection drops).
    TcpOut(String),
}

impl fmt::Display for Url {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Url::UdpOut(a) => write!(f, "udpout:{a}"),
            Url::UdpIn(a) => write!(f, "udpin:{a}"),
            Url::TcpOut(a) => write!(f, "tcpout:{a}"),
        }
    }
}

/// ArduSub's flight modes the stack pilots in (HEARTBEAT `custom_mode`, ArduSub's `mode.h`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Pass-through: each MANUAL_CONTROL axis is a fraction of that axis's thrust.
    Manual,
    /// Attitude held level; yaw stick is a yaw-rate demand.
    Stabilize,
    /// Depth held as well (needs the depth sensor).
    AltHold,
}

impl Mode {
    pub fn custom_mode(self) -> u32 {
        match self {
            Mode::Stabilize => 0,
            Mode::AltHold => 2,
            Mode::Manual => 19,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Mode::Manual => "MANUAL",
            Mode::Stabilize => "STABILIZE",
            Mode::AltHold => "ALT_HOLD",
        }
    }
}

pub use messages::ardusub_mode_name as mode_name;

/// Who arms the vehicle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arming {
    /// The driver arms at a fresh start; a driver restarted by the supervisor never does.
    Auto,
    /// Never the driver: the pilot arms from a ground station.
    Manual,
}

/// How the companion pilots.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// This companion's MAVLink system id: ArduSub takes MANUAL_CONTROL only from its ground
    /// stations' ids (see this crate's README), and 255 is the ground station's own.
    pub system: u8,
    pub component: u8,
    /// MANUAL_CONTROL messages per second.
    pub rate_hz: f64,
    pub mode: Mode,
    pub arm: Arming,
    /// The scenario's `[pilot]` fractions, when the stack flies the vehicle as step one's model
    /// says: a DOF's command of 1 is then that fraction of the full stick at joystick gain 1.
    /// Without them a command of 1 is the axis's full thrust.
    pub fractions: Option<config::PilotFractions>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            system: 254,
            component: 191,
            rate_hz: 20.0,
            mode: Mode::Manual,
            arm: Arming::Auto,
            fractions: None,
        }
    }
}

impl Options {
    pub fn period(&self) -> Duration {
        Duration::from_secs_f64(1.0 / self.rate_hz)
    }
}

/// The whole `ardusub:` sink spec.
#[derive(Clone, Debug, PartialEq)]
pub struct Spec {
    pub url: Url,
    pub options: Options,
    /// Whether the spec named the mode (`mode=`), rather than taking the default.
    pub mode_named: bool,
}

impl From<config::PilotMode> for Mode {
    fn from(mode: config::PilotMode) -> Self {
        match mode {
            config::PilotMode::Manual => Mode::Manual,
            config::PilotMode::Stabilize => Mode::Stabilize,
            config::PilotMode::AltHold => Mode::AltHold,
        }
    }
}

impl Spec {
    /// Flies as the scenario's `[pilot]` says: its mode (unless the spec named another: an error,
    /// since step one learned on that mode's response) and its fractions.
    pub fn with_pilot(mut self, pilot: &config::PilotParams) -> Result<Self, String> {
        let wanted = Mode::from(pilot.mode);
        if self.mode_named && self.options.mode != wanted {
            return Err(format!(
                "ArduSub sink `{}`: mode={} but the scenario's [pilot] flies in {} (step one learned that mode's response): drop `mode=` or set [pilot] mode",
                self.url,
                self.options.mode.name().to_lowercase(),
                wanted.name().to_lowercase()
            ));
        }
        self.options.mode = wanted;
        self.options.fractions = Some(pilot.fraction);
        Ok(self)
    }
}

/// The fastest and slowest MANUAL_CONTROL rates accepted: ArduSub's pilot-input failsafe wants one
/// within FS_PILOT_TIMEOUT (at least 0.1 s), and faster than 50 Hz only loads the link.
const RATES_HZ: (f64, f64) = (2.0, 50.0);

impl std::str::FromStr for Spec {
    type Err = String;

    /// Parses `URL[?key=value&...]` (without the `ardusub:` prefix).
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = |reason: String| format!("ArduSub sink `{s}`: {reason}");
        let (url, query) = match s.split_once('?') {
            Some((u, q)) => (u, Some(q)),
            None => (s, None),
        };
        let (scheme, address) = url.split_once(':').ok_or_else(|| {
            bad("expected udpout:HOST:PORT, udpin:ADDR:PORT or tcpout:HOST:PORT".into())
        })?;
        let url = match scheme {
            "udpout" => Url::UdpOut(address.into()),
            "udpin" => Url::UdpIn(address.into()),
            "tcpout" => Url::TcpOut(address.into()),
            other => {
                return Err(bad(format!(
                    "unknown transport `{other}` (expected udpout, udpin or tcpout)"
                )));
            }
        };
        match address.rsplit_once(':') {
            Some((host, port)) if !host.is_empty() && port.parse::<u16>().is_ok_and(|p| p > 0) => {}
            _ => {
                return Err(bad(format!(
                    "`{address}` is not HOST:PORT with a port from 1 to 65535"
                )));
            }
        }
        let mut options = Options::default();
        let mut mode_named = false;
        for pair in query.unwrap_or("").split('&').filter(|p| !p.is_empty()) {
            let (key, value) = pair
                .split_once('=')
                .ok_or_else(|| bad(format!("option `{pair}` is not key=value")))?;
            let number = |what: &str| {
                value
                    .parse::<f64>()
                    .map_err(|_| bad(format!("{key}={value}: {what}")))
            };
            match key {
                "sysid" => {
                    options.system = match value.parse::<u8>() {
                        Ok(255) => {
                            return Err(bad(
                                "sysid=255 is the ground station's own system id: take another (254 by default) and add it to ArduSub's ground stations (MAV_GCS_SYSID, MAV_GCS_SYSID_HI)".into(),
                            ));
                        }
                        Ok(v) if v >= 1 => v,
                        _ => return Err(bad(format!("sysid={value}: expected 1 to 254"))),
                    }
                }
                "compid" => {
                    options.component = match value.parse::<u8>() {
                        Ok(v) if v >= 1 => v,
                        _ => return Err(bad(format!("compid={value}: expected 1 to 255"))),
                    }
                }
                "rate" => {
                    let r = number("expected messages per second")?;
                    if !(RATES_HZ.0..=RATES_HZ.1).contains(&r) {
                        return Err(bad(format!(
                            "rate={value}: expected {} to {} MANUAL_CONTROL per second",
                            RATES_HZ.0, RATES_HZ.1
                        )));
                    }
                    options.rate_hz = r;
                }
                "mode" => {
                    mode_named = true;
                    options.mode = match value {
                        "manual" => Mode::Manual,
                        "stabilize" => Mode::Stabilize,
                        "alt_hold" => Mode::AltHold,
                        _ => {
                            return Err(bad(format!(
                                "mode={value}: expected manual, stabilize or alt_hold"
                            )));
                        }
                    }
                }
                "arm" => {
                    options.arm = match value {
                        "auto" => Arming::Auto,
                        "manual" => Arming::Manual,
                        _ => return Err(bad(format!("arm={value}: expected auto or manual"))),
                    }
                }
                _ => {
                    return Err(bad(format!(
                        "unknown option `{key}` (expected sysid, compid, rate, mode, arm)"
                    )));
                }
            }
        }
        Ok(Spec {
            url,
            options,
            mode_named,
        })
    }
}

/// How long the companion waits, and how often it tries again.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timing {
    /// Our heartbeat's period (MAVLink's 1 Hz).
    pub heartbeat: Duration,
    /// The autopilot counts as lost after this long without its heartbeat (three of its periods).
    pub lost: Duration,
    /// How long to wait for the autopilot's first heartbeat.
    pub connect: Duration,
    /// A parameter unanswered for this long is asked again, up to `param_tries` times.
    pub param_retry: Duration,
    pub param_tries: u32,
    /// A command unacknowledged for this long is sent again, up to `command_tries` times.
    pub ack: Duration,
    pub command_tries: u32,
    /// After an accepted command, how long the autopilot's heartbeat may take to show its effect.
    pub confirm: Duration,
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            heartbeat: Duration::from_secs(1),
            lost: Duration::from_secs(3),
            connect: Duration::from_secs(10),
            param_retry: Duration::from_secs(1),
            param_tries: 3,
            ack: Duration::from_secs(1),
            command_tries: 5,
            confirm: Duration::from_secs(3),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pilot_section_sets_the_mode_and_fractions_and_a_contrary_mode_is_refused() {
        let pilot = config::PilotParams {
            mode: config::PilotMode::AltHold,
            fraction: config::PilotFractions {
                surge: 0.05,
                sway: 0.07,
                yaw: 0.2,
            },
            yaw_rate_time_constant_s: Some(0.05),
            autopilot: Default::default(),
        };
        let s: Spec = "udpout:127.0.0.1:14550".parse().unwrap();
        let s = s.with_pilot(&pilot).unwrap();
        assert_eq!(s.options.mode, Mode::AltHold);
        assert_eq!(s.options.fractions, Some(pilot.fraction));
        let same: Spec = "udpout:127.0.0.1:14550?mode=alt_hold".parse().unwrap();
        assert!(same.with_pilot(&pilot).is_ok());
        let other: Spec = "udpout:127.0.0.1:14550?mode=manual".parse().unwrap();
        let e = other.with_pilot(&pilot).unwrap_err();
        assert!(e.contains("mode=manual") && e.contains("alt_hold"), "{e}");
    }

    #[test]
    fn specs_parse_with_their_defaults_and_options() {
        let s: Spec = "udpout:192.168.2.2:14550".parse().unwrap();
        assert_eq!(s.url, Url::UdpOut("192.168.2.2:14550".into()));
        assert_eq!(s.options, Options::default());
        assert_eq!(s.options.period(), Duration::from_millis(50));
        let s: Spec = "tcpout:localhost:5777?sysid=200&compid=194&rate=25&mode=alt_hold&arm=manual"
            .parse()
            .unwrap();
        assert_eq!(s.url.to_string(), "tcpout:localhost:5777");
        assert_eq!(
            s.options,
            Options {
                system: 200,
                component: 194,
                rate_hz: 25.0,
                mode: Mode::AltHold,
                arm: Arming::Manual,
                fractions: None,
            }
        );
        assert_eq!(
            "udpin:0.0.0.0:14660".parse::<Spec>().unwrap().url,
            Url::UdpIn("0.0.0.0:14660".into())
        );
    }

    #[test]
    fn bad_specs_name_what_is_wrong() {
        let err = |s: &str| s.parse::<Spec>().unwrap_err();
        assert!(err("udpout:host").contains("HOST:PORT"));
        assert!(err("serial:/dev/ttyACM0:115200").contains("unknown transport `serial`"));
        assert!(err("udpout:h:0").contains("port from 1"));
        assert!(err("udpout:h:1?sysid=255").contains("ground station's own"));
        assert!(err("udpout:h:1?sysid=0").contains("sysid=0"));
        assert!(err("udpout:h:1?rate=200").contains("rate=200"));
        assert!(err("udpout:h:1?mode=acro").contains("mode=acro"));
        assert!(err("udpout:h:1?arm=yes").contains("arm=yes"));
        assert!(err("udpout:h:1?speed=3").contains("unknown option `speed`"));
        assert!(err("udpout:h:1?rate").contains("not key=value"));
    }
}
