//! Structure priors as the wall front-end's segmentation (`wall_segmentation = "prior"`),
//! and loading a prior by name or file.

use std::path::{Path, PathBuf};

use slam_priors::{Library, Params, Prior, PriorError, SHIPPED, ScanInput, infer};
use slam_sensors::LaserScan;

use super::features::PriorSegmentationConfig;
use crate::error::{Result, RuntimeError};

/// The shipped priors and then `files` (which may specialize them).
pub fn prior_library(files: &[PathBuf]) -> Result<Library> {
    let mut library = Library::shipped()?;
    for path in files {
        library.add_file(path)?;
    }
    Ok(library)
}

/// Loads and compiles a prior named by `spec`, after loading `files` into the shipped
/// library: a shipped prior by its file stem (`rectangular` for `rectangular.prior`; `-` may
/// stand for `_`), the `name:` of a loaded prior, or the path of a prior file to load.
/// Unknown names and malformed files are errors that say so (with the file, line and column).
///
/// ```
/// let prior = slam_runtime::load_prior("rectangular", &[])?;
/// # let _ = prior;
/// # Ok::<(), slam_runtime::RuntimeError>(())
/// ```
pub fn load_prior(spec: &str, files: &[PathBuf]) -> Result<Prior> {
    let mut library = prior_library(files)?;
    let path = Path::new(spec);
    let name = if library.names().iter().any(|n| n == spec) {
        spec.to_string()
    } else if let Some((origin, text)) = SHIPPED.iter().find(|(file, _)| {
        file.strip_suffix(".prior")
            .is_some_and(|stem| stem.eq_ignore_ascii_case(&spec.replace('-', "_")))
    }) {
        // Its `name:` (parsed again on its own; it is in the library already).
        Library::default().add(text, origin)?
    } else if path.is_file() {
        library.add_file(path)?
    } else {
        let stems: Vec<&str> = SHIPPED
            .iter()
            .filter_map(|(file, _)| file.strip_suffix(".prior"))
            .collect();
        return Err(RuntimeError::Data(format!(
            "unknown prior {spec:?}: not a shipped prior ({}), not a loaded prior's name ({}) and \
             not a prior file",
            stems.join(", "),
            library
                .names()
                .iter()
                .map(|n| format!("{n:?}"))
                .collect::<Vec<_>>()
                .join(", ")
        )));
    };
    Ok(library.compile(&name)?)
}

/// A structure prior that segments scans into walls.
#[derive(Debug)]
pub(super) struct PriorSegmenter {
    prior: Prior,
    params: Params,
    min_points: usize,
    tolerance: f64,
}

impl PriorSegmenter {
    /// Loads and compiles the prior and checks the engine settings: errors name the table.
    pub(super) fn new(settings: &PriorSegmentationConfig) -> Result<Self> {
        let prior = load_prior(&settings.prior, &settings.files)
            .map_err(|e| RuntimeError::setting("frontend.prior", e.to_string()))?;
        settings
            .inference
            .validate()
            .map_err(|e| RuntimeError::setting("frontend.prior.inference", e.to_string()))?;
        if !(settings.tolerance.is_finite() && settings.tolerance >= 0.0) {
            return Err(RuntimeError::setting(
                "frontend.prior",
                format!(
                    "tolerance must be a non-negative angle, got {}",
                    settings.tolerance
                ),
            ));
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
    pub(super) fn wall_readings(
        &self,
        scan: &LaserScan,
        sigma_range: f64,
    ) -> std::result::Result<Vec<Vec<usize>>, PriorError> {
        let input = ScanInput::from_scan(scan, sigma_range)?;
        if input.len() < self.min_points.max(2) {
            // Too few readings for a wall: nothing to segment, and no failure.
            return Ok(Vec::new());
        }
        let solution = infer(&self.prior, &input, &self.params)?;
        if !solution.feasible {
            return Err(PriorError::Numerical(format!(
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
