//! Raw sensor data to observations: laser scans to walls and poles, ceiling images to lines
//! and lamps, with the settings of the `[frontend]` table.

use slam_core::{Observation, Pose3};
use slam_sensors::LaserScan;
use slam_sensors::camera::{GrayImage, PinholeCamera};
use slam_sensors::extract::image::extract_image_features;
use slam_sensors::extract::{
    LineExtractorParams, PoleExtractorParams, extract_poles, extract_segments,
};

use crate::config::{FrontendConfig, WallRepresentation};
use crate::error::Result;

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
}

/// The configured front-end.
#[derive(Debug)]
pub struct Frontend {
    config: FrontendConfig,
    lines: LineExtractorParams,
    poles: PoleExtractorParams,
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
    pub fn new(config: &FrontendConfig, sigma_range: f64, noise_factor: f64) -> Self {
        Frontend {
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
            for mut segment in extract_segments(scan, &self.lines) {
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
