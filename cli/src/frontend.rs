//! Raw sensor data to observations: laser scans to walls and poles, ceiling images to lines
//! and lamps, with the settings of the `[frontend]` table.

use slam_core::{Observation, Pose3};
use slam_priors::{Params, Prior, ScanInput, infer};
use slam_sensors::LaserScan;
use slam_sensors::camera::{GrayImage, PinholeCamera};
use slam_sensors::extract::image::extract_image_features;
use slam_sensors::extract::{
    ExtractedSegment, LineExtractorParams, PoleExtractorParams, extract_poles, extract_segments,
    segments_from_readings,
};

use crate::config::{FrontendConfig, WallRepresentation, WallSegmentation};
use crate::error::{CliError, Result};

/// Counts of what the front-end produced and dropped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct FrontendCounts {
    /// Wall segments extracted.
    pub walls: usize,
    /// Poles extracted.
    pub poles: usize,
    /// Ceiling lines extracted.
    pub ceiling_lines: usize,
    /// Lamps extracted.
    pub lamps: usize,
    /// Extracted items whose observation could not be formed (degenerate geometry).
    pub dropped: usize,
    /// Scans whose structure-prior inference failed (a numerical failure, or no feasible
    /// topology): their walls are dropped (`wall_segmentation = "prior"` only).
    pub prior_failures: usize,
}

/// A structure prior that segments scans into walls (`wall_segmentation = "prior"`).
#[derive(Debug)]
struct PriorSegmenter {
    prior: Prior,
    params: Params,
    min_points: usize,
    tolerance: f64,
}

/// The configured front-end.
#[derive(Debug)]
pub struct Frontend {
    config: FrontendConfig,
    lines: LineExtractorParams,
    poles: PoleExtractorParams,
    /// The structure prior, when it segments the walls.
    prior: Option<PriorSegmenter>,
    sigma_range: f64,
    /// Factor on the deviations of what the extractors find.
    noise_factor: f64,
    /// What it produced so far.
    pub counts: FrontendCounts,
}

impl Frontend {
    /// A front-end for a laser with range noise `sigma_range` (m), whose extracted features'
    /// deviations are multiplied by `noise_factor` (the extractors decide what is a wall or a
    /// pole with the laser's own noise).
    ///
    /// With `wall_segmentation = "prior"` the prior is loaded and compiled here: an unknown
    /// prior, a malformed prior file or engine settings out of range are errors now rather
    /// than failures at every scan.
    pub fn new(config: &FrontendConfig, sigma_range: f64, noise_factor: f64) -> Result<Self> {
        let prior = match config.wall_segmentation {
            WallSegmentation::Prior if config.walls => Some(PriorSegmenter::new(config)?),
            _ => None,
        };
        Ok(Frontend {
            prior,
            lines: LineExtractorParams {
                sigma_range,
                ..config.lines.clone()
            },
            poles: PoleExtractorParams {
                sigma_range,
                ..config.pole_extractor.clone()
            },
            config: config.clone(),
            sigma_range,
            noise_factor,
            counts: FrontendCounts::default(),
        })
    }

    /// Checks the settings that [`Frontend::new`] checks (the structure prior loads and
    /// compiles), without a laser: to report a bad `[frontend]` before the data are loaded.
    pub fn check(config: &FrontendConfig) -> Result<()> {
        if config.walls && config.wall_segmentation == WallSegmentation::Prior {
            PriorSegmenter::new(config)?;
        }
        Ok(())
    }

    /// The wall segments of a scan, by the configured segmentation.
    fn wall_segments(&mut self, scan: &LaserScan) -> Vec<ExtractedSegment> {
        let Some(prior) = &self.prior else {
            return extract_segments(scan, &self.lines);
        };
        match prior.wall_readings(scan, self.sigma_range) {
            Ok(groups) => segments_from_readings(scan, &groups, &self.lines),
            Err(_) => {
                self.counts.prior_failures += 1;
                Vec::new()
            }
        }
    }

    /// Wall and pole observations of one scan taken by a laser at `robot_from_sensor`.
    pub fn scan_observations(
        &mut self,
        scan: &LaserScan,
        robot_from_sensor: &Pose3,
    ) -> Vec<Observation> {
        let mut out = Vec::new();
        let observation = |measurement| Observation {
            robot_from_sensor: *robot_from_sensor,
            measurement,
            landmark_id: None,
        };
        if self.config.walls {
            let f = self.noise_factor;
            for mut segment in self.wall_segments(scan) {
                segment.cov *= f * f;
                segment.end_spacing = segment.end_spacing.map(|s| s * f);
                let measurement: Option<Box<dyn slam_core::DynMeasurementModel>> =
                    match self.config.wall_representation {
                        WallRepresentation::Mspace => segment
                            .to_observation(self.sigma_range * f)
                            .ok()
                            .map(|o| Box::new(o) as _),
                        WallRepresentation::Endpoints => segment
                            .to_observation(self.sigma_range * f)
                            .ok()
                            .and_then(|o| {
                                slam_examples::EndpointWallObservation::new(
                                    o,
                                    self.config.endpoint_sigma_along_wall,
                                )
                                .ok()
                            })
                            .map(|o| Box::new(o) as _),
                    };
                match measurement {
                    Some(m) => {
                        self.counts.walls += 1;
                        out.push(observation(m));
                    }
                    None => self.counts.dropped += 1,
                }
            }
        }
        if self.config.poles {
            for mut pole in extract_poles(scan, &self.poles) {
                pole.cov *= self.noise_factor * self.noise_factor;
                match pole.to_observation(self.config.pole_sigma_floor * self.noise_factor) {
                    Ok(o) => {
                        self.counts.poles += 1;
                        out.push(observation(Box::new(o)));
                    }
                    Err(_) => self.counts.dropped += 1,
                }
            }
        }
        out
    }

    /// Line and lamp observations of one ceiling image.
    pub fn image_observations(
        &mut self,
        image: &GrayImage,
        camera: &PinholeCamera,
        robot_from_sensor: &Pose3,
    ) -> Result<Vec<Observation>> {
        if !self.config.camera {
            return Ok(Vec::new());
        }
        let features = extract_image_features(image, camera, &self.config.image);
        let (lines, lamps) = features.observations(
            camera,
            &self.config.image,
            self.config.assumed_ceiling_depth,
        )?;
        self.counts.ceiling_lines += lines.len();
        self.counts.lamps += lamps.len();
        let observation = |measurement| Observation {
            robot_from_sensor: *robot_from_sensor,
            measurement,
            landmark_id: None,
        };
        let mut out: Vec<Observation> = lines
            .into_iter()
            .map(|l| observation(Box::new(l) as Box<dyn slam_core::DynMeasurementModel>))
            .collect();
        out.extend(lamps.into_iter().map(|l| observation(Box::new(l))));
        Ok(out)
    }
}

impl PriorSegmenter {
    fn new(config: &FrontendConfig) -> Result<Self> {
        let settings = &config.prior;
        let context = |e: CliError| CliError::Usage(format!("[frontend.prior]: {e}"));
        let prior = crate::prior::load_prior(&settings.prior, &settings.files).map_err(context)?;
        settings
            .inference
            .validate()
            .map_err(|e| CliError::Usage(format!("[frontend.prior.inference]: {e}")))?;
        if !(settings.tolerance.is_finite() && settings.tolerance >= 0.0) {
            return Err(CliError::Usage(format!(
                "[frontend.prior] tolerance must be a non-negative angle, got {}",
                settings.tolerance
            )));
        }
        Ok(PriorSegmenter {
            prior,
            params: settings.inference.clone(),
            min_points: settings.min_points,
            tolerance: settings.tolerance,
        })
    }

    /// Runs the prior on the scan's valid readings and returns, per straight region, the
    /// beam indices of its readings in INMODEL (outliers inside a region's span are left
    /// out). An error when the inference fails or finds no feasible topology.
    fn wall_readings(
        &self,
        scan: &LaserScan,
        sigma_range: f64,
    ) -> std::result::Result<Vec<Vec<usize>>, slam_priors::PriorError> {
        let input = ScanInput::from_scan(scan, sigma_range)?;
        if input.len() < self.min_points.max(2) {
            // Too few readings for a wall: nothing to segment, and no failure.
            return Ok(Vec::new());
        }
        let solution = infer(&self.prior, &input, &self.params)?;
        if !solution.feasible {
            return Err(slam_priors::PriorError::Numerical(format!(
                "no feasible topology (largest violation {:.1e})",
                solution.max_violation
            )));
        }
        Ok(solution
            .straight_regions(self.min_points, self.tolerance)
            .iter()
            .map(|region| {
                (region.readings.0..=region.readings.1)
                    .filter(|&i| solution.in_model[i])
                    .map(|i| input.beam[i])
                    .collect()
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_priors::scene::{ScanSpec, Scene};

    /// A 6 m x 4 m room seen all around from (2, 1.5) heading 0.3 rad, with 2 cm range noise
    /// and three clutter readings, and its walls `(direction, distance)` in the sensor frame.
    /// (The scan is not closed: the first and last beams' readings are neighbours in space but
    /// not in the scan, as for a real laser; a wall across the seam would be two walls.)
    fn room_scan(seed: u64) -> (LaserScan, Vec<(f64, f64)>) {
        let (x, y, heading) = (2.0, 1.5, 0.3);
        let spec = ScanSpec {
            world_from_sensor: [x, y, heading],
            // The scan starts at the corner (0, 0), so that no wall is cut at its seam.
            angle_min: (-y).atan2(-x) - heading + 0.5 * std::f64::consts::TAU / 240.0,
            angle_increment: std::f64::consts::TAU / 240.0,
            beams: 240,
            sigma: 0.02,
            outliers: 3,
            max_range: 30.0,
        };
        let scan = Scene::rectangle(6.0, 4.0)
            .simulate_seeded(&spec, seed)
            .unwrap()
            .scan;
        let pi = std::f64::consts::PI;
        let walls = [(pi, x), (0.0, 6.0 - x), (-pi / 2.0, y), (pi / 2.0, 4.0 - y)]
            .map(|(direction, distance)| (direction - heading, distance));
        (scan, walls.to_vec())
    }

    fn prior_config(prior: &str) -> FrontendConfig {
        let mut config = FrontendConfig {
            wall_segmentation: WallSegmentation::Prior,
            poles: false,
            ..Default::default()
        };
        config.prior.prior = prior.into();
        config
    }

    fn angle(a: f64) -> f64 {
        a.sin().atan2(a.cos())
    }

    #[test]
    fn a_structure_prior_finds_the_walls_of_a_room() {
        for prior in ["rectangular", "polygonal"] {
            for seed in [1, 2] {
                let (scan, walls) = room_scan(seed);
                let mut frontend = Frontend::new(&prior_config(prior), 0.02, 1.5).unwrap();
                let segments = frontend.wall_segments(&scan);
                assert_eq!(segments.len(), 4, "{prior}, seed {seed}: {segments:#?}");
                for (direction, distance) in &walls {
                    let found = segments.iter().any(|s| {
                        angle(s.alpha - direction).abs() < 0.02 && (s.rho - distance).abs() < 0.03
                    });
                    assert!(
                        found,
                        "{prior}, seed {seed}: wall {direction} {distance} missing"
                    );
                }
                // The corners between the walls are real ends.
                let real = segments.iter().flat_map(|s| s.real).filter(|&r| r).count();
                assert!(real >= 6, "{prior}, seed {seed}: {real} real ends");
                // Observations come out as on the default path, and are counted.
                let observations = frontend.scan_observations(&scan, &Pose3::identity());
                assert_eq!(observations.len(), 4);
                assert_eq!(frontend.counts.walls, 4);
                assert_eq!(frontend.counts.prior_failures, 0);
            }
        }
    }

    #[test]
    fn bad_priors_are_errors_when_the_frontend_is_built() {
        let error = Frontend::new(&prior_config("no-such-prior"), 0.02, 1.0)
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("[frontend.prior]") && error.contains("unknown prior"),
            "{error}"
        );
        let file = std::env::temp_dir().join(format!("slam-frontend-{}.prior", std::process::id()));
        std::fs::write(
            &file,
            "name: Bad\norder: 2\npriorlet same_region:\n  rho_1 === 2\n",
        )
        .unwrap();
        let mut config = prior_config(&file.display().to_string());
        let error = Frontend::new(&config, 0.02, 1.0).unwrap_err().to_string();
        assert!(
            error.contains(&format!("{}:4:11", file.display())),
            "{error}"
        );
        std::fs::remove_file(&file).unwrap();
        config = prior_config("rectangular");
        config.prior.inference.inlier_probability = 1.5;
        let error = Frontend::new(&config, 0.02, 1.0).unwrap_err().to_string();
        assert!(error.contains("[frontend.prior.inference]"), "{error}");
        // Without walls, or with split-and-merge, the prior is not loaded.
        config = prior_config("no-such-prior");
        config.walls = false;
        assert!(Frontend::new(&config, 0.02, 1.0).is_ok());
    }

    #[test]
    fn a_failed_inference_drops_the_scans_walls_and_is_counted() {
        let mut config = prior_config("rectangular");
        // No relaxation allowed and a penalty too weak to reach feasibility.
        config.prior.inference.max_outer_iterations = Some(1);
        config.prior.inference.penalty_max = config.prior.inference.penalty_start;
        let mut frontend = Frontend::new(&config, 0.02, 1.0).unwrap();
        let (scan, _) = room_scan(1);
        let observations = frontend.scan_observations(&scan, &Pose3::identity());
        assert!(observations.is_empty());
        assert_eq!(frontend.counts.prior_failures, 1);
        assert_eq!(frontend.counts.walls, 0);
    }
}
