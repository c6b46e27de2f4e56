//! `sway-behaviour`: keeps the cable centred in the image (x_g) by learning the sway policy online.
//! Everything is the crate's library, for the sway DOF; `--help` lists the flags.

fn main() -> std::process::ExitCode {
    behaviour::main(config::Dof::Sway)
}
