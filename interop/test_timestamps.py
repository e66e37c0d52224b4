"""`trajectory.tum` carries the log's own timestamps, so that evo pairs it with another
tool's poses of the same log without options (`evo_ape tum REF EST`), and the ATE evo
computes is the one our metrics.json reports.

- The real Intel log (its first lines, as a CARMEN file): the reference is written here from
  the FLASER lines (their x y theta at their logger timestamp, parsed in this test).
- A simulated CARMEN log (always runs): its times are the simulator's, those of `truth.tum`.
"""

import gzip
import json
import math
import os
import pathlib
import re
import shutil
import subprocess
import sys

import pytest
from evo.core import sync
from evo.tools import file_interface

from conftest import run_slam

# The first lines of the Intel log: about 90 scans, a run of a second or two.
INTEL_LINES = 2000
# The first lines of a simulated CARMEN log: about 130 scans.
SIM_LINES = 400


def evo_env(tmp_path: pathlib.Path) -> dict:
    """evo writes its settings under ~/.evo and matplotlib its cache: keep both in tmp_path."""
    env = dict(os.environ)
    env["HOME"] = str(tmp_path)
    env["MPLCONFIGDIR"] = str(tmp_path / "mpl")
    return env


def evo_ape(ref: pathlib.Path, est: pathlib.Path, tmp_path: pathlib.Path) -> dict:
    """`evo_ape tum REF EST` with no options: its statistics, by name."""
    tool = shutil.which("evo_ape", path=str(pathlib.Path(sys.executable).parent)) or "evo_ape"
    result = subprocess.run(
        [tool, "tum", str(ref), str(est)],
        capture_output=True,
        text=True,
        env=evo_env(tmp_path),
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "(not aligned)" in result.stdout, result.stdout
    stats = dict(
        (name, float(value))
        for name, value in re.findall(r"^\s*(\w+)\s+([-+0-9.eE]+)\s*$", result.stdout, re.M)
    )
    assert "rmse" in stats, result.stdout
    return stats


def pairs(ref: pathlib.Path, est: pathlib.Path):
    """The trajectories and their evo association with its default max_diff (0.01 s)."""
    traj_ref = file_interface.read_tum_trajectory_file(str(ref))
    traj_est = file_interface.read_tum_trajectory_file(str(est))
    ref_synced, est_synced = sync.associate_trajectories(traj_ref, traj_est)
    return traj_ref, traj_est, ref_synced, est_synced


def carmen_stamp(fields: list) -> str:
    """The logger timestamp of a CARMEN record: its last field."""
    return fields[-1]


def test_intel_trajectory_pairs_with_the_log_reference_poses(slam, datasets, tmp_path):
    source = datasets / "radish-carmen-corrected" / "intel-corrected.log.gz"
    with gzip.open(source, "rt") as log:
        lines = [line for _, line in zip(range(INTEL_LINES), log)]
    head = tmp_path / "intel-head.log"
    head.write_text("".join(lines))

    # The reference: each FLASER line's pose (x y theta follow the n readings) at its
    # logger timestamp, as another tool would write it.
    ref = tmp_path / "reference.tum"
    rows = []
    for line in lines:
        fields = line.split()
        if not fields or fields[0] != "FLASER":
            continue
        n = int(fields[1])
        x, y, theta = (float(v) for v in fields[2 + n : 5 + n])
        stamp = carmen_stamp(fields)
        rows.append(f"{stamp} {x!r} {y!r} 0 0 0 {math.sin(theta / 2)!r} {math.cos(theta / 2)!r}\n")
    assert len(rows) > 50
    ref.write_text("".join(rows))

    config = tmp_path / "cheap.toml"
    config.write_text("[data.odometry_from_poses]\n")
    out = tmp_path / "out"
    run_slam(slam, "run", str(config), "--data", f"carmen:{head}", "--out", str(out), "--quiet")
    est = out / "trajectory.tum"

    traj_ref, traj_est, ref_synced, est_synced = pairs(ref, est)
    # Every reference pose has its estimate, at its own time.
    assert ref_synced.num_poses == traj_ref.num_poses == len(rows)
    assert max(abs(a - b) for a, b in zip(ref_synced.timestamps, est_synced.timestamps)) < 1e-6

    metrics = json.loads((out / "metrics.json").read_text())
    stats = evo_ape(ref, est, tmp_path)
    # The same ATE (evo_ape without -a is the unaligned one); the TUM files' 6 decimals
    # round the coordinates by up to 5e-7 m.
    assert stats["rmse"] == pytest.approx(metrics["ate_rmse_unaligned_m"], abs=1e-5)
    assert metrics["ate"]["count"] == len(rows)
    # The stamps were usable: no warning says the times are line numbers.
    warnings = metrics["input"]["warnings"]
    assert not any("line numbers" in w for w in warnings), warnings


def test_simulated_carmen_trajectory_carries_the_simulator_times(slam, tmp_path):
    sim = tmp_path / "sim"
    run_slam(slam, "simulate", "--out", str(sim))
    with open(sim / "run.carmen.log") as log:
        lines = [line for _, line in zip(range(SIM_LINES), log)]
    head = tmp_path / "sim-head.log"
    head.write_text("".join(lines))
    stamps = [float(carmen_stamp(l.split())) for l in lines if l.split()[:1] in (["ODOM"], ["ROBOTLASER1"])]

    out = tmp_path / "out"
    run_slam(slam, "run", "--data", f"carmen:{head}", "--out", str(out), "--quiet")
    est = out / "trajectory.tum"
    truth = sim / "truth.tum"

    traj_truth, traj_est, truth_synced, est_synced = pairs(truth, est)
    # Every estimate pose pairs with the true pose of its own time (line numbers would not).
    assert est_synced.num_poses == traj_est.num_poses
    assert max(abs(a - b) for a, b in zip(truth_synced.timestamps, est_synced.timestamps)) < 1e-6
    assert traj_est.timestamps[0] == pytest.approx(min(stamps))
    assert traj_est.timestamps[-1] == pytest.approx(max(stamps))
    # Paired by time, the estimate stays near the truth (at line numbers, poses of the first
    # seconds would be compared with the truth of much later times, metres away).
    stats = evo_ape(truth, est, tmp_path)
    assert stats["rmse"] < 0.3, stats
