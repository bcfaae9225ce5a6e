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
from datasets import speed_pair  # noqa: E402

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


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data_dir", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--near", type=float, default=200.0, help="round trips below this (ns): caches shared")
    ap.add_argument("--far", type=float, default=350.0, help="round trips above this (ns): cores far apart")
    ap.add_argument("--before", help="also run this commit's --paths 4 --fusion none each round")
    args = ap.parse_args()
    left, right, sparse = speed_pair(args.data_dir)
    rounds = []
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as old:
        variants = {"4 paths, --fusion none": (FOUR, ROOT), "default (8 paths, fused)": ([], ROOT)}
        older = f"commit {args.before}, 4 paths, --fusion none" if args.before else None
        if older:
            variants[older] = (FOUR, export(args.before, old))
        for n, img in (("l.png", left), ("r.png", right)):
            cv2.imwrite(os.path.join(tmp, n), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        grey = opencv_grey_files(left, right, tmp)
        write_disparity(os.path.join(tmp, "s.tif"), sparse)
        base = [os.path.join(tmp, "l.png"), os.path.join(tmp, "r.png"), "--sparse", os.path.join(tmp, "s.tif"),
                "--min-disp", "0", "--max-disp", "79", "--tile", "0", "-o", os.path.join(tmp, "d.tif")]
        for extra, path in variants.values():
            run(path, base + extra, {})  # each copy's Numba cache filled (or checked) once
        end = time.monotonic() + 60 * args.minutes
        while time.monotonic() < end:
            first = probe()
            cv = {m: float(np.median(t)) for m, t in opencv_times_apart(grey, 0, 79, ("HH", "SGBM_3WAY"), 3).items()}
            rb = {name: run(path, base + extra, {})[1] for name, (extra, path) in variants.items()}
            last = probe()
            rounds.append((placement(first, last, args.near, args.far), cv, rb))
            print(f"round {len(rounds)}: probes {first:.0f} / {last:.0f} ns, OpenCV 3WAY {cv['SGBM_3WAY']:.4f} s, "
                  + ", ".join(f"{k} {v:.4f} s" for k, v in rb.items()), file=sys.stderr, flush=True)
    print(f"\n### riverbed and OpenCV by vCPU placement ({len(rounds)} rounds, {args.minutes:g} min)\n")
    print("| placement (round trip) | rounds | OpenCV HH s | OpenCV 3WAY s | riverbed | seconds | vs HH | vs 3WAY |"
          + (f" vs commit {args.before} |" if older else ""))
    print("|---|---:|---:|---:|---|---:|---:|---:|" + ("---:|" if older else ""))
    for kind, label in (("near", f"near (< {args.near:g} ns)"), ("far", f"far (> {args.far:g} ns)"),
                        ("changed", "changed during the round")):
        sel = [r for r in rounds if r[0] == kind]
        if not sel:
            print(f"| {label} | 0 | | | | | | |" + (" |" if older else ""))
            continue
        hh = np.array([r[1]["HH"] for r in sel])
        w3 = np.array([r[1]["SGBM_3WAY"] for r in sel])
        for name in variants:
            s = np.array([r[2][name] for r in sel])
            vs = ""
            if older:  # the median of each round's ratio to the older commit's 4-path match
                vs = f" {np.median(s / np.array([r[2][older] for r in sel])):.2f} |" if "4 paths" in name else " |"
            print(f"| {label} | {len(sel)} | {np.median(hh):.3f} | {np.median(w3):.4f} | {name} | {np.median(s):.4f} | "
                  f"{np.median(s / hh):.2f} | {np.median(s / w3):.2f} |" + vs)


if __name__ == "__main__":
    main()
