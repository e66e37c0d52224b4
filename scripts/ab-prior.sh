#!/usr/bin/env bash
# Same-run A/B timing of the structure-prior inference on real scans: two `slam` binaries
# run `slam prior` alternately on the same scan, RUNS times each, and the inference times
# they print ("feasible in ...") are listed with each binary's median and minimum. The two
# binaries must print the same solution (regions, outliers, fit cost, largest correction,
# degrees of freedom); the script says so or stops.
#
#   scripts/ab-prior.sh OLD_SLAM NEW_SLAM [RUNS] [SCAN]
#
# Defaults: 10 runs each, Intel scan 0, with the rectangular prior and a range sigma of 2 cm
# as in BENCHMARKS.md ("Structure priors"). The log is
# ../shared/datasets/radish-carmen-corrected/intel-corrected.log.gz (or under SLAM_DATA_DIR).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
old=$(realpath "$1")
new=$(realpath "$2")
runs=${3:-10}
scan=${4:-0}
data=$(realpath -m "${SLAM_DATA_DIR:-$here/../../shared/datasets}")
log=$data/radish-carmen-corrected/intel-corrected.log.gz
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

run() { # binary, label
  "$1" prior --data "carmen:$log" --scan "$scan" --prior "Rectangular prior" \
    --sigma-range 0.02 --dof --out "$work/prior.png" > "$work/$2.out"
  # The inference time in ms, from "feasible in 12.34ms" (or s, or µs).
  grep -o ' in [0-9.]*[µm]*s ' "$work/$2.out" | head -n 1 |
    awk '{ v = $2; if (v ~ /µs/) f = 1e-3; else if (v ~ /ms/) f = 1; else f = 1e3;
           sub(/[µm]*s/, "", v); printf "%.2f\n", v * f }' >> "$work/$2.times"
  grep -v ' in [0-9.]*[µm]*s ' "$work/$2.out" | grep -v '^image:' > "$work/$2.solution"
}

for i in $(seq "$runs"); do
  run "$old" old
  run "$new" new
  if ! cmp -s "$work/old.solution" "$work/new.solution"; then
    echo "the two binaries print different solutions:" >&2
    diff "$work/old.solution" "$work/new.solution" >&2 || true
    exit 1
  fi
done
echo "Intel scan $scan, $runs alternating runs each, inference time (ms):"
for label in old new; do
  sort -n "$work/$label.times" | awk -v l="$label" '{ t[NR] = $1 }
    END { printf "%s: median %.1f, min %.1f, all:", l, t[int((NR + 1) / 2)], t[1];
          for (i = 1; i <= NR; i++) printf " %s", t[i]; printf "\n" }'
done
echo "same solution printed by both (regions, outliers, fit cost, degrees of freedom)"
