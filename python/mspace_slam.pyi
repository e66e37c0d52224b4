"""mspace_slam: the M-space SLAM framework (the `slam` command) from Python."""

import os
from typing import Any, Mapping, Optional, TypedDict, Union

import numpy as np
import numpy.typing as npt

__version__: str

class _RequiredResult(TypedDict):
    trajectory: npt.NDArray[np.float64]
    """(N, 4): time, x (m), y (m), theta (rad) after each time step (trajectory.tum)."""
    covariance: npt.NDArray[np.float64]
    """(N, 3, 3): each pose's covariance (x, y, theta)."""
    map: list[dict[str, Any]]
    """One dict per feature, as in map.json."""
    shared_blocks: list[dict[str, Any]]
    """The map's shared blocks (wall corners), as in map.json."""
    metrics: dict[str, Any]
    """The content of metrics.json."""

class Result(_RequiredResult, total=False):
    reference: npt.NDArray[np.float64]
    """(M, 4): the data's true (else reference) poses, t, x, y, theta; when the data have any."""
    map_path: npt.NDArray[np.float64]
    """(N, 4): the path the map belongs to (particle filters only; map_path.tum)."""

def run(
    config: Union[None, str, "os.PathLike[str]", Mapping[str, Any]] = None,
    data: Optional[str] = None,
    seed: Optional[int] = None,
) -> Result:
    """Run the estimator of a configuration as `slam run` does; return the results.

    config: None (defaults), a TOML file's path, TOML text, or a dict of tables and keys.
    data: a data spec as `slam run --data` ("sim", "world:FILE", "carmen:FILE", ...).
    seed: the simulation seed.

    Raises ValueError (bad config or data, the message `slam run` prints),
    FileNotFoundError / OSError (unreadable data file), RuntimeError (a failure of the run),
    TypeError (config of another type), KeyboardInterrupt (Ctrl-C).
    """
    ...
