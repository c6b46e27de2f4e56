//! `yaw-behaviour`: keeps the cable aligned with the image's vertical (Theta) by learning the yaw
//! policy online. Everything is the crate's library, for the yaw DOF; `--help` lists the flags.

fn main() -> std::process::ExitCode {
    behaviour::main(config::Dof::Yaw)
}
