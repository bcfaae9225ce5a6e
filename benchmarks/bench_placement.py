"""riverbed against OpenCV StereoSGBM on the speed pair, told apart by where the VM placed its two vCPUs.

Usage: python benchmarks/bench_placement.py [DATA_DIR] [--minutes 10] [--near 200] [--far 350] [--before REV]

The dev VM's two vCPUs sit either on cores that share their caches (a cache line's round trip between two threads
about 100 ns) or on cores far apart (about 500 ns), in periods of ten seconds to minutes (``core_latency.py``). Far
apart, riverbed's stages that hand arrays from one thread to the other slow down, and the speed ratios of
``bench_tubes.py`` (medians over rounds) land on whichever placement the run met. Here each round is: the probe,
OpenCV (MODE_HH and MODE_SGBM_3WAY, warm calls in a process of their own: ``opencv_timer.py``), a fresh ``riverbed
match --paths 4 --fusion none`` and a fresh default ``riverbed match`` (``seconds`` from ``--json``), the probe
again. Rounds whose two probes agree are reported by placement: the medians of the times and of each round's
ratios. The pair is the 740 x 500 Reindeer, 0..79, 5 % LiDAR cut at the range (``datasets.speed_pair``). With
``--before REV`` each round also runs commit REV's ``--paths 4 --fusion none`` (from an exported copy of its
sources, as ``bench_startup.py`` does), so that a change is compared in the same placements.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_match import opencv_grey_files, opencv_times_apart  # noqa: E402
from bench_startup import export, run  # noqa: E402
from datasets import rewrite_block, speed_pair  # noqa: E402

from riverbed_cli.io.disparity import write_disparity  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
FOUR = ["--paths", "4", "--fusion", "none"]


def probe():
    """The two CPUs' cache-line round trip (ns), from a process of its own."""
    p = subprocess.run([sys.executable, str(HERE / "core_latency.py")], capture_output=True, text=True, check=True)
    return float(p.stdout)


def placement(first, last, near, far):
    """A round's placement from its two probes (ns): near, far, or changed (the probes disagree)."""
    if first < near and last < near:
        return "near"
    return "far" if first > far and last > far else "changed"


FOUR_NAME, FUSED_NAME = "4 paths, --fusion none", "default (8 paths, fused)"
#: the markers of docs/tubes.md's block
BEGIN, END = "<!-- bench_placement: begin -->", "<!-- bench_placement: end -->"


def measure(data_dir, minutes, near, far, before=None):
    """The rounds (module docstring): ``{"minutes", "near", "far", "before", "rounds": [{"placement", "probes",
    "opencv": {mode: s}, "riverbed": {variant: s}}]}``."""
    left, right, sparse = speed_pair(data_dir)
    rounds = []
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as old:
        variants = {FOUR_NAME: (FOUR, ROOT), FUSED_NAME: ([], ROOT)}
        if before:
            variants[f"commit {before}, 4 paths, --fusion none"] = (FOUR, export(before, old))
        for n, img in (("l.png", left), ("r.png", right)):
            cv2.imwrite(os.path.join(tmp, n), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        grey = opencv_grey_files(left, right, tmp)
        write_disparity(os.path.join(tmp, "s.tif"), sparse)
        base = [os.path.join(tmp, "l.png"), os.path.join(tmp, "r.png"), "--sparse", os.path.join(tmp, "s.tif"),
                "--min-disp", "0", "--max-disp", "79", "--tile", "0", "-o", os.path.join(tmp, "d.tif")]
        for extra, path in variants.values():
            run(path, base + extra, {})  # each copy's Numba cache filled (or checked) once
        end = time.monotonic() + 60 * minutes
        while time.monotonic() < end:
            first = probe()
            cv = {m: float(np.median(t)) for m, t in opencv_times_apart(grey, 0, 79, ("HH", "SGBM_3WAY"), 3).items()}
            rb = {name: run(path, base + extra, {})[1] for name, (extra, path) in variants.items()}
            last = probe()
            rounds.append({"placement": placement(first, last, near, far), "probes": [first, last], "opencv": cv,
                           "riverbed": rb})
            print(f"round {len(rounds)}: probes {first:.0f} / {last:.0f} ns, OpenCV 3WAY {cv['SGBM_3WAY']:.4f} s, "
                  + ", ".join(f"{k} {v:.4f} s" for k, v in rb.items()), file=sys.stderr, flush=True)
    return {"minutes": minutes, "near": near, "far": far, "before": before, "rounds": rounds}


def summary(res):
    """Per placement: ``{kind: {"rounds", "3way", "four", "four_x_3way", "fused_x_hh", "four_x_before"}}`` (medians;
    ratios the medians of each round's)."""
    out = {}
    for kind in ("near", "far", "changed"):
        sel = [r for r in res["rounds"] if r["placement"] == kind]
        if not sel:
            continue
        hh = np.array([r["opencv"]["HH"] for r in sel])
        w3 = np.array([r["opencv"]["SGBM_3WAY"] for r in sel])
        four = np.array([r["riverbed"][FOUR_NAME] for r in sel])
        fused = np.array([r["riverbed"][FUSED_NAME] for r in sel])
        row = {"rounds": len(sel), "3way": float(np.median(w3)), "four": float(np.median(four)),
               "four_x_3way": float(np.median(four / w3)), "fused_x_hh": float(np.median(fused / hh))}
        if res.get("before"):
            old = np.array([r["riverbed"][f"commit {res['before']}, 4 paths, --fusion none"] for r in sel])
            row["four_x_before"] = float(np.median(four / old))
        out[kind] = row
    return out


def table(res):
    """docs/tubes.md's block: the rounds by placement."""
    labels = {"near": "near", "far": "far", "changed": "changed during the round"}
    lines = [f"{len(res['rounds'])} rounds in {res['minutes']:g} minutes (near: both probes under {res['near']:g} ns, "
             f"far: both over {res['far']:g} ns):", "",
             "| placement | rounds | OpenCV 3WAY s | `--paths 4 --fusion none` s | x 3WAY | fused default x HH |",
             "|---|---:|---:|---:|---:|---:|"]
    for kind, r in summary(res).items():
        bold = "**" if kind != "changed" else ""
        lines.append(f"| {labels[kind]} | {r['rounds']} | {r['3way']:.4f} | {r['four']:.4f} | "
                     f"{bold}{r['four_x_3way']:.2f}{bold} | {r['fused_x_hh']:.2f} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data_dir", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--near", type=float, default=200.0, help="round trips below this (ns): caches shared")
    ap.add_argument("--far", type=float, default=350.0, help="round trips above this (ns): cores far apart")
    ap.add_argument("--before", help="also run this commit's --paths 4 --fusion none each round")
    ap.add_argument("--write", help="store the rounds in this JSON file (benchmarks/results_placement.json)")
    ap.add_argument("--rows", help="take the rounds from this JSON file instead of running")
    ap.add_argument("--docs", help="rewrite this Markdown file's block (docs/tubes.md)")
    args = ap.parse_args()
    res = (json.loads(Path(args.rows).read_text()) if args.rows
           else measure(args.data_dir, args.minutes, args.near, args.far, args.before))
    if args.write:
        Path(args.write).write_text(json.dumps(res, indent=1) + "\n")
    if args.docs:
        rewrite_block(args.docs, BEGIN, END, table(res))
    print(table(res))
    for kind, r in summary(res).items():
        if "four_x_before" in r:
            print(f"{kind}: 4 paths x commit {res['before']}: {r['four_x_before']:.3f}")


if __name__ == "__main__":
    main()
