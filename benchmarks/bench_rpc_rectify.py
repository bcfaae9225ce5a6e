"""Rectification of the real Pléiades Ventoux pair (RPC, 500 x 500 crops, SRTM heights): accuracy in one run.

    python benchmarks/bench_rpc_rectify.py [DATA] [--json]

DATA is the shared data folder (default ``$RIVERBED_DATA`` or ``../shared/data``). Prints (docs/rpc.md):

- the affine model's own error: the row difference of the virtual matches (RPC projections) after rectification;
- the **vertical parallax of independent tie points**: OpenCV SIFT on the two rectified images, Lowe's ratio 0.75,
  no geometric filtering besides |dy| < 3 px and a disparity inside the rectification's range (outliers);
  median and 95th percentile of |dy|, raw and after Lucas-Kanade refinement (21 px window);
- **shareloc's ground-truth grids** (``shareloc_gt_*_grid_with_margins.tif``, epipolar step 30 px): the row
  difference our rectification gives to shareloc's left/right correspondences inside the crops, and the difference
  between shareloc's left grid and ours once the two epipolar frames are aligned by a similarity (px).
"""

import argparse
import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np
import rasterio
from affine import Affine

from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.rpc import read_rpc
from riverbed_cli.geometry.rpc_dem import read_dem
from riverbed_cli.geometry.rpc_rectify import (apply_h, estimate_row_offset, heights_over_roi, rectify_rpc_pair,
                                              resample, stretch_to_uint8, virtual_matches, with_row_offset)

VENTOUX = "satellite_pleiades_ventoux_shareloc/tests/data"


def crop_offset(path):
    """The (col, row) offset of a crop in its full image, from a TIFF geotransform that is a pure translation."""
    with rasterio.open(path) as ds:
        t = ds.transform
        image = ds.read(1)
    if ds.crs is not None or (t.a, t.b, t.d, t.e) != (1.0, 0.0, 0.0, 1.0):
        return 0.0, 0.0, image
    return float(t.c), float(t.f), image


def load_pair(data):
    base = Path(data) / VENTOUX / "rectification"
    c0, r0, left = crop_offset(base / "left_image.tif")
    c1, r1, right = crop_offset(base / "right_image.tif")
    rpc_l = read_rpc(base / "left_image.geom").shifted(c0, r0)
    rpc_r = read_rpc(base / "right_image.geom").shifted(c1, r1)
    return left, right, rpc_l, rpc_r, (c0, r0), (c1, r1)


to8 = stretch_to_uint8


def sift_parallax(rl, rr, dmin, dmax, lk=False, center=False):
    a, b = to8(rl), to8(rr)
    sift = cv2.SIFT_create()
    ka, da = sift.detectAndCompute(a, (rl > 0).astype(np.uint8))
    kb, db = sift.detectAndCompute(b, (rr > 0).astype(np.uint8))
    pairs = cv2.BFMatcher().knnMatch(da, db, k=2)
    good = [m for m, n2 in (p for p in pairs if len(p) == 2) if m.distance < 0.75 * n2.distance]
    pa = np.array([ka[m.queryIdx].pt for m in good], np.float32)
    pb = np.array([kb[m.trainIdx].pt for m in good], np.float32)
    if lk and len(pa):
        pb2, st, _ = cv2.calcOpticalFlowPyrLK(a, b, pa.reshape(-1, 1, 2), pb.reshape(-1, 1, 2).copy(),
                                              winSize=(21, 21), maxLevel=0,
                                              flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
                                              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3))
        keep = (st.ravel() == 1) & (np.abs(pb2.reshape(-1, 2) - pb).max(axis=1) < 1.5)
        pa, pb = pa[keep], pb2.reshape(-1, 2)[keep]
    dy = pa[:, 1] - pb[:, 1]
    d = pa[:, 0] - pb[:, 0]
    ok = (np.abs(dy - (np.median(dy) if center else 0)) < 3) & (d >= dmin - 3) & (d <= dmax + 3)
    dy = dy[ok]
    return {"matches": int(ok.sum()), "dy_median_abs": float(np.median(np.abs(dy))),
            "dy_p95_abs": float(np.percentile(np.abs(dy), 95)), "dy_mean": float(np.mean(dy))}


def shareloc_grids(data, rect, off_l, off_r, size_l, size_r):
    """Our rectification against shareloc's grids: rows of its correspondences, and the grids' difference."""
    base = Path(data) / VENTOUX / "rectification"
    with rasterio.open(base / "shareloc_gt_left_grid_with_margins.tif") as ds:
        gl, tr = ds.read(), ds.transform
    with rasterio.open(base / "shareloc_gt_right_grid_with_margins.tif") as ds:
        gr = ds.read()
    # band 1 col, band 2 row (shareloc's xy convention), full-sensor coordinates with (0, 0) at the first pixel's
    # corner (topleftconvention): riverbed's crop pixel = value - 0.5 - crop offset
    xl, yl = gl[0] - 0.5 - off_l[0], gl[1] - 0.5 - off_l[1]
    xr, yr = gr[0] - 0.5 - off_r[0], gr[1] - 0.5 - off_r[1]
    inside = ((xl >= 0) & (xl <= size_l[0] - 1) & (yl >= 0) & (yl <= size_l[1] - 1) & (xr >= 0)
              & (xr <= size_r[0] - 1) & (yr >= 0) & (yr <= size_r[1] - 1))
    ul, vl = apply_h(rect.H_left, xl[inside], yl[inside])
    ur, vr = apply_h(rect.H_right, xr[inside], yr[inside])
    # shareloc's epipolar coordinates of the grid nodes (the grid's geotransform: node index -> epipolar pixel)
    # (the files hold it in GDAL's order, Affine(-20, 30, 0, -20, 0, 30): origin -20, step 30 epipolar px)
    if tr.c == 0 and tr.f == 30 and tr.b == 30:
        tr = Affine.from_gdal(tr.a, tr.b, tr.c, tr.d, tr.e, tr.f)
    jj, ii = np.meshgrid(np.arange(gl.shape[2]), np.arange(gl.shape[1]))
    es, ts = tr * (jj[inside], ii[inside])
    es, ts = np.asarray(es, np.float64), np.asarray(ts, np.float64)
    # similarity (shareloc epipolar -> ours) by least squares: [u, v] = [[p, -q], [q, p]] [es, ts] + [tx, ty]
    # or its mirror [[p, q], [q, -p]] (rows [e, -m t], [m t, e], m = -1): the frames may differ by a reflection
    best = None
    for mirror in (1.0, -1.0):
        A = np.zeros((2 * es.size, 4))
        A[0::2] = np.column_stack([es, -mirror * ts, np.ones_like(es), np.zeros_like(es)])
        A[1::2] = np.column_stack([mirror * ts, es, np.zeros_like(es), np.ones_like(es)])
        rhs = np.empty(2 * es.size)
        rhs[0::2], rhs[1::2] = ul, vl
        sol = np.linalg.lstsq(A, rhs, rcond=None)[0]
        res = (A @ sol - rhs).reshape(-1, 2)
        if best is None or np.sum(res ** 2) < np.sum(best[1] ** 2):
            best = (sol, res, mirror)
    sol, res, mirror = best
    return {"nodes_inside": int(inside.sum()),
            "row_difference_of_shareloc_matches_median_abs": float(np.median(np.abs(vl - vr))),
            "row_difference_of_shareloc_matches_max_abs": float(np.max(np.abs(vl - vr))),
            "grid_difference_after_similarity_rms_px": float(np.sqrt(np.mean(np.sum(res ** 2, axis=1)))),
            "grid_difference_after_similarity_max_px": float(np.max(np.hypot(res[:, 0], res[:, 1]))),
            "similarity_scale": float(np.hypot(sol[0], sol[1])), "similarity_mirrored": bool(mirror < 0),
            "similarity_angle_deg": float(np.degrees(np.arctan2(sol[1], sol[0])))}


def run(data):
    left, right, rpc_l, rpc_r, off_l, off_r = load_pair(data)
    hgt = Path(data) / VENTOUX / "dtm/srtm_ventoux/srtm90_non_void_filled/N44E005.hgt"
    roi = (0, 0, left.shape[1], left.shape[0])
    lon, lat = rpc_l.localize([0, roi[2], 0, roi[2]], [0, 0, roi[3], roi[3]], [rpc_l.height_off] * 4)
    bounds = (lon.min() - 0.01, lat.min() - 0.01, lon.max() + 0.01, lat.max() + 0.01)
    try:
        dem = read_dem(hgt, bounds=bounds)
    except RiverbedError as e:
        # no EGM96 grid on this machine (Debian's proj-data): SRTM read as ellipsoidal, ~51 m low here; the
        # rectification's rows do not depend on it (the height range only sets the disparity range)
        print(f"warning: {e}; SRTM heights used as ellipsoidal", file=sys.stderr)
        dem = read_dem(hgt, bounds=bounds, vertical="ellipsoid")
    heights = heights_over_roi(rpc_l, roi, dem)
    rect = rectify_rpc_pair(rpc_l, rpc_r, roi, heights)
    rl = resample(left, rect.H_left, rect.size)
    rr = resample(right, rect.H_right, rect.size)
    before = sift_parallax(rl, rr, *rect.disparity, center=True)
    # the affine model checked on denser virtual matches than it was fitted on
    x1, y1, x2, y2, _ = virtual_matches(rpc_l, rpc_r, roi, heights, n=41, n_heights=9)
    _, v1 = apply_h(rect.H_left, x1, y1)
    _, v2 = apply_h(rect.H_right, x2, y2)
    check = float(np.max(np.abs(v1 - v2)))
    grids = shareloc_grids(data, rect, off_l, off_r, left.shape[::-1], right.shape[::-1])
    # the RPCs' relative pointing error, from ORB tie points (SIFT below measures independently)
    offset, n_orb = estimate_row_offset(rl, rr, rect.disparity)
    rect = with_row_offset(rect, offset)
    rr = resample(right, rect.H_right, rect.size)
    out = {"heights": list(heights), "dem_vertical": dem.vertical, "size": list(rect.size),
           "disparity": list(rect.disparity), **rect.info, "orb_tie_points": n_orb,
           "sift_before_pointing_correction": before,
           "check_row_residual_max_px": check,
           "sift": sift_parallax(rl, rr, *rect.disparity), "sift_lk": sift_parallax(rl, rr, *rect.disparity, lk=True),
           "shareloc_before_pointing_correction": grids}
    return out, rl, rr


#: the markers of docs/rpc.md's block of this benchmark
BEGIN, END = "<!-- bench_rpc_rectify begin -->", "<!-- bench_rpc_rectify end -->"


def doc_text(out):
    """docs/rpc.md's block: the run's figures as a table."""
    b, s, lk, g = (out["sift_before_pointing_correction"], out["sift"], out["sift_lk"],
                   out["shareloc_before_pointing_correction"])
    lo, hi = out["heights"]
    return "\n".join([
        f"Heights {lo:.1f}–{hi:.1f} m (SRTM, vertical datum {out['dem_vertical']} -> ellipsoid), output "
        f"{out['size'][0]} x {out['size'][1]}, d in {out['disparity'][0]:.0f}–{out['disparity'][1]:.1f} px, "
        f"{out['disparity_per_metre']:.3f} px per metre of height.", "",
        "| what | figure |", "|---|---|",
        f"| affine model: row difference of virtual matches (41 x 41 x 9, denser than the fit) | max "
        f"**{out['check_row_residual_max_px']:.4f} px** (the fit's {out['virtual_matches']}: max "
        f"{out['virtual_row_residual_max_px']:.4f}, rms {out['virtual_row_residual_rms_px']:.4f}) |",
        f"| SIFT tie points, before the pointing correction | {b['matches']} matches, median \\|dy\\| "
        f"{b['dy_median_abs']:.2f} px (mean dy {b['dy_mean']:.2f}): the RPCs' relative pointing error |",
        f"| pointing correction (ORB + LK, {out['orb_tie_points']} tie points) | {out['pointing_row_offset_px']:.2f} "
        "px of rows |",
        f"| independent SIFT tie points (ratio 0.75, \\|dy\\| < 3 px), raw positions | {s['matches']} matches, "
        f"median \\|dy\\| {s['dy_median_abs']:.2f} px, p95 {s['dy_p95_abs']:.2f} px, mean {s['dy_mean']:.3f} |",
        f"| same, refined by Lucas-Kanade (21 px) | {lk['matches']} matches, median \\|dy\\| "
        f"**{lk['dy_median_abs']:.3f} px**, p95 **{lk['dy_p95_abs']:.3f} px** (targets 0.2 / 0.5) |",
        "| shareloc's ground-truth grids (step 30 px): row difference our rectification gives to shareloc's "
        f"left/right correspondences inside the crops ({g['nodes_inside']} nodes) | median "
        f"{g['row_difference_of_shareloc_matches_median_abs']:.4f} px, max "
        f"{g['row_difference_of_shareloc_matches_max_abs']:.3f} px |",
        f"| shareloc's left grid vs ours after the best similarity | rms "
        f"**{g['grid_difference_after_similarity_rms_px']:.5f} px**, max "
        f"{g['grid_difference_after_similarity_max_px']:.4f} px (scale {g['similarity_scale']:.6f}, angle "
        f"{g['similarity_angle_deg']:.4f}°) |"])


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    p.add_argument("--json", action="store_true")
    p.add_argument("--save", help="write the rectified pair as PNGs with this prefix")
    p.add_argument("--write", help="store the figures in this JSON file (benchmarks/results_rpc_rectify.json)")
    p.add_argument("--rows", help="take the figures from this JSON file instead of running")
    p.add_argument("--docs", help="rewrite this Markdown file's block (docs/rpc.md)")
    a = p.parse_args(argv)
    if a.rows:
        out = json.loads(Path(a.rows).read_text())
    else:
        out, rl, rr = run(a.data)
    if a.write:
        Path(a.write).write_text(json.dumps(out, indent=1) + "\n")
    if a.docs:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from datasets import rewrite_block

        rewrite_block(a.docs, BEGIN, END, doc_text(out))
    if a.save and not a.rows:
        cv2.imwrite(a.save + "_left.png", to8(rl))
        cv2.imwrite(a.save + "_right.png", to8(rr))
    print(json.dumps(out, indent=1) if a.json else "\n".join(f"{k}: {v}" for k, v in out.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
