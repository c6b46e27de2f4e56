//! What step one hands to step two: each learned DOF's policy, learner statistics, counters and
//! parameters, in a file that is checked on the way in and replaced atomically on the way out.
//!
//! File layout (all integers little-endian):
//!
//! | bytes | content |
//! |---|---|
//! | 8  | magic `CTRKCKPT` |
//! | 4  | format version (u32), [`FORMAT_VERSION`] |
//! | 8  | payload length (u64) |
//! | 4  | CRC-32 (IEEE) of the payload |
//! | .. | payload: a [`Checkpoint`] encoded with `bincode` 2 (serde, standard configuration) |
//!
//! The payload holds plain arrays, not `nalgebra` types, so the format does not change with that
//! crate's serialisation. It does embed the `config` crate's `LearningParams` and `QuadraticCost`,
//! and bincode encodes fields by position: adding, removing or reordering a field of any type in the
//! payload changes the format, and must bump [`FORMAT_VERSION`]. A reader refuses a file written by
//! a newer format rather than guessing; it reads the older ones:
//!
//! - version 1: no step-two parameters (`LearningParams::evaluation`, `safety`) and no safety state
//!   in an agent's state; read with their defaults (nothing evaluated, nothing refused yet).
//! - version 2: no count of the lost trials of the evaluation in progress
//!   (`SafetyState::evaluation_lost`); read as none lost.
//! - version 3: no pair in the best policy (`BestPolicy::cost`, `trial`) and no pair's cost of the
//!   evaluation in progress or weights of the pair's score (`SafetyState::evaluation_cost`,
//!   `scale`); read with the best's pair unknown (the next evaluation judged replaces it) and the
//!   weights taken from the next evaluation.
//! - version 4: no parameters of step two's own learner (`LearningParams::step_two`); read with
//!   their defaults.
//! - versions 4 and 5: the pair's costs (`BestPolicy::cost`, `SafetyState::evaluation_cost`,
//!   `scale`) are state costs only, without the action term; read like version 3's, with the
//!   best's pair unknown and the weights taken from the next evaluation.
//! - versions 5 and 6: a trust region of one fixed bound (no `TrustRegionParams::min_action_change`,
//!   no adapted bound `SafetyState::action_change_bound`); read with the smallest bound equal to
//!   the largest, so the bound stays as it was.
//! - version 7: no start of the session (`SafetyState::start`, `start_lost`); read with the start
//!   unknown, so that before a best a failed evaluation restores nothing, as it did then.
//! - version 8: the current format.
//!
//! Saving writes a temporary file in the target's directory, syncs it, renames it over the target and
//! syncs the directory: a crash leaves either the old checkpoint or the new one, never a mix.

use crate::learner::Algorithm;
use crate::safety::SafetyState;
use config::{Dof, Invalid, LearningParams, QuadraticCost, Validate};
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

/// The first bytes of every checkpoint file.
pub const MAGIC: [u8; 8] = *b"CTRKCKPT";
/// The format this code writes, and the newest it reads.
pub const FORMAT_VERSION: u32 = 8;
/// Magic, version, payload length, CRC.
pub const HEADER_LEN: usize = 8 + 4 + 8 + 4;

/// The checkpoint of one or both learned DOFs.
///
/// The in-process trainer writes both; each behaviour service loads its own DOF
/// ([`Checkpoint::load_dof`]) and saves its own (a file per service avoids two writers racing).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// The sway agent, if saved.
    pub sway: Option<AgentState>,
    /// The yaw agent, if saved.
    pub yaw: Option<AgentState>,
}

/// Everything needed to resume one DOF's agent (see [`crate::Agent::checkpoint`]).
///
/// Fields are public so that step two can, deliberately, resume with other parameters
/// (e.g. a different learning rate on the vehicle) before calling [`crate::Agent::from_state`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AgentState {
    /// The DOF this agent learns (and the checkpoint slot it belongs in).
    pub dof: Dof,
    /// The learning parameters in force (the agent uses its DOF's entries).
    pub params: LearningParams,
    /// The DOF's reward.
    pub cost: QuadraticCost,
    /// The observation box `|x_i| <= state_max[i]`, which also sets the failure reward.
    pub state_max: [f64; 2],
    /// The actor.
    pub policy: PolicyState,
    /// The learner's statistics.
    pub learner: LearnerState,
    /// Transitions completed (learning or not).
    pub steps: u64,
    /// Episodes completed.
    pub episodes: u64,
    /// Step two's safety layer: its counts and the best policy evaluated so far.
    pub safety: SafetyState,
}

impl AgentState {
    /// The algorithm the learner state belongs to.
    pub fn algorithm(&self) -> Algorithm {
        match self.learner {
            LearnerState::Nac(_) => Algorithm::Nac,
            LearnerState::Gpomdp(_) => Algorithm::Gpomdp,
        }
    }

    /// Checks that the state can drive an agent: valid parameters, a positive box and sigma, finite
    /// numbers everywhere.
    pub fn validate(&self) -> Result<(), AgentStateError> {
        self.params.validate("params")?;
        self.cost.validate("cost")?;
        for (i, m) in self.state_max.iter().enumerate() {
            if !(m.is_finite() && *m > 0.0) {
                return Err(Invalid::new(
                    format!("state_max[{i}]"),
                    m,
                    "must be a finite number > 0",
                )
                .into());
            }
        }
        if !(self.policy.sigma.is_finite() && self.policy.sigma > 0.0) {
            return Err(Invalid::new(
                "policy.sigma",
                self.policy.sigma,
                "must be a finite number > 0",
            )
            .into());
        }
        finite("policy.gain", &self.policy.gain)?;
        match &self.learner {
            LearnerState::Nac(s) => {
                for (i, row) in s.a.iter().enumerate() {
                    finite(&format!("learner.a[{i}]"), row)?;
                }
                finite("learner.b", &s.b)?;
                finite("learner.z", &s.z)?;
                finite("learner.v", &s.v)?;
                finite("learner.w", &s.w)?;
                if s.w_history.len() > config::MAX_ANGLE_LAG {
                    return Err(Invalid::new(
                        "learner.w_history",
                        s.w_history.len(),
                        format!("holds at most {} estimates", config::MAX_ANGLE_LAG),
                    )
                    .into());
                }
                finite("learner.mass", &[s.mass])?;
                for (i, w) in s.w_history.iter().enumerate() {
                    finite(&format!("learner.w_history[{i}]"), w)?;
                }
            }
            LearnerState::Gpomdp(s) => finite("learner.z", &s.z)?,
        }
        if !self.safety.is_valid() {
            return Err(Invalid::new(
                "safety",
                format!("{:?}", self.safety),
                "the best policy's gain and the evaluation in progress must be finite",
            )
            .into());
        }
        Ok(())
    }
}

fn finite(key: &str, values: &[f64]) -> Result<(), AgentStateError> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(Invalid::new(format!("{key}[{i}]"), values[i], "must be finite").into()),
    }
}

/// Why an [`AgentState`] cannot drive an agent.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid agent state: {0}")]
pub struct AgentStateError(#[from] pub Invalid);

/// The policy `u ~ N(Kx, sigma^2)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PolicyState {
    /// K for (position, rate).
    pub gain: [f64; 2],
    /// The exploration's standard deviation.
    pub sigma: f64,
}

/// The learner's state; the variant names the algorithm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum LearnerState {
    /// NAC (boxed: its statistics are some 400 bytes, OLPOMDP's a few words).
    Nac(Box<NacState>),
    /// OLPOMDP.
    Gpomdp(GpomdpState),
}

/// NAC's statistics for a 2-D state (6 unknowns `[v; w]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NacState {
    /// LSTD's `A`, row by row.
    pub a: [[f64; 6]; 6],
    /// LSTD's `b`.
    pub b: [f64; 6],
    /// The eligibility trace.
    pub z: [f64; 6],
    /// The critic's value weights for `[x1^2, x1 x2, x2^2, 1]`.
    pub v: [f64; 4],
    /// The last natural gradient.
    pub w: [f64; 2],
    /// The last natural gradients, oldest first, for the angle test (at most `MAX_ANGLE_LAG`).
    pub w_history: Vec<[f64; 2]>,
    /// Transitions in the statistics, forgotten like them.
    pub mass: f64,
    /// Transitions learned from.
    pub steps: u64,
    /// Actor updates made.
    pub actor_updates: u64,
}

/// OLPOMDP's state.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GpomdpState {
    /// The eligibility trace.
    pub z: [f64; 2],
    /// Transitions learned from.
    pub steps: u64,
    /// Actor updates made (one per transition).
    pub actor_updates: u64,
}

/// What is wrong with a checkpoint file. Every variant names the file (`path`).
#[derive(Debug, thiserror::Error)]
#[allow(missing_docs)] // the fields are named for what they hold; the variants say what happened
pub enum CheckpointError {
    /// The file does not start with the checkpoint magic.
    #[error("{} is not a cabletrack checkpoint (bad magic bytes)", path.display())]
    NotACheckpoint { path: PathBuf },
    /// The file ends before the header or the payload it announces.
    #[error("checkpoint {} is truncated: {found} bytes, expected {expected}", path.display())]
    Truncated {
        path: PathBuf,
        expected: u64,
        found: u64,
    },
    /// The bytes do not check out.
    #[error("checkpoint {} is corrupt: {corruption}", path.display())]
    Corrupt {
        path: PathBuf,
        corruption: Corruption,
    },
    /// Written by a newer format than this build reads.
    #[error("checkpoint {} has format version {found}; this build reads up to {supported}", path.display())]
    NewerVersion {
        path: PathBuf,
        found: u32,
        supported: u32,
    },
    /// The payload passed its checksum but does not decode as a checkpoint.
    #[error("checkpoint {} does not decode", path.display())]
    Decode {
        path: PathBuf,
        #[source]
        source: bincode::error::DecodeError,
    },
    /// The checkpoint could not be encoded.
    #[error("cannot encode checkpoint for {}", path.display())]
    Encode {
        path: PathBuf,
        #[source]
        source: bincode::error::EncodeError,
    },
    /// The checkpoint decodes but holds values an agent cannot run with.
    #[error("checkpoint {} holds an invalid {dof} state", path.display())]
    Invalid {
        path: PathBuf,
        dof: Dof,
        #[source]
        source: AgentStateError,
    },
    /// The checkpoint has no state for the DOF asked for.
    #[error("checkpoint {} has no {dof} state", path.display())]
    MissingDof { path: PathBuf, dof: Dof },
    /// Reading or writing failed.
    #[error("cannot {action} checkpoint {}", path.display())]
    Io {
        path: PathBuf,
        action: &'static str,
        #[source]
        source: io::Error,
    },
}

/// How a checkpoint's bytes fail their checks.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Corruption {
    /// The payload's CRC-32 is not the one in the header.
    #[error("payload checksum {computed:#010x} does not match the stored {stored:#010x}")]
    Checksum {
        /// From the header.
        stored: u32,
        /// Of the payload as read.
        computed: u32,
    },
    /// More bytes than the header announces.
    #[error("{extra} bytes after the payload")]
    TrailingBytes {
        /// How many.
        extra: u64,
    },
    /// A version number no format ever had (0).
    #[error("format version {0} does not exist")]
    UnknownVersion(u32),
}

impl Checkpoint {
    /// A checkpoint holding one DOF.
    pub fn single(state: AgentState) -> Self {
        let mut c = Checkpoint::default();
        c.insert(state);
        c
    }

    /// Puts `state` in its DOF's slot, returning what was there.
    pub fn insert(&mut self, state: AgentState) -> Option<AgentState> {
        self.slot_mut(state.dof).replace(state)
    }

    /// The state of `dof`, if present.
    pub fn get(&self, dof: Dof) -> Option<&AgentState> {
        match dof {
            Dof::Sway => self.sway.as_ref(),
            Dof::Yaw => self.yaw.as_ref(),
        }
    }

    /// Takes the state of `dof` out.
    pub fn take(&mut self, dof: Dof) -> Option<AgentState> {
        self.slot_mut(dof).take()
    }

    fn slot_mut(&mut self, dof: Dof) -> &mut Option<AgentState> {
        match dof {
            Dof::Sway => &mut self.sway,
            Dof::Yaw => &mut self.yaw,
        }
    }

    /// Writes the checkpoint to `path` atomically (see the module docs).
    pub fn save(&self, path: &Path) -> Result<(), CheckpointError> {
        self.save_with(path, |file, bytes| file.write_all(bytes))
    }

    /// [`save`](Self::save) with the write of the file's bytes injected, so a test can fail it half-way.
    pub(crate) fn save_with(
        &self,
        path: &Path,
        write: impl FnOnce(&mut File, &[u8]) -> io::Result<()>,
    ) -> Result<(), CheckpointError> {
        // Never replace a good checkpoint with one that would not load.
        self.check(path)?;
        let bytes = self.to_bytes().map_err(|source| CheckpointError::Encode {
            path: path.to_owned(),
            source,
        })?;
        write_atomically(path, &bytes, write)?;
        tracing::debug!(path = %path.display(), bytes = bytes.len(), "checkpoint saved");
        Ok(())
    }

    /// Reads and checks the checkpoint at `path`.
    pub fn load(path: &Path) -> Result<Self, CheckpointError> {
        let io_err = |action| {
            move |source| CheckpointError::Io {
                path: path.to_owned(),
                action,
                source,
            }
        };
        let mut file = File::open(path).map_err(io_err("open"))?;
        let mut header = Vec::with_capacity(HEADER_LEN);
        (&mut file)
            .take(HEADER_LEN as u64)
            .read_to_end(&mut header)
            .map_err(io_err("read"))?;
        let magic_seen = header.len().min(MAGIC.len());
        if header[..magic_seen] != MAGIC[..magic_seen] {
            return Err(CheckpointError::NotACheckpoint {
                path: path.to_owned(),
            });
        }
        if header.len() < HEADER_LEN {
            return Err(CheckpointError::Truncated {
                path: path.to_owned(),
                expected: HEADER_LEN as u64,
                found: header.len() as u64,
            });
        }
        let version = u32::from_le_bytes(header[8..12].try_into().expect("4 bytes"));
        let payload_len = u64::from_le_bytes(header[12..20].try_into().expect("8 bytes"));
        let stored_crc = u32::from_le_bytes(header[20..24].try_into().expect("4 bytes"));
        // The version decides how to read the rest, so it is checked before anything else.
        if version > FORMAT_VERSION {
            return Err(CheckpointError::NewerVersion {
                path: path.to_owned(),
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        let corrupt = |corruption| CheckpointError::Corrupt {
            path: path.to_owned(),
            corruption,
        };
        if version == 0 {
            return Err(corrupt(Corruption::UnknownVersion(version)));
        }
        // Read at most one byte more than announced: enough to tell "trailing bytes" from "exact".
        let mut payload = Vec::new();
        (&mut file)
            .take(payload_len.saturating_add(1))
            .read_to_end(&mut payload)
            .map_err(io_err("read"))?;
        let found = payload.len() as u64;
        if found < payload_len {
            return Err(CheckpointError::Truncated {
                path: path.to_owned(),
                // The length is the file's word: it may be anything up to u64::MAX.
                expected: (HEADER_LEN as u64).saturating_add(payload_len),
                found: HEADER_LEN as u64 + found,
            });
        }
        if found > payload_len {
            let total = file.metadata().map_err(io_err("inspect"))?.len();
            let extra = total.saturating_sub(HEADER_LEN as u64 + payload_len);
            return Err(corrupt(Corruption::TrailingBytes { extra }));
        }
        let computed = crc32fast::hash(&payload);
        if computed != stored_crc {
            return Err(corrupt(Corruption::Checksum {
                stored: stored_crc,
                computed,
            }));
        }
        let decode_err = |source| CheckpointError::Decode {
            path: path.to_owned(),
            source,
        };
        let (mut checkpoint, used): (Checkpoint, usize) = if version == 1 {
            let (old, used): (v1::Checkpoint, usize) =
                bincode::serde::decode_from_slice(&payload, bincode::config::standard())
                    .map_err(decode_err)?;
            (old.into(), used)
        } else if version == 2 {
            let (old, used): (v2::Checkpoint, usize) =
                bincode::serde::decode_from_slice(&payload, bincode::config::standard())
                    .map_err(decode_err)?;
            (old.into(), used)
        } else if version == 3 {
            let (old, used): (v3::Checkpoint, usize) =
                bincode::serde::decode_from_slice(&payload, bincode::config::standard())
                    .map_err(decode_err)?;
            (old.into(), used)
        } else if version == 4 {
            let (old, used): (v4::Checkpoint, usize) =
                bincode::serde::decode_from_slice(&payload, bincode::config::standard())
                    .map_err(decode_err)?;
            (old.into(), used)
        } else if version == 5 || version == 6 {
            let (old, used): (v6::Checkpoint, usize) =
                bincode::serde::decode_from_slice(&payload, bincode::config::standard())
                    .map_err(decode_err)?;
            (old.into(), used)
        } else if version == 7 {
            let (old, used): (v7::Checkpoint, usize) =
                bincode::serde::decode_from_slice(&payload, bincode::config::standard())
                    .map_err(decode_err)?;
            (old.into(), used)
        } else {
            bincode::serde::decode_from_slice(&payload, bincode::config::standard())
                .map_err(decode_err)?
        };
        if used != payload.len() {
            return Err(corrupt(Corruption::TrailingBytes {
                extra: (payload.len() - used) as u64,
            }));
        }
        if version == 4 || version == 5 {
            for s in [checkpoint.sway.as_mut(), checkpoint.yaw.as_mut()]
                .into_iter()
                .flatten()
            {
                s.safety = forget_pair_costs(s.safety);
            }
        }
        checkpoint.check(path)?;
        Ok(checkpoint)
    }

    /// Each present state is valid and sits in its own DOF's slot.
    fn check(&self, path: &Path) -> Result<(), CheckpointError> {
        for dof in Dof::ALL {
            if let Some(state) = self.get(dof) {
                let checked = if state.dof != dof {
                    let reason = format!("stored in the {dof} slot");
                    Err(AgentStateError(Invalid::new("dof", state.dof, reason)))
                } else {
                    state.validate()
                };
                if let Err(source) = checked {
                    return Err(CheckpointError::Invalid {
                        path: path.to_owned(),
                        dof,
                        source,
                    });
                }
            }
        }
        Ok(())
    }

    /// Loads `path` and takes the state of `dof` from it.
    pub fn load_dof(path: &Path, dof: Dof) -> Result<AgentState, CheckpointError> {
        Checkpoint::load(path)?
            .take(dof)
            .ok_or_else(|| CheckpointError::MissingDof {
                path: path.to_owned(),
                dof,
            })
    }

    /// The file's bytes: header and payload.
    fn to_bytes(&self) -> Result<Vec<u8>, bincode::error::EncodeError> {
        let payload = bincode::serde::encode_to_vec(self, bincode::config::standard())?;
        let mut bytes = Vec::with_capacity(HEADER_LEN + payload.len());
        bytes.extend_from_slice(&MAGIC);
        bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        bytes.extend_from_slice(&payload);
        Ok(bytes)
    }
}

/// The payload of format version 1 (see the module docs), read into the current types.
mod v1 {
    use super::{LearnerState, PolicyState};
    use config::{Dof, GpomdpParams, NacParams, PolicyParams, QuadraticCost};
    use serde::{Deserialize, Serialize};

    #[derive(Serialize, Deserialize)]
    pub struct Checkpoint {
        pub sway: Option<AgentState>,
        pub yaw: Option<AgentState>,
    }

    #[derive(Serialize, Deserialize)]
    pub struct AgentState {
        pub dof: Dof,
        pub params: LearningParams,
        pub cost: QuadraticCost,
        pub state_max: [f64; 2],
        pub policy: PolicyState,
        pub learner: LearnerState,
        pub steps: u64,
        pub episodes: u64,
    }

    #[derive(Serialize, Deserialize)]
    pub struct LearningParams {
        pub policy: PolicyParams,
        pub nac: NacParams,
        pub gpomdp: GpomdpParams,
    }

    impl From<AgentState> for super::AgentState {
        fn from(s: AgentState) -> Self {
            super::AgentState {
                dof: s.dof,
                params: config::LearningParams {
                    policy: s.params.policy,
                    nac: s.params.nac,
                    gpomdp: s.params.gpomdp,
                    ..Default::default()
                },
                cost: s.cost,
                state_max: s.state_max,
                policy: s.policy,
                learner: s.learner,
                steps: s.steps,
                episodes: s.episodes,
                safety: Default::default(),
            }
        }
    }

    impl From<Checkpoint> for super::Checkpoint {
        fn from(c: Checkpoint) -> Self {
            super::Checkpoint {
                sway: c.sway.map(Into::into),
                yaw: c.yaw.map(Into::into),
            }
        }
    }
}

/// The payload of format versions 2 to 6 (see the module docs): today's agent state but for the
/// safety layer's, `S`, which each of them has its own, and the learning parameters `P`: before
/// step two's learner had its own ([`super::v4::LearningParams`], versions 2 to 4), or before the
/// trust region could adapt ([`super::v6::LearningParams`], versions 5 and 6).
mod older {
    use super::{LearnerState, PolicyState};
    use config::{Dof, QuadraticCost};
    use serde::{Deserialize, Serialize};

    #[derive(Serialize, Deserialize)]
    pub struct Checkpoint<S, P = super::v4::LearningParams> {
        pub sway: Option<AgentState<S, P>>,
        pub yaw: Option<AgentState<S, P>>,
    }

    #[derive(Serialize, Deserialize)]
    pub struct AgentState<S, P = super::v4::LearningParams> {
        pub dof: Dof,
        pub params: P,
        pub cost: QuadraticCost,
        pub state_max: [f64; 2],
        pub policy: PolicyState,
        pub learner: LearnerState,
        pub steps: u64,
        pub episodes: u64,
        pub safety: S,
    }

    impl<S, P> From<AgentState<S, P>> for super::AgentState
    where
        S: Into<crate::safety::SafetyState>,
        P: Into<config::LearningParams>,
    {
        fn from(s: AgentState<S, P>) -> Self {
            super::AgentState {
                dof: s.dof,
                params: s.params.into(),
                cost: s.cost,
                state_max: s.state_max,
                policy: s.policy,
                learner: s.learner,
                steps: s.steps,
                episodes: s.episodes,
                safety: s.safety.into(),
            }
        }
    }

    impl<S, P> From<Checkpoint<S, P>> for super::Checkpoint
    where
        S: Into<crate::safety::SafetyState>,
        P: Into<config::LearningParams>,
    {
        fn from(c: Checkpoint<S, P>) -> Self {
            super::Checkpoint {
                sway: c.sway.map(Into::into),
                yaw: c.yaw.map(Into::into),
            }
        }
    }
}

/// Format version 2: the safety layer's state without the lost trials of an evaluation.
mod v2 {
    use serde::{Deserialize, Serialize};

    pub type Checkpoint = super::older::Checkpoint<SafetyState>;
    #[cfg(test)]
    pub type AgentState = super::older::AgentState<SafetyState>;

    #[derive(Clone, Copy, Serialize, Deserialize)]
    pub struct SafetyState {
        pub bounded: u64,
        pub refused: u64,
        pub rollbacks: u64,
        pub evaluations: u64,
        pub best: Option<super::v3::BestPolicy>,
        pub evaluation_sum: f64,
        pub evaluation_trials: u32,
    }

    impl From<SafetyState> for crate::safety::SafetyState {
        fn from(f: SafetyState) -> Self {
            super::v3::SafetyState {
                bounded: f.bounded,
                refused: f.refused,
                rollbacks: f.rollbacks,
                evaluations: f.evaluations,
                best: f.best,
                evaluation_sum: f.evaluation_sum,
                evaluation_trials: f.evaluation_trials,
                evaluation_lost: 0,
            }
            .into()
        }
    }
}

/// Format version 3: the safety layer's state with one DOF's best policy (before pairs).
mod v3 {
    use config::PerDof;
    use serde::{Deserialize, Serialize};

    pub type Checkpoint = super::older::Checkpoint<SafetyState>;
    #[cfg(test)]
    pub type AgentState = super::older::AgentState<SafetyState>;

    #[derive(Clone, Copy, Serialize, Deserialize)]
    pub struct SafetyState {
        pub bounded: u64,
        pub refused: u64,
        pub rollbacks: u64,
        pub evaluations: u64,
        pub best: Option<BestPolicy>,
        pub evaluation_sum: f64,
        pub evaluation_trials: u32,
        pub evaluation_lost: u32,
    }

    /// The best policy before pairs: one DOF's gain and return.
    #[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
    pub struct BestPolicy {
        pub gain: [f64; 2],
        pub evaluated: f64,
    }

    impl From<SafetyState> for crate::safety::SafetyState {
        fn from(f: SafetyState) -> Self {
            crate::safety::SafetyState {
                bounded: f.bounded,
                refused: f.refused,
                rollbacks: f.rollbacks,
                evaluations: f.evaluations,
                best: f.best.map(|b| crate::safety::BestPolicy {
                    gain: b.gain,
                    evaluated: b.evaluated,
                    cost: PerDof::both(f64::INFINITY),
                    trial: u32::MAX,
                }),
                // The pair's cost of an evaluation in progress is unknown: it starts again
                // empty, and as it misses trials it is not judged.
                evaluation_sum: 0.0,
                evaluation_trials: 0,
                evaluation_lost: 0,
                evaluation_cost: PerDof::default(),
                scale: PerDof::default(),
                action_change_bound: 0.0,
                start: None,
                start_lost: 0,
            }
        }
    }
}

/// Format version 4: today's safety state, the learning parameters without step two's learner's
/// (`LearningParams::step_two`), read with their defaults.
mod v4 {
    use super::v6::SafetyParams;
    use config::{EvaluationParams, GpomdpParams, NacParams, PolicyParams};
    use serde::{Deserialize, Serialize};

    pub type Checkpoint = super::older::Checkpoint<crate::safety::SafetyState>;
    #[cfg(test)]
    pub type AgentState = super::older::AgentState<crate::safety::SafetyState>;

    #[derive(Clone, Serialize, Deserialize)]
    pub struct LearningParams {
        pub policy: PolicyParams,
        pub nac: NacParams,
        pub gpomdp: GpomdpParams,
        pub evaluation: EvaluationParams,
        pub safety: SafetyParams,
    }

    impl From<LearningParams> for config::LearningParams {
        fn from(p: LearningParams) -> Self {
            config::LearningParams {
                policy: p.policy,
                nac: p.nac,
                gpomdp: p.gpomdp,
                evaluation: p.evaluation,
                safety: p.safety.into(),
                ..Default::default()
            }
        }
    }
}

/// Formats 5 and 6: the trust region of one fixed bound (see the module docs), read with the
/// smallest bound equal to the largest and no bound adapted yet.
mod v6 {
    use crate::safety::BestPolicy;
    use config::{
        EvaluationParams, GpomdpParams, NacParams, PerDof, PolicyParams, RollbackParams,
        StabilityParams, StepTwoParams,
    };
    use serde::{Deserialize, Serialize};

    pub type Checkpoint = super::older::Checkpoint<SafetyState, LearningParams>;
    #[cfg(test)]
    pub type AgentState = super::older::AgentState<SafetyState, LearningParams>;

    #[derive(Clone, Serialize, Deserialize)]
    pub struct LearningParams {
        pub policy: PolicyParams,
        pub nac: NacParams,
        pub gpomdp: GpomdpParams,
        pub evaluation: EvaluationParams,
        pub safety: SafetyParams,
        pub step_two: StepTwoParams,
    }

    #[derive(Clone, Serialize, Deserialize)]
    pub struct SafetyParams {
        pub trust_region: TrustRegionParams,
        pub stability: StabilityParams,
        pub rollback: RollbackParams,
    }

    #[derive(Clone, Serialize, Deserialize)]
    pub struct TrustRegionParams {
        pub enabled: bool,
        pub max_action_change: f64,
    }

    #[derive(Clone, Copy, Serialize, Deserialize)]
    pub struct SafetyState {
        pub bounded: u64,
        pub refused: u64,
        pub rollbacks: u64,
        pub evaluations: u64,
        pub best: Option<BestPolicy>,
        pub evaluation_sum: f64,
        pub evaluation_trials: u32,
        pub evaluation_lost: u32,
        pub evaluation_cost: PerDof<f64>,
        pub scale: PerDof<f64>,
    }

    impl From<SafetyParams> for config::SafetyParams {
        fn from(p: SafetyParams) -> Self {
            let tr = p.trust_region;
            config::SafetyParams {
                trust_region: config::TrustRegionParams {
                    enabled: tr.enabled,
                    max_action_change: tr.max_action_change,
                    min_action_change: tr.max_action_change,
                },
                stability: p.stability,
                rollback: p.rollback,
            }
        }
    }

    impl From<SafetyState> for crate::safety::SafetyState {
        fn from(f: SafetyState) -> Self {
            crate::safety::SafetyState {
                bounded: f.bounded,
                refused: f.refused,
                rollbacks: f.rollbacks,
                evaluations: f.evaluations,
                best: f.best,
                evaluation_sum: f.evaluation_sum,
                evaluation_trials: f.evaluation_trials,
                evaluation_lost: f.evaluation_lost,
                evaluation_cost: f.evaluation_cost,
                scale: f.scale,
                action_change_bound: 0.0,
                start: None,
                start_lost: 0,
            }
        }
    }

    impl From<LearningParams> for config::LearningParams {
        fn from(p: LearningParams) -> Self {
            config::LearningParams {
                policy: p.policy,
                nac: p.nac,
                gpomdp: p.gpomdp,
                evaluation: p.evaluation,
                safety: p.safety.into(),
                step_two: p.step_two,
            }
        }
    }
}

/// Format version 7: today's parameters; the safety state without the session's start.
mod v7 {
    use serde::{Deserialize, Serialize};

    pub type Checkpoint = super::older::Checkpoint<SafetyState, config::LearningParams>;
    #[cfg(test)]
    pub type AgentState = super::older::AgentState<SafetyState, config::LearningParams>;

    /// Format 6's fields, then the adapted bound: bincode writes a nested struct's fields in
    /// place, so this is format 7's layout.
    #[derive(Clone, Copy, Serialize, Deserialize)]
    pub struct SafetyState {
        pub fixed: super::v6::SafetyState,
        pub action_change_bound: f64,
    }

    impl From<SafetyState> for crate::safety::SafetyState {
        fn from(f: SafetyState) -> Self {
            crate::safety::SafetyState {
                action_change_bound: f.action_change_bound,
                ..f.fixed.into()
            }
        }
    }
}

/// A safety state whose pair's costs left out the action term (formats 4 and 5), as one that
/// knows none: the best's pair unknown (infinitely costly: the next evaluation judged replaces
/// it), no weights (the next evaluation's costs are), the evaluation in progress started again.
fn forget_pair_costs(s: SafetyState) -> SafetyState {
    SafetyState {
        best: s.best.map(|b| crate::safety::BestPolicy {
            cost: config::PerDof::both(f64::INFINITY),
            ..b
        }),
        evaluation_sum: 0.0,
        evaluation_trials: 0,
        evaluation_lost: 0,
        evaluation_cost: config::PerDof::default(),
        scale: config::PerDof::default(),
        ..s
    }
}

/// Replaces `path` with `bytes` (`durable::replace`): temporary file, fsync, rename, fsync of the
/// directory. On failure before the rename the temporary file is removed and the old file is
/// untouched.
fn write_atomically(
    path: &Path,
    bytes: &[u8],
    write: impl FnOnce(&mut File, &[u8]) -> io::Result<()>,
) -> Result<(), CheckpointError> {
    durable::replace_with(path, |file| write(file, bytes)).map_err(|e| CheckpointError::Io {
        path: e.path,
        action: e.action,
        source: e.source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::agent::Agent;
    use config::Rewards;
    use config::StepStatus;
    use std::fs;

    /// An agent that has learned something, so every field of its state is non-trivial.
    fn trained(dof: Dof, algorithm: Algorithm) -> AgentState {
        let params = LearningParams::default();
        let cost = *Rewards::default().of(dof);
        let mut agent = Agent::new(dof, algorithm, &params, cost, [0.5, 0.5], 3);
        let mut x = [0.3, 0.0];
        for t in 0..500 {
            let kind = if t % 100 == 99 {
                StepStatus::TimeLimit
            } else {
                StepStatus::Running
            };
            let u = agent.step(x, kind).action;
            x = [
                (0.95 * x[0] + 0.1 * u).clamp(-0.5, 0.5),
                (0.5 * x[1] + 0.2 * u).clamp(-0.5, 0.5),
            ];
            if kind == StepStatus::TimeLimit {
                x = [-0.3, 0.1];
            }
        }
        // Mid-episode: the trace is non-zero too.
        agent.step(x, StepStatus::Running);
        agent.step(x, StepStatus::Running);
        agent.checkpoint()
    }

    fn both() -> Checkpoint {
        let mut c = Checkpoint::single(trained(Dof::Sway, Algorithm::Nac));
        c.insert(trained(Dof::Yaw, Algorithm::Gpomdp));
        c
    }

    #[test]
    fn round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("step-one.ckpt");
        let c = both();
        let LearnerState::Nac(nac) = &c.sway.as_ref().unwrap().learner else {
            panic!("sway runs NAC")
        };
        assert!(
            nac.actor_updates > 0 && nac.z.iter().any(|z| *z != 0.0),
            "the fixture must have learned"
        );
        c.save(&path).unwrap();
        assert_eq!(Checkpoint::load(&path).unwrap(), c);
        assert_eq!(
            Checkpoint::load_dof(&path, Dof::Yaw).unwrap(),
            *c.get(Dof::Yaw).unwrap()
        );
        // Saving again replaces the file.
        let mut one = c.clone();
        one.take(Dof::Yaw);
        one.save(&path).unwrap();
        assert_eq!(Checkpoint::load(&path).unwrap(), one);
        assert!(matches!(
            Checkpoint::load_dof(&path, Dof::Yaw),
            Err(CheckpointError::MissingDof { dof: Dof::Yaw, .. })
        ));
    }

    fn saved_bytes() -> (tempfile::TempDir, PathBuf, Vec<u8>) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.ckpt");
        both().save(&path).unwrap();
        let bytes = fs::read(&path).unwrap();
        (dir, path, bytes)
    }

    #[test]
    fn a_flipped_payload_byte_is_corrupt() {
        let (_dir, path, mut bytes) = saved_bytes();
        let i = HEADER_LEN + (bytes.len() - HEADER_LEN) / 2;
        bytes[i] ^= 0x10;
        fs::write(&path, &bytes).unwrap();
        let err = Checkpoint::load(&path).unwrap_err();
        assert!(
            matches!(&err, CheckpointError::Corrupt { corruption: Corruption::Checksum { .. }, path: p } if *p == path),
            "{err}"
        );
        // A flipped stored checksum is the same failure.
        let (_dir, path, mut bytes) = saved_bytes();
        bytes[21] ^= 0x01;
        fs::write(&path, &bytes).unwrap();
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::Corrupt { .. })
        ));
    }

    #[test]
    fn a_short_file_is_truncated() {
        let (_dir, path, bytes) = saved_bytes();
        fs::write(&path, &bytes[..bytes.len() - 7]).unwrap();
        match Checkpoint::load(&path).unwrap_err() {
            CheckpointError::Truncated {
                expected,
                found,
                path: p,
            } => {
                assert_eq!(
                    (expected, found),
                    (bytes.len() as u64, bytes.len() as u64 - 7)
                );
                assert_eq!(p, path);
            }
            other => panic!("expected Truncated, got {other}"),
        }
        // Shorter than the header, but the magic fits: truncated, not foreign.
        fs::write(&path, &bytes[..10]).unwrap();
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::Truncated {
                expected: 24,
                found: 10,
                ..
            })
        ));
        fs::write(&path, &bytes[..3]).unwrap();
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::Truncated { found: 3, .. })
        ));
        // Longer than announced is not truncation.
        let mut longer = bytes.clone();
        longer.extend_from_slice(&[0; 5]);
        fs::write(&path, &longer).unwrap();
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::Corrupt {
                corruption: Corruption::TrailingBytes { extra: 5 },
                ..
            })
        ));
    }

    #[test]
    fn a_newer_format_is_refused_with_both_versions() {
        let (_dir, path, mut bytes) = saved_bytes();
        bytes[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
        fs::write(&path, &bytes).unwrap();
        match Checkpoint::load(&path).unwrap_err() {
            CheckpointError::NewerVersion {
                found, supported, ..
            } => {
                assert_eq!((found, supported), (FORMAT_VERSION + 1, FORMAT_VERSION));
            }
            other => panic!("expected NewerVersion, got {other}"),
        }
        bytes[8..12].copy_from_slice(&0u32.to_le_bytes());
        fs::write(&path, &bytes).unwrap();
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::Corrupt {
                corruption: Corruption::UnknownVersion(0),
                ..
            })
        ));
    }

    #[test]
    fn a_foreign_file_is_not_a_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("learning.toml");
        fs::write(&path, "[nac]\nbeta = 0.9\n").unwrap();
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::NotACheckpoint { .. })
        ));
        let (_dir, path, mut bytes) = saved_bytes();
        bytes[0] = b'X';
        fs::write(&path, &bytes).unwrap();
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::NotACheckpoint { .. })
        ));
        let missing = dir.path().join("none.ckpt");
        assert!(matches!(
            Checkpoint::load(&missing),
            Err(CheckpointError::Io { action: "open", path, .. }) if path == missing
        ));
    }

    #[test]
    fn a_payload_that_is_not_a_checkpoint_is_a_decode_error_and_bad_values_are_invalid() {
        let (_dir, path, _) = saved_bytes();
        let write = |payload: &[u8]| {
            let mut bytes = MAGIC.to_vec();
            bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
            bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
            bytes.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
            bytes.extend_from_slice(payload);
            fs::write(&path, bytes).unwrap();
        };
        write(&[7, 7, 7]);
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::Decode { .. })
        ));

        let mut c = both();
        c.sway.as_mut().unwrap().policy.sigma = -1.0;
        write(&bincode::serde::encode_to_vec(&c, bincode::config::standard()).unwrap());
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::Invalid { dof: Dof::Sway, .. })
        ));

        let mut c = both();
        c.yaw.as_mut().unwrap().dof = Dof::Sway;
        write(&bincode::serde::encode_to_vec(&c, bincode::config::standard()).unwrap());
        assert!(matches!(
            Checkpoint::load(&path),
            Err(CheckpointError::Invalid { dof: Dof::Yaw, .. })
        ));
    }

    #[test]
    fn a_save_failing_half_way_keeps_the_previous_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.ckpt");
        let old = Checkpoint::single(trained(Dof::Sway, Algorithm::Nac));
        old.save(&path).unwrap();
        let new = both();
        let err = new
            .save_with(&path, |file, bytes| {
                file.write_all(&bytes[..bytes.len() / 2])?;
                Err(io::Error::new(
                    io::ErrorKind::StorageFull,
                    "disk full (injected)",
                ))
            })
            .unwrap_err();
        assert!(
            matches!(
                &err,
                CheckpointError::Io {
                    action: "write",
                    ..
                }
            ),
            "{err}"
        );
        assert_eq!(Checkpoint::load(&path).unwrap(), old);
        let names: Vec<_> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        assert_eq!(
            names,
            vec!["c.ckpt".to_string()],
            "no temporary file may be left behind"
        );
        // And a later save goes through.
        new.save(&path).unwrap();
        assert_eq!(Checkpoint::load(&path).unwrap(), new);
    }

    #[test]
    fn an_invalid_state_is_not_saved_over_a_good_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.ckpt");
        let good = both();
        good.save(&path).unwrap();
        let mut bad = good.clone();
        bad.yaw.as_mut().unwrap().policy.gain[1] = f64::NAN;
        assert!(matches!(
            bad.save(&path),
            Err(CheckpointError::Invalid { dof: Dof::Yaw, .. })
        ));
        assert_eq!(Checkpoint::load(&path).unwrap(), good);
    }

    /// A file of format 1 (before step two's parameters and safety state) still loads, with their
    /// defaults.
    #[test]
    fn a_format_1_checkpoint_loads_with_the_step_two_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.ckpt");
        let now = both();
        let old = |s: &AgentState| v1::AgentState {
            dof: s.dof,
            params: v1::LearningParams {
                policy: s.params.policy.clone(),
                nac: s.params.nac.clone(),
                gpomdp: s.params.gpomdp.clone(),
            },
            cost: s.cost,
            state_max: s.state_max,
            policy: s.policy,
            learner: s.learner.clone(),
            steps: s.steps,
            episodes: s.episodes,
        };
        let file = v1::Checkpoint {
            sway: now.sway.as_ref().map(old),
            yaw: now.yaw.as_ref().map(old),
        };
        let payload = bincode::serde::encode_to_vec(&file, bincode::config::standard()).unwrap();
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&1u32.to_le_bytes());
        bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        bytes.extend_from_slice(&payload);
        fs::write(&path, bytes).unwrap();
        assert_eq!(Checkpoint::load(&path).unwrap(), now);
    }

    fn file_of(version: u32, payload: &[u8]) -> Vec<u8> {
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&version.to_le_bytes());
        bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
        bytes.extend_from_slice(payload);
        bytes
    }

    /// `s` as an older format's agent state: its learning parameters without step two's own, its
    /// safety layer's state `safety`.
    fn legacy<S>(s: &AgentState, safety: S) -> older::AgentState<S> {
        older_agent(s, v4_params(&s.params), safety)
    }

    /// `s` as an older format's agent state with the learning parameters `params` and the safety
    /// layer's state `safety`.
    fn older_agent<S, P>(s: &AgentState, params: P, safety: S) -> older::AgentState<S, P> {
        older::AgentState {
            dof: s.dof,
            params,
            cost: s.cost,
            state_max: s.state_max,
            policy: s.policy,
            learner: s.learner.clone(),
            steps: s.steps,
            episodes: s.episodes,
            safety,
        }
    }

    fn v4_params(p: &LearningParams) -> v4::LearningParams {
        v4::LearningParams {
            policy: p.policy.clone(),
            nac: p.nac.clone(),
            gpomdp: p.gpomdp.clone(),
            evaluation: p.evaluation.clone(),
            safety: v6_safety_params(&p.safety),
        }
    }

    fn v6_safety_params(p: &config::SafetyParams) -> v6::SafetyParams {
        v6::SafetyParams {
            trust_region: v6::TrustRegionParams {
                enabled: p.trust_region.enabled,
                max_action_change: p.trust_region.max_action_change,
            },
            stability: p.stability.clone(),
            rollback: p.rollback.clone(),
        }
    }

    /// `f` as formats 5 and 6 keep it (no adapted bound, no start).
    fn v6_safety(f: &SafetyState) -> v6::SafetyState {
        v6::SafetyState {
            bounded: f.bounded,
            refused: f.refused,
            rollbacks: f.rollbacks,
            evaluations: f.evaluations,
            best: f.best,
            evaluation_sum: f.evaluation_sum,
            evaluation_trials: f.evaluation_trials,
            evaluation_lost: f.evaluation_lost,
            evaluation_cost: f.evaluation_cost,
            scale: f.scale,
        }
    }

    /// `c` as a checkpoint of formats 5 and 6 (the trust region's bound fixed).
    fn v6_of(c: &Checkpoint) -> v6::Checkpoint {
        let agent = |s: &AgentState| -> v6::AgentState {
            let p = &s.params;
            let params = v6::LearningParams {
                policy: p.policy.clone(),
                nac: p.nac.clone(),
                gpomdp: p.gpomdp.clone(),
                evaluation: p.evaluation.clone(),
                safety: v6_safety_params(&p.safety),
                step_two: p.step_two.clone(),
            };
            older_agent(s, params, v6_safety(&s.safety))
        };
        v6::Checkpoint {
            sway: c.sway.as_ref().map(agent),
            yaw: c.yaw.as_ref().map(agent),
        }
    }

    /// `c` as it reads from a file of formats 4 to 6: the trust region's smallest bound its
    /// largest, no bound adapted.
    fn with_fixed_trust_region(mut c: Checkpoint) -> Checkpoint {
        for s in [c.sway.as_mut(), c.yaw.as_mut()].into_iter().flatten() {
            let tr = &mut s.params.safety.trust_region;
            tr.min_action_change = tr.max_action_change;
            s.safety.action_change_bound = 0.0;
        }
        c
    }

    /// A file of format 6 (a trust region of one fixed bound) loads with that bound fixed and
    /// everything else as saved; the same agents in the current format keep the adapted bound.
    #[test]
    fn a_format_6_checkpoint_loads_with_its_trust_regions_bound_fixed() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.ckpt");
        let mut saved = both();
        for s in [saved.sway.as_mut(), saved.yaw.as_mut()]
            .into_iter()
            .flatten()
        {
            s.params.safety.trust_region.max_action_change = 0.3;
            s.params.safety.trust_region.min_action_change = 0.05;
            s.safety.action_change_bound = 0.2;
            s.safety.rollbacks = 2;
        }
        let c = bincode::config::standard();
        let six = bincode::serde::encode_to_vec(v6_of(&saved), c).unwrap();
        fs::write(&path, file_of(6, &six)).unwrap();
        let loaded = Checkpoint::load(&path).unwrap();
        assert_eq!(loaded, with_fixed_trust_region(saved.clone()));
        let tr = &loaded.sway.as_ref().unwrap().params.safety.trust_region;
        assert_eq!((tr.min_action_change, tr.max_action_change), (0.3, 0.3));
        saved.save(&path).unwrap();
        assert_eq!(Checkpoint::load(&path).unwrap(), saved);
    }

    /// A file of format 7 (no start of the session in the safety state) loads with the start
    /// unknown and everything else as saved; the same agents in the current format keep it.
    #[test]
    fn a_format_7_checkpoint_loads_with_the_sessions_start_unknown() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.ckpt");
        let mut saved = both();
        for s in [saved.sway.as_mut(), saved.yaw.as_mut()]
            .into_iter()
            .flatten()
        {
            s.safety.start = Some(crate::safety::BestPolicy {
                gain: [6.5, 3.5],
                evaluated: -30.1,
                cost: config::PerDof::both(40.0),
                trial: 4,
            });
            s.safety.start_lost = 1;
            s.safety.action_change_bound = 0.2;
            s.safety.rollbacks = 2;
        }
        let agent = |s: &AgentState| -> v7::AgentState {
            let safety = v7::SafetyState {
                fixed: v6_safety(&s.safety),
                action_change_bound: s.safety.action_change_bound,
            };
            older_agent(s, s.params.clone(), safety)
        };
        // Format 7 wrote format 6's fields and then the bound, in place.
        let c = bincode::config::standard();
        let state = agent(saved.sway.as_ref().unwrap()).safety;
        let mut flat = bincode::serde::encode_to_vec(state.fixed, c).unwrap();
        flat.extend(bincode::serde::encode_to_vec(state.action_change_bound, c).unwrap());
        assert_eq!(bincode::serde::encode_to_vec(state, c).unwrap(), flat);
        let seven = v7::Checkpoint {
            sway: saved.sway.as_ref().map(agent),
            yaw: saved.yaw.as_ref().map(agent),
        };
        let bytes = bincode::serde::encode_to_vec(&seven, c).unwrap();
        fs::write(&path, file_of(7, &bytes)).unwrap();
        let mut expected = saved.clone();
        for s in [expected.sway.as_mut(), expected.yaw.as_mut()]
            .into_iter()
            .flatten()
        {
            (s.safety.start, s.safety.start_lost) = (None, 0);
        }
        assert_eq!(Checkpoint::load(&path).unwrap(), expected);
        saved.save(&path).unwrap();
        assert_eq!(Checkpoint::load(&path).unwrap(), saved);
    }

    /// A file of format 4 (before step two's learner had parameters of its own) still loads, with
    /// their defaults and everything else as saved.
    #[test]
    fn a_format_4_checkpoint_loads_with_step_twos_learner_at_its_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.ckpt");
        let mut saved = both();
        for s in [saved.sway.as_mut(), saved.yaw.as_mut()]
            .into_iter()
            .flatten()
        {
            s.params.step_two.lambda = 0.3;
            s.params.nac.lambda = 0.7;
            s.safety.rollbacks = 2;
        }
        let old = |s: &AgentState| -> v4::AgentState { legacy(s, s.safety) };
        let four = v4::Checkpoint {
            sway: saved.sway.as_ref().map(old),
            yaw: saved.yaw.as_ref().map(old),
        };
        let c = bincode::config::standard();
        fs::write(
            &path,
            file_of(4, &bincode::serde::encode_to_vec(&four, c).unwrap()),
        )
        .unwrap();
        let mut expected = saved.clone();
        for s in [expected.sway.as_mut(), expected.yaw.as_mut()]
            .into_iter()
            .flatten()
        {
            s.params.step_two = config::StepTwoParams::default();
        }
        let loaded = Checkpoint::load(&path).unwrap();
        assert_eq!(loaded, with_fixed_trust_region(expected));
        assert_eq!(loaded.sway.unwrap().params.nac.lambda, 0.7);
    }

    /// Files of formats 2 (before the count of lost evaluation trials) and 3 (before pairs) still
    /// load: the counts as saved, the best policy with its pair unknown (infinitely costly, so the
    /// next evaluation replaces it), the evaluation in progress started again.
    #[test]
    fn format_2_and_3_checkpoints_load_with_the_best_pair_unknown() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.ckpt");
        let best = v3::BestPolicy {
            gain: [1.0, 2.0],
            evaluated: -3.5,
        };
        let mut now = both();
        now.sway.as_mut().unwrap().safety = crate::safety::SafetyState {
            rollbacks: 3,
            evaluations: 4,
            best: Some(crate::safety::BestPolicy {
                gain: best.gain,
                evaluated: best.evaluated,
                cost: config::PerDof::both(f64::INFINITY),
                trial: u32::MAX,
            }),
            ..Default::default()
        };
        let v3_of = |s: &AgentState| -> v3::AgentState {
            legacy(
                s,
                v3::SafetyState {
                    bounded: s.safety.bounded,
                    refused: s.safety.refused,
                    rollbacks: s.safety.rollbacks,
                    evaluations: s.safety.evaluations,
                    best: s.safety.best.map(|_| best),
                    evaluation_sum: -7.0,
                    evaluation_trials: 2,
                    evaluation_lost: 1,
                },
            )
        };
        let v2_of = |s: &AgentState| {
            let f = v3_of(s);
            v2::AgentState {
                dof: f.dof,
                params: f.params,
                cost: f.cost,
                state_max: f.state_max,
                policy: f.policy,
                learner: f.learner,
                steps: f.steps,
                episodes: f.episodes,
                safety: v2::SafetyState {
                    bounded: f.safety.bounded,
                    refused: f.safety.refused,
                    rollbacks: f.safety.rollbacks,
                    evaluations: f.safety.evaluations,
                    best: f.safety.best,
                    evaluation_sum: f.safety.evaluation_sum,
                    evaluation_trials: f.safety.evaluation_trials,
                },
            }
        };
        let c = bincode::config::standard();
        let three = v3::Checkpoint {
            sway: now.sway.as_ref().map(v3_of),
            yaw: now.yaw.as_ref().map(v3_of),
        };
        fs::write(
            &path,
            file_of(3, &bincode::serde::encode_to_vec(&three, c).unwrap()),
        )
        .unwrap();
        assert_eq!(
            Checkpoint::load(&path).unwrap(),
            with_fixed_trust_region(now.clone())
        );
        let two = v2::Checkpoint {
            sway: now.sway.as_ref().map(v2_of),
            yaw: now.yaw.as_ref().map(v2_of),
        };
        fs::write(
            &path,
            file_of(2, &bincode::serde::encode_to_vec(&two, c).unwrap()),
        )
        .unwrap();
        assert_eq!(
            Checkpoint::load(&path).unwrap(),
            with_fixed_trust_region(now.clone())
        );
    }

    /// A file of format 5 (the pair's costs without the action term) loads with everything as
    /// saved but those costs: the best's pair unknown, no weights, no evaluation in progress.
    #[test]
    fn a_format_5_checkpoint_loads_with_its_pair_costs_forgotten() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.ckpt");
        let mut saved = both();
        let best = crate::safety::BestPolicy {
            gain: [-1.0, -0.2],
            evaluated: -3.5,
            cost: config::PerDof {
                sway: 2.0,
                yaw: 1.0,
            },
            trial: 7,
        };
        for s in [saved.sway.as_mut(), saved.yaw.as_mut()]
            .into_iter()
            .flatten()
        {
            s.safety = SafetyState {
                rollbacks: 2,
                evaluations: 3,
                best: Some(best),
                evaluation_sum: -1.5,
                evaluation_trials: 1,
                evaluation_cost: config::PerDof {
                    sway: 0.5,
                    yaw: 0.25,
                },
                scale: config::PerDof {
                    sway: 2.5,
                    yaw: 1.5,
                },
                ..Default::default()
            };
        }
        let c = bincode::config::standard();
        let payload = bincode::serde::encode_to_vec(v6_of(&saved), c).unwrap();
        fs::write(&path, file_of(5, &payload)).unwrap();
        let loaded = Checkpoint::load(&path).unwrap();
        let safety = loaded.sway.as_ref().unwrap().safety;
        assert_eq!((safety.rollbacks, safety.evaluations), (2, 3));
        let forgotten = safety.best.unwrap();
        assert_eq!((forgotten.gain, forgotten.trial), (best.gain, best.trial));
        assert_eq!(forgotten.cost, config::PerDof::both(f64::INFINITY));
        assert_eq!(safety.scale, config::PerDof::default());
        assert_eq!(safety.evaluation_cost, config::PerDof::default());
        assert_eq!((safety.evaluation_sum, safety.evaluation_trials), (0.0, 0));
        assert_eq!(loaded.yaw.unwrap().safety, safety);
        // The same payload as format 6 keeps them.
        fs::write(&path, file_of(6, &payload)).unwrap();
        assert_eq!(
            Checkpoint::load(&path).unwrap(),
            with_fixed_trust_region(saved)
        );
    }

    #[test]
    fn the_header_is_the_documented_layout() {
        let (_dir, _path, bytes) = saved_bytes();
        assert_eq!(&bytes[..8], b"CTRKCKPT");
        assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 8);
        let len = u64::from_le_bytes(bytes[12..20].try_into().unwrap());
        assert_eq!(len as usize, bytes.len() - HEADER_LEN);
        let crc = u32::from_le_bytes(bytes[20..24].try_into().unwrap());
        assert_eq!(crc, crc32fast::hash(&bytes[HEADER_LEN..]));
    }
}
