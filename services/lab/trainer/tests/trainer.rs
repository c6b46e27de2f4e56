//! The trainer's integration tests, one module per subject, in one binary (see Cargo.toml).

mod bluerov2;
mod step_one;
mod step_two;
