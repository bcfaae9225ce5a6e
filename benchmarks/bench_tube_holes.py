"""Holes in the LiDAR: the nominal range against a coarse match's range (``--tube-holes coarse``) where no LiDAR is
within the tube rule's reach.

    python benchmarks/bench_tube_holes.py [DATA] --write benchmarks/results_tube_holes.json --docs docs/tubes.md

LiDAR at 5 % of the image pixels sampled from the GT (seed 0), then removed inside 4 discs of radius 0.2 min(H, W)
(seed 1): the pixels with no LiDAR within reach are the holes. Errors over the GT pixels in the holes (bad3 %, mean
px; a pixel without disparity counts as bad) of the LiDAR alone (nearest, linear, guided), riverbed-guided SGM alone
and fused, untiled and in tiles of 256 px;
coverage: the share of the hole pixels whose true disparity lies inside their range.

``--write`` stores the rows (the committed result file), ``--docs`` rewrites docs/tubes.md's table from it
(``tests/test_tube_holes_doc.py`` checks the doc and the claims its text makes on the committed rows).
"""

import logging
import math
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_tubes import scenes  # noqa: E402
from datasets import cell, rows_main  # noqa: E402

from riverbed_cli.matching.config import MatchConfig  # noqa: E402
from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.matching.range_maps import fill_tube_holes  # noqa: E402
from riverbed_cli.matching.tubes import lidar_tubes  # noqa: E402
from riverbed_cli.products.densify import densify  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402
from riverbed_cli.scale.tiles import match_tiled  # noqa: E402

BEGIN, END = "<!-- bench_tube_holes: begin -->", "<!-- bench_tube_holes: end -->"
#: the columns after the LiDAR-only ones: (key, fusion, holes, tiled)
MATCHES = (("matcher_full", "none", "full", False), ("matcher_coarse", "none", "coarse", False),
           ("fused_full", "auto", "full", False), ("fused_coarse", "auto", "coarse", False),
           ("tiles_full", "auto", "full", True), ("tiles_coarse", "auto", "coarse", True))


def _errors(disp, gt, ev):
    # bad3 counts a pixel without disparity as an error (as evaluate_disparity does); the mean is over the others
    e = np.abs(disp - gt)[ev]
    return [round(100 * float(np.mean(~(e <= 3))), 2), round(float(np.nanmean(e)), 3)]


def run(data, share=0.05, seed=1):
    logging.getLogger("riverbed_cli").setLevel(logging.ERROR)
    rng = np.random.default_rng(seed)
    rows = []
    for name, left, right, gt in scenes(data):
        H, W = gt.shape
        d_max = int(math.ceil(np.nanmax(gt))) + 4
        mask = np.zeros((H, W), np.uint8)
        for _ in range(4):
            cv2.circle(mask, (int(rng.integers(W)), int(rng.integers(H))), int(0.2 * min(H, W)), 1, -1)
        sparse = simulate_lidar(gt, share, seed=0)
        sparse[mask.astype(bool)] = np.nan
        lo, hi, hole = lidar_tubes(sparse, 0, d_max, return_holes=True)
        clo, chi = fill_tube_holes(left, right, lo, hi, hole, 0, d_max, MatchConfig().replace(tube={"holes": "coarse"}),
                                   match_pair)
        ev = hole & np.isfinite(gt)
        row = {"scene": name, "holes": round(100 * float(hole.mean()), 1), "gt_pixels": int(ev.sum()),
               "coverage_coarse": round(100 * float(((gt[ev] >= clo[ev]) & (gt[ev] <= chi[ev])).mean()), 2),
               "nominal": d_max + 1, "width_coarse": round(float((chi - clo + 1)[hole].mean()), 1)}
        for method in ("nearest", "linear", "guided"):  # the LiDAR alone, interpolated across the holes
            row[f"lidar_{method}"] = _errors(densify(sparse, method, image=left), gt, ev)
        for key, fusion, holes, tiled in MATCHES:
            if tiled:  # each tile's LiDAR range, and its own coarse match in the holes
                disp = match_tiled(left, right, sparse, 0, d_max, tile=256, tube={"holes": holes}).disparity
            else:
                disp = match_pair(left, right, sparse, 0, d_max, fusion=fusion, tube={"holes": holes}).disparity
            row[key] = _errors(disp, gt, ev)
        rows.append(row)
    return rows


def tables(rows):
    out = ["| scene | holes % of image | GT px in holes | coverage full / coarse % | width in holes full / coarse | "
           "LiDAR nearest | LiDAR linear | LiDAR guided | matcher, full | matcher, coarse | fused, full | "
           "fused, coarse | fused, tiles of 256, full | fused, tiles of 256, coarse |",
           "|---|---:|---:|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [cell(r[f"lidar_{m}"]) for m in ("nearest", "linear", "guided")] + [cell(r[k[0]]) for k in MATCHES]
        out.append(f"| {r['scene']} | {r['holes']:.1f} | {r['gt_pixels']} | 100.00 / {r['coverage_coarse']:.2f} | "
                   f"{r['nominal']} / {r['width_coarse']:.1f} | {' | '.join(cells)} |")
    lidar = ("lidar_nearest", "lidar_linear", "lidar_guided")
    beaten = all(r[k[0]][i] < min(r[m][i] for m in lidar) for r in rows for k in MATCHES for i in (0, 1))
    mean = [r for r in rows if r["fused_coarse"][1] < r["fused_full"][1]]
    bad3 = [r for r in rows if r["fused_coarse"][0] < r["fused_full"][0]]
    tiles = [r for r in rows if r["tiles_coarse"][1] < r["tiles_full"][1]]
    worst = min(rows, key=lambda r: r["coverage_coarse"])
    out += ["", f"In the holes every matcher column beats every LiDAR-only baseline on both metrics: "
            f"{'yes' if beaten else 'no'}. The coarse ranges lower the fused mean error on {len(mean)} of {len(rows)} "
            f"scenes and bad3 on {len(bad3)}; tiled, the mean error on {len(tiles)}. The lowest coverage of the coarse "
            f"ranges: {worst['scene']}, {worst['coverage_coarse']:.2f} % of its hole pixels."]
    return "\n".join(out)


def main():
    rows_main(__doc__, run, tables, BEGIN, END)


if __name__ == "__main__":
    main()
