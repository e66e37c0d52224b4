//! The `"features"` front-end: laser scans to walls and poles, ceiling images to lines and
//! lamps, and the observations the data give.

use std::path::PathBuf;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use slam_core::{Observation, Pose3};
use slam_sensors::camera::{GrayImage, PinholeCamera};
use slam_sensors::extract::image::{ImageExtractorParams, extract_image_features};
use slam_sensors::extract::{
    ExtractedSegment, LineExtractorParams, PoleExtractorParams, extract_poles, extract_segments,
    segments_from_readings,
};
use slam_sensors::{Event, LaserScan};

use super::prior::PriorSegmenter;
use super::walls::{MspaceWalls, WallModel, by_name};
use super::{Frontend, FrontendConfig, FrontendCounts, SensorInfo};
use crate::error::{Result, RuntimeError};

/// How the laser wall front-end decides which readings of a scan form a wall.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WallSegmentation {
    /// Split-and-merge (`slam_sensors::extract::extract_segments`, `[frontend.lines]`).
    #[default]
    SplitMerge,
    /// A structure prior's inference on each scan (`[frontend.prior]`): its straight regions
    /// are the walls and its outliers are left out; each wall is then fitted like a
    /// split-and-merge segment (`slam_sensors::extract::segments_from_readings`).
    Prior,
}

/// The `[frontend.prior]` table: the structure prior that segments scans when
/// `wall_segmentation = "prior"`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PriorSegmentationConfig {
    /// The prior: a shipped prior by its file stem (`polygonal`, `rectangular`,
    /// `rectangular_relaxed`, ...), the `name:` of a shipped or loaded prior, or the path of a
    /// prior file (relative paths from the working directory).
    pub prior: String,
    /// More prior files to load first (they may specialize the shipped ones).
    pub files: Vec<PathBuf>,
    /// Fewest readings in a region taken as a wall (the pieces are then filtered by
    /// `[frontend.lines] min_points` and `min_length` as well).
    pub min_points: usize,
    /// A region is straight (a wall) when its corrected normals agree within this, rad.
    pub tolerance: f64,
    /// Settings of the inference engine.
    pub inference: slam_priors::Params,
}

impl Default for PriorSegmentationConfig {
    fn default() -> Self {
        PriorSegmentationConfig {
            prior: "rectangular".into(),
            files: Vec::new(),
            min_points: 8,
            tolerance: 1e-3,
            inference: slam_priors::Params::default(),
        }
    }
}

/// The `[frontend]` table of `type = "features"`.
///
/// ```
/// use slam_runtime::Config;
/// let config = Config::from_toml(
///     "[frontend]\nwall_representation = \"mspace\"\ncamera = false\n",
///     "inline",
/// )?;
/// # let _ = config;
/// # Ok::<(), slam_runtime::RuntimeError>(())
/// ```
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FeaturesFrontendConfig {
    /// Extract wall segments from laser scans.
    pub walls: bool,
    /// Extract poles from laser scans.
    pub poles: bool,
    /// Extract lines and lamps from ceiling images.
    pub camera: bool,
    /// Use the observations the data give ready-made (range-bearing landmarks, tree
    /// detections). Default (absent): only when the data hold no raw scans or images, since
    /// a simulated world's range-bearing stream sees the same poles the laser does.
    pub landmarks: Option<bool>,
    /// Drop the landmark ids the data give, so that the estimator associates the given
    /// observations itself (to test association on data with known ids).
    pub ignore_landmark_ids: bool,
    /// How walls are represented: a registered name (`"mspace"`; `"endpoints"` from
    /// `slam-examples`) or a table with `type` and the representation's settings.
    #[serde(deserialize_with = "by_name")]
    pub wall_representation: Box<dyn WallModel>,
    /// How scans are cut into walls: split-and-merge or a structure prior.
    pub wall_segmentation: WallSegmentation,
    /// The structure prior, for `wall_segmentation = "prior"`.
    pub prior: PriorSegmentationConfig,
    /// Range noise of the laser, m, which the extractors use (default: a simulated laser's,
    /// else 0.03).
    pub sigma_range: Option<f64>,
    /// On simulated data, the deviations of what the extractors find (wall lines and ends,
    /// poles) are multiplied by this factor (1: the laser's own noise). The wall extractor is
    /// calibrated at 1 against the simulator's truth (mean line NIS 2.05, corner ends 1.02:
    /// `cargo run --release -p slam-sensors --example segment_calibration`), and so is the
    /// filter: over seeds 1-50 of the built-in world (`slam consistency`) the average pose
    /// NEES is 2.81 with 1.0 and 2.51 with 1.25 (3 when consistent). Larger factors make the
    /// filter pessimistic; they are for experiments.
    pub simulated_noise_factor: f64,
    /// Deviation of a real wall's distance from its straight-line model, m, added to each
    /// wall observation's distance variance (walls are not exactly straight and flat, and
    /// a scan's points are not exactly simultaneous). Default 0: a simulated wall is exact.
    pub wall_model_sigma: f64,
    /// Deviation of a real wall's direction from its model, degrees, added to each wall
    /// observation's direction variance. Default 0.
    pub wall_model_sigma_deg: f64,
    /// Line extractor settings (its `sigma_range` is replaced by the laser's).
    pub lines: LineExtractorParams,
    /// Pole extractor settings (its `sigma_range` is replaced by the laser's).
    pub pole_extractor: PoleExtractorParams,
    /// Smallest deviation of a pole observation's range and radius, m.
    pub pole_sigma_floor: f64,
    /// Ceiling-image extractor settings.
    pub image: ImageExtractorParams,
    /// Distance above the camera at which a one-view ceiling feature is placed, m.
    pub assumed_ceiling_depth: f64,
    /// Treat every laser and camera as mounted level: the pitch and roll of each mount are
    /// dropped before the observations are built, as a planar SLAM system assumes. For
    /// studying what ignoring a tilted mount costs (BENCHMARKS.md, "A tilted laser and
    /// camera"); default false.
    pub level_mounts: bool,
    /// Readings of a tilted laser whose point lies below the laser and less than this height
    /// above the floor (z = 0 of the robot frame) are dropped before extraction, m: a tilted
    /// scan plane meets the floor along a straight line, which is not a wall. Level mounts
    /// lose nothing. 0: off.
    pub floor_clearance: f64,
}

impl Default for FeaturesFrontendConfig {
    fn default() -> Self {
        FeaturesFrontendConfig {
            walls: true,
            poles: true,
            camera: true,
            landmarks: None,
            ignore_landmark_ids: false,
            wall_representation: Box::new(MspaceWalls::default()),
            wall_segmentation: WallSegmentation::SplitMerge,
            prior: PriorSegmentationConfig::default(),
            sigma_range: None,
            simulated_noise_factor: 1.0,
            wall_model_sigma: 0.0,
            wall_model_sigma_deg: 0.0,
            lines: LineExtractorParams::default(),
            pole_extractor: PoleExtractorParams::default(),
            pole_sigma_floor: 0.01,
            image: ImageExtractorParams::default(),
            assumed_ceiling_depth: 2.3,
            level_mounts: false,
            floor_clearance: 0.05,
        }
    }
}

impl FeaturesFrontendConfig {
    /// The laser's range noise the extractors assume and the factor by which the covariances
    /// of what they extract are inflated: `sigma_range` (factor 1), else a simulated laser's
    /// noise with `simulated_noise_factor`, else 3 cm (factor 1).
    pub fn laser_noise(&self, sensors: &SensorInfo) -> Result<(f64, f64)> {
        let (sigma, factor) = match (self.sigma_range, sensors.laser_sigma_range) {
            (Some(sigma), _) => (sigma, 1.0),
            (None, Some(sigma)) => (sigma, self.simulated_noise_factor),
            (None, None) => (0.03, 1.0),
        };
        if sigma.is_finite() && sigma > 0.0 && factor.is_finite() && factor > 0.0 {
            Ok((sigma, factor))
        } else {
            Err(RuntimeError::setting(
                "frontend",
                format!(
                    "sigma_range and simulated_noise_factor must be positive, got {sigma} and \
                     {factor}"
                ),
            ))
        }
    }
}

#[typetag::serde(name = "features")]
impl FrontendConfig for FeaturesFrontendConfig {
    /// Loads and compiles the structure prior when it segments the walls: an unknown prior,
    /// a malformed prior file or engine settings out of range are errors before the data
    /// are read.
    fn validate(&self) -> Result<()> {
        for (key, value) in [
            ("wall_model_sigma", self.wall_model_sigma),
            ("wall_model_sigma_deg", self.wall_model_sigma_deg),
            ("floor_clearance", self.floor_clearance),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(RuntimeError::setting(
                    "frontend",
                    format!("{key} must be finite and at least 0, got {value}"),
                ));
            }
        }
        self.wall_representation
            .validate()
            .map_err(|e| RuntimeError::setting("frontend.wall_representation", e.to_string()))?;
        self.image
            .hough
            .validate()
            .map_err(|e| RuntimeError::setting("frontend.image", e.to_string()))?;
        if self.walls && self.wall_segmentation == WallSegmentation::Prior {
            PriorSegmenter::new(&self.prior)?;
        }
        Ok(())
    }

    fn build(&self, sensors: &SensorInfo) -> Result<Box<dyn Frontend>> {
        let (sigma_range, noise_factor) = self.laser_noise(sensors)?;
        Ok(Box::new(FeaturesFrontend::new(
            self,
            sigma_range,
            noise_factor,
            sensors.raw_sensors,
        )?))
    }
}

/// What the features front-end produced and dropped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Counts {
    walls: usize,
    poles: usize,
    ceiling_lines: usize,
    lamps: usize,
    /// Extracted items whose observation could not be formed (degenerate geometry).
    dropped: usize,
    /// Scans whose structure-prior inference failed: their walls are dropped.
    prior_failures: usize,
    /// Readings of a tilted laser dropped as floor (`floor_clearance`).
    floor_readings: usize,
}

/// The features front-end at work.
#[derive(Debug)]
pub(crate) struct FeaturesFrontend {
    config: FeaturesFrontendConfig,
    lines: LineExtractorParams,
    poles: PoleExtractorParams,
    /// The structure prior, when it segments the walls.
    prior: Option<PriorSegmenter>,
    sigma_range: f64,
    /// Factor on the deviations of what the extractors find.
    noise_factor: f64,
    /// Whether the observations the data give are passed on.
    use_given: bool,
    counts: Counts,
}

impl FeaturesFrontend {
    /// A front-end for a laser with range noise `sigma_range` (m), whose extracted features'
    /// deviations are multiplied by `noise_factor` (the extractors decide what is a wall or a
    /// pole with the laser's own noise).
    pub(crate) fn new(
        config: &FeaturesFrontendConfig,
        sigma_range: f64,
        noise_factor: f64,
        raw_sensors: bool,
    ) -> Result<Self> {
        let prior = match config.wall_segmentation {
            WallSegmentation::Prior if config.walls => Some(PriorSegmenter::new(&config.prior)?),
            _ => None,
        };
        Ok(FeaturesFrontend {
            prior,
            lines: LineExtractorParams {
                sigma_range,
                ..config.lines.clone()
            },
            poles: PoleExtractorParams {
                sigma_range,
                ..config.pole_extractor.clone()
            },
            use_given: config.landmarks.unwrap_or(!raw_sensors),
            config: config.clone(),
            sigma_range,
            noise_factor,
            counts: Counts::default(),
        })
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
    fn scan_observations(
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
        let tilted = robot_from_sensor.pitch != 0.0 || robot_from_sensor.roll != 0.0;
        let without_floor;
        let scan = if tilted && self.config.floor_clearance > 0.0 {
            let mut copy = scan.clone();
            self.counts.floor_readings +=
                copy.drop_floor_readings(robot_from_sensor, self.config.floor_clearance);
            without_floor = copy;
            &without_floor
        } else {
            scan
        };
        if self.config.walls {
            let f = self.noise_factor;
            for mut segment in self.wall_segments(scan) {
                segment.cov *= f * f;
                segment.cov[(0, 0)] += self.config.wall_model_sigma_deg.to_radians().powi(2);
                segment.cov[(1, 1)] += self.config.wall_model_sigma.powi(2);
                segment.end_spacing = segment.end_spacing.map(|s| s * f);
                match self
                    .config
                    .wall_representation
                    .observation(&segment, self.sigma_range * f)
                {
                    Ok(m) => {
                        self.counts.walls += 1;
                        out.push(observation(Arc::from(m)));
                    }
                    Err(_) => self.counts.dropped += 1,
                }
            }
        }
        if self.config.poles {
            for mut pole in extract_poles(scan, &self.poles) {
                pole.cov *= self.noise_factor * self.noise_factor;
                match pole.to_observation(self.config.pole_sigma_floor * self.noise_factor) {
                    Ok(o) => {
                        self.counts.poles += 1;
                        out.push(observation(Arc::new(o)));
                    }
                    Err(_) => self.counts.dropped += 1,
                }
            }
        }
        out
    }

    /// Line and lamp observations of one ceiling image.
    fn image_observations(
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
            .map(|l| observation(Arc::new(l) as Arc<dyn slam_core::DynMeasurementModel>))
            .collect();
        out.extend(lamps.into_iter().map(|l| observation(Arc::new(l))));
        Ok(out)
    }
}

impl Frontend for FeaturesFrontend {
    fn observe(&mut self, event: &Event) -> Result<Vec<Observation>> {
        let mount = |robot_from_sensor: &Pose3| {
            if self.config.level_mounts {
                Pose3::new(
                    robot_from_sensor.translation,
                    robot_from_sensor.yaw,
                    0.0,
                    0.0,
                )
            } else {
                *robot_from_sensor
            }
        };
        match event {
            Event::Scan {
                scan,
                robot_from_sensor,
            } => Ok(self.scan_observations(scan, &mount(robot_from_sensor))),
            Event::Image {
                image,
                camera,
                robot_from_sensor,
            } => self.image_observations(image, camera, &mount(robot_from_sensor)),
            Event::Observations(given) if self.use_given => {
                let mut observations = given.clone();
                if self.config.ignore_landmark_ids {
                    for o in &mut observations {
                        o.landmark_id = None;
                    }
                }
                Ok(observations)
            }
            _ => Ok(Vec::new()),
        }
    }

    fn counts(&self) -> FrontendCounts {
        let c = &self.counts;
        [
            ("walls", c.walls),
            ("poles", c.poles),
            ("ceiling_lines", c.ceiling_lines),
            ("lamps", c.lamps),
            ("dropped", c.dropped),
            ("prior_failures", c.prior_failures),
            ("floor_readings", c.floor_readings),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
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

    fn prior_config(prior: &str) -> FeaturesFrontendConfig {
        let mut config = FeaturesFrontendConfig {
            wall_segmentation: WallSegmentation::Prior,
            poles: false,
            ..Default::default()
        };
        config.prior.prior = prior.into();
        config
    }

    fn frontend(config: &FeaturesFrontendConfig, factor: f64) -> Result<FeaturesFrontend> {
        FeaturesFrontend::new(config, 0.02, factor, true)
    }

    fn angle(a: f64) -> f64 {
        a.sin().atan2(a.cos())
    }

    #[test]
    fn a_structure_prior_finds_the_walls_of_a_room() {
        for prior in ["rectangular", "polygonal"] {
            for seed in [1, 2] {
                let (scan, walls) = room_scan(seed);
                let mut frontend = frontend(&prior_config(prior), 1.5).unwrap();
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
        let error = frontend(&prior_config("no-such-prior"), 1.0)
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("[frontend.prior]") && error.contains("unknown prior"),
            "{error}"
        );
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("bad.prior");
        std::fs::write(
            &file,
            "name: Bad\norder: 2\npriorlet same_region:\n  rho_1 === 2\n",
        )
        .unwrap();
        let mut config = prior_config(&file.display().to_string());
        let error = frontend(&config, 1.0).unwrap_err().to_string();
        assert!(
            error.contains(&format!("{}:4:11", file.display())),
            "{error}"
        );
        config = prior_config("rectangular");
        config.prior.inference.inlier_probability = 1.5;
        let error = frontend(&config, 1.0).unwrap_err().to_string();
        assert!(error.contains("[frontend.prior.inference]"), "{error}");
        // Without walls, or with split-and-merge, the prior is not loaded.
        config = prior_config("no-such-prior");
        config.walls = false;
        assert!(frontend(&config, 1.0).is_ok());
    }

    #[test]
    fn a_failed_inference_drops_the_scans_walls_and_is_counted() {
        let mut config = prior_config("rectangular");
        // No relaxation allowed and a penalty too weak to reach feasibility.
        config.prior.inference.max_outer_iterations = Some(1);
        config.prior.inference.penalty_max = config.prior.inference.penalty_start;
        let mut frontend = frontend(&config, 1.0).unwrap();
        let (scan, _) = room_scan(1);
        let observations = frontend.scan_observations(&scan, &Pose3::identity());
        assert!(observations.is_empty());
        assert_eq!(frontend.counts.prior_failures, 1);
        assert_eq!(frontend.counts.walls, 0);
    }
}
