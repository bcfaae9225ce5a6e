"""The real LiDAR case: KITTI object frame -> pair file -> sparse LiDAR disparities -> guided matching.

Usage: python benchmarks/kitti_lidar_demo.py DATA_DIR [--out docs] [--work DIR]

DATA_DIR is the shared data folder (``../shared/data``); the KITTI frame stays there (CC BY-NC-SA: never
copied into the repository). Runs the real CLI (``riverbed pair kitti``, ``riverbed project``, ``riverbed
match``) and prints:

- the projection counts and the photometric check: median |I_left(x, y) - I_right(x - d, y)| at the LiDAR
  pixels, against the same with the disparity off by +-3 px;
- held-out accuracy: half of the LiDAR pixels (seeded) guide ``match``; every map is scored on the other half
  (LiDAR as sparse ground truth): unguided matching on the same range, riverbed with the default fusion and
  without it (``--fusion none``), and the LiDAR-only interpolations of the guiding half (``riverbed densify``
  nearest, linear, guided);
- writes OUT/kitti_guided.png and OUT/kitti_unguided.png: colourised maps guided by *all* LiDAR pixels and
  unguided, on one colour scale.
"""

import argparse
import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.io.disparity import read_disparity, write_disparity
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.visualize import colorize_disparity, write_png

KITTI = "kitti_object_stereo_lidar_stereorcnn/demo"


def run(args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    if r.exit_code != 0:
        raise SystemExit(f"riverbed {' '.join(map(str, args))} failed:\n{r.output}")
    return r.stdout


def photometric(left, right, sparse, offset=0.0):
    """Median |I_L(x, y) - I_R(x - d + offset, y)| over the LiDAR pixels (grey, linear interpolation in x)."""
    L = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY).astype(np.float64)
    R = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY).astype(np.float64)
    rows, cols = np.nonzero(np.isfinite(sparse))
    xs = cols - sparse[rows, cols].astype(np.float64) + offset
    ok = (xs >= 0) & (xs <= R.shape[1] - 1)
    rows, cols, xs = rows[ok], cols[ok], xs[ok]
    x0 = np.floor(xs).astype(int)
    x1 = np.minimum(x0 + 1, R.shape[1] - 1)
    f = xs - x0
    return float(np.median(np.abs(L[rows, cols] - (R[rows, x0] * (1 - f) + R[rows, x1] * f))))


def pipeline(data_dir, work):
    """Pair file, sparse map and photometric figures; returns (paths, summary)."""
    base = Path(data_dir) / KITTI
    left, right = base / "left.png", base / "right.png"
    pair, sparse = work / "kitti.yaml", work / "lidar.tif"
    run(["pair", "kitti", base / "calib.txt", "-o", pair, "--left", left, "--right", right, "--overwrite"])
    stats = json.loads(run(["project", base / "lidar.bin", pair, "-o", sparse, "--json", "--overwrite"]))
    s = read_disparity(sparse)
    L, R = cv2.imread(str(left)), cv2.imread(str(right))
    photo = {f"{o:+d}" if o else "0": photometric(L, R, s, o) for o in (0, -3, 3)}
    paths = {"left": left, "right": right, "pair": pair, "sparse": sparse}
    return paths, {"project": stats, "photometric": photo}


def edge_share(sparse, dropped, reach=8, step=3.0):
    """Share of the ``dropped`` LiDAR pixels with another LiDAR point within ``reach`` px at least ``step`` px
    nearer (a larger disparity): points behind a depth edge, which the LiDAR sees and the camera may not."""
    near = cv2.dilate(np.nan_to_num(sparse, nan=-1e9).astype(np.float32), np.ones((2 * reach + 1,) * 2, np.uint8))
    rows, cols = np.nonzero(dropped)
    if rows.size == 0:
        return 0.0
    return float(np.mean(near[rows, cols] >= sparse[rows, cols] + step))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data_dir")
    ap.add_argument("--out", default="docs", help="Folder for kitti_guided.png and kitti_unguided.png.")
    ap.add_argument("--work", default=None, help="Folder for intermediate files (default: a temporary one).")
    args = ap.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="kitti_"))
    work.mkdir(parents=True, exist_ok=True)
    paths, summary = pipeline(args.data_dir, work)
    st = summary["project"]
    print(f"project: {st['points_read']} read, {st['behind_camera']} behind, {st['outside']} outside, "
          f"{st['row_offset']} off the row, {st['filtered']['outliers']} outliers, occluded "
          f"{st['occluded']}, {st['kept']} kept (share {st['lidar_share']:.4f}, window {st['window']}), "
          f"d {st['d_range']}, "
          f"{st['seconds']:.2f} s")
    ph = summary["photometric"]
    print(f"photometric median |dI|: at x-d {ph['0']:.2f}, at x-d-3 {ph['-3']:.2f}, at x-d+3 {ph['+3']:.2f}")

    sparse = read_disparity(paths["sparse"])
    lo, hi = int(np.floor(np.nanmin(sparse))) - 4, int(np.ceil(np.nanmax(sparse))) + 4
    rng = np.random.default_rng(0)
    guide_half = sparse.copy()
    held = np.isfinite(sparse) & (rng.random(sparse.shape) < 0.5)
    guide_half[held] = np.nan
    truth = np.where(held, sparse, np.nan)
    write_disparity(work / "half.tif", guide_half, overwrite=True)
    rows = []
    common = [paths["left"], paths["right"], "--min-disp", lo, "--max-disp", hi, "--overwrite"]
    runs = (("unguided", ["--guide", "none"]),
            ("riverbed + fusion (default), half the LiDAR", ["--sparse", work / "half.tif", "--lidar-mask",
                                                            work / "mask.png"]),
            ("riverbed + fusion, LiDAR check off, half the LiDAR", ["--sparse", work / "half.tif", "--lidar-check",
                                                                   "off"]),
            ("riverbed, no fusion, half the LiDAR", ["--sparse", work / "half.tif", "--fusion", "none"]),
            ("riverbed, all LiDAR", ["--sparse", paths["sparse"]]))
    for name, extra in runs:
        out = work / f"run_{len(rows)}.tif"
        info = json.loads(run(["match", *common, *extra, "-o", out, "--json"]))
        disp = read_disparity(out)
        m = evaluate_disparity(disp, truth) if "all" not in name else None
        rows.append((name, info, m, disp))
    for method in ("nearest", "linear", "guided"):
        out = work / f"densify_{method}.tif"
        info = json.loads(run(["densify", work / "half.tif", "-o", out, "--method", method, "--image",
                               paths["left"], "--json", "--overwrite"]))
        disp = read_disparity(out)
        rows.append((f"LiDAR only: {method} interpolation of half the LiDAR", info, evaluate_disparity(disp, truth),
                     disp))
    check = rows[1][1]["lidar_check"]
    mask = cv2.imread(str(work / "mask.png"), cv2.IMREAD_UNCHANGED)
    dropped = (mask == 2) | (mask == 3)
    print(f"LiDAR check (half the LiDAR): {check['points']} points, {check['outliers']} outliers and "
          f"{check['changed']} in {check['regions']} changed regions dropped; {edge_share(guide_half, dropped):.0%} "
          "of the dropped points lie at a LiDAR depth edge (a point within 8 px more than 3 px nearer)")
    print("\n| matching | window | >1 px | >3 px | mean abs (px) | seconds |\n|---|---:|---:|---:|---:|---:|")
    for name, info, m, _ in rows:
        if m is None:
            continue
        print(f"| {name} | {info.get('window') or '-'} | {m['bad1']:.1f} % | {m['bad3']:.1f} % | "
              f"{m['avg']:.2f} | {info['seconds']:.1f} |")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    unguided, guided = rows[0][3], rows[4][3]
    for name, disp in (("kitti_unguided.png", unguided), ("kitti_guided.png", guided)):
        write_png(out / name, colorize_disparity(disp, lo, hi), overwrite=True)
        print(f"wrote {out / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
