#!/usr/bin/env python3
"""Where a CARMEN log's laser rays cross a wall line, and whether that wall returns there.

For a horizontal wall line y = Y between x = X0 and X1 (map frame of the log's poses, e.g.
a corrected log's), counts per 1 m cell of x:
  - "through": readings placed beyond the line (more than 2.5 m past it, on the far side
    from the robot) whose ray crosses the line in that cell;
  - "solid": readings placed on the line (within 1.5 m of it) in that cell.
A cell with rays through and no solid returns is an opening (a door, or glass that never
returns); rays through a cell that also returns would be glass seen through.

    scripts/rays-through-line.py LOG.gz --y -27 --x -95 15 [--max-range 49]

Reads FLASER lines (181 beams over 180 degrees, the pose fields after the ranges).
"""
import argparse
import collections
import gzip
import math


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("log")
    parser.add_argument("--y", type=float, required=True, help="the wall line, m")
    parser.add_argument("--x", type=float, nargs=2, required=True, help="its extent, m")
    parser.add_argument("--max-range", type=float, default=49.0,
                        help="readings at or beyond this are no return, m")
    args = parser.parse_args()
    opener = gzip.open if args.log.endswith(".gz") else open
    through, solid = collections.Counter(), collections.Counter()
    x0, x1 = args.x
    with opener(args.log, "rt") as f:
        for line in f:
            fields = line.split()
            if not fields or fields[0] != "FLASER":
                continue
            n = int(fields[1])
            ranges = [float(v) for v in fields[2:2 + n]]
            x, y, theta = (float(v) for v in fields[2 + n:5 + n])
            side = 1.0 if y > args.y else -1.0
            for i, r in enumerate(ranges):
                if r >= args.max_range or r <= 0.01:
                    continue
                a = theta - math.pi / 2 + i * math.pi / (n - 1)
                px, py = x + r * math.cos(a), y + r * math.sin(a)
                if side * (args.y - py) > 2.5 and side * (y - args.y) > 1.0:
                    cx = x + (args.y - y) / (py - y) * (px - x)
                    if x0 <= cx < x1:
                        through[math.floor(cx)] += 1
                if abs(py - args.y) < 1.5 and x0 <= px < x1:
                    solid[math.floor(px)] += 1
    print("x cell (m) | rays through | solid returns")
    for cell in range(math.floor(x0), math.ceil(x1)):
        if through[cell] or solid[cell]:
            print(f"{cell} | {through[cell]} | {solid[cell]}")
    both = sum(through[c] for c in through if solid[c] > 0)
    print(f"rays through: {sum(through.values())}, of them through cells that also return: {both}")


if __name__ == "__main__":
    main()
