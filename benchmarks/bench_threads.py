"""Throughput of a match on 1 and on 2 threads, side by side in one process, and what the structure lets 8-16 cores
expect.

The DublinCity aerial dev half tile (1024 x 512 px) with LiDAR sampled from its GT at 5 % of the pixels (seed 0):
the default match (tubes, riverbed guidance, the LiDAR check, the fusion) and unguided SGM over the whole range;
the Middlebury Cones pair likewise at 5 %. Each run alternates 1 and 2 Numba threads (``numba.set_num_threads``)
and keeps the fastest of 5 per count (warm kernels).

    python benchmarks/bench_threads.py [DATA] --write benchmarks/results_threads.json --docs docs/architecture.md

The projection: SGM's aggregation runs its two passes on two threads whatever the machine (docs/architecture.md,
"Threads"), and so does the LiDAR check's reference (an SGM match at half resolution, most of the check's time);
every other stage is taken to shorten in proportion to the cores (an upper bound). At ``n`` cores:
``t(n) = t_bound(2) + t_rest(2) * 2 / n``.
"""

import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_faults import scenes  # noqa: E402
from datasets import rows_main  # noqa: E402

from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402

BEGIN, END = "<!-- bench_threads: begin -->", "<!-- bench_threads: end -->"
#: the stages whose kernels run on two threads whatever the machine
BOUND = ("aggregation", "lidar_check")
REPEAT = 5


def _runs(data):
    for name, left, right, gt in scenes(data):
        if name not in ("Dublin aerial", "Cones"):
            continue
        sparse = simulate_lidar(gt, 0.05, seed=0)
        vals = sparse[np.isfinite(sparse)]
        yield name, "default (riverbed, tubes, check, fusion)", lambda l=left, r=right, s=sparse: match_pair(l, r, s)
        if name == "Dublin aerial":
            lo, hi = int(np.floor(vals.min())) - 8, int(np.ceil(vals.max())) + 8
            yield name, "unguided SGM, whole range", lambda l=left, r=right: match_pair(l, r, None, lo, hi,
                                                                                        guide="none")


def run(data):
    rows = []
    most = numba.get_num_threads()
    if most < 2:
        raise SystemExit("bench_threads needs 2 Numba threads")
    for scene, label, match in _runs(data):
        best = {}
        for _ in range(REPEAT):
            for n in (1, 2):
                numba.set_num_threads(n)
                t0 = time.perf_counter()
                res = match()
                wall = time.perf_counter() - t0
                if n not in best or res.info["seconds"] < best[n][0]:
                    best[n] = (res.info["seconds"], dict(res.info["stages"]), wall)
        numba.set_num_threads(most)
        s1, s2 = best[1][0], best[2][0]
        bound = sum(best[2][1].get(k, 0.0) for k in BOUND)
        rows.append({"scene": scene, "run": label, "seconds_1": round(s1, 4), "seconds_2": round(s2, 4),
                     "bound_2": round(bound, 4), "stages_1": best[1][1], "stages_2": best[2][1]})
    return rows


def projected(row, n):
    """The speed-up over one thread the structure allows at ``n`` cores (module docstring)."""
    rest = row["seconds_2"] - row["bound_2"]
    return row["seconds_1"] / (row["bound_2"] + rest * 2 / n)


def tables(rows):
    out = ["Fastest of 5 warm runs per count, one process, 2 vCPUs; `bound`: the share of the 2-thread run in SGM's "
           "aggregation and the LiDAR check (its reference is an SGM match), which run on two threads whatever the "
           "machine; the last two columns are projected from that structure (the other stages taken to shorten in "
           "proportion to the cores), not measured.", "",
           "| scene | run | 1 thread s | 2 threads s | speed-up | bound | 8 cores (projected) | 16 cores (projected) |",
           "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['scene']} | {r['run']} | {r['seconds_1']:.3f} | {r['seconds_2']:.3f} | "
                   f"{r['seconds_1'] / r['seconds_2']:.2f} x | {100 * r['bound_2'] / r['seconds_2']:.0f} % | "
                   f"{projected(r, 8):.2f} x | {projected(r, 16):.2f} x |")
    return "\n".join(out)


if __name__ == "__main__":
    rows_main(__doc__, run, tables, BEGIN, END)
