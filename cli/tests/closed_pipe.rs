//! Output into a pipe whose reader has gone (`slam ... | head`) ends the command quietly, by
//! SIGPIPE as for other command-line tools, never with a panic.

#[cfg(unix)]
#[test]
fn a_closed_pipe_ends_the_command_without_a_panic() {
    use std::os::unix::process::ExitStatusExt;
    use std::process::{Command, Stdio};

    let (reader, writer) = std::io::pipe().expect("a pipe");
    // No reader from the start: the command's first write to its standard output fails.
    drop(reader);
    let output = Command::new(env!("CARGO_BIN_EXE_slam"))
        .args(["completions", "bash"])
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .expect("slam runs");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!stderr.contains("panicked"), "stderr: {stderr}");
    assert_eq!(
        output.status.signal(),
        Some(13),
        "status {:?}",
        output.status
    );
}
