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

/// The inference engine's settings, checked key by key (the conditions of
/// [`Params::validate`], whose own message lists every setting): the error names the key.
fn check_inference(p: &Params) -> Result<()> {
    let checks = [
        (
            "bound_sigmas",
            p.bound_sigmas,
            p.bound_sigmas > 0.0,
            "positive",
        ),
        (
            "inlier_probability",
            p.inlier_probability,
            p.inlier_probability > 0.0 && p.inlier_probability < 1.0,
            "in (0, 1)",
        ),
        (
            "feasibility_tolerance",
            p.feasibility_tolerance,
            p.feasibility_tolerance > 0.0,
            "positive",
        ),
        (
            "penalty_start",
            p.penalty_start,
            p.penalty_start > 0.0,
            "positive",
        ),
        (
            "penalty_factor",
            p.penalty_factor,
            p.penalty_factor > 1.0,
            "above 1",
        ),
        (
            "penalty_max",
            p.penalty_max,
            p.penalty_max >= p.penalty_start,
            "at least penalty_start",
        ),
        (
            "barrier_start",
            p.barrier_start,
            p.barrier_start > 0.0,
            "positive",
        ),
        (
            "barrier_factor",
            p.barrier_factor,
            p.barrier_factor > 0.0 && p.barrier_factor < 1.0,
            "in (0, 1)",
        ),
        (
            "min_normal_bound_deg",
            p.min_normal_bound_deg,
            p.min_normal_bound_deg >= 0.0,
            "non-negative",
        ),
        (
            "stall_ratio",
            p.stall_ratio,
            p.stall_ratio.is_finite(),
            "finite",
        ),
        (
            "max_incidence_deg",
            p.max_incidence_deg,
            p.max_incidence_deg.is_finite(),
            "finite",
        ),
    ];
    for (key, value, ok, what) in checks {
        if !ok || value.is_nan() {
            return Err(RuntimeError::setting(
                "frontend.prior.inference",
                format!("{key} must be {what}, got {value}"),
            ));
        }
    }
    if p.max_newton_steps == 0 {
        return Err(RuntimeError::setting(
            "frontend.prior.inference",
            "max_newton_steps must be at least 1, got 0",
        ));
    }
    Ok(())
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
        check_inference(&settings.inference)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_engine_settings_name_their_key_not_a_struct_dump() {
        let params = Params {
            bound_sigmas: f64::NAN,
            ..Params::default()
        };
        let error = check_inference(&params).unwrap_err().to_string();
        assert_eq!(
            error,
            "[frontend.prior.inference] bound_sigmas must be positive, got NaN"
        );
        let params = Params {
            barrier_factor: 2.0,
            ..Params::default()
        };
        let error = check_inference(&params).unwrap_err().to_string();
        assert!(error.contains("barrier_factor must be in (0, 1)") && !error.contains("Params {"));
        assert!(check_inference(&Params::default()).is_ok());
    }
}
