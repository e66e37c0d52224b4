#!/usr/bin/env python3
"""How large a loop the filter closes: ring corridors of growing size, simulated.

Each world is a rectangular ring corridor (outer walls `a` x `a/2` m, 2.5 m wide, a door
alcove 1 m wide and 0.4 m deep every 6 m of the outer wall, so that the corridor is not
featureless along its length), driven once round its centre line and on along the first
two sides again, so that the walls seen first are seen again after the whole loop. The
robot, odometry noise and laser are the built-in world's (0.5 m/s, 0.05 m/s and 2 deg/s,
a 180-degree laser of 8 m). For each size and seed it runs

    slam run CONFIG --data world:RING.toml --seed SEED --out OUT/a-SEED

and prints one table row: the loop length (the centre line), the ATE, the error of the
last pose, the map error, the wall count, and the doubled wall length on the same side
(`metrics.json` `map_quality`: a second wall within 10 cm and 5 degrees overlapping it),
which stays above zero where the loop's walls were mapped twice and not merged.

    scripts/loop-size.py --slam target/release/slam --config configs/carmen-walls.toml \\
        --out /tmp/loop-size [--sides 20,40,80,160] [--seeds 1,2,3,4,5]

Needs only Python 3's standard library.
"""

import argparse
import csv
import json
import math
import os
import subprocess
import sys

WIDTH = 2.5  # corridor width, m
ALCOVE_EVERY = 6.0  # m along the outer wall
ALCOVE_WIDTH = 1.0
ALCOVE_DEPTH = 0.4


def outer_side(p0, p1, outward):
    """Points of one outer wall from p0 to p1 with alcoves recessed towards `outward`."""
    dx, dy = p1[0] - p0[0], p1[1] - p0[1]
    length = math.hypot(dx, dy)
    ux, uy = dx / length, dy / length

    def at(t, depth):
        return [round(p0[0] + ux * t + outward[0] * depth, 3),
                round(p0[1] + uy * t + outward[1] * depth, 3)]

    points = [list(p0)]
    s = ALCOVE_EVERY
    while s + ALCOVE_WIDTH < length - 2.0:
        points += [at(s, 0), at(s, ALCOVE_DEPTH), at(s + ALCOVE_WIDTH, ALCOVE_DEPTH),
                   at(s + ALCOVE_WIDTH, 0)]
        s += ALCOVE_EVERY
    return points


def ring_world(a):
    """The world file (TOML text) of the ring of outer size a x a/2, and its loop length."""
    b = a / 2
    corners = [[0.0, 0.0], [a, 0.0], [a, b], [0.0, b]]
    outward = [[0, -1], [1, 0], [0, 1], [-1, 0]]
    outer = []
    for i in range(4):
        outer += outer_side(corners[i], corners[(i + 1) % 4], outward[i])
    w, h = WIDTH, WIDTH / 2
    inner = [[w, w], [a - w, w], [a - w, b - w], [w, b - w]]
    # Once round the centre line, then along the first two sides again.
    waypoints = [[a - h, h], [a - h, b - h], [h, b - h], [h, h], [a - h, h], [a - h, b / 2]]
    loop_length = 2 * ((a - 2 * h) + (b - 2 * h))
    text = f"""# A ring corridor of {a:g} m x {b:g} m (scripts/loop-size.py).
name = "ring-{a:g}"

[[walls]]
points = {outer}
closed = true

[[walls]]
points = {inner}
closed = true

[robot]
start = [{a / 2}, {h}]
start_heading_deg = 0.0
speed = 0.5
max_yaw_rate_deg = 45.0
dt = 0.1
waypoints = {waypoints}

[odometry]
sigma_v = 0.05
sigma_omega_deg = 2.0

[laser]
position = [0.15, 0.0, 0.3]
yaw_deg = 0.0
fov_deg = 180.0
beams = 361
max_range = 8.0
sigma_range = 0.02
every = 2
"""
    return text, loop_length


def run(slam, config, world, seed, out):
    """Runs `slam run` and returns its figures for the table."""
    args = [slam, "run"] + ([config] if config else []) + [
        "--data", f"world:{world}", "--seed", str(seed), "--out", out, "--quiet"]
    done = subprocess.run(args, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"loop-size.py: {' '.join(args)} failed:\n{done.stderr.strip()}")
    with open(os.path.join(out, "metrics.json")) as f:
        metrics = json.load(f)
    with open(os.path.join(out, "estimates.csv")) as f:
        last = list(csv.DictReader(f))[-1]
    final = math.hypot(float(last["x"]) - float(last["true_x"]),
                       float(last["y"]) - float(last["true_y"]))
    quality = metrics["map_quality"]
    return {
        "ate": metrics["ate_rmse_m"],
        "final": final,
        "map_error": metrics["map_error_m"],
        "walls": quality["walls"],
        "doubled_same": 100 * quality["doubled_same_side_fraction"],
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--slam", default="target/release/slam")
    parser.add_argument("--config", default="configs/carmen-walls.toml",
                        help="config file ('' for the defaults)")
    parser.add_argument("--out", required=True, help="folder for the worlds and the runs")
    parser.add_argument("--sides", default="20,40,80,160", help="outer lengths a, m")
    parser.add_argument("--seeds", default="1,2,3,4,5")
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    seeds = [int(s) for s in args.seeds.split(",")]
    print("| outer size | loop length | seed | ATE | last pose off | map error | walls | "
          "doubled (same side) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for a in [float(s) for s in args.sides.split(",")]:
        text, loop_length = ring_world(a)
        world = os.path.join(args.out, f"ring-{a:g}.toml")
        with open(world, "w") as f:
            f.write(text)
        for seed in seeds:
            r = run(args.slam, args.config, world, seed,
                    os.path.join(args.out, f"ring-{a:g}-{seed}"))
            print(f"| {a:g} x {a / 2:g} m | {loop_length:.0f} m | {seed} | {r['ate']:.3f} m | "
                  f"{r['final']:.3f} m | {r['map_error']:.3f} m | {r['walls']} | "
                  f"{r['doubled_same']:.1f} % |", flush=True)


if __name__ == "__main__":
    main()
