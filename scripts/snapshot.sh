#!/usr/bin/env bash
# Runs the commands behind the figures of README.md and BENCHMARKS.md with one `slam` binary
# and keeps every output, so that two commits can be compared output by output:
#
#   scripts/snapshot.sh target/release/slam /tmp/snap-new [quick|all]
#   scripts/compare-snapshots.py /tmp/snap-old /tmp/snap-new
#
# `quick` (the default) runs the built-in world, rb2d, Victoria Park (EKF), MR.CLAM, the EM
# polygon on the Intel lab, the particle filters on the built-in world and a short stretch of
# the structure-prior front-end (a few minutes); `all` adds the 50-seed consistency studies,
# FastSLAM on Victoria Park and IPSLAM on the Intel lab (about 20 minutes). Real-data runs
# are left out when ../shared/datasets (or SLAM_DATA_DIR) is absent.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
bin=$(realpath "$1")
out=$(realpath -m "$2")
mode=${3:-quick}
data=$(realpath -m "${SLAM_DATA_DIR:-$here/../../shared/datasets}")
mkdir -p "$out"
cd "$out"
world=$here/../worlds/rb2d-circle.toml

run() { # name, then slam arguments
  local name=$1; shift
  echo "== $name: slam $*" >&2
  "$bin" "$@" --out "$out/$name" --quiet > "$out/$name.summary" 2> "$out/$name.stderr" || echo "FAILED: $name" >&2
}
config() { printf "%b" "$2" > "$out/$1.toml"; echo "$out/$1.toml"; }

run default run
run seed27 run --seed 27
run split-merge run "$(config split-merge '[frontend]\nwall_segmentation = "split-merge"\n')"
run prior-short run "$(config prior-short '[data]\nmax_events = 2400\n[frontend]\ncamera = false\nwall_segmentation = "prior"\n[frontend.prior]\nprior = "rectangular"\n')"
run fastslam-sim run "$(config fastslam '[estimator]\ntype = "fastslam"\nparticles = 100\n')"
run ipslam-sim run "$(config ipslam '[estimator]\ntype = "ipslam"\n')"
run em-polygon-sim run "$(config em-polygon-ekf '[estimator]\ntype = "ekf"\n[[postprocess]]\ntype = "em-polygon"\nposes = "estimate"\n')"
"$bin" simulate "$world" --out "$out/rb2d" > /dev/null
run rb2d-run run "$(config noplot '[output]\nplots = false\n')" --data "rb2d:$out/rb2d/run.rb2d"
run rb2d-jcbb run "$(config rb2d-jcbb "[data]\nspec = \"world:$world\"\n[estimator]\ntype = \"ekf\"\nassociation = \"jcbb\"\nconfirm_after = 2\n[frontend]\nignore_landmark_ids = true\n[output]\nplots = false\n")"
if [ -d "$data" ]; then
  run vp-ekf run --data "victoria-park:$data/victoria-park"
  run mrclam1 run --data "mrclam:$data/utias-mrclam1:1"
  run intel-polygon run "$(config em-polygon '[estimator]\ntype = "dead-reckoning"\n[[postprocess]]\ntype = "em-polygon"\nposes = "given"\n')" \
    --data "carmen:$data/radish-carmen-corrected/intel-corrected.log.gz"
  run intel-ekf-lo run "$(config intel-ekf-lo "[data]\nspec = \"carmen:$data/radish-carmen-corrected/intel-corrected.log.gz\"\n[data.odometry_from_poses]\n[data.laser_odometry]\n[estimator]\ntype = \"ekf\"\nassociation = \"jcbb\"\n")"
fi
if [ "$mode" = all ]; then
  "$bin" consistency --runs 50 --out "$out/consistency-1" --quiet > "$out/consistency-1.summary" 2>&1 || true
  "$bin" consistency --runs 50 --first-seed 101 --out "$out/consistency-101" --quiet > "$out/consistency-101.summary" 2>&1 || true
  if [ -d "$data" ]; then
    run vp-fastslam run "$(config vp-fastslam '[estimator]\ntype = "fastslam"\nparticles = 100\n')" \
      --data "victoria-park:$data/victoria-park"
    for seed in 1 2 3; do
      run "intel-ipslam-$seed" run "$(config "intel-ipslam-$seed" "[data]\nspec = \"carmen:$data/radish-carmen-corrected/intel-corrected.log.gz\"\nseed = $seed\n[data.odometry_from_poses]\n[data.laser_odometry]\n[estimator]\ntype = \"ipslam\"\nlikelihood_scale = 0.02\nresample_threshold = 0.5\nmax_normal_distance = 0.1\n")"
    done
  fi
fi
echo "snapshot in $out" >&2
