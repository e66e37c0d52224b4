//! The pinhole camera and grayscale images.
//!
//! Camera frame: the optical axis is `z`; image `u` runs along `x` and `v` along `y`. A
//! ceiling camera looks up, so its frame is the robot frame raised to the camera's height (no
//! pitch, so no Euler-angle singularity).

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{Matrix2x3, Vector2, Vector3};
use slam_core::{Error, Result};

/// The most pixels an image may have (a resource limit: 64 Mi, e.g. 8192 x 8192).
pub const MAX_PIXELS: u64 = 1 << 26;

/// Pinhole intrinsics in pixels.
///
/// ```
/// use slam_sensors::camera::PinholeCamera;
/// use slam_core::nalgebra::Vector3;
/// let camera = PinholeCamera::default();
/// let (pixel, _) = camera.project(&Vector3::new(0.0, 0.0, 2.0)).unwrap();
/// assert_eq!(pixel, camera.principal_point());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinholeCamera {
    /// Focal length along u, px.
    pub fx: f64,
    /// Focal length along v, px.
    pub fy: f64,
    /// Principal point u, px.
    pub cx: f64,
    /// Principal point v, px.
    pub cy: f64,
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
}

impl Default for PinholeCamera {
    /// A 320x240 web camera with a 283 px focal length (the wide-angle QuickCam of the paper's
    /// Pioneer experiments).
    fn default() -> Self {
        PinholeCamera {
            fx: 283.0,
            fy: 283.0,
            cx: 160.0,
            cy: 120.0,
            width: 320,
            height: 240,
        }
    }
}

/// Points closer than this in front of the camera are not projected, m.
pub const MIN_DEPTH: f64 = 1e-6;

impl PinholeCamera {
    /// Checks the intrinsics: positive focal lengths and image size, finite values.
    pub fn validate(&self) -> Result<()> {
        let finite = [self.fx, self.fy, self.cx, self.cy]
            .iter()
            .all(|v| v.is_finite());
        if !finite || self.fx <= 0.0 || self.fy <= 0.0 || self.width == 0 || self.height == 0 {
            return Err(Error::InvalidArgument(format!(
                "camera intrinsics: fx {} and fy {} must be finite and positive, cx {} and cy \
                 {} finite, width {} and height {} at least 1",
                self.fx, self.fy, self.cx, self.cy, self.width, self.height
            )));
        }
        let pixels = u64::from(self.width) * u64::from(self.height);
        if pixels > MAX_PIXELS {
            return Err(Error::InvalidArgument(format!(
                "camera intrinsics: width x height = {} x {} = {pixels} pixels is above the \
                 limit of {MAX_PIXELS} (a resource limit: a byte per pixel and image)",
                self.width, self.height
            )));
        }
        Ok(())
    }

    /// The principal point `(cx, cy)`.
    pub fn principal_point(&self) -> Vector2<f64> {
        Vector2::new(self.cx, self.cy)
    }

    /// The pixel of a camera-frame point and its Jacobian (2x3); an error behind the camera.
    pub fn project(&self, p: &Vector3<f64>) -> Result<(Vector2<f64>, Matrix2x3<f64>)> {
        if p.z <= MIN_DEPTH {
            return Err(Error::Degenerate("point behind the camera".into()));
        }
        let (iz, iz2) = (1.0 / p.z, 1.0 / (p.z * p.z));
        Ok((
            Vector2::new(self.fx * p.x * iz + self.cx, self.fy * p.y * iz + self.cy),
            Matrix2x3::new(
                self.fx * iz,
                0.0,
                -self.fx * p.x * iz2,
                0.0,
                self.fy * iz,
                -self.fy * p.y * iz2,
            ),
        ))
    }

    /// Normalized image coordinates `((u - cx) / fx, (v - cy) / fy)` of a pixel.
    pub fn normalized(&self, pixel: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy)
    }

    /// The pixel of normalized coordinates.
    pub fn pixel(&self, normalized: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            normalized.x * self.fx + self.cx,
            normalized.y * self.fy + self.cy,
        )
    }

    /// Whether a pixel lies inside the image.
    pub fn contains(&self, pixel: &Vector2<f64>) -> bool {
        pixel.x >= 0.0
            && pixel.y >= 0.0
            && pixel.x < self.width as f64
            && pixel.y < self.height as f64
    }
}

/// An 8-bit grayscale image, row-major.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GrayImage {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// `width * height` intensities, row by row.
    pub data: Vec<u8>,
}

impl GrayImage {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Self {
        GrayImage {
            width,
            height,
            data: vec![0; width as usize * height as usize],
        }
    }

    /// The intensity at `(x, y)`, or `None` outside the image.
    pub fn get(&self, x: i64, y: i64) -> Option<u8> {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            return None;
        }
        Some(self.data[y as usize * self.width as usize + x as usize])
    }

    /// Sets the intensity at `(x, y)`; ignored outside the image.
    pub fn set(&mut self, x: i64, y: i64, value: u8) {
        if x >= 0 && y >= 0 && x < self.width as i64 && y < self.height as i64 {
            self.data[y as usize * self.width as usize + x as usize] = value;
        }
    }
}
