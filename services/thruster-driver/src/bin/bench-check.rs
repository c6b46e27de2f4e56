//! `bench-check`: the props-off bench check of a BlueROV2 under ArduSub, through the vehicle's own
//! path. It plays the allocator: each axis (surge, sway, yaw) in turn, a low positive command
//! allocated to setpoints by the allocator's own code and published on the setpoint topic, which the
//! thruster driver (`--sink ardusub:...`) turns into MANUAL_CONTROL; it reads the autopilot's
//! SERVO_OUTPUT_RAW back from the driver's telemetry topic and holds each thruster's sign against
//! the vectored frame's (`thruster_driver::bench`). Prints the table; fails naming each thruster and
//! axis with the wrong sign. `scripts/bench-check` starts the driver (and the twin) around it.

use anyhow::{Context, bail};
use clap::Parser;
use messages::{Outbox, Stamp, StepStatus, ThrusterSetpoints, topics};
use model::Forces;
use runtime::{CommonArgs, Flow, Timer};
use std::process::ExitCode;
use std::time::{Duration, Instant};
use thruster_allocator::Allocator;
use thruster_driver::bench::{self, Axis, MOTORS};

#[derive(Parser)]
#[command(
    version,
    about = "Props-off bench check: drives surge, sway and yaw in turn through the thruster driver and ArduSub, and checks each thruster's sign in SERVO_OUTPUT_RAW."
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// The command on each axis, a fraction of its full thrust.
    #[arg(long, default_value_t = 0.2, value_name = "F")]
    thrust: f64,
    /// How long each axis is driven.
    #[arg(long, default_value_t = 2.0, value_name = "S")]
    hold_s: f64,
    /// The pulses of the first part of each hold are not judged (the stick reaching the autopilot,
    /// its outputs following).
    #[arg(long, default_value_t = 0.8, value_name = "S")]
    settle_s: f64,
    /// Seconds to wait for the autopilot to be armed (by the driver, or by the pilot).
    #[arg(long, default_value_t = 30.0, value_name = "S")]
    arm_timeout_s: f64,
    /// Thrusters (1..6) meant to run reversed on this vehicle (MOT_n_DIRECTION = -1 for its
    /// propeller): their expected sign is flipped. Comma-separated.
    #[arg(long, value_delimiter = ',', value_name = "N,...")]
    reversed: Vec<usize>,
}

/// Where the check is.
enum Phase {
    Arming { until: Instant },
    Driving { axis: usize, since: Instant },
    Resting { next: usize, until: Instant },
}

/// The allocator's side of the setpoint topic: each call a new step, timed now.
struct Steps {
    out: Outbox<ThrusterSetpoints>,
    clock: runtime::VehicleClock,
    epoch: u32,
    seq: u64,
    count: usize,
}

impl Steps {
    fn send(&mut self, values: &[f64]) -> anyhow::Result<()> {
        self.seq += 1;
        let stamp = Stamp::new(
            self.seq,
            self.seq * 200_000_000,
            0,
            self.seq as u32,
            StepStatus::Running,
        )
        .timed(self.epoch, self.clock.now_ns());
        let mut m = ThrusterSetpoints {
            stamp,
            count: self.count as u32,
            scale: 1.0,
            ..Default::default()
        };
        m.values[..self.count].copy_from_slice(&values[..self.count]);
        self.out.send(m).context("publishing setpoints")?;
        Ok(())
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::run("bench-check", &args.common, |rt| {
        if !(0.0..=0.5).contains(&args.thrust) || args.thrust == 0.0 {
            bail!("--thrust {}: a low thrust, in (0, 0.5]", args.thrust);
        }
        let mut reversed = [false; MOTORS];
        for &n in &args.reversed {
            if !(1..=MOTORS).contains(&n) {
                bail!("--reversed {n}: thrusters are 1 to {MOTORS}");
            }
            reversed[n - 1] = true;
        }
        let allocator = Allocator::new(&rt.scenario().thrusters);
        let clock = *rt.clock();
        let mut steps = Steps {
            out: rt.outbox(&topics::THRUSTER_SETPOINTS)?,
            epoch: clock.new_epoch(),
            clock,
            seq: 0,
            count: allocator.layout().len(),
        };
        let servos = rt.inbox(&topics::AUTOPILOT_SERVO_OUTPUTS)?;
        let state = rt.inbox(&topics::AUTOPILOT_STATE)?;
        let (hold, settle) = (
            Duration::from_secs_f64(args.hold_s),
            Duration::from_secs_f64(args.settle_s),
        );
        let period = Duration::from_secs_f64(rt.scenario().timing.sample_time_s);
        let mut phase = Phase::Arming {
            until: Instant::now() + Duration::from_secs_f64(args.arm_timeout_s),
        };
        let mut pulses: Vec<Vec<u16>> = vec![Vec::new(); MOTORS];
        let mut readings = Vec::new();
        let mut failure = None;
        tracing::info!(
            thrust = args.thrust,
            "waiting for the autopilot to be armed"
        );
        rt.serve(&[servos.listener()], Timer::Interval(period), |_| {
            let now = Instant::now();
            let mut armed = None;
            for s in state.drain()? {
                armed = Some(s.heartbeat == 1 && s.armed == 1);
            }
            let outputs = servos.drain()?;
            if armed == Some(false) && !matches!(phase, Phase::Arming { .. }) {
                failure = Some("the autopilot disarmed during the check".to_string());
                return Ok(Flow::Stop);
            }
            let command = match &mut phase {
                Phase::Arming { until } => {
                    if armed == Some(true) {
                        tracing::info!("armed: driving each axis in turn");
                        phase = Phase::Resting {
                            next: 0,
                            until: now + settle,
                        };
                    } else if now >= *until {
                        failure = Some(format!(
                            "the autopilot was not armed within {} s",
                            args.arm_timeout_s
                        ));
                        return Ok(Flow::Stop);
                    }
                    None
                }
                Phase::Driving { axis, since } => {
                    if now.duration_since(*since) >= settle {
                        for o in &outputs {
                            for (m, p) in pulses.iter_mut().enumerate() {
                                if m < usize::from(o.count) && o.port == 0 {
                                    p.push(o.pwm_us[m]);
                                }
                            }
                        }
                    }
                    let axis_now = Axis::ALL[*axis];
                    if now.duration_since(*since) >= hold {
                        let pwm: [Option<u16>; MOTORS] =
                            std::array::from_fn(|m| bench::median(std::mem::take(&mut pulses[m])));
                        let judged = bench::judge(axis_now, &pwm, &reversed);
                        tracing::info!(axis = axis_now.name(), ?pwm, "axis done");
                        readings.extend(judged);
                        let next = *axis + 1;
                        phase = Phase::Resting {
                            next,
                            until: now + settle,
                        };
                        None
                    } else {
                        Some(axis_now)
                    }
                }
                Phase::Resting { next, until } => {
                    if now >= *until {
                        if *next == Axis::ALL.len() {
                            steps.send(&[0.0; MOTORS])?;
                            return Ok(Flow::Stop);
                        }
                        tracing::info!(axis = Axis::ALL[*next].name(), "driving");
                        let axis = *next;
                        phase = Phase::Driving { axis, since: now };
                        Some(Axis::ALL[axis])
                    } else {
                        None
                    }
                }
            };
            let f = args.thrust;
            let forces = match command {
                None => Forces::default(),
                Some(Axis::Surge) => Forces {
                    surge: f,
                    ..Forces::default()
                },
                Some(Axis::Sway) => Forces {
                    sway: f,
                    ..Forces::default()
                },
                Some(Axis::Yaw) => Forces {
                    yaw: f,
                    ..Forces::default()
                },
            };
            steps.send(allocator.allocate(forces).setpoints.as_slice())?;
            Ok(Flow::Continue)
        })?;
        if let Some(f) = failure {
            bail!("{f}");
        }
        if readings.len() < Axis::ALL.len() * MOTORS {
            bail!("stopped before every axis was driven");
        }
        println!("{}", bench::table(&readings));
        let wrong: Vec<String> = readings
            .iter()
            .filter(|r| !r.right())
            .map(|r| r.to_string())
            .collect();
        if wrong.is_empty() {
            println!("bench check: every thruster's sign is right on surge, sway and yaw");
            Ok(())
        } else {
            for w in &wrong {
                println!("WRONG: {w}");
            }
            bail!("bench check: {} wrong: {}", wrong.len(), wrong.join("; "));
        }
    })
}
