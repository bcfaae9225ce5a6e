"""AD-Census (riverbed-guided) on LiDAR tubes against the full range, on the Middlebury dev scenes (and the dev aerial
pair when present): accuracy and warm speed, measured back to back in one process.

    python benchmarks/bench_adcensus_tubes.py [DATA] --write benchmarks/results_adcensus_tubes.json --docs docs/tubes.md

LiDAR is a seeded sample of the GT at a share of the *image* pixels (``simulate_lidar``, seed 0), as in
``bench_tubes.py``. Accuracy: bad3 % / avg px over GT pixels not sampled as LiDAR, the matcher alone (``fusion
none``) and with the fusion default. Speed: ``info["seconds"]`` of the matcher alone, full and tubes alternating,
the median of ``--repeat`` rounds after one warm-up of each; ``support`` is the number of raw costs the tube path
computes (the cross aggregation's first support layout) per pixel.

``--write`` stores the rows (the committed result file), ``--docs`` rewrites docs/tubes.md's AD-Census table from it
(``tests/test_adcensus_tubes_doc.py`` checks the doc and the claims its text makes on the committed rows).
"""

import math
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_tubes import scenes  # noqa: E402
from datasets import cell, rows_main  # noqa: E402

from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.evaluate import evaluate_disparity  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402


SHARES = (0.05, 0.0123)
REPEAT = 3
BEGIN, END = "<!-- bench_adcensus_tubes: begin -->", "<!-- bench_adcensus_tubes: end -->"


def _score(r, gt, sparse):
    m = evaluate_disparity(r.disparity, gt, exclude=sparse)
    return [round(float(m["bad3"]), 2), round(float(m["avg"]), 3)]


def run(data, repeat=None):
    repeat = int(repeat or REPEAT)
    rows = []
    for name, left, right, gt in scenes(data):
        d_max = int(math.ceil(np.nanmax(gt))) + 4
        for share in SHARES:
            sparse = simulate_lidar(gt, share, seed=0)
            row, secs = {"scene": name, "share": share}, {"full": [], "tube": []}
            for rng in ("full", "tube"):  # warm-up, and the accuracy (deterministic)
                res = match_pair(left, right, sparse, 0, d_max, matcher="adcensus", guide="riverbed", range=rng,
                                 fusion="none")
                row[rng] = _score(res, gt, sparse)
                row[rng + "_fused"] = _score(match_pair(left, right, sparse, 0, d_max, matcher="adcensus",
                                                        guide="riverbed", range=rng), gt, sparse)
                if rng == "tube":
                    t = res.info["tubes"]
                    row["mean_width"], row["nominal"] = round(float(t["mean_width"]), 1), int(t["nominal"])
                    row["support"] = round(res.info["refinement"].get("support_costs", 0) / gt.size, 1)
            for _ in range(repeat):  # full and tubes alternating, the matcher alone
                for rng in ("full", "tube"):
                    r = match_pair(left, right, sparse, 0, d_max, matcher="adcensus", guide="riverbed", range=rng,
                                   fusion="none")
                    secs[rng].append(r.info["seconds"])
            row["seconds"] = [round(statistics.median(secs["full"]), 3), round(statistics.median(secs["tube"]), 3)]
            rows.append(row)
    return rows


def tables(rows):
    out = ["| scene | LiDAR | full | tubes | fused full | fused tubes | mean width / nominal | support costs / px | "
           "full s | tubes s |", "|---|---:|---|---|---|---|---|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['scene']} | {r['share'] * 100:.2f} % | {cell(r['full'])} | {cell(r['tube'])} | "
                   f"{cell(r['full_fused'])} | {cell(r['tube_fused'])} | {r['mean_width']:.1f} / {r['nominal']} | "
                   f"{r['support']:.1f} | {r['seconds'][0]:.3f} | {r['seconds'][1]:.3f} |")
    better = sum(r[f"tube{k}"][i] <= r[f"full{k}"][i] for r in rows for k in ("", "_fused") for i in (0, 1))
    gain = max(rows, key=lambda r: r["full"][1] - r["tube"][1])
    speed = [r["seconds"][0] / r["seconds"][1] for r in rows]
    layout = [r["support"] / r["mean_width"] for r in rows]
    out += ["", f"Tubes are as good as the full range or better in {better} of {4 * len(rows)} cells (scene x share "
            f"x bad3/avg x fused or not; the largest gain: {gain['scene']} {gain['share'] * 100:.2f} %, mean "
            f"{gain['full'][1]:g} -> {gain['tube'][1]:g} px). They run at {min(speed):.2f}-{max(speed):.2f}x the full "
            f"range's speed; the exact aggregation's support layout holds {min(layout):.1f}-{max(layout):.1f}x the "
            "tubes' costs."]
    return "\n".join(out)


def main():
    rows_main(__doc__, run, tables, BEGIN, END, options=(("--repeat", f"timed rounds (default {REPEAT})"),))


if __name__ == "__main__":
    main()
