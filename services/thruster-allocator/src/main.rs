//! `thruster-allocator`: the three DOF commands of a step in, thruster setpoints out: on the setpoint
//! topic, and on the vehicle endpoint to the vehicle's thruster sink too (see `SinkSpec`).

use adapters::ThrusterSink;
use adapters::record::{NullSink, RecordSink};
use adapters::twin::TwinThrusterSink;
use clap::Parser;
use messages::{DofCommand, Endpoint, Stamp, ThrusterSetpoints, topics};
use runtime::lockstep::{Gather, Once, Partial};
use runtime::{CommonArgs, Flow, Runtime, Timer};
use std::process::ExitCode;
use std::time::Duration;
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

/// Inputs, in the order of the `missing` bits of ThrusterSetpoints.
const DOFS: [&str; 3] = ["surge", "sway", "yaw"];

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("thruster-allocator", &args.common, |rt| {
        let allocator = Allocator::new(&rt.scenario().thrusters);
        let mut sink = open_sink(rt, args.sink.as_ref())?;
        let inputs = [
            rt.inbox(&topics::SURGE_COMMAND)?,
            rt.inbox(&topics::SWAY_COMMAND)?,
            rt.inbox(&topics::YAW_COMMAND)?,
        ];
        let out = rt.outbox(&topics::THRUSTER_SETPOINTS)?;
        let deadline = Duration::from_millis(args.deadline_ms);
        let mut gather = Gather::<DofCommand, 3>::new();
        let mut once = Once::<ThrusterSetpoints>::new();
        // Sends the step's setpoints, computing them the first time the step is answered.
        let mut publish = |once: &mut Once<ThrusterSetpoints>,
                           stamp: Stamp,
                           values: [Option<f64>; 3]|
         -> anyhow::Result<()> {
            let sent = once.step(stamp.seq, || {
                Ok::<_, anyhow::Error>(setpoints(&allocator, stamp, values))
            })?;
            if let Some(msg) = sent.output() {
                out.send(msg)?;
                // A re-sent step is written again: the thrusters' side may be waiting for it.
                if let Some(sink) = sink.as_mut()
                    && let Err(e) = sink.write(&msg.stamp, msg.as_slice())
                {
                    // Keep serving: the next step's setpoints may get through.
                    tracing::error!(seq = msg.stamp.seq, sink = %sink.describe(), "cannot write the setpoints: {e}");
                }
            }
            Ok(())
        };
        let listeners = inputs.each_ref().map(|i| i.listener());
        let served = rt.serve(&listeners, Timer::Timeout(deadline / 4), |_| {
            for (i, inbox) in inputs.iter().enumerate() {
                for cmd in inbox.drain()? {
                    // A step already answered (a re-send) gets the same setpoints again.
                    if let Some(last) = once.last_seq().filter(|&l| cmd.stamp.seq <= l) {
                        if cmd.stamp.seq == last {
                            publish(&mut once, cmd.stamp, [None; 3])?;
                        }
                        continue;
                    }
                    match gather.put(i, cmd.stamp.seq, cmd) {
                        Ok(Some((_, all))) => {
                            publish(&mut once, all[0].stamp, all.map(|c| Some(c.value)))?
                        }
                        Ok(None) => {}
                        Err(dropped) => warn_missing(&dropped, "a newer step arrived"),
                    }
                }
            }
            if let Some(late) = gather.take_overdue(deadline) {
                warn_missing(&late, "deadline passed: missing commands count as 0");
                let stamp = late
                    .values
                    .iter()
                    .flatten()
                    .next()
                    .map(|c| c.stamp)
                    .expect("an overdue step has a command");
                publish(&mut once, stamp, late.values.map(|c| c.map(|c| c.value)))?;
            }
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

fn setpoints(allocator: &Allocator, stamp: Stamp, values: [Option<f64>; 3]) -> ThrusterSetpoints {
    let [surge, sway, yaw] = values.map(|v| v.unwrap_or(0.0));
    let allocation = allocator.allocate(model::Forces { surge, sway, yaw });
    let s = allocation.setpoints.as_slice();
    let mut msg = ThrusterSetpoints {
        stamp,
        count: s.len() as u32,
        missing: values
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_none())
            .map(|(k, _)| 1 << k)
            .sum(),
        scale: allocation.scale,
        ..Default::default()
    };
    msg.values[..s.len()].copy_from_slice(s);
    msg
}

fn warn_missing(p: &Partial<DofCommand, 3>, why: &str) {
    let missing: Vec<&str> = DOFS
        .iter()
        .zip(&p.values)
        .filter(|(_, v)| v.is_none())
        .map(|(d, _)| *d)
        .collect();
    tracing::warn!(seq = p.seq, ?missing, "step incomplete: {why}");
}
