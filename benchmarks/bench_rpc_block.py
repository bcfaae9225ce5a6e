"""The Ventoux Pléiades crops as a block of 4 overlapping ROIs on dask, against the whole crop as one ROI (issue 14
step 5; docs/rpc.md, "Large scenes").

    python benchmarks/bench_rpc_block.py [DATA] [--work DIR] [--json]

1. ``riverbed rectify --rpc`` of the whole crop (``bench_rpc_ventoux.rectify``) only to place the "LiDAR": the SRTM
   surface sampled one point per 4 x 4 rectified pixels over the left crop's footprint (``write_srtm_lidar``);
2. ``riverbed block split-rpc`` of the part of the left crop the right crop sees (rows 250..499: the right crop
   covers only the left one's bottom ~30 %) into 280 x 150 px ROIs overlapping by >= 50 px: 2 x 2 = 4 ROIs, SRTM
   heights, ``defaults: {crs: EPSG:32631, resolution: 0.5}``; ``riverbed block`` on a 2-worker local dask cluster;
3. the whole crop as one ``rpc:`` entry (no ROI: the whole left image), same cloud, DEM and defaults, ``riverbed
   block --workers 0``;
4. on the cells both DSMs have (the grids are snapped to multiples of 0.5 m, so cells coincide): dz = merged -
   whole; and each against the SRTM (ellipsoidal, bilinear at the cell centres) where the ground is inside both
   input crops (``bench_rpc_ventoux.seen_mask``): median, NMAD (1.4826 x median |dz - median|), cells.
"""

import argparse
import json
import os
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np
import rasterio
import yaml
from pyproj import Transformer

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_rpc_ventoux import HGT, VENTOUX, rectify, riverbed, seen_mask, srtm_dem, write_srtm_lidar  # noqa: E402

from riverbed_cli.geometry.pairfile import load_pairfile  # noqa: E402
from riverbed_cli.geometry.rpc_geometry import ground_sample_distance  # noqa: E402

REGION = "0,250,500,250"
SIZE, OVERLAP = "280x150", 50


def read(path):
    with rasterio.open(path) as ds:
        return ds.read(1), ds.transform, ds.crs


def stats(dz):
    dz = dz[np.isfinite(dz)]
    med = float(np.median(dz))
    return {"median": round(med, 3), "nmad": round(float(1.4826 * np.median(np.abs(dz - med))), 3),
            "cells": int(dz.size)}


def on_common_grid(a, ta, b, tb):
    """``a`` and ``b`` (same cell size, grids offset by whole cells) cut to their common cells; its transform."""
    r = ta.a
    x0, y1 = max(ta.c, tb.c), min(ta.f, tb.f)
    x1 = min(ta.c + a.shape[1] * r, tb.c + b.shape[1] * r)
    y0 = max(ta.f - a.shape[0] * r, tb.f - b.shape[0] * r)
    w, h = int(round((x1 - x0) / r)), int(round((y1 - y0) / r))

    def cut(z, t):
        c, rr = int(round((x0 - t.c) / r)), int(round((t.f - y1) / r))
        return z[rr:rr + h, c:c + w]
    return cut(a, ta), cut(b, tb), rasterio.Affine(r, 0, x0, 0, -r, y1)


def srtm_reference(dsm, t, crs, pair, right_size, dem):
    rows, cols = np.mgrid[0:dsm.shape[0], 0:dsm.shape[1]]
    x, y = t * (cols + 0.5, rows + 0.5)
    lon, lat = Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(x, y)
    h = dem.height(lon, lat)
    return np.where(seen_mask(pair, right_size, lon, lat, h), h, np.nan)


def run(data, work, single=None):
    """The whole comparison (module docstring); ``single``: the ROI ``"COL,ROW,W,H"`` of the one-ROI block (default
    the whole left crop)."""
    data, work = Path(data), Path(work)
    base = data / VENTOUX / "rectification"
    hgt = data / VENTOUX / HGT
    s, vertical = rectify(data, work)
    pair = load_pairfile(work / "rect" / "pair.yaml", accept_rpc=True)
    dem = srtm_dem(data, pair, vertical)
    cloud = work / "srtm_lidar.las"
    n_points = write_srtm_lidar(cloud, pair, dem, ground_sample_distance(pair), 4)
    vert = ["--vertical", "ellipsoid"] if vertical.startswith("ellipsoid") else []
    imgs = [base / "left_image.tif", base / "left_image.geom", base / "right_image.tif", base / "right_image.geom"]
    split = riverbed("block", "split-rpc", *imgs, "--cloud", cloud, "--size", SIZE, "--overlap", OVERLAP,
                     "--region", REGION, "--dem", hgt, *vert, "--resolution", "0.5", "-o", work / "split.yaml",
                     "--json", "--overwrite")
    # the SRTM guides as it is (lidar_check off): the figures measure the geometry against that same SRTM
    manifest = yaml.safe_load((work / "split.yaml").read_text())
    manifest.setdefault("defaults", {})["lidar_check"] = "off"
    (work / "split.yaml").write_text(yaml.safe_dump(manifest))
    out_split = riverbed("block", work / "split.yaml", "-o", work / "split", "--workers", "2", "--json",
                         "--overwrite")
    entry = {"left": str(imgs[0]), "left_rpc": str(imgs[1]), "right": str(imgs[2]), "right_rpc": str(imgs[3]),
             "dem": str(hgt), **({"vertical": "ellipsoid"} if vert else {}),
             **({"roi": [int(v) for v in single.split(",")]} if single else {})}
    whole = {"defaults": {"crs": "EPSG:32631", "resolution": 0.5, "lidar_check": "off"},
             "pairs": [{"name": "whole", "rpc": entry, "cloud": str(cloud)}]}
    (work / "whole.yaml").write_text(yaml.safe_dump(whole))
    out_whole = riverbed("block", work / "whole.yaml", "-o", work / "whole", "--workers", "0", "--json",
                         "--overwrite")
    m, tm, crs = read(work / "split" / "dsm.tif")
    w, tw, _ = read(work / "whole" / "dsm.tif")
    with rasterio.open(imgs[2]) as ds:
        right_size = (ds.width, ds.height)
    mm, ww, t = on_common_grid(m, tm, w, tw)
    ref_m = srtm_reference(m, tm, crs, pair, right_size, dem)
    ref_w = srtm_reference(w, tw, crs, pair, right_size, dem)
    figures = {"merged_vs_whole": stats(mm - ww), "merged_vs_srtm": stats(m - ref_m),
               "whole_vs_srtm": stats(w - ref_w),
               "merged_cells": int(np.isfinite(m).sum()), "whole_cells": int(np.isfinite(w).sum())}
    return {"vertical": vertical, "lidar_points": n_points, "split_manifest": split, "split": out_split,
            "whole": out_whole, "figures": figures}


def table(s):
    f = s["figures"]
    rows = ["| dz | median (m) | NMAD (m) | cells |", "|---|---|---|---|"]
    for key, what in (("merged_vs_whole", "merged 4 ROIs - whole crop"), ("merged_vs_srtm", "merged 4 ROIs - SRTM"),
                      ("whole_vs_srtm", "whole crop - SRTM")):
        rows.append(f"| {what} | {f[key]['median']:.3f} | {f[key]['nmad']:.3f} | {f[key]['cells']} |")
    return "\n".join(rows)


#: the markers of docs/rpc.md's block of this benchmark
BEGIN, END = "<!-- bench_rpc_block begin -->", "<!-- bench_rpc_block end -->"


def doc_text(s):
    """docs/rpc.md's block: the split, the table, and the merged and whole DSMs' cells."""
    m, f = s["split_manifest"], s["figures"]
    rois = ", ".join(f"{r['name']} ({r['roi'][2]} x {r['roi'][3]} at {r['roi'][0]},{r['roi'][1]}, right share "
                     f"{r['right_share']:.2f})" for r in m["rois"])
    lo, hi = m["heights"]
    text = [f"The split: {len(m['rois'])} ROIs, {rois}; heights {lo:.0f}–{hi:.0f} m (SRTM, {s['vertical']}); the "
            f"SRTM \"LiDAR\" of {s['lidar_points']} points. Every pair "
            + ("done" if all(p["status"] == "done" for p in s["split"]["pairs"]) else "NOT done") + "; the merged "
            f"DSM has {f['merged_cells']} cells, the whole crop's {f['whole_cells']}.", "", table(s)]
    return "\n".join(textwrap.fill(t, 116, break_on_hyphens=False) if not t.startswith("|") else t for t in text)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    ap.add_argument("--work", default=None)
    ap.add_argument("--single", default=None, metavar="COL,ROW,W,H",
                    help="ROI of the one-ROI block (default the whole left crop)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--write", help="store the figures in this JSON file (benchmarks/results_rpc_block.json)")
    ap.add_argument("--rows", help="take the figures from this JSON file instead of running")
    ap.add_argument("--docs", help="rewrite this Markdown file's block (docs/rpc.md)")
    a = ap.parse_args()
    if a.rows:
        s = json.loads(Path(a.rows).read_text())
        work = None
    else:
        work = Path(a.work) if a.work else Path(tempfile.mkdtemp(prefix="bench_rpc_block_"))
        work.mkdir(parents=True, exist_ok=True)
        s = run(a.data, work, a.single)
    if a.write:  # the work folder's paths as WORK
        text = json.dumps(s, indent=1, default=str)
        Path(a.write).write_text((text.replace(str(work), "WORK") if work is not None else text) + "\n")
    if a.docs:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from datasets import rewrite_block

        rewrite_block(a.docs, BEGIN, END, doc_text(s))
    if a.json:
        print(json.dumps(s, indent=2, default=str))
    else:
        print(f"heights: {s['vertical']}; LiDAR {s['lidar_points']} points; work {work}")
        for p in s["split"]["pairs"]:
            print(f"  {p['name']}: {p['status']}, {p['points']} points, {p['seconds']} s")
        print(f"split block {s['split']['seconds']} s on {s['split']['cluster']['workers']} workers; whole "
              f"{s['whole']['seconds']} s")
        print(table(s))


if __name__ == "__main__":
    main()
