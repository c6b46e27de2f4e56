//! Integration tests of the `plot` crate, grouped by behaviour.

mod util;

mod figure;
mod robustness;
