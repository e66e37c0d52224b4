#!/usr/bin/env python3
"""ATE of any Victoria Park `trajectory.tum` against the GPS fixes, as `slam run` scores it
today (runtime/src/eval/mod.rs): the estimate's antenna point (3.78 m ahead, 0.5 m left),
each fix paired with the nearest pose within 0.5 s, SE(2) least-squares alignment; once with
every fix and once with the receiver's jumps left out (`gps_jumps`, 20 m/s). For scoring the
trajectories of older binaries, whose own metrics.json used other rules, the same way.

    scripts/vp-gps-ate.py TRAJECTORY.tum [DATASET_DIR]   (needs numpy)

DATASET_DIR defaults to SLAM_DATA_DIR/victoria-park or ../shared/datasets/victoria-park."""
import csv, math, os, sys, bisect
from pathlib import Path
import numpy as np
root = Path(__file__).resolve().parent.parent
data = Path(sys.argv[2]) if len(sys.argv) > 2 else Path(os.environ.get("SLAM_DATA_DIR", root.parent / "shared" / "datasets")) / "victoria-park"
rows = list(csv.DictReader(open(data / "converted" / "gps.csv")))
gps = [(int(r['time_ms'])/1000, float(r['Lo_m']), float(r['La_m'])) for r in rows]
def speed(a, b):
    dt = abs(b[0]-a[0]); d = math.hypot(b[1]-a[1], b[2]-a[2])
    return d/dt if dt > 0 else (math.inf if d > 0 else 0)
V = 20.0
jump = [0 < i < len(gps)-1 and speed(gps[i-1], gps[i]) > V and speed(gps[i], gps[i+1]) > V and speed(gps[i-1], gps[i+1]) <= V for i in range(len(gps))]
est = []
for line in open(sys.argv[1]):
    if line.startswith('#') or not line.strip(): continue
    t, x, y, z, qx, qy, qz, qw = map(float, line.split()[:8])
    th = 2*math.atan2(qz, qw)
    est.append((t, x + 3.78*math.cos(th) - 0.5*math.sin(th), y + 3.78*math.sin(th) + 0.5*math.cos(th)))
times = [e[0] for e in est]
def ate(skip):
    P, Q = [], []
    for i, g in enumerate(gps):
        if skip and jump[i]: continue
        k = bisect.bisect_left(times, g[0]); best = None
        for j in (k-1, k):
            if 0 <= j < len(est) and abs(est[j][0]-g[0]) <= 0.5 and (best is None or abs(est[j][0]-g[0]) < abs(est[best][0]-g[0])): best = j
        if best is None: continue
        P.append(est[best][1:]); Q.append(g[1:])
    P, Q = np.array(P), np.array(Q)
    mp, mq = P.mean(0), Q.mean(0)
    H = (P-mp).T @ (Q-mq); U, S, Vt = np.linalg.svd(H)
    D = np.diag([1, np.sign(np.linalg.det(Vt.T @ U.T))]); R = Vt.T @ D @ U.T
    e = np.linalg.norm((R @ (P-mp).T).T + mq - Q, axis=1)
    return math.sqrt((e**2).mean()), len(e)
print(sys.argv[1], "all fixes: %.3f m (%d)" % ate(False), "jumps left out: %.3f m (%d)" % ate(True))
