#!/usr/bin/env bash
# Same-run A/B of two `slam` binaries (or any two programs) on the same arguments: each runs
# RUNS times, alternated (A, B, A, B, ...), and the CPU time (user + sys, microsecond
# resolution, ../shared/peers/cputime.py) of every whole process is listed with each
# binary's median and minimum.
#
#   scripts/ab-cpu.sh RUNS OLD NEW -- ARGS...
#
# e.g. scripts/ab-cpu.sh 7 /tmp/slam-old target/release/slam -- run --data \
#        victoria-park:../shared/datasets/victoria-park --out /tmp/vp --quiet
# Both binaries write to the same --out folder in turn; compare their outputs separately.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
CPUTIME=${CPUTIME:-$HERE/../../shared/peers/cputime.py}
die() { echo "ab-cpu.sh: $*" >&2; exit 1; }
[ $# -ge 4 ] && [ "$4" = "--" ] || die "usage: ab-cpu.sh RUNS OLD NEW -- ARGS..."
RUNS=$1; OLD=$2; NEW=$3; shift 4
[ -f "$CPUTIME" ] || die "no cputime.py at $CPUTIME (set CPUTIME)"
for b in "$OLD" "$NEW"; do [ -x "$b" ] || die "not an executable: $b"; done
for _ in $(seq "$RUNS"); do
  for label in old new; do
    bin=$OLD; [ "$label" = new ] && bin=$NEW
    cpu=$(python3 "$CPUTIME" -- "$bin" "$@") || die "$label run failed: $bin $*"
    echo "$label ${cpu%% *}"
  done
done | python3 -c '
import statistics as st, sys
runs = {}
for line in sys.stdin:
    label, cpu = line.split()
    runs.setdefault(label, []).append(float(cpu))
for label, values in runs.items():
    listed = " ".join(f"{v:.4f}" for v in values)
    print(f"{label}: median {st.median(values):.4f} s, min {min(values):.4f} s, all: {listed}")
'
