//! `thruster-allocator`: the three DOF commands of a step in, thruster setpoints out: on the setpoint
//! topic, and on the vehicle endpoint to the vehicle's thruster sink too (see `SinkSpec`).

use adapters::ThrusterSink;
use adapters::record::{NullSink, RecordSink};
use adapters::twin::TwinThrusterSink;
use clap::Parser;
use messages::{Endpoint, topics};
use runtime::{CommonArgs, Flow, Runtime, Timer};
use std::process::ExitCode;
use std::time::{Duration, Instant};
use thruster_allocator::step::{self, Event, Input, StepAllocator};
use thruster_allocator::{Allocator, SinkSpec};

#[derive(Parser)]
#[command(
    version,
    about = "Maps the surge, sway and yaw commands of each step to thruster setpoints."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// A step's three commands must arrive within this time of its first; a missing one counts as 0.
    #[arg(long, default_value_t = 1000)]
    deadline_ms: u64,
    /// Vehicle endpoint: the thruster sink written besides the setpoint topic, `twin` (the vehicle
    /// twin's thrusters), `record:FILE` (a file of setpoints with their times) or `null`
    /// [default: twin].
    #[arg(long, value_name = "twin|record:FILE|null")]
    sink: Option<SinkSpec>,
}

/// The vehicle's thrusters, if this endpoint has any.
fn open_sink(
    rt: &Runtime,
    spec: Option<&SinkSpec>,
) -> anyhow::Result<Option<Box<dyn ThrusterSink>>> {
    let thrusters = &rt.scenario().thrusters.thruster;
    let sink: Box<dyn ThrusterSink> = match (rt.endpoint(), spec) {
        (Endpoint::Sim, None) => return Ok(None),
        (Endpoint::Sim, Some(_)) => anyhow::bail!(
            "--sink is for the `vehicle` endpoint; on `sim` the simulator reads the setpoint topic"
        ),
        (Endpoint::Vehicle, None | Some(SinkSpec::Twin)) => {
            Box::new(TwinThrusterSink::open(rt.node(), thrusters.len())?)
        }
        (Endpoint::Vehicle, Some(SinkSpec::Record(path))) => {
            let names: Vec<String> = thrusters.iter().map(|t| t.name.clone()).collect();
            Box::new(RecordSink::create(path, &names)?)
        }
        (Endpoint::Vehicle, Some(SinkSpec::Null)) => Box::new(NullSink::new(thrusters.len())?),
    };
    tracing::info!(sink = %sink.describe(), "thruster sink open");
    Ok(Some(sink))
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("thruster-allocator", &args.common, |rt| {
        let allocator = Allocator::new(&rt.scenario().thrusters);
        let mut steps = StepAllocator::new(allocator, Duration::from_millis(args.deadline_ms));
        let mut sink = open_sink(rt, args.sink.as_ref())?;
        let inputs = [
            (Input::Surge, rt.inbox(&topics::SURGE_COMMAND)?),
            (Input::Sway, rt.inbox(&topics::SWAY_COMMAND)?),
            (Input::Yaw, rt.inbox(&topics::YAW_COMMAND)?),
        ];
        let out = rt.outbox(&topics::THRUSTER_SETPOINTS)?;
        let mut act = |event: Event| -> anyhow::Result<()> {
            let msg = match event {
                Event::Idle => return Ok(()),
                Event::Send(msg) => msg,
                Event::Overtaken(p) => {
                    tracing::warn!(seq = p.seq, missing = ?step::missing(&p), "step incomplete: a newer step arrived");
                    return Ok(());
                }
                Event::Overdue { partial, setpoints } => {
                    tracing::warn!(seq = partial.seq, missing = ?step::missing(&partial), "step incomplete: deadline passed, missing commands count as 0");
                    setpoints
                }
            };
            out.send(msg)?;
            // A re-sent step is written again: the thrusters' side may be waiting for it.
            if let Some(sink) = sink.as_mut()
                && let Err(e) = sink.write(&msg.stamp, msg.as_slice())
            {
                // Keep serving: the next step's setpoints may get through.
                tracing::error!(seq = msg.stamp.seq, sink = %sink.describe(), "cannot write the setpoints: {e}");
            }
            Ok(())
        };
        let listeners = inputs.each_ref().map(|(_, i)| i.listener());
        let served = rt.serve(&listeners, Timer::Timeout(steps.deadline() / 4), |_| {
            for (input, inbox) in &inputs {
                for cmd in inbox.drain()? {
                    act(steps.on_command(*input, cmd, Instant::now()))?;
                }
            }
            act(steps.on_time(Instant::now()))?;
            Ok(Flow::Continue)
        });
        if let Some(sink) = sink.as_mut()
            && let Err(e) = sink.close()
        {
            tracing::error!(sink = %sink.describe(), "cannot close the thruster sink: {e}");
        }
        served?;
        Ok(())
    })
}
