//! The whole closed loop in one process: the same service cores the mesh runs as processes
//! (simulator, camera, perception, sway and yaw behaviours, surge controller, thruster allocator),
//! called in the mesh's order with no IPC. Step one runs here thousands of episodes per second.

use crate::Perceiver;
use behaviour::{behave, new_agent};
use config::StepStatus;
use config::{Dof, LearningParams, PerDof, Scenario, derive_seed};
use learning::Algorithm;
use learning::agent::{Agent, EpisodeSummary};
use model::Forces;
use simulator::{SimStep, Simulator};
use surge_controller::SurgeController;
use thruster_allocator::Allocator;

/// What one episode gave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeResult {
    pub episode: u32,
    /// Control steps taken (transitions).
    pub steps: u32,
    /// The cable left the image.
    pub lost: bool,
    /// Each behaviour's episode return (the sum of its rewards, the failure reward included).
    pub returns: PerDof<f64>,
    /// Each policy's gain K at the end of the episode.
    pub gains: PerDof<[f64; 2]>,
    /// Each learner's actor updates so far.
    pub actor_updates: PerDof<u64>,
}

/// One step of a recorded episode, for the state-trace figures.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct TracePoint {
    pub time_s: f64,
    pub x_g: f64,
    pub theta: f64,
    pub sway: f64,
    pub yaw: f64,
    pub surge: f64,
}

/// The in-process loop.
pub struct World {
    sim: Simulator,
    perceiver: Perceiver,
    agents: PerDof<Agent>,
    surge: SurgeController,
    allocator: Allocator,
    sample_time_s: f64,
    trace: Option<Vec<TracePoint>>,
}

/// The random streams of one experiment seed (shared with the mesh's services).
pub fn stream_seeds(seed: u64) -> (u64, PerDof<u64>) {
    (
        derive_seed(seed, "simulator"),
        PerDof {
            sway: derive_seed(seed, "sway"),
            yaw: derive_seed(seed, "yaw"),
        },
    )
}

impl World {
    /// A fresh world: both behaviours start from the configured initial gains.
    pub fn new(
        scenario: &Scenario,
        learning: &LearningParams,
        algorithm: Algorithm,
        perceiver: Perceiver,
        seed: u64,
    ) -> Self {
        let (_, agent_seeds) = stream_seeds(seed);
        let agent = |dof: Dof| new_agent(dof, algorithm, scenario, learning, *agent_seeds.get(dof));
        let agents = PerDof {
            sway: agent(Dof::Sway),
            yaw: agent(Dof::Yaw),
        };
        World::with_agents(scenario, agents, perceiver, seed)
    }

    /// A world around existing agents (e.g. loaded from a checkpoint).
    pub fn with_agents(
        scenario: &Scenario,
        agents: PerDof<Agent>,
        perceiver: Perceiver,
        seed: u64,
    ) -> Self {
        let (sim_seed, _) = stream_seeds(seed);
        World {
            sim: Simulator::new(scenario, sim_seed),
            perceiver,
            agents,
            surge: SurgeController::new(&scenario.surge, &scenario.commanded_model().surge),
            allocator: Allocator::new(&scenario.thrusters),
            sample_time_s: scenario.timing.sample_time_s,
            trace: None,
        }
    }

    pub fn agents(&self) -> &PerDof<Agent> {
        &self.agents
    }

    pub fn agents_mut(&mut self) -> &mut PerDof<Agent> {
        &mut self.agents
    }

    pub fn perceiver(&self) -> &Perceiver {
        &self.perceiver
    }

    pub fn into_agents(self) -> PerDof<Agent> {
        self.agents
    }

    /// Records the next episodes' state traces (see [`World::take_trace`]).
    pub fn record(&mut self, on: bool) {
        self.trace = on.then(Vec::new);
    }

    /// The trace recorded since the last call.
    pub fn take_trace(&mut self) -> Vec<TracePoint> {
        self.trace.as_mut().map(std::mem::take).unwrap_or_default()
    }

    /// Runs one episode from a fresh reset to its end.
    pub fn run_episode(&mut self) -> EpisodeResult {
        let mut step = self.sim.reset();
        self.perceiver.reset();
        loop {
            let obs = self.perceiver.observe(&self.sim, &step);
            let kind = step.status;
            let sway = behave(&mut self.agents.sway, &obs, kind);
            let yaw = behave(&mut self.agents.yaw, &obs, kind);
            if let (Some(s), Some(y)) = (sway.1, yaw.1) {
                return self.result(&step, s, y);
            }
            let surge = self.surge.command(&obs);
            if let Some(trace) = &mut self.trace {
                trace.push(TracePoint {
                    time_s: step.step as f64 * self.sample_time_s,
                    x_g: obs.x_g,
                    theta: obs.theta,
                    sway: sway.0,
                    yaw: yaw.0,
                    surge,
                });
            }
            let command = Forces {
                surge,
                sway: sway.0,
                yaw: yaw.0,
            };
            let allocation = self.allocator.allocate(command);
            step = self.sim.step(allocation.setpoints.as_slice());
        }
    }

    fn result(&self, step: &SimStep, sway: EpisodeSummary, yaw: EpisodeSummary) -> EpisodeResult {
        EpisodeResult {
            episode: step.episode,
            steps: step.step,
            lost: step.status == StepStatus::Lost,
            returns: PerDof {
                sway: sway.return_,
                yaw: yaw.return_,
            },
            gains: PerDof {
                sway: self.agents.sway.gain(),
                yaw: self.agents.yaw.gain(),
            },
            actor_updates: PerDof {
                sway: sway.actor_updates,
                yaw: yaw.actor_updates,
            },
        }
    }
}
