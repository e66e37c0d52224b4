//! The `"scan-points"` front-end: every valid return of a laser scan as a
//! [`LinePoint`] observation, for estimators that build their maps from the returns
//! themselves (IPSLAM).

use serde::{Deserialize, Serialize};
use slam_core::Observation;
use slam_core::nalgebra::Vector2;
use slam_sensors::Event;
use slam_sensors::models::LinePoint;
use std::sync::Arc;

use super::{Frontend, FrontendConfig, FrontendCounts, SensorInfo};
use crate::error::{Result, RuntimeError};

/// The `[frontend]` table of `type = "scan-points"`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScanPointsConfig {
    /// Range noise of the laser, m, given to each return (default: a simulated laser's, else
    /// 0.03).
    pub sigma_range: Option<f64>,
}

#[typetag::serde(name = "scan-points")]
impl FrontendConfig for ScanPointsConfig {
    fn build(&self, sensors: &SensorInfo) -> Result<Box<dyn Frontend>> {
        let sigma = self
            .sigma_range
            .or(sensors.laser_sigma_range)
            .unwrap_or(0.03);
        if !(sigma.is_finite() && sigma > 0.0) {
            return Err(RuntimeError::setting(
                "frontend",
                format!("sigma_range must be positive, got {sigma}"),
            ));
        }
        Ok(Box::new(ScanPoints {
            sigma,
            points: 0,
            scans: 0,
        }))
    }
}

/// The scan-points front-end at work.
struct ScanPoints {
    sigma: f64,
    points: usize,
    scans: usize,
}

impl Frontend for ScanPoints {
    fn observe(&mut self, event: &Event) -> Result<Vec<Observation>> {
        let Event::Scan {
            scan,
            robot_from_sensor,
        } = event
        else {
            return Ok(Vec::new());
        };
        self.scans += 1;
        let mut out = Vec::with_capacity(scan.ranges.len());
        for p in scan.points() {
            let point = Vector2::new(p.range * p.bearing.cos(), p.range * p.bearing.sin());
            out.push(Observation {
                robot_from_sensor: *robot_from_sensor,
                measurement: Arc::new(LinePoint::new(point, self.sigma)?),
                landmark_id: None,
            });
        }
        self.points += out.len();
        Ok(out)
    }

    fn counts(&self) -> FrontendCounts {
        [("scans", self.scans), ("points", self.points)]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect()
    }
}
