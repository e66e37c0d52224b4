//! The occupancy grid of `slam run --grid` (`[output] grid = true`): every laser scan cast
//! into a log-odds grid from the pose estimated at the end of its time step
//! ([`GridObserver`] during a run), and its images in the format of ROS `map_server` /
//! `map_saver` ([`OccupancyGrid::pgm`], [`OccupancyGrid::yaml`]; the command writes them as
//! `map.pgm` + `map.yaml`).
//!
//! The pose is the estimate of `trajectory.tum` (for a particle filter, the weighted mean).
//! Each beam lowers the log-odds of the cells it crosses (free) and raises the log-odds of the
//! cell of its return (occupied); a reading at or beyond the laser's maximum range marks the
//! cells up to the maximum range free and nothing occupied; a reading at or below the minimum
//! range, or not finite, is left out. Beams are cut at `grid_max_range` (default 30 m): a
//! longer one marks the cells up to there free and nothing occupied. The grid grows with the area the beams reach, never with
//! the number of scans: the observer keeps only the scans of the open time step.

use std::fmt::Write as _;

use slam_core::nalgebra::{Vector2, Vector3};
use slam_core::{Estimator, Pose2, Pose3, UpdateReport};
use slam_sensors::{Event, LaserScan, TimedEvent};

use crate::error::{Result, RuntimeError};
use crate::session::Observer;

/// Log-odds added to the cell of a return: `ln(0.7 / 0.3)`.
pub const LOG_ODDS_HIT: f32 = 0.847_297_9;
/// Log-odds added to a cell a beam crosses: `ln(0.4 / 0.6)`.
pub const LOG_ODDS_MISS: f32 = -0.405_465_1;
/// The log-odds of a cell stay within `±LOG_ODDS_LIMIT` (so that a moved object can be
/// un-mapped by later scans).
pub const LOG_ODDS_LIMIT: f32 = 3.5;
/// `occupied_thresh` of `map.yaml` (map_saver's default).
pub const OCCUPIED_THRESH: f64 = 0.65;
/// `free_thresh` of `map.yaml` (map_saver's default).
pub const FREE_THRESH: f64 = 0.196;
/// Most cells a grid may hold (400 MB of log-odds).
const MAX_CELLS: usize = 100_000_000;

/// A log-odds occupancy grid over the world frame, growing as beams reach new area.
#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    /// Cell side, m.
    resolution: f64,
    /// World cell index (`floor(x / resolution)`) of column 0.
    min_ix: i64,
    /// World cell index of row 0 (the lowest y).
    min_iy: i64,
    width: usize,
    height: usize,
    /// Row-major from the lowest y, log-odds of occupancy (0: unknown).
    log_odds: Vec<f32>,
    /// Scans cast.
    scans: usize,
    /// Longest beam cast, m.
    max_range: f64,
}

/// What a cell is, by map_server's trinary reading of its probability.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CellState {
    /// Probability of occupancy above [`OCCUPIED_THRESH`].
    Occupied,
    /// Probability of occupancy below [`FREE_THRESH`].
    Free,
    /// Between, or never seen.
    Unknown,
}

impl OccupancyGrid {
    /// An empty grid of cells `resolution` m wide, casting beams `max_range` m long at most
    /// (both checked by the config: positive).
    pub fn new(resolution: f64, max_range: f64) -> Self {
        OccupancyGrid {
            resolution,
            max_range,
            min_ix: 0,
            min_iy: 0,
            width: 0,
            height: 0,
            log_odds: Vec::new(),
            scans: 0,
        }
    }

    /// Scans cast into the grid.
    pub fn scans(&self) -> usize {
        self.scans
    }

    /// Width and height in cells.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The world cell index of a point.
    fn cell_of(&self, p: &Vector2<f64>) -> (i64, i64) {
        (
            slam_core::grid::floor_i64(p.x / self.resolution),
            slam_core::grid::floor_i64(p.y / self.resolution),
        )
    }

    /// The log-odds of the cell holding world point `p` (0 outside the grid).
    pub fn log_odds_at(&self, p: &Vector2<f64>) -> f32 {
        let (ix, iy) = self.cell_of(p);
        self.index(ix, iy).map_or(0.0, |k| self.log_odds[k])
    }

    /// The state of the cell holding world point `p`.
    pub fn state_at(&self, p: &Vector2<f64>) -> CellState {
        state_of(self.log_odds_at(p))
    }

    fn index(&self, ix: i64, iy: i64) -> Option<usize> {
        let col = usize::try_from(ix - self.min_ix).ok()?;
        let row = usize::try_from(iy - self.min_iy).ok()?;
        (col < self.width && row < self.height).then(|| row * self.width + col)
    }

    /// Grows the grid to hold the cells `lo ..= hi`, with a margin so that growth is rare.
    fn ensure(&mut self, lo: (i64, i64), hi: (i64, i64)) -> Result<()> {
        let inside = self.width > 0
            && lo.0 >= self.min_ix
            && lo.1 >= self.min_iy
            && hi.0 < self.min_ix + self.width as i64
            && hi.1 < self.min_iy + self.height as i64;
        if inside {
            return Ok(());
        }
        let margin = 64 + (self.width.max(self.height) / 2) as i64;
        let (mut x0, mut y0, mut x1, mut y1) =
            (lo.0 - margin, lo.1 - margin, hi.0 + margin, hi.1 + margin);
        if self.width > 0 {
            x0 = x0.min(self.min_ix);
            y0 = y0.min(self.min_iy);
            x1 = x1.max(self.min_ix + self.width as i64 - 1);
            y1 = y1.max(self.min_iy + self.height as i64 - 1);
        }
        let width = usize::try_from(x1 - x0 + 1).unwrap_or(usize::MAX);
        let height = usize::try_from(y1 - y0 + 1).unwrap_or(usize::MAX);
        if width.saturating_mul(height) > MAX_CELLS {
            return Err(RuntimeError::setting(
                "output",
                format!(
                    "the occupancy grid would need {width} x {height} cells of {} m (more than \
                     {MAX_CELLS}): raise grid_resolution",
                    self.resolution
                ),
            ));
        }
        let mut log_odds = vec![0.0f32; width * height];
        for row in 0..self.height {
            let new_row = (self.min_iy + row as i64 - y0) as usize;
            let new_col = (self.min_ix - x0) as usize;
            let start = new_row * width + new_col;
            log_odds[start..start + self.width]
                .copy_from_slice(&self.log_odds[row * self.width..(row + 1) * self.width]);
        }
        self.log_odds = log_odds;
        self.min_ix = x0;
        self.min_iy = y0;
        self.width = width;
        self.height = height;
        Ok(())
    }

    fn add(&mut self, ix: i64, iy: i64, delta: f32) {
        if let Some(k) = self.index(ix, iy) {
            let value = &mut self.log_odds[k];
            *value = (*value + delta).clamp(-LOG_ODDS_LIMIT, LOG_ODDS_LIMIT);
        }
    }

    /// Casts one scan taken by a laser at `robot_from_sensor` on a robot at
    /// `world_from_robot`.
    pub fn insert_scan(
        &mut self,
        world_from_robot: &Pose2,
        robot_from_sensor: &Pose3,
        scan: &LaserScan,
    ) -> Result<()> {
        let rotation = robot_from_sensor.rotation();
        let in_world = |p: Vector2<f64>| {
            let in_robot = robot_from_sensor.translation + rotation * Vector3::new(p.x, p.y, 0.0);
            world_from_robot.transform_point(&in_robot.xy())
        };
        let origin = world_from_robot.transform_point(&robot_from_sensor.translation.xy());
        // Each usable beam's end in the world and whether it is a return.
        let mut beams = Vec::with_capacity(scan.ranges.len());
        for (index, &range) in scan.ranges.iter().enumerate() {
            if !range.is_finite() || range <= scan.min_range {
                continue;
            }
            let hit = range < scan.max_range && range <= self.max_range;
            let length = if hit {
                range
            } else {
                scan.max_range.min(self.max_range)
            };
            if !length.is_finite() {
                continue;
            }
            let bearing = scan.bearing(index);
            let end = in_world(Vector2::new(length * bearing.cos(), length * bearing.sin()));
            if end.x.is_finite() && end.y.is_finite() {
                beams.push((end, hit));
            }
        }
        if !origin.x.is_finite() || !origin.y.is_finite() || beams.is_empty() {
            return Ok(());
        }
        let start = self.cell_of(&origin);
        let (mut lo, mut hi) = (start, start);
        let cells: Vec<((i64, i64), bool)> = beams
            .iter()
            .map(|(end, hit)| (self.cell_of(end), *hit))
            .collect();
        for ((ix, iy), _) in &cells {
            lo = (lo.0.min(*ix), lo.1.min(*iy));
            hi = (hi.0.max(*ix), hi.1.max(*iy));
        }
        self.ensure(lo, hi)?;
        for (end, hit) in cells {
            self.cast(start, end, hit);
        }
        self.scans += 1;
        Ok(())
    }

    /// One beam from cell `start` to cell `end` (Bresenham): the cells before `end` free,
    /// `end` occupied when the beam returned there, else free.
    fn cast(&mut self, start: (i64, i64), end: (i64, i64), hit: bool) {
        let (mut x, mut y) = start;
        let dx = (end.0 - x).abs();
        let dy = -(end.1 - y).abs();
        let sx = if x < end.0 { 1 } else { -1 };
        let sy = if y < end.1 { 1 } else { -1 };
        let mut error = dx + dy;
        while (x, y) != end {
            self.add(x, y, LOG_ODDS_MISS);
            let twice = 2 * error;
            if twice >= dy {
                error += dy;
                x += sx;
            }
            if twice <= dx {
                error += dx;
                y += sy;
            }
        }
        self.add(end.0, end.1, if hit { LOG_ODDS_HIT } else { LOG_ODDS_MISS });
    }

    /// The columns and rows holding every cell a beam reached (`col0 .. col1`,
    /// `row0 .. row1`, end exclusive): the part of the grid the files hold.
    fn seen(&self) -> (usize, usize, usize, usize) {
        let (mut col0, mut row0, mut col1, mut row1) = (self.width, self.height, 0, 0);
        for row in 0..self.height {
            for col in 0..self.width {
                if self.log_odds[row * self.width + col] != 0.0 {
                    col0 = col0.min(col);
                    row0 = row0.min(row);
                    col1 = col1.max(col + 1);
                    row1 = row1.max(row + 1);
                }
            }
        }
        if col0 >= col1 {
            (0, 0, self.width, self.height)
        } else {
            (col0, row0, col1, row1)
        }
    }

    /// `map.pgm`: binary PGM (P5) of the cells the beams reached, the top row at the largest
    /// y, occupied cells 0, free cells 254, unknown ones 205 (as map_saver writes them).
    pub fn pgm(&self) -> Vec<u8> {
        let (col0, row0, col1, row1) = self.seen();
        let mut bytes = format!(
            "P5\n# CREATOR: mspace-slam {:.3} m/pix\n{} {}\n255\n",
            self.resolution,
            col1 - col0,
            row1 - row0
        )
        .into_bytes();
        bytes.reserve((col1 - col0) * (row1 - row0));
        for row in (row0..row1).rev() {
            for value in &self.log_odds[row * self.width + col0..row * self.width + col1] {
                bytes.push(match state_of(*value) {
                    CellState::Occupied => 0,
                    CellState::Free => 254,
                    CellState::Unknown => 205,
                });
            }
        }
        bytes
    }

    /// `map.yaml` for the image `image` (map_server's keys; origin: the world pose of the
    /// lower-left pixel of [`Self::pgm`], yaw 0).
    pub fn yaml(&self, image: &str) -> String {
        let (col0, row0, _, _) = self.seen();
        let x = (self.min_ix + col0 as i64) as f64 * self.resolution;
        let y = (self.min_iy + row0 as i64) as f64 * self.resolution;
        let mut text = String::new();
        // Writing to a String cannot fail.
        let _ = writeln!(text, "image: {image}");
        let _ = writeln!(text, "mode: trinary");
        let _ = writeln!(text, "resolution: {}", self.resolution);
        let _ = writeln!(text, "origin: [{x}, {y}, 0.0]");
        let _ = writeln!(text, "negate: 0");
        let _ = writeln!(text, "occupied_thresh: {OCCUPIED_THRESH}");
        let _ = writeln!(text, "free_thresh: {FREE_THRESH}");
        text
    }
}

/// The trinary state of a cell of log-odds `value`.
fn state_of(value: f32) -> CellState {
    let p = 1.0 - 1.0 / (1.0 + f64::from(value).exp());
    if value == 0.0 {
        CellState::Unknown
    } else if p > OCCUPIED_THRESH {
        CellState::Occupied
    } else if p < FREE_THRESH {
        CellState::Free
    } else {
        CellState::Unknown
    }
}

/// The [`Observer`] that builds the grid during a run: it keeps the scans of the open time
/// step and casts them from the pose estimated at the step's end.
#[derive(Debug)]
pub struct GridObserver {
    /// The grid so far.
    pub grid: OccupancyGrid,
    pending: Vec<(LaserScan, Pose3)>,
}

impl GridObserver {
    /// An observer building a grid of cells `resolution` m wide from beams `max_range` m
    /// long at most.
    pub fn new(resolution: f64, max_range: f64) -> Self {
        GridObserver {
            grid: OccupancyGrid::new(resolution, max_range),
            pending: Vec::new(),
        }
    }
}

impl Observer for GridObserver {
    fn event(
        &mut self,
        event: &TimedEvent,
        _: Option<&UpdateReport>,
        _: &dyn Estimator<Pose2>,
    ) -> Result<()> {
        if let Event::Scan {
            scan,
            robot_from_sensor,
        } = &event.event
        {
            self.pending.push((scan.clone(), *robot_from_sensor));
        }
        Ok(())
    }

    fn step_end(&mut self, _: f64, estimator: &dyn Estimator<Pose2>) -> Result<()> {
        let pose = estimator.pose();
        for (scan, robot_from_sensor) in self.pending.drain(..) {
            if pose.is_finite() {
                self.grid.insert_scan(&pose, &robot_from_sensor, &scan)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(ranges: Vec<f64>) -> LaserScan {
        let n = ranges.len();
        let half = if n > 1 { 0.5 } else { 0.0 };
        LaserScan::new(-half, half, ranges, 0.1, 10.0).unwrap()
    }

    #[test]
    fn one_ray_frees_the_cells_it_crosses_and_occupies_its_return() {
        let mut grid = OccupancyGrid::new(0.1, 30.0);
        // One beam straight ahead along +x, returning at 2.05 m.
        grid.insert_scan(
            &Pose2::new(0.05, 0.05, 0.0),
            &Pose3::identity(),
            &scan(vec![2.0]),
        )
        .unwrap();
        let at = |grid: &OccupancyGrid, x: f64| grid.log_odds_at(&Vector2::new(x, 0.05));
        assert_eq!(at(&grid, 2.05), LOG_ODDS_HIT);
        for x in [0.05, 0.55, 1.05, 1.95] {
            assert_eq!(at(&grid, x), LOG_ODDS_MISS, "x = {x}");
        }
        assert_eq!(at(&grid, 2.25), 0.0);
        assert_eq!(grid.log_odds_at(&Vector2::new(1.0, 0.5)), 0.0);
        assert_eq!(
            grid.state_at(&Vector2::new(2.05, 0.05)),
            CellState::Occupied
        );
        // One free pass is not yet "free" at map_saver's threshold; four are.
        assert_eq!(grid.state_at(&Vector2::new(1.05, 0.05)), CellState::Unknown);
        for _ in 0..3 {
            grid.insert_scan(
                &Pose2::new(0.05, 0.05, 0.0),
                &Pose3::identity(),
                &scan(vec![2.0]),
            )
            .unwrap();
        }
        assert_eq!(grid.state_at(&Vector2::new(1.05, 0.05)), CellState::Free);
        // Four hits: 4 x 0.85 = 3.39, below the clamp; a fifth is clamped.
        assert_eq!(at(&grid, 2.05), 4.0 * LOG_ODDS_HIT);
        grid.insert_scan(
            &Pose2::new(0.05, 0.05, 0.0),
            &Pose3::identity(),
            &scan(vec![2.0]),
        )
        .unwrap();
        assert_eq!(at(&grid, 2.05), LOG_ODDS_LIMIT);
    }

    #[test]
    fn max_range_readings_free_only_and_short_ones_are_left_out() {
        let mut grid = OccupancyGrid::new(0.1, 30.0);
        let pose = Pose2::new(0.05, 0.05, std::f64::consts::FRAC_PI_2);
        grid.insert_scan(&pose, &Pose3::identity(), &scan(vec![10.0]))
            .unwrap();
        // The beam points along +y; no cell is occupied, the last one is free.
        assert_eq!(grid.log_odds_at(&Vector2::new(0.05, 9.95)), LOG_ODDS_MISS);
        assert!(grid.log_odds.iter().all(|v| *v <= 0.0));
        let mut empty = OccupancyGrid::new(0.1, 30.0);
        empty
            .insert_scan(&pose, &Pose3::identity(), &scan(vec![0.05, f64::NAN]))
            .unwrap();
        assert_eq!(empty.scans(), 0);
        assert_eq!(empty.size(), (0, 0));
    }

    #[test]
    fn beams_are_cut_at_grid_max_range() {
        let mut grid = OccupancyGrid::new(0.1, 1.0);
        grid.insert_scan(
            &Pose2::new(0.05, 0.05, 0.0),
            &Pose3::identity(),
            &scan(vec![2.0]),
        )
        .unwrap();
        // Free up to 1 m, nothing beyond, no return.
        assert_eq!(grid.log_odds_at(&Vector2::new(0.95, 0.05)), LOG_ODDS_MISS);
        assert_eq!(grid.log_odds_at(&Vector2::new(1.05, 0.05)), LOG_ODDS_MISS);
        assert_eq!(grid.log_odds_at(&Vector2::new(1.15, 0.05)), 0.0);
        assert_eq!(grid.log_odds_at(&Vector2::new(2.05, 0.05)), 0.0);
    }

    #[test]
    fn the_laser_mounting_and_the_robot_pose_place_the_beam() {
        let mut grid = OccupancyGrid::new(0.05, 30.0);
        // A laser 0.5 m ahead of the robot, the robot at (1, 2) facing +y: a return at 1 m
        // lands at (1, 3.5).
        let mount = Pose3::new(Vector3::new(0.5, 0.0, 0.3), 0.0, 0.0, 0.0);
        grid.insert_scan(
            &Pose2::new(1.0, 2.0, std::f64::consts::FRAC_PI_2),
            &mount,
            &scan(vec![1.0]),
        )
        .unwrap();
        assert_eq!(
            grid.state_at(&Vector2::new(1.01, 3.51)),
            CellState::Occupied
        );
    }

    #[test]
    fn the_pgm_and_yaml_follow_map_saver() {
        let mut grid = OccupancyGrid::new(0.1, 30.0);
        // One beam along +x from cell (0, 0), returning in cell (20, 0).
        grid.insert_scan(
            &Pose2::new(0.05, 0.05, 0.0),
            &Pose3::identity(),
            &scan(vec![2.0]),
        )
        .unwrap();
        let pgm = grid.pgm();
        // Only the reached cells are written: one row of 21.
        let header = "P5\n# CREATOR: mspace-slam 0.100 m/pix\n21 1\n255\n";
        assert!(pgm.starts_with(header.as_bytes()));
        let body = &pgm[header.len()..];
        assert_eq!(body.len(), 21);
        // The crossed cells seen once are unknown at map_saver's thresholds; the return is
        // occupied (black).
        assert!(body[..20].iter().all(|v| *v == 205));
        assert_eq!(body[20], 0);
        let yaml = grid.yaml("map.pgm");
        assert!(yaml.contains("image: map.pgm\n"));
        assert!(yaml.contains("resolution: 0.1\n"));
        assert!(yaml.contains("origin: [0, 0, 0.0]\n"), "{yaml}");
        assert!(yaml.contains("negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"));
        // A beam straight up adds a column: the image grows, its origin stays.
        grid.insert_scan(
            &Pose2::new(0.05, 0.05, std::f64::consts::FRAC_PI_2),
            &Pose3::identity(),
            &scan(vec![1.0]),
        )
        .unwrap();
        let pgm = grid.pgm();
        assert!(pgm.starts_with(b"P5\n# CREATOR: mspace-slam 0.100 m/pix\n21 11\n255\n"));
        let body = &pgm[pgm.len() - 21 * 11..];
        // The top row (y = 1.0 .. 1.1) holds the second return at column 0.
        assert_eq!(body[0], 0);
        assert_eq!(body[1], 205);
        // The bottom row holds the first return at column 20.
        assert_eq!(body[10 * 21 + 20], 0);
        assert!(grid.yaml("map.pgm").contains("origin: [0, 0, 0.0]\n"));
    }

    #[test]
    fn a_grid_too_large_is_an_error_naming_the_key() {
        let mut grid = OccupancyGrid::new(1e-4, 30.0);
        let diagonal = std::f64::consts::FRAC_PI_4;
        let far = LaserScan::new(diagonal, diagonal, vec![5.0], 0.1, 10.0).unwrap();
        let error = grid
            .insert_scan(&Pose2::identity(), &Pose3::identity(), &far)
            .unwrap_err()
            .to_string();
        assert!(error.contains("grid_resolution"), "{error}");
    }
}
