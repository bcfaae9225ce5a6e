"""Throughput of a match on 1 and on 2 threads, side by side in one process, of one SGM pass on 1 and 2 threads, and
what the structure lets 8-16 cores expect.

The DublinCity aerial dev half tile (1024 x 512 px) with LiDAR sampled from its GT at 5 % of the pixels (seed 0):
the default match (tubes, riverbed guidance, the LiDAR check, the fusion) and unguided SGM over the whole range;
the Middlebury Cones pair likewise at 5 %. Each run alternates 1 and 2 Numba threads (``numba.set_num_threads``)
and keeps the fastest of 5 per count (warm kernels). On 2 threads a match runs its two SGM passes one per thread;
with more, each pass sweeps its rows on half of them (docs/architecture.md, "Threads"). How a pass scales is
measured apart: the forward pass alone (``sgm.sgm_forward_pass``) over the volume each aerial run aggregates, on 1
and 2 threads (fastest of 9).

    python benchmarks/bench_threads.py [DATA] --write benchmarks/results_threads.json --docs docs/architecture.md

The projection: at ``n`` cores each pass has ``n / 2`` threads, and a pass is taken to speed up by the measured
2-thread factor ``s`` at every doubling of its threads (``s ** log2(n / 2)``); the SGM stages (the aggregation and
the LiDAR check, whose reference is an SGM match) shorten by that, every other stage in proportion to the cores
(an upper bound): ``t(n) = t_sgm(2) / s ** log2(n / 2) + t_rest(2) * 2 / n``.
"""

import math
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_faults import scenes  # noqa: E402
from datasets import rows_main  # noqa: E402

from riverbed_cli.matching import sgm  # noqa: E402
from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402

BEGIN, END = "<!-- bench_threads: begin -->", "<!-- bench_threads: end -->"
#: the stages made of SGM passes (the check's reference is an SGM match)
BOUND = ("aggregation", "lidar_check")
REPEAT = 5
PASS_REPEAT = 9


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


def _volume(match):
    # the cost volume and settings the match hands to SGM's aggregation (the first call: the match's own, after the
    # LiDAR check's reference)
    seen = []
    real = sgm.sgm_aggregate_select

    def keep(cost, p1, p2, d_min, paths=8, max_cost=None, tubes=None, **kw):
        seen.append((cost, p1, p2, paths, max_cost, tubes))
        return real(cost, p1, p2, d_min, paths, max_cost, tubes, **kw)

    sgm.sgm_aggregate_select = keep
    try:
        match()
    finally:
        sgm.sgm_aggregate_select = real
    return seen[-1]


def pass_speed(cost, p1, p2, paths, max_cost, tubes):
    """Fastest of PASS_REPEAT forward passes over the volume on 1 and on 2 threads, alternated (s)."""
    best = {}
    for _ in range(PASS_REPEAT):
        for n in (1, 2):
            t0 = time.perf_counter()
            sgm.sgm_forward_pass(cost, p1, p2, paths, max_cost=max_cost, tubes=tubes, threads=n)
            best[n] = min(best.get(n, np.inf), time.perf_counter() - t0)
    return best[1], best[2]


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
        row = {"scene": scene, "run": label, "seconds_1": round(s1, 4), "seconds_2": round(s2, 4),
               "bound_2": round(bound, 4), "stages_1": best[1][1], "stages_2": best[2][1]}
        if scene == "Dublin aerial":
            cost, p1, p2, paths, max_cost, tubes = _volume(match)
            p_1, p_2 = pass_speed(cost, p1, p2, paths, max_cost, tubes)
            row.update(pass_volume=f"{cost.size / 1e6:.1f} M costs, {paths} paths"
                       + (f", tubes of mean width {cost.size / (tubes.shape[0] * tubes.shape[1]):.1f}"
                          if tubes is not None else ", dense"), pass_1=round(p_1, 4), pass_2=round(p_2, 4))
        rows.append(row)
    return rows


def pass_factor(rows, row):
    """The measured 2-thread speed-up of a pass for ``row``: its own volume's, else the aerial run's of its kind."""
    src = row if "pass_1" in row else next(r for r in rows if "pass_1" in r and r["run"] == row["run"])
    return src["pass_1"] / src["pass_2"]


def projected(rows, row, n):
    """The speed-up over one thread the structure allows at ``n`` cores (module docstring)."""
    rest = row["seconds_2"] - row["bound_2"]
    return row["seconds_1"] / (row["bound_2"] / pass_factor(rows, row) ** math.log2(n / 2) + rest * 2 / n)


def tables(rows):
    out = ["Fastest of 5 warm runs per count, one process, 2 vCPUs; `SGM`: the share of the 2-thread run in SGM's "
           "aggregation and the LiDAR check (its reference is an SGM match); `pass x`: one SGM pass over the aerial "
           "run's volume on 2 threads against 1 (Cones: the aerial default's); the last two columns are projected "
           "from these (module docstring of `benchmarks/bench_threads.py`), not measured.", "",
           "| scene | run | 1 thread s | 2 threads s | speed-up | SGM | pass x | 8 cores (projected) "
           "| 16 cores (projected) |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['scene']} | {r['run']} | {r['seconds_1']:.3f} | {r['seconds_2']:.3f} | "
                   f"{r['seconds_1'] / r['seconds_2']:.2f} x | {100 * r['bound_2'] / r['seconds_2']:.0f} % | "
                   f"{pass_factor(rows, r):.2f} x | {projected(rows, r, 8):.2f} x | {projected(rows, r, 16):.2f} x |")
    out += ["", "One SGM pass (the forward one) over the aerial runs' volumes, fastest of 9 per count:", "",
            "| run | volume | 1 thread s | 2 threads s | speed-up |", "|---|---|---:|---:|---:|"]
    for r in rows:
        if "pass_1" in r:
            out.append(f"| {r['run']} | {r['pass_volume']} | {r['pass_1']:.4f} | {r['pass_2']:.4f} | "
                       f"{r['pass_1'] / r['pass_2']:.2f} x |")
    return "\n".join(out)


if __name__ == "__main__":
    rows_main(__doc__, run, tables, BEGIN, END)
