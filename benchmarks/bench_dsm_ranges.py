"""Range maps from a coarse DSM, through the commands as a user runs them (docs/tubes.md, "Range maps from a coarse
DSM").

    python benchmarks/bench_dsm_ranges.py [DATA] [--factors 4,16,48] [--margin 2] [--work DIR]

On the bundled sample block (sample_data/block: synthetic, with a ground-truth DSM and disparity), for each factor
k the ground-truth DSM is averaged over k x k cells (0.2 m -> 0.2 k m), and then, each step a fresh ``riverbed``
process:

1. ``riverbed project coarse.tif pair.yaml`` (the DSM's cells as points) -> sparse disparities;
2. ``riverbed range-map --window auto --margin M`` -> per-pixel ranges;
3. ``riverbed match --guide none`` over the full range 0..63 and with ``--range-map``; ``riverbed densify --method
   linear`` of the DSM's sparse disparities (the coarse DSM alone, no images: the baseline the match must beat);
   ``riverbed match --sparse`` with the DSM's sparse disparities, as if they were LiDAR (the defaults);
4. the block's LiDAR guiding the match (the defaults), and its linear interpolation, for reference.

Errors over the ground truth's pixels (bad3 %, mean px). With DATA (``$RIVERBED_DATA``) holding the Pléiades
Ventoux pair, its SRTM tile is projected through the rectified RPC pair and made into ranges too (no ground truth
there: the ranges' width only).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine

from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.windowed import read_range_map
from riverbed_cli.products.evaluate import evaluate_disparity

BLOCK = Path(__file__).resolve().parents[1] / "sample_data" / "block"
VENTOUX = "satellite_pleiades_ventoux_shareloc/tests/data"
HGT = "dtm/srtm_ventoux/srtm90_non_void_filled/N44E005.hgt"


def riverbed(*args):
    """``riverbed ARGS`` in a fresh process; its ``--json`` output parsed, if asked for."""
    exe = Path(sys.executable).with_name("riverbed")
    cmd = [str(exe) if exe.exists() else "riverbed", *map(str, args)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r.returncode}): {r.stderr.strip()}")
    return json.loads(r.stdout) if "--json" in cmd else None


def coarse_dsm(path, k):
    """The sample block's ground-truth DSM averaged over k x k cells (cells with no value ignored), as a GeoTIFF."""
    with rasterio.open(BLOCK / "gt_dsm.tif") as ds:
        z, t, nodata, crs = ds.read(1).astype(np.float64), ds.transform, ds.nodata, ds.crs
    z[z == nodata] = np.nan
    H, W = z.shape[0] // k * k, z.shape[1] // k * k
    blocks = z[:H, :W].reshape(H // k, k, W // k, k).transpose(0, 2, 1, 3).reshape(H // k, W // k, k * k)
    count = np.isfinite(blocks).sum(axis=2)
    mean = np.where(count > 0, np.nansum(blocks, axis=2) / np.maximum(count, 1), np.nan).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=mean.shape[1], height=mean.shape[0], count=1,
                       dtype="float32", crs=crs, transform=t * Affine.scale(k, k), nodata=np.nan) as ds:
        ds.write(mean, 1)
    return float(t.a * k)


def block(work, factors, margin):
    gt = read_disparity(BLOCK / "gt_disparity.tif")
    known = np.isfinite(gt)
    left, right, pair = BLOCK / "left.png", BLOCK / "right.png", BLOCK / "pair.yaml"

    def err(path):
        e = evaluate_disparity(read_disparity(path), gt)
        return f"{e['bad3']:.2f} / {e['avg']:.3f}"

    print("### Sample block (720 x 540, full range 0..63): unguided census SGM in a coarse DSM's ranges\n")
    print(f"`--window auto --margin {margin}`; bad3 % / avg px over the {int(known.sum())} ground-truth pixels; "
          "seconds from `--json`.\n")
    print("| source | cell m | points in the image | window px | mean width | truth inside % | source alone, "
          "linear | unguided, full range | unguided, in its ranges | its points as LiDAR (defaults) | "
          "match s full / ranges |")
    print("|---|---:|---:|---:|---:|---:|---|---|---|---|---|")
    full = work / "full.tif"
    m_full = riverbed("match", left, right, "--guide", "none", "--min-disp", 0, "--max-disp", 63, "-o", full,
                      "--json", "--overwrite")
    for k in factors:
        dsm, sparse, ranges = work / f"dsm{k}.tif", work / f"sparse{k}.tif", work / f"ranges{k}.tif"
        cell = coarse_dsm(dsm, k)
        p = riverbed("project", dsm, pair, "-o", sparse, "--json", "--overwrite")
        r = riverbed("range-map", sparse, "--window", "auto", "--margin", margin, "--min-disp", 0, "--max-disp", 63,
                     "-o", ranges, "--json", "--overwrite")
        lo, hi = read_range_map(ranges)
        inside = 100 * float(((gt >= lo) & (gt <= hi))[known].mean())
        out, alone = work / f"map{k}.tif", work / f"alone{k}.tif"
        m = riverbed("match", left, right, "--guide", "none", "--min-disp", 0, "--max-disp", 63, "--range-map",
                     ranges, "-o", out, "--json", "--overwrite")
        riverbed("densify", sparse, "-o", alone, "--method", "linear", "--overwrite")
        # the DSM's points guiding the match as LiDAR would (riverbed guide, tubes, fusion)
        riverbed("match", left, right, "--sparse", sparse, "-o", work / f"as_lidar{k}.tif", "--overwrite")
        print(f"| coarse DSM, {k} x {k} cells | {cell:.1f} | {p['kept']} | {r['window']} | {r['mean_width']:.1f} | "
              f"{inside:.1f} | {err(alone)} | {err(full)} | {err(out)} | {err(work / f'as_lidar{k}.tif')} | "
              f"{m_full['seconds']:.3f} / {m['seconds']:.3f} |", flush=True)
    # the block's own LiDAR, for reference: what the defaults do with it, and its interpolation alone
    sparse, guided, alone = work / "lidar_sparse.tif", work / "guided.tif", work / "lidar_alone.tif"
    p = riverbed("project", BLOCK / "lidar.laz", pair, "-o", sparse, "--json", "--overwrite")
    m = riverbed("match", left, right, "--sparse", sparse, "-o", guided, "--json", "--overwrite")
    riverbed("densify", sparse, "-o", alone, "--method", "linear", "--overwrite")
    print(f"| the block's LiDAR ({100 * p['lidar_share']:.2f} % of the image pixels) | | {p['kept']} | | "
          f"{m['tubes']['mean_width']:.1f} (tubes) | | {err(alone)} | {err(full)} | | {err(guided)} | "
          f"{m_full['seconds']:.3f} / {m['seconds']:.3f} |")


def ventoux(data, work):
    base = Path(data) / VENTOUX
    if not base.is_dir():
        return
    rect = base / "rectification"
    riverbed("rectify", "--rpc", rect / "left_image.tif", rect / "left_image.geom", rect / "right_image.tif",
             rect / "right_image.geom", "-o", work / "rect", "--dem", base / HGT, "--vertical", "ellipsoid", "--json")
    pair = work / "rect" / "pair.yaml"
    p = riverbed("project", base / HGT, pair, "-o", work / "srtm.tif", "--crs", "EPSG:4979", "--json")
    lo, hi = (int(np.floor(p["d_range"][0])) - 20, int(np.ceil(p["d_range"][1])) + 20)
    r = riverbed("range-map", work / "srtm.tif", "--window", "auto", "--margin", 14, "-o", work / "ranges.tif",
                 "--json")
    print("\n### Pléiades Ventoux (rectified RPC pair, 613 x 614 at 0.5 m): its SRTM tile (90 m) as ranges\n")
    print(f"{p['points_read']} SRTM posts read, {p['kept']} in the left image (d {p['d_range'][0]:.1f} .. "
          f"{p['d_range'][1]:.1f} px); `--window auto` = {r['window']} px, `--margin 14` (about 20 m at 0.70 px/m): "
          f"ranges {r['mean_width']:.1f} px wide on average over {100 * r['known_share']:.0f} % of the pixels, "
          f"against the {hi - lo + 1} of the SRTM's span +- 20 px. Heights read as ellipsoidal (`--crs EPSG:4979`; "
          "with PROJ's EGM96 grid `--crs EPSG:4326+5773`).")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    ap.add_argument("--factors", default="4,16,48")
    ap.add_argument("--margin", type=float, default=2.0)
    ap.add_argument("--work", default=None)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(a.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        block(work, [int(f) for f in a.factors.split(",")], a.margin)
        ventoux(a.data, work)


if __name__ == "__main__":
    main()
