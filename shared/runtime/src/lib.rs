//! What every cabletrack process shares, written once: the common command line (and the one that
//! runs a mesh, [`MeshArgs`]), tracing, the configuration, the iceoryx2 node (isolated by a prefix
//! and root, with dead nodes' leftovers removed at start), clean shutdown on SIGINT/SIGTERM, the
//! blocking wait loop, the lockstep protocol ([`lockstep`], [`Runtime::serve_steps`]), the one
//! judge of stamps every consumer uses ([`screen::Screen`]), the clocks ([`clock`]), rate-limited
//! warnings ([`Tally`], [`BadValues`]), and the processes a program starts ([`process`],
//! [`Namespace`]).
//!
//! A service's `main` reads:
//!
//! ```ignore
//! fn main() -> std::process::ExitCode {
//!     let args = Args::parse();
//!     runtime::run("perception", &args.common, |rt| {
//!         let frames = rt.frame_inbox()?;                       // open ports
//!         let out = rt.outbox(&topics::CABLE_OBSERVATION)?;
//!         rt.serve(&[frames.listener()], Timer::None, |_| {    // loop { wait, take input,
//!             /* call the core, publish */                      //        call core, publish }
//!             Ok(Flow::Continue)
//!         })
//!     })
//! }
//! ```

pub mod clock;
pub mod lockstep;
mod namespace;
mod node;
pub mod process;
pub mod screen;
mod steps;
mod tally;
mod wait;

pub use clock::VehicleClock;
pub use namespace::Namespace;
pub use node::{
    CommonArgs, IoxSettings, MeshArgs, RESTARTS_ENV, RunArgs, Runtime, RuntimeError, create_node,
    init_tracing, remove_dead_nodes, restarts, run, shm_files, shm_leftovers,
};
pub use steps::{Answer, StepInput};
pub use tally::{BadValues, Tally, WARN_EVERY};
pub use wait::{Flow, Input, Stopped, Timer, Wake, Watch};
