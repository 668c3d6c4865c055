"""Two builds' main-job figures, paired over the phantom's sensor seeds.

A change to the phantom's pixels moves the main job's figures by its own
effect and by chance: one run's TRE moves by about 13 % between sensor
noise realisations alone (`phantom.generate`'s `sensor_seed`). Run both
builds on the same seeds and the chance mostly cancels in each seed's
difference, so a few seeds tell a 2 % change apart. For each figure prints
the two builds' means, the change of the mean and the change's standard
error (the paired differences' standard deviation over sqrt(seeds)), as a
Markdown table. Standard library only.

    python3 bench/paired_builds.py OLD_FUSEGRAPH NEW_FUSEGRAPH [--seeds 1-10]
        [--graph graphs/fusion.toml] [--set NODE.KEY=VALUE ...] [--out DIR]

`--set` goes to both builds' runs (e.g. `--set phantom.conditions='"lab"'`
or another scene, `--set phantom.seed=2`).

Each run is cold (`--no-cache`); `--out` keeps every run's folder
(default: a temporary one).
"""

import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

# (label, node, metric): the accuracy figures and the stable ones
# beside them.
FIGURES = [
    ("TRE, mm", "evaluate", "tre_mm"),
    ("worst target, mm", "targets", "target_error_max_mm"),
    ("registration RMSE, inliers, mm", "evaluate", "rmse_mm"),
    ("registration RMSE, overlap, mm", "evaluate", "rmse_all_mm"),
    ("markers after ICP, RMSE mm", "evaluate_markers", "rmse_mm"),
    ("camera skin, mean mm", "eval_camera_surface", "mean_mm"),
    ("camera skin, p95 mm", "eval_camera_surface", "p95_mm"),
    ("camera skin, RMS mm", "eval_camera_surface", "rms_mm"),
    ("MRI skin, RMS mm", "eval_surface", "rms_mm"),
    ("calibration RMS, px", "stereo", "rms_px"),
    ("epipolar RMS, px", "eval_calibration", "epipolar_rms_px"),
]


def seeds_of(text):
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def run(build, graph, seed, sets, out):
    cmd = [build, "run", graph, "--no-cache", "--set", f"phantom.sensor_seed={seed}"]
    for assignment in sets:
        cmd += ["--set", assignment]
    cmd += ["--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return json.loads((out / "report.json").read_text())["metrics"]


def figure(metrics, node, name):
    nested = metrics.get(node)
    if isinstance(nested, dict) and name in nested:
        return nested[name]
    return metrics.get(f"{node}.{name}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old")
    parser.add_argument("new")
    parser.add_argument("--seeds", default="1-10", help="sensor seeds, e.g. 1-10")
    parser.add_argument("--graph", default="graphs/fusion.toml")
    parser.add_argument("--set", action="append", default=[], metavar="NODE.KEY=VALUE",
                        help="a parameter for both builds' runs (repeatable)")
    parser.add_argument("--out", help="keep the runs' folders here")
    args = parser.parse_args()
    seeds = seeds_of(args.seeds)
    if len(seeds) < 2:
        sys.exit("--seeds: give at least two, for a standard error")
    root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="paired_"))
    runs = {"old": {}, "new": {}}
    for seed in seeds:
        # Alternating, so a slow spell of the machine falls on both.
        for which, build in (("old", args.old), ("new", args.new)):
            runs[which][seed] = run(build, args.graph, seed, args.set, root / f"{which}_{seed}")
        print(f"sensor seed {seed} done", file=sys.stderr)
    sets = "".join(f" --set {a}" for a in args.set)
    print(f"{len(seeds)} sensor seeds ({args.seeds}), {args.graph}{sets}; runs in {root}\n")
    print("| figure | old | new | change | its standard error |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for label, node, name in FIGURES:
        old = [figure(runs["old"][s], node, name) for s in seeds]
        new = [figure(runs["new"][s], node, name) for s in seeds]
        if None in old or None in new:
            print(f"| {label} | - | - | not in both reports | - |")
            continue
        mean_old, mean_new = statistics.mean(old), statistics.mean(new)
        differences = [b - a for a, b in zip(old, new)]
        se = statistics.stdev(differences) / math.sqrt(len(seeds))
        scale = abs(mean_old) or 1.0
        print(f"| {label} | {mean_old:.4g} | {mean_new:.4g} | "
              f"{100 * (mean_new - mean_old) / scale:+.1f} % | {100 * se / scale:.1f} % |")


if __name__ == "__main__":
    main()
