"""Rasterisation speed: riverbed's DSM accumulator against plain numpy per-cell aggregation, in one run.

    python benchmarks/bench_dsm.py --write benchmarks/results_dsm_speed.json --docs docs/dsm.md

10 million points random over a 1 km x 1 km UTM-like tile (heights ~ 300 m) onto 0.5 m cells; each method builds
the same grid (checked). ``--write`` stores the rows (the committed result file), ``--docs`` rewrites the table of
docs/dsm.md from it (``tests/test_dsm_doc.py`` checks the doc and the claims it states on the committed rows).
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import rows_main  # noqa: E402

from riverbed_cli.products.dsm import Grid, rasterize  # noqa: E402

BEGIN, END = "<!-- bench_dsm: begin -->", "<!-- bench_dsm: end -->"
POINTS, RESOLUTION = 10_000_000, 0.5


def numpy_max_at(x, y, z, g):
    col = np.floor((x - g.xmin) / g.resolution).astype(np.int64)
    row = np.floor((g.ymax - y) / g.resolution).astype(np.int64)
    out = np.full((g.height, g.width), -np.inf)
    np.maximum.at(out, (row, col), z)
    out[np.isinf(out)] = np.nan
    return out


def numpy_max_sorted(x, y, z, g):
    key = (np.floor((g.ymax - y) / g.resolution).astype(np.int64) * g.width
           + np.floor((x - g.xmin) / g.resolution).astype(np.int64))
    order = np.argsort(key, kind="stable")
    key, zs = key[order], z[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    out = np.full(g.height * g.width, np.nan)
    out[key[starts]] = np.maximum.reduceat(zs, starts)
    return out.reshape(g.height, g.width)


def numpy_mean_bincount(x, y, z, g):
    key = (np.floor((g.ymax - y) / g.resolution).astype(np.int64) * g.width
           + np.floor((x - g.xmin) / g.resolution).astype(np.int64))
    n = g.height * g.width
    with np.errstate(invalid="ignore"):
        return (np.bincount(key, z, n) / np.bincount(key, None, n)).reshape(g.height, g.width)


def numpy_median_sorted(x, y, z, g):
    key = (np.floor((g.ymax - y) / g.resolution).astype(np.int64) * g.width
           + np.floor((x - g.xmin) / g.resolution).astype(np.int64))
    order = np.lexsort((z, key))
    key, zs = key[order], z[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], key.size]
    out = np.full(g.height * g.width, np.nan)
    out[key[starts]] = 0.5 * (zs[starts + (ends - starts - 1) // 2] + zs[starts + (ends - starts) // 2])
    return out.reshape(g.height, g.width)


def timed(fn, *a):
    t = time.perf_counter()
    r = fn(*a)
    return r, time.perf_counter() - t


def run(data=None, points=None):
    """The rows: per aggregation, riverbed's seconds and each numpy baseline's, measured side by side."""
    rng = np.random.default_rng(0)
    n = int(points or POINTS)
    x = 500000 + rng.uniform(0, 1000, n)
    y = 5000000 + rng.uniform(0, 1000, n)
    z = rng.normal(300, 5, n)
    g = Grid.from_bounds(500000, 5000000, 501000, 5001000, RESOLUTION)
    for agg in ("max", "mean", "median", "idw"):  # JIT warm-up
        rasterize(x[:1000], y[:1000], z[:1000], g, agg)
    rows = []
    baselines = {"max": [("np.maximum.at", numpy_max_at), ("argsort + maximum.reduceat", numpy_max_sorted)],
                 "mean": [("bincount", numpy_mean_bincount)], "median": [("lexsort", numpy_median_sorted)],
                 "idw": []}
    for agg, bases in baselines.items():
        ours, t_ours = timed(rasterize, x, y, z, g, agg)
        rows.append({"aggregation": agg, "method": "riverbed", "seconds": round(t_ours, 3), "points": n,
                     "cells": [g.width, g.height]})
        for name, fn in bases:
            ref, t = timed(fn, x, y, z, g)
            assert np.allclose(ours, ref, equal_nan=True, atol=1e-3), f"{agg}: {name} disagrees"
            rows.append({"aggregation": agg, "method": f"numpy {name}", "seconds": round(t, 3), "points": n,
                         "cells": [g.width, g.height]})
    return rows


def tables(rows):
    """The speed table of docs/dsm.md from the rows (the speed-up: a baseline's seconds over riverbed's, same run)."""
    n, (w, h) = rows[0]["points"], rows[0]["cells"]
    ours = {r["aggregation"]: r["seconds"] for r in rows if r["method"] == "riverbed"}
    out = [f"{n / 1e6:g} million points onto {w} x {h} cells, one run:", "",
           "| aggregation | method | seconds | million points / s | riverbed speed-up |", "|---|---|---:|---:|---:|"]
    for r in rows:
        up = "" if r["method"] == "riverbed" else f"{r['seconds'] / ours[r['aggregation']]:.1f}x"
        out.append(f"| {r['aggregation']} | {r['method']} | {r['seconds']:.2f} | {n / r['seconds'] / 1e6:.1f} | {up} |")
    return "\n".join(out)


def main():
    rows_main(__doc__, run, tables, BEGIN, END, options=(("--points", f"points (default {POINTS:,})"),))


if __name__ == "__main__":
    main()
