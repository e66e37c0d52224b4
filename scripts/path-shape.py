#!/usr/bin/env python3
"""How an estimated path differs in shape from a reference path, beyond a rigid motion.

    scripts/path-shape.py REF.tum EST.tum

Both files are TUM text (t x y z qx qy qz qw); poses are paired by time (to the millisecond),
only x, y and the heading are used. Prints, on one line each:

- the RMS position error after the best rigid (SE(2)) fit, after the best similarity (Sim(2),
  with its scale) and after the best affine map (its 2 x 2 linear part: a stretch along x or
  y, or a shear, that the rigid fit cannot take out);
- the heading increments between consecutive poses: the least-squares slope of ours on the
  reference's and of the reference's on ours (a true scale of the turns makes one the
  inverse of the other; noise on one side lowers the slope fitted on that side), and the
  total absolute turn of ours over the reference's (a path that wiggles more turns more).

numpy only (e.g. the peers venv: ../shared/peers/README.md).
"""
import math
import sys

import numpy as np


def read_tum(path):
    """{time in ms: (x, y, heading)} of a TUM file."""
    poses = {}
    with open(path) as f:
        for n, line in enumerate(f, 1):
            words = line.split()
            if not words or words[0].startswith("#"):
                continue
            if len(words) < 8:
                sys.exit(f"{path}:{n}: expected 't x y z qx qy qz qw'")
            t, x, y = (float(w) for w in words[:3])
            heading = 2.0 * math.atan2(float(words[6]), float(words[7]))
            poses[round(t * 1000)] = (x, y, heading)
    return poses


def rms(residuals):
    return float(np.sqrt((np.linalg.norm(residuals, axis=1) ** 2).mean()))


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    reference, estimate = read_tum(sys.argv[1]), read_tum(sys.argv[2])
    times = sorted(set(reference) & set(estimate))
    if len(times) < 3:
        sys.exit("fewer than 3 poses paired by time")
    ref = np.array([reference[t] for t in times])
    est = np.array([estimate[t] for t in times])
    a, b = est[:, :2], ref[:, :2]
    ma, mb = a.mean(0), b.mean(0)
    u, s, vt = np.linalg.svd((a - ma).T @ (b - mb))
    d = np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T)) or 1.0])
    rotation = vt.T @ d @ u.T
    rigid = rms((a - ma) @ rotation.T + mb - b)
    scale = float((s * np.diag(d)).sum() / ((a - ma) ** 2).sum())
    similar = rms(scale * (a - ma) @ rotation.T + mb - b)
    design = np.hstack([a, np.ones((len(a), 1))])
    affine_map, *_ = np.linalg.lstsq(design, b, rcond=None)
    affine = rms(design @ affine_map - b)
    linear = affine_map[:2].T  # reference = linear @ ours + offset
    print(f"{len(times)} poses paired: RMS error rigid {rigid:.3f} m, similarity {similar:.3f} m "
          f"(scale {scale:.4f}), affine {affine:.3f} m (linear part "
          f"[[{linear[0, 0]:.4f}, {linear[0, 1]:.4f}], [{linear[1, 0]:.4f}, {linear[1, 1]:.4f}]])")
    wrap = lambda v: (v + math.pi) % (2.0 * math.pi) - math.pi  # noqa: E731
    turn_ref, turn_est = wrap(np.diff(ref[:, 2])), wrap(np.diff(est[:, 2]))
    slope = float(turn_est @ turn_ref / (turn_ref @ turn_ref))
    reverse = float(turn_est @ turn_ref / (turn_est @ turn_est))
    total = float(np.abs(turn_est).sum() / np.abs(turn_ref).sum())
    print(f"heading increments: slope ours on reference {slope:.4f}, reference on ours "
          f"{reverse:.4f}; total turn ours / reference {total:.4f}")


if __name__ == "__main__":
    main()
