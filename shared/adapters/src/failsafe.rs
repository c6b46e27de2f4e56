//! The failsafe between the allocator's setpoints and a [`ThrusterSink`]: the thrusters start at
//! rest, take fresh setpoints, and stop (every setpoint 0, marked as a stop with its cause) when the
//! setpoints they hold are no longer fresh, when asked to (shutdown, the allocator's death), and
//! when closed. A plain state machine fed the vehicle clock (ns): the `thruster-driver` binary
//! wakes it on time; the conformance suite drives it over every sink with a clock of its own.
//!
//! Freshness: setpoints are valid until the time given with them (the driver gives the step's age
//! limit on its clock, [`Failsafe::fresh_until`], or arrival plus the deadline for untimed stamps).
//! Once that passes without newer ones, [`Failsafe::on_time`] stops the thrusters, once, until
//! setpoints come again.
//!
//! The deadline's rule ([`deadline`]): a step's setpoints stay valid through one missed camera frame
//! and stop at the second, whatever the sink (the twin's thrusters on shared memory, ArduSub over
//! MAVLink: both are driven through this failsafe).

use crate::{AdapterError, Applied, Stamp, StopCause, ThrusterSink};
use std::time::Duration;

/// Camera frames in a row that may go missing while the thrusters keep the setpoints of the step
/// before them. A camera drops a frame now and then (the twin 3% of them): one such frame must not
/// stop the vehicle. The next one missing stops it.
pub const MISSED_FRAMES: u32 = 1;

/// The failsafe deadline at the camera's sample period: how old a step's setpoints may get, counted
/// from when the camera took its frame, before the thrusters stop. Three periods: the step's own,
/// one per frame that may be missed ([`MISSED_FRAMES`]), and one of slack for the processing time.
///
/// The slack is a whole period because that is what the loop has to answer a frame before the next
/// one comes (camera to thrusters takes milliseconds, benchmarks.md): with one frame missed the next
/// step's setpoints arrive two periods plus that latency after the step, inside the deadline, and
/// the thrusters never pause. With two missed, they stop at three periods, before a third frame's
/// setpoints could arrive (three periods plus the latency). A deadline of exactly two periods would
/// trip on every dropped frame, since the next step's setpoints come a latency after that.
pub fn deadline(period: Duration) -> Duration {
    period * (MISSED_FRAMES + 2)
}

/// What the thrusters are doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Thrust {
    /// Driven by setpoints valid until this time (ns).
    Driven { until_ns: i64 },
    /// Stopped, for this cause.
    Stopped(StopCause),
}

/// A sink under the failsafe.
pub struct Failsafe<S: ThrusterSink> {
    sink: S,
    deadline: Duration,
    thrust: Thrust,
    last: Stamp,
    stops: u64,
}

impl<S: ThrusterSink> Failsafe<S> {
    /// The failsafe over `sink`, with `deadline`: how long setpoints stay fresh when their stamp
    /// does not say (untimed) — and the deadline the driver's own watchdog wakes on.
    /// Nothing is sent until [`Failsafe::start`].
    pub fn new(sink: S, deadline: Duration) -> Self {
        Failsafe {
            sink,
            deadline,
            thrust: Thrust::Stopped(StopCause::Start),
            last: Stamp::default(),
            stops: 0,
        }
    }

    /// The thrusters begin at rest: a stop for [`StopCause::Start`].
    pub fn start(&mut self) -> Result<(), AdapterError> {
        self.send_stop(StopCause::Start)
    }

    pub fn deadline(&self) -> Duration {
        self.deadline
    }

    pub fn thrust(&self) -> Thrust {
        self.thrust
    }

    /// Stops sent so far.
    pub fn stops(&self) -> u64 {
        self.stops
    }

    pub fn sink(&self) -> &S {
        &self.sink
    }

    pub fn sink_mut(&mut self) -> &mut S {
        &mut self.sink
    }

    /// Writes fresh setpoints of `stamp`, valid until `until_ns` on the vehicle clock.
    pub fn apply(
        &mut self,
        stamp: &Stamp,
        setpoints: &[f64],
        until_ns: i64,
    ) -> Result<Applied, AdapterError> {
        let applied = self.sink.write(stamp, setpoints)?;
        self.sink.flush()?;
        self.last = *stamp;
        self.thrust = Thrust::Driven { until_ns };
        Ok(applied)
    }

    /// The setpoints of a step the camera took at `clock_ns` (the vehicle clock) are fresh until the
    /// deadline after it: their delivery time is part of the step's age.
    pub fn fresh_until(&self, clock_ns: i64) -> i64 {
        clock_ns.saturating_add(self.deadline.as_nanos().min(i64::MAX as u128) as i64)
    }

    /// Setpoints arriving at `now_ns` with no freshness of their own stay valid for the deadline.
    pub fn until_from(&self, now_ns: i64) -> i64 {
        now_ns.saturating_add(self.deadline.as_nanos().min(i64::MAX as u128) as i64)
    }

    /// Time passed: stops the thrusters once the setpoints they hold are stale. Returns the stop
    /// made now, if any.
    pub fn on_time(&mut self, now_ns: i64) -> Result<Option<StopCause>, AdapterError> {
        match self.thrust {
            Thrust::Driven { until_ns } if now_ns >= until_ns => {
                self.send_stop(StopCause::Deadline)?;
                Ok(Some(StopCause::Deadline))
            }
            _ => Ok(None),
        }
    }

    /// How long until the setpoints held go stale (`None` while stopped).
    pub fn time_left(&self, now_ns: i64) -> Option<Duration> {
        match self.thrust {
            Thrust::Driven { until_ns } => Some(Duration::from_nanos(
                until_ns.saturating_sub(now_ns).max(0) as u64,
            )),
            Thrust::Stopped(_) => None,
        }
    }

    /// Stops the thrusters for `cause` unless they are stopped already; `true` if a stop was made.
    pub fn stop(&mut self, cause: StopCause) -> Result<bool, AdapterError> {
        if matches!(self.thrust, Thrust::Stopped(_)) {
            return Ok(false);
        }
        self.send_stop(cause)?;
        Ok(true)
    }

    fn send_stop(&mut self, cause: StopCause) -> Result<(), AdapterError> {
        self.thrust = Thrust::Stopped(cause);
        self.sink.stop(&self.last, cause)?;
        self.sink.flush()?;
        self.stops += 1;
        Ok(())
    }

    /// Stops the thrusters (if they are not) and closes the sink.
    pub fn close(&mut self) -> Result<(), AdapterError> {
        self.stop(StopCause::Shutdown)?;
        self.sink.close()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::NullSink;
    use messages::StepStatus;

    const MS: i64 = 1_000_000;

    #[test]
    fn stale_setpoints_stop_the_thrusters_once() {
        let mut f = Failsafe::new(NullSink::new(3).unwrap(), Duration::from_millis(400));
        f.start().unwrap();
        assert_eq!(f.thrust(), Thrust::Stopped(StopCause::Start));
        assert_eq!(f.on_time(10_000 * MS).unwrap(), None, "at rest already");
        let st = Stamp::new(1, 0, 0, 0, StepStatus::Running);
        let until = f.until_from(1000 * MS);
        f.apply(&st, &[0.5, 0.5, 0.0], until).unwrap();
        assert_eq!(f.time_left(1100 * MS), Some(Duration::from_millis(300)));
        assert_eq!(f.on_time(1399 * MS).unwrap(), None);
        assert_eq!(f.on_time(1400 * MS).unwrap(), Some(StopCause::Deadline));
        assert_eq!(f.on_time(1500 * MS).unwrap(), None, "once");
        assert_eq!(f.stops(), 2);
        assert!(
            !f.stop(StopCause::AllocatorDead).unwrap(),
            "stopped already"
        );
        f.apply(&st, &[0.1, 0.1, 0.0], f.until_from(2000 * MS))
            .unwrap();
        assert!(f.stop(StopCause::AllocatorDead).unwrap());
        assert_eq!(f.thrust(), Thrust::Stopped(StopCause::AllocatorDead));
        assert_eq!(f.sink().stops(), 3);
        f.close().unwrap();
        assert_eq!(
            f.sink().stops(),
            3,
            "closing stopped thrusters adds no stop"
        );
    }
}
