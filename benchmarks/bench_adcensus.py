"""Speed of the AD-Census matcher against our SGM path, measured side by side in one run (issue 6: within 2x).

Usage: python benchmarks/bench_adcensus.py DATA_DIR [--repeat 9] [--guides riverbed,diffusion,riverbed+]

The pair is the issue's speed case (Reindeer resized to 740x500, 80 disparities, 5 % LiDAR, ``datasets.speed_pair``).
Runs alternate between the two matchers, so load from other processes hits both alike; the table gives the best and
the median of ``--repeat`` runs of ``match_pair`` (compiled code loaded beforehand) and the ratio AD-Census / SGM.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import speed_pair  # noqa: E402

from riverbed_cli.matching.pipeline import match_pair, warm_up  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data_dir")
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--guides", default="riverbed")
    args = ap.parse_args()
    left, right, sparse = speed_pair(args.data_dir)
    guides = [g for g in args.guides.split(",") if g]
    for matcher in ("sgm", "adcensus"):
        warm_up(matcher, tuple(guides))
    print("| guide | SGM best / median s | AD-Census best / median s | ratio (best) | ratio (median) | stages of "
          "AD-Census (best run, s) |")
    print("|---|---:|---:|---:|---:|---|")
    for guide in guides:
        times = {"sgm": [], "adcensus": []}
        stages = {}
        for _ in range(args.repeat):
            for matcher in times:
                info = match_pair(left, right, sparse, 0, 79, guide=guide, matcher=matcher).info
                times[matcher].append(info["seconds"])
                if matcher == "adcensus" and info["seconds"] == min(times[matcher]):
                    stages = info["stages"]
        s, a = np.array(times["sgm"]), np.array(times["adcensus"])
        st = ", ".join(f"{k} {v:.3f}" for k, v in stages.items())
        print(f"| {guide} | {s.min():.3f} / {np.median(s):.3f} | {a.min():.3f} / {np.median(a):.3f} | "
              f"{a.min() / s.min():.2f} | {np.median(a) / np.median(s):.2f} | {st} |")


if __name__ == "__main__":
    main()
