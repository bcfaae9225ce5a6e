"""LiDAR that disagrees with the images: a disparity offset on every LiDAR point (a height offset, another vertical
datum), estimated and removed by riverbed (``--lidar-offset auto``, the default), against the LiDAR kept as it is
(``--lidar-offset none``: the paper's method with today's tubes and fusion), unguided matching, the LiDAR alone and
the oracle (the clean LiDAR).

Every dev scene (Middlebury Cones, Reindeer, Cloth3, Wood2; the DublinCity aerial half tile) and the held-out KITTI
2015 frame, LiDAR sampled from the GT at 5 % and 1.23 % of the image pixels (seed 0), offsets of +-3 px and +-5 and
+-10 % of the LiDAR's disparity span. Errors (bad3 %, mean px) over the GT pixels not sampled.

The ground truths sampled as LiDAR are not exactly registered to their own images: the offset the images see in the
clean LiDAR (``clean est``) is what unguided stereo sees too. ``est - clean`` is the estimate of the added offset.

    python benchmarks/bench_faults.py [DATA] --write benchmarks/results_faults.json --docs docs/lidar_faults.md

``--write`` stores the rows (the committed result file), ``--docs`` rewrites the tables of docs/lidar_faults.md from
it (``tests/test_lidar_faults_doc.py`` checks that the committed doc is that rewrite, and the claims it states).
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import DEV_SCENES, KITTI2015, kitti2015, middlebury, rows_main  # noqa: E402

from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.densify import densify  # noqa: E402
from riverbed_cli.products.evaluate import evaluate_disparity  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402

AERIAL = "aerial_dublincity_fusionx3"
SHARES = (0.05, 0.0123)
#: offsets added to every LiDAR disparity: px, or a share of the LiDAR's disparity span
OFFSETS = (("+3 px", 3.0, None), ("-3 px", -3.0, None), ("+5 %", None, 0.05), ("-5 %", None, -0.05),
           ("+10 %", None, 0.10), ("-10 %", None, -0.10))
BEGIN, END = "<!-- bench_faults: begin -->", "<!-- bench_faults: end -->"


def scenes(data):
    from riverbed_cli.io.disparity import read_disparity
    from riverbed_cli.io.images import read_image

    out = [(n, *(lambda s: (s.left, s.right, s.gt))(middlebury(data, n))) for n in DEV_SCENES]
    base = Path(data) / AERIAL
    out.append(("Dublin aerial", read_image(base / "left.png"), read_image(base / "right.png"),
                read_disparity(base / "gt.png", scale=256)))
    if (Path(data) / KITTI2015).is_dir():
        k = kitti2015(data)
        out.append((f"{k.name} (held out)", k.left, k.right, k.gt))
    return out


def _score(disp, gt, sparse):
    e = evaluate_disparity(disp, gt, exclude=sparse)
    return [round(float(e["bad3"]), 3), round(float(e["avg"]), 4)]


def run(data):
    rows = []
    for name, left, right, gt in scenes(data):
        for share in SHARES:
            sparse = simulate_lidar(gt, share, seed=0)
            vals = sparse[np.isfinite(sparse)]
            span = float(vals.max() - vals.min())
            t0 = time.perf_counter()
            clean = match_pair(left, right, sparse)
            unguided = match_pair(left, right, None, int(np.floor(vals.min())) - 8, int(np.ceil(vals.max())) + 8,
                                  guide="none").disparity
            resid = unguided - gt
            near = np.isfinite(resid) & (np.abs(resid) < 2)  # the stereo's view of where the GT sits
            base = {"scene": name, "share": share, "span": round(span, 2),
                    "clean_estimate": clean.info["lidar_offset"]["estimated"],
                    "gt_minus_stereo": round(-float(np.median(resid[near])), 3),
                    "oracle": _score(clean.disparity, gt, sparse), "unguided": _score(unguided, gt, sparse)}
            for label, px, rel in OFFSETS:
                off = px if px is not None else rel * span
                biased = sparse + np.float32(off)
                auto = match_pair(left, right, biased)
                kept = match_pair(left, right, biased, lidar_offset="none", lidar_check="off")
                lidar = densify(biased, "planes")
                rows.append({**base, "offset": label, "offset_px": round(off, 3),
                             "estimated": auto.info["lidar_offset"]["estimated"],
                             "applied": auto.info["lidar_offset"]["applied"],
                             "default": _score(auto.disparity, gt, sparse),
                             "kept": _score(kept.disparity, gt, sparse),
                             "lidar_only": _score(lidar, gt, sparse),
                             "seconds_offset": auto.info["stages"]["lidar_offset"],
                             "seconds_default": auto.info["seconds"]})
            print(f"{name} {share:.2%}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return rows


def tables(rows):
    """The Markdown tables of docs/lidar_faults.md from the result rows."""
    out = ["LiDAR shares are of the image pixels (sampled from the GT, seed 0); errors over the GT pixels not sampled; "
           "cells are bad3 % / mean px. `default`: the offset estimated and removed (`--lidar-offset auto`); "
           "`kept`: the LiDAR as given (`--lidar-offset none --lidar-check off`); `LiDAR only`: the offset LiDAR "
           "interpolated by local planes (`riverbed densify --method planes`); `oracle`: the clean LiDAR, default "
           "settings.", "",
           "`estimate error`: the estimate minus the clean LiDAR's (below) minus the offset added (px).", "",
           "| scene | LiDAR | offset | estimate error px | default | kept | unguided | LiDAR only | oracle |",
           "|---|---:|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        cell = lambda v: f"{v[0]:.2f} / {v[1]:.3f}"  # noqa: E731
        out.append(f"| {r['scene']} | {r['share'] * 100:.2f} % | {r['offset']} ({r['offset_px']:+.2f} px) | "
                   f"{r['estimated'] - r['clean_estimate'] - r['offset_px']:+.2f} | {cell(r['default'])} | "
                   f"{cell(r['kept'])} | {cell(r['unguided'])} | {cell(r['lidar_only'])} | {cell(r['oracle'])} |")
    out += ["", "The offset the images see in the clean LiDAR (`clean est`, px, LiDAR minus images), beside the GT's "
            "offset from unguided stereo (median of GT minus stereo where they differ by less than 2 px), and the "
            "share of the default match's `seconds` the estimate takes (median over the six offsets):", "",
            "| scene | LiDAR | clean est px | GT - unguided stereo px | estimate's share of `seconds` |",
            "|---|---:|---:|---:|---:|"]
    seen = set()
    for r in rows:
        key = (r["scene"], r["share"])
        if key in seen:
            continue
        seen.add(key)
        shares = [x["seconds_offset"] / x["seconds_default"] for x in rows if (x["scene"], x["share"]) == key]
        out.append(f"| {r['scene']} | {r['share'] * 100:.2f} % | {r['clean_estimate']:+.2f} | "
                   f"{r['gt_minus_stereo']:+.2f} | {np.median(shares) * 100:.0f} % |")
    return "\n".join(out)


def main():
    rows_main(__doc__, run, tables, BEGIN, END)


if __name__ == "__main__":
    main()
