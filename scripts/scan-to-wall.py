#!/usr/bin/env python3
"""What a wall map's scan-to-wall distance is made of, on a CARMEN log.

    scripts/scan-to-wall.py roughness [--window W]... [--every N] LOG[.gz]...
    scripts/scan-to-wall.py parts [--window W] [--refit N] [--png OUT.png] LOG[.gz] RUN_DIR

`roughness`: the scans' own straightness, with no pose and no map. For every run of W
consecutive valid readings of a FLASER scan (ranges above 5 cm and below 30 m) it fits the
total-least-squares line in the laser's frame; a reading's figure is its smallest distance
from the line of a run that holds it (so a reading at a wall's end, beside a corner or
clutter, is measured against the run on its wall). Prints per log and W the median, the
fraction within 3 cm, and the fraction of valid ranges that are whole multiples of 5 cm (a
coarse range resolution). W = 11 spans 10 degrees of a 180-reading sweep.

`parts`: the readings of LOG placed by RUN_DIR/trajectory.tum (one pose per FLASER line, in
order: a `slam run` or its `relocalize` folder on that log) and their distance to the
nearest confirmed wall of RUN_DIR/map.json, split by whether the reading lies on a straight
run (within 3 cm of the line of some W-run, W = 11 by default) and by distance: within 3 cm,
3-10 cm, 10-30 cm and beyond 30 cm (no wall there). `--refit N` then moves every wall N times
to the line that best fits its readings (those nearest to it within 10 cm, a Cauchy-weighted
total-least-squares line of scale 3 cm, its ends projected onto the new line; at least 10
readings) with the poses kept, and prints the figures again: how much of the distance is
the walls' placement. `--png` draws the readings: grey, blue where no wall is within 30 cm,
red where no wall is within 30 cm of a reading on a straight run.

Beams: 180 readings over 180 degrees as the project's reader spreads them (`FLASER`: n odd,
pi / (n - 1) apart; n even, pi / n), starting at -90 degrees; no laser mount. Needs numpy
(and matplotlib for `--png`).
"""
import argparse
import gzip
import json
import math

import numpy as np

MIN_RANGE, MAX_RANGE = 0.05, 30.0


def scans(path, every=1):
    """Ranges of every `every`-th FLASER line."""
    opener = gzip.open if path.endswith(".gz") else open
    count = 0
    with opener(path, "rt") as log:
        for line in log:
            words = line.split()
            if not words or words[0] != "FLASER":
                continue
            count += 1
            if (count - 1) % every:
                continue
            n = int(words[1])
            yield np.array(list(map(float, words[2 : 2 + n])))


def bearings(n):
    """The reader's beam bearings of an n-reading FLASER line."""
    step = math.pi / (n - 1) if n % 2 else math.pi / n
    return -math.pi / 2 + step * np.arange(n)


def straightness(ranges, window):
    """Each reading's smallest distance from the TLS line of a W-run that holds it (inf
    where no run of valid readings holds it)."""
    n = len(ranges)
    best = np.full(n, np.inf)
    if n < window:
        return best
    angles = bearings(n)
    points = np.c_[ranges * np.cos(angles), ranges * np.sin(angles)]
    valid = (ranges > MIN_RANGE) & (ranges < MAX_RANGE)
    index = np.arange(n - window + 1)[:, None] + np.arange(window)
    index = index[valid[index].all(axis=1)]
    if len(index) == 0:
        return best
    centred = points[index] - points[index].mean(axis=1, keepdims=True)
    sxx = (centred[..., 0] ** 2).sum(1)
    syy = (centred[..., 1] ** 2).sum(1)
    sxy = (centred[..., 0] * centred[..., 1]).sum(1)
    # the normal of the TLS line: the direction of least scatter
    angle = 0.5 * np.arctan2(2 * sxy, sxx - syy) + math.pi / 2
    normal = np.c_[np.cos(angle), np.sin(angle)]
    member = np.abs((centred * normal[:, None, :]).sum(2))
    np.minimum.at(best, index.ravel(), member.ravel())
    return best


def roughness(args):
    windows = args.window or [5, 7, 11]
    print("| log | scans | window | median distance | within 3 cm | ranges on a 5 cm grid |")
    print("|---|---:|---:|---:|---:|---:|")
    for path in args.logs:
        distances = {w: [] for w in windows}
        on_grid = valid = count = 0
        for ranges in scans(path, args.every):
            count += 1
            good = ranges[(ranges > MIN_RANGE) & (ranges < MAX_RANGE)]
            valid += len(good)
            on_grid += int(np.sum(np.abs(good * 20 - np.round(good * 20)) < 1e-6))
            for w in windows:
                d = straightness(ranges, w)
                distances[w].append(d[np.isfinite(d)])
        if count == 0 or valid == 0:
            raise SystemExit(f"{path}: no FLASER line with a valid reading")
        name = path.split("/")[-1]
        for w in windows:
            d = np.concatenate(distances[w])
            print(
                f"| {name} | {count} | {w} | {100 * np.median(d):.2f} cm | "
                f"{np.mean(d < 0.03):.2f} | {on_grid / valid:.2f} |"
            )


def confirmed_walls(run):
    """The confirmed walls of RUN/map.json as rows x0 y0 x1 y1."""
    with open(f"{run}/map.json") as f:
        features = json.load(f)["features"]
    rows = [
        f["coordinates"][0]["Point2"] + f["coordinates"][1]["Point2"]
        for f in features
        if f["type"] == "wall" and f["confirmed"]
    ]
    if not rows:
        raise SystemExit(f"{run}/map.json: no confirmed wall")
    return np.array(rows, dtype=float)


def placed_readings(log, run, window):
    """Every valid reading placed by RUN/trajectory.tum, and its straightness."""
    path = np.loadtxt(f"{run}/trajectory.tum", ndmin=2)
    placed, straight = [], []
    count = 0
    for pose, ranges in zip(path, scans(log)):
        count += 1
        x, y, qz, qw = pose[1], pose[2], pose[6], pose[7]
        heading = 2 * math.atan2(qz, qw)
        ok = (ranges > MIN_RANGE) & (ranges < MAX_RANGE)
        angles = heading + bearings(len(ranges))[ok]
        placed.append(np.c_[x + ranges[ok] * np.cos(angles), y + ranges[ok] * np.sin(angles)])
        straight.append(straightness(ranges, window)[ok])
    if count != len(path):
        raise SystemExit(f"{run}/trajectory.tum has {len(path)} poses, {log} {count}+ scans")
    return np.vstack(placed), np.concatenate(straight)


def nearest_wall(points, walls):
    """Distance of each point to its nearest wall, and that wall's index."""
    start = walls[:, :2]
    along = walls[:, 2:] - start
    length2 = np.maximum((along**2).sum(1), 1e-12)
    distance = np.empty(len(points))
    which = np.empty(len(points), dtype=int)
    for i in range(0, len(points), 1000):
        p = points[i : i + 1000, None, :]
        t = np.clip(((p - start) * along).sum(2) / length2, 0.0, 1.0)
        d = np.sqrt(((p - start - t[..., None] * along) ** 2).sum(2))
        which[i : i + 1000] = d.argmin(1)
        distance[i : i + 1000] = d.min(1)
    return distance, which


def refit(points, walls):
    """Every wall moved to the Cauchy-weighted TLS line of the points nearest to it within
    10 cm (at least 10), its ends projected onto that line."""
    distance, which = nearest_wall(points, walls)
    moved = walls.copy()
    for j in range(len(walls)):
        mine = points[(which == j) & (distance < 0.10)]
        if len(mine) < 10:
            continue
        weight = np.ones(len(mine))
        for _ in range(5):
            centre = (weight[:, None] * mine).sum(0) / weight.sum()
            offset = mine - centre
            scatter = (weight[:, None, None] * offset[:, :, None] * offset[:, None, :]).sum(0)
            normal = np.linalg.eigh(scatter)[1][:, 0]
            weight = 1.0 / (1.0 + ((offset @ normal) / 0.03) ** 2)
        direction = np.array([-normal[1], normal[0]])
        for end in (slice(0, 2), slice(2, 4)):
            moved[j, end] = centre + ((walls[j, end] - centre) @ direction) * direction
    return moved


def parts_table(label, distance, straight):
    bins = [(0, 0.03), (0.03, 0.10), (0.10, 0.30), (0.30, np.inf)]
    on = straight < 0.03
    cells = []
    for subset in (on, ~on):
        d = distance[subset]
        cells.append(" / ".join(f"{np.mean((d >= lo) & (d < hi)):.2f}" for lo, hi in bins))
    print(
        f"| {label} | {100 * np.median(distance):.1f} cm | {np.mean(distance < 0.03):.2f} | "
        f"{np.mean(on):.2f} | {cells[0]} | {cells[1]} |"
    )


def parts(args):
    walls = confirmed_walls(args.run)
    points, straight = placed_readings(args.log, args.run, args.window)
    print(
        "| walls | median to wall | within 3 cm | readings on a straight run | on a run: "
        "0-3 / 3-10 / 10-30 / 30+ cm | not on a run: 0-3 / 3-10 / 10-30 / 30+ cm |"
    )
    print("|---|---:|---:|---:|---|---|")
    mapped, _ = nearest_wall(points, walls)
    parts_table(f"{len(walls)} as mapped", mapped, straight)
    moved = walls
    for k in range(args.refit):
        moved = refit(points, moved)
        parts_table(f"refitted {k + 1}x", nearest_wall(points, moved)[0], straight)
    if args.png:
        draw(args.png, points, straight, mapped, walls)


def draw(out, points, straight, distance, walls):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    far = distance > 0.30
    on = straight < 0.03
    fig, ax = plt.subplots(figsize=(14, 10))
    for w in walls:
        ax.plot([w[0], w[2]], [w[1], w[3]], "k-", lw=0.7)
    for subset, colour, size in ((~far, "0.75", 0.3), (far & ~on, "tab:blue", 0.6), (far & on, "tab:red", 1.0)):
        ax.scatter(points[subset, 0], points[subset, 1], s=size, c=colour, linewidths=0)
    ax.set_aspect("equal")
    ax.set_title("readings with no wall within 30 cm: red on a straight run, blue not")
    fig.savefig(out, dpi=90, bbox_inches="tight")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rough = sub.add_parser("roughness")
    rough.add_argument("logs", nargs="+")
    rough.add_argument("--window", type=int, action="append")
    rough.add_argument("--every", type=int, default=1)
    split = sub.add_parser("parts")
    split.add_argument("log")
    split.add_argument("run")
    split.add_argument("--window", type=int, default=11)
    split.add_argument("--refit", type=int, default=0)
    split.add_argument("--png")
    args = parser.parse_args()
    windows = (args.window or []) if args.command == "roughness" else [args.window]
    if any(w < 3 or w % 2 == 0 for w in windows):
        parser.error("--window must be odd and at least 3")
    if getattr(args, "every", 1) < 1:
        parser.error("--every must be at least 1")
    if getattr(args, "refit", 0) < 0:
        parser.error("--refit must not be negative")
    roughness(args) if args.command == "roughness" else parts(args)


if __name__ == "__main__":
    main()
