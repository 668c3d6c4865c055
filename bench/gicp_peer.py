"""small_gicp's GICP per iteration, on the clouds `fusegraph bench icp --out DIR` writes.

`peers.py smallgicp` times each method by the difference of a 10- and a
30-iteration run; small_gicp's GICP converges (and stops, whatever its
epsilons) in about 6 iterations on these clouds, so that difference is
empty. This times runs of 1 and N iterations instead (N, or fewer where it
stops sooner: the figures say how many) and reports (t_N - t_1) / (N - 1), and t_N / N: compare the latter
with ours over the same N (`fusegraph bench icp --iterations N`, whose
figure is its whole run over N, the first iteration's full searches
included), since a converged fit's later iterations cost ours almost
nothing (its nearest-neighbour cache skips them).

Usage: python bench/gicp_peer.py DIR [--iters 7] [--threads 1] [--repeat 3]
(the peers' venv: ../shared/bench/setup-peers.sh)
"""
import argparse
import time

import numpy as np
import open3d as o3d
import small_gicp


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("folder")
    ap.add_argument("--iters", type=int, default=7)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    load = lambda name: np.asarray(o3d.io.read_point_cloud(f"{a.folder}/{name}").points, dtype=np.float64)
    src, tgt = load("source.ply"), load("target.ply")
    T, S = small_gicp.PointCloud(tgt), small_gicp.PointCloud(src)
    t0 = time.perf_counter()
    tree = small_gicp.KdTree(T, num_threads=a.threads)
    small_gicp.estimate_normals_covariances(T, tree, num_neighbors=20, num_threads=a.threads)
    small_gicp.estimate_normals_covariances(S, small_gicp.KdTree(S, num_threads=a.threads), num_neighbors=20,
                                            num_threads=a.threads)
    prep_ms = (time.perf_counter() - t0) * 1e3

    def run(n):
        best, result = float("inf"), None
        for _ in range(a.repeat):
            t = time.perf_counter()
            result = small_gicp.align(T, S, tree, registration_type="GICP", max_correspondence_distance=10.0,
                                      num_threads=a.threads, max_iterations=n, rotation_epsilon=0.0,
                                      translation_epsilon=0.0)
            best = min(best, time.perf_counter() - t)
        return best, result

    t1, r1 = run(1)
    tn, rn = run(a.iters)
    # small_gicp counts the iterations after the first (a run of N reports
    # N - 1) and may stop before N once converged: take the counts it ran.
    done = rn.iterations + 1
    if done < 2:
        raise SystemExit("small_gicp stopped after its first iteration: nothing to time")
    print(f"small_gicp GICP {len(src)} vs {len(tgt)} pts, {a.threads} threads: "
          f"{(tn - t1) * 1e3 / (done - 1):.2f} ms/it over iterations 2-{done}, "
          f"{tn * 1e3 / done:.2f} ms/it over all {done} "
          f"(trees and covariances, 20 neighbours: {prep_ms:.0f} ms; error {rn.error:.4g})")

if __name__ == "__main__":
    main()
