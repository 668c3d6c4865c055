"""OpenCV's chessboard detection on the same photos as `fusegraph bench chessboard`,
for a side-by-side comparison (never a dependency of fusegraph or its tests).

Usage (python from ../shared/bench/setup-peers.sh):
  opencv_chessboard.py DIR [--glob '*.jpg'] [--pattern 9x6] [--win 5] [--repeat 3]
                       [--ours corners.csv]

Times findChessboardCorners + cornerSubPix (OpenCV's winSize is the half size:
--win 5, i.e. winSize (5, 5), is an 11 x 11 window; --win 2 a 5 x 5 one) per image
on one thread, decoding included, best of --repeat. With --ours (the CSV that
`fusegraph bench chessboard --out` writes) it prints, per image found by both,
the mean and max distance between the corners, and whether the order agrees.
"""
import argparse, collections, glob, os, time
import numpy as np
import cv2


def main():
    p = argparse.ArgumentParser()
    p.add_argument("dir"); p.add_argument("--glob", default="*.jpg"); p.add_argument("--pattern", default="9x6")
    p.add_argument("--win", type=int, default=2, help="cornerSubPix half window (2: 5 x 5)")
    p.add_argument("--repeat", type=int, default=3); p.add_argument("--ours")
    p.add_argument("--square", type=float, default=25.0, help="square size, mm (for --calibrate)")
    p.add_argument("--calibrate", action="store_true", help="also calibrateCamera (k3 fixed) on the boards found")
    a = p.parse_args()
    cv2.setNumThreads(1)
    cols, rows = map(int, a.pattern.lower().split("x"))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    ours = collections.defaultdict(list)
    if a.ours:
        for line in open(a.ours).read().splitlines()[1:]:
            f, k, x, y = line.split(","); ours[f].append((float(x), float(y)))
    files = sorted(glob.glob(os.path.join(a.dir, a.glob)))
    found, total, means, views, size = 0, 0.0, [], [], None
    for f in files:
        best, corners = 1e9, None
        for _ in range(a.repeat):
            t = time.perf_counter()
            img = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
            ok, c = cv2.findChessboardCorners(img, (cols, rows))
            if ok:
                c = cv2.cornerSubPix(img, c, (a.win, a.win), (-1, -1), crit)
            best = min(best, time.perf_counter() - t)
            corners = c.reshape(-1, 2) if ok else None
        total += best; name = os.path.basename(f)
        line = f"{name}: {'found' if corners is not None else 'refused'}, {best*1e3:.1f} ms"
        if corners is not None:
            found += 1; views.append(corners.astype(np.float32)); size = img.shape[::-1]
            if name in ours:
                o = np.array(ours[name])
                d = np.linalg.norm(o - corners, axis=1)
                flipped = np.linalg.norm(o[::-1] - corners, axis=1)
                order = "same order" if d.mean() <= flipped.mean() else "REVERSED order"
                dd = d if d.mean() <= flipped.mean() else flipped
                means.append(dd.mean())
                line += f"; vs ours: {order}, mean {dd.mean():.3f} px, median {np.median(dd):.3f}, max {dd.max():.3f} px"
            else:
                line += "; ours: refused"
        elif name in ours:
            line += "; ours: found"
        print(line)
    summary = f"opencv chessboard: {found} of {len(files)} found; {total/len(files)*1e3:.1f} ms per image on one thread, decoding included"
    if means:
        summary += f"; mean distance to ours {np.mean(means):.3f} px over {len(means)} boards"
    print(summary)
    if a.calibrate and len(views) >= 3:
        objp = np.zeros((cols * rows, 3), np.float32)
        objp[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * a.square
        t = time.perf_counter()
        rms, K, D, _, _ = cv2.calibrateCamera([objp] * len(views), views, size, None, None, flags=cv2.CALIB_FIX_K3)
        ms = (time.perf_counter() - t) * 1e3
        print(f"opencv calibrateCamera (k3 fixed, cornerSubPix {2*a.win+1} x {2*a.win+1}): {len(views)} views; rms {rms:.4f} px; "
              f"fx {K[0,0]:.2f} fy {K[1,1]:.2f} cx {K[0,2]:.2f} cy {K[1,2]:.2f}; k1 {D[0,0]:.4f} k2 {D[0,1]:.4f}; {ms:.0f} ms")


if __name__ == "__main__":
    main()
