"""`slam run --data mcap:FILE` on ROS 2 bags written by the standard Python writer
(`mcap-ros2-support`) from CARMEN logs: the same trajectory as `--data carmen:FILE`."""

import csv
import gzip
import os
import itertools
import math
import pathlib
import subprocess

import pytest
from mcap.reader import make_reader

from carmen_to_mcap import convert
from conftest import run_slam

# Dead reckoning: the poses follow the data's motion, so the two runs must agree to rounding.
DEAD_RECKONING = """
[data.mcap]
reference_topic = "/reference_pose"

[estimator]
type = "dead-reckoning"

[output]
plots = false
"""

# The odometry built from the reference poses (as for the Radish logs), dead-reckoned.
FROM_REFERENCE_POSES = """
[data.odometry_from_poses]
""" + DEAD_RECKONING

# The walls EKF on the same odometry: the scans enter the estimate.
EKF_WALLS = """
[data.odometry_from_poses]

[data.mcap]
reference_topic = "/reference_pose"

[estimator]
type = "ekf"

[frontend]
type = "features"
walls = true
poles = false
camera = false

[output]
plots = false
"""


def trajectory(folder: pathlib.Path) -> list[list[float]]:
    """The rows `time x y theta` of a run's estimates.csv (all digits; trajectory.tum has 6
    decimals, where a difference in the 16th digit can show in the 6th)."""
    with open(folder / "estimates.csv") as f:
        rows = list(csv.DictReader(f))
    return [[float(r["time"]), float(r["x"]), float(r["y"]), float(r["theta"])] for r in rows]


def line_stamps(log: pathlib.Path) -> dict[int, float]:
    """The logger timestamp of each ODOM and laser line by line number, held at the largest
    before it when it goes back (as the bag reader holds its stamps)."""
    opener = gzip.open if log.suffix == ".gz" else open
    stamps, latest = {}, -math.inf
    with opener(log, "rt") as f:
        for number, line in enumerate(f, 1):
            fields = line.split()
            if fields and fields[0] in ("ODOM", "FLASER", "ROBOTLASER1"):
                latest = max(latest, float(fields[-1]))
                stamps[number] = latest
    return stamps


def by_stamp(carmen: list[list[float]], log: pathlib.Path) -> list[list[float]]:
    """A trajectory read with line numbers as times, as one row per logger timestamp: the last
    row of the lines sharing a stamp, timed by it (the bag's events of one stamp are one step).
    A trajectory already timed in seconds is returned as it is."""
    if not all(row[0] == int(row[0]) for row in carmen):
        return carmen
    stamps = line_stamps(log)
    rows: list[list[float]] = []
    for row in carmen:
        t = stamps[int(row[0])]
        if rows and rows[-1][0] == t:
            rows[-1] = [t, *row[1:]]
        else:
            rows.append([t, *row[1:]])
    return rows


def run_both(slam, tmp_path, log: pathlib.Path, config_text: str, compression="zstd"):
    """Converts `log` to a bag and runs both; returns the two trajectories (the CARMEN one one
    row per stamp, see `by_stamp`) and the mcap run's stderr."""
    bag = tmp_path / (log.stem + ".mcap")
    counts = convert(str(log), str(bag), compression=compression)
    assert counts["/scan"] > 0 and counts["/odom"] > 0, counts
    with open(bag, "rb") as f:
        # Written by the standard writer: zstd chunks by default, which the reader must take.
        summary = make_reader(f).get_summary()
        expected = "" if compression == "none" else compression
        assert {c.compression for c in summary.chunk_indexes} == {expected}
    config = tmp_path / "config.toml"
    config.write_text(config_text)
    runs = {}
    for kind, source in [("carmen", log), ("mcap", bag)]:
        out = tmp_path / f"out-{kind}"
        result = run_slam(slam, "run", str(config), "--data", f"{kind}:{source}", "--out", str(out))
        runs[kind] = (trajectory(out), result.stderr)
    return by_stamp(runs["carmen"][0], log), runs["mcap"][0], runs["mcap"][1]


def assert_same_poses(carmen, mcap, tolerance):
    assert len(carmen) == len(mcap) > 10
    worst = 0.0
    for k, (a, b) in enumerate(zip(carmen, mcap)):
        dyaw = math.remainder(a[3] - b[3], 2 * math.pi)
        error = max(abs(a[1] - b[1]), abs(a[2] - b[2]), abs(dyaw))
        assert error <= tolerance, f"step {k}: carmen {a} vs mcap {b}"
        worst = max(worst, error)
    return worst


def assert_same_times(carmen, mcap):
    for a, b in zip(carmen, mcap):
        assert abs(a[0] - b[0]) < 1e-6, (a[0], b[0])


@pytest.fixture(scope="module")
def simulated_log(slam, tmp_path_factory) -> pathlib.Path:
    """The first 400 lines of the CARMEN log of a simulated run (ROBOTLASER1 and ODOM lines)."""
    folder = tmp_path_factory.mktemp("sim")
    run_slam(slam, "simulate", "--out", str(folder / "sim"))
    lines = (folder / "sim" / "run.carmen.log").read_text().splitlines(keepends=True)
    head = folder / "sim-head.carmen.log"
    head.write_text("".join(lines[:400]))
    return head


@pytest.fixture(scope="module")
def intel_head(datasets, tmp_path_factory) -> pathlib.Path:
    """The first 1500 lines of the Intel corrected log (FLASER and ODOM lines), gzipped."""
    source = datasets / "radish-carmen-corrected" / "intel-corrected.log.gz"
    if not source.exists():
        message = f"{source} is absent; see DATASETS.md"
        if os.environ.get("SLAM_REQUIRE_DATA") == "1":
            pytest.fail(message)
        pytest.skip(message)
    head = tmp_path_factory.mktemp("intel") / "intel-head.log.gz"
    with gzip.open(source, "rt") as f, gzip.open(head, "wt") as out:
        out.writelines(itertools.islice(f, 1500))
    return head


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_simulated_log_dead_reckoned(slam, tmp_path, simulated_log, compression):
    carmen, mcap, stderr = run_both(slam, tmp_path, simulated_log, DEAD_RECKONING, compression)
    assert_same_poses(carmen, mcap, 1e-9)
    assert_same_times(carmen, mcap)
    # The simulated laser's mount came from /tf_static.
    assert "laser mount of frame `robot_laser` from /tf_static" in stderr, stderr


def test_simulated_log_from_reference_poses(slam, tmp_path, simulated_log):
    carmen, mcap, _ = run_both(slam, tmp_path, simulated_log, FROM_REFERENCE_POSES)
    assert_same_poses(carmen, mcap, 1e-9)


def test_intel_log_from_reference_poses(slam, tmp_path, intel_head):
    carmen, mcap, stderr = run_both(slam, tmp_path, intel_head, FROM_REFERENCE_POSES)
    assert_same_poses(carmen, mcap, 1e-9)
    assert_same_times(carmen, mcap)
    assert "laser mount of frame `front_laser` from /tf_static" in stderr, stderr


def test_intel_log_walls_ekf(slam, tmp_path, intel_head):
    # The bag holds angles and ranges as float32 (ROS's LaserScan); ranges come back as the
    # log's decimals, angles to float32 precision (~1e-7 rad), so the walls EKF agrees to
    # about that, not to the last bit.
    carmen, mcap, _ = run_both(slam, tmp_path, intel_head, EKF_WALLS)
    worst = assert_same_poses(carmen, mcap, 1e-5)
    print(f"walls EKF, Intel head: largest pose difference {worst:.3g}")


def test_missing_topic_is_a_clear_error(slam, tmp_path, simulated_log):
    bag = tmp_path / "sim.mcap"
    convert(str(simulated_log), str(bag))
    config = tmp_path / "config.toml"
    config.write_text('[data.mcap]\nscan_topic = "/laser"\n[estimator]\ntype = "dead-reckoning"\n')
    result = subprocess.run(
        [str(slam), "run", str(config), "--data", f"mcap:{bag}", "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 1, result
    assert "no topic /laser (scan_topic, sensor_msgs/msg/LaserScan)" in result.stderr, result.stderr
    assert "/odom (nav_msgs/msg/Odometry, cdr)" in result.stderr, result.stderr
    assert not (tmp_path / "out").exists()
