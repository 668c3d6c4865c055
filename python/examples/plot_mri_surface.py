"""A run's mesh and markers as numpy arrays, plotted with matplotlib, as a
notebook user would: the MRI branch on the small phantom, its skin surface
and the marker centres it found.

    python python/examples/plot_mri_surface.py [figure.png]

Needs matplotlib beside the fusegraph package.
"""

import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import fusegraph  # noqa: E402

REPO = pathlib.Path(__file__).resolve().parents[2]


def main(figure: str = "mri_surface.png") -> None:
    r = fusegraph.run(REPO / "graphs" / "mri.toml", set={"phantom.size": "small"})
    if not r.ok:
        sys.exit(f"the run failed: {r.errors}")
    mesh = r["surface.mesh"]  # vertices (N, 3) mm, LPS; triangles (M, 3)
    markers = r["centroids.markers"]  # positions_mm (K, 3), ids (K,)
    print(f"{len(mesh.vertices)} vertices, {len(mesh.triangles)} triangles, "
          f"{len(markers.ids)} markers; mean marker error "
          f"{r.metrics['eval_markers.mean_error_mm']:.3f} mm")
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot_trisurf(v[:, 0], v[:, 1], v[:, 2], triangles=t, color="#d9b8a6",
                    alpha=0.35, linewidth=0)
    p = np.asarray(markers.positions_mm)
    ax.scatter(p[:, 0], p[:, 1], p[:, 2], color="#1b7837", s=30, depthshade=False,
               label="markers found")
    for (x, y, z), i in zip(p, markers.ids):
        ax.text(x, y, z, f" {i}", fontsize=8)
    ax.set_xlabel("x (L), mm")
    ax.set_ylabel("y (P), mm")
    ax.set_zlabel("z (S), mm")
    ax.set_box_aspect(np.ptp(v, axis=0))
    ax.legend(loc="upper left")
    ax.set_title("MRI skin surface and markers (small phantom)")
    fig.savefig(figure, dpi=120, bbox_inches="tight")
    print(f"figure: {figure}")


if __name__ == "__main__":
    main(*sys.argv[1:2])
