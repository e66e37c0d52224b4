//! Small synthetic scenes (segments and circles) ray-cast into laser scans with the true
//! surface normal of every reading, for tests, benchmarks and demonstrations.

use rand::{Rng, RngExt};
use rand_distr::{Distribution, Normal};
use slam_sensors::LaserScan;

use crate::error::{PriorError, Result};

/// A surface of a scene, in world coordinates (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// A wall from `a` to `b`.
    Segment {
        /// One end.
        a: [f64; 2],
        /// The other end.
        b: [f64; 2],
    },
    /// A circle (a round room seen from inside, or a pillar seen from outside).
    Circle {
        /// Centre.
        centre: [f64; 2],
        /// Radius.
        radius: f64,
    },
}

/// A set of surfaces.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Scene {
    /// The surfaces.
    pub shapes: Vec<Shape>,
}

/// The true return of one beam.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// True range, m.
    pub range: f64,
    /// True surface normal in the sensor frame (facing the sensor), rad.
    pub normal: f64,
    /// Index of the surface hit.
    pub shape: usize,
}

/// A simulated scan and its truth.
#[derive(Clone, Debug)]
pub struct SimulatedScan {
    /// The scan (noisy ranges; outliers and beams with no return included).
    pub scan: LaserScan,
    /// True return of each beam (`None`: no return).
    pub truth: Vec<Option<Hit>>,
    /// Beams whose range was replaced by a random shorter one (clutter).
    pub outlier_beams: Vec<usize>,
}

/// How to simulate a scan.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanSpec {
    /// Sensor pose in the world `(x, y, heading)`.
    pub world_from_sensor: [f64; 3],
    /// Bearing of the first beam, rad.
    pub angle_min: f64,
    /// Angle between beams, rad.
    pub angle_increment: f64,
    /// Number of beams.
    pub beams: usize,
    /// Range noise standard deviation, m.
    pub sigma: f64,
    /// Number of beams replaced by clutter (a uniform range between 0.3 m and 0.3 m short of
    /// the true range).
    pub outliers: usize,
    /// Largest range, m.
    pub max_range: f64,
}

impl Scene {
    /// The rectangle `[0, width] x [0, height]` as four walls.
    pub fn rectangle(width: f64, height: f64) -> Scene {
        let c = [[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]];
        Scene {
            shapes: (0..4)
                .map(|k| Shape::Segment {
                    a: c[k],
                    b: c[(k + 1) % 4],
                })
                .collect(),
        }
    }

    /// The nearest return along a ray from `origin` in world direction `angle`.
    pub fn cast(&self, origin: [f64; 2], angle: f64) -> Option<(f64, [f64; 2], usize)> {
        let d = [angle.cos(), angle.sin()];
        let mut best: Option<(f64, [f64; 2], usize)> = None;
        for (k, shape) in self.shapes.iter().enumerate() {
            let hit = match *shape {
                Shape::Segment { a, b } => {
                    let e = [b[0] - a[0], b[1] - a[1]];
                    let denom = d[0] * (-e[1]) + d[1] * e[0];
                    if denom.abs() < 1e-12 {
                        None
                    } else {
                        let w = [a[0] - origin[0], a[1] - origin[1]];
                        let t = (w[0] * (-e[1]) + w[1] * e[0]) / denom;
                        let s = (d[0] * w[1] - d[1] * w[0]) / denom;
                        let len = (e[0] * e[0] + e[1] * e[1]).sqrt();
                        (t > 1e-9 && (0.0..=1.0).contains(&s))
                            .then(|| (t, [-e[1] / len, e[0] / len]))
                    }
                }
                Shape::Circle { centre, radius } => {
                    let w = [origin[0] - centre[0], origin[1] - centre[1]];
                    let b = w[0] * d[0] + w[1] * d[1];
                    let c = w[0] * w[0] + w[1] * w[1] - radius * radius;
                    let disc = b * b - c;
                    if disc < 0.0 {
                        None
                    } else {
                        let root = disc.sqrt();
                        let t = if -b - root > 1e-9 {
                            -b - root
                        } else {
                            -b + root
                        };
                        (t > 1e-9).then(|| {
                            let p = [origin[0] + t * d[0], origin[1] + t * d[1]];
                            (
                                t,
                                [(p[0] - centre[0]) / radius, (p[1] - centre[1]) / radius],
                            )
                        })
                    }
                }
            };
            if let Some((t, mut n)) = hit
                && best.is_none_or(|(bt, _, _)| t < bt)
            {
                if n[0] * d[0] + n[1] * d[1] > 0.0 {
                    n = [-n[0], -n[1]];
                }
                best = Some((t, n, k));
            }
        }
        best
    }

    /// Simulates one scan with a seeded generator (ChaCha8), reproducibly.
    pub fn simulate_seeded(&self, spec: &ScanSpec, seed: u64) -> Result<SimulatedScan> {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        self.simulate(spec, &mut rng)
    }

    /// Simulates one scan with Gaussian range noise and clutter outliers.
    pub fn simulate<R: Rng>(&self, spec: &ScanSpec, rng: &mut R) -> Result<SimulatedScan> {
        let noise = Normal::new(0.0, spec.sigma)
            .map_err(|e| PriorError::InvalidInput(format!("noise deviation: {e}")))?;
        let [x, y, heading] = spec.world_from_sensor;
        let mut ranges = Vec::with_capacity(spec.beams);
        let mut truth = Vec::with_capacity(spec.beams);
        for k in 0..spec.beams {
            let bearing = spec.angle_min + spec.angle_increment * k as f64;
            match self.cast([x, y], heading + bearing) {
                Some((t, n, shape)) if t < spec.max_range => {
                    ranges.push(t + noise.sample(rng));
                    let normal = n[1].atan2(n[0]) - heading;
                    truth.push(Some(Hit {
                        range: t,
                        normal: normal.sin().atan2(normal.cos()),
                        shape,
                    }));
                }
                _ => {
                    ranges.push(spec.max_range);
                    truth.push(None);
                }
            }
        }
        let candidates: Vec<usize> = (0..spec.beams)
            .filter(|&k| truth[k].is_some_and(|h| h.range > 1.0))
            .collect();
        let mut outlier_beams = Vec::new();
        while outlier_beams.len() < spec.outliers.min(candidates.len()) {
            let k = candidates[rng.random_range(0..candidates.len())];
            if outlier_beams.contains(&k) {
                continue;
            }
            let true_range = truth[k].map_or(1.0, |h| h.range);
            ranges[k] = rng.random_range(0.3..true_range - 0.3);
            outlier_beams.push(k);
        }
        outlier_beams.sort_unstable();
        let scan = LaserScan::with_increment(
            spec.angle_min,
            spec.angle_increment,
            ranges,
            0.0,
            spec.max_range,
        )
        .map_err(|e| PriorError::InvalidInput(e.to_string()))?;
        Ok(SimulatedScan {
            scan,
            truth,
            outlier_beams,
        })
    }
}
