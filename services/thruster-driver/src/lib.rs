//! The thruster driver's core: between the allocator's setpoint topic and the vehicle's thruster
//! sink (`adapters`), where a real vehicle has its failsafe. Plain state fed the vehicle clock (ns);
//! the `thruster-driver` binary binds it to the topic and wakes it on time.
//!
//! - The thrusters start at rest (a stop, cause `start`).
//! - Setpoints whose stamp the [`Screen`] accepts are written to the sink (each value under the rule
//!   for bad values) and are fresh until their step is the deadline old on the vehicle clock,
//!   counted from when the camera took it (not from when the setpoints arrived: the loop's delivery
//!   time is part of the step's age). The deadline is three sample periods by default
//!   ([`adapters::failsafe::deadline`]): one missed camera frame passes, the second stops the
//!   thrusters. A repeat of the step written last is not written again; a stale, older or absurd
//!   step is refused, so a late-joining driver never acts on old setpoints.
//! - The thrusters stop (every setpoint 0, marked with its cause) when the setpoints they hold go
//!   stale (`deadline`), when the allocator's process is gone (`allocator_dead`), and on shutdown
//!   (`shutdown`); each stop once, until fresh setpoints come again.

pub mod bench;

use adapters::failsafe::{Failsafe, Thrust};
use adapters::{AdapterError, Applied, StopCause, ThrusterSink};
use messages::ThrusterSetpoints;
use runtime::screen::{Refusal, Screen, ScreenLimits, Verdict};
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

/// The driver's screen of the setpoint topic at the scenario's `sample_time_s`: the control loop's
/// limits, with the failsafe deadline as the age limit, `deadline` if given, by default the rule of
/// [`adapters::failsafe::deadline`] (one missed frame passes, two stop the thrusters).
pub fn limits(sample_time_s: f64, deadline: Option<Duration>) -> ScreenLimits {
    let period = Duration::from_secs_f64(sample_time_s);
    ScreenLimits {
        max_age: deadline.unwrap_or_else(|| adapters::failsafe::deadline(period)),
        ..ScreenLimits::control(sample_time_s)
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
            Some(t) if self.on_own_clock(&msg.stamp, now_ns) => {
                t.min(self.failsafe.fresh_until(msg.stamp.clock_ns))
            }
            // A producer whose clock is behind: its age is read through its epoch's offset.
            Some(t) => t,
            None => self.failsafe.until_from(now_ns),
        };
        let applied = self.failsafe.apply(&msg.stamp, msg.as_slice(), until)?;
        self.screen.accept(&msg.stamp, now_ns);
        Ok(Taken::Written(applied))
    }

    /// Whether `stamp`'s clock reads as the driver's: taken no later than `now_ns` and less than
    /// the deadline before it. A clock so far behind that its age overflows is not.
    fn on_own_clock(&self, stamp: &messages::Stamp, now_ns: i64) -> bool {
        stamp.is_timed()
            && stamp.clock_ns <= now_ns
            && now_ns
                .checked_sub(stamp.clock_ns)
                .is_some_and(|age| age < self.deadline().as_nanos() as i64)
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

    const MS: i64 = 1_000_000;
    const T0: i64 = 7_200_000 * MS;

    fn driver() -> Driver<NullSink> {
        let mut d = Driver::new(
            NullSink::new(3).unwrap(),
            Screen::new("setpoints", limits(0.2, None)),
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
        assert_eq!(d.deadline(), Duration::from_millis(600));
        // Taken 1 ms before it arrives: fresh until the step is 600 ms old.
        let m = setpoints(1, T0, [0.5, 0.5, 0.1]);
        assert!(matches!(
            d.on_setpoints(&m, T0 + MS).unwrap(),
            Taken::Written(_)
        ));
        assert_eq!(d.on_setpoints(&m, T0 + 5 * MS).unwrap(), Taken::Repeat);
        assert_eq!(d.time_left(T0 + 100 * MS), Some(Duration::from_millis(500)));
        assert_eq!(d.on_time(T0 + 599 * MS).unwrap(), None);
        assert_eq!(d.on_time(T0 + 600 * MS).unwrap(), Some(StopCause::Deadline));
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

    /// Frame `k` of a 5 Hz camera: taken at T0 + k periods, its setpoints `[0.1 k; 3]`.
    fn frame(k: u32) -> ThrusterSetpoints {
        setpoints(
            u64::from(k) + 1,
            T0 + i64::from(k) * 200 * MS,
            [0.1 * f64::from(k); 3],
        )
    }

    /// Drives `d` through frames `0..=last` but `missed`, each frame's setpoints arriving `latency`
    /// after it was taken, the driver woken every millisecond: the stops made, with their times.
    fn run(d: &mut Driver<NullSink>, last: u32, missed: &[u32], latency: i64) -> Vec<i64> {
        let mut stops = Vec::new();
        let end = T0 + i64::from(last + 1) * 200 * MS;
        let mut k = 0;
        for now in (T0..end).step_by(MS as usize) {
            if k <= last && now == T0 + i64::from(k) * 200 * MS + latency {
                if !missed.contains(&k) {
                    assert!(
                        matches!(d.on_setpoints(&frame(k), now).unwrap(), Taken::Written(_)),
                        "frame {k}"
                    );
                }
                k += 1;
            }
            if d.on_time(now).unwrap().is_some() {
                stops.push(now);
            }
        }
        stops
    }

    #[test]
    fn one_missed_frame_keeps_the_thrusters_driven_and_the_second_stops_them() {
        // Camera to thrusters in 1 ms (the vehicle's p50) and in 150 ms (far slower than any seen):
        // the rule does not depend on it within the period.
        for latency in [MS, 150 * MS] {
            let mut d = driver();
            let stops = run(&mut d, 9, &[3], latency);
            assert_eq!(
                stops,
                Vec::<i64>::new(),
                "one missed frame stopped the thrusters"
            );
            assert_eq!(d.sink().written(), 9);
            assert_eq!(d.sink().stops(), 1, "the start's alone");
            assert!(matches!(d.thrust(), Thrust::Driven { .. }));

            // Frames 3 and 4 missed: stopped three periods after frame 2 was taken, before frame 5's
            // setpoints arrive; frame 5 drives again.
            let mut d = driver();
            let stops = run(&mut d, 9, &[3, 4], latency);
            assert_eq!(stops, [T0 + (2 + 3) * 200 * MS], "latency {latency}");
            assert!(stops[0] < T0 + 5 * 200 * MS + latency);
            assert_eq!(d.sink().written(), 8);
            assert!(matches!(d.thrust(), Thrust::Driven { .. }));
        }
    }

    #[test]
    fn a_deadline_given_replaces_the_rule() {
        let mut d = Driver::new(
            NullSink::new(3).unwrap(),
            Screen::new("setpoints", limits(0.2, Some(Duration::from_millis(400)))),
        );
        d.start().unwrap();
        // At 400 ms the dropped frame's gap stops the thrusters until the next setpoints come.
        let stops = run(&mut d, 5, &[3], 2 * MS);
        assert_eq!(stops, [T0 + (2 * 200 + 400) * MS]);
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
        assert_eq!(d.on_time(T0 + 804 * MS).unwrap(), None);
        assert_eq!(d.on_time(T0 + 805 * MS).unwrap(), Some(StopCause::Deadline));
    }

    /// The fuzzer's find (target `shm_setpoints`, a stamp's clock at i64::MIN + 16): a clock so
    /// far behind that its age overflows an i64 read as the driver's own (a panic where overflow
    /// is checked), and its steps went stale as they arrived.
    #[test]
    fn a_step_from_a_clock_behind_by_more_than_an_i64_is_fresh_for_the_deadline_after_it_arrives() {
        let mut d = driver();
        let behind = i64::MIN + 16;
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
        assert_eq!(d.on_time(T0 + 804 * MS).unwrap(), None);
        assert_eq!(d.on_time(T0 + 805 * MS).unwrap(), Some(StopCause::Deadline));
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
