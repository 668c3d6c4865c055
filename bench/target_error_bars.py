"""Predicted against observed target error over phantom seeds.

Reads the comparison.csv of `fusegraph sweep graphs/sweeps/target_seeds.toml`
and, for each noise level (the variants' conditions and read noise, seeds
pooled), sets the targets' observed errors against the truth
(targets.target_*_error_mm) beside what the registration's covariance
predicted for them: how many lie within their predicted 95 % bound (95 %
if the bars are right), the observed RMS error over all targets against the
RMS of the predicted RMS errors, and their ratio. Where the sweep folder
holds each variant's report.json and targets_camera.csv (it does), also the
mean squared Mahalanobis distance of the error vectors under their
predicted covariances (3 if the bars are right; above 3, too narrow) and
the mean error vector over the level (a bias the bars, zero-mean, cannot
hold). Prints Markdown tables. Standard library only.

    python3 bench/target_error_bars.py OUT/comparison.csv
"""

import csv
import json
import math
import os
import sys
from collections import defaultdict

from error_bars import level_of

AXES = "xyz"


def solve3(c, e):
    """c^-1 e for a symmetric 3 x 3 c (Cramer's rule)."""
    def det(m):
        return (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
                - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
                + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
    d = det(c)
    out = []
    for k in range(3):
        m = [[e[r] if col == k else c[r][col] for col in range(3)] for r in range(3)]
        out.append(det(m) / d)
    return out


def error_vectors(folder):
    """Each target's (error vector, covariance) of one variant's folder, or
    nothing where its files are missing."""
    try:
        metrics = json.load(open(os.path.join(folder, "report.json")))["metrics"]
        rows = list(csv.DictReader(open(os.path.join(folder, "targets_camera.csv"))))
    except (OSError, KeyError, ValueError):
        return []
    out = []
    for r in rows:
        key = f"targets.target_{int(float(r['id']))}_error_"
        if not all(key + a + "_mm" in metrics for a in AXES):
            return []

        def cov(a, b):
            a, b = sorted((a, b), key=AXES.index)
            return float(r[f"cov_{a}{b}_mm2"])
        out.append(([metrics[key + a + "_mm"] for a in AXES],
                    [[cov(a, b) for b in AXES] for a in AXES]))
    return out


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    folder = os.path.dirname(os.path.abspath(sys.argv[1]))
    rows = [r for r in csv.DictReader(open(sys.argv[1])) if r.get("status", "done") == "done"]
    levels = defaultdict(list)
    for r in rows:
        levels[level_of(r["variant"])].append(r)
    print("| level | seeds | targets | within predicted 95 % bound | observed RMS, mm | predicted RMS, mm | observed / predicted | mean squared Mahalanobis (3) | mean error x, y, z, mm |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    for level, rs in sorted(levels.items()):
        observed, predicted, inside = [], [], 0
        vectors = []
        for r in rs:
            k = 0
            while f"targets.target_{k}_error_mm" in r and r[f"targets.target_{k}_error_mm"]:
                e = float(r[f"targets.target_{k}_error_mm"])
                p = float(r[f"targets.target_{k}_predicted_tre_mm"])
                b = float(r[f"targets.target_{k}_bound95_mm"])
                observed.append(e)
                predicted.append(p)
                inside += e <= b
                k += 1
            vectors += error_vectors(os.path.join(folder, r["variant"]))
        if not observed:
            continue
        n = len(observed)
        o = math.sqrt(sum(e * e for e in observed) / n)
        p = math.sqrt(sum(x * x for x in predicted) / n)
        if vectors:
            d2 = sum(sum(a * b for a, b in zip(e, solve3(c, e))) for e, c in vectors) / len(vectors)
            mean = [sum(e[i] for e, _ in vectors) / len(vectors) for i in range(3)]
            shape = f"{d2:.2f} | {mean[0]:+.3f}, {mean[1]:+.3f}, {mean[2]:+.3f}"
        else:
            shape = "- | -"
        print(f"| {level} | {len(rs)} | {n} | {inside} / {n} ({100 * inside / n:.0f} %) | "
              f"{o:.3f} | {p:.3f} | {o / p:.2f} | {shape} |")


if __name__ == "__main__":
    main()
