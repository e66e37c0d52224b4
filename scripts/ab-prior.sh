#!/usr/bin/env bash
# Same-run A/B timing of the structure-prior inference: two `slam` binaries run `slam prior`
# (rectangular prior) alternately on the same scan, RUNS times each, and the inference times
# they print ("feasible in ...") are listed with each binary's median and minimum. The two
# binaries must print the same solution (regions, outliers, fit cost, largest correction,
# degrees of freedom); the script says so or stops.
#
#   scripts/ab-prior.sh OLD_SLAM NEW_SLAM [RUNS] [intel:SCAN | square:BEAMS]
#
# Defaults: 10 runs each on Intel scan 0 with a range sigma of 2 cm, as in BENCHMARKS.md
# ("Structure priors"); the log is
# ../shared/datasets/radish-carmen-corrected/intel-corrected.log.gz (or under SLAM_DATA_DIR).
# `square:361` is the bench's simulated square room (361 beams, sigma 1 cm, 3 outliers).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
old=$(realpath "$1")
new=$(realpath "$2")
runs=${3:-10}
case=${4:-intel:0}
datadir=$(realpath -m "${SLAM_DATA_DIR:-$here/../../shared/datasets}")
log=$datadir/radish-carmen-corrected/intel-corrected.log.gz
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

case $case in
  intel:*) data=(--data "carmen:$log" --scan "${case#intel:}" --sigma-range 0.02) ;;
  square:*) data=(--data square --beams "${case#square:}" --sigma-range 0.01 --outliers 3) ;;
  *) echo "unknown case $case (intel:SCAN or square:BEAMS)" >&2; exit 2 ;;
esac

run() { # binary, label
  "$1" prior "${data[@]}" --prior "Rectangular prior" --dof --out "$work/prior.png" \
    > "$work/$2.out"
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
echo "$case, $runs alternating runs each, inference time (ms):"
for label in old new; do
  sort -n "$work/$label.times" | awk -v l="$label" '{ t[NR] = $1 }
    END { printf "%s: median %.1f, min %.1f, all:", l, t[int((NR + 1) / 2)], t[1];
          for (i = 1; i <= NR; i++) printf " %s", t[i]; printf "\n" }'
done
echo "same solution printed by both (regions, outliers, fit cost, degrees of freedom)"
