//! ArduSub's parameters the companion reads before it arms, and what they must be.
//!
//! - Whose MANUAL_CONTROL ArduSub obeys: its ground stations' system ids. ArduSub 4.7 names a range,
//!   `MAV_GCS_SYSID` to `MAV_GCS_SYSID_HI` (just `MAV_GCS_SYSID` when `MAV_GCS_SYSID_HI` is not above
//!   it, as by default: 255 and 0); before 4.7 there was one id, `SYSID_MYGCS`. Both names are asked
//!   at once; the newer answer wins.
//! - Its pilot-input failsafe, `FS_PILOT_INPUT` (0 off, 1 warn and neutral controls, 2 disarm), after
//!   `FS_PILOT_TIMEOUT` seconds without MANUAL_CONTROL: the vehicle's own stop when this driver stops
//!   sending, so it must be on.
//! - The pilot gain, which scales every MANUAL_CONTROL axis: ArduSub starts with `JS_GAIN_DEFAULT`
//!   held within `JS_GAIN_MIN`..`JS_GAIN_MAX` (or, when it lies outside, a setting between them
//!   counted in `JS_GAIN_STEPS`), and within 0.1..1.
//! - `ACRO_YAW_P`, by which MANUAL mode scales the yaw axis (relative to its default 4.5).
//!
//! ArduSub answers a PARAM_REQUEST_READ for a name it does not have with nothing: a request
//! unanswered is asked again, a few times, then taken as absent.

use crate::spec::Options;
use std::time::{Duration, Instant};

pub const GCS_SYSID: &str = "MAV_GCS_SYSID";
pub const GCS_SYSID_HI: &str = "MAV_GCS_SYSID_HI";
pub const MYGCS: &str = "SYSID_MYGCS";
pub const PILOT_INPUT: &str = "FS_PILOT_INPUT";
pub const PILOT_TIMEOUT: &str = "FS_PILOT_TIMEOUT";
pub const GAIN_DEFAULT: &str = "JS_GAIN_DEFAULT";
pub const GAIN_MIN: &str = "JS_GAIN_MIN";
pub const GAIN_MAX: &str = "JS_GAIN_MAX";
pub const GAIN_STEPS: &str = "JS_GAIN_STEPS";
pub const YAW_P: &str = "ACRO_YAW_P";

/// Every parameter read, in the order asked.
pub const READ: [&str; 10] = [
    GCS_SYSID,
    GCS_SYSID_HI,
    MYGCS,
    PILOT_INPUT,
    PILOT_TIMEOUT,
    GAIN_DEFAULT,
    GAIN_MIN,
    GAIN_MAX,
    GAIN_STEPS,
    YAW_P,
];

/// ACRO_YAW_P's default: MANUAL mode scales the yaw axis by ACRO_YAW_P / 4.5.
pub const YAW_P_DEFAULT: f64 = 4.5;

struct Item {
    name: &'static str,
    value: Option<f32>,
    tries: u32,
    /// When the last request is given up (and the next one sent, if any are left).
    next: Option<Instant>,
}

/// Reads [`READ`] with retries.
pub struct Reader {
    items: Vec<Item>,
    retry: Duration,
    tries: u32,
}

impl Reader {
    pub fn new(retry: Duration, tries: u32) -> Self {
        Reader {
            items: READ
                .iter()
                .map(|&name| Item {
                    name,
                    value: None,
                    tries: 0,
                    next: None,
                })
                .collect(),
            retry,
            tries,
        }
    }

    fn item(&self, name: &str) -> Option<&Item> {
        self.items.iter().find(|i| i.name == name)
    }

    /// The value read for `name`.
    pub fn value(&self, name: &str) -> Option<f32> {
        self.item(name).and_then(|i| i.value)
    }

    fn answered(&self, names: &[&str]) -> bool {
        names.iter().all(|n| self.value(n).is_some())
    }

    /// Whether a parameter no longer needs an answer: one naming the same thing answered under
    /// the other name.
    fn superseded(&self, name: &str) -> bool {
        match name {
            MYGCS => self.answered(&[GCS_SYSID, GCS_SYSID_HI]),
            GCS_SYSID | GCS_SYSID_HI => self.answered(&[MYGCS]),
            _ => false,
        }
    }

    /// The names to request now: first asks, and asks again of those unanswered for the retry time.
    pub fn due(&mut self, now: Instant) -> Vec<&'static str> {
        let mut out = Vec::new();
        for k in 0..self.items.len() {
            let name = self.items[k].name;
            if self.superseded(name) {
                continue;
            }
            let (retry, tries) = (self.retry, self.tries);
            let item = &mut self.items[k];
            if item.value.is_none() && item.tries < tries && item.next.is_none_or(|t| now >= t) {
                item.tries += 1;
                item.next = Some(now + retry);
                out.push(name);
            }
        }
        out
    }

    /// A PARAM_VALUE from the autopilot (names it did not ask for are ignored).
    pub fn on_value(&mut self, name: &str, value: f32) {
        if let Some(item) = self.items.iter_mut().find(|i| i.name == name) {
            item.value = Some(value);
        }
    }

    fn settled(&self, item: &Item, now: Instant) -> bool {
        item.value.is_some()
            || self.superseded(item.name)
            || (item.tries >= self.tries && item.next.is_some_and(|t| now >= t))
    }

    /// Whether every parameter is answered or given up.
    pub fn done(&self, now: Instant) -> bool {
        self.items.iter().all(|i| self.settled(i, now))
    }

    /// When an answer is given up next (to wake then).
    pub fn next_deadline(&self) -> Option<Instant> {
        self.items
            .iter()
            .filter(|i| i.value.is_none())
            .filter_map(|i| i.next)
            .min()
    }

    /// What was read, once [`Reader::done`].
    pub fn settings(&self) -> Result<Settings, Unanswered> {
        let missing: Vec<&str> = [
            PILOT_INPUT,
            PILOT_TIMEOUT,
            GAIN_DEFAULT,
            GAIN_MIN,
            GAIN_MAX,
            GAIN_STEPS,
        ]
        .into_iter()
        .filter(|n| self.value(n).is_none())
        .collect();
        let ground = match (
            self.value(GCS_SYSID),
            self.value(GCS_SYSID_HI),
            self.value(MYGCS),
        ) {
            (Some(lo), Some(hi), _) => Some(GroundStations::Range {
                lo: id(lo),
                hi: id(hi),
            }),
            (_, _, Some(one)) => Some(GroundStations::Single(id(one))),
            _ => None,
        };
        let Some(ground) = ground.filter(|_| missing.is_empty()) else {
            let mut names: Vec<String> = missing.iter().map(|s| s.to_string()).collect();
            if ground.is_none() {
                names.push(format!("{GCS_SYSID} and {GCS_SYSID_HI} (or {MYGCS})"));
            }
            return Err(Unanswered {
                names: names.join(", "),
                tries: self.tries,
            });
        };
        let v = |n| self.value(n).map(f64::from).unwrap_or(f64::NAN);
        Ok(Settings {
            ground,
            pilot_input: v(PILOT_INPUT).round() as i32,
            pilot_timeout_s: v(PILOT_TIMEOUT),
            gain: Gain {
                default: v(GAIN_DEFAULT),
                min: v(GAIN_MIN),
                max: v(GAIN_MAX),
                steps: v(GAIN_STEPS).round() as i32,
            },
            yaw_p: self.value(YAW_P).map(f64::from),
        })
    }
}

/// A system id read as a float parameter (ArduPilot sends integers as their float value).
fn id(v: f32) -> u8 {
    v.round().clamp(0.0, 255.0) as u8
}

/// Parameters the autopilot never answered.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error(
    "ArduSub did not answer PARAM_REQUEST_READ for {names} ({tries} tries each): is it ArduSub, and this driver's system id allowed to read?"
)]
pub struct Unanswered {
    pub names: String,
    pub tries: u32,
}

/// Whose MANUAL_CONTROL ArduSub obeys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GroundStations {
    /// ArduSub 4.7: `MAV_GCS_SYSID`..`MAV_GCS_SYSID_HI`, or `MAV_GCS_SYSID` alone when the high end
    /// is not above it.
    Range { lo: u8, hi: u8 },
    /// Before 4.7: `SYSID_MYGCS`.
    Single(u8),
}

impl GroundStations {
    /// The ids obeyed, lowest to highest.
    fn span(&self) -> (u8, u8) {
        match *self {
            GroundStations::Range { lo, hi } if hi > lo => (lo, hi),
            GroundStations::Range { lo, .. } => (lo, lo),
            GroundStations::Single(id) => (id, id),
        }
    }

    pub fn accepts(&self, system: u8) -> bool {
        let (lo, hi) = self.span();
        (lo..=hi).contains(&system)
    }

    /// Why `system` is not obeyed and what to set, or `None` when it is.
    pub fn refusal(&self, system: u8) -> Option<String> {
        if self.accepts(system) {
            return None;
        }
        let (lo, hi) = self.span();
        let now = if lo == hi {
            format!("{lo} only")
        } else {
            format!("{lo} to {hi}")
        };
        Some(match *self {
            GroundStations::Range {
                lo: set_lo,
                hi: set_hi,
            } => {
                // Widen the range to take this driver in, keeping the ground stations obeyed now.
                let (want_lo, want_hi) = (lo.min(system), hi.max(system));
                let mut set = Vec::new();
                if want_lo != set_lo {
                    set.push(format!("{GCS_SYSID} to {want_lo}"));
                }
                if want_hi != set_hi {
                    set.push(format!("{GCS_SYSID_HI} to {want_hi}"));
                }
                format!(
                    "ArduSub ignores MANUAL_CONTROL from system {system}: it obeys ground stations {now} ({GCS_SYSID} = {set_lo}, {GCS_SYSID_HI} = {set_hi}): set {}",
                    set.join(" and ")
                )
            }
            GroundStations::Single(id) => format!(
                "ArduSub ignores MANUAL_CONTROL from system {system}: it obeys ground station {id} only ({MYGCS} = {id}): set {MYGCS} to {system} (a ground station's joystick is then ignored), or update ArduSub to 4.7, whose {GCS_SYSID} and {GCS_SYSID_HI} take a range"
            ),
        })
    }
}

impl std::fmt::Display for GroundStations {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            GroundStations::Range { lo, hi } => {
                write!(f, "{GCS_SYSID} = {lo}, {GCS_SYSID_HI} = {hi}")
            }
            GroundStations::Single(id) => write!(f, "{MYGCS} = {id}"),
        }
    }
}

/// ArduSub's pilot gain settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gain {
    pub default: f64,
    pub min: f64,
    pub max: f64,
    pub steps: i32,
}

impl Gain {
    /// The gain ArduSub starts with (its `init_joystick`): the default held within min..max when it
    /// lies there (within 0.01) or when there is one step, else the step below the middle; always
    /// within 0.1..1.
    pub fn at_boot(&self) -> f64 {
        let steps = self.steps.max(1);
        let gain =
            if steps == 1 || (self.default < self.max + 0.01 && self.default > self.min - 0.01) {
                self.default.max(self.min).min(self.max)
            } else {
                self.min + f64::from(steps / 2 - 1) * (self.max - self.min) / f64::from(steps - 1)
            };
        gain.clamp(0.1, 1.0)
    }
}

/// What was read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    pub ground: GroundStations,
    pub pilot_input: i32,
    pub pilot_timeout_s: f64,
    pub gain: Gain,
    /// `None` where ArduSub has no ACRO_YAW_P.
    pub yaw_p: Option<f64>,
}

impl Settings {
    /// Why the companion must not pilot with these settings (the parameter, its value and what to
    /// set), or `None`.
    pub fn refusal(&self, options: &Options) -> Option<String> {
        if let Some(r) = self.ground.refusal(options.system) {
            return Some(r);
        }
        if self.pilot_input == 0 {
            return Some(format!(
                "ArduSub's pilot-input failsafe is off ({PILOT_INPUT} = 0): nothing would stop the vehicle if this driver stopped sending: set {PILOT_INPUT} to 2 (disarm) or 1 (warn and neutral controls)"
            ));
        }
        let period = options.period().as_secs_f64();
        if self.pilot_timeout_s < 2.0 * period {
            return Some(format!(
                "ArduSub's pilot-input failsafe would trip between two MANUAL_CONTROL ({PILOT_TIMEOUT} = {} s, one every {:.3} s): set {PILOT_TIMEOUT} to {:.1} s or more (3 by default), or raise the rate",
                self.pilot_timeout_s,
                period,
                (4.0 * period).max(0.1)
            ));
        }
        None
    }
}

impl std::fmt::Display for Settings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}, {PILOT_INPUT} = {}, {PILOT_TIMEOUT} = {} s, pilot gain {} ({GAIN_DEFAULT} = {}, {GAIN_MIN} = {}, {GAIN_MAX} = {}, {GAIN_STEPS} = {}), {YAW_P} = {}",
            self.ground,
            self.pilot_input,
            self.pilot_timeout_s,
            self.gain.at_boot(),
            self.gain.default,
            self.gain.min,
            self.gain.max,
            self.gain.steps,
            self.yaw_p.map_or("absent".to_string(), |v| v.to_string())
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: Duration = Duration::from_secs(1);

    fn answer(r: &mut Reader, table: &[(&str, f32)]) {
        for (n, v) in table {
            r.on_value(n, *v);
        }
    }

    const ARDUSUB_47: [(&str, f32); 9] = [
        (GCS_SYSID, 250.0),
        (GCS_SYSID_HI, 255.0),
        (PILOT_INPUT, 2.0),
        (PILOT_TIMEOUT, 3.0),
        (GAIN_DEFAULT, 0.5),
        (GAIN_MIN, 0.25),
        (GAIN_MAX, 1.0),
        (GAIN_STEPS, 4.0),
        (YAW_P, 4.5),
    ];

    #[test]
    fn the_47_names_settle_at_once_and_the_old_one_is_not_waited_for() {
        let t0 = Instant::now();
        let mut r = Reader::new(S, 3);
        assert_eq!(r.due(t0), READ.to_vec(), "all asked at once");
        assert_eq!(
            r.due(t0),
            Vec::<&str>::new(),
            "not again before the retry time"
        );
        answer(&mut r, &ARDUSUB_47);
        assert!(r.done(t0), "SYSID_MYGCS is superseded");
        let s = r.settings().unwrap();
        assert_eq!(s.ground, GroundStations::Range { lo: 250, hi: 255 });
        assert!(s.ground.accepts(254) && s.ground.accepts(255) && !s.ground.accepts(249));
        assert_eq!(s.gain.at_boot(), 0.5);
        assert_eq!(s.refusal(&Options::default()), None);
    }

    #[test]
    fn before_47_the_single_id_is_used_and_unanswered_names_are_asked_again_then_given_up() {
        let t0 = Instant::now();
        let mut r = Reader::new(S, 3);
        r.due(t0);
        answer(
            &mut r,
            &[
                (MYGCS, 255.0),
                (PILOT_INPUT, 1.0),
                (PILOT_TIMEOUT, 3.0),
                (GAIN_DEFAULT, 0.5),
                (GAIN_MIN, 0.25),
                (GAIN_MAX, 1.0),
                (GAIN_STEPS, 4.0),
            ],
        );
        // The 4.7 names are superseded; ACRO_YAW_P is asked again until given up.
        assert_eq!(r.due(t0 + S), vec![YAW_P]);
        assert!(!r.done(t0 + S));
        assert_eq!(r.due(t0 + 2 * S), vec![YAW_P]);
        assert_eq!(r.due(t0 + 3 * S), Vec::<&str>::new(), "three tries");
        assert!(!r.done(t0 + 3 * S - Duration::from_millis(1)));
        assert!(r.done(t0 + 3 * S));
        let s = r.settings().unwrap();
        assert_eq!(s.ground, GroundStations::Single(255));
        assert_eq!(s.yaw_p, None);
        let refusal = s.refusal(&Options::default()).unwrap();
        assert!(
            refusal.contains("system 254") && refusal.contains("set SYSID_MYGCS to 254"),
            "{refusal}"
        );
    }

    #[test]
    fn a_silent_autopilot_is_named_with_what_it_did_not_answer() {
        let t0 = Instant::now();
        let mut r = Reader::new(S, 2);
        r.due(t0);
        r.due(t0 + S);
        assert!(r.done(t0 + 2 * S));
        let e = r.settings().unwrap_err();
        assert!(
            e.to_string().contains("FS_PILOT_INPUT") && e.to_string().contains("SYSID_MYGCS"),
            "{e}"
        );
    }

    #[test]
    fn refusals_name_the_parameter_and_the_value_to_set() {
        let ok = Settings {
            ground: GroundStations::Range { lo: 255, hi: 0 },
            pilot_input: 2,
            pilot_timeout_s: 3.0,
            gain: Gain {
                default: 1.0,
                min: 0.25,
                max: 1.0,
                steps: 4,
            },
            yaw_p: Some(4.5),
        };
        let o = Options::default();
        // ArduSub's defaults: ground station 255 only.
        let r = ok.refusal(&o).unwrap();
        assert!(
            r.contains("255 only")
                && r.contains("set MAV_GCS_SYSID to 254 and MAV_GCS_SYSID_HI to 255"),
            "{r}"
        );
        // A range below us: only its high end moves.
        let below = Settings {
            ground: GroundStations::Range { lo: 1, hi: 200 },
            ..ok
        };
        let r = below.refusal(&o).unwrap();
        assert!(
            r.contains("1 to 200") && r.ends_with("set MAV_GCS_SYSID_HI to 254"),
            "{r}"
        );
        let covered = Settings {
            ground: GroundStations::Range { lo: 254, hi: 255 },
            ..ok
        };
        assert_eq!(covered.refusal(&o), None);
        let off = Settings {
            pilot_input: 0,
            ..covered
        };
        let r = off.refusal(&o).unwrap();
        assert!(
            r.contains("FS_PILOT_INPUT = 0") && r.contains("set FS_PILOT_INPUT to 2"),
            "{r}"
        );
        let hasty = Settings {
            pilot_timeout_s: 0.08,
            ..covered
        };
        let r = hasty.refusal(&o).unwrap();
        assert!(r.contains("FS_PILOT_TIMEOUT = 0.08"), "{r}");
    }

    #[test]
    fn the_boot_gain_follows_ardusub() {
        let g = |default, min, max, steps| {
            Gain {
                default,
                min,
                max,
                steps,
            }
            .at_boot()
        };
        assert_eq!(g(0.5, 0.25, 1.0, 4), 0.5);
        assert_eq!(g(1.0, 0.25, 1.0, 4), 1.0);
        // Outside min..max with several steps: the step below the middle, min + (4/2 - 1) * 0.75/3.
        assert_eq!(g(0.1, 0.25, 1.0, 4), 0.5);
        // One step: the default, held within min..max.
        assert_eq!(g(0.1, 0.25, 1.0, 1), 0.25);
        // Never above 1 (JS_GAIN_MAX may be set higher).
        assert_eq!(g(2.0, 0.25, 2.0, 4), 1.0);
    }
}
