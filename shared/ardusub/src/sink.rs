//! The thin shell: [`ArduSubSink`] binds the [`Companion`] to a [`Link`] and to the mesh's
//! telemetry topics, behind the [`ThrusterSink`] trait.

use crate::companion::{self, Companion, Event, Level, Output};
use crate::link::{Inbound, Link};
use crate::spec::{Spec, Timing};
use crate::telemetry::Telemetry;
use crate::{Error, wire::WireCounts};
use adapters::{AdapterError, Applied, LastSent, Stamp, StopCause, ThrusterSink};
use iceoryx2::prelude::*;
use messages::{
    AutopilotAttitude, AutopilotDepth, AutopilotState, Endpoint, Outbox, PortError, ServoOutputs,
    StatusText, topics,
};
use model::ThrusterLayout;
use std::time::{Duration, Instant};

/// How often a link's refused frames, or failing sends, are logged at most.
const TELL_EVERY: Duration = Duration::from_secs(5);

/// The autopilot's telemetry topics, and the vehicle clock their messages are timed by.
pub struct Publishers {
    state: Outbox<AutopilotState>,
    attitude: Outbox<AutopilotAttitude>,
    depth: Outbox<AutopilotDepth>,
    servos: Outbox<ServoOutputs>,
    texts: Outbox<StatusText>,
    clock: Box<dyn Fn() -> i64>,
    seq: u64,
}

impl Publishers {
    /// Opens the topics on `endpoint`. The state topic takes one publisher: a second driver stops
    /// here, before it touches the autopilot. `clock` reads the vehicle clock (ns).
    pub fn open(
        node: &Node<ipc::Service>,
        endpoint: Endpoint,
        clock: impl Fn() -> i64 + 'static,
    ) -> Result<Self, PortError> {
        Ok(Publishers {
            state: Outbox::open(node, endpoint, &topics::AUTOPILOT_STATE)?,
            attitude: Outbox::open(node, endpoint, &topics::AUTOPILOT_ATTITUDE)?,
            depth: Outbox::open(node, endpoint, &topics::AUTOPILOT_DEPTH)?,
            servos: Outbox::open(node, endpoint, &topics::AUTOPILOT_SERVO_OUTPUTS)?,
            texts: Outbox::open(node, endpoint, &topics::AUTOPILOT_STATUS_TEXT)?,
            clock: Box::new(clock),
            seq: 0,
        })
    }

    /// The vehicle clock when `at` was (an arrival a moment ago).
    fn clock_at(&self, at: Instant) -> i64 {
        (self.clock)().saturating_sub(at.elapsed().as_nanos().min(i64::MAX as u128) as i64)
    }

    fn next(&mut self) -> u64 {
        self.seq += 1;
        self.seq
    }

    fn publish(&mut self, at: Instant, t: Telemetry) -> Result<(), PortError> {
        let (seq, clock_ns) = (self.next(), self.clock_at(at));
        match t {
            Telemetry::Attitude(m) => self.attitude.send(AutopilotAttitude { seq, clock_ns, ..m }),
            Telemetry::Depth(m) => self.depth.send(AutopilotDepth { seq, clock_ns, ..m }),
            Telemetry::Servos(m) => self.servos.send(ServoOutputs { seq, clock_ns, ..m }),
            Telemetry::Text(m) => self.texts.send(StatusText { seq, clock_ns, ..m }),
        }
        .map(|_| ())
    }

    fn publish_state(&mut self, at: Instant, s: AutopilotState) -> Result<(), PortError> {
        let (seq, clock_ns) = (self.next(), self.clock_at(at));
        self.state
            .send(AutopilotState { seq, clock_ns, ..s })
            .map(|_| ())
    }
}

/// The thrusters of a vehicle under ArduSub, piloted over MAVLink as a companion computer: the
/// layout's setpoints go out as the DOF forces they make, in MANUAL_CONTROL (see the crate docs).
pub struct ArduSubSink {
    describe: String,
    url: String,
    layout: ThrusterLayout,
    link: Link,
    companion: Companion,
    publishers: Option<Publishers>,
    last: LastSent,
    closed: bool,
    /// The refused-frame count last told, and when.
    told: (u64, Option<Instant>),
    send_failed: Option<Instant>,
}

impl ArduSubSink {
    /// Connects to the autopilot of `spec` and makes it ready to pilot: its heartbeat, its
    /// parameters checked, its mode set and armed (on a fresh start, not when `restarted`). The
    /// layout's setpoints are what [`ThrusterSink::write`] takes. Telemetry goes to `publishers`.
    pub fn open(
        spec: &Spec,
        layout: ThrusterLayout,
        restarted: bool,
        publishers: Option<Publishers>,
    ) -> Result<Self, Error> {
        Self::open_with(spec, layout, restarted, publishers, Timing::default())
    }

    /// [`ArduSubSink::open`] with other waits and retries.
    pub fn open_with(
        spec: &Spec,
        layout: ThrusterLayout,
        restarted: bool,
        publishers: Option<Publishers>,
        timing: Timing,
    ) -> Result<Self, Error> {
        let url = spec.url.to_string();
        let describe = format!("ArduSub at {url}");
        adapters::check_thrusters(&describe, layout.len())?;
        let link = Link::open(&spec.url, spec.options.system, spec.options.component).map_err(
            |(what, source)| Error::Link {
                url: url.clone(),
                what,
                source,
            },
        )?;
        tracing::info!(
            url = %url,
            local = ?link.local_address(),
            system = spec.options.system,
            component = spec.options.component,
            rate_hz = spec.options.rate_hz,
            mode = spec.options.mode.name(),
            restarted,
            "waiting for ArduSub's heartbeat"
        );
        let companion = Companion::new(spec.options, timing, restarted, Instant::now());
        let mut sink = ArduSubSink {
            describe,
            url,
            layout,
            link,
            companion,
            publishers,
            last: LastSent::default(),
            closed: false,
            told: (0, None),
            send_failed: None,
        };
        match sink.run_until(Companion::is_running) {
            Ok(()) => Ok(sink),
            Err(e) => {
                // Nothing to undo: opening arms last.
                sink.closed = true;
                Err(e)
            }
        }
    }

    /// The companion, to look at (tests, logs).
    pub fn companion(&self) -> &Companion {
        &self.companion
    }

    /// The address the sink sends from (the port ArduSub answers to).
    pub fn local_address(&self) -> Option<std::net::SocketAddr> {
        self.link.local_address()
    }

    /// Frames sent so far.
    pub fn frames_sent(&self) -> u64 {
        self.link.sent()
    }

    /// What the link has received and refused so far.
    pub fn counts(&self) -> WireCounts {
        self.link.counts()
    }

    fn autopilot_error(&self, source: companion::Error) -> Error {
        Error::Autopilot {
            url: self.url.clone(),
            source,
        }
    }

    /// Feeds the frames received so far (waiting for one until `deadline`, if given).
    fn receive(&mut self, deadline: Option<Instant>) {
        let mut wait = deadline;
        while let Some(inbound) = self.link.receive(wait) {
            wait = None;
            match inbound {
                Inbound::Frame { at, frame } => self.companion.on_frame(at, &frame),
                Inbound::Note(note) => tracing::warn!(url = %self.url, "{note}"),
            }
        }
    }

    /// Runs the companion until `done` (opening, closing), waiting for frames or its next wake.
    fn run_until(&mut self, done: fn(&Companion) -> bool) -> Result<(), Error> {
        loop {
            self.receive(None);
            let now = Instant::now();
            let r = self.companion.on_time(now);
            self.flush_output();
            r.map_err(|e| self.autopilot_error(e))?;
            if done(&self.companion) {
                return Ok(());
            }
            self.receive(Some(self.companion.next_wake()));
        }
    }

    /// Sends, logs and publishes what the companion produced.
    fn flush_output(&mut self) {
        let Output {
            send,
            events,
            telemetry,
            state,
        } = self.companion.take();
        for m in &send {
            if let Err(e) = self.link.send(m) {
                let now = Instant::now();
                if self.send_failed.is_none_or(|t| now >= t + TELL_EVERY) {
                    self.send_failed = Some(now);
                    tracing::warn!(url = %self.url, message = crate::wire::name(m), "cannot send to ArduSub: {e}");
                }
            }
        }
        for e in events {
            log(&e);
        }
        let counts = self.link.counts();
        let refused = counts.refused() + u64::from(counts.garbage_bytes > 0);
        let now = Instant::now();
        if refused > self.told.0 && self.told.1.is_none_or(|t| now >= t + TELL_EVERY) {
            self.told = (refused, Some(now));
            tracing::warn!(url = %self.url, refused = counts.refused(), bad_crc = counts.bad_crc, garbage_bytes = counts.garbage_bytes, "MAVLink refused on the link: {counts}");
        }
        let Some(p) = &mut self.publishers else {
            return;
        };
        let mut failed = None;
        for (at, t) in telemetry {
            if let Err(e) = p.publish(at, t) {
                failed = Some(e);
            }
        }
        for (at, s) in state {
            let s = AutopilotState {
                frames_refused: counts.refused(),
                ..s
            };
            if let Err(e) = p.publish_state(at, s) {
                failed = Some(e);
            }
        }
        if let Some(e) = failed {
            tracing::warn!("cannot publish the autopilot's telemetry: {e}");
        }
    }
}

fn log(e: &Event) {
    match e.level() {
        Level::Info => tracing::info!("{e}"),
        Level::Warn => tracing::warn!("{e}"),
        Level::Error => tracing::error!("{e}"),
    }
}

impl ThrusterSink for ArduSubSink {
    fn describe(&self) -> String {
        self.describe.clone()
    }

    fn thrusters(&self) -> usize {
        self.layout.len()
    }

    fn write(&mut self, stamp: &Stamp, setpoints: &[f64]) -> Result<Applied, AdapterError> {
        if self.closed {
            return Err(adapters::closed(self));
        }
        let applied = adapters::apply(&self.describe, self.layout.len(), setpoints)?;
        let forces = self.layout.forces(applied.as_slice());
        self.companion.command(&forces, stamp);
        self.flush_output();
        self.last.sent(stamp, false);
        Ok(applied)
    }

    fn stop(&mut self, stamp: &Stamp, cause: StopCause) -> Result<(), AdapterError> {
        if self.closed {
            return Err(adapters::closed(self));
        }
        self.companion.stop(stamp, cause);
        self.flush_output();
        self.last.sent(stamp, true);
        Ok(())
    }

    fn flush(&mut self) -> Result<(), AdapterError> {
        if self.closed {
            return Err(adapters::closed(self));
        }
        Ok(())
    }

    fn close(&mut self) -> Result<(), AdapterError> {
        if self.closed {
            return Ok(());
        }
        self.closed = true;
        // Neutral first, then the disarm.
        if !self.last.stopped {
            let last = self.last.stamp;
            self.companion.stop(&last, StopCause::Shutdown);
            self.last.sent(&last, true);
        }
        let r = self
            .companion
            .close(Instant::now())
            .map_err(|e| self.autopilot_error(e))
            .and_then(|()| self.run_until(Companion::is_closed));
        self.flush_output();
        r.map_err(AdapterError::from)
    }

    fn service(&mut self, now: Instant) -> Result<Option<Instant>, AdapterError> {
        if self.closed {
            return Ok(None);
        }
        self.receive(None);
        let r = self.companion.on_time(now);
        self.flush_output();
        r.map_err(|e| AdapterError::from(self.autopilot_error(e)))?;
        Ok(Some(self.companion.next_wake()))
    }
}

impl Drop for ArduSubSink {
    /// A sink dropped without closing (an error after opening) still leaves the vehicle at rest
    /// and disarmed.
    fn drop(&mut self) {
        if !self.closed
            && let Err(e) = self.close()
        {
            tracing::error!("{}: cannot stop and disarm the vehicle: {e}", self.describe);
        }
    }
}
