"""mspace_slam.run against the `slam run` command: same results, same errors.

Needs the package installed (`pip install ./python`) and the `slam` binary (`SLAM_BIN`,
default target/debug/slam, built when missing).
"""

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import mspace_slam

REPO = pathlib.Path(__file__).resolve().parents[2]

# The default world (the command's default data), cut after its first turns so that a
# debug build runs it in seconds; the ATE is defined (the path is no longer a line).
SHORT = "[data]\nmax_events = 2000\n[output]\nplots = false\n"
# Shorter still (along the first corridor: no ATE), for comparisons between calls.
SHORTER = {"data": {"max_events": 400}, "output": {"plots": False}}
SHORTER_TOML = "[data]\nmax_events = 400\n[output]\nplots = false\n"


@pytest.fixture(scope="session")
def slam() -> pathlib.Path:
    """The `slam` binary: `SLAM_BIN`, or `target/debug/slam` (built when missing)."""
    path = pathlib.Path(os.environ.get("SLAM_BIN", REPO / "target" / "debug" / "slam"))
    if not path.exists():
        subprocess.run(["cargo", "build", "-p", "slam-cli"], cwd=REPO, check=True)
    return path


def slam_run(slam: pathlib.Path, *args: str) -> subprocess.CompletedProcess:
    """`slam run ARGS... --quiet`, its exit code not checked."""
    return subprocess.run(
        [str(slam), "run", *args, "--quiet"], capture_output=True, text=True, cwd=REPO
    )


@pytest.fixture(scope="module")
def short_run(slam, tmp_path_factory):
    """The short run by the command (its output folder) and by the module (its result)."""
    folder = tmp_path_factory.mktemp("short")
    config = folder / "short.toml"
    config.write_text(SHORT)
    out = folder / "out"
    done = slam_run(slam, str(config), "--out", str(out))
    assert done.returncode == 0, done.stderr
    return out, mspace_slam.run(config=str(config))


def test_the_ate_and_the_metrics_equal_the_commands(short_run):
    out, result = short_run
    metrics = json.loads((out / "metrics.json").read_text())
    ate = result["metrics"]["ate_rmse_m"]
    assert ate is not None and ate == metrics["ate_rmse_m"], (ate, metrics["ate_rmse_m"])
    # Everything but the clock and the output folder (--out) is the same run's.
    for key in ("wall_time_s", "time_per_step_ms"):
        metrics.pop(key)
        result["metrics"].pop(key)
    assert metrics["config"].pop("output")["dir"] == str(out)
    result["metrics"]["config"].pop("output")
    assert result["metrics"] == metrics


def test_the_trajectory_is_trajectory_tum_as_t_x_y_theta(short_run):
    out, result = short_run
    trajectory = result["trajectory"]
    assert trajectory.dtype == np.float64
    assert trajectory.shape == (result["metrics"]["steps"], 4)
    tum = np.loadtxt(out / "trajectory.tum")
    assert tum.shape[0] == trajectory.shape[0]
    np.testing.assert_allclose(trajectory[:, :3], tum[:, :3], rtol=0, atol=1e-6)
    # Yaw from the quaternion (qx qy qz qw), wrapped.
    yaw = 2 * np.arctan2(tum[:, 6], tum[:, 7])
    difference = np.angle(np.exp(1j * (trajectory[:, 3] - yaw)))
    assert np.max(np.abs(difference)) < 1e-6
    assert result["covariance"].shape == (trajectory.shape[0], 3, 3)
    np.testing.assert_allclose(result["covariance"], result["covariance"].transpose(0, 2, 1))


def test_the_map_and_the_reference_are_the_runs(short_run):
    out, result = short_run
    features = json.loads((out / "map.json").read_text())["features"]
    assert result["map"] == features
    assert len(features) > 0
    # The simulated world's true poses, one per step at least.
    reference = result["reference"]
    assert reference.shape[1] == 4 and reference.shape[0] >= result["trajectory"].shape[0]
    assert result["metrics"]["ate_against"] == "ground truth"
    assert "map_path" not in result


def test_a_dict_config_is_the_same_config_as_its_toml():
    as_toml = mspace_slam.run(config=SHORTER_TOML)
    as_dict = mspace_slam.run(config=SHORTER)
    assert as_dict["trajectory"].shape[0] > 100
    np.testing.assert_array_equal(as_dict["trajectory"], as_toml["trajectory"])
    assert as_dict["map"] == as_toml["map"]


def test_the_seed_and_the_data_override_the_config():
    first = mspace_slam.run(config=SHORTER)
    other = mspace_slam.run(config=SHORTER, seed=2)
    assert (first["metrics"]["seed"], other["metrics"]["seed"]) == (1, 2)
    assert first["trajectory"].shape == other["trajectory"].shape
    assert not np.array_equal(first["trajectory"], other["trajectory"])
    world = REPO / "worlds" / "rb2d-circle.toml"
    circle = mspace_slam.run(config=SHORTER, data=f"world:{world}")
    assert circle["metrics"]["data"] != first["metrics"]["data"]
    assert circle["metrics"]["features"] != first["metrics"]["features"]
    assert circle["trajectory"].shape[0] == circle["metrics"]["steps"]


def test_a_misspelt_key_is_a_value_error_naming_it_as_the_command_does(slam, tmp_path):
    config = tmp_path / "bad.toml"
    config.write_text('[estimator]\ntype = "ekf"\ngate_probabilty = 0.9\n')
    done = slam_run(slam, str(config), "--out", str(tmp_path / "out"))
    assert done.returncode == 1
    with pytest.raises(ValueError) as raised:
        mspace_slam.run(config=str(config))
    assert "gate_probabilty" in str(raised.value)
    assert done.stderr.strip() == f"slam: {raised.value}"
    # The same as text and as a dict (the origin differs, the key is named).
    with pytest.raises(ValueError, match="gate_probabilty"):
        mspace_slam.run(config=config.read_text())
    with pytest.raises(ValueError, match="gate_probabilty"):
        mspace_slam.run(config={"estimator": {"type": "ekf", "gate_probabilty": 0.9}})


def test_bad_data_is_an_error_with_the_commands_message(slam, tmp_path):
    done = slam_run(slam, "--data", "nonsense:x", "--out", str(tmp_path / "out"))
    assert done.returncode == 1
    with pytest.raises(ValueError) as raised:
        mspace_slam.run(data="nonsense:x")
    assert done.stderr.strip() == f"slam: {raised.value}"
    missing = tmp_path / "no-such.log"
    with pytest.raises(FileNotFoundError, match="no-such.log"):
        mspace_slam.run(data=f"carmen:{missing}")
    with pytest.raises(TypeError):
        mspace_slam.run(config=3)


def test_the_module_and_run_are_documented():
    assert "run(" in mspace_slam.__doc__
    assert "ValueError" in mspace_slam.run.__doc__
    assert mspace_slam.__version__


def test_ctrl_c_stops_a_run_with_keyboard_interrupt():
    # Ctrl-C ends a run at the next event: the interrupted run ends well before the same run
    # left alone, both timed here. The child sets Python's own Ctrl-C handler: started from a
    # shell's background job it inherits SIGINT ignored, and then no Ctrl-C reaches it.
    script = (
        "import mspace_slam, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
        "print('go', flush=True); mspace_slam.run()"
    )

    def started():
        child = subprocess.Popen(
            [sys.executable, "-c", script],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert child.stdout.readline().strip() == "go"
        return child, time.monotonic()

    child, began = started()
    _, stderr = child.communicate(timeout=600)
    whole = time.monotonic() - began
    assert child.returncode == 0, stderr

    child, began = started()
    time.sleep(0.1 * whole)
    child.send_signal(signal.SIGINT)
    _, stderr = child.communicate(timeout=600)
    interrupted = time.monotonic() - began
    assert interrupted < 0.6 * whole, (interrupted, whole)
    assert child.returncode != 0
    assert "KeyboardInterrupt" in stderr, stderr
