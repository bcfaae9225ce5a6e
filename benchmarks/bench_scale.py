"""Bounded memory and LiDAR-driven tile ranges on large pairs built on the fly.

Usage: python benchmarks/bench_scale.py [--sizes 10,20,40] [--workdir DIR] [--skip-full]

For each size (megapixels) a rectified pair is generated to tiled TIFFs: a smooth terrain-and-buildings disparity field
from ~20 to ~500 px (slopes below 1 px/px, so the right image is an exact backward warp of the left one), a random
texture, and ~1 % of the pixels as LiDAR (exact GT disparities). Each match runs in a fresh process that reads the
inputs by windows and writes the disparity tile by tile, and reports its peak RSS. On the largest size the full
disparity range is matched too (same process set-up), and OpenCV StereoSGBM runs on one tile it can hold, so the
throughput (million disparity evaluations per second) is compared in the same run.
"""

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from opencv_timer import create_sgbm  # benchmarks/: the same StereoSGBM settings as bench_match

CHILD = r"""
import json, resource, sys, time
from riverbed_cli.runtime import Env
Env().__enter__()  # the riverbed program's process settings (NumPy huge pages, malloc thresholds)
import numpy as np
from riverbed_cli.io.windowed import TiffSink, open_windowed
from riverbed_cli.scale.tiles import match_tiled
from riverbed_cli.matching.pipeline import warm_up
d, lidar_range, rng = sys.argv[1], sys.argv[2] == "1", sys.argv[3]
warm_up()
left, right = open_windowed(d + "/left.tif"), open_windowed(d + "/right.tif")
sparse = open_windowed(d + "/lidar.tif", "disparity")
extra = {"range": rng}
if rng == "map":  # the tubes from a range map (read by windows), the LiDAR guiding the cost
    from riverbed_cli.io.windowed import open_range_map
    extra = {"range": "tube", "range_map": open_range_map(d + "/ranges.tif")}
t = time.perf_counter()
with TiffSink(d + f"/disp_{int(lidar_range)}_{rng}.tif", *left.shape[:2]) as sink:
    r = match_tiled(left, right, sparse, 0, 520, tile="auto", overlap=128, lidar_range=lidar_range, out=sink,
                    **extra)
info = {k: r.info[k] for k in ("tiles", "tile", "disparity_evaluations", "tile_ranges", "window")}
info["seconds"] = time.perf_counter() - t
info["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(info))
"""


def make_pair(folder, megapixels, seed=0, ranges=False):
    """Write left.tif, right.tif, gt.tif, lidar.tif (tiled) for a pair of about ``megapixels`` MP; with ``ranges``
    also ranges.tif, the 2-band range map of the GT +- 4 px (``--range-map``, as a coarse DSM would give)."""
    import rasterio

    W = int(math.sqrt(megapixels * 1e6 * 1.6))
    W -= W % 64
    H = int(megapixels * 1e6 / W)
    rng = np.random.default_rng(seed)
    prof = dict(driver="GTiff", width=W, height=H, count=1, tiled=True, blockxsize=256, blockysize=256,
                compress="deflate")
    # Terrain: a smooth field over the whole frame (slope <= ~0.3 px/px); buildings: plateaus with 0.5 px/px ramps.
    # Every row of x - d(x) is then increasing, so the right image is an exact backward warp of the left one.
    coarse = cv2.resize(rng.uniform(0, 1, (3, 4)).astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC)
    coarse = (coarse - coarse.min()) / max(float(coarse.max() - coarse.min()), 1e-6)
    span = min(400.0, 0.3 * W / 2)
    n_b = max(4, megapixels * 6)
    bx, by = rng.integers(0, W - 400, n_b), rng.integers(0, H - 400, n_b)
    bw, bh, bz = rng.integers(80, 380, n_b), rng.integers(80, 380, n_b), rng.uniform(20, 60, n_b)
    files = {k: rasterio.open(folder / f"{k}.tif", "w", dtype=("uint8" if k in ("left", "right") else "float32"),
                              nodata=(None if k in ("left", "right") else float("nan")), **prof)
             for k in ("left", "right", "gt", "lidar")}
    if ranges:
        files["ranges"] = rasterio.open(folder / "ranges.tif", "w", dtype="float32", nodata=float("nan"),
                                        **{**prof, "count": 2})
    from rasterio.windows import Window

    xs = np.arange(W, dtype=np.float64)
    block = 256
    for y0 in range(0, H, block):
        y1 = min(H, y0 + block)
        d = 20 + span * coarse[y0:y1].astype(np.float64)
        yy = np.arange(y0, y1)[:, None]
        bump = np.zeros_like(d)
        for i in range(n_b):
            dx = np.maximum(np.maximum(bx[i] - xs, xs - (bx[i] + bw[i])), 0)[None, :]
            dy = np.maximum(np.maximum(by[i] - yy, yy - (by[i] + bh[i])), 0)
            bump = np.maximum(bump, bz[i] - 0.5 * np.maximum(dx, dy))
        d = d + bump
        d = np.clip(d, 0, 510)
        tex = cv2.GaussianBlur(rng.uniform(0, 255, (y1 - y0 + 8, W)).astype(np.float32), (0, 0), 1.2)[4:-4]
        tex = np.clip((tex - 128) * 3 + 128, 0, 255)
        right = np.empty_like(tex)
        for r in range(y1 - y0):
            xr = xs - d[r]  # monotonic: slopes < 1
            right[r] = np.interp(xs, xr, tex[r], left=tex[r, 0], right=tex[r, -1])
        lidar = np.where(rng.random(d.shape) < 0.01, d, np.nan).astype(np.float32)
        win = Window(0, y0, W, y1 - y0)
        files["left"].write(tex.astype(np.uint8)[None], window=win)
        files["right"].write(np.clip(right + rng.normal(0, 1.5, right.shape), 0, 255).astype(np.uint8)[None],
                             window=win)
        files["gt"].write(d.astype(np.float32)[None], window=win)
        files["lidar"].write(lidar[None], window=win)
        if ranges:
            files["ranges"].write(np.stack([d - 4, d + 4]).astype(np.float32), window=win)
    for f in files.values():
        f.close()
    return H, W


def run_child(folder, lidar_range, rng="tile"):
    env = dict(os.environ)
    p = subprocess.run([sys.executable, "-c", CHILD, str(folder), "1" if lidar_range else "0", rng],
                       capture_output=True, text=True, env=env)
    if p.returncode:
        sys.exit(f"bench_scale: child failed: {p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def accuracy(folder, name):
    import rasterio

    from riverbed_cli.products.evaluate import evaluate_disparity

    with rasterio.open(folder / name) as a, rasterio.open(folder / "gt.tif") as g, \
            rasterio.open(folder / "lidar.tif") as s:
        # evaluate on a decimated grid to keep memory small
        step = 4
        d, gt, sp = (x.read(1)[::step, ::step] for x in (a, g, s))
    return evaluate_disparity(d, gt, exclude=sp)


def opencv_tile(folder, size=1024, d_range=512):
    import rasterio
    from rasterio.windows import Window

    with rasterio.open(folder / "left.tif") as a, rasterio.open(folder / "right.tif") as b:
        L = a.read(1, window=Window(d_range, 0, size + d_range, size))
        R = b.read(1, window=Window(d_range, 0, size + d_range, size))
    sgbm = create_sgbm(0, d_range, cv2.STEREO_SGBM_MODE_HH)
    sgbm.compute(L[:64], R[:64])
    t = time.perf_counter()
    sgbm.compute(L, R)
    dt = time.perf_counter() - t
    return L.size * d_range / dt / 1e6, dt


#: the markers of docs/tubes.md's scale block
BEGIN, END = "<!-- bench_scale: begin -->", "<!-- bench_scale: end -->"
#: the throughput before tubes the targets compare against (M disparity evaluations per second, nominal)
BEFORE_TUBES = 55


def doc_table(res):
    """docs/tubes.md's block: per size and range mode, time, memory, work and accuracy; then the tubes' throughput
    against the target's 55 M/s."""
    lines = ["| size | ranges | tiles | seconds | peak RSS MiB | evaluations done, M | nominal Mevals/s | "
             "bad3 % / avg px |", "|---|---|---:|---:|---:|---:|---:|---|"]
    for x in res["rows"]:
        r, m = x["run"], x["accuracy"]
        lines.append(f"| {x['mp']} MP | {x['label']} | {r['tiles']} of {r['tile']} | {r['seconds']:.1f} | "
                     f"{r['peak_rss_mib']:.0f} | {r['disparity_evaluations'] / 1e6:.0f} | "
                     f"{x['H'] * x['W'] * 521 / r['seconds'] / 1e6:.0f} | {m['bad3']:.2f} / {m['avg']:.3f} |")
    tubes = [x for x in res["rows"] if x["rng"] == "tube"]
    lines += ["", "The LiDAR tubes' nominal throughput: " + ", ".join(
        f"{x['mp']} MP {x['H'] * x['W'] * 521 / x['run']['seconds'] / 1e6 / BEFORE_TUBES:.0f}x the {BEFORE_TUBES} M/s "
        f"before tubes at {x['run']['peak_rss_mib']:.0f} MiB peak" for x in tubes) + "."]
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="10,20,40", help="megapixels, comma separated")
    ap.add_argument("--workdir", default=None,
                    help="folder for the generated pairs (made if missing; default: the system's temporary folder)")
    ap.add_argument("--skip-full", action="store_true", help="do not match the full range on the largest size")
    ap.add_argument("--ranges", default="tile,tube",
                    help="range modes matched at every size (tile, tube; map: a range map of the GT +- 4 px)")
    ap.add_argument("--write", help="store the rows in this JSON file (benchmarks/results_scale.json)")
    ap.add_argument("--rows", help="take the rows from this JSON file instead of running")
    ap.add_argument("--docs", help="rewrite this Markdown file's block (docs/tubes.md)")
    args = ap.parse_args()
    if args.rows:
        res = json.loads(Path(args.rows).read_text())
        if args.docs:
            from datasets import rewrite_block

            rewrite_block(args.docs, BEGIN, END, doc_table(res))
        print(doc_table(res))
        return
    sizes = [int(s) for s in args.sizes.split(",")]
    if args.workdir:
        Path(args.workdir).mkdir(parents=True, exist_ok=True)  # the pairs go in a temporary folder inside it
    with tempfile.TemporaryDirectory(dir=args.workdir) as tmp:
        rows, kept = [], []
        for mp in sizes:
            folder = Path(tmp) / f"{mp}mp"
            folder.mkdir()
            t = time.perf_counter()
            H, W = make_pair(folder, mp, ranges="map" in args.ranges.split(","))
            gen = time.perf_counter() - t
            for rng in args.ranges.split(","):
                r = run_child(folder, True, rng)
                m = accuracy(folder, f"disp_1_{rng}.tif")
                label = {"tube": "LiDAR tubes", "map": "range map (GT +- 4 px)"}.get(rng, "LiDAR tile ranges")
                rows.append((mp, H, W, label, r, m))
                kept.append({"mp": mp, "H": H, "W": W, "rng": rng, "label": label, "run": r,
                             "accuracy": {k: float(m[k]) for k in ("bad1", "bad3", "avg")}})
                print(f"{mp} MP ({W}x{H}, generated in {gen:.0f} s), range {rng}: {r}", file=sys.stderr, flush=True)
            if mp == max(sizes) and not args.skip_full:
                rf = run_child(folder, False, "full")
                mf = accuracy(folder, "disp_0_full.tif")
                rows.append((mp, H, W, "full range", rf, mf))
                print(f"  full range: {rf}", file=sys.stderr, flush=True)
                cv_mevals, cv_t = opencv_tile(folder)
        print("| size | pixels | ranges | tile | tiles | seconds | peak RSS MiB | Mevals/s done | nominal Mevals/s "
              "(H W 521 / s) | bad3 % | avg px |")
        print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
        for mp, H, W, label, r, m in rows:
            print(f"| {mp} MP | {W}x{H} | {label} | {r['tile']} | {r['tiles']} | {r['seconds']:.1f} | "
                  f"{r['peak_rss_mib']:.0f} | {r['disparity_evaluations'] / r['seconds'] / 1e6:.0f} | "
                  f"{H * W * 521 / r['seconds'] / 1e6:.0f} | {m['bad3']:.2f} | {m['avg']:.3f} |")
        full = [x for x in rows if x[3] == "full range"]
        if full:
            lid = [x for x in rows if x[0] == full[0][0] and x[3] != "full range"][-1]
            speedup = full[0][4]["seconds"] / lid[4]["seconds"]
            print(f"\nLiDAR tile ranges vs full range on {full[0][0]} MP: {speedup:.1f}x "
                  f"faster; OpenCV StereoSGBM MODE_HH on one 1024x1024 tile, 512 disparities: {cv_mevals:.0f} "
                  f"Mevals/s ({cv_t:.1f} s).")
    if args.write:
        Path(args.write).write_text(json.dumps({"sizes": sizes, "ranges": args.ranges, "rows": kept}, indent=1) + "\n")
    if args.docs:
        from datasets import rewrite_block

        rewrite_block(args.docs, BEGIN, END, doc_table({"rows": kept}))


if __name__ == "__main__":
    main()
