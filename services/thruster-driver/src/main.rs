//! `thruster-driver`: on the vehicle endpoint, the only process that drives the thrusters. It owns
//! the thruster sink, writes the allocator's fresh setpoints to it, and stops the thrusters (all 0,
//! logged with the cause) when no fresh setpoints come within the deadline, when the allocator's
//! process dies, and on SIGINT/SIGTERM. The core is the library's [`Driver`].

use adapters::ThrusterSink;
use adapters::record::{NullSink, RecordSink};
use adapters::twin::TwinThrusterSink;
use ardusub::{ArduSubSink, Publishers};
use clap::Parser;
use messages::{Endpoint, topics};
use model::ThrusterLayout;
use runtime::screen::Screen;
use runtime::{BadValues, CommonArgs, Runtime, Watch};
use std::process::ExitCode;
use std::time::{Duration, Instant};

/// How much before the deadline the driver acts on it: a wait's timeout ends up to a millisecond
/// late, and a failsafe that errs should err early.
const EARLY: Duration = Duration::from_millis(2);
use thruster_driver::{Driver, SinkSpec, Taken};

#[derive(Parser)]
#[command(
    version,
    about = "The vehicle's thruster driver: fresh setpoints to the thrusters, zero thrust when they stop, on shutdown and when the allocator dies."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// The thruster sink: `twin` (the vehicle twin's thrusters), `record:FILE` (a file of setpoints
    /// and stops with their times), `ardusub:URL[?OPTIONS]` (a vehicle under ArduSub, piloted over
    /// MAVLink: URL `udpout:HOST:PORT`, `udpin:ADDR:PORT` or `tcpout:HOST:PORT`; OPTIONS
    /// `sysid=254&compid=191&rate=20&mode=manual|stabilize|alt_hold&arm=auto|manual`) or `null`.
    #[arg(
        long,
        default_value = "twin",
        value_name = "twin|record:FILE|ardusub:URL|null"
    )]
    sink: SinkSpec,
    /// Setpoints go stale, and the thrusters stop, once their step is older than this [default:
    /// three sample periods, so one missed camera frame passes and the second stops the thrusters].
    #[arg(long, value_name = "MS")]
    deadline_ms: Option<u64>,
}

/// The vehicle's thrusters.
fn open_sink(rt: &Runtime, spec: &SinkSpec) -> anyhow::Result<Box<dyn ThrusterSink>> {
    let thrusters = &rt.scenario().thrusters.thruster;
    Ok(match spec {
        SinkSpec::Twin => Box::new(TwinThrusterSink::open(rt.node(), thrusters.len())?),
        SinkSpec::Record(path) => {
            let names: Vec<String> = thrusters.iter().map(|t| t.name.clone()).collect();
            Box::new(RecordSink::create(path, &names)?)
        }
        SinkSpec::Null => Box::new(NullSink::new(thrusters.len())?),
        SinkSpec::ArduSub(spec) => {
            // The autopilot's telemetry topics first: a second driver stops there, before it
            // touches the autopilot.
            let clock = *rt.clock();
            let publishers = Publishers::open(rt.node(), rt.endpoint(), move || clock.now_ns())?;
            let layout = ThrusterLayout::new(&rt.scenario().thrusters);
            // Under a `[pilot]` the commands go out as step one's model of the sticks assumes.
            // A spec naming another mode (the bench check's MANUAL) flies as it says, in plain thrust.
            let spec = match &rt.scenario().pilot {
                Some(pilot)
                    if spec.mode_named && ardusub::Mode::from(pilot.mode) != spec.options.mode =>
                {
                    tracing::warn!(
                        mode = spec.options.mode.name(),
                        pilot = pilot.mode.name(),
                        "the sink's mode is not the scenario's [pilot] mode: commands go out as plain thrust, not as step one's model of the sticks"
                    );
                    (**spec).clone()
                }
                Some(pilot) => (**spec)
                    .clone()
                    .with_pilot(pilot)
                    .map_err(anyhow::Error::msg)?,
                None => (**spec).clone(),
            };
            Box::new(ArduSubSink::open(
                &spec,
                layout,
                runtime::restarts() > 0,
                Some(publishers),
            )?)
        }
    })
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("thruster-driver", &args.common, |rt| {
        if rt.endpoint() != Endpoint::Vehicle {
            anyhow::bail!(
                "the thruster driver serves the `vehicle` endpoint; on `sim` the simulator reads the setpoint topic"
            );
        }
        let limits = thruster_driver::limits(
            rt.scenario().timing.sample_time_s,
            args.deadline_ms.map(Duration::from_millis),
        );
        // The thrusters first: a second driver stops here, before it touches anything.
        let sink = open_sink(rt, &args.sink)?;
        let setpoints = rt.inbox(&topics::THRUSTER_SETPOINTS)?;
        let mut driver = Driver::new(sink, Screen::new(setpoints.service(), limits));
        driver.start()?;
        let deadline = driver.deadline();
        tracing::info!(sink = %driver.sink().describe(), deadline_ms = deadline.as_millis() as u64, "thrusters at rest: waiting for setpoints");
        let mut bad = BadValues::new(setpoints.service());
        let clock = *rt.clock();
        let mut allocator_seen = false;
        // The allocator's death is announced on the setpoint topic's event service (iceoryx2's
        // notifier-dead event, sent once the dead process's leftovers are removed: by the supervisor
        // as it restarts it, or by any process that opens the topic): only then, and when the
        // setpoints stopped coming for the deadline, are the publishers' processes looked at. The
        // deadline stops the thrusters whether or not anyone announces the death.
        let served = rt.serve_watched(setpoints.listener(), deadline, |wake| {
            let now = clock.now_ns();
            let look = matches!(
                wake,
                Watch::Input {
                    publisher_died: true,
                    ..
                } | Watch::Missed
            );
            for msg in setpoints.drain()? {
                match driver.on_setpoints(&msg, now) {
                    Ok(Taken::Written(applied)) => {
                        bad.note(applied.fixes, msg.stamp.seq, now);
                        if !allocator_seen {
                            tracing::info!(seq = msg.stamp.seq, "setpoints arrive: driving the thrusters");
                            allocator_seen = true;
                        }
                    }
                    Ok(Taken::Repeat) | Ok(Taken::Refused(Some(_))) => {}
                    Ok(Taken::Refused(None)) => {
                        tracing::warn!(seq = msg.stamp.seq, "a stop on the setpoint topic refused: only the driver stops the thrusters")
                    }
                    // Keep serving: the next setpoints may get through; the deadline stops the thrusters.
                    Err(e) => tracing::error!(seq = msg.stamp.seq, "cannot write the setpoints: {e}"),
                }
            }
            if look {
                let publishers = setpoints.publisher_processes(rt.node());
                if publishers.alive.is_empty() && driver.allocator_gone()? {
                    tracing::warn!(cause = "allocator_dead", dead = publishers.dead, "thrusters stopped: the allocator's process is gone");
                    allocator_seen = false;
                }
            }
            // The wait ends up to a millisecond late (its timeout's resolution, the wake-up's
            // latency): setpoints with less than EARLY left count as stale now, so the thrusters stop
            // within the deadline, never after it.
            if driver.on_time(clock.now_ns() + EARLY.as_nanos() as i64)?.is_some() {
                tracing::warn!(cause = "deadline", deadline_ms = deadline.as_millis() as u64, "thrusters stopped: no fresh setpoints within the deadline");
            }
            // The sink's own work (ArduSub's steady stick and heartbeat) from this thread alone: if
            // the driver hangs, the sink falls silent too.
            let now = Instant::now();
            let service = match driver.service(now) {
                Ok(at) => at.map(|at| at.saturating_duration_since(now)),
                Err(e) => {
                    tracing::error!("the thruster sink's periodic work failed: {e}");
                    None
                }
            };
            // Woken again EARLY before the setpoints held go stale, or when the sink asks.
            let left = driver.time_left(clock.now_ns()).unwrap_or(deadline);
            let wake = left.saturating_sub(EARLY);
            Ok(Some(service.map_or(wake, |s| s.min(wake))))
        });
        let closed = driver.shutdown();
        match &closed {
            Ok(()) => tracing::info!(cause = "shutdown", "thrusters stopped: the driver stops"),
            Err(e) => tracing::error!("cannot stop the thrusters at shutdown: {e}"),
        }
        served?;
        closed?;
        Ok(())
    })
}
