//! Step two in one process: the twin composed with the very cores the vehicle endpoint runs as
//! processes (perception, the sway and yaw behaviours, the surge controller, the thruster
//! allocator), called in the mesh's order with no IPC, like `trainer::World` for step one. A frame
//! the twin drops never reaches perception: that step gets no command, and the thrusters hold.

use behaviour::{Behaviour, StepTwo, resume_seed};
use config::{Dof, Eyes, PerDof, Scenario, TwinParams, derive_seed};
use learning::lqr::LqrError;
use learning::{Agent, Checkpoint, CheckpointError};
use messages::{CableObservationMsg, CameraFrameHeader, LearningStats, Stamp, StepStatus};
use perception::Observer;
use surge_controller::SurgeController;
use thruster_allocator::Allocator;
use vehicle_twin::{Shot, Twin, TwinError};
use vision::VisionError;

/// What one trial gave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrialResult {
    pub trial: u32,
    /// Control steps (the twin's periods) in the trial.
    pub steps: u32,
    /// The cable left the image.
    pub lost: bool,
    /// Frames lost on the way (no command for them).
    pub dropped: u32,
    /// Frames in which perception did not find the cable although it was in view.
    pub missed: u32,
    /// Each behaviour's return over the trial (its reported episode return; the failure reward
    /// included), and its transitions.
    pub returns: PerDof<f64>,
    pub transitions: PerDof<u32>,
    /// Each policy's gain after the trial.
    pub gains: PerDof<[f64; 2]>,
    pub actor_updates: PerDof<u64>,
    /// An evaluation trial of step two (the policies acted without learning).
    pub evaluation: bool,
    /// The mean returns of the evaluation this trial closed (NaN when it closed none), and whether
    /// each behaviour then restored its best policy.
    pub evaluated: PerDof<f64>,
    pub rolled_back: PerDof<bool>,
    /// The best evaluated return so far (NaN before the first evaluation).
    pub best: PerDof<f64>,
    /// The pair's score of the evaluation this trial closed (`learning::pair_score`, on which both
    /// behaviours judged it: -2 for the session's first; NaN when it closed none).
    pub pair_score: f64,
    /// Each behaviour's safety counts after the trial: actor updates shortened, refused; rollbacks.
    pub bounded: PerDof<u64>,
    pub refused: PerDof<u64>,
    pub rollbacks: PerDof<u64>,
}

/// What the behaviours do on the vehicle: learn under step two's protocol (`--step-two`), or act and
/// evaluate (`--step-two --act-only`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Learn,
    Act,
}

impl TrialResult {
    /// The evaluated return of the policy in force after the evaluation this trial closed: the
    /// evaluated one, or the best one when it was restored.
    pub fn in_force(&self) -> PerDof<f64> {
        let pick = |dof: Dof| {
            if *self.rolled_back.get(dof) {
                *self.best.get(dof)
            } else {
                *self.evaluated.get(dof)
            }
        };
        PerDof {
            sway: pick(Dof::Sway),
            yaw: pick(Dof::Yaw),
        }
    }

    /// A DOF's mean reward per transition.
    pub fn per_step(&self, dof: Dof) -> f64 {
        *self.returns.get(dof) / (*self.transitions.get(dof)).max(1) as f64
    }
}

/// One step of a trial, for the state-trace figures (paper Figs. 8 to 11).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TracePoint {
    pub trial: u32,
    pub time_s: f64,
    /// What the behaviours saw (perception's output; NaN for a dropped frame).
    pub x_g: f64,
    pub theta: f64,
    /// What the mounted camera truly saw.
    pub true_x_g: f64,
    pub true_theta: f64,
    /// The commands (0 for a dropped frame: none was given).
    pub sway: f64,
    pub yaw: f64,
    pub surge: f64,
}

/// The twin and the vehicle's cores in one loop.
pub struct TwinWorld {
    twin: Twin,
    observer: Observer,
    behaviours: PerDof<Behaviour>,
    surge: SurgeController,
    allocator: Allocator,
    image: Vec<u8>,
    trace: Option<Vec<TracePoint>>,
}

impl TwinWorld {
    /// A world around existing agents (their learning switch as they come), without step two's
    /// protocol.
    pub fn new(
        scenario: &Scenario,
        twin: &TwinParams,
        agents: PerDof<Agent>,
        eyes: Eyes,
        seed: u64,
    ) -> Result<Self, TwinError> {
        let behaviours = PerDof {
            sway: Behaviour::new(agents.sway),
            yaw: Behaviour::new(agents.yaw),
        };
        Self::with_behaviours(scenario, twin, behaviours, eyes, seed)
    }

    /// A world around existing behaviours.
    pub fn with_behaviours(
        scenario: &Scenario,
        twin: &TwinParams,
        behaviours: PerDof<Behaviour>,
        eyes: Eyes,
        seed: u64,
    ) -> Result<Self, TwinError> {
        let images = eyes == Eyes::Images;
        let twin = Twin::new(scenario, twin, seed, images)?;
        let observer = Observer::new(scenario, eyes).map_err(TwinError::Vision)?;
        let (w, h) = twin.eye().size();
        Ok(TwinWorld {
            twin,
            observer,
            behaviours,
            surge: SurgeController::new(&scenario.surge, &scenario.commanded_model().surge),
            allocator: Allocator::new(&scenario.thrusters),
            image: if images {
                vec![0; w as usize * h as usize]
            } else {
                Vec::new()
            },
            trace: None,
        })
    }

    /// The world of the vehicle mesh's behaviours started with `--initial CHECKPOINT --step-two`
    /// (and `--act-only` for [`Mode::Act`]) under the supervisor's `--seed seed`: each DOF's agent
    /// resumed from the checkpoint, its exploration seeded as the service seeds it, running step
    /// two's protocol with the checkpoint's learning parameters.
    pub fn from_checkpoint(
        scenario: &Scenario,
        twin: &TwinParams,
        checkpoint: &Checkpoint,
        eyes: Eyes,
        seed: u64,
        mode: Mode,
    ) -> Result<Self, FromCheckpointError> {
        let behaviour = |dof: Dof| -> Result<Behaviour, FromCheckpointError> {
            let state = checkpoint
                .get(dof)
                .cloned()
                .ok_or(FromCheckpointError::Missing(dof))?;
            let stream = derive_seed(seed, dof.name());
            let agent_seed = resume_seed(stream, &state);
            let mut agent = Agent::from_state(state, agent_seed)
                .map_err(|e| FromCheckpointError::Invalid(dof, e.to_string()))?;
            let learning = mode == Mode::Learn;
            agent.set_learning(learning);
            let step_two = StepTwo::new(agent.params(), learning, stream, agent_seed);
            Ok(Behaviour::for_step_two(agent, step_two, scenario)?)
        };
        let behaviours = PerDof {
            sway: behaviour(Dof::Sway)?,
            yaw: behaviour(Dof::Yaw)?,
        };
        Ok(TwinWorld::with_behaviours(
            scenario, twin, behaviours, eyes, seed,
        )?)
    }

    pub fn twin(&self) -> &Twin {
        &self.twin
    }

    pub fn agent(&self, dof: Dof) -> &Agent {
        self.behaviours.get(dof).agent()
    }

    pub fn behaviour(&self, dof: Dof) -> &Behaviour {
        self.behaviours.get(dof)
    }

    /// The agents, e.g. to checkpoint them.
    pub fn into_agents(self) -> PerDof<Agent> {
        PerDof {
            sway: self.behaviours.sway.into_agent(),
            yaw: self.behaviours.yaw.into_agent(),
        }
    }

    /// Records the next trials' state traces (see [`TwinWorld::take_trace`]).
    pub fn record(&mut self, on: bool) {
        self.trace = on.then(Vec::new);
    }

    pub fn take_trace(&mut self) -> Vec<TracePoint> {
        self.trace.as_mut().map(std::mem::take).unwrap_or_default()
    }

    /// Runs the current trial to its end; the next call runs the next trial.
    pub fn run_trial(&mut self) -> TrialResult {
        let mut shot = self.twin.start();
        let trial = shot.trial;
        let mut missed = 0;
        let mut stats: PerDof<Option<LearningStats>> = PerDof {
            sway: None,
            yaw: None,
        };
        loop {
            if shot.dropped {
                self.push_trace(&shot, None, [0.0; 3]);
                shot = self.twin.advance(None).0;
                continue;
            }
            let msg = self.perceive(&shot);
            let obs = msg.observation();
            if !obs.found && shot.truth.found == 1 {
                missed += 1;
            }
            let sway = self.behaviours.sway.step(&msg);
            let yaw = self.behaviours.yaw.step(&msg);
            // Each behaviour sees its partner's command, as over the command topics.
            self.behaviours.sway.partner_command(&yaw.command);
            self.behaviours.yaw.partner_command(&sway.command);
            stats.sway = stats.sway.or(sway.stats);
            stats.yaw = stats.yaw.or(yaw.stats);
            let surge = self.surge.command(&obs);
            let commands = [surge, sway.command.value, yaw.command.value];
            self.push_trace(&shot, Some(&obs), commands);
            if shot.status.is_terminal() {
                let (next, end) = self.twin.advance(None);
                debug_assert_eq!(next.trial, trial + 1);
                let end = end.expect("a terminal frame closes its trial");
                // A behaviour that took no step in the trial reports nothing: its state as it is.
                let get = |dof: Dof| {
                    let b = self.behaviours.get(dof);
                    (*stats.get(dof)).unwrap_or_else(|| {
                        let a = b.agent();
                        let safety = a.safety();
                        LearningStats {
                            gain: a.gain(),
                            actor_updates: a.learner().actor_updates(),
                            evaluation: b.trial_kind().is_evaluation() as u8,
                            bounded: safety.bounded,
                            refused: safety.refused,
                            rollbacks: safety.rollbacks,
                            evaluated: f64::NAN,
                            best_evaluated: safety.reference().map_or(f64::NAN, |b| b.evaluated),
                            ..Default::default()
                        }
                    })
                };
                let (sway, yaw) = (get(Dof::Sway), get(Dof::Yaw));
                let scores = Dof::ALL.map(|dof| self.behaviours.get(dof).pair_score(trial));
                // Both behaviours judge the pair on what both saw: one score.
                assert!(
                    scores[0].map(f64::to_bits) == scores[1].map(f64::to_bits)
                        || scores.contains(&None),
                    "trial {trial}: the behaviours judged the pair apart: {scores:?}"
                );
                let pair_score = scores.into_iter().flatten().next().unwrap_or(f64::NAN);
                let both = |f: fn(&LearningStats) -> f64| PerDof {
                    sway: f(&sway),
                    yaw: f(&yaw),
                };
                let count = |f: fn(&LearningStats) -> u64| PerDof {
                    sway: f(&sway),
                    yaw: f(&yaw),
                };
                return TrialResult {
                    trial,
                    steps: end.steps,
                    lost: end.status == StepStatus::Lost,
                    dropped: end.dropped,
                    missed,
                    returns: both(|s| s.episode_return),
                    transitions: PerDof {
                        sway: sway.steps,
                        yaw: yaw.steps,
                    },
                    gains: PerDof {
                        sway: sway.gain,
                        yaw: yaw.gain,
                    },
                    actor_updates: count(|s| s.actor_updates),
                    evaluation: sway.evaluation != 0 && yaw.evaluation != 0,
                    evaluated: both(|s| s.evaluated),
                    best: both(|s| s.best_evaluated),
                    rolled_back: PerDof {
                        sway: sway.rolled_back != 0,
                        yaw: yaw.rolled_back != 0,
                    },
                    bounded: count(|s| s.bounded),
                    refused: count(|s| s.refused),
                    rollbacks: count(|s| s.rollbacks),
                    pair_score,
                };
            }
            let allocation = self.allocator.allocate(model::Forces {
                surge,
                sway: sway.command.value,
                yaw: yaw.command.value,
            });
            shot = self.twin.advance(Some(allocation.setpoints.as_slice())).0;
        }
    }

    /// The camera's frame of `shot` through perception: the observation message the behaviours get.
    fn perceive(&mut self, shot: &Shot) -> CableObservationMsg {
        let (w, h) = self.twin.eye().size();
        let header = CameraFrameHeader {
            stamp: Stamp::new(shot.seq, shot.time_ns(), shot.trial, shot.step, shot.status),
            width: w,
            height: h,
            truth: shot.truth,
            ..Default::default()
        };
        if !self.image.is_empty() {
            self.twin
                .render(&mut self.image)
                .expect("the image buffer has the camera's size");
        }
        self.observer
            .observe(&header, &self.image)
            .expect("the twin renders frames of the camera's size")
            .msg
    }

    fn push_trace(&mut self, shot: &Shot, obs: Option<&model::CableObservation>, c: [f64; 3]) {
        if let Some(trace) = &mut self.trace {
            trace.push(TracePoint {
                trial: shot.trial,
                time_s: shot.step as f64 * self.twin.sample_time_s(),
                x_g: obs.map_or(f64::NAN, |o| o.x_g),
                theta: obs.map_or(f64::NAN, |o| o.theta),
                true_x_g: shot.truth.x_g,
                true_theta: shot.truth.theta,
                surge: c[0],
                sway: c[1],
                yaw: c[2],
            });
        }
    }
}

/// Why a world could not start from a checkpoint.
#[derive(Debug, thiserror::Error)]
pub enum FromCheckpointError {
    #[error("the checkpoint has no {0} entry")]
    Missing(Dof),
    #[error("the checkpoint's {0} entry cannot be resumed: {1}")]
    Invalid(Dof, String),
    #[error("the stability guard cannot be built from the identified model")]
    Guard(#[from] LqrError),
    #[error(transparent)]
    Vision(#[from] VisionError),
    #[error(transparent)]
    Twin(#[from] TwinError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
}
