"""What a Python op costs over the same function called directly.

An 800 x 600 colour pair (the phantom's image size) is given to a graph
whose one node is a Python op; the function does a fixed amount of numpy
work and returns an 800 x 600 disparity map. The node's time in the report
(the engine's wall time for the node: taking the GIL, handing the images
over as numpy views, calling, converting and copying the map back) is set
against the function's own time measured inside it, and against calling it
directly. A second op on the same pair returns one number: its overhead is
the fixed part, without the map's copy into the engine (which a value the
engine keeps cannot avoid). Medians over the runs.

    python bench/python_op_overhead.py [runs]     # with the fusegraph package installed
"""

import pathlib
import statistics
import sys
import tempfile
import time

import numpy as np

import fusegraph

GRAPH = """
[node.left]
op = "math.constant"
[node.right]
op = "math.constant"
[node.match]
op = "bench.passthrough"
in.left = "left.image"
in.right = "right.image"
"""


def work(left, right):
    """A stand-in matcher: a grey difference as the 'disparity' (float32)."""
    return (left[..., 1].astype(np.float32) - right[..., 1].astype(np.float32)) * 0.01


inside_ms = []


@fusegraph.op("bench.passthrough", inputs={"left": "Image", "right": "Image"},
              outputs={"disparity": "Disparity"})
def passthrough(left, right):
    t = time.perf_counter()
    d = work(left, right)
    inside_ms.append((time.perf_counter() - t) * 1e3)
    return d


first_inside_ms = []


@fusegraph.op("bench.first_pixel", inputs={"left": "Image", "right": "Image"},
              outputs={"value": "Scalar"})
def first_pixel(left, right):
    t = time.perf_counter()
    v = float(left[0, 0, 0]) + float(right[0, 0, 0])
    first_inside_ms.append((time.perf_counter() - t) * 1e3)
    return v


def node_times(op: str, left, right, runs: int):
    """The node's wall time (ms) in `runs` runs, a new pair each run."""
    times = []
    with tempfile.TemporaryDirectory() as d:
        graph = pathlib.Path(d) / "g.toml"
        graph.write_text(GRAPH.replace("bench.passthrough", op))
        for i in range(runs):
            # A new pair each run: no cache, and nothing reused.
            left[0, 0, 0] = i % 256
            r = fusegraph.run(graph, out=pathlib.Path(d) / "out", no_cache=True, jobs=1,
                              inputs={"left.image": ("Image", left), "right.image": ("Image", right)})
            assert r.ok, r.errors
            times.append(r.nodes["match"]["ms"])
    return times


def main(runs: int = 60) -> None:
    rng = np.random.default_rng(7)
    left = rng.integers(0, 256, (600, 800, 3), dtype=np.uint8)
    right = rng.integers(0, 256, (600, 800, 3), dtype=np.uint8)
    direct = []
    for _ in range(runs):
        t = time.perf_counter()
        work(left, right)
        direct.append((time.perf_counter() - t) * 1e3)
    node = node_times("bench.passthrough", left, right, runs)
    first = node_times("bench.first_pixel", left, right, runs)
    med = statistics.median
    overhead = [n - i for n, i in zip(node, inside_ms)]
    print(f"800 x 600 pair, {runs} runs, medians:")
    print(f"  the function called directly:      {med(direct):7.3f} ms")
    print(f"  the function inside the node:      {med(inside_ms):7.3f} ms")
    print(f"  the node (engine's wall time):     {med(node):7.3f} ms")
    print(f"  overhead, node - inside:                {med(overhead):7.3f} ms "
          f"(p90 {sorted(overhead)[int(0.9 * len(overhead))]:.3f} ms)")
    fixed = [n - i for n, i in zip(first, first_inside_ms)]
    print(f"  fixed overhead (an op returning one number): {med(fixed):7.3f} ms")
    print("  the rest: the 800 x 600 float32 map (1.9 MB) copied into the engine")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:2]))
