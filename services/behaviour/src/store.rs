//! A behaviour's own checkpoint file, `FILE`, and the one before it, `FILE.prev`.
//!
//! Saving renames the current `FILE` to `FILE.prev`, then writes the new state to `FILE` atomically
//! (`learning::Checkpoint::save`). A crash between the two leaves `FILE` missing and `FILE.prev`
//! whole; a crash during the write leaves the same. Loading takes `FILE`; when `FILE` is refused
//! (corrupt, truncated, written by a newer format, without this DOF's state, unreadable) it is logged
//! as an ERROR and `FILE.prev` is used instead if it loads (a WARN); when neither loads, loading
//! fails with both reasons.
//!
//! A refused `FILE` is never kept as `FILE.prev`: the next save replaces it without touching the
//! good previous file.

use config::Dof;
use learning::{AgentState, AgentStateError, Checkpoint, CheckpointError};
use std::error::Error;
use std::path::{Path, PathBuf};

/// Why no checkpoint could be loaded, or a save failed. Every variant names its files.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// `FILE` was refused and there is no `FILE.prev`.
    #[error("checkpoint {} is refused and there is no previous checkpoint {}", path.display(), prev.display())]
    Refused {
        path: PathBuf,
        prev: PathBuf,
        #[source]
        source: Box<CheckpointError>,
    },
    /// `FILE` is missing (an interrupted save) and `FILE.prev` was refused.
    #[error("checkpoint {} is missing and the previous checkpoint {} is refused", path.display(), prev.display())]
    PreviousRefused {
        path: PathBuf,
        prev: PathBuf,
        #[source]
        source: Box<CheckpointError>,
    },
    /// Both were refused.
    #[error(
        "neither checkpoint {} nor the previous checkpoint {} loads: {}; and: {}",
        path.display(), prev.display(), chain(current.as_ref()), chain(previous.as_ref())
    )]
    NoneLoads {
        path: PathBuf,
        prev: PathBuf,
        current: Box<CheckpointError>,
        previous: Box<CheckpointError>,
    },
    /// The state would not load again: nothing was written.
    #[error("the {dof} state is not saved to {}", path.display())]
    Invalid {
        path: PathBuf,
        dof: Dof,
        #[source]
        source: AgentStateError,
    },
    /// The current file could not be kept as the previous one: nothing was written.
    #[error("cannot keep checkpoint {} as {}", path.display(), prev.display())]
    KeepPrevious {
        path: PathBuf,
        prev: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Writing the new checkpoint failed (`FILE.prev` holds the last good one).
    #[error(transparent)]
    Save(Box<CheckpointError>),
}

/// An error and its sources, `: `-separated (`{:#}` of anyhow, for a plain error).
pub fn chain(e: &dyn Error) -> String {
    let mut s = e.to_string();
    let mut source = e.source();
    while let Some(cause) = source {
        s.push_str(": ");
        s.push_str(&cause.to_string());
        source = cause.source();
    }
    s
}

/// A state loaded from the checkpoint files, and the file it came from.
#[derive(Clone, Debug, PartialEq)]
pub struct Loaded {
    pub state: AgentState,
    pub from: PathBuf,
    /// It came from `FILE.prev`: `FILE` was refused or missing.
    pub fell_back: bool,
}

/// A behaviour's checkpoint file and its previous version.
#[derive(Clone, Debug)]
pub struct CheckpointFile {
    path: PathBuf,
    prev: PathBuf,
    /// `path` holds a checkpoint that loaded or that was written here: only such a file is kept as
    /// the previous one when saving.
    good: bool,
}

impl CheckpointFile {
    pub fn new(path: impl Into<PathBuf>) -> Self {
        let path = path.into();
        let prev = Self::prev_of(&path);
        // Not known to be good until it loads.
        CheckpointFile {
            path,
            prev,
            good: false,
        }
    }

    /// `FILE.prev` for `FILE`.
    pub fn prev_of(path: &Path) -> PathBuf {
        let mut name = path.as_os_str().to_owned();
        name.push(".prev");
        PathBuf::from(name)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn prev(&self) -> &Path {
        &self.prev
    }

    /// Loads `dof`'s state from `FILE`, or from `FILE.prev` when `FILE` is refused or missing.
    /// `Ok(None)`: neither file exists (a first start).
    pub fn load(&mut self, dof: Dof) -> Result<Option<Loaded>, StoreError> {
        let current = if self.path.exists() {
            match Checkpoint::load_dof(&self.path, dof) {
                Ok(state) => {
                    self.good = true;
                    return Ok(Some(Loaded {
                        state,
                        from: self.path.clone(),
                        fell_back: false,
                    }));
                }
                Err(e) => {
                    tracing::error!(
                        path = %self.path.display(),
                        "checkpoint refused: {}; trying the previous checkpoint {}",
                        chain(&e),
                        self.prev.display()
                    );
                    Some(e)
                }
            }
        } else {
            None
        };
        self.good = false;
        if !self.prev.exists() {
            return match current {
                Some(source) => Err(StoreError::Refused {
                    path: self.path.clone(),
                    prev: self.prev.clone(),
                    source: Box::new(source),
                }),
                None => Ok(None),
            };
        }
        match (Checkpoint::load_dof(&self.prev, dof), current) {
            (Ok(state), current) => {
                match &current {
                    Some(_) => tracing::warn!(
                        path = %self.prev.display(),
                        "using the previous checkpoint instead of the refused {}",
                        self.path.display()
                    ),
                    None => tracing::warn!(
                        path = %self.prev.display(),
                        "{} is missing (a save was interrupted): using the previous checkpoint",
                        self.path.display()
                    ),
                }
                Ok(Some(Loaded {
                    state,
                    from: self.prev.clone(),
                    fell_back: true,
                }))
            }
            (Err(previous), Some(current)) => {
                tracing::error!(path = %self.prev.display(), "previous checkpoint refused too: {}", chain(&previous));
                Err(StoreError::NoneLoads {
                    path: self.path.clone(),
                    prev: self.prev.clone(),
                    current: Box::new(current),
                    previous: Box::new(previous),
                })
            }
            (Err(source), None) => {
                tracing::error!(path = %self.prev.display(), "previous checkpoint refused: {}", chain(&source));
                Err(StoreError::PreviousRefused {
                    path: self.path.clone(),
                    prev: self.prev.clone(),
                    source: Box::new(source),
                })
            }
        }
    }

    /// Saves `state` to `FILE`, keeping the current `FILE` (if it is good) as `FILE.prev`.
    pub fn save(&mut self, state: &AgentState) -> Result<(), StoreError> {
        // Check first: a good file is never moved aside for a state that cannot be written.
        state.validate().map_err(|source| StoreError::Invalid {
            path: self.path.clone(),
            dof: state.dof,
            source,
        })?;
        if self.good && self.path.exists() {
            std::fs::rename(&self.path, &self.prev).map_err(|source| StoreError::KeepPrevious {
                path: self.path.clone(),
                prev: self.prev.clone(),
                source,
            })?;
        }
        // From here until the write succeeds, FILE is missing or not ours.
        self.good = false;
        Checkpoint::single(state.clone())
            .save(&self.path)
            .map_err(|e| StoreError::Save(Box::new(e)))?;
        self.good = true;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use config::{LearningParams, Scenario};
    use learning::{Algorithm, StepStatus};
    use std::fs;

    fn state(dof: Dof, steps: usize) -> AgentState {
        let mut a = crate::new_agent(
            dof,
            Algorithm::Nac,
            &Scenario::default(),
            &LearningParams::default(),
            3,
        );
        for i in 0..steps {
            a.step([0.1 * (i as f64).sin(), 0.05], StepStatus::Running);
        }
        a.checkpoint()
    }

    #[test]
    fn a_save_keeps_the_previous_file_and_a_load_takes_the_newest() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sway.ckpt");
        let mut f = CheckpointFile::new(&path);
        assert_eq!(f.load(Dof::Sway).unwrap(), None);
        let (one, two) = (state(Dof::Sway, 3), state(Dof::Sway, 9));
        f.save(&one).unwrap();
        assert!(!f.prev().exists());
        f.save(&two).unwrap();
        assert_eq!(Checkpoint::load_dof(f.prev(), Dof::Sway).unwrap(), one);
        let loaded = CheckpointFile::new(&path).load(Dof::Sway).unwrap().unwrap();
        assert_eq!((loaded.state, loaded.fell_back), (two, false));
    }

    #[test]
    fn a_corrupt_file_falls_back_to_the_previous_and_is_never_kept_as_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("yaw.ckpt");
        let (one, two, three) = (state(Dof::Yaw, 3), state(Dof::Yaw, 9), state(Dof::Yaw, 12));
        let mut f = CheckpointFile::new(&path);
        f.save(&one).unwrap();
        f.save(&two).unwrap();
        let mut bytes = fs::read(&path).unwrap();
        let n = bytes.len();
        bytes[n - 3] ^= 0x40;
        fs::write(&path, &bytes).unwrap();

        let mut f = CheckpointFile::new(&path);
        let loaded = f.load(Dof::Yaw).unwrap().unwrap();
        assert_eq!((&loaded.state, loaded.fell_back), (&one, true));
        assert_eq!(loaded.from, f.prev());
        // The corrupt file is replaced, the good previous one kept.
        f.save(&three).unwrap();
        assert_eq!(Checkpoint::load_dof(&path, Dof::Yaw).unwrap(), three);
        assert_eq!(Checkpoint::load_dof(f.prev(), Dof::Yaw).unwrap(), one);
    }

    #[test]
    fn an_interrupted_save_leaves_the_previous_file_to_load() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sway.ckpt");
        let one = state(Dof::Sway, 4);
        let mut f = CheckpointFile::new(&path);
        f.save(&one).unwrap();
        fs::rename(&path, f.prev()).unwrap();
        let loaded = CheckpointFile::new(&path).load(Dof::Sway).unwrap().unwrap();
        assert_eq!((loaded.state, loaded.fell_back), (one, true));
    }

    #[test]
    fn when_nothing_loads_the_error_names_both_files_and_reasons() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sway.ckpt");
        let mut f = CheckpointFile::new(&path);
        fs::write(&path, b"CTRKCKPT\x01").unwrap();
        let e = f.load(Dof::Sway).unwrap_err();
        assert!(matches!(e, StoreError::Refused { .. }), "{e}");
        assert!(chain(&e).contains("truncated"), "{}", chain(&e));

        fs::write(f.prev(), b"not a checkpoint at all").unwrap();
        let e = f.load(Dof::Sway).unwrap_err();
        let text = chain(&e);
        for needle in ["sway.ckpt ", "sway.ckpt.prev", "truncated", "bad magic"] {
            assert!(text.contains(needle), "`{needle}` in {text}");
        }
        // A file holding only the other DOF is refused as well.
        let mut f = CheckpointFile::new(dir.path().join("other.ckpt"));
        f.save(&state(Dof::Yaw, 2)).unwrap();
        let e = f.load(Dof::Sway).unwrap_err();
        assert!(chain(&e).contains("no sway state"), "{}", chain(&e));
    }

    #[test]
    fn an_invalid_state_moves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sway.ckpt");
        let mut f = CheckpointFile::new(&path);
        let good = state(Dof::Sway, 3);
        f.save(&good).unwrap();
        let mut bad = good.clone();
        bad.policy.gain[0] = f64::NAN;
        assert!(matches!(f.save(&bad), Err(StoreError::Invalid { .. })));
        assert!(!f.prev().exists());
        assert_eq!(Checkpoint::load_dof(&path, Dof::Sway).unwrap(), good);
    }
}
