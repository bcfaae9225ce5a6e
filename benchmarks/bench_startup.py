"""Start-up of a fresh ``riverbed match``: this tree against an earlier commit, side by side in one run.

Usage: python benchmarks/bench_startup.py [DATA_DIR] [--before REV] [--repeat 7]

On the 740 x 500 speed pair (80 disparities, 5 % LiDAR, ``--tile 0``, the default tubes and fusion), fresh
processes in round-robin: this tree, this tree with ``RIVERBED_NUMBA_REFRESH=1`` (Numba refreshes its target context
before loading the cached kernels, as it does by default: riverbed_cli/runtime/numba_cache.py), and the commit ``REV``
(default: a commit before the start-up changes of riverbed_cli/runtime) run from an exported copy of its sources, and
this tree with ``RIVERBED_GC=default`` (Python's garbage collector as it is: no pause while the command starts up,
nothing frozen for the exit; riverbed_cli/runtime/collector.py). Each
variant's Numba cache is filled by one run first. Reports medians of the whole-process wall time, the matching
``seconds`` from --json, and the rest (interpreter, imports, loading the kernels, reading and writing files).
"""

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import speed_pair  # noqa: E402

from riverbed_cli.io.disparity import write_disparity  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BEFORE = "a1d4c36"  # the last commit before the start-up work of 2026-12-03


def export(rev, dest):
    # the riverbed_cli package of commit rev, as files (its own Numba cache lands beside them)
    data = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "riverbed_cli"], capture_output=True,
                          check=True).stdout
    path = Path(dest) / "src.tar"
    path.write_bytes(data)
    with tarfile.open(path) as tar:
        tar.extractall(dest, filter="data")
    return dest


def run(pythonpath, args, extra_env):
    env = {k: v for k, v in os.environ.items() if k not in ("RIVERBED_NUMBA_REFRESH", "RIVERBED_GC", "PYTHONPATH")}
    env.update(extra_env, PYTHONPATH=str(pythonpath))
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "riverbed_cli", "match", *args, "--json", "--overwrite"], env=env,
                       capture_output=True, text=True, check=True, cwd=str(pythonpath))
    return time.perf_counter() - t, json.loads(p.stdout)["seconds"]


#: the markers of docs/tubes.md's start-up block
BEGIN, END = "<!-- bench_startup: begin -->", "<!-- bench_startup: end -->"


def measure(data_dir, before, repeat):
    """``{"repeat", "before", "times": {variant: [[wall s, --json seconds], ...]}}`` (module docstring)."""
    left, right, sparse = speed_pair(data_dir)
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as old:
        for n, img in (("l.png", left), ("r.png", right)):
            cv2.imwrite(os.path.join(tmp, n), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        write_disparity(os.path.join(tmp, "s.tif"), sparse)
        base = [os.path.join(tmp, "l.png"), os.path.join(tmp, "r.png"), "--sparse", os.path.join(tmp, "s.tif"),
                "--min-disp", "0", "--max-disp", "79", "--tile", "0", "-o", os.path.join(tmp, "d.tif")]
        variants = [
            ("this tree", ROOT, {}),
            ("this tree, RIVERBED_NUMBA_REFRESH=1 (Numba's own cache loading)", ROOT, {"RIVERBED_NUMBA_REFRESH": "1"}),
            ("this tree, RIVERBED_GC=default (Python's collector as it is)", ROOT, {"RIVERBED_GC": "default"}),
            (f"commit {before}", export(before, old), {}),
        ]
        for _, path, env in variants:
            run(path, base, env)  # fill (or check) the variant's Numba cache
        times = {name: [] for name, _, _ in variants}
        for _ in range(repeat):
            for name, path, env in variants:
                times[name].append(list(run(path, base, env)))
    return {"repeat": repeat, "before": before, "times": times}


def table(res):
    """The run's table: per variant the medians of the wall time and of the matching ``seconds``."""
    lines = [f"Fresh `riverbed match` of the 740x500 speed pair (0..79, 5 % LiDAR, default tubes and fusion), medians "
             f"of {res['repeat']}, round-robin:", "",
             "| riverbed | wall s | matching s (--json seconds) | rest s (start-up, I/O) | wall vs this tree |",
             "|---|---:|---:|---:|---:|"]
    ref = float(np.median([w for w, _ in res["times"]["this tree"]]))
    for name, t in res["times"].items():
        wall, sec = float(np.median([w for w, _ in t])), float(np.median([s for _, s in t]))
        lines.append(f"| {name} | {wall:.3f} | {sec:.3f} | {wall - sec:.3f} | {wall / ref:.2f} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data_dir", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    ap.add_argument("--before", default=BEFORE)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--write", help="store the times in this JSON file (benchmarks/results_startup.json)")
    ap.add_argument("--rows", help="take the times from this JSON file instead of running")
    ap.add_argument("--docs", help="rewrite this Markdown file's block (docs/tubes.md)")
    args = ap.parse_args()
    res = json.loads(Path(args.rows).read_text()) if args.rows else measure(args.data_dir, args.before, args.repeat)
    if args.write:
        Path(args.write).write_text(json.dumps(res, indent=1) + "\n")
    if args.docs:
        from datasets import rewrite_block

        rewrite_block(args.docs, BEGIN, END, table(res))
    print(table(res))


if __name__ == "__main__":
    main()
