"""AD-Census (riverbed-guided) on LiDAR tubes against the full range, on the Middlebury dev scenes (and the dev aerial
pair when present): accuracy and warm speed, measured back to back in one process.

Usage: python benchmarks/bench_adcensus_tubes.py [DATA_DIR] [--shares 0.05,0.0123] [--repeat 2] [--no-aerial]

LiDAR is a seeded sample of the GT at a share of the *image* pixels (``simulate_lidar``, seed 0), as in
``bench_tubes.py``. Accuracy: bad3 % / avg px over GT pixels not sampled as LiDAR, the matcher alone (``fusion
none``) and with the fusion default. Speed: ``info["seconds"]`` of the matcher alone, full and tubes alternating,
the median of ``--repeat`` rounds after one warm-up of each; ``support`` is the number of raw costs the tube path
computes (the cross aggregation's first support layout) per pixel.
"""

import argparse
import math
import os
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_tubes import scenes  # noqa: E402

from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.evaluate import evaluate_disparity  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    ap.add_argument("--shares", default="0.05,0.0123")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--no-aerial", action="store_true")
    args = ap.parse_args()
    shares = [float(s) for s in args.shares.split(",")]
    print("| scene | LiDAR | full: bad3 / avg | tubes: bad3 / avg | fused full | fused tubes | width / nominal | "
          "support / px | full s | tubes s | speed-up |")
    print("|---|---:|---|---|---|---|---|---:|---:|---:|---:|")
    for name, left, right, gt in scenes(args.data):
        if args.no_aerial and "aerial" in name:
            continue
        d_max = int(math.ceil(np.nanmax(gt))) + 4
        for share in shares:
            sparse = simulate_lidar(gt, share, seed=0)
            res, secs = {}, {"full": [], "tube": []}
            for rng in ("full", "tube"):  # warm-up, and the accuracy (deterministic)
                res[rng] = match_pair(left, right, sparse, 0, d_max, matcher="adcensus", guide="riverbed",
                                      range=rng, fusion="none")
                res[rng + "_fused"] = match_pair(left, right, sparse, 0, d_max, matcher="adcensus",
                                                 guide="riverbed", range=rng)
            for _ in range(args.repeat):
                for rng in ("full", "tube"):
                    r = match_pair(left, right, sparse, 0, d_max, matcher="adcensus", guide="riverbed", range=rng,
                                   fusion="none")
                    secs[rng].append(r.info["seconds"])
            cell = {}
            for k, r in res.items():
                m = evaluate_disparity(r.disparity, gt, exclude=sparse)
                cell[k] = f"{m['bad3']:.2f} / {m['avg']:.3f}"
            t = res["tube"].info["tubes"]
            sup = res["tube"].info["refinement"].get("support_costs", 0) / gt.size
            fs, ts = statistics.median(secs["full"]), statistics.median(secs["tube"])
            print(f"| {name} | {share * 100:.2f} % | {cell['full']} | {cell['tube']} | {cell['full_fused']} | "
                  f"{cell['tube_fused']} | {t['mean_width']:.1f} / {t['nominal']} | {sup:.1f} | {fs:.3f} | "
                  f"{ts:.3f} | {fs / ts:.2f} |", flush=True)


if __name__ == "__main__":
    main()
