"""The LiDAR check's cost at the scale users match: a 10 MP pair over 0..520 px (bench_scale's synthetic terrain and
buildings, 1 % LiDAR), matched in tiles in fresh processes with the check (its reference coarse to fine, the default),
with the check's reference over the whole range at half resolution, and with the check off; round-robin, medians
of the time and the largest peak RSS.

    python benchmarks/bench_check_scale.py --write benchmarks/results_check_scale.json --docs docs/lidar_faults.md

``--write`` stores the rows (the committed result file), ``--docs`` rewrites the table of docs/lidar_faults.md from it
(``tests/test_lidar_faults_doc.py`` checks that the committed doc is that rewrite).
"""

import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_scale import make_pair  # noqa: E402
from datasets import rows_main  # noqa: E402

MEGAPIXELS = 10
D_MIN, D_MAX = 0, 520
REPEAT = 5
BEGIN, END = "<!-- bench_check_scale: begin -->", "<!-- bench_check_scale: end -->"
VARIANTS = ("default", "whole range", "off")

CHILD = r"""
import json, resource, sys
from riverbed_cli.runtime import Env
Env().__enter__()
from riverbed_cli.io.windowed import TiffSink, open_windowed
from riverbed_cli.matching import lidar_check
from riverbed_cli.matching.pipeline import warm_up
from riverbed_cli.scale.tiles import match_tiled
folder, variant, d_min, d_max = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
if variant == "whole range":  # the reference over the whole range at half resolution, whatever its size
    lidar_check.FINE_CELLS = float("inf")
warm_up()
left, right = open_windowed(folder + "/left.tif"), open_windowed(folder + "/right.tif")
sparse = open_windowed(folder + "/lidar.tif", "disparity")
with TiffSink(folder + "/disp.tif", *left.shape[:2]) as sink:
    r = match_tiled(left, right, sparse, d_min, d_max, tile="auto", out=sink,
                    lidar_check="off" if variant == "off" else "auto")
check = r.info.to_dict().get("lidar_check")
print(json.dumps({"seconds": r.info["seconds"], "check": r.info["stages"].get("lidar_check", 0.0),
                  "dropped": None if check is None else check["outliers"] + check["changed"],
                  "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def _child(folder, variant):
    p = subprocess.run([sys.executable, "-c", CHILD, str(folder), variant, str(D_MIN), str(D_MAX)],
                       capture_output=True, text=True)
    if p.returncode:
        sys.exit(f"bench_check_scale: {variant} failed: {p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def run(data=None):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        H, W = make_pair(folder, MEGAPIXELS)
        for variant in VARIANTS:  # the first run of each loads its kernels; not timed
            _child(folder, variant)
        runs = {v: [] for v in VARIANTS}
        for _ in range(REPEAT):
            for variant in VARIANTS:
                runs[variant].append(_child(folder, variant))
    row = {"size": [H, W], "range": [D_MIN, D_MAX], "repeat": REPEAT}
    for variant, rs in runs.items():
        row[variant] = {"seconds": round(statistics.median(r["seconds"] for r in rs), 3),
                        "check": round(statistics.median(r["check"] for r in rs), 3), "dropped": rs[0]["dropped"],
                        "peak_rss_mib": round(max(r["peak_rss_mib"] for r in rs))}
    return [row]


def tables(rows):
    r = rows[0]
    off = r["off"]["seconds"]
    out = [f"A {r['size'][1]} x {r['size'][0]} pair ({r['size'][0] * r['size'][1] / 1e6:.0f} MP) over "
           f"{r['range'][0]}..{r['range'][1]} px with 1 % LiDAR, matched in tiles in fresh processes (medians of "
           f"{r['repeat']}, round-robin; `python benchmarks/bench_check_scale.py`):", "",
           "| LiDAR check | `seconds` | the check's stage s | longer than off | points dropped | peak RSS MiB |",
           "|---|---:|---:|---:|---:|---:|"]
    for v, label in (("default", "on, its reference coarse to fine (the default)"),
                     ("whole range", "on, its reference over the whole range"), ("off", "off")):
        s = r[v]
        longer = f"{(s['seconds'] / off - 1) * 100:.0f} %" if v != "off" else ""
        dropped = "" if s["dropped"] is None else f"{s['dropped']:,}"
        out.append(f"| {label} | {s['seconds']:.2f} | {s['check']:.2f} | {longer} | {dropped} | "
                   f"{s['peak_rss_mib']} |")
    return "\n".join(out)


def main():
    rows_main(__doc__, run, tables, BEGIN, END)


if __name__ == "__main__":
    main()
