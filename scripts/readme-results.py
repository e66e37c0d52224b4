#!/usr/bin/env python3
"""Regenerates the figures of README.md's results table from the runs that make them.

    scripts/readme-results.py [--slam BIN] [--rows KEY,...] [--check | --write] [--work DIR]

Each row of the table that this script knows is identified by its first cell; the script
runs the row's command(s) with BIN (default target/release/slam), formats the figures and
prints the row's third cell. With --check it compares them with README.md and exits 1 if any
differs (CI runs the cheap rows this way: `--slam target/debug/slam --rows ekf-builtin`);
with --write it replaces them in README.md. The datasets are read from SLAM_DATA_DIR
(default ../shared/datasets beside the repository).

Rows (KEY: what it runs, roughly how long in release on the 2-core machine):
  ekf-builtin        slam run (the built-in world, seed 1)                        ~1 s
  consistency        slam consistency, seeds 1-50 both wall kinds, 101-150 M-space ~5 min
  particle-builtin   slam run with fastslam (100 particles) and ipslam            ~20 s
  rb2d-kfslam        ../shared/peers/bench-ekf-vs-kfslam.sh seeds 1-3 (MRPT)       ~90 s
  victoria-park      slam run --data victoria-park:...                            ~7 s
  victoria-park-fastslam  FastSLAM 2.0 on Victoria Park, 100 and 1000 particles  ~4 min
  em-polygon-intel   the em-polygon stage on the Intel lab's corrected poses       ~3 s
  mrclam             slam run --data mrclam:...:1                                  ~1 s
  structure-prior-intel  slam prior on 24 Intel lab scans (rectangular prior)       ~10 s
  ipslam-intel       IPSLAM on the Intel lab, odometry seeds 1-3 (two settings) and paper settings ~6 min
  carmen-walls       configs/carmen-walls.toml beside MRPT icp-slam and rbpf-slam on the four
                     Radish logs with noisy odometry, seeds 1-3 (bench-laser-vs-mrpt.sh), and
                     on the logs' own odometry                                      ~10 min
                     (also writes WORK/carmen-walls-files.md: a table row per file)
`--rows cheap` is ekf-builtin; `--rows all` (the default) is every row above.

The rb2d and carmen-walls rows install MRPT (Debian mrpt-apps) when missing.

Run times are machine figures: a --check of a row with one (rb2d-kfslam, victoria-park,
victoria-park-fastslam, structure-prior-intel) fails whenever the time moves; read it as "regenerate", not as a
regression.
"""

import argparse
import concurrent.futures
import json
import math
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DATA = Path(os.environ.get("SLAM_DATA_DIR", ROOT.parent / "shared" / "datasets"))


def slam(args, work, name, config=None, extra=()):
    """Runs `slam ARGS... --out WORK/NAME --quiet`; returns the output folder."""
    out = work / name
    command = [ARGS.slam, *args]
    if config is not None:
        path = work / f"{name}.toml"
        path.write_text(config)
        command.insert(2, str(path))
    command += ["--out", str(out), "--quiet", *extra]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        sys.exit(f"readme-results: {' '.join(command)} failed:\n{result.stderr[-2000:]}")
    return out


def metrics(folder):
    return json.loads((folder / "metrics.json").read_text())


def cm(metres):
    return f"{100 * metres:.1f} cm"


def ekf_builtin(work):
    m = metrics(slam(["run"], work, "ekf"))
    return f"{cm(m['ate_rmse_m'])} / {cm(m['map_error_m'])}"


def consistency(work):
    def study(folder, kind):
        report = json.loads((folder / "consistency.json").read_text())
        s = report["representations"][kind]
        return s["mean_nees"], 100 * s["fraction_within_band"]

    both = slam(["consistency", "--runs", "50"], work, "consistency")
    later = slam(
        ["consistency", "--runs", "50", "--first-seed", "101", "--walls", "mspace"],
        work,
        "consistency-101",
    )
    m1, b1 = study(both, "mspace")
    e1, eb1 = study(both, "endpoints")
    m2, b2 = study(later, "mspace")
    return (
        f"M-space {m1:.2f}, {b1:.1f} % (seeds 101-150: {m2:.2f}, {b2:.1f} %); "
        f"naive endpoint walls {e1:.0f}, {eb1:.1f} %"
    )


def particle_builtin(work):
    fs = metrics(
        slam(["run"], work, "fastslam", '[estimator]\ntype = "fastslam"\nparticles = 100\n')
    )
    ip = metrics(slam(["run"], work, "ipslam", '[estimator]\ntype = "ipslam"\n'))
    lines = sum(ip["features"].get("ppca-line", {}).values())
    fe, ie = fs["map_error"], ip["map_error"]
    return (
        f"{cm(fs['ate_rmse_m'])} / {cm(fe['rms_m'])} ({cm(fe['median_m'])}); "
        f"{cm(ip['ate_rmse_m'])} / {ie['rms_m']:.2f} m ({cm(ie['median_m'])}), "
        f"{lines} PPCA lines"
    )


def rb2d_kfslam(work):
    """Our EKF beside MRPT kf-slam on the same rb2d logs (seeds 1-3), by the peers' script."""
    script = ROOT.parent / "shared" / "peers" / "bench-ekf-vs-kfslam.sh"
    ratios, ates = [], []
    for seed in (1, 2, 3):
        # 11 interleaved runs each: with 5 the median of one seed moved by a third between
        # two invocations on an idle machine.
        command = [str(script), str(seed), "1000", "50", str(Path(ARGS.slam).resolve()), "11"]
        result = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
        last = result.stdout.strip().splitlines()[-1:] or [""]
        if result.returncode != 0 or not last[0].startswith("ratio kf-slam/ours"):
            sys.exit(f"readme-results: {' '.join(command)} failed:\n{result.stderr[-2000:]}")
        # "ratio kf-slam/ours (per-step CPU) = R (median), R2 (min); ATE unaligned ours = A m,
        # kf-slam = B m"
        words = last[0].replace(",", " ").replace(";", " ").split()
        ratios.append(float(words[words.index("=") + 1]))
        numbers = [w for w in words if w.replace(".", "", 1).isdigit()]
        ates.append((float(numbers[-2]), float(numbers[-1])))
    ours, theirs = ates[0]
    return (
        f"{cm(ours)} (MRPT kf-slam: {cm(theirs)}), seed 1; per-step CPU "
        f"{min(ratios):.1f}-{max(ratios):.1f} times lower than kf-slam's on the same file in "
        "one run, seeds 1-3 (`../shared/peers/bench-ekf-vs-kfslam.sh SEED`, medians of 11 "
        'interleaved runs; an earlier "ten times" compared runs of different days)'
    )


def victoria_park(work):
    m = metrics(
        slam(["run"], work, "vp", extra=["--data", f"victoria-park:{DATA / 'victoria-park'}"])
    )
    return (
        f"{m['ate_rmse_m']:.2f} m ({m['ate']['median']:.2f} m); "
        f"{m['wall_time_s']:.1f} s for 26 minutes of data"
    )


def victoria_park_fastslam(work):
    data = ["--data", f"victoria-park:{DATA / 'victoria-park'}"]
    runs = [
        metrics(
            slam(
                ["run"],
                work,
                f"vp-fastslam-{n}",
                f'[estimator]\ntype = "fastslam"\nparticles = {n}\nproposal = "improved"\n',
                extra=data,
            )
        )
        for n in (100, 1000)
    ]
    ates = " / ".join(f"{m['ate_rmse_m']:.1f} m" for m in runs)
    ratios = " / ".join(f"{m['wall_time_s'] / 1560:.3f}" for m in runs)
    times = " / ".join(f"{m['wall_time_s']:.0f} s" for m in runs)
    return (
        f"{ates}; {ratios} of real time ({times}, 2 cores; FastSLAM 1.0: see BENCHMARKS.md)"
    )


def em_polygon_intel(work):
    log = DATA / "radish-carmen-corrected" / "intel-corrected.log.gz"
    config = (
        '[estimator]\ntype = "dead-reckoning"\n'
        '[[postprocess]]\ntype = "em-polygon"\nposes = "given"\n'
    )
    bounded = config + "[postprocess.fit]\nmax_mean_distance = 0.05\n"
    fits = [
        metrics(slam(["run"], work, name, text, extra=["--data", f"carmen:{log}"]))[
            "postprocess"
        ]["em-polygon"]
        for name, text in [("em-polygon", config), ("em-polygon-5cm", bounded)]
    ]
    default, compact = (
        f"{f['segments']}; {cm(f['mean_point_to_segment_m'])}; {f['compression_ratio']:.0f}:1"
        for f in fits
    )
    return (
        f"{default}; with `max_mean_distance = 0.05`: {compact} "
        "(the paper: 49, 5 cm, 1455:1 on an outdoor map)"
    )


def structure_prior_intel(work):
    """`slam prior` (rectangular prior, sigma 2 cm) on 24 scans of the Intel lab: the median and
    largest inference time as the command prints it, and how many took at most 50 ms."""
    log = DATA / "radish-carmen-corrected" / "intel-corrected.log.gz"
    scans = list(range(0, 250, 25)) + list(range(250, 901, 50))
    times = []
    for scan in scans:
        command = [
            ARGS.slam, "prior", "--data", f"carmen:{log}", "--scan", str(scan),
            "--sigma-range", "0.02", "--prior", "Rectangular prior",
            "--out", str(work / f"prior-{scan}.png"),
        ]
        result = subprocess.run(command, capture_output=True, text=True)
        if result.returncode != 0:
            sys.exit(f"readme-results: {' '.join(command)} failed:\n{result.stderr}")
        found = re.search(r" in ([0-9.]+)(µs|ms|s) ", result.stdout)
        if found is None:
            sys.exit(f"readme-results: no inference time in: {result.stdout.splitlines()[0]}")
        value, unit = float(found.group(1)), found.group(2)
        times.append(value * {"µs": 1e-3, "ms": 1.0, "s": 1e3}[unit])
    slowest = max(range(len(scans)), key=lambda k: times[k])
    within = sum(t <= 50.0 for t in times)
    return (
        f"median {statistics.median(times):.0f} ms, slowest {times[slowest]:.0f} ms "
        f"(scan {scans[slowest]}); {within} of {len(scans)} in at most 50 ms (one run each; "
        "the machine's speed moves these by up to 2x)"
    )


def mrclam(work):
    m = metrics(
        slam(["run"], work, "mrclam", extra=["--data", f"mrclam:{DATA / 'utias-mrclam1'}:1"])
    )
    e = m["map_error"]
    return (
        f"{e['median_m']:.2f} m ({e['rms_m']:.1f} m: landmarks 11 and 17 come out at each "
        "other's surveyed place, 6 m apart, for robots 1, 2 and 3 alike)"
    )


def ipslam_intel(work):
    log = DATA / "radish-carmen-corrected" / "intel-corrected.log.gz"

    def run(name, seed, estimator):
        config = (
            f'[data]\nspec = "carmen:{log}"\nseed = {seed}\n[data.odometry_from_poses]\n'
            + estimator
        )
        return metrics(slam(["run"], work, name, config))

    tempered = (
        '[data.laser_odometry]\n[estimator]\ntype = "ipslam"\nlikelihood_scale = 0.02\n'
        "resample_threshold = 0.5\nmax_normal_distance = 0.1\n"
    )
    runs = [run(f"ipslam-lo-{seed}", seed, tempered) for seed in (1, 2, 3)]
    paper = run("ipslam-paper-1", 1, '[estimator]\ntype = "ipslam"\n')
    # The real-building laser odometry of configs/carmen-walls.toml and the compact options.
    walls = (ROOT / "configs" / "carmen-walls.toml").read_text()
    odometry = walls[walls.index("[data.laser_odometry]") : walls.index("[estimator]")]
    compact = odometry + (
        '[estimator]\ntype = "ipslam"\nlikelihood_scale = 0.02\nresample_threshold = 0.5\n'
        "max_normal_distance = 0.1\nnew_cluster_min_points = 30\nprune_unconfirmed_after = 10\n"
        "map_merge_max_sigma = 0.07\n"
    )
    compacts = [run(f"ipslam-compact-{seed}", seed, compact) for seed in (1, 2, 3)]

    def clusters(m):
        return sum(m["features"].get("ppca-line", {}).values())

    def doubled(m):
        return 100 * m["map_quality"]["doubled_fraction"]

    ates = " / ".join(f"{m['ate_rmse_m']:.2f}" for m in runs)
    paths = " / ".join(f"{m['map_path_ate_rmse_m']:.2f}" for m in runs)
    counts = [clusters(m) for m in runs]
    fractions = [doubled(m) for m in runs]
    compact_counts = " / ".join(str(clusters(m)) for m in compacts)
    compact_fractions = " / ".join(f"{doubled(m):.1f}" for m in compacts)
    return (
        f"with `[data.laser_odometry]` and the motion proposal, 201 particles, tempered: "
        f"{ates} m (the map particle's path, `map_path.tum`: {paths} m), "
        f"{min(counts)}-{max(counts)} clusters, {min(fractions):.0f}-{max(fractions):.0f} % "
        f"of the line length doubled; the same with `configs/carmen-walls.toml`'s laser "
        f"odometry and the compact options (`new_cluster_min_points = 30`, "
        f"`prune_unconfirmed_after = 10`, `map_merge_max_sigma = 0.07`): "
        + " / ".join(f"{m['ate_rmse_m']:.2f}" for m in compacts)
        + f" m, {compact_counts} clusters, {compact_fractions} % doubled; paper settings "
        f"(seed 1): {paper['ate_rmse_m']:.2f} m, {clusters(paper)} clusters"
    )


def significant(x):
    """Two significant figures, as the CARMEN row prints its metres (0.083, 0.40, 1.0, 27)."""
    if x != x:
        return "nan"
    decimals = 1 - math.floor(math.log10(abs(x))) if x else 2
    return f"{x:.{max(0, decimals)}f}"


def spread(values, unit=significant):
    """`lo-hi` of some figures, or the one figure when they print the same."""
    if not values:
        return "failed"
    lo, hi = unit(min(values)), unit(max(values))
    return lo if lo == hi else f"{lo}-{hi}"


CARMEN_LOGS = (("intel", "Intel lab"), ("fhw", "fhw"), ("freiburg-079", "freiburg-079"), ("acapulco", "acapulco"))


FILE_TABLE_HEAD = (
    "| log | seed | odometry | ours: filter (relocalized) | icp-slam | rbpf-slam "
    "| CPU s: ours / icp / rbpf | walls | length m | point to wall: filter / relocalized "
    "| doubled (same side) |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|\n"
)


def file_row(log, seed, folder, lines, ates):
    """One Markdown row of the per-file table: the peers' script's printed figures (SE(2)-aligned
    ATE in m, CPU s) and ours' `metrics.json` map figures."""
    printed = {}
    for line in lines:
        words = line.split()
        if words and words[0] in ("odometry", "ours", "icp-slam", "rbpf-slam") and len(words) >= 6:
            printed[words[0]] = words  # name, aligned, unaligned, anchored, wall s, CPU s, ...
    quality = json.loads((folder / "ours" / "metrics.json").read_text())["map_quality"]
    cpu = " / ".join(printed.get(name, ["?"] * 6)[5] for name in ("ours", "icp-slam", "rbpf-slam"))
    return (
        f"| {log} | {seed} | {float(printed['odometry'][1]):.3f} "
        f"| **{ates['ours']:.3f}** ({ates['reloc']:.3f}) | {ates['icp-slam']:.3f} "
        f"| {ates['rbpf-slam']:.3f} | {cpu} | {quality['walls']} | {quality['wall_length_m']:.0f} "
        f"| {100 * quality['median_point_to_wall_m']:.1f} / {100 * ates['to_wall']:.1f} cm "
        f"| {100 * quality['doubled_fraction']:.1f} % ({100 * quality['doubled_same_side_fraction']:.1f} %) |\n"
    )


def carmen_walls(work):
    """`configs/carmen-walls.toml` beside MRPT icp-slam and rbpf-slam on the noisy-odometry
    versions of the four Radish corrected logs, seeds 1-3, by the peers' script (one file per
    run, two runs at a time); then the logs' own odometry, ours alone."""
    script = ROOT.parent / "shared" / "peers" / "bench-laser-vs-mrpt.sh"
    config = ROOT / "configs" / "carmen-walls.toml"
    binary = str(Path(ARGS.slam).resolve())

    def beside_mrpt(job):
        log, seed = job
        path = DATA / "radish-carmen-corrected" / f"{log}-corrected.log.gz"
        command = [str(script), str(path), str(seed), str(config), binary]
        result = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
        lines = result.stdout.strip().splitlines()
        folder = next((l.split()[2] for l in lines if l.startswith("work files: ")), None)
        if result.returncode != 0 or folder is None or not lines[-1].startswith("ATE aligned:"):
            sys.exit(f"readme-results: {' '.join(command)} failed:\n{result.stderr[-2000:]}")
        # "ATE aligned: ours = A m; icp-slam = B m; rbpf-slam = C m" (a failed program: "failed")
        ates = {}
        for part in lines[-1].split(":", 1)[1].split(";"):
            name, value = part.split("=")
            word = value.split()[0]
            if word == "failed":
                # A program that wrote no path is an error of the run, not a figure to leave out.
                sys.exit(
                    f"readme-results: {name.strip()} failed on {log} seed {seed} "
                    f"(work files: {folder}):\n{result.stderr[-2000:]}"
                )
            ates[name.strip()] = float(word)
        reloc = json.loads((Path(folder) / "ours" / "relocalize" / "metrics.json").read_text())
        ates["reloc"] = reloc["ate_rmse_after_m"]
        ates["to_wall"] = reloc["median_point_to_wall_after_m"]
        ates["file"] = file_row(log, seed, Path(folder), lines, ates)
        return log, ates

    jobs = [(log, seed) for log, _ in CARMEN_LOGS for seed in (1, 2, 3)]
    # The first run alone: it compiles MRPT's log converter, which two runs at once would both
    # write and execute ("Text file busy").
    results = [beside_mrpt(jobs[0])]
    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
        results += list(pool.map(beside_mrpt, jobs[1:]))

    def figures(log, key):
        return [a[key] for l, a in results if l == log and a[key] is not None]

    table = work / "carmen-walls-files.md"
    table.write_text(FILE_TABLE_HEAD + "".join(a["file"] for _, a in results))
    print(f"carmen-walls: one row per file in {table}", file=sys.stderr)
    files = "; ".join(
        f"{label} {spread(figures(log, 'ours'))} ({spread(figures(log, 'reloc'))}) / "
        f"{spread(figures(log, 'icp-slam'))} / {spread(figures(log, 'rbpf-slam'))} m"
        for log, label in CARMEN_LOGS
    )
    to_wall = ", ".join(
        f"{label} {spread(figures(log, 'to_wall'), lambda x: f'{100 * x:.1f}')}"
        for log, label in CARMEN_LOGS
    )
    own = []
    for log, label in CARMEN_LOGS:
        path = DATA / "radish-carmen-corrected" / f"{log}-corrected.log.gz"
        out = slam(["run", str(config)], work, f"own-{log}", extra=["--data", f"carmen:{path}"])
        reloc = json.loads((out / "relocalize" / "metrics.json").read_text())
        own.append(f"{label.split()[0]} {significant(reloc['ate_rmse_after_m'])}")
    return (
        f"{files} (scan points to walls, median, relocalized: {to_wall} cm; with the logs' own "
        f"odometry: {', '.join(own)} m relocalized)"
    )


# key -> (first cell of the README row, function giving its third cell)
ROWS = {
    "ekf-builtin": ("built-in world, seed 1 (`slam run`)", ekf_builtin),
    "consistency": ("built-in world, 50 seeds (`slam consistency`)", consistency),
    "particle-builtin": (
        'built-in world, `type = "fastslam"` (100 particles) / `"ipslam"` (201)',
        particle_builtin,
    ),
    "rb2d-kfslam": ("rb2d circle log, 1000 steps, 50 landmarks", rb2d_kfslam),
    "victoria-park": ("Victoria Park, whole run", victoria_park),
    "victoria-park-fastslam": (
        'Victoria Park, FastSLAM 2.0 (`proposal = "improved"`) 100 / 1000 particles',
        victoria_park_fastslam,
    ),
    "em-polygon-intel": (
        'Intel lab, corrected poses (`[[postprocess]] type = "em-polygon"`, `poses = "given"`)',
        em_polygon_intel,
    ),
    "mrclam": ("MR.CLAM robot 1", mrclam),
    "structure-prior-intel": (
        "Intel lab, 24 scans (0, 25, ..., 900), `slam prior` with the rectangular prior",
        structure_prior_intel,
    ),
    "ipslam-intel": (
        "Intel lab (Radish corrected log), IPSLAM, odometry from the poses with noise (4.3 m alone)",
        ipslam_intel,
    ),
    "carmen-walls": (
        "Radish CARMEN logs with noisy odometry (seeds 1-3), `configs/carmen-walls.toml`, beside MRPT on the same files",
        carmen_walls,
    ),
}


def cells(line):
    """The cells of a Markdown table row (`\\|` inside a cell kept)."""
    inner = line.strip()[1:-1].replace("\\|", "\0")
    return [c.strip().replace("\0", "\\|") for c in inner.split("|")]


def main():
    global ARGS
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slam", default=str(ROOT / "target" / "release" / "slam"))
    parser.add_argument("--rows", default="all", help="KEY,... or cheap or all")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="exit 1 if README.md differs")
    mode.add_argument("--write", action="store_true", help="rewrite README.md's rows")
    parser.add_argument("--work", help="keep the runs in this folder")
    ARGS = parser.parse_args()
    if not Path(ARGS.slam).is_file():
        sys.exit(f"readme-results: no slam binary at {ARGS.slam} (cargo build --release -p slam-cli)")
    keys = {"all": list(ROWS), "cheap": ["ekf-builtin"]}.get(ARGS.rows, ARGS.rows.split(","))
    unknown = [k for k in keys if k not in ROWS]
    if unknown:
        sys.exit(f"readme-results: unknown rows {unknown}; known: {', '.join(ROWS)}")
    text = README.read_text()
    lines = text.split("\n")
    work = Path(ARGS.work or tempfile.mkdtemp(prefix="readme-results."))
    work.mkdir(parents=True, exist_ok=True)
    differing = []
    for key in keys:
        first, compute = ROWS[key]
        index = next((i for i, l in enumerate(lines) if l.startswith("|") and cells(l)[0] == first), None)
        if index is None:
            sys.exit(f"readme-results: README.md has no results row starting with `{first}`")
        row = cells(lines[index])
        figure = compute(work)
        same = row[2] == figure
        print(f"{key}: {'same' if same else 'differs'}\n  README: {row[2]}\n  run:    {figure}")
        if not same:
            differing.append(key)
            row[2] = figure
            lines[index] = "| " + " | ".join(row) + " |"
    if ARGS.write and differing:
        README.write_text("\n".join(lines))
        print(f"README.md: rewrote {', '.join(differing)}")
    if ARGS.check and differing:
        sys.exit(f"readme-results: README.md disagrees with the runs on {', '.join(differing)}")


if __name__ == "__main__":
    main()
