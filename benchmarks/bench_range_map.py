"""Coarse to fine without LiDAR, as tSGM does: a match at half resolution, `riverbed range-map --like`, the match
in its ranges, against the full range (docs/tubes.md, "Range maps from a previous run").

    python benchmarks/bench_range_map.py [DATA] [--write benchmarks/results_range_map.json] [--docs docs/tubes.md]

On the 740 x 500 speed pair (Reindeer, 0..79) and, with DATA holding it, the 1024 x 1024 Dublin aerial pair
(0..143), each step a fresh ``riverbed`` process (``seconds`` from ``--json``): unguided census SGM over the full
range; the same on the images halved (``cv2.INTER_AREA``) over half the range; ``riverbed range-map HALF --like
LEFT --window 2 --margin 4``; unguided SGM in those ranges. Errors over the GT pixels inside the range (bad3 %, mean
px; a GT pixel left without a disparity counts as bad).
"""

import math
import sys
import tempfile
import textwrap
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_rpc_ventoux import riverbed  # noqa: E402  (runs the CLI as a user would)
from bench_tubes import AERIAL, aerial  # noqa: E402
from datasets import rows_main, speed_scene  # noqa: E402

from riverbed_cli.io.disparity import read_disparity  # noqa: E402
from riverbed_cli.products.evaluate import evaluate_disparity  # noqa: E402

BEGIN, END = "<!-- bench_range_map: begin -->", "<!-- bench_range_map: end -->"
WINDOW, MARGIN = 2, 4


def pair_row(label, left, right, gt, d_max, work):
    """One pair's figures (dict)."""
    gt = np.where(gt <= d_max, gt, np.nan).astype(np.float32)
    paths = {n: work / f"{n}.png" for n in ("l", "r", "lh", "rh")}
    half = [cv2.resize(im, (im.shape[1] // 2, im.shape[0] // 2), interpolation=cv2.INTER_AREA) for im in (left, right)]
    for n, im in zip(paths, (left, right, *half)):
        cv2.imwrite(str(paths[n]), cv2.cvtColor(im, cv2.COLOR_RGB2BGR) if im.ndim == 3 else im)
    out = ("--json", "--overwrite")
    full = riverbed("match", paths["l"], paths["r"], "--guide", "none", "--min-disp", 0, "--max-disp", d_max,
                    "--tile", 0, "-o", work / "full.tif", *out)
    coarse = riverbed("match", paths["lh"], paths["rh"], "--guide", "none", "--min-disp", 0, "--max-disp",
                      math.ceil(d_max / 2), "--tile", 0, "-o", work / "half.tif", *out)
    ranges = riverbed("range-map", work / "half.tif", "--like", paths["l"], "--window", WINDOW, "--margin", MARGIN,
                      "--min-disp", 0, "--max-disp", d_max, "-o", work / "ranges.tif", *out)
    fine = riverbed("match", paths["l"], paths["r"], "--guide", "none", "--min-disp", 0, "--max-disp", d_max,
                    "--range-map", work / "ranges.tif", "--tile", 0, "-o", work / "fine.tif", *out)

    def scores(path):
        e = evaluate_disparity(read_disparity(path), gt)
        return [float(e["bad3"]), float(e["avg"])]

    return {"pair": label, "d_max": d_max, "full_seconds": full["seconds"], "full": scores(work / "full.tif"),
            "half_seconds": coarse["seconds"], "range_map_seconds": ranges.get("seconds"),
            "fine_seconds": fine["seconds"], "mean_width": (fine.get("tubes") or {}).get("mean_width"),
            "fine": scores(work / "fine.tif")}


def run(data):
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        left, right, gt = speed_scene(data)
        rows.append(pair_row("740x500 speed pair, 0..79", left, right, gt, 79, Path(tmp)))
        if (Path(data) / AERIAL).is_dir():
            left, right, gt = aerial(data, pad_to=1024)
            rows.append(pair_row("1024x1024 Dublin aerial, 0..143", left, right, gt, 143, Path(tmp)))
    return rows


def tables(rows):
    out = ["| pair | full range: s, bad3 % / avg px | half resolution s + `range-map` s + in its ranges s (mean "
           "width) | bad3 % / avg px |", "|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['pair']} | {r['full_seconds']:.3f}, {r['full'][0]:.2f} / {r['full'][1]:.3f} | "
                   f"{r['half_seconds']:.3f} + {r['range_map_seconds']:.3f} + {r['fine_seconds']:.3f} "
                   f"({r['mean_width']:.1f}) | {r['fine'][0]:.2f} / {r['fine'][1]:.3f} |")
    text = []
    for r in rows:
        total = r["half_seconds"] + r["range_map_seconds"] + r["fine_seconds"]
        text.append(f"{r['pair']}: mean error {r['full'][1]:.3f} -> {r['fine'][1]:.3f} px, bad3 {r['full'][0]:.2f} -> "
                    f"{r['fine'][0]:.2f} %, in {total / r['full_seconds']:.2f}x the full range's matching time.")
    return "\n".join(out) + "\n\n" + textwrap.fill(" ".join(text), 116, break_on_hyphens=False)


def main():
    rows_main(__doc__, run, tables, BEGIN, END)


if __name__ == "__main__":
    main()
