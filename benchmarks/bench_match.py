"""Accuracy and speed of riverbed's matcher against unguided SGM, Gauss guidance and OpenCV StereoSGBM, in one run.

Usage: python benchmarks/bench_match.py DATA_DIR [--shares 0.05,0.0123,0.0016] [--markdown docs/benchmarks.md]

On the real Middlebury dev scenes (and the held-out KITTI 2015 frame), LiDAR is simulated by seeded random sampling of
the ground truth; every method is evaluated on the GT pixels that were not sampled (the paper's protocol). Time ratios
are against OpenCV StereoSGBM (MODE_HH and MODE_SGBM_3WAY) on the same pair in the same run.
"""

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import all_scenes, speed_pair  # noqa: E402
from opencv_timer import create_sgbm, num_disparities  # noqa: E402

from riverbed_cli.io.disparity import write_disparity  # noqa: E402
from riverbed_cli.io.images import to_grey  # noqa: E402
from riverbed_cli.matching.pipeline import match_pair  # noqa: E402
from riverbed_cli.products.evaluate import evaluate_disparity  # noqa: E402
from riverbed_cli.products.simulate import simulate_lidar  # noqa: E402


def opencv_grey(img):
    """The 8-bit grey image OpenCV StereoSGBM matches."""
    return np.clip(to_grey(img), 0, 255).astype(np.uint8)


def opencv_sgbm(left, right, d_min, d_max, mode):
    """OpenCV StereoSGBM (:func:`opencv_timer.create_sgbm`); returns (disparity, seconds of compute())."""
    gl, gr = opencv_grey(left), opencv_grey(right)
    sgbm = create_sgbm(d_min, num_disparities(d_min, d_max), mode)
    sgbm.compute(gl, gr)  # warm-up (allocations)
    t = time.perf_counter()
    raw = sgbm.compute(gl, gr)
    dt = time.perf_counter() - t
    disp = raw.astype(np.float32) / 16.0
    disp[raw <= (d_min - 1) * 16] = np.nan
    return disp, dt


OPENCV_TIMER = Path(__file__).with_name("opencv_timer.py")


def opencv_grey_files(left, right, folder):
    """The images :func:`opencv_sgbm` matches (:func:`opencv_grey`), written to ``folder`` for
    :func:`opencv_times_apart`."""
    paths = [str(Path(folder) / name) for name in ("opencv_left.png", "opencv_right.png")]
    for path, img in zip(paths, (left, right)):
        cv2.imwrite(path, opencv_grey(img))
    return paths


def opencv_times_apart(files, d_min, d_max, modes=("HH", "SGBM_3WAY"), repeat=1):
    """Seconds of warm ``compute()`` calls of OpenCV StereoSGBM in a process of its own (``opencv_timer.py``: none
    of riverbed's process settings, which speed OpenCV up in riverbed's process), ``{mode: [seconds, ...]}``."""
    p = subprocess.run([sys.executable, str(OPENCV_TIMER), *files, str(d_min), str(num_disparities(d_min, d_max)),
                        ",".join(modes), str(repeat)], capture_output=True, text=True, check=True)
    return json.loads(p.stdout)


def fmt(v, nd=2):
    return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{nd}f}"


def accuracy(args):
    scenes = all_scenes(args.data_dir, held_out=not args.dev_only)
    shares = [float(s) for s in args.shares.split(",")]
    windows = [int(w) for w in args.windows.split(",")] if args.windows else []
    rows = []
    for sc in scenes:
        gt = sc.gt
        d_min, d_max = 0, int(math.ceil(np.nanmax(gt))) + 4
        base = {}
        for mode, name in [(cv2.STEREO_SGBM_MODE_HH, "OpenCV HH"), (cv2.STEREO_SGBM_MODE_SGBM_3WAY, "OpenCV 3WAY")]:
            base[name] = opencv_sgbm(sc.left, sc.right, d_min, d_max, mode)
        for share in shares:
            sparse = simulate_lidar(gt, share, seed=args.seed)
            cases = [("none", {"guide": "none"}), ("gauss", {"guide": "gauss"}), ("riverbed", {"guide": "riverbed"})]
            cases += [(f"riverbed s={w}", {"guide": "riverbed", "window": w}) for w in windows]
            results = {}
            for label, kw in cases:
                res = match_pair(sc.left, sc.right, sparse, d_min, d_max, **kw)
                results[label] = (res.disparity, res.info["seconds"], res.info.get("window"))
            for label, (disp, sec) in base.items():
                results[label] = (disp, sec, None)
            t_hh = base["OpenCV HH"][1]
            for label, (disp, sec, win) in results.items():
                m = evaluate_disparity(disp, gt, exclude=sparse)
                rows.append({"scene": sc.name, "held_out": sc.held_out, "share": share, "method": label,
                             "window": win, **m, "seconds": sec, "vs_hh": sec / t_hh})
                print(f"{sc.name:12s} {share * 100:5.2f}% {label:16s} bad1 {m['bad1']:6.2f} bad3 {m['bad3']:6.2f} "
                      f"avg {fmt(m['avg'])} dens {m['density']:5.1f} {sec:.3f}s", file=sys.stderr, flush=True)
    return rows


def speed(args):
    """The ~740x500 / 80-disparity speed case: riverbed (census 9x7, 8 paths) vs OpenCV in the same run."""
    left, right, sparse = speed_pair(args.data_dir, args.seed)
    out = {}
    for label, kw in [("riverbed", {"guide": "riverbed"}), ("none", {"guide": "none"})]:
        match_pair(left, right, sparse, 0, 79, **kw)  # JIT warm-up
        ts = [match_pair(left, right, sparse, 0, 79, **kw).info["seconds"] for _ in range(args.repeat)]
        out[label] = float(np.median(ts))
    for mode, name in [(cv2.STEREO_SGBM_MODE_HH, "OpenCV HH"), (cv2.STEREO_SGBM_MODE_SGBM_3WAY, "OpenCV 3WAY")]:
        ts = [opencv_sgbm(left, right, 0, 79, mode)[1] for _ in range(args.repeat)]
        out[name] = float(np.median(ts))

    # First-run JIT compile cost and peak memory of the real command, each in a fresh process.
    with tempfile.TemporaryDirectory() as tmp:
        for name, img in (("left.png", left), ("right.png", right)):
            cv2.imwrite(os.path.join(tmp, name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        write_disparity(os.path.join(tmp, "sparse.tif"), sparse)
        cmd = [sys.executable, "-m", "riverbed_cli", "match", os.path.join(tmp, "left.png"),
               os.path.join(tmp, "right.png"), "--sparse", os.path.join(tmp, "sparse.tif"), "--min-disp", "0",
               "--max-disp", "79", "--overwrite", "--json", "-o"]
        env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, "numba-cache"))
        t = time.perf_counter()
        subprocess.run(cmd + [os.path.join(tmp, "d0.tif")], env=env, check=True, capture_output=True)
        out["first_run_wall"] = time.perf_counter() - t
        t = time.perf_counter()
        r = subprocess.run(cmd + [os.path.join(tmp, "d1.tif")], env=env, check=True, capture_output=True, text=True)
        out["cached_run_wall"] = time.perf_counter() - t
        out["cached_run_seconds"] = json.loads(r.stdout)["seconds"]
        # ru_maxrss of children is the largest child so far: measure the match after a bare import for reference.
        rss_cmd = [sys.executable, "-c", "import resource, subprocess, sys; subprocess.run(sys.argv[1:], check=True,"
                   " capture_output=True); print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)"]
        out["peak_rss_mib"] = int(subprocess.run(rss_cmd + cmd + [os.path.join(tmp, "d2.tif")], env=env, check=True,
                                                 capture_output=True, text=True).stdout) / 1024
        out["import_rss_mib"] = int(subprocess.run(rss_cmd + [sys.executable, "-c", "import riverbed_cli.cli.main"],
                                                   env=env, check=True, capture_output=True,
                                                   text=True).stdout) / 1024
    out["volume_mib"] = 740 * 500 * 80 * 2 / 2**20
    return out


def markdown(rows, sp, shares):
    lines = []
    if sp:
        hh, w3 = sp["OpenCV HH"], sp["OpenCV 3WAY"]
        lines += [
            "### Speed and memory: Reindeer resized to 740x500, 80 disparities, census 9x7, 8 paths, 5 % LiDAR", "",
            "| method | seconds (median) | ratio vs OpenCV HH | ratio vs OpenCV 3WAY |", "|---|---:|---:|---:|",
            f"| riverbed (guided) | {sp['riverbed']:.3f} | {sp['riverbed'] / hh:.2f} | {sp['riverbed'] / w3:.2f} |",
            f"| unguided SGM | {sp['none']:.3f} | {sp['none'] / hh:.2f} | {sp['none'] / w3:.2f} |",
            f"| OpenCV StereoSGBM MODE_HH | {hh:.3f} | 1.00 | {hh / w3:.2f} |",
            f"| OpenCV StereoSGBM MODE_SGBM_3WAY | {w3:.3f} | {w3 / hh:.2f} | 1.00 |", "",
            f"`riverbed match` as a command: first run with an empty Numba cache {sp['first_run_wall']:.1f} s "
            f"(JIT compile), next run {sp['cached_run_wall']:.1f} s wall of which {sp['cached_run_seconds']:.3f} s "
            f"matching; peak RSS {sp['peak_rss_mib']:.0f} MiB (Python with the imports alone: "
            f"{sp['import_rss_mib']:.0f} MiB; one uint16 cost volume is {sp['volume_mib']:.0f} MiB).", ""]
    if rows:
        methods = list(dict.fromkeys(r["method"] for r in rows))
        lines += ["### Accuracy (evaluated on the GT pixels not used as LiDAR)", "",
                  "Mean over the Middlebury dev scenes (Cones, Reindeer, Cloth3, Wood2):", "",
                  "| LiDAR | method | bad1 % | bad2 % | bad3 % | avg px | rmse px | density % | s | vs HH |",
                  "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for share in shares:
            for m in methods:
                sel = [r for r in rows if r["share"] == share and r["method"] == m and not r["held_out"]]
                if not sel:
                    continue
                avg = {k: float(np.mean([r[k] for r in sel])) for k in
                       ("bad1", "bad2", "bad3", "avg", "rmse", "density", "seconds", "vs_hh")}
                lines.append(f"| {share * 100:.2f} % | {m} | {avg['bad1']:.2f} | {avg['bad2']:.2f} | "
                             f"{avg['bad3']:.2f} | {avg['avg']:.2f} | {avg['rmse']:.2f} | {avg['density']:.1f} | "
                             f"{avg['seconds']:.3f} | {avg['vs_hh']:.2f} |")
        lines += ["", "Per scene:", "",
                  "| scene | LiDAR | method | window | bad1 % | bad2 % | bad3 % | avg px | rmse px | density % "
                  "| d1 % |",
                  "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in rows:
            lines.append(f"| {r['scene']}{' (held out)' if r['held_out'] else ''} | {r['share'] * 100:.2f} % | "
                         f"{r['method']} | {r['window'] or ''} | {r['bad1']:.2f} | {r['bad2']:.2f} | {r['bad3']:.2f} | "
                         f"{fmt(r['avg'])} | {fmt(r['rmse'])} | {r['density']:.1f} | {r['d1']:.2f} |")
        lines += ["", "Checks (issue 2):", ""]
        for sc in dict.fromkeys(r["scene"] for r in rows):
            def get(share, m, sc=sc):
                return next((r for r in rows if r["scene"] == sc and r["share"] == share and r["method"] == m), None)
            hi, lo = max(shares), min(shares)
            n, g, rb = get(hi, "none"), get(hi, "gauss"), get(hi, "riverbed")
            n0, rb0 = get(lo, "none"), get(lo, "riverbed")
            cut = 100 * (1 - rb["bad3"] / n["bad3"]) if n["bad3"] else float("nan")
            between = rb["bad3"] <= g["bad3"] <= n["bad3"] and rb["avg"] <= g["avg"] <= n["avg"]
            lines.append(f"- {sc}: at {hi * 100:g} % riverbed cuts bad3 by {cut:.0f} % ({n['bad3']:.2f} -> "
                         f"{rb['bad3']:.2f}), avg {rb['avg']:.2f} px; Gauss between: {'yes' if between else 'no'}; "
                         f"at {lo * 100:g} % riverbed vs unguided: bad3 {rb0['bad3']:.2f} vs {n0['bad3']:.2f}, "
                         f"avg {rb0['avg']:.2f} vs {n0['avg']:.2f} px")
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data_dir", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    ap.add_argument("--shares", default="0.05,0.0123,0.0016")
    ap.add_argument("--windows", default="5,9,15,25", help="extra riverbed window sizes ('' for none)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--dev-only", action="store_true", help="skip the held-out KITTI frame")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--markdown", help="also write the tables to this file")
    ap.add_argument("--json", help="also write the raw rows to this file")
    args = ap.parse_args()
    if not Path(args.data_dir).is_dir():
        sys.exit(f"bench_match: data folder {args.data_dir} not found")
    sp = None if args.skip_speed else speed(args)
    rows = [] if args.skip_accuracy else accuracy(args)
    md = markdown(rows, sp, [float(s) for s in args.shares.split(",")])
    print(md)
    if args.markdown:
        Path(args.markdown).write_text(md)
    if args.json:
        Path(args.json).write_text(json.dumps({"speed": sp, "rows": rows}, indent=1))



if __name__ == "__main__":
    main()
