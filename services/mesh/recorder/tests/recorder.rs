//! The flight recorder's integration tests, one module per subject, in one binary (see Cargo.toml).

mod disk_full;
mod every_channel;
mod file;
mod fuzz;
mod outside_reader;
mod process;
mod reader_view;
