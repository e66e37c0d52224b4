//! Rendering of the ceiling as seen by an upward camera: dark ceiling, bright light strips and
//! round lamps, with intensity noise.

use rand::Rng;
use rand_distr::{Distribution, Normal};
use slam_core::Pose3;
use slam_core::nalgebra::{Vector2, Vector3};

use super::world::CameraSpec;
use crate::camera::GrayImage;

/// Grey level of the ceiling.
const CEILING: f64 = 40.0;
/// Grey level of a light strip.
const STRIP: f64 = 220.0;
/// Grey level of a lamp.
const LAMP: f64 = 255.0;

/// What the ceiling holds: light strips `(a, b)` and lamps `(centre, radius)`, in the world.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Ceiling {
    /// Light strips.
    pub lines: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// Lamps.
    pub lamps: Vec<(Vector3<f64>, f64)>,
}

/// The image the camera at `world_from_camera` takes of the ceiling.
pub fn render_ceiling<R: Rng>(
    world_from_camera: &Pose3,
    spec: &CameraSpec,
    ceiling: &Ceiling,
    rng: &mut R,
) -> GrayImage {
    let camera = &spec.intrinsics;
    let mut values = vec![CEILING; camera.width as usize * camera.height as usize];
    let focal = 0.5 * (camera.fx + camera.fy);
    for (a, b) in &ceiling.lines {
        let (pa, pb) = (
            world_from_camera.inverse_transform_point(a),
            world_from_camera.inverse_transform_point(b),
        );
        if let (Ok((ua, _)), Ok((ub, _))) = (camera.project(&pa), camera.project(&pb)) {
            let width = focal * spec.strip_width / (0.5 * (pa.z + pb.z));
            paint(
                &mut values,
                camera.width,
                camera.height,
                |p| (segment_distance(&p, &ua, &ub) <= 0.5 * width.max(1.0)).then_some(STRIP),
                bounding_box(&[ua, ub], width),
            );
        }
    }
    for (lamp, lamp_radius) in &ceiling.lamps {
        let p: Vector3<f64> = world_from_camera.inverse_transform_point(lamp);
        if let Ok((centre, _)) = camera.project(&p) {
            let radius = focal * lamp_radius / p.z;
            paint(
                &mut values,
                camera.width,
                camera.height,
                |q| ((q - centre).norm() <= radius).then_some(LAMP),
                bounding_box(&[centre], 2.0 * radius),
            );
        }
    }
    let mut image = GrayImage::new(camera.width, camera.height);
    let noise = Normal::new(0.0, spec.intensity_noise.max(0.0)).ok();
    for (pixel, value) in image.data.iter_mut().zip(values) {
        let jitter = noise.as_ref().map_or(0.0, |n| n.sample(rng));
        *pixel = (value + jitter).round().clamp(0.0, 255.0) as u8;
    }
    image
}

fn bounding_box(points: &[Vector2<f64>], margin: f64) -> (f64, f64, f64, f64) {
    let lo_x = points.iter().map(|p| p.x).fold(f64::INFINITY, f64::min) - margin;
    let hi_x = points.iter().map(|p| p.x).fold(f64::NEG_INFINITY, f64::max) + margin;
    let lo_y = points.iter().map(|p| p.y).fold(f64::INFINITY, f64::min) - margin;
    let hi_y = points.iter().map(|p| p.y).fold(f64::NEG_INFINITY, f64::max) + margin;
    (lo_x, hi_x, lo_y, hi_y)
}

/// Sets every pixel of the box (clipped to the image) whose centre `shade` accepts.
fn paint(
    values: &mut [f64],
    width: u32,
    height: u32,
    shade: impl Fn(Vector2<f64>) -> Option<f64>,
    (lo_x, hi_x, lo_y, hi_y): (f64, f64, f64, f64),
) {
    let clamp = |v: f64, n: u32| v.floor().clamp(0.0, n as f64 - 1.0) as usize;
    if hi_x < 0.0 || hi_y < 0.0 || lo_x >= width as f64 || lo_y >= height as f64 {
        return;
    }
    for y in clamp(lo_y, height)..=clamp(hi_y, height) {
        for x in clamp(lo_x, width)..=clamp(hi_x, width) {
            if let Some(v) = shade(Vector2::new(x as f64 + 0.5, y as f64 + 0.5)) {
                values[y * width as usize + x] = v;
            }
        }
    }
}

fn segment_distance(p: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let e = b - a;
    let t = ((p - a).dot(&e) / e.norm_squared().max(1e-12)).clamp(0.0, 1.0);
    (p - (a + e * t)).norm()
}
