"""Hidden point removal against known visibility: Cones (round-trip scene) and the sample aerial block.

    python benchmarks/bench_visibility.py --write benchmarks/results_visibility.json --docs docs/projection.md

Two scenes whose LiDAR points have a known visibility, each projected by ``project_cloud`` with the default
options (SOR, z-buffer in both views) but for the visibility rule of the row:

- **Cones**: the round-trip scene of tests/test_cli_project.py (Middlebury 2003 Cones GT as LiDAR at a share of
  the pixels; hidden points behind the surface at 20 % of the other pixels and behind every tenth visible point on
  its own ray; floating outliers). "visible": the samples visible in both views (the GT ordering test for the
  right view, inside the right image); "hidden": the points behind the surface.
- **sample block**: ``sample_data/block`` regenerated in memory (``riverbed sample --size small --seed 0``: the
  same points as ``lidar.laz``); each LiDAR point's truth by ray casting the synthetic surface from both camera
  centres (:func:`block_truth`): visible when no surface lies more than ``TRUTH_TOLERANCE`` m before it on the ray
  from either camera, hidden otherwise (last returns under crowns, ground next to walls). Outliers and class-7
  noise are in neither set; points outside either image neither.

Per scene: **visible kept** (share of the pixels holding a truly visible point whose disparity, or that of another
visible point of that pixel, is in the sparse map), **hidden removed** (share of the hidden points whose own
disparity is not in the map), and **wrong pixels**, kept pixels more than 1 px off the ground-truth disparity
map. Then the round trip of tests/test_cli_project.py (Cones, 10 %) under the command's options, against what that
test requires (:data:`REQUIRED`).

``--write`` stores the rows (the committed result file), ``--docs`` rewrites docs/projection.md's three tables
from it (``tests/test_visibility.py`` gates the projections against the rows, ``tests/test_projection_doc.py``
checks the doc).
"""

import os
import tempfile
import sys
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "tests"))

from datasets import rows_main  # noqa: E402

from riverbed_cli.geometry import projection as pj  # noqa: E402
from riverbed_cli.geometry.pairfile import load_pairfile  # noqa: E402
from riverbed_cli.io.disparity import read_disparity  # noqa: E402

BLOCK = ROOT / "sample_data" / "block"
#: A LiDAR point is hidden when the surface lies more than this before it on a camera ray (m). The range noise
#: is 0.04 m; 0.25 m behind a surface at 600 m is 0.2 px of disparity, which misguides nobody.
TRUTH_TOLERANCE = 0.25
#: A sparse pixel "holds" a point when it carries the point's disparity to this (px; float32 storage).
MATCH = 1e-3
DEFAULT = "z-buffer, `edge_reach 1` (default)"
#: the visibility rules compared on both scenes: (label, project_cloud keywords)
RULES = [(DEFAULT, {})] + [(f"z-buffer, `edge_reach {r:g}`", {"edge_reach": r}) for r in (0.5, 0.25, 0.0)]
RULES += [("`surface`", {"visibility": "surface"}), ("`surface+zbuffer`", {"visibility": "surface+zbuffer"}),
          ("`surface+zbuffer`, `edge_reach 0.75`", {"visibility": "surface+zbuffer", "edge_reach": 0.75})]
#: the most aggressive z-buffer tried on the block
AGGRESSIVE = ("z-buffer, `footprint 8`, `slope 0`", {"footprint": 8, "slope": 0.0})
SHARES = (0.05, 0.1, 0.3)
#: the round trip of tests/test_cli_project.py (Cones, 10 % LiDAR) under the command's options
ROUND_TRIP = [("defaults", {}), ("`--outliers none`", {"outliers": "none"}), ("`--side left`", {"side": "left"}),
              ("`--visibility hpr`", {"visibility": "hpr"})]
#: what tests/test_cli_project.py requires of the defaults' round trip: (figure, bound, at least / at most)
REQUIRED = {"max_error": (0.01, "max"), "hidden_removed": (0.99, "min"), "outliers_removed": (1.0, "min"),
            "visible_kept": (0.93, "min"), "right_occluded_removed": (0.90, "min")}


def cones_scene(share, folder):
    from test_cli_project import build_scene

    gt = read_disparity(ROOT / "tests/data/cones/disp2.png", scale=4)
    cwd = os.getcwd()
    os.chdir(ROOT)  # build_scene names the images relative to the repository
    try:
        sc = build_scene(Path(folder), gt, share=share)
    finally:
        os.chdir(cwd)
    return sc, gt


def score_cones(sparse, gt, sc):
    """Visible kept, hidden removed, wrong pixels of a sparse map of the Cones round-trip scene."""
    from test_cli_project import score

    m = score(sparse, gt, sc)
    ok = np.isfinite(sparse)
    wrong = int((ok & ~(np.abs(sparse - gt) <= 1.0)).sum())  # also kept pixels without GT
    return {"visible_kept": m["visible_kept"], "hidden_removed": m["hidden_removed"], "wrong": wrong,
            "n_visible": int(sc["expected_visible"].sum()), "n_hidden": int(sc["n_hidden"])}


def block_truth(tolerance=TRUTH_TOLERANCE):
    """Truth for the sample block's LiDAR: per point of ``lidar.laz`` its left pixel, disparity and visibility.

    Regenerates the scene and the scan of ``riverbed sample --size small --seed 0`` (checked to be the points of
    ``lidar.laz`` to 1 mm) and casts a ray from each camera centre towards each point.

    Returns
    -------
    dict
        ``pair``, ``gt`` (the GT disparity map), ``rows``, ``cols``, ``disp`` (of the points in both images, in
        front of both cameras), ``visible`` and ``hidden`` (bool over those points; outliers and noise in
        neither), ``kind``.
    """
    from riverbed_cli.sample.layout import build_scene
    from riverbed_cli.sample.raycast import cast_rays
    from riverbed_cli.sample.scan import simulate_scan
    from riverbed_cli.sample.spec import SIZES

    spec = SIZES["small"]
    scene = build_scene(spec, 0)
    lidar = simulate_scan(scene, spec, 0)
    pair = load_pairfile(BLOCK / "pair.yaml")
    las = laspy.read(str(BLOCK / "lidar.laz"))
    xyz = np.asarray(las.xyz) - pair.origin
    if len(xyz) != len(lidar["xyz"]) or np.abs(xyz - lidar["xyz"]).max() > 1e-3:
        raise SystemExit("the regenerated scan differs from sample_data/block/lidar.laz")
    H, W = pair.image_size
    xl, yl, xr, zl, yr, zr = pair.project(xyz, full=True)
    inside = (zl > 0) & (zr > 0)
    for v, lim in ((xl, W), (yl, H), (xr, W), (yr, H)):
        inside &= (v >= -0.5) & (v < lim - 0.5)
    seen = np.ones(len(xyz), bool)
    for c in pair.centres:
        vec = xyz - c
        dist = np.linalg.norm(vec, axis=1)
        t = cast_rays(scene, np.broadcast_to(c, vec.shape), vec / dist[:, None], 0.0, dist + 1.0)
        seen &= (t < 0) | (t >= dist - tolerance)
    kind = lidar["kind"][inside]
    surface = kind <= 1  # 0 first returns, 1 last returns under crowns; 2 outliers, 3 class-7 noise
    return {"pair": pair, "gt": read_disparity(BLOCK / "gt_disparity.tif"),
            "rows": np.floor(yl[inside] + 0.5).astype(np.int64), "cols": np.floor(xl[inside] + 0.5).astype(np.int64),
            "disp": (xl - xr)[inside], "visible": surface & seen[inside], "hidden": surface & ~seen[inside],
            "kind": kind}


def score_points(sparse, gt, rows, cols, disp, visible, hidden):
    """Visible kept (per pixel holding a visible point), hidden removed (per point), wrong pixels (> 1 px off)."""
    held = np.abs(sparse[rows, cols] - disp) <= MATCH  # NaN compares False
    W = sparse.shape[1]
    pix = rows * W + cols
    vis_pix = np.unique(pix[visible])
    kept_pix = np.unique(pix[visible & held])
    ok = np.isfinite(sparse)
    wrong = int((ok & ~(np.abs(sparse - gt) <= 1.0)).sum())
    return {"visible_kept": kept_pix.size / vis_pix.size, "hidden_removed": 1.0 - held[hidden].mean(),
            "wrong": wrong, "n_visible": int(vis_pix.size), "n_hidden": int(hidden.sum())}


def _scores(m):
    return {k: round(float(m[k]), 6) for k in ("visible_kept", "hidden_removed")} | {
        "wrong": int(m["wrong"]), "n_visible": int(m["n_visible"]), "n_hidden": int(m["n_hidden"])}


def run(data=None):
    rows = []
    for share in SHARES:
        with tempfile.TemporaryDirectory(prefix="bench_vis_") as tmp:
            sc, gt = cones_scene(share, tmp)
            for name, kw in RULES:
                sparse, _ = pj.project_cloud(Path(tmp) / "scene.las", sc["pair"], **kw)
                rows.append({"scene": "Cones", "share": share, "rule": name, **_scores(score_cones(sparse, gt, sc))})
            if share == 0.1:
                from test_cli_project import score

                for name, kw in ROUND_TRIP:
                    sparse, st = pj.project_cloud(Path(tmp) / "scene.las", sc["pair"], **kw)
                    m = score(sparse, gt, sc)
                    rows.append({"scene": "Cones round trip", "share": share, "options": name,
                                 **{k: round(float(m[k]), 6) for k in REQUIRED},
                                 "n_hidden": int(sc["n_hidden"]), "n_outliers": int(sc["n_outliers"]),
                                 "sor_removed": int(st["filtered"]["outliers"])})
    truth = block_truth()
    for name, kw in RULES + [AGGRESSIVE]:
        sparse, _ = pj.project_cloud(BLOCK / "lidar.laz", truth["pair"], **kw)
        m = score_points(sparse, truth["gt"], truth["rows"], truth["cols"], truth["disp"], truth["visible"],
                         truth["hidden"])
        rows.append({"scene": "sample block", "share": None, "rule": name, **_scores(m)})
    return rows


def row(rows, scene, rule, share=None):
    """The row of ``scene`` (``Cones``, ``sample block``) and ``rule`` (a label of :data:`RULES`)."""
    return next(r for r in rows if r["scene"] == scene and r.get("rule") == rule and r["share"] == share)


def _label(r):
    return f"Cones {100 * r['share']:.0f} %" if r["scene"] == "Cones" else r["scene"]


def _table(rows, rules):
    out = ["| scene | rule | visible kept | hidden removed | wrong pixels |", "|---|---|---:|---:|---:|"]
    for r in rows:
        if r.get("rule") in rules:
            out.append(f"| {_label(r)} | {r['rule']} | {100 * r['visible_kept']:.2f} % | "
                       f"{100 * r['hidden_removed']:.2f} % | {r['wrong']} |")
    return out


def reach_table(rows):
    """The ``edge_reach`` table (the z-buffer's rules; the block's hidden and visible counts)."""
    b = row(rows, "sample block", DEFAULT)
    return "\n".join(_table(rows, [n for n, kw in RULES if "visibility" not in kw] + [AGGRESSIVE[0]]) + [
        "", f"The block's truth: {b['n_visible']} pixels with a visible point, {b['n_hidden']} hidden points."])


def surface_table(rows):
    """The surface modes' table, beside the default."""
    return "\n".join(_table(rows, [DEFAULT] + [n for n, kw in RULES if "visibility" in kw]))


def round_trip_table(rows):
    """The round trip's figures under the command's options, and what tests/test_cli_project.py requires."""
    def cells(r):
        return [f"{r['max_error']:.4f} px", f"{100 * r['hidden_removed']:.2f} %",
                f"{100 * r['outliers_removed']:.1f} %", f"{100 * r['visible_kept']:.1f} %",
                f"{100 * r['right_occluded_removed']:.1f} %", str(r["sor_removed"])]
    trips = [r for r in rows if r["scene"] == "Cones round trip"]
    t = trips[0]
    out = [f"Cones, 10 % LiDAR: {t['n_hidden']:,} points hidden behind the surface, {t['n_outliers']} outliers "
           "floating above it.", "",
           "| options | max error at kept visible points | hidden removed | outliers removed | visible kept | "
           "right-hidden removed | SOR removed |", "|---|---:|---:|---:|---:|---:|---:|"]
    out += [f"| {r['options']} | " + " | ".join(cells(r)) + " |" for r in trips]
    req = {k: "all" if (v, how) == (1.0, "min") else f"{'<=' if how == 'max' else '>='} {100 * v:g} %"
           for k, (v, how) in REQUIRED.items()}
    out.append(f"| required of the defaults | <= {REQUIRED['max_error'][0]:g} px | {req['hidden_removed']} | "
               f"{req['outliers_removed']} | {req['visible_kept']} | {req['right_occluded_removed']} | |")
    return "\n".join(out)


TABLES = [(reach_table, "<!-- bench_visibility reach: begin -->", "<!-- bench_visibility reach: end -->"),
          (surface_table, "<!-- bench_visibility surface: begin -->", "<!-- bench_visibility surface: end -->"),
          (round_trip_table, "<!-- bench_visibility round trip: begin -->",
           "<!-- bench_visibility round trip: end -->")]


def main():
    rows_main(__doc__, run, TABLES)


if __name__ == "__main__":
    main()
