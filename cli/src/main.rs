//! The `slam` command (see the `slam_cli` library).

fn main() -> std::process::ExitCode {
    slam_cli::main_with(std::env::args_os())
}
