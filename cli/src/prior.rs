//! `slam prior`: runs a structure prior (a priorlet file) on one scan, prints the topology,
//! outliers and degrees of freedom, and draws the readings before and after, the region and
//! surface boundaries and the outliers.

use std::path::PathBuf;
use std::time::Instant;

use plotters::style::RGBColor;
use slam_core::nalgebra::Vector2;
use slam_priors::scene::{ScanSpec, Scene, Shape};
use slam_priors::{Params, ScanInput, Solution, Topology, analyze, infer};
use slam_sensors::{Event, LaserScan};

use crate::error::{CliError, Result};
use crate::plot::{Figure, palette};

/// Arguments of `slam prior`.
#[derive(Debug, clap::Args)]
pub struct PriorArgs {
    /// Data: a built-in scene (square, rectangle, circle, two-circles) or any data source of
    /// `slam extract` (sim, world:FILE, carmen:FILE).
    #[arg(long, default_value = "square")]
    pub data: String,
    /// Which scan of a data source (0-based, in stream order).
    #[arg(long, default_value_t = 0)]
    pub scan: usize,
    /// The prior to apply: a shipped prior's file stem (rectangular, polygonal, ...), a
    /// prior's name (see --list) or a prior file.
    #[arg(long, default_value = "Rectangular prior")]
    pub prior: String,
    /// More prior files to load (they may specialize the shipped ones); repeatable.
    #[arg(long = "prior-file")]
    pub prior_files: Vec<PathBuf>,
    /// List the loaded priors and exit.
    #[arg(long)]
    pub list: bool,
    /// Range noise standard deviation, m (simulated and assumed).
    #[arg(long, default_value_t = 0.01)]
    pub sigma_range: f64,
    /// Beams of a built-in scene's 360-degree scan.
    #[arg(long, default_value_t = 180)]
    pub beams: usize,
    /// Clutter outliers added to a built-in scene's scan.
    #[arg(long, default_value_t = 3)]
    pub outliers: usize,
    /// Keep only beams between these bearings (rad), e.g. `--fov=-1.57,1.57`.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 2,
        allow_hyphen_values = true,
        value_names = ["MIN", "MAX"]
    )]
    pub fov: Option<Vec<f64>>,
    /// Compute the degrees of freedom and the posterior covariance.
    #[arg(long)]
    pub dof: bool,
    /// List and draw the straight regions as wall segments (what a wall front-end would
    /// take).
    #[arg(long)]
    pub walls: bool,
    /// Seed of the simulation.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output image (.png or .svg).
    #[arg(long, default_value = "prior.png")]
    pub out: PathBuf,
}

use slam_runtime::frontend::prior_library as library;
use slam_runtime::load_prior;

/// A scan to process, with the true surfaces of a built-in scene.
struct Input {
    name: String,
    scan: LaserScan,
    scene: Option<Scene>,
}

fn built_in(args: &PriorArgs) -> Option<(Scene, [f64; 3])> {
    let circle = |centre, radius| Shape::Circle { centre, radius };
    match args.data.as_str() {
        "square" => Some((Scene::rectangle(4.0, 4.0), [1.7, 2.2, 0.3])),
        "rectangle" => Some((Scene::rectangle(6.0, 3.0), [2.0, 1.2, 0.0])),
        "circle" => Some((
            Scene {
                shapes: vec![circle([0.0, 0.0], 3.0)],
            },
            [0.7, -0.4, 0.2],
        )),
        "two-circles" => Some((
            Scene {
                shapes: vec![circle([2.0, 1.0], 0.5), circle([2.0, -1.5], 0.7)],
            },
            [0.0, 0.0, 0.0],
        )),
        _ => None,
    }
}

fn load(args: &PriorArgs) -> Result<Input> {
    if let Some((scene, pose)) = built_in(args) {
        if args.beams < 3 {
            return Err(CliError::Usage("--beams must be at least 3".into()));
        }
        let spec = ScanSpec {
            world_from_sensor: pose,
            angle_min: -std::f64::consts::PI,
            angle_increment: std::f64::consts::TAU / args.beams as f64,
            beams: args.beams,
            sigma: args.sigma_range,
            outliers: args.outliers,
            max_range: 30.0,
        };
        let sim = scene.simulate_seeded(&spec, args.seed)?;
        // Draw the scene in the sensor frame.
        let (s, c) = pose[2].sin_cos();
        let to_sensor = |p: [f64; 2]| {
            let (dx, dy) = (p[0] - pose[0], p[1] - pose[1]);
            [c * dx + s * dy, -s * dx + c * dy]
        };
        let shapes = scene
            .shapes
            .iter()
            .map(|shape| match *shape {
                Shape::Segment { a, b } => Shape::Segment {
                    a: to_sensor(a),
                    b: to_sensor(b),
                },
                Shape::Circle { centre, radius } => Shape::Circle {
                    centre: to_sensor(centre),
                    radius,
                },
            })
            .collect();
        return Ok(Input {
            name: format!(
                "{} ({} beams, seed {}, {} outliers)",
                args.data, args.beams, args.seed, args.outliers
            ),
            scan: sim.scan,
            scene: Some(Scene { shapes }),
        });
    }
    let data = slam_runtime::data::DataConfig {
        spec: args.data.clone(),
        seed: args.seed,
        ..Default::default()
    }
    .open()?;
    let name = data.events.info.name.clone();
    let mut count = 0;
    for event in data.events {
        if let Event::Scan { scan, .. } = event?.event {
            if count == args.scan {
                return Ok(Input {
                    name: format!("{name}, scan {}", args.scan),
                    scan,
                    scene: None,
                });
            }
            count += 1;
        }
    }
    Err(CliError::Usage(format!(
        "--scan {} is out of range: the data hold {count} scans",
        args.scan
    )))
}

/// Runs `slam prior`.
pub fn run(args: &PriorArgs) -> Result<()> {
    if args.list {
        return list_priors(args);
    }
    let prior = load_prior(&args.prior, &args.prior_files)?;
    if !(args.sigma_range.is_finite() && args.sigma_range > 0.0) {
        return Err(CliError::Usage(format!(
            "--sigma-range must be positive, got {}",
            args.sigma_range
        )));
    }
    let input = load(args)?;
    let mut scan_input = ScanInput::from_scan(&input.scan, args.sigma_range)?;
    if let Some(fov) = &args.fov {
        scan_input = within(&scan_input, fov[0], fov[1]);
    }
    let start = Instant::now();
    let solution = infer(&prior, &scan_input, &Params::default())?;
    print_solution(
        &input.name,
        &prior,
        &solution,
        scan_input.len(),
        start.elapsed(),
    );
    if args.dof {
        print_degrees_of_freedom(&prior, &solution)?;
    }
    let mut figure = Figure::new(
        format!("{}: {} (sensor frame)", input.name, prior.name),
        1400,
    );
    if let Some(scene) = &input.scene {
        draw_scene(&mut figure, scene);
    }
    draw_readings(&mut figure, &solution);
    draw_boundaries(&mut figure, &solution);
    if args.walls {
        draw_walls(&mut figure, &solution);
    }
    figure.marker(Vector2::zeros(), palette::TRUE_PATH, 14, true);
    figure.legend("sensor", palette::TRUE_PATH);
    figure.save(&args.out)?;
    println!("image: {}", args.out.display());
    Ok(())
}

/// `slam prior --list`: the loaded priors with their order.
fn list_priors(args: &PriorArgs) -> Result<()> {
    let library = library(&args.prior_files)?;
    for name in library.names() {
        let prior = library.compile(&name)?;
        println!("{name} (order {})", prior.order);
    }
    Ok(())
}

/// The readings of `input` whose bearings lie in `[lo, hi]`.
fn within(input: &ScanInput, lo: f64, hi: f64) -> ScanInput {
    let keep: Vec<usize> = (0..input.len())
        .filter(|&i| input.phi[i] >= lo && input.phi[i] <= hi)
        .collect();
    ScanInput {
        phi: keep.iter().map(|&i| input.phi[i]).collect(),
        rho: keep.iter().map(|&i| input.rho[i]).collect(),
        sigma: keep.iter().map(|&i| input.sigma[i]).collect(),
        beam: keep.iter().map(|&i| input.beam[i]).collect(),
    }
}

/// What the inference found, in three lines.
fn print_solution(
    name: &str,
    prior: &slam_priors::Prior,
    solution: &Solution,
    readings: usize,
    elapsed: std::time::Duration,
) {
    println!(
        "{name}: {readings} readings, prior {:?}: {} in {:.2?} ({} topologies, {} inner \
         optimizations of their parts), largest violation {:.1e}",
        prior.name,
        if solution.feasible {
            "feasible"
        } else {
            "NOT feasible"
        },
        elapsed,
        solution.outer_iterations,
        solution.inner_optimizations,
        solution.max_violation
    );
    println!(
        "{} regions on {} surfaces, {} outliers; fit cost {:.1}, objective {:.1}",
        solution.regions().len(),
        solution.surfaces().len(),
        solution.outliers().len(),
        solution.fit_cost,
        solution.objective
    );
    let moved = solution
        .inliers()
        .iter()
        .map(|&i| (solution.rho[i] - solution.measured[i]).abs())
        .fold(0.0, f64::max);
    println!("largest range correction {:.4} m", moved);
}

/// `--dof`: the degrees of freedom and the posterior range deviations.
fn print_degrees_of_freedom(prior: &slam_priors::Prior, solution: &Solution) -> Result<()> {
    if !solution.feasible {
        println!("degrees of freedom: not computed (the solution is not feasible)");
        return Ok(());
    }
    let dof = analyze(prior, solution)?;
    println!(
        "degrees of freedom: free {}, extrinsic {}, intrinsic {} ({} constraints)",
        dof.free_dim(),
        dof.extrinsic_dim(),
        dof.intrinsic_dim(),
        dof.constraints
    );
    let sd = dof.range_std();
    let before =
        dof.members.iter().map(|&i| solution.sigma[i]).sum::<f64>() / sd.len().max(1) as f64;
    let after = sd.iter().sum::<f64>() / sd.len().max(1) as f64;
    println!(
        "mean range standard deviation: {before:.4} m before, {after:.4} m after; largest \
         eigen-variations (sd): {}",
        dof.variations
            .iter()
            .take(5)
            .map(|(s, _)| format!("{s:.4}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(())
}

/// The true surfaces of a built-in scene.
fn draw_scene(figure: &mut Figure, scene: &Scene) {
    for shape in &scene.shapes {
        match *shape {
            Shape::Segment { a, b } => figure.segment(
                Vector2::new(a[0], a[1]),
                Vector2::new(b[0], b[1]),
                palette::TRUTH,
                2,
            ),
            Shape::Circle { centre, radius } => figure.circle(
                Vector2::new(centre[0], centre[1]),
                radius,
                palette::TRUTH,
                false,
            ),
        }
    }
    figure.legend("true surfaces", palette::TRUTH);
}

/// Reading `i` at range `rho` in the sensor frame.
fn reading(solution: &Solution, i: usize, rho: f64) -> Vector2<f64> {
    let (s, c) = solution.phi[i].sin_cos();
    Vector2::new(rho * c, rho * s)
}

/// The measured readings, the corrected ones (one colour per region) and their normals.
fn draw_readings(figure: &mut Figure, solution: &Solution) {
    figure.dots(
        (0..solution.phi.len())
            .map(|i| reading(solution, i, solution.measured[i]))
            .collect(),
        palette::POINTS,
        3,
    );
    figure.legend("measured readings", palette::POINTS);
    let colours = [
        RGBColor(20, 60, 200),
        RGBColor(20, 150, 60),
        RGBColor(160, 40, 160),
        RGBColor(0, 140, 160),
    ];
    let regions = solution.regions();
    for (k, region) in regions.iter().enumerate() {
        let colour = colours[k % colours.len()];
        let points: Vec<_> = region
            .iter()
            .map(|&i| reading(solution, i, solution.rho[i]))
            .collect();
        figure.polyline(points.clone(), colour, 2);
        figure.dots(points, colour, 2);
    }
    figure.legend(
        format!(
            "corrected readings, one colour per region ({} regions)",
            regions.len()
        ),
        colours[0],
    );
    // Normals: a short segment from every corrected reading (every other for dense scans).
    let stride = (solution.phi.len() / 180).max(1);
    for (k, i) in solution.inliers().into_iter().enumerate() {
        if k % stride != 0 {
            continue;
        }
        let p = reading(solution, i, solution.rho[i]);
        let n = Vector2::new(solution.alpha[i].cos(), solution.alpha[i].sin());
        figure.segment(p, p + 0.12 * n, palette::CORNER, 1);
    }
    figure.legend("corrected normals", palette::CORNER);
}

/// Region and surface boundaries (both readings of a link marked) and the outliers.
fn draw_boundaries(figure: &mut Figure, solution: &Solution) {
    let mut region_marks = 0;
    let mut surface_marks = 0;
    for link in &solution.links {
        if link.topology == Topology::SameRegion {
            continue;
        }
        // Hollow for a region boundary, filled for a surface boundary.
        let surface = link.topology == Topology::DifferentSurface;
        for i in [link.from, link.to] {
            let at = reading(solution, i, solution.rho[i]);
            figure.marker(at, RGBColor(0, 0, 0), 10, surface);
        }
        if surface {
            surface_marks += 1;
        } else {
            region_marks += 1;
        }
    }
    figure.legend(
        format!(
            "boundaries (both readings marked): {region_marks} between regions (hollow), \
             {surface_marks} between surfaces (filled)"
        ),
        RGBColor(0, 0, 0),
    );
    let outliers = solution.outliers();
    for &i in &outliers {
        let at = reading(solution, i, solution.measured[i]);
        figure.marker(at, palette::PATH, 9, true);
    }
    figure.legend(
        format!("{} outliers (out of INMODEL)", outliers.len()),
        palette::PATH,
    );
}

/// `--walls`: the straight regions as wall segments, drawn and printed.
fn draw_walls(figure: &mut Figure, solution: &Solution) {
    let walls = solution.straight_regions(5, 1e-4);
    for w in &walls {
        let (a, b) = (
            Vector2::new(w.ends[0][0], w.ends[0][1]),
            Vector2::new(w.ends[1][0], w.ends[1][1]),
        );
        figure.segment(a, b, palette::WALL, 5);
        println!(
            "wall: readings {}-{} ({} points), normal {:.4} rad, distance {:.3} m, ends \
             ({:.3}, {:.3}) ({:.3}, {:.3})",
            w.readings.0, w.readings.1, w.points, w.normal, w.distance, a.x, a.y, b.x, b.y
        );
    }
    figure.legend(
        format!("{} straight regions as wall segments", walls.len()),
        palette::WALL,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(data: &str, out: PathBuf) -> PriorArgs {
        PriorArgs {
            data: data.into(),
            scan: 0,
            prior: "Rectangular prior".into(),
            prior_files: Vec::new(),
            list: false,
            sigma_range: 0.01,
            beams: 90,
            outliers: 2,
            fov: None,
            dof: true,
            walls: true,
            seed: 3,
            out,
        }
    }

    #[test]
    fn a_built_in_scene_is_drawn() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("square.png");
        run(&args("square", out.clone())).unwrap();
        assert!(std::fs::metadata(&out).unwrap().len() > 1000);
    }

    #[test]
    fn bad_prior_files_and_names_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("bad.prior");
        std::fs::write(
            &file,
            "name: Bad\norder: 2\npriorlet same_region:\n  rho_1 === 2\n",
        )
        .unwrap();
        let mut a = args("square", dir.path().join("unused.png"));
        a.prior_files = vec![file.clone()];
        let error = run(&a).unwrap_err().to_string();
        assert!(error.contains("bad.prior:4:11"), "{error}");
        let mut a = args("square", dir.path().join("unused.png"));
        a.prior = "No such prior".into();
        assert!(run(&a).unwrap_err().to_string().contains("unknown prior"));
    }

    #[test]
    #[cfg_attr(
        not(slam_data),
        ignore = "needs the real datasets (DATASETS.md, SLAM_DATA_DIR)"
    )]
    fn a_real_scan_of_the_intel_log() {
        let log = std::path::Path::new(option_env!("SLAM_DATA").unwrap_or("absent"))
            .join("radish-carmen-corrected/intel-corrected.log.gz");
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("intel.png");
        let mut a = args(&format!("carmen:{}", log.display()), out.clone());
        a.sigma_range = 0.02;
        run(&a).unwrap();
        assert!(std::fs::metadata(&out).unwrap().len() > 1000);
    }
}
