#!/usr/bin/env python3
"""How a path's heading error against a reference follows the reference's net turn.

    scripts/heading-vs-turn.py ESTIMATE.tum REFERENCE.tum

Poses are paired by timestamp (to the microsecond). The heading error (estimate minus
reference, wrapped) is fitted by least squares as `a * net_turn + b`, where `net_turn` is the
reference's heading unwrapped from its first paired pose: a path that turns `a` too much per
radian turned has `a` there. Prints `a` (percent), `b` (degrees), and the RMS heading error
before and after the fit. Both paths must start in the same frame (as `slam run` writes them
for a CARMEN log: the first pose is the reference's).
"""
import math
import sys


def load(path):
    poses = {}
    with open(path) as f:
        for number, line in enumerate(f, 1):
            if line.startswith('#') or not line.strip():
                continue
            fields = line.split()
            if len(fields) != 8:
                sys.exit(f"{path}:{number}: expected 8 fields (TUM), found {len(fields)}")
            t, x, y, _, _, _, qz, qw = map(float, fields)
            poses[round(t, 6)] = (x, y, 2 * math.atan2(qz, qw))
    return poses


def wrap(angle):
    return (angle + math.pi) % (2 * math.pi) - math.pi


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    estimate, reference = load(sys.argv[1]), load(sys.argv[2])
    times = sorted(set(estimate) & set(reference))
    if len(times) < 3:
        sys.exit(f"only {len(times)} poses pair up by timestamp")
    turn, previous, rows = 0.0, None, []
    for t in times:
        heading = reference[t][2]
        if previous is not None:
            turn += wrap(heading - previous)
        previous = heading
        rows.append((turn, wrap(estimate[t][2] - heading)))
    n = len(rows)
    sx = sum(x for x, _ in rows)
    sy = sum(y for _, y in rows)
    sxx = sum(x * x for x, _ in rows)
    sxy = sum(x * y for x, y in rows)
    denominator = n * sxx - sx * sx
    if denominator <= 0:
        sys.exit("the reference does not turn")
    a = (n * sxy - sx * sy) / denominator
    b = (sy - a * sx) / n
    rms = math.sqrt(sum(y * y for _, y in rows) / n)
    residual = math.sqrt(sum((y - a * x - b) ** 2 for x, y in rows) / n)
    low, high = min(x for x, _ in rows), max(x for x, _ in rows)
    print(f"{n} poses; heading error = {100 * a:.3f} % of the net turn "
          f"{math.degrees(b):+.2f} degrees; RMS {math.degrees(rms):.2f} -> "
          f"{math.degrees(residual):.2f} degrees after the fit; net turn "
          f"{math.degrees(low):.0f} to {math.degrees(high):.0f} degrees")


if __name__ == '__main__':
    main()
