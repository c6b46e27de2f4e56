//! The service mesh's benchmark: how fast the seven processes close the loop
//! with images, how long each hop and each step takes, what each process costs in CPU and memory, and
//! how far all of that is from the limit, measured in the same run.
//!
//! Each repeat runs, in this order, on the same machine and within seconds of each other:
//!
//! 1. **the mesh** (`supervisor` with `config/sim-mesh.toml`, `eyes = images`, a namespace of its own)
//!    watched only from outside: every 20 ms the bench reads `/proc` for each process and asks a
//!    listener-less subscriber which step the mesh is at ([`probe::Progress`]: never woken, so it
//!    costs the mesh nothing but one more queue). This gives the pace (steps/s over the steady
//!    window, the first episode excluded) and each process's CPU per step and memory;
//! 2. **the mesh with the probe** ([`probe::Probe`]): one more subscriber and listener on every topic,
//!    timing when each step's message appears on each; the per-hop and per-step latencies come from
//!    here ([`timeline`]). The pace with and without it shows what it costs;
//! 3. **limit (a)**: the same cores in one process, no IPC: the trainer's `World` with images and the
//!    NAC learners, one thread;
//! 4. **limit (b)**: the bare iceoryx2 ring ([`ring`]): seven empty processes passing the same
//!    messages in the mesh's pattern with the same ports and wait loop;
//! 5. **the bare ring with the probe**: the probe's own wake-up delay, measured exactly (ring senders
//!    stamp their send time), and the ring's hops measured the way the mesh's are.
//!
//! The two mesh runs swap places from one repeat to the next. The report gives medians over the
//! repeats and compares the mesh's time per step with (a) + (b).
//!
//! `mesh-bench vehicle` ([`vehicle`]) measures the vehicle endpoint instead: camera-to-thruster
//! latency at the vehicle's 5 Hz over many steps, and every service's CPU and memory; `mesh-bench ring`
//! runs the bare ring alone, by default in the vehicle's shape (the twin's frame, a thruster driver's
//! hop) at the vehicle's 5 Hz: the vehicle's limit, what its processes and IPC cost a frame at cold
//! caches before any perceiving. The fault drill of the vehicle's safety layer (`fault-drill`)
//! starts and watches its meshes with this crate's [`runs`] and [`probe`].

pub mod cuts;
pub mod probe;
pub mod procfs;
pub mod report;
pub mod ring;
pub mod runs;
pub mod timeline;
pub mod vehicle;
