//! Extraction front-ends: laser scans to wall segments ([`extract_segments`], or
//! [`segments_from_readings`] for a segmentation made elsewhere) and poles
//! ([`extract_poles`]); ceiling images to lines and lamps ([`image`]; lines also by a Hough
//! transform: [`hough`]).

pub mod hough;
pub mod image;
mod lines;
mod poles;

pub use lines::{ExtractedSegment, LineExtractorParams, extract_segments, segments_from_readings};
pub use poles::{ExtractedPole, PoleExtractorParams, extract_poles};

use crate::scan::{LaserScan, ScanPoint};

/// Index ranges (inclusive, into `points`) of runs of points from consecutive beams whose
/// neighbours are closer than `max_gap + gap_per_metre * range`.
pub(crate) fn clusters(
    points: &[ScanPoint],
    scan: &LaserScan,
    max_gap: f64,
    gap_per_metre: f64,
) -> Vec<(usize, usize)> {
    let _ = scan;
    let mut out = Vec::new();
    let mut start = 0;
    for k in 1..=points.len() {
        let breaks = k == points.len() || {
            let (a, b) = (&points[k - 1], &points[k]);
            let gap = (b.position - a.position).norm();
            b.index != a.index + 1 || gap > max_gap + gap_per_metre * a.range.max(b.range)
        };
        if breaks {
            if k > start {
                out.push((start, k - 1));
            }
            start = k;
        }
    }
    out
}

/// What a beam next to a cluster saw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Neighbour {
    /// A valid return at this range.
    Range(f64),
    /// No return within the maximum range (finite reading at or beyond it).
    NoReturn,
    /// An invalid reading (NaN, infinite, zero, negative, below the minimum range).
    Unknown,
}

pub(crate) fn far_or_unknown(scan: &LaserScan, beam: usize) -> Neighbour {
    match scan.ranges.get(beam) {
        Some(&r) if scan.is_valid(r) => Neighbour::Range(r),
        Some(&r) if r.is_finite() && r >= scan.max_range => Neighbour::NoReturn,
        _ => Neighbour::Unknown,
    }
}
