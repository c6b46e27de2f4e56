//! The end-to-end tests that run for minutes: the main job through the mesh, the BlueROV2 over
//! MAVLink (its dives, bench checks, faults and the job piloting its autopilot).

mod bluerov2;
mod bluerov2_faults;
mod two_step;
