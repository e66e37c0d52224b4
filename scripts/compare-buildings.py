#!/usr/bin/env python3
"""Compares two sets of runs of scripts/real-buildings.sh, file by file.

    scripts/real-buildings.sh OLD_BIN CONFIG OLD_DIR "1 2 3" > old.txt
    scripts/real-buildings.sh NEW_BIN CONFIG NEW_DIR "1 2 3" > new.txt
    scripts/compare-buildings.py old.txt[,more.txt] new.txt[,more.txt]

For each log and figure (filter ATE, relocalized ATE, the filter's median scan reading to
wall, doubled length, pose NEES against the reference), prints the median over the files both
sets ran, before -> after, and on how many files the figure went down and up. A file is
LOG-SEED; the tables' "failed" lines are left out (and listed).
"""
import statistics
import sys

# Column of each figure in real-buildings.sh's table (after the file name).
FIGURES = {
    "filter ATE m": 1,
    "reloc ATE m": 9,
    "to wall cm": 4,
    "doubled %": 5,
    "NEES": 8,
}


def load(paths):
    """{file: [columns]} from the tables at the comma-separated `paths`."""
    rows, failed = {}, []
    for path in paths.split(","):
        with open(path) as table:
            for line in table:
                words = line.split()
                if not words or words[0] == "log":
                    continue
                if "failed" in line:
                    failed.append(words[0])
                    continue
                rows[words[0]] = words
    return rows, failed


def number(word):
    try:
        return float(word)
    except ValueError:
        return None


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    (old, old_failed), (new, new_failed) = load(sys.argv[1]), load(sys.argv[2])
    for label, failed in (("before", old_failed), ("after", new_failed)):
        if failed:
            print(f"failed {label}: {' '.join(failed)}")
    common = sorted(set(old) & set(new))
    logs = sorted({name.rsplit("-", 1)[0] for name in common})
    print(f"{'log':14} {'figure':13} {'median before -> after':>26} {'down':>5} {'up':>4} {'files':>6}")
    for log in logs:
        files = [name for name in common if name.rsplit("-", 1)[0] == log]
        for figure, column in FIGURES.items():
            pairs = [(number(old[f][column]), number(new[f][column])) for f in files]
            pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
            if not pairs:
                continue
            before = statistics.median(a for a, _ in pairs)
            after = statistics.median(b for _, b in pairs)
            down = sum(b < a for a, b in pairs)
            up = sum(b > a for a, b in pairs)
            print(f"{log:14} {figure:13} {before:12.3f} -> {after:<10.3f} {down:5d} {up:4d} {len(pairs):6d}")


if __name__ == "__main__":
    main()
