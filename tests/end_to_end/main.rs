//! The end-to-end tests that run for minutes, in one binary: the main job through the mesh, the
//! BlueROV2 over MAVLink (its dives, bench checks, faults and the job piloting its autopilot).
//! Cargo runs test binaries one after another; apart, each job's binary left one of the harness's
//! two threads idle while its job ran. Together, the shorter tests run beside the jobs.

mod bluerov2;
mod bluerov2_faults;
mod two_step;
