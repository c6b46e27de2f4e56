//! The system's tests, one module per subject, in one binary (see Cargo.toml): the harness runs them
//! two at a time, so the short tests run beside the end-to-end jobs that take minutes.
//! `cargo test --release -p system-tests --test system mesh::` runs one subject.

mod ardusub;
mod bench_ring;
mod command_line;
mod cuts;
mod docs;
mod end_to_end;
mod failsafe;
mod mesh;
mod profiling;
mod replay;
mod vehicle;
mod vehicle_endpoint;
