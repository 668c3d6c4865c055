"""The deformable fit's parameters against the targets' error on held-out seeds.

Reads the comparison.csv of `fusegraph sweep graphs/sweeps/deformable_tuning.toml`
and prints a Markdown table: for each value of the varied deform parameter
and each motion, the targets' mean error over the seeds (each seed's mean
over its lesions) and the worst seed, then over all motions. Standard
library only.

    python3 bench/deformable_tuning.py OUT/comparison.csv [PARAM]

PARAM defaults to deform.stiffness_mm.
"""

import csv
import sys
from collections import defaultdict

from deformable_sweep import overrides


def main(path, param):
    rows = [r for r in csv.DictReader(open(path)) if r["status"] == "done"]
    # value -> motion -> [error per seed]
    table = defaultdict(lambda: defaultdict(list))
    for r in rows:
        o = overrides(r)
        motion = f'{o["phantom.motion"]} {o.get("phantom.motion_peak_mm", "")}'.strip()
        err = float(r["targets.target_error_mm"])
        table[o[param]][motion].append(err)
        table[o[param]]["all"].append(err)
    motions = sorted({m for v in table.values() for m in v if m != "all"}) + ["all"]
    print(f"| {param} | " + " | ".join(f"{m}: mean / worst, mm" for m in motions) + " |")
    print("| ---: |" + " --- |" * len(motions))
    for value in sorted(table, key=float):
        cells = []
        for m in motions:
            errs = table[value][m]
            cells.append(f"{sum(errs) / len(errs):.2f} / {max(errs):.2f}" if errs else "-")
        print(f"| {value} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "deform.stiffness_mm")
