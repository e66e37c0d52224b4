"""Shared fixtures: the `slam` binary, the real datasets and a scratch folder."""

import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def repo() -> pathlib.Path:
    """The repository's root folder."""
    return REPO


@pytest.fixture(scope="session")
def slam() -> pathlib.Path:
    """The `slam` binary: `SLAM_BIN`, or `target/debug/slam` (built when missing)."""
    path = pathlib.Path(os.environ.get("SLAM_BIN", REPO / "target" / "debug" / "slam"))
    if not path.exists():
        subprocess.run(["cargo", "build", "-p", "slam-cli"], cwd=REPO, check=True)
    return path


@pytest.fixture(scope="session")
def datasets() -> pathlib.Path:
    """The real datasets folder (`SLAM_DATA_DIR`, default `../shared/datasets`).

    Absent data skip the test, or fail it when `SLAM_REQUIRE_DATA=1`.
    """
    path = pathlib.Path(os.environ.get("SLAM_DATA_DIR", REPO.parent / "shared" / "datasets"))
    if not path.is_dir():
        message = f"the real datasets are absent ({path}); see DATASETS.md"
        if os.environ.get("SLAM_REQUIRE_DATA") == "1":
            pytest.fail(message)
        pytest.skip(message)
    return path


def run_slam(slam: pathlib.Path, *args: str, cwd: pathlib.Path | None = None) -> subprocess.CompletedProcess:
    """Runs `slam ARGS...` and fails the test with its output when it fails."""
    result = subprocess.run([str(slam), *args], cwd=cwd, capture_output=True, text=True)
    if result.returncode != 0:
        pytest.fail(f"slam {' '.join(args)} exited {result.returncode}:\n{result.stderr}")
    return result
