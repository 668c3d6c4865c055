"""OpenCV's StereoSGBM as a fusegraph op: the peer becomes a variant of a sweep.

`opencv.sgbm` takes the ports of the built-in matchers (`stereo.sgm`, the
`census.match` plugin), so a graph swaps it in by config alone
(`--set match.op=opencv.sgbm`). The sweeps beside this file compare the three
on the phantom and on the real Middlebury pairs:

    python -m fusegraph sweep python/examples/sgbm_phantom.toml
    python -m fusegraph sweep python/examples/sgbm_middlebury.toml

(each loads this file through its graph's `python` key; the census plugin
needs `cargo build --release -p census-matcher` first). Needs opencv-python
(or opencv-python-headless) beside the fusegraph package.
"""

import math

import numpy as np

import fusegraph

try:
    import cv2
except ImportError as e:  # named in the node's error, not at import
    cv2 = None
    _missing = e


def grey(image):
    """Grey levels 0..255 (uint8) of an (H, W) or (H, W, 3) image, u8 or 0..1 floats."""
    a = np.asarray(image)
    if a.dtype != np.uint8:
        a = np.clip(np.rint(a * 255.0), 0, 255).astype(np.uint8)
    if a.ndim == 3:
        # fusegraph's images are RGB.
        a = cv2.cvtColor(a, cv2.COLOR_RGB2GRAY)
    return a


@fusegraph.op(
    "opencv.sgbm",
    version=1,
    inputs={
        "left": fusegraph.Port("Image", doc="Left rectified image"),
        "right": fusegraph.Port("Image", doc="Right rectified image, same size"),
        "min_disparity": fusegraph.Port("Scalar", optional=True, doc="Lowest disparity, px"),
        "max_disparity": fusegraph.Port("Scalar", optional=True, doc="Highest disparity, px"),
    },
    outputs={"disparity": fusegraph.Port("Disparity", doc="Disparity on the left rectified image, px (NaN: no match)")},
    params={
        "block_px": fusegraph.Param(int, 5, unit="px", min=1, max=11, doc="Matched block side (odd)"),
        "min_disparity_px": fusegraph.Param(int, 0, unit="px", doc="Lowest disparity when no input gives it"),
        "max_disparity_px": fusegraph.Param(int, 64, unit="px", doc="Highest disparity when no input gives it"),
        "uniqueness_pct": fusegraph.Param(int, 10, unit="%", min=0, max=100, doc="Margin of the best cost over the second"),
        "lr_max_diff_px": fusegraph.Param(int, 1, unit="px", doc="Largest left-right disagreement kept (negative: no check)"),
        "mode": fusegraph.Param(str, "sgbm", choices=["sgbm", "hh", "sgbm_3way"], doc="5 paths, 8 paths, or 3-way"),
    },
)
def sgbm(left, right, block_px, min_disparity_px, max_disparity_px, uniqueness_pct,
         lr_max_diff_px, mode, min_disparity=None, max_disparity=None, ctx=None):
    """OpenCV 5 StereoSGBM (P1 = 8 c b^2, P2 = 32 c b^2, as OpenCV's sample), sub-pixel to 1/16 px."""
    if cv2 is None:
        raise ImportError(f"opencv.sgbm needs OpenCV (pip install opencv-python-headless): {_missing}")
    if block_px % 2 == 0:
        raise ValueError(f"block_px = {block_px}: must be odd")
    lo = math.floor(min_disparity) if min_disparity is not None else min_disparity_px
    hi = math.ceil(max_disparity) if max_disparity is not None else max_disparity_px
    count = max(16, 16 * math.ceil((hi - lo + 1) / 16))
    channels = 1
    matcher = cv2.StereoSGBM_create(
        minDisparity=int(lo),
        numDisparities=int(count),
        blockSize=block_px,
        P1=8 * channels * block_px ** 2,
        P2=32 * channels * block_px ** 2,
        disp12MaxDiff=lr_max_diff_px,
        uniquenessRatio=uniqueness_pct,
        mode={"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
              "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY}[mode],
    )
    raw = matcher.compute(grey(left), grey(right))
    disparity = raw.astype(np.float32) / 16.0
    disparity[raw < (lo * 16)] = np.nan
    if ctx is not None:
        ctx.metric("coverage_pct", 100.0 * float(np.isfinite(disparity).mean()))
        ctx.metric("disparities", count)
    return disparity
