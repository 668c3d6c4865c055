"""The dense chain's disparity bias over phantom seeds.

Reads the comparison.csv of `fusegraph sweep graphs/sweeps/disparity_bias.toml`
and prints a Markdown table: for each level (conditions, read noise, SGM
paths; seeds pooled) the median signed disparity error out of stereo.sgm and
after the whole chain, each the mean over a job's views, their mean over the
seeds, and the whole chain's RMS over the seeds (what register.icp's
matcher_bias_sd_px stands for). Standard library only.

    python3 bench/disparity_bias.py OUT/comparison.csv
"""

import csv
import math
import sys
from collections import defaultdict


def overrides(row):
    """The variant's overrides as a dict (`a.b=v; c.d=w`)."""
    return dict(p.strip().split("=", 1) for p in row["overrides"].split(";") if "=" in p)


def view_mean(row, node):
    """Mean over the views of `node_<view>.median_signed_px`, or None."""
    values = [float(v) for k, v in row.items() if k.startswith(node + "_") and k.endswith(".median_signed_px") and v]
    return sum(values) / len(values) if values else None


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    levels = defaultdict(list)
    for row in csv.DictReader(open(sys.argv[1])):
        if row.get("status", "done") != "done":
            continue
        o = overrides(row)
        key = (o.get("phantom.conditions", "?"), o.get("phantom.read_noise_dn", "?"), o.get("match.paths", "?"))
        sgm, final = view_mean(row, "e_sgm"), view_mean(row, "e_final")
        if sgm is not None and final is not None:
            levels[key].append((sgm, final))
    print("| conditions | read noise, DN | SGM paths | seeds | SGM, mean px | whole chain, mean px | whole chain, RMS px |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    pooled = defaultdict(list)
    for key, rows in sorted(levels.items()):
        finals = [f for _, f in rows]
        pooled[key[2]] += finals
        rms = math.sqrt(sum(f * f for f in finals) / len(finals))
        print(f"| {key[0]} | {key[1]} | {key[2]} | {len(rows)} | {sum(s for s, _ in rows) / len(rows):+.4f} | "
              f"{sum(finals) / len(finals):+.4f} | {rms:.4f} |")
    for paths, finals in sorted(pooled.items()):
        print(f"\nPooled, {paths} paths: whole chain RMS {math.sqrt(sum(f * f for f in finals) / len(finals)):.4f} px")


if __name__ == "__main__":
    main()
