//! Measurement models: the innovation `eta(x_o, v)` with `J_eta_o`, `J_eta_v` and `C_v` for
//! each sensor and feature pair (paper section V-A). Each is property-tested against central
//! differences through `slam_core::testing::check_measurement`.

pub mod camera;
pub mod line_point;
pub mod pole;
pub mod range_bearing;
pub mod wall;

pub use camera::{ImageLineObservation, ImagePointObservation};
pub use line_point::LinePoint;
pub use pole::PoleObservation;
pub use range_bearing::RangeBearing;
pub use wall::{BEYOND_ESTIMATED_END, MAX_GAP, WallObservation};

use slam_core::Pose3;
use slam_core::nalgebra::{DMatrix, Dim, Matrix, Matrix2, RawStorage, Vector2};

/// The map-frame vertical line through a point of a (possibly tilted) scan plane: the
/// inverse of paper eq. 34, `x_m = M (u, v) + t_xy` with `M` the top-left 2x2 block of the
/// sensor's rotation.
pub fn scan_plane_to_world(world_from_sensor: &Pose3, in_plane: &Vector2<f64>) -> Vector2<f64> {
    let m: Matrix2<f64> = world_from_sensor
        .rotation()
        .fixed_view::<2, 2>(0, 0)
        .into_owned();
    m * in_plane + world_from_sensor.translation.xy()
}

/// A small stack matrix as a dynamic one (what a model's own linearization returns).
pub(crate) fn dynamic<R: Dim, C: Dim, S: RawStorage<f64, R, C>>(
    matrix: &Matrix<f64, R, C, S>,
) -> DMatrix<f64> {
    DMatrix::from_fn(matrix.nrows(), matrix.ncols(), |i, j| matrix[(i, j)])
}

/// Checks that standard deviations are finite and positive.
pub(crate) fn check_sigmas(sigmas: &[f64], what: &str) -> slam_core::Result<()> {
    if sigmas.iter().all(|s| s.is_finite() && *s > 0.0) {
        Ok(())
    } else {
        Err(slam_core::Error::InvalidArgument(format!(
            "{what}: standard deviations must be finite and positive, got {sigmas:?}"
        )))
    }
}
