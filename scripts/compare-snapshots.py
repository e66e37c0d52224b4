#!/usr/bin/env python3
"""Compares two output snapshots made by scripts/snapshot.sh, run by run and file by file.

    scripts/compare-snapshots.py OLD NEW

Text outputs (trajectory.tum, map_path.tum, estimates.csv, map.json) must be identical;
metrics.json and consistency.json are compared key by key with timings, the echoed config
and keys present on one side only listed apart (a new key is not a difference of results).
PNG/SVG figures are not compared. Exits 1 when a result differs.
"""
import json
import re
import sys
from pathlib import Path

TIMING = re.compile(r"(time|_s$|_ms$|seconds)")
TEXT = ["trajectory.tum", "map_path.tum", "estimates.csv", "map.json"]


def flatten(value, prefix=""):
    if isinstance(value, dict):
        for k, v in value.items():
            yield from flatten(v, f"{prefix}.{k}" if prefix else k)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from flatten(v, f"{prefix}[{i}]")
    else:
        yield prefix, value


def compare_json(old, new, label):
    a = dict(flatten(json.loads(old.read_text())))
    b = dict(flatten(json.loads(new.read_text())))
    differences, only = [], []
    for key in sorted(set(a) | set(b)):
        leaf = key.split(".")[-1]
        if key.startswith("config") or TIMING.search(leaf):
            continue
        if key not in a or key not in b:
            only.append(f"{label}: {key} only in {'new' if key in b else 'old'}")
        elif a[key] != b[key]:
            differences.append(f"{label}: {key}: {a[key]!r} -> {b[key]!r}")
    return differences, only


def main():
    old_root, new_root = Path(sys.argv[1]), Path(sys.argv[2])
    differences, notes, compared = [], [], 0
    for old_run in sorted(p for p in old_root.iterdir() if p.is_dir()):
        new_run = new_root / old_run.name
        if not new_run.is_dir():
            notes.append(f"{old_run.name}: not in the new snapshot")
            continue
        stages = [d for d in new_run.iterdir() if d.is_dir() and not (old_run / d.name).is_dir()]
        if stages:
            # A post-processing stage that used to be the run itself (em-polygon was an
            # estimator): its map and figures are in its own folder now.
            for stage in stages:
                label = f"{old_run.name}/{stage.name}"
                old_map, new_map = old_run / "map.json", stage / "map.json"
                if old_map.exists() and new_map.exists():
                    d, o = compare_json(old_map, new_map, label + "/map.json")
                    differences += d
                    compared += 1
                d, o = compare_json(old_run / "metrics.json", stage / "metrics.json", label)
                differences += d
                notes.append(f"{label}: {len(o)} keys on one side only (the run's and the stage's metrics)")
                compared += 1
            continue
        for old_file in sorted(old_run.iterdir()):
            new_file = new_run / old_file.name
            label = f"{old_run.name}/{old_file.name}"
            if old_file.suffix == ".json":
                if not new_file.exists():
                    notes.append(f"{label}: missing in the new snapshot")
                    continue
                d, o = compare_json(old_file, new_file, label)
                differences += d
                notes += o
                compared += 1
            elif old_file.name in TEXT:
                if not new_file.exists():
                    differences.append(f"{label}: missing in the new snapshot")
                elif old_file.read_bytes() != new_file.read_bytes():
                    differences.append(f"{label}: differs")
                compared += 1
    print(f"{compared} files compared")
    for line in notes:
        print("note:", line)
    for line in differences:
        print("DIFF:", line)
    sys.exit(1 if differences else 0)


if __name__ == "__main__":
    main()
