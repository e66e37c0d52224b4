#!/usr/bin/env python3
"""Our wall map beside the reference map of a CARMEN log, as one PNG.

    scripts/wall-map-figure.py CORRECTED_LOG[.gz] RUN_DIR OUT.png [TITLE]

CORRECTED_LOG: a log whose FLASER poses are the reference (e.g. the Radish *-corrected logs);
left panel: its scans placed by those poses (the reference map). RUN_DIR: the output folder
of `slam run` on a noisy-odometry version of that log (`map.json`, `trajectory.tum`); right
panel: our confirmed walls and estimated path over the same reference scans in light grey.
Both runs start at the first reference pose, so no alignment is applied. Needs numpy and
matplotlib.
"""
import gzip
import json
import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def reference_points(path):
    """Scan points (n x 2) placed by the FLASER poses (beams over 180 degrees)."""
    opener = gzip.open if path.endswith(".gz") else open
    chunks = []
    with opener(path, "rt") as log:
        for line in log:
            words = line.split()
            if not words or words[0] != "FLASER":
                continue
            n = int(words[1])
            ranges = np.array(list(map(float, words[2 : 2 + n])))
            x, y, theta = map(float, words[2 + n : 5 + n])
            step = math.pi / (n - 1) if n % 2 else math.pi / n
            bearings = -math.pi / 2 + step * np.arange(n)
            ok = (ranges > 0) & (ranges < 30)
            angles = theta + bearings[ok]
            chunks.append(np.c_[x + ranges[ok] * np.cos(angles), y + ranges[ok] * np.sin(angles)])
    if not chunks:
        sys.exit(f"{path}: no FLASER line")
    return np.vstack(chunks)


def walls(run_dir):
    """Confirmed wall segments of map.json, with whether their end or corner is estimated."""
    with open(f"{run_dir}/map.json") as f:
        features = json.load(f)["features"]
    out = []
    for feature in features:
        if feature["type"] != "wall" or not feature.get("confirmed"):
            continue
        body = feature["feature"]
        if body.get("start") and body.get("end"):
            out.append((body["start"], body["end"], feature["mspace_dim"] > 2 or any(body.get("shared", []))))
    return out


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    log, run_dir, out = sys.argv[1:4]
    title = sys.argv[4] if len(sys.argv) > 4 else run_dir
    points = reference_points(log)
    with open(f"{run_dir}/trajectory.tum") as f:
        path = np.array([list(map(float, l.split()[1:3])) for l in f if l.strip() and not l.startswith("#")])
    fig, (left, right) = plt.subplots(1, 2, figsize=(20, 10))
    for ax in (left, right):
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
    left.scatter(points[:, 0], points[:, 1], s=0.02, c="0.2")
    left.set_title("reference: scans placed by the corrected poses")
    right.scatter(points[:, 0], points[:, 1], s=0.02, c="0.85")
    segments = walls(run_dir)
    for start, end, anchored in segments:
        right.plot([start[0], end[0]], [start[1], end[1]], "-", color="#1f3fbf" if anchored else "#7f9fef", lw=1.6)
    right.plot(path[:, 0], path[:, 1], "r-", lw=0.4)
    right.set_title(f"{title}: {len(segments)} walls (dark: an end or corner estimated), path in red")
    right.set_xlim(left.get_xlim())
    right.set_ylim(left.get_ylim())
    fig.savefig(out, dpi=80, bbox_inches="tight")


if __name__ == "__main__":
    main()
