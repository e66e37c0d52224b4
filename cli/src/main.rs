//! The `slam` command. Its `run` subcommand arrives with the EKF; until then it explains
//! what exists and exits with status 2.

fn main() {
    eprintln!(
        "slam: no subcommand is implemented yet.\n\
         Try `cargo run --release -p slam-examples --example mspace_tour` for a tour of the M-space core."
    );
    std::process::exit(2);
}
