//! The `slam` command as a library: its arguments, its subcommands and what they write. The
//! binary (`main.rs`) calls [`main_with`]; a program that registers its own estimator,
//! front-end or feature type calls it too, to run them through the command's own code path.
//!
//! The command knows no concrete estimator or feature type: estimators, front-ends, wall
//! representations and post-processing stages come from the registries of
//! [`slam_runtime`], features are drawn and scored through their trait. Linking
//! `slam_examples` here registers its naive endpoint walls (`wall_representation =
//! "endpoints"`, for `slam consistency`).

#![warn(missing_docs)]

mod bench;
mod camera;
mod config_print;
mod consistency;
pub mod error;
mod eval;
mod extract;
mod figures;
mod outputs;
mod outset;
mod plot;
mod prior;
mod progress;
mod run;
mod simulate;

use std::ffi::OsString;
use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};

pub use error::{CliError, Result};
pub use outputs::map_json;
pub use run::{
    EXIT_DIVERGED, EXIT_INTERRUPTED, RunArgs, RunStatus, compute_run, run_config, run_config_until,
    with_overrides,
};
pub use slam_runtime::RunResults;

/// Links the example crate, whose `typetag` registrations the command offers by name.
use slam_examples as _;

/// A SLAM framework for maps made of geometry (walls, ceiling lines, poles, points).
#[derive(Debug, Parser)]
#[command(name = "slam", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run an estimator (default: the EKF on the built-in simulated world) and write
    /// trajectory.tum, map.json, estimates.csv, metrics.json, map.svg and map.png (and, when
    /// asked, map.pgm + map.yaml, graph.g2o, run.mcap).
    Run(run::RunArgs),
    /// Run the scan front-ends on one scan and draw what they find.
    Extract(extract::ExtractArgs),
    /// Run the ceiling-image front-end on one image and draw what it finds.
    Camera(camera::CameraArgs),
    /// Measure the estimator's consistency (average pose NEES) over many seeded simulated
    /// runs, one study per wall representation.
    Consistency(consistency::ConsistencyArgs),
    /// Write a simulated run as files other tools read (rb2d, CARMEN, TUM ground truth).
    Simulate(simulate::SimulateArgs),
    /// Compare an estimated trajectory with ground truth (ATE, RPE).
    Eval(eval::EvalArgs),
    /// Run a structure prior (priorlets) on one scan and draw the corrected readings, the
    /// region and surface boundaries and the outliers.
    Prior(prior::PriorArgs),
    /// Run the configured estimator several times without outputs and print the time per
    /// step, the CPU time, the peak resident memory and the state size.
    Bench(bench::BenchArgs),
    /// Show the configuration `slam run` uses, every default included (`slam config print`).
    Config(config_print::ConfigArgs),
    /// Print a shell completion script (bash, zsh, fish, elvish, powershell) to standard
    /// output; e.g. `slam completions bash > ~/.local/share/bash-completion/completions/slam`.
    Completions(CompletionsArgs),
}

/// Arguments of `slam completions`.
#[derive(Debug, clap::Args)]
struct CompletionsArgs {
    /// The shell to complete for.
    #[arg(value_enum)]
    shell: clap_complete::Shell,
}

/// The completion script of `slam` for `shell`.
fn completions(shell: clap_complete::Shell) -> String {
    let mut script = Vec::new();
    clap_complete::generate(shell, &mut Cli::command(), "slam", &mut script);
    String::from_utf8_lossy(&script).into_owned()
}

/// Runs the command line `args` (the first is the program name) and returns what it
/// printed as its summary.
///
/// ```no_run
/// let summary = slam_cli::command(["slam", "run", "--quiet", "--out", "/tmp/slam-out"])?;
/// println!("{summary}");
/// # Ok::<(), slam_cli::CliError>(())
/// ```
pub fn command<I, T>(args: I) -> Result<String>
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = Cli::try_parse_from(args).map_err(|e| CliError::Usage(e.to_string()))?;
    match &cli.command {
        Command::Run(args) => run::run(args),
        Command::Extract(args) => extract::run(args).map(|()| String::new()),
        Command::Camera(args) => camera::run(args).map(|()| String::new()),
        Command::Simulate(args) => simulate::run(args).map(|()| String::new()),
        Command::Consistency(args) => consistency::run(args).map(|()| String::new()),
        Command::Eval(args) => eval::run(args).map(|()| String::new()),
        Command::Bench(args) => bench::run_bench(args),
        Command::Prior(args) => prior::run(args).map(|()| String::new()),
        Command::Config(args) => config_print::run(args),
        Command::Completions(args) => Ok(completions(args.shell)),
    }
}

/// `slam run` with Ctrl-C (SIGINT) and SIGTERM stopping it at the next step, its outputs
/// written; a second Ctrl-C ends the process at once.
fn run_command(args: &run::RunArgs) -> ExitCode {
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        // A second signal while the first is handled ends the process (exit code 130).
        let _ = signal_hook::flag::register_conditional_shutdown(
            signal,
            i32::from(EXIT_INTERRUPTED),
            std::sync::Arc::clone(&stop),
        );
        let _ = signal_hook::flag::register(signal, std::sync::Arc::clone(&stop));
    }
    match run::run_until(args, &stop) {
        Ok((summary, status)) => {
            println!("{summary}");
            ExitCode::from(status.exit_code())
        }
        Err(error) => {
            eprintln!("slam: {}", error.chain());
            ExitCode::FAILURE
        }
    }
}

/// The `slam` binary: parses `args` (help and version print and exit), runs the command,
/// prints its summary, and on an error prints it with its causes and returns failure.
pub fn main_with(args: impl IntoIterator<Item = OsString>) -> ExitCode {
    let cli = Cli::parse_from(args);
    let result = match &cli.command {
        Command::Run(args) => return run_command(args),
        Command::Extract(args) => extract::run(args),
        Command::Camera(args) => camera::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Consistency(args) => consistency::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Prior(args) => prior::run(args),
        Command::Bench(args) => bench::run_bench(args).map(|text| println!("{text}")),
        Command::Config(args) => config_print::run(args).map(|text| print!("{text}")),
        Command::Completions(args) => {
            print!("{}", completions(args.shell));
            Ok(())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("slam: {}", error.chain());
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The help text of every subcommand (and of the command itself).
    fn helps() -> Vec<(String, String)> {
        let mut cli = Cli::command();
        let mut helps = vec![("slam".to_string(), cli.render_long_help().to_string())];
        for sub in cli.get_subcommands_mut() {
            let name = sub.get_name().to_string();
            helps.push((name, sub.render_long_help().to_string()));
        }
        helps
    }

    #[test]
    fn help_texts_point_to_other_help_not_to_themselves() {
        let helps = helps();
        let names: Vec<&str> = helps.iter().map(|(n, _)| n.as_str()).collect();
        for expected in ["run", "eval", "config", "completions", "help"] {
            assert!(names.contains(&expected), "{names:?}");
        }
        for (name, help) in &helps {
            assert!(
                !help.contains(&format!("slam {name} --help")),
                "{name}: {help}"
            );
            // `slam help` lists the commands only: it explains no option.
            assert!(!help.contains("`slam help`"), "{name}: {help}");
            // Every `slam X` a help text mentions is a subcommand.
            for mention in help.split("`slam ").skip(1) {
                let word = mention.split([' ', '`']).next().unwrap_or("");
                assert!(
                    names.contains(&word),
                    "{name} mentions `slam {word}`: {help}"
                );
            }
        }
        let run = &helps.iter().find(|(n, _)| n == "run").unwrap().1;
        assert!(run.contains("slam config print"), "{run}");
    }

    #[test]
    fn completions_are_printed_for_the_common_shells() {
        for shell in ["bash", "zsh", "fish"] {
            let script = command(["slam", "completions", shell]).unwrap();
            for word in ["slam", "run", "eval", "config", "completions", "--data"] {
                assert!(script.contains(word), "{shell}: no {word}");
            }
        }
        let bash = command(["slam", "completions", "bash"]).unwrap();
        assert!(bash.contains("complete -F"), "{bash:.300}");
        assert!(command(["slam", "completions", "tcsh"]).is_err());
    }

    #[test]
    fn config_print_is_a_command() {
        let text = command(["slam", "config", "print"]).unwrap();
        let parsed = slam_runtime::Config::from_toml(&text, "printed").unwrap();
        assert!(text.ends_with(&parsed.to_toml().unwrap()));
    }
}
