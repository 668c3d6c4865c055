"""How far the merged set's frame is off, against its predicted spread.

`register.multiview` registers every view onto the first, so the first
view's data's error moves the whole merged set, and `merge.frame_shift_sd_mm`
predicts how far. This script measures it against the truth: it derives a
graph from graphs/fusion.toml that triangulates with the phantom's true rig
(so the calibration's error is out of the way) and writes each view's
adjusted pose and its true one, runs it on the given seeds, and prints, per
seed and over them, the other views' mean misregistration at the targets
(each view's adjusted pose against its true pose relative to the first
view: the frame error the merge carries to every view), the targets' own
errors and the predicted frame shift. Standard library only.

    python3 bench/frame_error.py --seeds 41-55 --out /tmp/frame_lab \\
        --set phantom.conditions=lab --set phantom.read_noise_dn=6

(About 10 s a seed on 2 cores; `--fusegraph` names the binary, default
target/release/fusegraph; `--estimated-rig` keeps the calibrated rig, so
the calibration's error joins the frame error.)
"""

import argparse
import csv
import json
import math
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VIEWS = 6

EXTRA_NODES = """
[node.truerig]
op = "phantom.true_rig"
in.truth = "phantom.truth"

[node.write_poses]
op = "io.write_table"
in.table = "merge.poses"
file = "merge_poses"

[each.view.node.true_pose]
op = "phantom.rig_pose"
in.truth = "phantom.truth"
view = "{view}"
noise_mm = 0.0
noise_deg = 0.0

[each.view.node.write_true_pose]
op = "io.write_transform"
in.transform = "true_pose.pose"
file = "true_pose_{view}"
"""


def true_rig_graph(fusion: str, true_rig: bool = True) -> str:
    """graphs/fusion.toml with every rig input but eval_calibration's taken
    from the phantom's true rig (unless `true_rig` is false), and the poses
    written."""
    lines, table = [], ""
    for line in fusion.splitlines():
        if line.startswith("["):
            table = line.strip()
        if (true_rig and line.strip() == 'in.rig = "stereo.rig"'
                and table != "[node.eval_calibration]"):
            line = 'in.rig = "truerig.rig"'
        lines.append(line)
    return "\n".join(lines) + "\n" + EXTRA_NODES


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def rigid_inverse(m):
    r = [[m[j][i] for j in range(3)] for i in range(3)]
    t = [-sum(r[i][k] * m[k][3] for k in range(3)) for i in range(3)]
    return [r[0] + [t[0]], r[1] + [t[1]], r[2] + [t[2]], [0.0, 0.0, 0.0, 1.0]]


def apply(m, p):
    return [sum(m[i][k] * p[k] for k in range(3)) + m[i][3] for i in range(3)]


def seed_figures(folder: Path):
    """(mean misregistration at the targets, mean target error, predicted
    frame shift), mm, of one run's output folder."""
    true = [json.loads((folder / f"true_pose_{v}.json").read_text())["matrix"] for v in range(VIEWS)]
    adjusted = {}
    for row in csv.DictReader(open(folder / "merge_poses.csv")):
        m = [[float(row[f"m{i}{j}"]) for j in range(4)] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]
        adjusted[int(row["view"])] = m
    targets = list(csv.DictReader(open(folder / "targets_camera.csv")))
    q = [sum(float(t[f"{a}_mm"]) for t in targets) / len(targets) for a in "xyz"]
    misregistration = [0.0, 0.0, 0.0]
    for v in range(1, VIEWS):
        relative = matmul(rigid_inverse(true[0]), true[v])
        moved = apply(matmul(adjusted[v], rigid_inverse(relative)), q)
        for a in range(3):
            misregistration[a] += (moved[a] - q[a]) / (VIEWS - 1)
    metrics = json.loads((folder / "report.json").read_text())["metrics"]
    n = sum(1 for k in metrics if k.startswith("targets.target_") and k.endswith("_error_x_mm"))
    error = [sum(metrics[f"targets.target_{i}_error_{a}_mm"] for i in range(n)) / n for a in "xyz"]
    return misregistration, error, metrics["merge.frame_shift_sd_mm"]


def seeds_of(text: str):
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def rms(values):
    return math.sqrt(sum(v * v for v in values) / len(values))


def correlation(a, b):
    ma, mb = sum(a) / len(a), sum(b) / len(b)
    cov = sum((x - ma) * (y - mb) for x, y in zip(a, b))
    den = math.sqrt(sum((x - ma) ** 2 for x in a) * sum((y - mb) ** 2 for y in b))
    return cov / den if den > 0 else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", required=True, help="first-last, e.g. 41-55")
    ap.add_argument("--out", required=True, type=Path, help="a folder for the runs")
    ap.add_argument("--set", action="append", default=[], help="an override, as fusegraph run --set")
    ap.add_argument("--fusegraph", default=str(ROOT / "target/release/fusegraph"))
    ap.add_argument("--estimated-rig", action="store_true",
                    help="triangulate with the calibrated rig, as the main job does: the "
                         "calibration's error joins the frame error")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    graph = args.out / "fusion_true_rig.toml"
    graph.write_text(true_rig_graph((ROOT / "graphs/fusion.toml").read_text(),
                                    true_rig=not args.estimated_rig))
    rows = []
    for seed in seeds_of(args.seeds):
        folder = args.out / str(seed)
        if not (folder / "report.json").exists():
            command = [args.fusegraph, "run", str(graph), "--no-cache", "--out", str(folder),
                       "--set", f"phantom.seed={seed}"]
            for s in args.set:
                command += ["--set", s]
            run = subprocess.run(command, capture_output=True, text=True)
            if run.returncode != 0:
                sys.exit(f"seed {seed}: fusegraph failed:\n{run.stderr[-2000:]}")
        misregistration, error, predicted = seed_figures(folder)
        rows.append((misregistration, error, predicted))
        print(f"seed {seed}: frame error {[round(x, 3) for x in misregistration]} mm, "
              f"targets' mean error {[round(x, 3) for x in error]} mm, predicted frame shift {predicted:.3f} mm")
    observed = [rms([r[0][a] for r in rows]) for a in range(3)]
    total = math.sqrt(sum(x * x for x in observed))
    predicted = rms([r[2] for r in rows])
    print(f"\n{len(rows)} seeds: frame error RMS {total:.3f} mm "
          f"(x {observed[0]:.3f}, y {observed[1]:.3f}, z {observed[2]:.3f}); "
          f"predicted {predicted:.3f} mm; observed / predicted {total / predicted:.2f}")
    print("correlation with the targets' mean error, x y z: " + ", ".join(
        f"{correlation([r[0][a] for r in rows], [r[1][a] for r in rows]):.2f}" for a in range(3)))


if __name__ == "__main__":
    main()
