"""LiDAR beyond the nominal range: the LiDAR cut at the range against the whole scene's, with tubes and the full range.

    python benchmarks/bench_tube_beyond.py [DATA] --write benchmarks/results_tube_beyond.json --docs docs/tubes.md

The speed pair (Reindeer at 740 x 500 with the range 0..79: a third of its pixels lie beyond) with its LiDAR cut at
the range against the same points plus those of the scene beyond 79 px at the same density; Cones with the range
0..39 (its GT reaches 55 px; 5 % of the image pixels sampled from the whole GT). Accuracy on the GT pixels inside the
range that are not LiDAR (bad1 %, bad3 %, mean px); the LiDAR-only baselines interpolate the points inside the range.

``--write`` stores the rows (the committed result file), ``--docs`` rewrites docs/tubes.md's table from it
(``tests/test_tube_beyond_doc.py`` checks the doc and the claims its text makes on the committed rows).
"""

import logging
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import middlebury, rows_main, speed_pair, speed_scene  # noqa: E402

from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.densify import densify  # noqa: E402
from riverbed_cli.products.evaluate import evaluate_disparity  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402

BEGIN, END = "<!-- bench_tube_beyond: begin -->", "<!-- bench_tube_beyond: end -->"


def _scores(e):
    return [round(float(e["bad1"]), 2), round(float(e["bad3"]), 2), round(float(e["avg"]), 3)]


def pairs(data):
    cones = middlebury(data, "Cones")
    whole = simulate_lidar(cones.gt, 0.05, seed=0)
    left, right, scene = speed_scene(data)
    return [("740x500 Reindeer, 0..79", left, right, scene, speed_pair(data)[2], speed_pair(data, beyond=True)[2], 79),
            ("Cones, 0..39 (GT to 55)", cones.left, cones.right, cones.gt, np.where(whole <= 39, whole, np.nan),
             whole, 39)]


def pair_rows(label, left, right, gt, cut, every, d_max):
    truth = np.where(gt <= d_max, gt, np.nan)
    rows = []
    for method in ("nearest", "linear", "guided"):  # LiDAR alone: the points inside the range, interpolated
        e = evaluate_disparity(densify(cut, method, image=left), truth, exclude=np.isfinite(every))
        rows.append({"pair": label, "lidar": f"LiDAR alone, {method}", "points": int(np.isfinite(cut).sum()),
                     "scores": _scores(e)})
    for name, sparse in (("cut at the range", cut), ("whole scene", every)):
        for rng in ("tube", "full"):
            for fusion in ("auto", "none"):
                res = match_pair(left, right, sparse, 0, d_max, range=rng, fusion=fusion)
                t = res.info.get("tubes") or {"mean_width": d_max + 1, "full_share": 1.0}
                row = {"pair": label, "lidar": name, "points": int(np.isfinite(sparse).sum()), "range": rng,
                       "fusion": fusion, "mean_width": round(float(t["mean_width"]), 1),
                       "full_range": round(100 * float(t["full_share"]), 1),
                       "scores": _scores(evaluate_disparity(res.disparity, truth, exclude=np.isfinite(every)))}
                far = (gt > d_max) & ~np.isfinite(every) & np.isfinite(res.disparity)
                if far.any():  # where the truth lies beyond the range: how near its end the output sits
                    d = res.disparity[far]
                    row["beyond"] = {"at_end": round(100 * float(np.mean(d >= d_max - 0.5)), 1),
                                     "under_70": round(100 * float(np.mean(d < 70)), 1),
                                     "error": round(float(np.mean(np.abs(d - gt[far]))), 1)}
                rows.append(row)
    return rows


def run(data):
    logging.getLogger("riverbed_cli").setLevel(logging.ERROR)  # each match warns of the points beyond the range
    return [r for p in pairs(data) for r in pair_rows(*p)]


def tables(rows):
    out = ["| pair | LiDAR | range | fusion | mean width | full range % | bad1 % | bad3 % | avg px |",
           "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        s = r["scores"]
        if "range" not in r:
            out.append(f"| {r['pair']} | {r['lidar']} ({r['points']} points inside) | | | | | {s[0]:.2f} | "
                       f"{s[1]:.2f} | {s[2]:.3f} |")
        else:
            out.append(f"| {r['pair']} | {r['lidar']} ({r['points']} points) | {r['range']} | {r['fusion']} | "
                       f"{r['mean_width']:.1f} | {r['full_range']:.1f} | {s[0]:.2f} | {s[1]:.2f} | {s[2]:.3f} |")
    width = {}
    for r in rows:
        if r.get("range") == "tube" and r["fusion"] == "auto":
            width.setdefault(r["pair"], []).append(r["mean_width"])
    moved = max(abs(a["scores"][i] - b["scores"][i]) for a in rows for b in rows
                if a.get("range") == b.get("range") == "tube" and a["fusion"] == b["fusion"] and a["pair"] == b["pair"]
                and a["lidar"] == "cut at the range" and b["lidar"] == "whole scene" for i in (1, 2))
    out += ["", "With the points beyond, the tubes narrow from " + "; from ".join(
        f"{w[0]:g} to {w[1]:g} px ({p.split(',')[0]})" for p, w in width.items()) + ", no pixel is left on the whole "
        f"range, and bad3 and the mean error inside the range move by at most {moved:g}."]
    speed = [r for r in rows if r.get("beyond") and r["lidar"] == "whole scene" and r["fusion"] == "auto"]
    if speed:
        tube, full = (next(r["beyond"] for r in speed if r["range"] == k) for k in ("tube", "full"))
        out += ["", "Where the truth lies beyond the range (the speed pair's reindeer), tubes put "
                f"{tube['at_end']:g} % of its pixels at the range's end (within half a pixel), mean error "
                f"{tube['error']:g} px; the whole range gives {full['under_70']:g} % of them under 70 px, mean error "
                f"{full['error']:g} px."]
    return "\n".join(out)


def main():
    rows_main(__doc__, run, tables, BEGIN, END)


if __name__ == "__main__":
    main()
