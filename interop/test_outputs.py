"""The standard outputs of `slam run` read by other people's readers.

- `map.pgm` + `map.yaml`: loaded as ROS map_server does (PIL + PyYAML, map_server's
  documented trinary thresholding), the occupied cells must lie on the walls of a room
  whose scans this test writes itself.
- `graph.g2o`: GTSAM's `readG2o`; its poses must be our trajectory and its odometry factors
  must be at rest there.
- `run.mcap`: the `mcap` library's reader; channels, Foxglove schema names, message counts
  and time order.

One short CARMEN log of a 6 m x 4 m room (written here, no simulator) and the first 300
events of the rb2d landmark world: a few seconds each with the debug binary.
"""

import json
import math
import pathlib

import numpy as np
import pytest
import yaml
from PIL import Image

from conftest import run_slam

ROOM = [((0.0, 0.0), (6.0, 0.0)), ((6.0, 0.0), (6.0, 4.0)), ((6.0, 4.0), (0.0, 4.0)), ((0.0, 4.0), (0.0, 0.0))]
POSES = [(1.5 + 0.15 * k, 2.0 + 0.3 * math.sin(0.3 * k), 0.25 * k) for k in range(21)]


def ray_to_walls(x, y, bearing):
    """The distance from (x, y) along `bearing` to the nearest wall of the room."""
    dx, dy = math.cos(bearing), math.sin(bearing)
    best = math.inf
    for (ax, ay), (bx, by) in ROOM:
        ex, ey = bx - ax, by - ay
        det = dx * (-ey) - dy * (-ex)
        if abs(det) < 1e-12:
            continue
        rx, ry = ax - x, ay - y
        t = (rx * (-ey) - ry * (-ex)) / det
        u = (dx * ry - dy * rx) / det
        if t > 0 and 0 <= u <= 1:
            best = min(best, t)
    return best


def wall_distance(px, py):
    """The distance from a point to the nearest wall of the room."""
    best = math.inf
    for (ax, ay), (bx, by) in ROOM:
        ex, ey = bx - ax, by - ay
        s = max(0.0, min(1.0, ((px - ax) * ex + (py - ay) * ey) / (ex * ex + ey * ey)))
        best = min(best, math.hypot(px - ax - s * ex, py - ay - s * ey))
    return best


@pytest.fixture(scope="module")
def room_run(slam, tmp_path_factory):
    """`slam run --grid --g2o --mcap` on a CARMEN log of the room (ODOM, and FLASER with 361
    beams, exact)."""
    folder = tmp_path_factory.mktemp("room")
    lines = []
    for k, (x, y, theta) in enumerate(POSES):
        ranges = [ray_to_walls(x, y, theta - math.pi / 2 + b * math.pi / 360) for b in range(361)]
        text = " ".join(f"{r:.4f}" for r in ranges)
        t = f"{0.1 * k:.1f}"
        lines.append(f"ODOM {x} {y} {theta} 0 0 0 {t} host {t}")
        lines.append(f"FLASER 361 {text} {x} {y} {theta} {x} {y} {theta} {t} host {t}")
    log = folder / "room.log"
    log.write_text("\n".join(lines) + "\n")
    config = folder / "run.toml"
    config.write_text("[output]\nplots = false\n")
    out = folder / "out"
    run_slam(slam, "run", str(config), "--data", f"carmen:{log}", "--out", str(out), "--quiet", "--grid", "--g2o", "--mcap")
    return out


@pytest.fixture(scope="module")
def landmark_run(slam, repo, tmp_path_factory):
    """`slam run --g2o` on the first 300 events of the rb2d landmark world."""
    folder = tmp_path_factory.mktemp("landmarks")
    config = folder / "run.toml"
    config.write_text("[data]\nmax_events = 300\n[output]\nplots = false\ng2o = true\n")
    out = folder / "out"
    world = repo / "worlds" / "rb2d-circle.toml"
    run_slam(slam, "run", str(config), "--data", f"world:{world}", "--out", str(out), "--quiet")
    return out


def read_tum(path: pathlib.Path):
    """(time, x, y, yaw) of each line of a TUM trajectory."""
    poses = []
    for line in path.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        t, x, y, _, qx, qy, qz, qw = map(float, line.split())
        poses.append((t, x, y, math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))))
    return poses


def load_map_server(yaml_path: pathlib.Path):
    """A map as ROS map_server loads it (map_server/src/image_loader.cpp, mode trinary):
    p = (255 - value) / 255 unless negate; occupied if p > occupied_thresh, free if
    p < free_thresh, else unknown. Returns the occupancy array (100 occupied, 0 free,
    -1 unknown) indexed [row from the bottom, column], the resolution and the origin."""
    meta = yaml.safe_load(yaml_path.read_text())
    for key in ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"):
        assert key in meta, f"map.yaml has no {key}"
    assert meta.get("mode", "trinary") == "trinary"
    image = Image.open(yaml_path.parent / meta["image"])
    assert image.format == "PPM" and image.mode == "L"
    values = np.asarray(image, dtype=np.float64)
    p = values / 255.0 if meta["negate"] else (255.0 - values) / 255.0
    grid = np.full(values.shape, -1, dtype=np.int8)
    grid[p > meta["occupied_thresh"]] = 100
    grid[p < meta["free_thresh"]] = 0
    # map_server's row 0 is the image's bottom row.
    return grid[::-1, :], float(meta["resolution"]), meta["origin"]


def test_the_grid_loads_as_map_server_does_and_shows_the_room(room_run):
    grid, resolution, origin = load_map_server(room_run / "map.yaml")
    assert resolution == pytest.approx(0.05)
    assert len(origin) == 3 and origin[2] == 0.0
    rows, cols = np.nonzero(grid == 100)
    assert len(rows) > 200, f"only {len(rows)} occupied cells"
    centres = [(origin[0] + (c + 0.5) * resolution, origin[1] + (r + 0.5) * resolution) for r, c in zip(rows, cols)]
    distances = np.array([wall_distance(x, y) for x, y in centres])
    # The occupied cells are the walls: within two cells of one.
    assert np.mean(distances < 2 * resolution) > 0.98, np.percentile(distances, [50, 90, 99])
    # Each wall is mapped along most of its length.
    for (ax, ay), (bx, by) in ROOM:
        along = [
            (x, y) for (x, y), d in zip(centres, distances)
            if d < 2 * resolution and wall_distance_to_segment(x, y, (ax, ay), (bx, by)) < 2 * resolution
        ]
        length = math.hypot(bx - ax, by - ay)
        assert len(along) * resolution > 0.6 * length, f"wall {(ax, ay)}-{(bx, by)}: {len(along)} cells"
    # Inside the room, away from the walls, the cells are free; outside nothing is occupied.
    def state(x, y):
        row, col = int((y - origin[1]) // resolution), int((x - origin[0]) // resolution)
        inside = 0 <= row < grid.shape[0] and 0 <= col < grid.shape[1]
        return grid[row, col] if inside else -1
    for x, y in [(2.0, 2.0), (3.0, 1.0), (4.0, 3.0), (5.0, 2.0)]:
        assert state(x, y) == 0, (x, y)
    for x, y in [(-0.5, 2.0), (7.0, 2.0), (3.0, 4.6), (3.0, -0.6)]:
        assert state(x, y) != 100, (x, y)


def wall_distance_to_segment(px, py, a, b):
    """The distance from a point to segment a-b."""
    (ax, ay), (bx, by) = a, b
    ex, ey = bx - ax, by - ay
    s = max(0.0, min(1.0, ((px - ax) * ex + (py - ay) * ey) / (ex * ex + ey * ey)))
    return math.hypot(px - ax - s * ex, py - ay - s * ey)


def between_errors(graph, values):
    """The largest error of the graph's BetweenFactorPose2 factors at `values`, and their count."""
    import gtsam

    count, worst = 0, 0.0
    for k in range(graph.size()):
        factor = graph.at(k)
        if isinstance(factor, gtsam.BetweenFactorPose2):
            count += 1
            worst = max(worst, factor.error(values))
    return count, worst


def test_gtsam_reads_the_pose_graph_as_our_trajectory(room_run):
    gtsam = pytest.importorskip("gtsam")
    graph, values = gtsam.readG2o(str(room_run / "graph.g2o"), False)
    trajectory = read_tum(room_run / "trajectory.tum")
    steps = json.loads((room_run / "metrics.json").read_text())["steps"]
    assert len(trajectory) == steps > 10
    for k, (_, x, y, yaw) in enumerate(trajectory):
        # trajectory.tum has 6 decimals (9 in the quaternion).
        pose = values.atPose2(k)
        assert pose.x() == pytest.approx(x, abs=6e-7)
        assert pose.y() == pytest.approx(y, abs=6e-7)
        assert math.remainder(pose.theta() - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-7)
    count, worst = between_errors(graph, values)
    assert count == steps - 1
    # The odometry factors hold the relative motion of the estimates: at rest there.
    assert worst < 1e-6
    # The walls: two XY vertices each, named by a comment line g2o readers skip.
    text = (room_run / "graph.g2o").read_text()
    walls = [line.split() for line in text.splitlines() if line.startswith("# WALL ")]
    assert len(walls) >= 4
    for _, _, _, v1, v2 in walls:
        for v in (int(v1), int(v2)):
            # readG2o keys landmarks (VERTEX_XY) as symbols 'l' + id.
            point = values.atPoint2(gtsam.symbol("l", v))
            assert wall_distance(point[0], point[1]) < 0.1


def test_gtsam_reads_the_landmarks_of_the_graph(landmark_run):
    gtsam = pytest.importorskip("gtsam")
    graph, values = gtsam.readG2o(str(landmark_run / "graph.g2o"), False)
    metrics = json.loads((landmark_run / "metrics.json").read_text())
    steps = metrics["steps"]
    landmarks = sum(metrics["features"].get("point", {}).values())
    assert landmarks > 10
    text = (landmark_run / "graph.g2o").read_text().splitlines()
    assert sum(line.startswith("VERTEX_XY ") for line in text) == landmarks
    assert sum(line.startswith("EDGE_SE2_XY ") for line in text) == landmarks
    # readG2o keys poses by their id and landmarks (VERTEX_XY) as symbols 'l' + id.
    poses = [k for k in values.keys() if k < steps]
    assert len(poses) == steps
    points = [k for k in values.keys() if gtsam.Symbol(k).chr() == ord("l")]
    assert len(points) == landmarks
    # Each landmark vertex is where map.json puts the feature.
    mapped = sorted(
        tuple(next(iter(f["coordinates"][0].values()))[:2])
        for f in json.loads((landmark_run / "map.json").read_text())["features"]
        if f["type"] == "point" and f["confirmed"]
    )
    ours = sorted(tuple(float(v) for v in values.atPoint2(k)) for k in points)
    assert len(ours) == len(mapped)
    for a, b in zip(ours, mapped):
        assert a == pytest.approx(b, abs=1e-12)
    count, _ = between_errors(graph, values)
    assert count == steps - 1
    # GTSAM's readG2o skips EDGE_SE2_XY; their measurement is the landmark in the frame of
    # the pose that first mapped it, which GTSAM's own geometry must give.
    for line in text:
        if line.startswith("EDGE_SE2_XY "):
            _, pose_id, point_id, dx, dy, i11, i12, i22 = line.split()
            point = values.atPoint2(gtsam.symbol("l", int(point_id)))
            local = values.atPose2(int(pose_id)).transformTo(point)
            assert float(dx) == pytest.approx(local[0], abs=1e-9)
            assert float(dy) == pytest.approx(local[1], abs=1e-9)
            information = np.array([[float(i11), float(i12)], [float(i12), float(i22)]])
            assert np.all(np.linalg.eigvalsh(information) > 0)


def test_the_mcap_log_reads_with_the_mcap_library(room_run):
    from mcap.reader import make_reader

    steps = json.loads((room_run / "metrics.json").read_text())["steps"]
    trajectory_times = [t for t, *_ in read_tum(room_run / "trajectory.tum")]
    with open(room_run / "run.mcap", "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        assert topics == {
            "/tf": "foxglove.FrameTransform",
            "/pose": "foxglove.PoseInFrame",
            "/pose_covariance": "foxglove.SceneUpdate",
            "/scan": "foxglove.LaserScan",
            "/map": "foxglove.SceneUpdate",
        }
        for schema in summary.schemas.values():
            assert schema.encoding == "jsonschema"
            assert json.loads(schema.data)["title"] == schema.name
        counts, last_time, pose_times, scene = {}, 0, [], {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert channel.message_encoding == "json"
            body = json.loads(message.data)
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            # Written in time order, each message stamped with its log time.
            assert message.log_time >= last_time
            last_time = message.log_time
            if channel.topic in ("/scan", "/pose"):
                stamp = body["timestamp"]
                assert stamp["sec"] * 10**9 + stamp["nsec"] == message.log_time
            if channel.topic == "/pose":
                assert body["frame_id"] == "map"
                pose_times.append(message.log_time / 1e9)
            if channel.topic == "/scan":
                assert len(body["ranges"]) == 361
                assert body["end_angle"] - body["start_angle"] == pytest.approx(math.pi)
            if channel.topic == "/map":
                # Replayed as Foxglove does: an entity replaces the one of its id.
                for deletion in body["deletions"]:
                    scene.pop(deletion["id"], None)
                for entity in body["entities"]:
                    assert entity["frame_id"] == "map"
                    scene[entity["id"]] = entity
        assert counts["/scan"] == len(POSES)
        assert counts["/pose"] == counts["/tf"] == counts["/pose_covariance"] == steps
        assert counts["/map"] >= 1
        # At the end the scene holds the walls of map.json, each a segment.
        walls = [f for f in json.loads((room_run / "map.json").read_text())["features"] if f["type"] == "wall" and f["confirmed"]]
        drawn = [e for e in scene.values() if e["lines"] and not e["spheres"]]
        assert len(drawn) == len(walls) >= 4
        assert all(len(e["lines"][0]["points"]) == 2 for e in drawn)
        assert pose_times == pytest.approx(trajectory_times, abs=1e-6)
        assert summary.statistics.message_count == sum(counts.values())
