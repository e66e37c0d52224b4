#!/usr/bin/env python3
"""Converts a CARMEN log (plain or gzip) into a ROS 2 bag stored as MCAP, with the standard
writer of `mcap-ros2-support` (zstd-compressed chunks, its default).

    python interop/carmen_to_mcap.py LOG OUT.mcap [--max-lines N] [--compression zstd|lz4|none]

What is written (the same events `slam run --data carmen:LOG` reads; see
sensors/src/data/carmen.rs):

- `FLASER` and `ROBOTLASER1` lines -> `/scan` (`sensor_msgs/msg/LaserScan`), stamped with the
  line's logger timestamp. `FLASER` beams span 180 degrees from -90 degrees, spaced pi/(n-1)
  for an odd count and pi/n for an even one; `range_max` is the largest reading of the file's
  laser lines (a max-range reading is "no return"), or the `ROBOTLASER1` line's own maximum
  range; `range_min` is 0. Frames: `front_laser` (FLASER), `robot_laser` (ROBOTLASER1).
- The laser line's robot pose -> `/reference_pose` (`geometry_msgs/msg/PoseStamped`, frame
  `map`), right after its scan with the same stamp.
- `ODOM` lines -> `/odom` (`nav_msgs/msg/Odometry`, `odom` -> `base_link`, the line's `tv`, `rv`
  as the twist), except an `ODOM` line right after a laser line that repeats its robot pose and
  is stamped more than 1 s before the latest stamp (the Radish corrected logs re-anchor their
  odometry at the corrected pose so after each scan): the CARMEN reader reads it as a reset of
  the odometry frame, not as motion, and a bag's `/odom` carries no such message. Those lines
  are counted on stderr.
- `/tf_static` (`tf2_msgs/msg/TFMessage`), first: `base_link` -> `front_laser` is the identity
  (the CARMEN reader's default front-laser mount); `base_link` -> `robot_laser` is the mount of
  the `ROBOTLASER1` lines (the laser pose relative to the robot pose; one for the whole log).

Messages are written in line order; the log time of each is the largest stamp so far (a
recording's clock does not go back, while some logs' timestamps do). `RLASER` and every other
line are left out (`RLASER` lines are counted on stderr).
"""

import argparse
import gzip
import math
import os
import sys

from mcap.writer import CompressionType
from mcap_ros2.writer import Writer

COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}

HEADER = """================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""

VECTORS = """================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w
"""

POSE = """================================================================================
MSG: geometry_msgs/Pose
geometry_msgs/Point position
geometry_msgs/Quaternion orientation
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
"""

LASER_SCAN = """std_msgs/Header header
float32 angle_min
float32 angle_max
float32 angle_increment
float32 time_increment
float32 scan_time
float32 range_min
float32 range_max
float32[] ranges
float32[] intensities
""" + HEADER

ODOMETRY = """std_msgs/Header header
string child_frame_id
geometry_msgs/PoseWithCovariance pose
geometry_msgs/TwistWithCovariance twist
""" + HEADER + """================================================================================
MSG: geometry_msgs/PoseWithCovariance
geometry_msgs/Pose pose
float64[36] covariance
================================================================================
MSG: geometry_msgs/TwistWithCovariance
geometry_msgs/Twist twist
float64[36] covariance
================================================================================
MSG: geometry_msgs/Twist
geometry_msgs/Vector3 linear
geometry_msgs/Vector3 angular
""" + POSE + VECTORS

POSE_STAMPED = """std_msgs/Header header
geometry_msgs/Pose pose
""" + HEADER + POSE + VECTORS

TF_MESSAGE = """geometry_msgs/TransformStamped[] transforms
================================================================================
MSG: geometry_msgs/TransformStamped
std_msgs/Header header
string child_frame_id
geometry_msgs/Transform transform
""" + HEADER + """================================================================================
MSG: geometry_msgs/Transform
geometry_msgs/Vector3 translation
geometry_msgs/Quaternion rotation
""" + VECTORS


class LogError(Exception):
    """A malformed line, with its location."""


def open_log(path):
    with open(path, "rb") as f:
        magic = f.read(2)
    if magic == b"\x1f\x8b":
        return gzip.open(path, "rt", errors="replace")
    return open(path, "rt", errors="replace")


def numbers(fields, start, count, where, what):
    try:
        return [float(v) for v in fields[start:start + count]]
    except ValueError as e:
        raise LogError(f"{where}: {what}: {e}") from None


def parse(line, where):
    """A record of a known line: ("laser", dict) or ("odom", dict); None otherwise."""
    fields = line.split()
    if not fields:
        return None
    tag = fields[0]
    if tag == "FLASER":
        n = int(fields[1])
        if len(fields) != n + 11:
            raise LogError(f"{where}: FLASER: expected {n + 11} fields, got {len(fields)}")
        ranges = numbers(fields, 2, n, where, "range")
        x, y, theta = numbers(fields, 2 + n, 3, where, "robot pose")
        increment = 0.0 if n < 2 else (math.pi / (n - 1) if n % 2 == 1 else math.pi / n)
        return "laser", {
            "ranges": ranges,
            "angle_min": -math.pi / 2,
            "angle_increment": increment,
            "max_range": None,
            "frame": "front_laser",
            "mount": (0.0, 0.0, 0.0),
            "pose": (x, y, theta),
            "stamp": float(fields[n + 10]),
        }
    if tag == "ROBOTLASER1":
        start, _fov, resolution, max_range = numbers(fields, 2, 4, where, "laser parameters")
        n = int(fields[8])
        m = int(fields[9 + n])
        if len(fields) != n + m + 24:
            raise LogError(f"{where}: ROBOTLASER1: expected {n + m + 24} fields, got {len(fields)}")
        ranges = numbers(fields, 9, n, where, "range")
        base = 10 + n + m
        lx, ly, lt, rx, ry, rt = numbers(fields, base, 6, where, "laser and robot poses")
        # The laser pose relative to the robot pose (Pose2::between).
        c, s = math.cos(rt), math.sin(rt)
        dx, dy = lx - rx, ly - ry
        mount = (c * dx + s * dy, -s * dx + c * dy, math.remainder(lt - rt, 2 * math.pi))
        return "laser", {
            "ranges": ranges,
            "angle_min": start,
            "angle_increment": resolution,
            "max_range": max_range if max_range > 0 else None,
            "frame": "robot_laser",
            "mount": mount,
            "pose": (rx, ry, rt),
            "stamp": float(fields[base + 13]),
        }
    if tag == "ODOM":
        if len(fields) != 10:
            raise LogError(f"{where}: ODOM: expected 10 fields, got {len(fields)}")
        x, y, theta, tv, rv = numbers(fields, 1, 5, where, "odometry")
        return "odom", {"pose": (x, y, theta), "tv": tv, "rv": rv, "stamp": float(fields[9])}
    if tag == "RLASER":
        return "rlaser", None
    return None


def records(path, max_lines):
    with open_log(path) as f:
        for number, line in enumerate(f, 1):
            if max_lines and number > max_lines:
                break
            where = f"{path}:{number}"
            try:
                record = parse(line, where)
            except (ValueError, IndexError) as e:
                raise LogError(f"{where}: {e}") from None
            if record is not None:
                yield record


def stamp(t):
    sec = math.floor(t)
    nanosec = min(round((t - sec) * 1e9), 999_999_999)
    return {"sec": sec, "nanosec": nanosec}


def quaternion(yaw):
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}


def pose(x, y, yaw):
    return {"position": {"x": x, "y": y, "z": 0.0}, "orientation": quaternion(yaw)}


def convert(log, out, max_lines=0, compression="zstd"):
    """Writes the bag (chunks compressed with `compression`: zstd, lz4 or none); returns the
    counts of messages by topic."""
    # First pass: the largest reading (the max range of FLASER lines) and the laser mounts.
    largest = 0.0
    mounts = {}
    for kind, record in records(log, max_lines):
        if kind != "laser":
            continue
        finite = [r for r in record["ranges"] if math.isfinite(r)]
        largest = max([largest, *finite])
        frame, mount = record["frame"], record["mount"]
        first = mounts.setdefault(frame, mount)
        if max(abs(a - b) for a, b in zip(first, mount)) > 1e-6:
            raise LogError(f"{log}: the {frame} mount changes from {first} to {mount}: a bag's "
                           "/tf_static holds one")
    counts = {"/scan": 0, "/odom": 0, "/reference_pose": 0, "/tf_static": 0, "RLASER (left out)": 0,
              "ODOM odometry resets (left out)": 0}
    # Written beside the output and renamed when complete: a failure leaves no partial bag.
    partial = f"{out}.partial"
    try:
        write(log, partial, max_lines, largest, mounts, counts, COMPRESSIONS[compression])
        os.replace(partial, out)
    finally:
        if os.path.exists(partial):
            os.remove(partial)
    return counts


def write(log, out, max_lines, largest, mounts, counts, compression):
    """The second pass: writes the messages into `out`."""
    with open(out, "wb") as f:
        writer = Writer(f, compression=compression)
        scan_schema = writer.register_msgdef("sensor_msgs/msg/LaserScan", LASER_SCAN)
        odom_schema = writer.register_msgdef("nav_msgs/msg/Odometry", ODOMETRY)
        pose_schema = writer.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED)
        tf_schema = writer.register_msgdef("tf2_msgs/msg/TFMessage", TF_MESSAGE)
        transforms = [{
            "header": {"stamp": stamp(0.0), "frame_id": "base_link"},
            "child_frame_id": frame,
            "transform": {
                "translation": {"x": x, "y": y, "z": 0.0},
                "rotation": quaternion(yaw),
            },
        } for frame, (x, y, yaw) in sorted(mounts.items())]
        writer.write_message("/tf_static", tf_schema, {"transforms": transforms}, log_time=0)
        counts["/tf_static"] += 1
        log_time = 0
        after_laser = None  # the robot pose of a laser line just read
        reached = None  # the latest stamp in order
        for kind, record in records(log, max_lines):
            if kind == "rlaser":
                counts["RLASER (left out)"] += 1
                continue
            t = record["stamp"]
            scan_pose, after_laser = after_laser, None
            if kind == "laser":
                after_laser = record["pose"]
            elif scan_pose is not None and reached is not None and t < reached - 1.0 and all(
                    abs(a - b) <= 1e-9 * (1.0 + max(abs(a), abs(b)))
                    for a, b in zip(scan_pose, record["pose"])):
                counts["ODOM odometry resets (left out)"] += 1
                continue
            if reached is None or t >= reached - 1.0:
                reached = t if reached is None else max(reached, t)
            log_time = max(log_time, round(t * 1e9))
            if kind == "laser":
                ranges = record["ranges"]
                n = len(ranges)
                max_range = record["max_range"] or largest
                scan = {
                    "header": {"stamp": stamp(t), "frame_id": record["frame"]},
                    "angle_min": record["angle_min"],
                    "angle_max": record["angle_min"] + record["angle_increment"] * (n - 1),
                    "angle_increment": record["angle_increment"],
                    "time_increment": 0.0,
                    "scan_time": 0.0,
                    "range_min": 0.0,
                    "range_max": max_range,
                    "ranges": ranges,
                    "intensities": [],
                }
                writer.write_message("/scan", scan_schema, scan, log_time=log_time)
                reference = {"header": {"stamp": stamp(t), "frame_id": "map"},
                             "pose": pose(*record["pose"])}
                writer.write_message("/reference_pose", pose_schema, reference, log_time=log_time)
                counts["/scan"] += 1
                counts["/reference_pose"] += 1
            else:
                odom = {
                    "header": {"stamp": stamp(t), "frame_id": "odom"},
                    "child_frame_id": "base_link",
                    "pose": {"pose": pose(*record["pose"]), "covariance": [0.0] * 36},
                    "twist": {
                        "twist": {
                            "linear": {"x": record["tv"], "y": 0.0, "z": 0.0},
                            "angular": {"x": 0.0, "y": 0.0, "z": record["rv"]},
                        },
                        "covariance": [0.0] * 36,
                    },
                }
                writer.write_message("/odom", odom_schema, odom, log_time=log_time)
                counts["/odom"] += 1
        writer.finish()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log", help="CARMEN log, plain or gzip")
    parser.add_argument("out", help="the MCAP file to write")
    parser.add_argument("--max-lines", type=int, default=0,
                        help="read only the first N lines of the log (0: all)")
    parser.add_argument("--compression", choices=sorted(COMPRESSIONS), default="zstd",
                        help="chunk compression (default zstd, the writer's default)")
    args = parser.parse_args()
    try:
        counts = convert(args.log, args.out, args.max_lines, args.compression)
    except (LogError, ValueError, IndexError, OSError) as e:
        sys.exit(f"carmen_to_mcap: {e}")
    print(", ".join(f"{topic}: {n}" for topic, n in counts.items() if n))


if __name__ == "__main__":
    main()
