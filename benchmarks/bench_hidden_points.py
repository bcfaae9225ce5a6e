"""Hidden point removal in ``riverbed project``: the z-buffer with a footprint (the default) against the nearest point
per pixel only, fixed footprints and HPR (Katz et al. 2007), on three scenes.

    python benchmarks/bench_hidden_points.py [DATA] --write benchmarks/results_hidden_points.json \\
        --docs docs/projection.md

1. The round-trip scene of tests/test_cli_project.py: the Cones ground truth as LiDAR at 5, 10 and 30 % of the
   pixels, hidden points behind the surface at 20 % of the other pixels and behind every tenth visible point on its
   own ray: the share of hidden points removed, of points visible in both views kept, of left-visible points the
   right camera cannot see removed, the largest error of a kept point, and the visibility stage's seconds.
2. The bundled sample aerial block (synthetic LiDAR with ground-truth disparity): points kept and removed, and kept
   points more than 1 and 0.5 px off the truth (hidden points that survived).
3. The real KITTI frame (``DATA``): points kept and removed, and the median photometric error |I_L(x) - I_R(x - d)|
   of each set (a hidden point matches badly).

``--write`` stores the rows (the committed result file), ``--docs`` rewrites the tables of docs/projection.md from it
(``tests/test_hidden_points_doc.py`` checks the doc and the claims its text makes on the committed rows).
"""

import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "tests"))
from datasets import rows_main  # noqa: E402
from kitti_lidar_demo import KITTI, photometric  # noqa: E402
from test_cli_project import build_scene, score  # noqa: E402  (the round-trip scene of the tests)

from riverbed_cli.geometry.cameras import kitti_pair  # noqa: E402
from riverbed_cli.geometry.pairfile import load_pairfile  # noqa: E402
from riverbed_cli.geometry.projection import project_cloud  # noqa: E402
from riverbed_cli.io.disparity import read_disparity  # noqa: E402

BEGIN, END = "<!-- bench_hidden_points: begin -->", "<!-- bench_hidden_points: end -->"
DEFAULT = "z-buffer, footprint auto (default)"
#: the methods compared: (label, project_cloud keywords)
METHODS = [("nearest point per pixel only", {"visibility": "none"}), (DEFAULT, {}),
           ("z-buffer, footprint auto, tolerance 2 px, slope 1", {"tolerance": 2.0, "slope": 1.0})]
METHODS += [(f"z-buffer, footprint {r}", {"footprint": r}) for r in (2, 3, 4)]
METHODS += [(f"HPR, gamma {g}", {"visibility": "hpr", "hpr_gamma": g}) for g in (3.0, 3.5, 4.0)]
SHARES = (0.05, 0.1, 0.3)


def cones_rows():
    gt = read_disparity(ROOT / "tests/data/cones/disp2.png", scale=4)
    rows = []
    for share in SHARES:
        with tempfile.TemporaryDirectory(prefix="vis_") as tmp:
            sc = build_scene(Path(tmp), gt, share=share)
            for name, kw in METHODS:
                sparse, st = project_cloud(Path(tmp) / "scene.las", sc["pair"], **kw)
                m = score(sparse, gt, sc)
                rows.append({"scene": "Cones", "share": share, "method": name,
                             "hidden_removed": round(100 * m["hidden_removed"], 2),
                             "visible_kept": round(100 * m["visible_kept"], 1),
                             "right_hidden_removed": round(100 * m["right_occluded_removed"], 1),
                             "max_error": round(m["max_error"], 4),
                             "seconds": round(st["stage_seconds"]["visibility"], 2)})
    return rows


def block_rows():
    block = ROOT / "sample_data" / "block"
    pair = load_pairfile(block / "pair.yaml")
    gt = read_disparity(block / "gt_disparity.tif")
    rows = []
    for name, kw in METHODS:
        sparse, st = project_cloud(block / "lidar.laz", pair, **kw)
        ok = np.isfinite(sparse) & np.isfinite(gt)
        err = np.abs(sparse[ok] - gt[ok])
        rows.append({"scene": "sample block", "method": name, "kept": int(st["kept"]), "compared": int(ok.sum()),
                     "removed": int(st["occluded"]["left"] + st["occluded"]["right"]),
                     "wrong_1px": int((err > 1).sum()), "wrong_half_px": int((err > 0.5).sum())})
    return rows


def kitti_rows(data):
    base = Path(data) / KITTI
    pair = kitti_pair(base / "calib.txt")
    L, R = cv2.imread(str(base / "left.png")), cv2.imread(str(base / "right.png"))
    shape = L.shape[:2]
    ref, _ = project_cloud(base / "lidar.bin", pair, visibility="none", shape=shape)
    rows = []
    for name, kw in METHODS:
        sparse, st = project_cloud(base / "lidar.bin", pair, shape=shape, **kw)
        removed = np.where(np.isfinite(ref) & ~np.isfinite(sparse), ref, np.nan)
        n_removed = int(np.isfinite(removed).sum())
        rows.append({"scene": "KITTI", "method": name, "kept": int(st["kept"]), "removed": n_removed,
                     "dI_kept": round(photometric(L, R, sparse), 2),
                     "dI_removed": round(photometric(L, R, removed), 2) if n_removed else None})
    return rows


def run(data):
    return cones_rows() + block_rows() + kitti_rows(data)


def _bold(r, text):
    return f"**{text}**" if r["method"] == DEFAULT else text


def tables(rows):
    """docs/projection.md's three tables."""
    out = ["| LiDAR share | method | hidden removed | visible kept | right-hidden removed | max error (px) | s |",
           "|---:|---|---:|---:|---:|---:|---:|"]
    for r in (r for r in rows if r["scene"] == "Cones"):
        hidden, visible = f"{r['hidden_removed']:.2f} %", f"{r['visible_kept']:.1f} %"
        out.append(f"| {100 * r['share']:.0f} % | {_bold(r, r['method'])} | {_bold(r, hidden)} | {_bold(r, visible)} | "
                   f"{r['right_hidden_removed']:.1f} % | {r['max_error']:.4f} | {r['seconds']:.2f} |")
    out += ["", "Then the bundled sample aerial block (`sample_data/block`: airborne LiDAR under a nadir pair, "
            "synthetic, with ground-truth disparity; a kept point more than 1 px off the truth is a hidden point "
            "that survived):", "", "| sample block | kept | removed | kept with error > 1 px | > 0.5 px |",
            "|---|---:|---:|---:|---:|"]
    for r in (r for r in rows if r["scene"] == "sample block"):
        share = 100 * r["wrong_1px"] / r["compared"]
        out.append(f"| {_bold(r, r['method'])} | {r['kept']} | {r['removed']} | {r['wrong_1px']} ({share:.2f} %) | "
                   f"{r['wrong_half_px']} |")
    out += ["", "And the real KITTI frame (no ground truth: the median photometric error |I_L(x) - I_R(x - d)| of the "
            "points each method keeps and removes; a hidden point matches badly):", "",
            "| KITTI | kept | removed | median abs dI kept | median abs dI removed |", "|---|---:|---:|---:|---:|"]
    for r in (r for r in rows if r["scene"] == "KITTI"):
        dr = "–" if r["dI_removed"] is None else f"{r['dI_removed']:.2f}"
        out.append(f"| {_bold(r, r['method'])} | {r['kept']} | {r['removed']} | {r['dI_kept']:.2f} | {dr} |")
    return "\n".join(out)


def main():
    rows_main(__doc__, run, tables, BEGIN, END)


if __name__ == "__main__":
    main()
