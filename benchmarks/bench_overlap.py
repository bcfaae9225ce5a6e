"""Frame pairs through the commands with their defaults: the overlap rule on a real survey and on the sample block.

Two routes, each as a user runs it (``riverbed`` commands in fresh processes):

- the real NGI pair (``aerial_ngi_orthority/ngi`` in RIVERBED_DATA: two DMC frames, 27 % forward overlap):
  ``orient`` (Orthority's files) -> ``rectify`` -> ``project`` (the reference DEM, as the guidance) -> ``match``
  -> ``dsm`` -> ``evaluate --dsm`` against the DEM;
- the sample block's raw frames (``sample_data/block/raw``): ``rectify`` -> ``project`` (its LiDAR) -> ``match`` ->
  ``dsm`` -> ``evaluate --dsm`` against its ground-truth DSM.

Rows per route: the default (LiDAR-guided, fused), unguided matching over the LiDAR's range (``project``'s
``d_range``, 8 px around it), and the LiDAR alone (``densify``, no matching). Columns: the DSM against the
reference (median, NMAD, RMSE in m over the reference cells the DSM covers; completeness %), the empty cells inside
the DSM's footprint with the default lattice rule and with ``--keep-lattice`` (docs/dsm.md), the share of the
left image with a disparity, the share outside the overlap (no candidate in the right image), and the pixels
outside the overlap that were triangulated anyway.

    python benchmarks/bench_overlap.py [DATA] --write benchmarks/results_overlap.json --docs docs/rectify.md

``--write`` stores the rows (the committed result file), ``--docs`` rewrites the table of docs/rectify.md from it
(``tests/test_overlap_doc.py`` checks that the doc is that rewrite, the claims it states, and measures the NGI
default row again).
"""

import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import rasterio

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import rows_main  # noqa: E402

from riverbed_cli.io.disparity import read_disparity  # noqa: E402
from riverbed_cli.matching.overlap import matchable_mask  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
NGI = "aerial_ngi_orthority/ngi"
NGI_FRAMES = ("3324c_2015_1004_05_0184_RGB", "3324c_2015_1004_05_0182_RGB")  # left (west), right
BEGIN, END = "<!-- bench_overlap: begin -->", "<!-- bench_overlap: end -->"
METHODS = ("default", "unguided", "lidar_only")


def riverbed(*args):
    """Run a riverbed command; its --json summary (or None)."""
    exe = Path(sys.executable).with_name("riverbed")
    r = subprocess.run([str(exe if exe.exists() else "riverbed"), *map(str, args)], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"riverbed {' '.join(map(str, args))} failed:\n{r.stderr}")
    return json.loads(r.stdout) if "--json" in args else None


def ngi_pair(data, out):
    """The NGI frames' rectified pair: its folder and the reference DEM."""
    base = Path(data) / NGI
    riverbed("orient", base / "ngi_int_param.yaml", base / "ngi_xyz_opk.csv", "-o", out / "orient",
             "--images", ",".join(NGI_FRAMES))
    riverbed("rectify", *(p for f in NGI_FRAMES for p in (base / f"{f}.tif", out / "orient" / f"{f}.yaml")),
             "-o", out / "rect")
    return out / "rect", base / "dem.tif", base / "dem.tif"


def sample_pair(out):
    """The sample block's raw frames rectified: its folder, the LiDAR and the ground-truth DSM."""
    b = REPO / "sample_data" / "block"
    raw = b / "raw"
    riverbed("rectify", raw / "frame0.png", raw / "frame0.yaml", raw / "frame1.png", raw / "frame1.yaml",
             "-o", out / "rect")
    return out / "rect", b / "lidar.laz", b / "gt_dsm.tif"


def route(name, rect, cloud, reference, out, methods=METHODS):
    """The rows of one rectified pair: each method's match (or LiDAR interpolation), DSM and scores."""
    pair = rect / "pair.yaml"
    proj = riverbed("project", cloud, pair, "-o", out / "sparse.tif", "--json")
    lo, hi = math.floor(proj["d_range"][0]) - 8, math.ceil(proj["d_range"][1]) + 8
    rows = []
    for method in methods:
        disp = out / f"{method}.tif"
        info = {}
        if method == "default":
            info = riverbed("match", rect / "left.png", rect / "right.png", "--sparse", out / "sparse.tif",
                            "-o", disp, "--json")
        elif method == "unguided":
            info = riverbed("match", rect / "left.png", rect / "right.png", "--min-disp", lo, "--max-disp", hi,
                            "-o", disp, "--json")
        else:
            riverbed("densify", out / "sparse.tif", "-o", disp, "--method", "planes")
        riverbed("dsm", disp, pair, "-o", out / f"{method}_dsm.tif")
        e = riverbed("evaluate", "--dsm", out / f"{method}_dsm.tif", reference, "--json")
        riverbed("dsm", disp, pair, "-o", out / f"{method}_open.tif", "--keep-lattice")
        holes = [footprint_holes(out / f"{method}_{n}.tif") for n in ("dsm", "open")]
        d = read_disparity(disp)
        d_min, d_max = info.get("d_min", lo), info.get("d_max", hi)
        outside = ~matchable_mask(d.shape, d_min, d_max)  # the whole range's rule (tubes narrow it further)
        rows.append({"route": name, "method": method, "median": round(e["median"], 3), "nmad": round(e["nmad"], 3),
                     "rmse": round(e["rmse"], 3), "completeness": round(e["completeness"], 2),
                     "matched": round(float(np.isfinite(d).mean()), 4),
                     "outside_overlap": round(float(outside.mean()), 4),
                     "outside_triangulated": int(np.count_nonzero(np.isfinite(d) & outside)),
                     "pixels": int(d.size), "holes": holes[0], "holes_open_lattice": holes[1]})
    return rows


def footprint_holes(path):
    """Share (%) of the empty cells of a DSM inside its footprint (its data cells closed by a 5 x 5 closing)."""
    with rasterio.open(path) as ds:
        data = np.isfinite(ds.read(1)).astype(np.uint8)
    footprint = cv2.morphologyEx(data, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) > 0
    return round(float(100.0 * (footprint & (data == 0)).sum() / max(int(footprint.sum()), 1)), 2)


def run(data, work):
    rows = []
    work = Path(work)
    if (Path(data) / NGI).is_dir():
        (work / "ngi").mkdir()
        rows += route("NGI DMC pair (real)", *ngi_pair(data, work / "ngi"), work / "ngi")
    (work / "sample").mkdir()
    rows += route("sample block, raw frames", *sample_pair(work / "sample"), work / "sample")
    return rows


LABELS = {"default": "default (LiDAR-guided, fused)", "unguided": "unguided, the LiDAR's range",
          "lidar_only": "LiDAR alone (`densify --method planes`)"}


def table(rows):
    """The Markdown table of docs/rectify.md from the result rows."""
    out = ["| pair | method | median m | NMAD m | RMSE m | completeness % | holes % (lattice open) | image matched % "
           "| outside the overlap % | triangulated outside |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['route']} | {LABELS[r['method']]} | {r['median']:+.2f} | {r['nmad']:.2f} | "
                   f"{r['rmse']:.2f} | {r['completeness']:.1f} | {r['holes']:.1f} ({r['holes_open_lattice']:.1f}) | "
                   f"{100 * r['matched']:.1f} | {100 * r['outside_overlap']:.1f} | {r['outside_triangulated']} |")
    return "\n".join(out)


def _run_in_temp(data):
    with tempfile.TemporaryDirectory() as work:
        return run(data, work)


def main():
    rows_main(__doc__, _run_in_temp, table, BEGIN, END)


if __name__ == "__main__":
    main()
