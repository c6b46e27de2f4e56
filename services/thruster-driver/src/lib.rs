//! The thruster driver's core: between the allocator's setpoint topic and the vehicle's thruster
//! sink (`adapters`), where a real vehicle has its failsafe. Plain state fed the vehicle clock (ns);
//! the `thruster-driver` binary binds it to the topic and wakes it on time.
//!
//! - The thrusters start at rest (a stop, cause `start`).
//! - Setpoints whose stamp the [`Screen`] accepts are written to the sink (each value under the rule
//!   for bad values) and are fresh until their step is the deadline old (two sample periods by
//!   default) on the vehicle clock, counted from when the camera took it (not from when the
//!   setpoints arrived: the loop's delivery time is part of the step's age); a repeat of the step written last is not written again; a
//!   stale, older or absurd step is refused, so a late-joining driver never acts on old setpoints.
//! - The thrusters stop (every setpoint 0, marked with its cause) when the setpoints they hold go
//!   stale (`deadline`), when the allocator's process is gone (`allocator_dead`), and on shutdown
//!   (`shutdown`); each stop once, until fresh setpoints come again.

use adapters::failsafe::{Failsafe, Thrust};
use adapters::{AdapterError, Applied, StopCause, ThrusterSink};
use messages::ThrusterSetpoints;
use runtime::screen::{Refusal, Screen, Verdict};
use std::time::{Duration, Instant};

/// Which thruster sink the driver owns.
#[derive(Clone, Debug, PartialEq)]
pub enum SinkSpec {
    /// The vehicle twin's thrusters (`cabletrack/twin/thrusters`).
    Twin,
    /// A record file of every setpoint and stop with its times (a dry run: nothing moves).
    Record(std::path::PathBuf),
    /// Nothing (the checks and the failsafe still run).
    Null,
    /// A vehicle under ArduSub, piloted over MAVLink (`ardusub:URL?OPTIONS`, see the `ardusub`
    /// crate).
    ArduSub(Box<ardusub::Spec>),
}

impl std::str::FromStr for SinkSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "twin" => Ok(SinkSpec::Twin),
            "null" => Ok(SinkSpec::Null),
            _ => match (s.strip_prefix("record:"), s.strip_prefix("ardusub:")) {
                (Some(file), _) if !file.is_empty() => Ok(SinkSpec::Record(file.into())),
                (_, Some(spec)) => Ok(SinkSpec::ArduSub(Box::new(spec.parse()?))),
                _ => Err(format!(
                    "unknown thruster sink `{s}` (expected `twin`, `record:FILE`, `ardusub:URL` or `null`)"
                )),
            },
        }
    }
}

/// What the driver did with one message of the setpoint topic.
#[derive(Clone, Debug, PartialEq)]
pub enum Taken {
    /// Written to the thrusters.
    Written(Applied),
    /// The step written last, again: nothing to do.
    Repeat,
    /// Refused: its stamp (counted and logged by the screen), or it is not a step's answer.
    Refused(Option<Refusal>),
}

/// The thruster driver's core.
pub struct Driver<S: ThrusterSink> {
    screen: Screen,
    failsafe: Failsafe<S>,
}

impl<S: ThrusterSink> Driver<S> {
    /// The driver of `sink`, judging setpoints with `screen` (whose `max_age` is the deadline).
    pub fn new(sink: S, screen: Screen) -> Self {
        let deadline = screen.limits().max_age;
        Driver {
            screen,
            failsafe: Failsafe::new(sink, deadline),
        }
    }

    /// The thrusters begin at rest.
    pub fn start(&mut self) -> Result<(), AdapterError> {
        self.failsafe.start()
    }

    pub fn deadline(&self) -> Duration {
        self.failsafe.deadline()
    }

    pub fn thrust(&self) -> Thrust {
        self.failsafe.thrust()
    }

    pub fn sink(&self) -> &S {
        self.failsafe.sink()
    }

    /// Stamps refused so far.
    pub fn refused(&self) -> u64 {
        self.screen.refused()
    }

    /// Setpoints arrived at `now_ns`.
    pub fn on_setpoints(
        &mut self,
        msg: &ThrusterSetpoints,
        now_ns: i64,
    ) -> Result<Taken, AdapterError> {
        if msg.stop != 0 {
            // Only the driver stops the thrusters: the allocator's topic carries answers.
            return Ok(Taken::Refused(None));
        }
        match self.screen.check(&msg.stamp, now_ns) {
            Verdict::Refused(r) => return Ok(Taken::Refused(Some(r))),
            Verdict::Repeat => return Ok(Taken::Repeat),
            Verdict::New => {}
        }
        let until = match self.screen.fresh_until_if_accepted(&msg.stamp, now_ns) {
            // Taken on the driver's own clock (not older than the deadline on it): stale once the
            // step is the deadline old, not later by the loop's delivery time.
            Some(t) if self.on_own_clock(&msg.stamp, now_ns) => t.min(
                msg.stamp
                    .clock_ns
                    .saturating_add(self.deadline().as_nanos() as i64),
            ),
            // A producer whose clock is behind: its age is read through its epoch's offset.
            Some(t) => t,
            None => self.failsafe.until_from(now_ns),
        };
        let applied = self.failsafe.apply(&msg.stamp, msg.as_slice(), until)?;
        self.screen.accept(&msg.stamp, now_ns);
        Ok(Taken::Written(applied))
    }

    /// Whether `stamp`'s clock reads as the driver's: taken no later than `now_ns` and less than
    /// the deadline before it.
    fn on_own_clock(&self, stamp: &messages::Stamp, now_ns: i64) -> bool {
        stamp.is_timed()
            && stamp.clock_ns <= now_ns
            && now_ns - stamp.clock_ns < self.deadline().as_nanos() as i64
    }

    /// The sink's periodic work (a link's heartbeat, a command held at its rate), done now;
    /// returns when it wants to be serviced next.
    pub fn service(&mut self, now: Instant) -> Result<Option<Instant>, AdapterError> {
        self.failsafe.sink_mut().service(now)
    }

    /// Time passed: the stop made now if the setpoints held went stale.
    pub fn on_time(&mut self, now_ns: i64) -> Result<Option<StopCause>, AdapterError> {
        self.failsafe.on_time(now_ns)
    }

    /// How long until the setpoints held go stale (`None` while stopped).
    pub fn time_left(&self, now_ns: i64) -> Option<Duration> {
        self.failsafe.time_left(now_ns)
    }

    /// The allocator's process is gone: stops the thrusters; `true` if a stop was made now.
    pub fn allocator_gone(&mut self) -> Result<bool, AdapterError> {
        self.failsafe.stop(StopCause::AllocatorDead)
    }

    /// Shutdown: stops the thrusters (if they are not) and closes the sink.
    pub fn shutdown(&mut self) -> Result<(), AdapterError> {
        self.failsafe.close()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use adapters::record::NullSink;
    use messages::{Stamp, StepStatus};
    use runtime::screen::ScreenLimits;

    const MS: i64 = 1_000_000;
    const T0: i64 = 7_200_000 * MS;

    fn driver() -> Driver<NullSink> {
        let mut d = Driver::new(
            NullSink::new(3).unwrap(),
            Screen::new("setpoints", ScreenLimits::control(0.2)),
        );
        d.start().unwrap();
        d
    }

    fn setpoints(seq: u64, clock_ns: i64, values: [f64; 3]) -> ThrusterSetpoints {
        let mut m = ThrusterSetpoints {
            stamp: Stamp::new(seq, 0, 0, seq as u32, StepStatus::Running).timed(5, clock_ns),
            count: 3,
            ..Default::default()
        };
        m.values[..3].copy_from_slice(&values);
        m
    }

    #[test]
    fn fresh_setpoints_drive_and_stale_ones_stop_the_thrusters() {
        let mut d = driver();
        assert_eq!(d.thrust(), Thrust::Stopped(StopCause::Start));
        assert_eq!(d.deadline(), Duration::from_millis(400));
        // Taken 1 ms before it arrives: fresh until the step is 400 ms old.
        let m = setpoints(1, T0, [0.5, 0.5, 0.1]);
        assert!(matches!(
            d.on_setpoints(&m, T0 + MS).unwrap(),
            Taken::Written(_)
        ));
        assert_eq!(d.on_setpoints(&m, T0 + 5 * MS).unwrap(), Taken::Repeat);
        assert_eq!(d.time_left(T0 + 100 * MS), Some(Duration::from_millis(300)));
        assert_eq!(d.on_time(T0 + 399 * MS).unwrap(), None);
        assert_eq!(d.on_time(T0 + 400 * MS).unwrap(), Some(StopCause::Deadline));
        assert_eq!(d.thrust(), Thrust::Stopped(StopCause::Deadline));
        assert_eq!(d.sink().stops(), 2);
        // A stale step after the stop is refused; a fresh one drives again.
        let late = setpoints(2, T0 + 200 * MS, [0.9; 3]);
        assert!(matches!(
            d.on_setpoints(&late, T0 + 900 * MS).unwrap(),
            Taken::Refused(Some(Refusal::TooOld { .. }))
        ));
        let fresh = setpoints(5, T0 + 1000 * MS, [0.2; 3]);
        assert!(matches!(
            d.on_setpoints(&fresh, T0 + 1001 * MS).unwrap(),
            Taken::Written(_)
        ));
        assert_eq!(d.sink().written(), 2);
    }

    #[test]
    fn a_step_from_a_clock_an_hour_behind_is_fresh_for_the_deadline_after_it_arrives() {
        let mut d = driver();
        let behind = T0 - 3_600_000 * MS;
        // Its first step cannot be judged; its second, at its pace, drives.
        let first = setpoints(1, behind, [0.1; 3]);
        assert!(matches!(
            d.on_setpoints(&first, T0 + 5 * MS).unwrap(),
            Taken::Refused(Some(_))
        ));
        let second = setpoints(2, behind + 200 * MS, [0.2; 3]);
        assert!(matches!(
            d.on_setpoints(&second, T0 + 205 * MS).unwrap(),
            Taken::Written(_)
        ));
        assert_eq!(d.on_time(T0 + 604 * MS).unwrap(), None);
        assert_eq!(d.on_time(T0 + 605 * MS).unwrap(), Some(StopCause::Deadline));
    }

    #[test]
    fn the_allocators_death_and_shutdown_stop_the_thrusters_once() {
        let mut d = driver();
        let m = setpoints(1, T0, [0.5, 0.5, 0.1]);
        d.on_setpoints(&m, T0 + MS).unwrap();
        assert!(d.allocator_gone().unwrap());
        assert!(!d.allocator_gone().unwrap(), "stopped already");
        assert_eq!(d.thrust(), Thrust::Stopped(StopCause::AllocatorDead));
        assert_eq!(d.on_time(T0 + 1000 * MS).unwrap(), None);
        d.on_setpoints(&setpoints(2, T0 + 200 * MS, [0.1; 3]), T0 + 201 * MS)
            .unwrap();
        d.shutdown().unwrap();
        assert_eq!(d.sink().stops(), 3);
    }

    #[test]
    fn bad_values_are_made_safe_and_stops_on_the_topic_refused() {
        let mut d = driver();
        let m = setpoints(1, T0, [f64::NAN, 7.0, -0.3]);
        match d.on_setpoints(&m, T0 + MS).unwrap() {
            Taken::Written(a) => {
                assert_eq!(a.as_slice(), [0.0, 1.0, -0.3]);
                assert_eq!((a.fixes.non_finite, a.fixes.clamped), (1, 1));
            }
            other => panic!("{other:?}"),
        }
        let mut stop = setpoints(2, T0 + 200 * MS, [0.0; 3]);
        stop.stop = StopCause::Deadline as u32;
        assert_eq!(
            d.on_setpoints(&stop, T0 + 201 * MS).unwrap(),
            Taken::Refused(None)
        );
        // A wrong count is the sink's error, and nothing is written.
        let mut short = setpoints(3, T0 + 400 * MS, [0.1; 3]);
        short.count = 2;
        assert!(d.on_setpoints(&short, T0 + 401 * MS).is_err());
        assert_eq!(d.sink().written(), 1);
    }

    #[test]
    fn sinks_parse() {
        assert_eq!("twin".parse(), Ok(SinkSpec::Twin));
        assert_eq!("null".parse(), Ok(SinkSpec::Null));
        assert_eq!(
            "record:/tmp/x.csv".parse(),
            Ok(SinkSpec::Record("/tmp/x.csv".into()))
        );
        assert!("record:".parse::<SinkSpec>().is_err());
        assert!("can0".parse::<SinkSpec>().is_err());
        match "ardusub:udpout:192.168.2.2:14550?rate=25".parse() {
            Ok(SinkSpec::ArduSub(spec)) => {
                assert_eq!(spec.url, ardusub::Url::UdpOut("192.168.2.2:14550".into()));
                assert_eq!(spec.options.rate_hz, 25.0);
            }
            other => panic!("{other:?}"),
        }
        let bad = "ardusub:udpout:192.168.2.2:14550?sysid=255".parse::<SinkSpec>();
        assert!(bad.is_err_and(|e| e.contains("sysid=255")));
    }
}
