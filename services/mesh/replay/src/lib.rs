//! Replay: a flight record's camera frames played back into a mesh (perception, the behaviours, surge
//! and the allocator take them as they took the camera's), and the mesh's new outputs compared with
//! the recorded ones. With the same code and seed (and the behaviours starting from the same
//! checkpoints) they are equal bit for bit; with changed code, the report says where they differ.
//! It is the regression test of perception and the behaviours on real dives.
//!
//! **A process of its own, not a frame source of the camera.** A lockstep replay needs the mesh's
//! answers (the thruster setpoints carrying each frame's `seq`), and the comparison needs the mesh's
//! outputs beside the recorded ones: a frame source sits behind the camera and sees neither. The
//! recorded frames also carry the camera's own stamps (`seq`, time, trial, step, status, truth):
//! published unchanged on the camera's topic, the replayed outputs line up with the recorded ones
//! step by step, on either endpoint (a sim-mesh record replays too), with no camera between.
//!
//! - [`frames`]: the record's frames pulled one at a time, the recorded outputs collected on the way;
//! - [`plant`]: the record as a `runtime::lockstep::Plant` (the lockstep's re-sends and deadlines);
//! - [`compare`]: outputs by step, and the report;
//! - `video` (the `video` feature): the record's compressed stream decoded as the camera decoded it,
//!   the frames of a record whose images were kept only now and then.

pub mod compare;
pub mod frames;
pub mod plant;
#[cfg(feature = "video")]
pub mod video;

pub use compare::{Difference, Outputs, Report, TopicReport};
pub use frames::{Frame, Frames, ReplayError};
pub use plant::{Played, ReplayPlant};
