//! `slam extract`: runs the scan front-ends (walls, poles) on one scan of a dataset, draws the
//! scan with what was extracted, and lists it.

use std::path::PathBuf;

use slam_core::nalgebra::Vector2;
use slam_core::{Pose2, Pose3, RobotPose};
use slam_sensors::extract::{
    ExtractedPole, ExtractedSegment, LineExtractorParams, PoleExtractorParams, extract_poles,
    extract_segments,
};
use slam_sensors::models::scan_plane_to_world;
use slam_sensors::{Event, LaserScan};

use crate::error::{CliError, Result};
use crate::plot::{Figure, palette};

/// Arguments of `slam extract`.
#[derive(Debug, clap::Args)]
pub struct ExtractArgs {
    /// Data: sim (the built-in world), world:FILE or carmen:FILE, as `slam run --data`.
    #[arg(long, default_value = "sim")]
    pub data: String,
    /// Which scan (0-based, in stream order).
    #[arg(long, default_value_t = 0)]
    pub scan: usize,
    /// Output image (.png or .svg).
    #[arg(long, default_value = "extract.png")]
    pub out: PathBuf,
    /// Range noise standard deviation assumed by the extractors, m (default: the simulated
    /// laser's, or 0.03 for real data).
    #[arg(long)]
    pub sigma_range: Option<f64>,
    /// Seed of the simulation.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// A scan, its mount, and the robot pose it was taken from (when the data give one).
struct PosedScan {
    scan: LaserScan,
    mount: Pose3,
    pose: Option<Pose2>,
}

/// The scans of the data with the poses given at their times, and every true pose.
fn scans(events: slam_sensors::EventStream) -> Result<(Vec<PosedScan>, Vec<Pose2>)> {
    let mut out: Vec<(f64, PosedScan)> = Vec::new();
    let mut poses: Vec<(f64, Pose2)> = Vec::new();
    let mut trajectory = Vec::new();
    for e in events {
        let e = e?;
        if let Event::GroundTruth {
            pose,
            kind: slam_sensors::TruthKind::True,
        } = &e.event
        {
            trajectory.push(*pose);
        }
        match e.event {
            Event::Scan {
                scan,
                robot_from_sensor,
            } => out.push((
                e.time,
                PosedScan {
                    scan,
                    mount: robot_from_sensor,
                    pose: None,
                },
            )),
            Event::GroundTruth { pose, .. } => poses.push((e.time, pose)),
            _ => {}
        }
    }
    for (time, posed) in &mut out {
        posed.pose = poses.iter().find(|(t, _)| t == time).map(|(_, p)| *p);
    }
    Ok((out.into_iter().map(|(_, p)| p).collect(), trajectory))
}

/// What was extracted from one scan, and how to place it in the world.
struct Extracted {
    posed: PosedScan,
    segments: Vec<ExtractedSegment>,
    poles: Vec<ExtractedPole>,
    world_from_sensor: Pose3,
}

impl Extracted {
    fn to_world(&self, p: &Vector2<f64>) -> Vector2<f64> {
        scan_plane_to_world(&self.world_from_sensor, p)
    }

    /// "world frame" when the data give the scan's pose, else "sensor frame".
    fn frame(&self) -> &'static str {
        if self.posed.pose.is_some() {
            "world frame"
        } else {
            "sensor frame"
        }
    }
}

/// Runs `slam extract`.
pub fn run(args: &ExtractArgs) -> Result<()> {
    let data = slam_runtime::data::DataConfig {
        spec: args.data.clone(),
        seed: args.seed,
        ..Default::default()
    }
    .open()?;
    let default_sigma = data.sensors.laser_sigma_range.unwrap_or(0.03);
    let sigma = args.sigma_range.unwrap_or(default_sigma);
    if !(sigma.is_finite() && sigma > 0.0) {
        return Err(CliError::Usage(format!(
            "--sigma-range must be positive, got {sigma}"
        )));
    }
    let name = data.events.info.name.clone();
    let (mut all, trajectory) = scans(data.events)?;
    let count = all.len();
    if args.scan >= count {
        return Err(CliError::Usage(format!(
            "--scan {} is out of range: the data hold {count} scans",
            args.scan
        )));
    }
    let extracted = extract(all.swap_remove(args.scan), sigma);
    let title = format!(
        "{name}: scan {} of {count} ({})",
        args.scan,
        extracted.frame()
    );
    let mut figure = Figure::new(title, 1400);
    if let Some(truth) = &data.truth {
        for (a, b) in &truth.walls {
            figure.segment(*a, *b, palette::TRUTH, 2);
        }
        for (c, r) in &truth.poles {
            figure.circle(*c, *r, palette::TRUTH, false);
        }
        figure.legend("true walls and poles", palette::TRUTH);
    }
    if !trajectory.is_empty() {
        figure.polyline(
            trajectory.iter().map(|p| p.translation()).collect(),
            palette::TRUE_PATH,
            1,
        );
        figure.legend("true robot path", palette::TRUE_PATH);
    }
    draw(&mut figure, &extracted);
    figure.save(&args.out)?;
    println!(
        "{} segments, {} poles from scan {} ({} beams, sigma_range {sigma} m); image: {}",
        extracted.segments.len(),
        extracted.poles.len(),
        args.scan,
        extracted.posed.scan.ranges.len(),
        args.out.display()
    );
    print_table(&extracted);
    Ok(())
}

/// The wall segments and poles of one scan for a laser of range deviation `sigma`.
fn extract(posed: PosedScan, sigma: f64) -> Extracted {
    let line_params = LineExtractorParams {
        sigma_range: sigma,
        ..Default::default()
    };
    let pole_params = PoleExtractorParams {
        sigma_range: sigma,
        ..Default::default()
    };
    let segments = extract_segments(&posed.scan, &line_params);
    let poles = extract_poles(&posed.scan, &pole_params);
    let world_from_sensor = posed
        .pose
        .unwrap_or_default()
        .world_from_sensor(&posed.mount);
    Extracted {
        posed,
        segments,
        poles,
        world_from_sensor,
    }
}

/// The scan's readings, the segments (filled squares at real ends), the poles, the sensor.
fn draw(figure: &mut Figure, extracted: &Extracted) {
    let scan = &extracted.posed.scan;
    let points: Vec<_> = scan
        .points()
        .iter()
        .map(|p| extracted.to_world(&p.position))
        .collect();
    figure.dots(points.clone(), palette::POINTS, 3);
    figure.legend(
        format!("{} valid readings of {}", points.len(), scan.ranges.len()),
        palette::POINTS,
    );
    for s in &extracted.segments {
        let (a, b) = (
            extracted.to_world(&s.ends[0]),
            extracted.to_world(&s.ends[1]),
        );
        figure.segment(a, b, palette::WALL, 4);
        figure.marker(a, palette::WALL, 10, s.real[0]);
        figure.marker(b, palette::WALL, 10, s.real[1]);
    }
    figure.legend(
        format!(
            "{} wall segments (filled square: real end)",
            extracted.segments.len()
        ),
        palette::WALL,
    );
    for p in &extracted.poles {
        figure.circle(extracted.to_world(&p.centre), p.radius, palette::POLE, true);
    }
    figure.legend(format!("{} poles", extracted.poles.len()), palette::POLE);
    let sensor = extracted.world_from_sensor.translation.xy();
    figure.marker(sensor, palette::PATH, 14, true);
    figure.legend("sensor", palette::PATH);
}

/// One line per segment (line, length, real ends, deviations, ends) and per pole.
fn print_table(extracted: &Extracted) {
    println!(
        "{:>8} {:>8} {:>7} {:>6} {:>5} {:>5} {:>9} {:>9} {:>9}  ends ({})",
        "alpha",
        "rho",
        "length",
        "points",
        "real0",
        "real1",
        "sd_alpha",
        "sd_rho",
        "sd_end",
        extracted.frame()
    );
    for s in &extracted.segments {
        let (a, b) = (
            extracted.to_world(&s.ends[0]),
            extracted.to_world(&s.ends[1]),
        );
        println!(
            "{:>8.3} {:>8.3} {:>7.2} {:>6} {:>5} {:>5} {:>9.5} {:>9.5} {:>9.4}  ({:.3}, {:.3}) ({:.3}, {:.3})",
            s.alpha,
            s.rho,
            s.length(),
            s.points,
            s.real[0],
            s.real[1],
            s.cov[(0, 0)].sqrt(),
            s.cov[(1, 1)].sqrt(),
            s.end_spacing[0].max(s.end_spacing[1]),
            a.x,
            a.y,
            b.x,
            b.y
        );
    }
    for p in &extracted.poles {
        println!(
            "pole at ({:.3}, {:.3}) radius {:.3} m, {} points",
            p.centre.x, p.centre.y, p.radius, p.points
        );
    }
}
