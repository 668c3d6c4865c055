"""OpenCV's calibration on the corners `fusegraph bench camera-calibration
DIR --out OUT` (OUT/views.csv: calibrateCamera) or `fusegraph bench
stereo-calibration DIR --out OUT` (OUT/pairs.csv: calibrateCamera x 2 +
stereoCalibrate with CALIB_USE_INTRINSIC_GUESS) found and wrote, with the same
model as calib.calibrate_camera's and calib.stereo_calibrate's default (k1 k2
p1 p2 free, k3 fixed at 0), best of N: their peer on exactly the same corners.
Run with the peers' venv (../shared/bench/setup-peers.sh); never a dependency
of the project or its tests.

    python bench/opencv_calibrate.py OUT/views.csv|OUT/pairs.csv [--repeat 5] [--threads 1]
"""

import argparse
import time

import cv2
import numpy as np

VIEWS = "view,corner,board_x_mm,board_y_mm,x_px,y_px,width_px,height_px"
PAIRS = "view,corner,board_x_mm,board_y_mm,left_x_px,left_y_px,right_x_px,right_y_px,width_px,height_px"


def best_of(repeat, f):
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("corners")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=-1, help="cv2.setNumThreads (-1: OpenCV's default)")
    a = ap.parse_args()
    if a.threads >= 0:
        cv2.setNumThreads(a.threads)
    header = open(a.corners).readline().strip()
    if header not in (VIEWS, PAIRS):
        raise SystemExit(f"{a.corners}: not a views.csv or pairs.csv of fusegraph bench")
    rows = np.loadtxt(a.corners, delimiter=",", skiprows=1)
    size = (int(rows[0, -2]), int(rows[0, -1]))
    views = [rows[rows[:, 0] == v] for v in np.unique(rows[:, 0])]
    O = [np.c_[r[:, 2:4], np.zeros(len(r))].astype(np.float32) for r in views]
    image = lambda c: [r[:, c:c + 2].reshape(-1, 1, 2).astype(np.float32) for r in views]
    flags = cv2.CALIB_FIX_K3
    who = f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads"
    if header == VIEWS:
        I = image(4)
        t, (rms, K, D, _, _) = best_of(a.repeat, lambda: cv2.calibrateCamera(O, I, size, None, None, flags=flags))
        print(f"{who}: {len(O)} views, rms {rms:.6f} px; fx {K[0, 0]:.4f} fy {K[1, 1]:.4f} "
              f"cx {K[0, 2]:.4f} cy {K[1, 2]:.4f}; k1 {D[0, 0]:.6f} k2 {D[0, 1]:.6f}")
        # Each parameter's standard deviation (calibrateCameraExtended, not timed).
        _, _, _, _, _, sd, _, _ = cv2.calibrateCameraExtended(O, I, size, None, None, flags=flags)
        sd = sd.ravel()
        print(f"standard deviations (calibrateCameraExtended): fx {sd[0]:.4f} fy {sd[1]:.4f} "
              f"cx {sd[2]:.4f} cy {sd[3]:.4f} px; k1 {sd[4]:.6f} k2 {sd[5]:.6f} p1 {sd[6]:.7f} p2 {sd[7]:.7f}")
        print(f"calibrateCamera, best of {a.repeat}: {t * 1e3:.1f} ms")
        return
    L, R = image(4), image(6)

    def stereo():
        r1, K1, D1, _, _ = cv2.calibrateCamera(O, L, size, None, None, flags=flags)
        r2, K2, D2, _, _ = cv2.calibrateCamera(O, R, size, None, None, flags=flags)
        out = cv2.stereoCalibrate(O, L, R, K1, D1, K2, D2, size, flags=cv2.CALIB_USE_INTRINSIC_GUESS | flags)
        return r1, r2, out

    t, (r1, r2, (rms, K1, D1, K2, D2, Rm, T, _, _)) = best_of(a.repeat, stereo)
    print(f"{who}: {len(O)} pairs, rms {rms:.6f} px (left alone {r1:.6f}, right alone {r2:.6f}); "
          f"left fx {K1[0, 0]:.4f} fy {K1[1, 1]:.4f} cx {K1[0, 2]:.4f} cy {K1[1, 2]:.4f}; "
          f"baseline {np.linalg.norm(T):.5f} mm")
    print(f"calibrateCamera x 2 + stereoCalibrate, best of {a.repeat}: {t * 1e3:.1f} ms")
    # Each camera's standard deviations alone (calibrateCameraExtended, not timed).
    for name, I in (("left", L), ("right", R)):
        sd = cv2.calibrateCameraExtended(O, I, size, None, None, flags=flags)[5].ravel()
        print(f"{name} camera's standard deviations alone (calibrateCameraExtended): fx {sd[0]:.4f} "
              f"fy {sd[1]:.4f} cx {sd[2]:.4f} cy {sd[3]:.4f} px; k1 {sd[4]:.6f}")


if __name__ == "__main__":
    main()
