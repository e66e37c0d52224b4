//! The `slam run` configuration file (TOML). Every table and key is optional; unknown keys
//! are errors that name the key.
//!
//! ```toml
//! [data]
//! spec = "sim"            # sim, world:FILE, carmen:FILE, victoria-park:DIR, mrclam:DIR[:ROBOT], rb2d:FILE
//! seed = 1                # simulation seed
//!
//! [estimator]
//! type = "ekf"            # the one word that selects the estimator: ekf, fastslam, ipslam
//! association = "nearest-neighbour"   # or "jcbb"; further keys: slam_estimators::EkfParams
//!                         # type = "em-polygon": polygonal map of the registered scans (polygon.rs)
//!
//! [frontend]
//! walls = true            # laser scans -> wall segments
//! poles = true            # laser scans -> poles
//! camera = true           # ceiling images -> lines and lamps
//! landmarks = true        # observations the data give (default: when there is no raw data)
//! wall_representation = "mspace"      # or "endpoints" (the naive representation, for comparison)
//! wall_segmentation = "split-merge"   # or "prior": a structure prior segments each scan
//!
//! [frontend.prior]        # with wall_segmentation = "prior" (slam_priors, issue 6)
//! prior = "rectangular"   # a shipped prior by file stem (polygonal, rectangular, ...; see
//!                         # `slam prior --list`), a prior's `name:`, or a .prior file's path
//! files = []              # more prior files to load first (they may specialize shipped ones)
//! min_points = 8          # fewest readings in a region taken as a wall
//! tolerance = 1e-3        # rad: a region is straight when its normals agree within this
//! [frontend.prior.inference]          # engine settings: slam_priors::Params
//! min_region_points = 8
//!
//! [output]
//! dir = "slam-out"
//! plots = true
//! ```

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use slam_estimators::{EkfParams, FastSlamParams, IpslamParams};
use slam_sensors::extract::image::ImageExtractorParams;
use slam_sensors::extract::{LineExtractorParams, PoleExtractorParams};

use crate::error::{CliError, Result};

/// The whole configuration.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Where the data come from.
    pub data: DataConfig,
    /// Which estimator, with its settings.
    pub estimator: EstimatorConfig,
    /// How raw sensor data become observations.
    pub frontend: FrontendConfig,
    /// What is written where.
    pub output: OutputConfig,
}

/// The `[data]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DataConfig {
    /// Data spec (see `slam run --help`).
    pub spec: String,
    /// Seed of simulations.
    pub seed: u64,
    /// Standard deviations `(x, y, heading)` of the initial pose (m, m, rad). Default 0: the
    /// map frame is the robot's first pose (or the simulated start, which is known).
    pub initial_pose_sigma: [f64; 3],
    /// Process at most this many events (0: all).
    pub max_events: usize,
    /// Victoria Park reader noise settings.
    pub victoria_park: crate::data::VictoriaParkConfig,
    /// MR.CLAM reader noise settings.
    pub mrclam: crate::data::MrclamConfig,
    /// Replace the data's motion by odometry built from its reference poses with seeded
    /// noise (for logs without raw odometry, such as the Radish corrected logs).
    pub odometry_from_poses: Option<crate::data::PoseOdometryConfig>,
    /// Replace the motion between consecutive scans by the match of the scans (ICP, the
    /// motion as its prior); applied after `odometry_from_poses`.
    pub laser_odometry: Option<slam_sensors::laser_odometry::LaserOdometryParams>,
}

impl DataConfig {
    /// The readers' settings.
    pub fn reader_options(&self) -> crate::data::ReaderOptions {
        crate::data::ReaderOptions {
            victoria_park: self.victoria_park.clone(),
            mrclam: self.mrclam.clone(),
        }
    }
}

impl Default for DataConfig {
    fn default() -> Self {
        DataConfig {
            spec: "sim".into(),
            seed: 1,
            initial_pose_sigma: [0.0; 3],
            max_events: 0,
            victoria_park: Default::default(),
            mrclam: Default::default(),
            odometry_from_poses: None,
            laser_odometry: None,
        }
    }
}

/// The `[estimator]` table: `type` selects the estimator, the other keys are its settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "kebab-case")]
pub enum EstimatorConfig {
    /// The M-space EKF ([`slam_estimators::Ekf`]).
    Ekf(EkfParams),
    /// EM polygonal approximation of the registered scans (post-processing, `cli/src/polygon.rs`).
    EmPolygon(crate::polygon::EmPolygonConfig),
    /// FastSLAM 1.0 over the same features ([`slam_estimators::FastSlam`]).
    #[serde(rename = "fastslam")]
    FastSlam(FastSlamParams),
    /// IPSLAM's particles with PPCA line maps from raw scans ([`slam_estimators::Ipslam`]).
    #[serde(rename = "ipslam")]
    Ipslam(IpslamParams),
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        EstimatorConfig::Ekf(EkfParams::default())
    }
}

impl EstimatorConfig {
    /// The estimator's name, as in the config.
    pub fn name(&self) -> &'static str {
        match self {
            EstimatorConfig::Ekf(_) => "ekf",
            EstimatorConfig::EmPolygon(_) => "em-polygon",
            EstimatorConfig::FastSlam(_) => "fastslam",
            EstimatorConfig::Ipslam(_) => "ipslam",
        }
    }
}

/// How walls are represented in the map.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum WallRepresentation {
    /// M-space walls (`slam_features::Wall`): dimensions 0, 2, 3, 4, shared corners.
    #[default]
    Mspace,
    /// The naive representation: both endpoints in the state from the start, with a large
    /// variance along the wall where no real end was seen (`slam_examples::EndpointWall`).
    Endpoints,
}

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

/// The `[frontend]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FrontendConfig {
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
    /// How walls are represented.
    pub wall_representation: WallRepresentation,
    /// How scans are cut into walls: split-and-merge or a structure prior.
    pub wall_segmentation: WallSegmentation,
    /// The structure prior, for `wall_segmentation = "prior"`.
    pub prior: PriorSegmentationConfig,
    /// Standard deviation along the wall of an endpoint not seen as a real end, for the
    /// `endpoints` representation, m.
    pub endpoint_sigma_along_wall: f64,
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
}

impl Default for FrontendConfig {
    fn default() -> Self {
        FrontendConfig {
            walls: true,
            poles: true,
            camera: true,
            landmarks: None,
            ignore_landmark_ids: false,
            wall_representation: WallRepresentation::Mspace,
            wall_segmentation: WallSegmentation::SplitMerge,
            prior: PriorSegmentationConfig::default(),
            endpoint_sigma_along_wall: 1.0,
            sigma_range: None,
            simulated_noise_factor: 1.0,
            lines: LineExtractorParams::default(),
            pole_extractor: PoleExtractorParams::default(),
            pole_sigma_floor: 0.01,
            image: ImageExtractorParams::default(),
            assumed_ceiling_depth: 2.3,
        }
    }
}

/// The `[output]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Output folder.
    pub dir: PathBuf,
    /// Draw `map.svg` and `map.png`.
    pub plots: bool,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            dir: PathBuf::from("slam-out"),
            plots: true,
        }
    }
}

impl Config {
    /// Parses a TOML configuration; unknown keys are errors naming the key.
    ///
    /// ```ignore
    /// let config = Config::from_toml("[estimator]\ntype = \"ekf\"\n", "inline").unwrap();
    /// ```
    pub fn from_toml(text: &str, origin: &str) -> Result<Self> {
        toml::from_str(text).map_err(|e| CliError::Usage(format!("config {origin}: {e}")))
    }

    /// Reads a TOML configuration file.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| CliError::Output {
            path: path.display().to_string(),
            message: format!("cannot read the config: {e}"),
        })?;
        Self::from_toml(&text, &path.display().to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_config_is_the_default() {
        assert_eq!(Config::from_toml("", "t").unwrap(), Config::default());
    }

    #[test]
    fn one_word_selects_the_estimator_and_its_keys() {
        let config = Config::from_toml(
            "[estimator]\ntype = \"ekf\"\nassociation = \"jcbb\"\nconfirm_after = 2\n",
            "t",
        )
        .unwrap();
        let EstimatorConfig::Ekf(params) = config.estimator else {
            panic!("not the EKF: {:?}", config.estimator);
        };
        assert_eq!(params.confirm_after, 2);
        assert_eq!(params.association, slam_estimators::Association::Jcbb);
    }

    #[test]
    fn the_prior_segmentation_and_its_keys() {
        let config = Config::from_toml(
            "[frontend]\nwall_segmentation = \"prior\"\n[frontend.prior]\nprior = \"polygonal\"\n\
             files = [\"a.prior\"]\nmin_points = 5\ntolerance = 1e-4\n\
             [frontend.prior.inference]\nmin_region_points = 6\nrefine_boundaries = false\n",
            "t",
        )
        .unwrap();
        let frontend = &config.frontend;
        assert_eq!(frontend.wall_segmentation, WallSegmentation::Prior);
        assert_eq!(frontend.prior.prior, "polygonal");
        assert_eq!(frontend.prior.files, vec![PathBuf::from("a.prior")]);
        assert_eq!(frontend.prior.min_points, 5);
        assert_eq!(frontend.prior.tolerance, 1e-4);
        assert_eq!(frontend.prior.inference.min_region_points, Some(6));
        assert!(!frontend.prior.inference.refine_boundaries);
        // The other engine settings keep their defaults.
        assert_eq!(
            frontend.prior.inference.bound_sigmas,
            slam_priors::Params::default().bound_sigmas
        );
        let default = Config::from_toml("[frontend]\nwalls = true\n", "t").unwrap();
        assert_eq!(
            default.frontend.wall_segmentation,
            WallSegmentation::SplitMerge
        );
        assert_eq!(default.frontend.prior, PriorSegmentationConfig::default());
    }

    #[test]
    fn unknown_keys_are_named() {
        for (text, key) in [
            ("[data]\nspeck = \"sim\"\n", "speck"),
            ("[estimator]\ntype = \"ekf\"\ngate = 0.9\n", "gate"),
            ("[frontend]\nwals = true\n", "wals"),
            ("[data.laser_odometry]\ngates = 0.3\n", "gates"),
            ("[frontend.lines]\nsplit = 1\n", "split"),
            ("[frontend.prior]\nname = \"polygonal\"\n", "name"),
            ("[frontend.prior.inference]\ngamma = 1.0\n", "gamma"),
            ("[frontend]\nwall_segmentation = \"em\"\n", "em"),
            ("[outputs]\n", "outputs"),
            ("[estimator]\ntype = \"kalman\"\n", "kalman"),
        ] {
            let error = Config::from_toml(text, "t").unwrap_err().to_string();
            assert!(error.contains(key), "{text}: {error}");
        }
    }
}
