//! The `slam` command.

mod camera;
mod config;
mod consistency;
mod data;
mod error;
mod eval;
mod extract;
mod frontend;
mod outputs;
mod pipeline;
mod plot;
mod polygon;
mod prior;
mod run;
mod simulate;

use clap::{Parser, Subcommand};

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
    /// trajectory.tum, map.json, metrics.json, map.svg and map.png.
    Run(run::RunArgs),
    /// Run the scan front-ends on one scan and draw what they find.
    Extract(extract::ExtractArgs),
    /// Run the ceiling-image front-end on one image and draw what it finds.
    Camera(camera::CameraArgs),
    /// Measure the estimator's consistency (average pose NEES) over many seeded simulated
    /// runs, M-space walls against naive endpoint walls.
    Consistency(consistency::ConsistencyArgs),
    /// Write a simulated run as files other tools read (rb2d, CARMEN, TUM ground truth).
    Simulate(simulate::SimulateArgs),
    /// Compare an estimated trajectory with ground truth (ATE, RPE).
    Eval(eval::EvalArgs),
    /// Run a structure prior (priorlets) on one scan and draw the corrected readings, the
    /// region and surface boundaries and the outliers.
    Prior(prior::PriorArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Run(args) => run::run(args),
        Command::Extract(args) => extract::run(args),
        Command::Camera(args) => camera::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Consistency(args) => consistency::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Prior(args) => prior::run(args),
    };
    if let Err(error) = result {
        eprintln!("slam: {error}");
        std::process::exit(1);
    }
}
