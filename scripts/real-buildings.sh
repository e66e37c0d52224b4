#!/usr/bin/env bash
# Our `slam` alone on the noisy-odometry versions of the four Radish corrected logs (the files
# ../shared/peers/bench-laser-vs-mrpt.sh makes, without MRPT), two runs at a time, and one
# table: SE(2)-aligned ATE against the corrected poses and the map figures of
# `metrics.json` (`map_quality`), with each run's user CPU seconds and the filter's pose NEES
# per degree of freedom against the reference poses (`nees_reference`); where the config has a
# `relocalize` stage, its ATE and median scan-reading-to-wall distance too (`reloc` columns);
# and how far apart the passes over the same places lie (`revisit_consistency`, median, cm)
# placed by the filter's poses, the relocalized ones and the log's reference poses.
#
#   scripts/real-buildings.sh SLAM_BIN CONFIG OUT_DIR [SEEDS="1 2 3"] [LOGS="intel fhw freiburg-079 acapulco"]
#
# The noisy logs are written once into OUT_DIR/logs by ../shared/peers/noisy_carmen.py (5 % of
# distance + 5 mm, 5 % of turn + 0.02 rad/m + 0.002 rad); the corrected logs are read from
# SLAM_DATA_DIR or ../shared/datasets. Each run's outputs stay in OUT_DIR/LOG-SEED.
# scripts/compare-buildings.py compares two such tables (two binaries or configs) file by file.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
bin=$(realpath "$1"); config=$(realpath "$2"); out=$(realpath -m "$3")
seeds=${4:-"1 2 3"}; logs=${5:-"intel fhw freiburg-079 acapulco"}
data=$(realpath -m "${SLAM_DATA_DIR:-$here/../../shared/datasets}")/radish-carmen-corrected
peers=$(realpath -m "$here/../../shared/peers")
mkdir -p "$out/logs"
runs=()
for log in $logs; do
  for seed in $seeds; do
    name=$log-$seed
    [ -s "$out/logs/$name.log" ] || python3 "$peers/noisy_carmen.py" "$data/$log-corrected.log.gz" \
      "$out/logs/$name.log" --seed "$seed" > /dev/null
    runs+=("$name")
  done
done
printf '%s\n' "${runs[@]}" | xargs -P 2 -I{} sh -c \
  "/usr/bin/time -f %U -o '$out/{}.cpu' '$bin' run '$config' --data 'carmen:$out/logs/{}.log' --out '$out/{}' --quiet > '$out/{}.summary' 2> '$out/{}.stderr' || echo 'slam failed on {}: see $out/{}.stderr' >&2"
python3 - "$out" "${runs[@]}" <<'PY'
import json, sys
out = sys.argv[1]
print(f"{'log':18} {'ATE m':>7} {'walls':>6} {'length m':>9} {'to wall cm':>10} {'doubled %':>10} {'same side %':>12} {'CPU s':>7} {'NEES':>6} {'reloc ATE m':>11} {'reloc cm':>8} {'passes cm: filter / reloc / reference':>38}")
def cm(figure):
    return f"{100 * figure['median_m']:.2f}" if figure else "-"
for name in sys.argv[2:]:
    try:
        m = json.load(open(f"{out}/{name}/metrics.json"))
        q = m.get("map_quality") or {}
        cpu = open(f"{out}/{name}.cpu").read().split()[-1]
        passes = m.get("revisit_consistency") or {}
        nees = (m.get("nees_reference") or {}).get("mean_per_dof", float("nan"))
        after = "-"
        try:
            r = json.load(open(f"{out}/{name}/relocalize/metrics.json"))
            reloc = f"{r['ate_rmse_after_m']:11.3f} {100 * r['median_point_to_wall_after_m']:8.2f}"
            after = cm(r.get("revisits_after"))
        except (OSError, KeyError, TypeError):
            reloc = f"{'-':>11} {'-':>8}"
        print(f"{name:18} {m['ate_rmse_m']:7.3f} {q.get('walls', 0):6d} {q.get('wall_length_m', 0):9.0f} "
              f"{100 * q.get('median_point_to_wall_m', float('nan')):10.2f} {100 * q.get('doubled_fraction', float('nan')):10.1f} "
              f"{100 * q.get('doubled_same_side_fraction', float('nan')):12.1f} {cpu:>7} {nees:6.1f} {reloc} "
              f"{cm(passes.get('estimate')) + ' / ' + after + ' / ' + cm(passes.get('reference')):>38}")
    except (OSError, KeyError, ValueError) as e:
        print(f"{name:18} failed ({e})")
PY
