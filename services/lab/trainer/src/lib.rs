//! Step one in one process: the service cores composed without IPC, and the experiments of the
//! paper's simulation section (Fig. 5's learning curves, the learning-rate sweep, the LQR limit,
//! Figs. 6 and 7's policy maps). Step two in one process too: the twin with the vehicle's cores
//! (`twin_world`), the evaluation protocol (`evaluation`), the twin's limit (`twin_limit`) and the
//! step-two benchmark (`step_two_bench`). The `trainer` binary is its command line.

pub mod evaluation;
pub mod experiment;
pub mod figures;
pub mod progress;
pub mod report;
pub mod step_two_bench;
pub mod twin_limit;
pub mod twin_world;
pub mod world;

use config::{ConfigError, Eyes, LearningParams, ObservationLimits, PerDof, Preset, Scenario};
use learning::Algorithm;
use model::CableObservation;
use simulator::{SimStep, Simulator};
use std::path::Path;
use vision::{SimulatedVision, VisionError};

/// The camera and perception stage of the loop: what the behaviours observe of a simulator step.
pub enum Perceiver {
    Ideal(ObservationLimits),
    Images(Box<SimulatedVision>),
}

impl Perceiver {
    /// The perception stage of a run with this seed seeing through `eyes` (the renderer's noise is
    /// the seed's `render` stream, as the mesh's camera draws it).
    pub fn for_run(scenario: &Scenario, eyes: Eyes, seed: u64) -> Result<Perceiver, VisionError> {
        Ok(match eyes {
            Eyes::Ideal => Perceiver::Ideal(scenario.observation.clone()),
            Eyes::Images => Perceiver::Images(Box::new(SimulatedVision::new(
                scenario,
                config::derive_seed(seed, "render"),
            )?)),
        })
    }

    /// Forgets what was tracked (a new episode starts elsewhere).
    pub fn reset(&mut self) {
        if let Perceiver::Images(vision) = self {
            vision.reset();
        }
    }

    /// What the behaviours observe at this step.
    pub fn observe(&mut self, sim: &Simulator, step: &SimStep) -> CableObservation {
        match self {
            Perceiver::Ideal(limits) => {
                sim.camera().observe_state(&step.state, sim.cable(), limits)
            }
            Perceiver::Images(vision) => vision.observe(&step.state),
        }
    }
}

/// Everything an experiment is configured by.
#[derive(Clone, Debug)]
pub struct Setup {
    pub scenario: Scenario,
    pub learning: LearningParams,
    pub eyes: Eyes,
}

impl Setup {
    /// The setup of `config_dir/scenario.toml` and `config_dir/learning.toml` with a preset applied.
    pub fn load(config_dir: &Path, preset: Preset) -> Result<Setup, ConfigError> {
        Ok(Setup {
            scenario: config::load(&config_dir.join("scenario.toml"))?,
            learning: config::load::<LearningParams>(&config_dir.join("learning.toml"))?
                .with_preset(preset),
            eyes: Eyes::Ideal,
        })
    }

    /// This setup seeing through `kind`; checks that the renderer and perception can be built.
    pub fn with_eyes(mut self, kind: Eyes) -> Result<Setup, VisionError> {
        if kind == Eyes::Images {
            SimulatedVision::new(&self.scenario, 0)?;
        }
        self.eyes = kind;
        Ok(self)
    }

    /// The perception stage for a run with this seed (the renderer's noise is its own stream).
    pub fn perceiver(&self, seed: u64) -> Perceiver {
        Perceiver::for_run(&self.scenario, self.eyes, seed)
            .expect("the vision configuration was checked by Setup::with_eyes")
    }

    /// Sets the learning rate of `algorithm`.
    pub fn set_alpha(&mut self, algorithm: Algorithm, alpha: PerDof<f64>) {
        match algorithm {
            Algorithm::Nac => self.learning.nac.alpha = alpha,
            Algorithm::Gpomdp => self.learning.gpomdp.alpha = alpha,
        }
    }

    /// The learning rate of `algorithm`.
    pub fn alpha(&self, algorithm: Algorithm) -> PerDof<f64> {
        match algorithm {
            Algorithm::Nac => self.learning.nac.alpha,
            Algorithm::Gpomdp => self.learning.gpomdp.alpha,
        }
    }
}
