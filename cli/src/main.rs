//! The `slam` command (see the `slam_cli` library).

fn main() -> std::process::ExitCode {
    restore_default_sigpipe();
    slam_cli::main_with(std::env::args_os())
}

/// Output piped into a command that stops reading (`slam prior ... | head`) ends the program
/// quietly, as it ends other command-line tools, instead of a panic in `println!`: a Rust
/// program ignores SIGPIPE unless told otherwise, and every write to the closed pipe fails.
fn restore_default_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called first in `main`, before any other thread exists; setting a signal's
    // disposition to its default has no other precondition.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
