"""Predicted against observed calibration error over phantom seeds.

Reads the comparison.csv of `fusegraph sweep graphs/sweeps/seeds.toml`
and, for each noise level (the variants' conditions and read noise, seeds
pooled), sets each parameter's signed error against the truth (eval.*)
beside the standard deviation the calibration predicted for it
(stereo.*_sd_*): the errors' mean (a bias the noise does not explain), their
RMS and standard deviation over the seeds, the mean predicted standard
deviation, their ratio, and how many errors lie within 1.96 predicted
standard deviations (95 % if the bars are right). Prints a Markdown table.
Standard library only.

    python3 bench/error_bars.py OUT/comparison.csv
"""

import csv
import math
import sys
from collections import defaultdict

# (label, signed error column, predicted standard deviation column)
PARAMETERS = [
    ("left fx, px", "eval.left_fx_error_px", "stereo.left_fx_sd_px"),
    ("left cx, px", "eval.left_cx_error_px", "stereo.left_cx_sd_px"),
    ("right fx, px", "eval.right_fx_error_px", "stereo.right_fx_sd_px"),
    ("baseline, mm", "eval.baseline_signed_error_mm", "stereo.baseline_sd_mm"),
    ("rotation x, deg", "eval.rotation_x_error_deg", "stereo.rotation_x_sd_deg"),
    ("rotation y, deg", "eval.rotation_y_error_deg", "stereo.rotation_y_sd_deg"),
    ("rotation z, deg", "eval.rotation_z_error_deg", "stereo.rotation_z_sd_deg"),
]


def level_of(variant: str) -> str:
    """The variant's name without its seed: NN_SEED_CONDITIONS_NOISE."""
    parts = variant.split("_")
    return " ".join(parts[2:]) if len(parts) > 2 else variant


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    rows = [r for r in csv.DictReader(open(sys.argv[1])) if r.get("status", "done") == "done"]
    levels = defaultdict(list)
    for r in rows:
        levels[level_of(r["variant"])].append(r)
    print("| level | seeds | parameter | error mean | error sd | predicted sd | sd / predicted | within 1.96 predicted sd |")
    print("| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    for level, rs in sorted(levels.items()):
        for label, err_key, sd_key in PARAMETERS:
            pairs = [(float(r[err_key]), float(r[sd_key])) for r in rs if r.get(err_key) and r.get(sd_key)]
            if len(pairs) < 2:
                continue
            errors = [e for e, _ in pairs]
            n = len(errors)
            mean = sum(errors) / n
            sd = math.sqrt(sum((e - mean) ** 2 for e in errors) / (n - 1))
            predicted = sum(s for _, s in pairs) / n
            inside = sum(abs(e) <= 1.96 * s for e, s in pairs)
            print(f"| {level} | {n} | {label} | {mean:.4g} | {sd:.4g} | {predicted:.4g} | "
                  f"{sd / predicted:.2f} | {inside} / {n} |")


if __name__ == "__main__":
    main()
