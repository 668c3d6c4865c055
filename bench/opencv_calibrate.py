"""OpenCV's calibrateCamera x 2 + stereoCalibrate (CALIB_USE_INTRINSIC_GUESS)
on the corners `fusegraph bench stereo-calibration DIR --out OUT` found and
wrote to OUT/pairs.csv, with the same model as calib.stereo_calibrate's
default (k1 k2 p1 p2 free, k3 fixed at 0), best of N: its peer on exactly the
same corners. Run with the peers' venv (../shared/bench/setup-peers.sh); never
a dependency of the project or its tests.

    python bench/opencv_stereo_calibrate.py OUT/pairs.csv [--repeat 5] [--threads 0]
"""

import argparse
import time

import cv2
import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("pairs")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=-1, help="cv2.setNumThreads (-1: OpenCV's default)")
    a = ap.parse_args()
    if a.threads >= 0:
        cv2.setNumThreads(a.threads)
    rows = np.loadtxt(a.pairs, delimiter=",", skiprows=1)
    size = (int(rows[0, 8]), int(rows[0, 9]))
    O, L, R = [], [], []
    for view in np.unique(rows[:, 0]):
        r = rows[rows[:, 0] == view]
        O.append(np.c_[r[:, 2:4], np.zeros(len(r))].astype(np.float32))
        L.append(r[:, 4:6].reshape(-1, 1, 2).astype(np.float32))
        R.append(r[:, 6:8].reshape(-1, 1, 2).astype(np.float32))
    flags = cv2.CALIB_FIX_K3
    best = float("inf")
    for _ in range(a.repeat):
        t = time.perf_counter()
        r1, K1, D1, _, _ = cv2.calibrateCamera(O, L, size, None, None, flags=flags)
        r2, K2, D2, _, _ = cv2.calibrateCamera(O, R, size, None, None, flags=flags)
        rms, K1, D1, K2, D2, Rm, T, _, _ = cv2.stereoCalibrate(
            O, L, R, K1, D1, K2, D2, size, flags=cv2.CALIB_USE_INTRINSIC_GUESS | flags)
        best = min(best, time.perf_counter() - t)
    print(
        f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads: {len(O)} pairs, rms {rms:.6f} px "
        f"(left alone {r1:.6f}, right alone {r2:.6f}); left fx {K1[0, 0]:.4f} fy {K1[1, 1]:.4f} "
        f"cx {K1[0, 2]:.4f} cy {K1[1, 2]:.4f}; baseline {np.linalg.norm(T):.5f} mm"
    )
    print(f"calibrateCamera x 2 + stereoCalibrate, best of {a.repeat}: {best * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
