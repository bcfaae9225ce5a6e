"""LiDAR tubes (riverbed match --range tube) against the full range and OpenCV StereoSGBM, measured in one run.

Usage: python benchmarks/bench_tubes.py [DATA_DIR] [--skip-speed] [--skip-coverage] [--skip-holes] [--skip-beyond]
       [--repeat 3]

1. Coverage of the tube rule (and alternatives) on the Middlebury dev scenes and the dev aerial pair: the share of
   ground-truth pixels (not sampled as LiDAR) whose true disparity lies in their tube, the mean tube width, the share
   of pixels left on the full range. LiDAR is a seeded sample of the GT at a share of the *image* pixels
   (``simulate_lidar``), as in docs/benchmarks.md.
2. Accuracy, full range against tubes (8 and 4 paths), riverbed-guided SGM fused (the default) and alone
   (``--fusion none``), beside the LiDAR-only baselines of the same points (``bench_tube_accuracy.py``).
3. LiDAR holes: pixels with no LiDAR within reach on the nominal range (the default) against the range of a coarse
   match (``--tube-holes coarse``): coverage, width and errors in holes cut into the LiDAR.
4. LiDAR beyond the nominal range: the speed pair and Cones with a range that cuts off their nearest parts, the
   LiDAR cut at the range against the LiDAR of the whole scene (the points beyond bound the pixels only they reach
   at the range's end): tube width, pixels on the full range, accuracy on the GT pixels inside the range.
5. Speed as a user runs it: fresh ``riverbed match`` processes (``seconds`` from --json and whole-process wall time),
   full range and tubes (the default, the matcher alone, 4 paths), against OpenCV StereoSGBM MODE_HH,
   MODE_SGBM_3WAY and MODE_SGBM (what ``StereoSGBM_create`` gives by default) at the same nominal range (warm calls
   in a process of its own that imports only OpenCV, as a user's program runs it: ``opencv_timer.py``), on the
   740 x 500 / 80-disparity speed pair and on the aerial pair padded to 1024 x 1024 (144 disparities). Ratios are
   medians of each round's ratio. Each round starts with a probe of where the VM put its two vCPUs
   (``bench_placement.py``), listed under the table.
"""

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# warm runs in this process with the riverbed program's process settings (riverbed_cli/runtime): no NumPy huge pages,
# freed arrays kept by glibc (without them each warm run faulted its arrays in anew), OpenMP workers sleeping
from riverbed_cli.runtime import Env  # noqa: E402

Env().__enter__()

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_match import opencv_grey_files, opencv_times_apart  # noqa: E402
from bench_placement import probe  # noqa: E402
from datasets import DEV_SCENES, middlebury, rewrite_block, speed_pair  # noqa: E402

from riverbed_cli.io.disparity import read_disparity, write_disparity  # noqa: E402
from riverbed_cli.io.images import read_image  # noqa: E402
from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402

AERIAL = "aerial_dublincity_fusionx3"
RULES = {
    "default (reach 2 s, margin 2, 3 levels)": {},
    "reach 1 s": {"reach": 1.0},
    "reach 4 s": {"reach": 4.0},
    "margin 1": {"margin": 1.0},
    "margin 4": {"margin": 4.0},
    "1 level": {"levels": 1},
}


def aerial(data_dir, pad_to=None):
    base = Path(data_dir) / AERIAL
    left, right = read_image(base / "left.png"), read_image(base / "right.png")
    gt = read_disparity(base / "gt.png", scale=256)
    if pad_to:
        reps = -(-pad_to // left.shape[0])
        left = np.concatenate([left, left[::-1]] * reps)[:pad_to]
        right = np.concatenate([right, right[::-1]] * reps)[:pad_to]
        gt = np.concatenate([gt, gt[::-1]] * reps)[:pad_to]
    return left, right, gt


def scenes(data_dir):
    out = [(n, *(lambda s: (s.left, s.right, s.gt))(middlebury(data_dir, n))) for n in DEV_SCENES]
    if (Path(data_dir) / AERIAL).is_dir():
        out.append(("Dublin aerial", *aerial(data_dir)))
    return out


def coverage(data_dir, shares):
    # the coverage section: benchmarks/bench_tube_coverage.py (its rows make docs/tubes.md's tables), printed here
    from bench_tube_coverage import scene_rows, tables

    print("### Tube coverage of the true disparity (GT pixels not sampled), mean width, pixels on the full range\n")
    rows = [r for name, _, _, gt in scenes(data_dir) for r in scene_rows(name, gt, shares)]
    print(tables(rows) if tuple(shares) == (0.05, 0.0123, 0.0016) else "\n".join(map(str, rows)), flush=True)


def accuracy(data_dir, shares):
    # the accuracy section: benchmarks/bench_tube_accuracy.py (its rows make docs/tubes.md's and docs/fusion.md's
    # tables), printed here for the shares asked
    from bench_tube_accuracy import scene_rows, tubes_table

    print("\n### Accuracy: riverbed-guided SGM, full range against tubes, beside the LiDAR alone (bad3 % / avg px)\n")
    rows = [r for name, left, right, gt in scenes(data_dir) for r in scene_rows(name, left, right, gt, shares)]
    print(tubes_table(rows), flush=True)


def holes(data_dir, share=0.05, seed=1):
    # the holes section: benchmarks/bench_tube_holes.py (its rows make docs/tubes.md's table), printed here
    from bench_tube_holes import run, tables

    print("\n### LiDAR holes: the nominal range against the coarse match's range (`--tube-holes coarse`)\n")
    print(tables(run(data_dir, share, seed)), flush=True)


# The default (tubes, 8 paths, fused) and what each part costs: the full range, the matcher alone (no fusion), and
# 4 paths (OpenCV's SGBM_3WAY sweeps fewer directions than HH's 8). A fourth item sets environment variables of the
# fresh process: RIVERBED_PREFAULT=0 is the command without its heap prefault (runtime/heap.py).
NO_PREFAULT = {"RIVERBED_PREFAULT": "0"}
#: OpenCV StereoSGBM modes timed beside riverbed: the issue's two references and the mode StereoSGBM_create gives
#: when none is asked for (MODE_SGBM: 5 directions in one pass, single-threaded)
OPENCV_MODES = ("HH", "SGBM_3WAY", "SGBM")

VARIANTS = [
    ("range full", ["--range", "full"], {"range": "full"}),
    ("range tube (default)", ["--range", "tube"], {"range": "tube"}),
    ("range tube, --fusion-lidar linear",
     ["--range", "tube", "--fusion-lidar", "linear"], {"range": "tube", "fusion_lidar": "linear"}),
    ("range tube, --fusion none", ["--range", "tube", "--fusion", "none"], {"range": "tube", "fusion": "none"}),
    ("range tube, --paths 4", ["--range", "tube", "--paths", "4"], {"range": "tube", "paths": 4}),
    ("range tube, --paths 4 --fusion none", ["--range", "tube", "--paths", "4", "--fusion", "none"],
     {"range": "tube", "paths": 4, "fusion": "none"}),
    ("range tube, --paths 4 --fusion none --lidar-check off --lidar-offset none",
     ["--range", "tube", "--paths", "4", "--fusion", "none", "--lidar-check", "off", "--lidar-offset", "none"],
     {"range": "tube", "paths": 4, "fusion": "none", "lidar_check": "off", "lidar_offset": "none"}),
    ("range tube, --lidar-check off --lidar-offset none", ["--range", "tube", "--lidar-check", "off",
                                                           "--lidar-offset", "none"],
     {"range": "tube", "lidar_check": "off", "lidar_offset": "none"}),
    ("range tube, --paths 4 --fusion none, GOMP_SPINCOUNT=0 (idle workers sleep at once)",
     ["--range", "tube", "--paths", "4", "--fusion", "none"], {"range": "tube", "paths": 4, "fusion": "none"},
     {"GOMP_SPINCOUNT": "0"}),
    ("range tube (default), RIVERBED_PREFAULT=0", ["--range", "tube"], {"range": "tube"}, NO_PREFAULT),
    ("range tube, --paths 4 --fusion none, RIVERBED_PREFAULT=0",
     ["--range", "tube", "--paths", "4", "--fusion", "none"], {"range": "tube", "paths": 4, "fusion": "none"},
     NO_PREFAULT),
    ("range tube, --tube-holes coarse", ["--range", "tube", "--tube-holes", "coarse"],
     {"range": "tube", "tube": {"holes": "coarse"}}),
    ("range tube, --tube-holes coarse --fusion none", ["--range", "tube", "--tube-holes", "coarse", "--fusion", "none"],
     {"range": "tube", "tube": {"holes": "coarse"}, "fusion": "none"}),
]


def beyond(data_dir):
    # the beyond section: benchmarks/bench_tube_beyond.py (its rows make docs/tubes.md's table), printed here
    from bench_tube_beyond import run, tables

    print("\n### LiDAR beyond the nominal range: cut at the range against the whole scene's\n")
    print(tables(run(data_dir)), flush=True)


def run_cli(args, env):
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "riverbed_cli", "match", *args, "--json", "--overwrite"], env=env,
                       capture_output=True, text=True, check=True)
    return json.loads(p.stdout), time.perf_counter() - t


def speed_measure(data_dir, repeat):
    """Fresh ``riverbed match`` processes and warm runs in this process, OpenCV in a process of its own, round-robin
    over ``repeat`` rounds: ``{"repeat", "pairs": [{"label", "d_max", "probes", "opencv": {mode: [s]}, "riverbed":
    {variant: {"seconds": [s], "wall": [s], "warm": [s], "width"}}}]}``."""
    cases = [("740x500 Reindeer, 0..79, 5 % LiDAR", *speed_pair(data_dir), 79),
             ("740x500 Reindeer, 0..79, the same LiDAR and the points beyond 79 px", *speed_pair(data_dir, beyond=True),
              79)]
    if (Path(data_dir) / AERIAL).is_dir():
        left, right, gt = aerial(data_dir, pad_to=1024)
        cases.append(("1024x1024 Dublin aerial, 0..143, 1 % LiDAR", left, right, simulate_lidar(gt, 0.01, 0), 143))
    pairs = []
    for label, left, right, sparse, d_max in cases:
        opencv = {mode: [] for mode in OPENCV_MODES}
        with tempfile.TemporaryDirectory() as tmp:
            for n, img in (("l.png", left), ("r.png", right)):
                cv2.imwrite(os.path.join(tmp, n), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            grey = opencv_grey_files(left, right, tmp)
            write_disparity(os.path.join(tmp, "s.tif"), sparse)
            env = dict(os.environ)
            base = [os.path.join(tmp, "l.png"), os.path.join(tmp, "r.png"), "--sparse", os.path.join(tmp, "s.tif"),
                    "--min-disp", "0", "--max-disp", str(d_max), "--tile", "0", "-o", os.path.join(tmp, "d.tif")]
            run_cli(base, env)  # load Numba's cache once
            # round-robin (each round: OpenCV, then every variant once), so that the machine's drift hits all alike
            runs = {name: [] for name, *_ in VARIANTS}
            warm = {name: [] for name, *_ in VARIANTS}
            for _, _, kw, *_ in VARIANTS:
                match_pair(left, right, sparse, 0, d_max, **kw)  # this process's kernels loaded
            probes = []
            for _ in range(repeat):
                probes.append(probe())  # where the VM put its two vCPUs this round (bench_placement.py)
                # OpenCV apart: in this process riverbed's process settings (runtime.Env) made HH 1.5-1.8x faster
                for mode, times in opencv_times_apart(grey, 0, d_max, OPENCV_MODES).items():
                    opencv[mode] += times
                for name, extra, kw, *more in VARIANTS:
                    runs[name].append(run_cli(base + extra, {**env, **(more[0] if more else {})}))
                    warm[name].append(match_pair(left, right, sparse, 0, d_max, **kw).info["seconds"])
        pairs.append({"label": label, "d_max": d_max, "probes": probes, "opencv": opencv,
                      "riverbed": {name: {"seconds": [r[0]["seconds"] for r in runs[name]],
                                          "wall": [r[1] for r in runs[name]], "warm": warm[name],
                                          "width": (runs[name][0][0].get("tubes") or {}).get("mean_width",
                                                                                             d_max + 1)}
                                   for name, *_ in VARIANTS}})
    return {"repeat": repeat, "pairs": pairs}


def ratio_per_round(a, b):
    """The median over the rounds of each round's ratio ``a / b`` (OpenCV gives ``len(b) / len(a)`` calls a round)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    per = len(b) // len(a)
    return float(np.median(a / np.array([np.median(b[i * per:(i + 1) * per]) for i in range(len(a))])))


def speed_table(res):
    """The whole speed table of a run (every variant, every ratio)."""
    lines = ["Ratios: medians over the rounds of each round's ratio (riverbed's time over OpenCV's of the same round: "
             "the machine's drift between rounds cancels); the times are medians over the rounds.", "",
             "| pair | method | seconds (--json) | wall s | warm s | mean tube width | vs OpenCV HH | vs OpenCV 3WAY | "
             "vs OpenCV SGBM | warm vs HH | warm vs 3WAY |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for p in res["pairs"]:
        cv = p["opencv"]
        for name, r in p["riverbed"].items():
            ratios = [ratio_per_round(r["seconds"], cv[m]) for m in OPENCV_MODES] + [ratio_per_round(r["warm"], cv[m])
                                                                            for m in OPENCV_MODES[:2]]
            lines.append(f"| {p['label']} | riverbed, {name} | {np.median(r['seconds']):.3f} | "
                         f"{np.median(r['wall']):.2f} | {np.median(r['warm']):.3f} | {r['width']:.1f} | "
                         + " | ".join(f"{x:.2f}" for x in ratios) + " |")
        for mode, title in zip(OPENCV_MODES, ("MODE_HH", "MODE_SGBM_3WAY", "MODE_SGBM (its default)")):
            vs = " | ".join(f"{float(np.median(np.array(cv[mode]) / np.array(cv[m]))):.2f}" for m in OPENCV_MODES)
            lines.append(f"| {p['label']} | OpenCV {title} | {np.median(cv[mode]):.3f} | | {np.median(cv[mode]):.3f} "
                         f"| {p['d_max'] + 1} | {vs} | | |")
    lines += ["", "The two vCPUs' cache-line round trip before each round (core_latency.py; about 100 ns where they "
              "share their caches, 500 ns far apart):"]
    lines += [f"* {p['label']}: " + ", ".join(f"{x:.0f}" for x in p["probes"]) + " ns" for p in res["pairs"]]
    return "\n".join(lines)


#: the variants docs/tubes.md's table shows: the matcher alone against 3WAY, the fused default against HH, each
#: also without the LiDAR's check and offset estimate
FOUR, DEFAULT = "range tube, --paths 4 --fusion none", "range tube (default)"
FOUR_UNCHECKED = "range tube, --paths 4 --fusion none --lidar-check off --lidar-offset none"
DEFAULT_UNCHECKED = "range tube, --lidar-check off --lidar-offset none"
#: the markers of docs/tubes.md's speed block
SPEED_BEGIN, SPEED_END = "<!-- bench_tubes speed: begin -->", "<!-- bench_tubes speed: end -->"


def speed_doc(res):
    """docs/tubes.md's block: per pair the 4-path matcher against OpenCV 3WAY and the fused default against HH."""
    near = [sum(x < 200 for x in p["probes"]) for p in res["pairs"]]
    lines = [f"{res['repeat']} rounds per pair; probes near (under 200 ns) in {sum(near)} of "
             f"{sum(len(p['probes']) for p in res['pairs'])} rounds:", "",
             "| pair | mean width | OpenCV 3WAY s | `--paths 4 --fusion none` s | x 3WAY | without the check s | "
             "x 3WAY | OpenCV HH s | fused default s | x HH | without the check s | x HH |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for p in res["pairs"]:
        cv, rb = p["opencv"], p["riverbed"]
        cells = [f"{rb[FOUR]['width']:.1f}"]
        for mode, names in (("SGBM_3WAY", (FOUR, FOUR_UNCHECKED)), ("HH", (DEFAULT, DEFAULT_UNCHECKED))):
            cells.append(f"{np.median(cv[mode]):.3f}")
            for name in names:
                secs = rb[name]["seconds"]
                cells += [f"{np.median(secs):.3f}", f"**{ratio_per_round(secs, cv[mode]):.2f}**"]
        lines.append(f"| {p['label']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def speed(data_dir, repeat, write=None, rows=None, docs=None):
    res = json.loads(Path(rows).read_text()) if rows else speed_measure(data_dir, repeat)
    if write:
        Path(write).write_text(json.dumps(res, indent=1) + "\n")
    if docs:
        rewrite_block(docs, SPEED_BEGIN, SPEED_END, speed_doc(res))
    print("\n### Speed: fresh `riverbed match` processes and warm in this process (median of runs, round-robin), "
          "OpenCV warm in a process of its own (opencv_timer.py)\n")
    print(speed_table(res), flush=True)


def beside(data_dir, repeat):
    print("\n### The fusion's LiDAR side beside the matcher or after it (warm, this process, alternating; median "
          f"of {repeat})\n")
    print("| pair | after the matcher s | beside it s | ratio (median of per-round ratios) | same bits |")
    print("|---|---:|---:|---:|---|")
    cases = [("740x500 Reindeer, 0..79, 5 % LiDAR", *speed_pair(data_dir), 79),
             ("740x500 Reindeer, the whole scene's LiDAR", *speed_pair(data_dir, beyond=True), 79)]
    if (Path(data_dir) / AERIAL).is_dir():
        left, right, gt = aerial(data_dir, pad_to=1024)
        cases.append(("1024x1024 Dublin aerial, 1 % LiDAR", left, right, simulate_lidar(gt, 0.01, 0), 143))
    for label, left, right, sparse, d_max in cases:
        times = {"after": [], "beside": []}
        outs = {}
        for k in range(repeat + 1):
            for name, beside_matcher in (("after", False), ("beside", True)):
                res = match_pair(left, right, sparse, 0, d_max, lidar_thread=beside_matcher)
                if k:  # the first round loads
                    times[name].append(res.info["seconds"])
                outs[name] = res.disparity
        a, b = np.array(times["after"]), np.array(times["beside"])
        same = np.array_equal(outs["after"], outs["beside"], equal_nan=True)
        print(f"| {label} | {np.median(a):.3f} | {np.median(b):.3f} | {float(np.median(b / a)):.2f} | {same} |",
              flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data_dir", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    ap.add_argument("--shares", default="0.05,0.0123,0.0016")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-coverage", action="store_true")
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-holes", action="store_true")
    ap.add_argument("--skip-beyond", action="store_true")
    ap.add_argument("--skip-beside", action="store_true")
    ap.add_argument("--write-speed", help="store the speed rounds in this JSON (benchmarks/results_tube_speed.json)")
    ap.add_argument("--speed-rows", help="take the speed rounds from this JSON file instead of running")
    ap.add_argument("--docs", help="rewrite this Markdown file's speed block (docs/tubes.md)")
    args = ap.parse_args()
    logging.getLogger("riverbed_cli").setLevel(logging.ERROR)  # each match would warn of the points beyond the range
    shares = [float(s) for s in args.shares.split(",")]
    if not args.skip_coverage:
        coverage(args.data_dir, shares)
    if not args.skip_accuracy:
        accuracy(args.data_dir, shares)
    if not args.skip_holes:
        holes(args.data_dir)
    if not args.skip_beyond:
        beyond(args.data_dir)
    if not args.skip_speed:
        speed(args.data_dir, args.repeat, args.write_speed, args.speed_rows, args.docs)
    if not args.skip_beside:
        beside(args.data_dir, max(args.repeat, 7))


if __name__ == "__main__":
    main()
