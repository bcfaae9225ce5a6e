"""Does fusion pay in the DSM? DSMs from riverbed-guided and from unguided disparities against the ground-truth DSM.

Usage: python benchmarks/bench_fusion.py DATA_DIR [--sample sample_data/block] [--docs docs]

* Middlebury dev scenes, camera frame as world: a nadir-like frame (x right, y up, height = -depth) with a made-up
  but plausible half-size calibration (f = 1870 px, B = 0.16 m, doffs = 100 px: depths ~1.5-2.5 m). LiDAR is
  simulated by sampling 5 % of the GT (seed 0). The GT DSM is rasterised from the GT disparity on the same grid.
* The sample aerial block (``--sample``): the LAZ is projected with ``riverbed project``, matched guided and
  unguided, and each DSM is compared with the block's ground-truth DSM.

Prints a markdown table (RMSE, NMAD, share of cells off by more than 3 x GSD, completeness) and writes side-by-side
PNGs (GT | unguided | riverbed) into --docs.
"""

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import DEV_SCENES, middlebury  # noqa: E402

from riverbed_cli.geometry.cameras import PairGeometry  # noqa: E402
from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.dsm import Grid, build_dsm  # noqa: E402
from riverbed_cli.products.dsm_compare import compare_dsm  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402


def middlebury_nadir_pair(width, height, f=1870.0, baseline=0.16, doffs=100.0):
    """Rectified pair looking down the -z axis from the origin; d = f B / depth - doffs."""
    K0 = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
    K1 = K0.copy()
    K1[0, 2] += doffs
    R = np.diag([1.0, -1.0, -1.0])
    return PairGeometry(K0 @ np.c_[R, np.zeros(3)], K1 @ np.c_[R, -R @ np.array([baseline, 0.0, 0.0])],
                        width=width, height=height)


def colour_height(dsm, lo, hi):
    v = np.clip((dsm - lo) / max(hi - lo, 1e-9) * 255, 0, 255)
    rgb = cv2.applyColorMap(np.nan_to_num(v).astype(np.uint8), cv2.COLORMAP_TURBO)
    rgb[np.isnan(dsm)] = 0
    return rgb


def side_by_side(path, dsms, labels):
    finite = np.concatenate([d[np.isfinite(d)] for d in dsms])
    lo, hi = np.percentile(finite, [1, 99])
    tiles = []
    for d, label in zip(dsms, labels):
        t = colour_height(d, lo, hi)
        cv2.putText(t, label, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2)
        tiles.append(t)
    gap = np.full((tiles[0].shape[0], 6, 3), 255, np.uint8)
    cv2.imwrite(str(path), np.hstack([x for t in tiles for x in (t, gap)][:-1]))


def compare_three(gt_dsm, dsms, gsd):
    return {name: compare_dsm(d, gt_dsm, (), resolution=gsd) for name, d in dsms.items()}


def middlebury_rows(data_dir, docs, share):
    rows = []
    for name in DEV_SCENES:
        sc = middlebury(data_dir, name)
        H, W = sc.gt.shape
        pair = middlebury_nadir_pair(W, H)
        sparse = simulate_lidar(sc.gt, share, seed=0)
        d_max = int(np.ceil(np.nanmax(sc.gt))) + 4
        disps = {"unguided": match_pair(sc.left, sc.right, sparse, 0, d_max, guide="none").disparity,
                 "riverbed": match_pair(sc.left, sc.right, sparse, 0, d_max, guide="riverbed").disparity}
        gt_res = build_dsm([(sc.gt, pair, None)])
        grid: Grid = gt_res.grid
        out = {k: build_dsm([(d, pair, None)], resolution=grid.resolution, bounds=grid.bounds).dsm
               for k, d in disps.items()}
        m = compare_three(gt_res.dsm, out, grid.resolution)
        for k in ("unguided", "riverbed"):
            rows.append({"scene": f"Middlebury {name}", "method": k, **m[k], "gsd": grid.resolution})
        if docs and name == "Reindeer":
            side_by_side(Path(docs) / "fusion_reindeer_dsm.png", [gt_res.dsm, out["unguided"], out["riverbed"]],
                         ["ground truth", "unguided SGM", "riverbed 5 %"])
    return rows


def sample_rows(sample_dir, docs):
    """The sample aerial block, through the real commands (project -> match -> dsm -> evaluate --dsm)."""
    sample = Path(sample_dir)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)

        def rb(*args):
            p = subprocess.run([sys.executable, "-m", "riverbed_cli", "-q", *map(str, args)], capture_output=True,
                               text=True)
            if p.returncode:
                sys.exit(f"bench_fusion: riverbed {' '.join(map(str, args))} failed: {p.stderr.strip()}")
            return p.stdout

        pair = sample / "pair.yaml"
        rb("project", sample / "lidar.laz", pair, "-o", t / "sparse.tif")
        for name, extra in (("unguided", ["--guide", "none"]), ("riverbed", [])):
            rb("match", sample / "left.png", sample / "right.png", "--sparse", t / "sparse.tif", *extra,
               "-o", t / f"{name}.tif")
            import rasterio

            with rasterio.open(sample / "gt_dsm.tif") as ref:
                res = ref.res[0]
                b = ref.bounds
            rb("dsm", t / f"{name}.tif", pair, "-o", t / f"{name}_dsm.tif", "--resolution", res, "--bounds",
               b.left, b.bottom, b.right, b.top)
            m = json.loads(rb("evaluate", "--dsm", t / f"{name}_dsm.tif", sample / "gt_dsm.tif", "--json",
                              "--thresholds", ""))
            rows.append({"scene": "sample block", "method": name, **m, "gsd": res})
        if docs:
            import rasterio

            def read(p):
                with rasterio.open(p) as ds:
                    return ds.read(1, masked=True).astype(np.float64).filled(np.nan)

            side_by_side(Path(docs) / "fusion_sample_dsm.png",
                         [read(sample / "gt_dsm.tif"), read(t / "unguided_dsm.tif"), read(t / "riverbed_dsm.tif")],
                         ["ground truth", "unguided SGM", "riverbed"])
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data_dir")
    ap.add_argument("--sample", default=None, help="sample block folder (pair.yaml, lidar.laz, gt_dsm.tif)")
    ap.add_argument("--docs", default=None, help="write the side-by-side PNGs here")
    ap.add_argument("--share", type=float, default=0.05)
    args = ap.parse_args()
    rows = middlebury_rows(args.data_dir, args.docs, args.share)
    if args.sample:
        rows += sample_rows(args.sample, args.docs)
    print("| scene | disparities | RMSE | NMAD | cells off > 3 GSD % | completeness % | GSD |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['scene']} | {r['method']} | {r['rmse']:.4f} | {r['nmad']:.4f} | {r['over_3res']:.2f} | "
              f"{r['completeness']:.1f} | {r['gsd']:.4g} |")


if __name__ == "__main__":
    main()
