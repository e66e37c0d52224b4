#!/usr/bin/env python3
"""How square a building's walls come out under each of several sets of poses: a check of
heading errors that needs no reference trajectory.

    scripts/wall-directions.py CARMEN_LOG POSES.tum [POSES.tum ...]

Office buildings are built at right angles. Straight runs of each scan's readings (at least
`MIN_POINTS` readings over `MIN_LENGTH` m, fitted within `MAX_RMS` m) are found once, in the
laser's frame, from the log's FLASER lines; their direction in the world is the pose's heading
plus their direction in the scan, so the same runs are compared under every pose set and only
the headings differ. For each pose set the script folds the directions to a quarter turn,
finds the building's grid (the length-weighted mean of four times the angle), and prints the
deviation of each run from the nearest grid direction: the RMS and median over the runs that
lie within `NEAR_DEG` of the grid under every pose set (the same runs for all; runs off the
grid, such as a diagonal wall, are left out for all). A heading error that varies over the
building (a map bent or sheared) widens the spread; a single rigid turn does not. The
length-weighted mean deviation of the runs along the grid minus that of the runs across it
is a map's shear (0 in a square building). Both figures also hold the heading noise between
views of one wall, so they rank pose sets; they do not measure a bend that every view shares.

Poses are paired with scans by the TUM timestamp (the reference's time field of
`noisy_carmen.py`'s logs, or our `trajectory.tum`, which carries the same times); a scan with
no pose in some set is left out of all.
"""

import gzip
import math
import sys

MIN_POINTS = 12
MIN_LENGTH = 1.0
MAX_RMS = 0.02
SPLIT = 0.04
NEAR_DEG = 5.0
MAX_STEP = 0.3


def open_text(path):
    return gzip.open(path, "rt") if path.endswith(".gz") else open(path)


def read_scans(path):
    """FLASER lines: (time, ranges)."""
    scans = []
    with open_text(path) as f:
        for line in f:
            w = line.split()
            if not w or w[0] != "FLASER":
                continue
            n = int(w[1])
            ranges = [float(x) for x in w[2 : 2 + n]]
            time = float(w[2 + n + 6])
            scans.append((time, ranges))
    return scans


def read_tum(path):
    poses = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        w = line.split()
        yaw = 2.0 * math.atan2(float(w[6]), float(w[7]))
        poses[round(float(w[0]), 6)] = yaw
    return poses


def fit(points):
    """(direction in [0, pi), rms, length) of the least-squares line through points."""
    n = len(points)
    cx = sum(p[0] for p in points) / n
    cy = sum(p[1] for p in points) / n
    sxx = sum((p[0] - cx) ** 2 for p in points)
    syy = sum((p[1] - cy) ** 2 for p in points)
    sxy = sum((p[0] - cx) * (p[1] - cy) for p in points)
    theta = 0.5 * math.atan2(2 * sxy, sxx - syy)
    trace, det = sxx + syy, sxx * syy - sxy * sxy
    smallest = 0.5 * (trace - math.sqrt(max(trace * trace - 4 * det, 0.0)))
    rms = math.sqrt(max(smallest, 0.0) / n)
    ux, uy = math.cos(theta), math.sin(theta)
    along = [(p[0] - cx) * ux + (p[1] - cy) * uy for p in points]
    return theta % math.pi, rms, max(along) - min(along)


def split(points, out):
    """Split-and-merge's split step: the run is cut at its reading farthest from the chord."""
    if len(points) < MIN_POINTS:
        return
    (x0, y0), (x1, y1) = points[0], points[-1]
    dx, dy = x1 - x0, y1 - y0
    norm = math.hypot(dx, dy) or 1e-12
    distances = [abs((p[0] - x0) * dy - (p[1] - y0) * dx) / norm for p in points]
    k = max(range(len(points)), key=distances.__getitem__)
    if distances[k] > SPLIT and 0 < k < len(points) - 1:
        split(points[: k + 1], out)
        split(points[k:], out)
        return
    direction, rms, length = fit(points)
    if rms <= MAX_RMS and length >= MIN_LENGTH:
        out.append((direction, length))


def runs_of(ranges):
    """Straight runs of one scan (180 degrees across its beams), in the laser's frame."""
    n = len(ranges)
    step = math.pi / n if n != 181 and n != 361 else math.pi / (n - 1)
    points = []
    for i, r in enumerate(ranges):
        if 0.05 < r < 40.0:
            a = -math.pi / 2 + i * step
            points.append((r * math.cos(a), r * math.sin(a)))
        else:
            points.append(None)
    runs, current = [], []
    for p in points + [None]:
        if p is not None and current and math.dist(p, current[-1]) > MAX_STEP:
            split(current, runs)
            current = []
        if p is None:
            split(current, runs)
            current = []
        else:
            current.append(p)
    return runs


def fold(angle):
    """The angle folded into [-45, 45) degrees around 0 (a quarter turn)."""
    quarter = math.pi / 2
    return (angle + quarter / 2) % quarter - quarter / 2


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    scans = read_scans(sys.argv[1])
    pose_sets = [read_tum(p) for p in sys.argv[2:]]
    segments = []  # (time, local direction, length)
    for time, ranges in scans:
        key = round(time, 6)
        if all(key in poses for poses in pose_sets):
            segments += [(key, d, length) for d, length in runs_of(ranges)]
    deviations, families = [], []
    for poses in pose_sets:
        world = [(poses[t] + d, length) for t, d, length in segments]
        z = sum(length * complex(math.cos(4 * a), math.sin(4 * a)) for a, length in world)
        grid = math.atan2(z.imag, z.real) / 4
        deviations.append([math.degrees(fold(a - grid)) for a, _ in world])
        # Along the grid (0) or across it (1).
        families.append([round((a - grid) / (math.pi / 2)) % 2 for a, _ in world])
    kept = [i for i in range(len(segments)) if all(abs(d[i]) < NEAR_DEG for d in deviations)]
    print(f"{len(segments)} straight runs of at least {MIN_POINTS} readings and {MIN_LENGTH} m; "
          f"{len(kept)} within {NEAR_DEG} degrees of the grid under every pose set")
    for path, d in zip(sys.argv[2:], deviations):
        values = sorted(abs(d[i]) for i in kept)
        weights = [segments[i][2] for i in kept]
        rms = math.sqrt(sum(w * d[i] ** 2 for w, i in zip(weights, kept)) / sum(weights))
        median = values[len(values) // 2]
        means = []
        for family in (0, 1):
            members = [i for i in kept if families[0][i] == family]
            total = sum(segments[i][2] for i in members)
            means.append(sum(segments[i][2] * d[i] for i in members) / total if total else 0.0)
        print(f"{path}: deviation from the grid, length-weighted RMS {rms:.3f} deg, "
              f"median {median:.3f} deg; the walls along the grid turned {means[0] - means[1]:+.3f} "
              f"deg from those across it (0 for a square building)")


if __name__ == "__main__":
    main()
