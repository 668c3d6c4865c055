"""Predicted against observed target error over phantom seeds.

Reads the comparison.csv of `fusegraph sweep graphs/sweeps/target_seeds.toml`
and, for each noise level (the variants' conditions and read noise, seeds
pooled), sets the targets' observed errors against the truth
(targets.target_*_error_mm) beside what the registration's covariance
predicted for them: how many lie within their predicted 95 % bound (95 %
if the bars are right), the observed RMS error over all targets against the
RMS of the predicted RMS errors, and their ratio. Prints a Markdown table.
Standard library only.

    python3 bench/target_error_bars.py OUT/comparison.csv
"""

import csv
import math
import sys
from collections import defaultdict

from error_bars import level_of


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    rows = [r for r in csv.DictReader(open(sys.argv[1])) if r.get("status", "done") == "done"]
    levels = defaultdict(list)
    for r in rows:
        levels[level_of(r["variant"])].append(r)
    print("| level | seeds | targets | within predicted 95 % bound | observed RMS, mm | predicted RMS, mm | observed / predicted |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for level, rs in sorted(levels.items()):
        observed, predicted, inside = [], [], 0
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
        if not observed:
            continue
        n = len(observed)
        o = math.sqrt(sum(e * e for e in observed) / n)
        p = math.sqrt(sum(x * x for x in predicted) / n)
        print(f"| {level} | {len(rs)} | {n} | {inside} / {n} ({100 * inside / n:.0f} %) | "
              f"{o:.3f} | {p:.3f} | {o / p:.2f} |")


if __name__ == "__main__":
    main()
