"""SimpleITK's ConnectedComponent (26 neighbours) and LabelShapeStatistics on a
mask, best of N: the peer of `fusegraph bench components MASK`. Run with the
peers' venv (../shared/bench/setup-peers.sh); never a dependency of the project
or its tests.

    python bench/sitk_components.py out/mri/otsu_mask.nii.gz [--repeat 5]
"""

import argparse
import time

import SimpleITK as sitk


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("mask")
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    mask = sitk.Cast(sitk.ReadImage(a.mask), sitk.sitkUInt8)
    best_cc = best_stats = float("inf")
    labels = 0
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        cc = sitk.ConnectedComponent(mask, True)
        t1 = time.perf_counter()
        stats = sitk.LabelShapeStatisticsImageFilter()
        stats.Execute(cc)
        labels = stats.GetNumberOfLabels()
        t2 = time.perf_counter()
        best_cc, best_stats = min(best_cc, t1 - t0), min(best_stats, t2 - t1)
    print(
        f"SimpleITK {sitk.Version_VersionString()}, {sitk.ProcessObject.GetGlobalDefaultNumberOfThreads()} threads, "
        f"best of {a.repeat}: ConnectedComponent (26) {best_cc * 1e3:.1f} ms ({labels} labels), "
        f"LabelShapeStatistics {best_stats * 1e3:.1f} ms"
    )


if __name__ == "__main__":
    main()
