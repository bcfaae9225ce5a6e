"""Rasterisation speed: riverbed's DSM accumulator against plain numpy per-cell aggregation, in one run.

Usage: python benchmarks/bench_dsm.py [--points 10000000] [--resolution 0.5]

Points are random over a 1 km x 1 km UTM-like tile (heights ~ 300 m); each method builds the same grid.
"""

import argparse
import time

import numpy as np

from riverbed_cli.products.dsm import Grid, rasterize


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


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=10_000_000)
    ap.add_argument("--resolution", type=float, default=0.5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    n = args.points
    x = 500000 + rng.uniform(0, 1000, n)
    y = 5000000 + rng.uniform(0, 1000, n)
    z = rng.normal(300, 5, n)
    g = Grid.from_bounds(500000, 5000000, 501000, 5001000, args.resolution)
    for agg in ("max", "mean", "median", "idw"):  # JIT warm-up
        rasterize(x[:1000], y[:1000], z[:1000], g, agg)
    rows = []
    baselines = {"max": [("np.maximum.at", numpy_max_at), ("argsort + maximum.reduceat", numpy_max_sorted)],
                 "mean": [("bincount", numpy_mean_bincount)], "median": [("lexsort", numpy_median_sorted)],
                 "idw": []}
    for agg, bases in baselines.items():
        ours, t_ours = timed(rasterize, x, y, z, g, agg)
        rows.append((agg, "riverbed", t_ours, None))
        for name, fn in bases:
            ref, t = timed(fn, x, y, z, g)
            assert np.allclose(ours, ref, equal_nan=True, atol=1e-3), f"{agg}: {name} disagrees"
            rows.append((agg, f"numpy {name}", t, t / t_ours))
    print(f"### DSM rasterisation: {n / 1e6:g} million points onto {g.width} x {g.height} cells\n")
    print("| aggregation | method | seconds | million points / s | riverbed speed-up |")
    print("|---|---|---:|---:|---:|")
    for agg, name, t, ratio in rows:
        print(f"| {agg} | {name} | {t:.2f} | {n / t / 1e6:.1f} | {'' if ratio is None else f'{ratio:.1f}x'} |")


if __name__ == "__main__":
    main()
