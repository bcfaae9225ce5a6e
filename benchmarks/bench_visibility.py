"""Hidden point removal against known visibility: Cones (round-trip scene) and the sample aerial block.

Usage: python benchmarks/bench_visibility.py [--before REV] [--reach 1,0.25] [--modes surface,surface+zbuffer:0.75]
[--shares 0.05,0.1,0.3] [--time]

Two scenes whose LiDAR points have a known visibility, each projected by ``project_cloud`` with the default
options (SOR, z-buffer in both views):

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
map. ``--before REV`` also runs ``riverbed_cli/geometry/visibility.py`` as it is at git revision ``REV`` (loaded
from ``git show``) for the before/after table; ``--reach`` lists the ``edge_reach`` values run with the working
tree's code (1 is the default). ``--time`` adds the visibility stage seconds on the block
(best of 5; noisy on a shared machine).
"""

import argparse
import contextlib
import importlib.util
import os
import subprocess
import sys
import tempfile
import types
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from riverbed_cli.geometry import projection as pj  # noqa: E402
from riverbed_cli.geometry.pairfile import load_pairfile  # noqa: E402
from riverbed_cli.io.disparity import read_disparity  # noqa: E402

BLOCK = ROOT / "sample_data" / "block"
#: A LiDAR point is hidden when the surface lies more than this before it on a camera ray (m). The range noise
#: is 0.04 m; 0.25 m behind a surface at 600 m is 0.2 px of disparity, which misguides nobody.
TRUTH_TOLERANCE = 0.25
#: A sparse pixel "holds" a point when it carries the point's disparity to this (px; float32 storage).
MATCH = 1e-3


def load_module(rev):
    """``riverbed_cli/geometry/visibility.py`` at git revision ``rev``, as a module (for the 'before' runs)."""
    src = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:riverbed_cli/geometry/visibility.py"],
                         capture_output=True, text=True, check=True).stdout
    folder = Path(tempfile.mkdtemp(prefix="vis_before_"))
    path = folder / "visibility_before.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("visibility_before", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    # The old zbuffer_visible has no edge_reach (project_cloud passes it last): drop it.
    return types.SimpleNamespace(zbuffer_visible=lambda *args: mod.zbuffer_visible(*args[:7]),
                                 hpr_visible=mod.hpr_visible)


@contextlib.contextmanager
def visibility_module(mod):
    """Run ``project_cloud`` with ``mod`` as its visibility module (None: the current one)."""
    saved = pj.vis
    if mod is not None:
        pj.vis = mod
    try:
        yield
    finally:
        pj.vis = saved


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


def run_block(truth, mod, kw, repeat=1):
    seconds = []
    with visibility_module(mod):
        for _ in range(repeat):
            sparse, st = pj.project_cloud(BLOCK / "lidar.laz", truth["pair"], **kw)
            seconds.append(st["stage_seconds"]["visibility"])
    m = score_points(sparse, truth["gt"], truth["rows"], truth["cols"], truth["disp"], truth["visible"],
                     truth["hidden"])
    m["seconds"] = min(seconds)
    m["kept"] = st["kept"]
    return m


def run_cones(scene, mod, kw, folder):
    sc, gt = scene
    with visibility_module(mod):
        sparse, st = pj.project_cloud(Path(folder) / "scene.las", sc["pair"], **kw)
    m = score_cones(sparse, gt, sc)
    m["seconds"] = st["stage_seconds"]["visibility"]
    m["kept"] = st["kept"]
    return m


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", default=None, help="Also run visibility.py of this git revision (e.g. ac957d7).")
    ap.add_argument("--reach", default="1,0.25", help="edge_reach values for the working tree (comma-separated).")
    ap.add_argument("--modes", default="surface,surface+zbuffer:1,surface+zbuffer:0.75",
                    help="Other visibility modes, MODE or MODE:EDGE_REACH (comma-separated; '' for none).")
    ap.add_argument("--shares", default="0.05,0.1,0.3", help="Cones LiDAR shares (comma-separated).")
    ap.add_argument("--time", action="store_true", help="Best of 5 visibility-stage seconds on the block.")
    args = ap.parse_args()
    versions = [(f"after, edge_reach {r}", None, {"edge_reach": float(r)}) for r in args.reach.split(",")]
    for item in filter(None, args.modes.split(",")):
        mode, _, reach = item.partition(":")
        kw = {"visibility": mode, **({"edge_reach": float(reach)} if reach else {})}
        versions.append((f"{mode}" + (f", edge_reach {reach}" if reach else ""), None, kw))
    if args.before:
        versions.insert(0, (f"before ({args.before})", load_module(args.before), {}))
    rows = []
    for share in (float(s) for s in filter(None, args.shares.split(","))):
        with tempfile.TemporaryDirectory(prefix="bench_vis_") as tmp:
            scene = cones_scene(share, tmp)
            for name, mod, kw in versions:
                rows.append((f"Cones {100 * share:.0f} %", name, run_cones(scene, mod, kw, tmp)))
    truth = block_truth()
    for name, mod, kw in versions:
        rows.append(("sample block", name, run_block(truth, mod, kw, 5 if args.time else 1)))
    print("| scene | code | visible kept | hidden removed | wrong pixels (> 1 px) | kept | visible | hidden | "
          "visibility s |\n|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for scene, name, m in rows:
        print(f"| {scene} | {name} | {100 * m['visible_kept']:.2f} % | {100 * m['hidden_removed']:.2f} % | "
              f"{m['wrong']} | {m['kept']} | {m['n_visible']} | {m['n_hidden']} | {m['seconds']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
