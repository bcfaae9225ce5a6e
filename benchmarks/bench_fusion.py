"""Does fusion pay in the DSM? DSMs from riverbed-guided disparities, from unguided disparities and from the LiDAR
alone, against the ground-truth DSM.

    python benchmarks/bench_fusion.py [DATA] --write benchmarks/results_fusion.json --docs docs/dsm.md [--png docs]

* Middlebury dev scenes, camera frame as world: a nadir-like frame (x right, y up, height = -depth) with a made-up
  but plausible half-size calibration (f = 1870 px, B = 0.16 m, doffs = 100 px: depths ~1.5-2.5 m). LiDAR is
  simulated by sampling 5 % of the image pixels from the GT (seed 0). The GT DSM is rasterised from the GT
  disparity on the same grid.
* The sample aerial block (``sample_data/block``): the LAZ is projected with ``riverbed project``, matched guided
  and unguided (and interpolated alone, ``riverbed densify --method planes``), and each DSM is compared with the
  block's ground-truth DSM through the commands.

``--write`` stores the rows (the committed result file), ``--docs`` rewrites the table of docs/dsm.md from it
(``tests/test_dsm_doc.py`` checks that the committed doc is that rewrite, and the claims it states); ``--png`` writes
the side-by-side PNGs (GT | unguided | riverbed) there.
"""

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import rasterio

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import DEV_SCENES, middlebury, rows_main  # noqa: E402

from riverbed_cli.geometry.cameras import PairGeometry  # noqa: E402
from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.dsm import Grid, build_dsm  # noqa: E402
from riverbed_cli.products.densify import densify  # noqa: E402
from riverbed_cli.products.dsm_compare import compare_dsm  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
BEGIN, END = "<!-- bench_fusion: begin -->", "<!-- bench_fusion: end -->"
#: the methods of each scene, in the table's order
METHODS = ("unguided", "LiDAR only", "riverbed")
#: the share of the image pixels sampled from the GT as LiDAR (Middlebury)
SHARE = 0.05


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


def _row(scene, method, m, gsd):
    # the figures the table shows, rounded (the committed file holds what the doc prints, and a test re-measures)
    return {"scene": scene, "method": method, "rmse": round(m["rmse"], 4), "nmad": round(m["nmad"], 4),
            "over_3res": round(m["over_3res"], 2), "completeness": round(m["completeness"], 1), "gsd": gsd}


def middlebury_scene(data_dir, name, share=SHARE):
    """One Middlebury dev scene's rows (unguided, LiDAR only, riverbed) and its DSMs (GT first)."""
    sc = middlebury(data_dir, name)
    H, W = sc.gt.shape
    pair = middlebury_nadir_pair(W, H)
    sparse = simulate_lidar(sc.gt, share, seed=0)
    d_max = int(np.ceil(np.nanmax(sc.gt))) + 4
    disps = {"unguided": match_pair(sc.left, sc.right, sparse, 0, d_max, guide="none").disparity,
             "LiDAR only": densify(sparse, "planes"),
             "riverbed": match_pair(sc.left, sc.right, sparse, 0, d_max, guide="riverbed").disparity}
    gt_res = build_dsm([(sc.gt, pair, None)])
    grid: Grid = gt_res.grid
    out = {k: build_dsm([(d, pair, None)], resolution=grid.resolution, bounds=grid.bounds).dsm
           for k, d in disps.items()}
    rows = [_row(f"Middlebury {name}", k, compare_dsm(out[k], gt_res.dsm, (), resolution=grid.resolution),
                 float(f"{grid.resolution:.4g}")) for k in METHODS]
    return rows, [gt_res.dsm, out["unguided"], out["riverbed"]]


def middlebury_rows(data_dir, docs):
    rows = []
    for name in DEV_SCENES:
        scene_rows, dsms = middlebury_scene(data_dir, name)
        rows += scene_rows
        if docs and name == "Reindeer":
            side_by_side(Path(docs) / "fusion_reindeer_dsm.png", dsms, ["ground truth", "unguided SGM", "riverbed 5 %"])
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
        with rasterio.open(sample / "gt_dsm.tif") as ref:
            res = ref.res[0]
            b = ref.bounds
        for name in METHODS:
            disp = t / f"{name.replace(' ', '_')}.tif"
            if name == "LiDAR only":
                rb("densify", t / "sparse.tif", "-o", disp, "--method", "planes")
            else:
                rb("match", sample / "left.png", sample / "right.png", "--sparse", t / "sparse.tif",
                   *(["--guide", "none"] if name == "unguided" else []), "-o", disp)
            dsm = t / f"{name.replace(' ', '_')}_dsm.tif"
            rb("dsm", disp, pair, "-o", dsm, "--resolution", res, "--bounds", b.left, b.bottom, b.right, b.top)
            m = json.loads(rb("evaluate", "--dsm", dsm, sample / "gt_dsm.tif", "--json"))
            rows.append(_row("sample block", name, m, res))
        if docs:
            def read(p):
                with rasterio.open(p) as ds:
                    return ds.read(1, masked=True).astype(np.float64).filled(np.nan)

            side_by_side(Path(docs) / "fusion_sample_dsm.png",
                         [read(sample / "gt_dsm.tif"), read(t / "unguided_dsm.tif"), read(t / "riverbed_dsm.tif")],
                         ["ground truth", "unguided SGM", "riverbed"])
    return rows


def run(data, png=None):
    return middlebury_rows(data, png) + sample_rows(REPO / "sample_data" / "block", png)


def tables(rows):
    """The table of docs/dsm.md from the rows."""
    out = ["| scene | disparities | RMSE (m) | NMAD (m) | cells off > 3 GSD % | completeness % | GSD (m) |",
           "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['scene']} | {r['method']} | {r['rmse']:.4f} | {r['nmad']:.4f} | {r['over_3res']:.2f} | "
                   f"{r['completeness']:.1f} | {r['gsd']:.4g} |")
    return "\n".join(out)


def main():
    rows_main(__doc__, run, tables, BEGIN, END, options=(("--png", "write the side-by-side PNGs into this folder"),))


if __name__ == "__main__":
    main()
