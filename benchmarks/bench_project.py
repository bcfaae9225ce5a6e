"""Speed and memory of ``riverbed project`` on 10 million points, against reading the file with laspy alone.

Usage: python benchmarks/bench_project.py [--points N] [--laz] [--width 6000] [--height 4000] [--keep DIR]

Generates, in a temporary folder, an aerial-like scene: a hilly terrain with flat-roofed buildings in a
UTM-like frame (origin 500000, 5000000), sampled at random and stored in 5 m strips (as a flight line would
be; LAS 1.4 point format 6, 1 mm scale; ``--laz`` for LAZ), and a pair file for a nadir camera 1000 m above it
(f = 10000 px, 300 m baseline, ``--width`` x ``--height`` px) that sees the whole cloud. Then, each in a fresh
subprocess (peak RSS as VmHWM and RSS after the imports, from /proc/self/status):

- ``laspy``: read the file in 1-million-point chunks and compute the float64 coordinates (the decoding floor);
- ``project``: the full ``riverbed project`` (CLI, default options: SOR, z-buffer visibility in both views);
- ``project --outliers none --visibility none``: streaming projection and the nearest point per pixel only.

Prints a markdown table (seconds, points per second, RSS, and ``project``'s own stage times).

The hidden point removal methods are compared by ``bench_hidden_points.py``.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# Peak RSS from /proc (VmHWM): ru_maxrss would include the parent's memory at fork time (it survives exec).
RSS_NOW = """
def rss_now(key="VmRSS:"):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1])
    return 0
"""

LASPY_READ = RSS_NOW + """
import sys, time
import laspy, numpy as np
base = rss_now()
t = time.perf_counter()
n = 0
with laspy.open(sys.argv[1]) as f:
    for pts in f.chunk_iterator(1_000_000):
        xyz = np.empty((len(pts), 3))
        xyz[:, 0], xyz[:, 1], xyz[:, 2] = pts.x, pts.y, pts.z
        n += len(pts)
dt = time.perf_counter() - t
print(json.dumps({"seconds": dt, "rss_kb": rss_now("VmHWM:"), "base_kb": base}))
""".replace("import sys", "import json, sys")

PROJECT = RSS_NOW + """
import json, sys, time
from click.testing import CliRunner
from riverbed_cli.cli.main import cli
import riverbed_cli.geometry.projection  # import and load the compiled kernels before timing
base = rss_now()
t = time.perf_counter()
r = CliRunner().invoke(cli, sys.argv[1:])
dt = time.perf_counter() - t
assert r.exit_code == 0, r.output
s = json.loads(r.stdout)
print(json.dumps({"seconds": dt, "rss_kb": rss_now("VmHWM:"), "base_kb": base, "stats": s}))
"""


def make_scene(folder, n, laz, width, height, seed=0):
    rng = np.random.default_rng(seed)
    gsd = 0.1  # m per pixel at 1000 m with f = 10000 px
    half_x, half_y = 0.48 * width * gsd, 0.48 * height * gsd
    x = rng.uniform(-half_x, half_x, n)
    y = rng.uniform(-half_y, half_y, n)
    order = np.lexsort((x, np.floor(y / 5.0)))  # 5 m strips, west to east: the locality of a flight line
    x, y = x[order], y[order]
    z = 20 * np.sin(x / 97.0) * np.cos(y / 61.0)
    blocks = (np.floor(x / 40) + np.floor(y / 40)) % 5 == 0  # flat-roofed buildings, 12 m high
    z = z + np.where(blocks & ((x % 40) > 8) & ((y % 40) > 8), 12.0, 0.0) + rng.normal(0, 0.03, n)
    origin = np.array([500000.0, 5000000.0, 200.0])
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = origin
    las = laspy.LasData(header)
    las.x, las.y, las.z = x + origin[0], y + origin[1], z + origin[2]
    las.classification = np.where(blocks, 6, 2).astype(np.uint8)
    path = folder / ("bench.laz" if laz else "bench.las")
    las.write(str(path))
    f, H, B = 10000.0, 1000.0, 300.0
    cx, cy = (width - 1) / 2, (height - 1) / 2
    # Nadir camera at (0, 0, H) above the origin: camera x = east, y = south, z = down.
    R = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])
    t = -R @ np.array([0.0, 0.0, H])
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]])
    PL = K @ np.hstack([R, t[:, None]])
    PR = K @ np.hstack([R, (t - np.array([B, 0, 0]))[:, None]])
    pair = folder / "pair.yaml"
    pair.write_text(json.dumps({"P_left": PL.tolist(), "P_right": PR.tolist(), "origin": origin.tolist(),
                                "width": width, "height": height}))
    return path, pair


def sub(code, *args):
    p = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True,
                       check=False)
    if p.returncode != 0:
        raise SystemExit(p.stderr)
    return json.loads(p.stdout)


def speed(args):
    with tempfile.TemporaryDirectory(prefix="bench_project_") as tmp:
        folder = Path(args.keep or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        t = time.perf_counter()
        cloud, pair = make_scene(folder, args.points, args.laz, args.width, args.height)
        print(f"generated {args.points:,} points ({cloud.stat().st_size / 2**20:.0f} MiB) in "
              f"{time.perf_counter() - t:.1f} s; image {args.width}x{args.height}")
        # Compile (or load from the cache) the kernels once.
        sub(PROJECT, "project", cloud, pair, "-o", folder / "warm.tif", "--json", "--overwrite")
        rows = [("laspy read (chunks of 1M, float64 xyz)", sub(LASPY_READ, cloud))]
        for name, extra in (("riverbed project (defaults: SOR, z-buffer both views)", []),
                            ("riverbed project --outliers none --visibility none",
                             ["--outliers", "none", "--visibility", "none"])):
            rows.append((name, sub(PROJECT, "project", cloud, pair, "-o", folder / "s.tif", "--json",
                                   "--overwrite", *extra)))
    print(f"\n{'LAZ' if args.laz else 'LAS'} 1.4, {args.points:,} points, {args.width}x{args.height} image\n")
    print("| run | seconds | points/s | peak RSS (MiB) | RSS after imports (MiB) | stages (s) |\n"
          "|---|---:|---:|---:|---:|---|")
    for name, r in rows:
        st = r.get("stats")
        stages = ", ".join(f"{k} {v:.1f}" for k, v in st["stage_seconds"].items()) if st else ""
        print(f"| {name} | {r['seconds']:.1f} | {args.points / r['seconds'] / 1e6:.2f} M | "
              f"{r['rss_kb'] / 1024:.0f} | {r['base_kb'] / 1024:.0f} | {stages} |")
    st = rows[1][1]["stats"]
    print(f"\nkept {st['kept']:,} pixels (share {st['lidar_share']:.3f}), same pixel "
          f"{st['occluded']['same_pixel']:,}, occluded left {st['occluded']['left']:,} right "
          f"{st['occluded']['right']:,}, outliers {st['filtered']['outliers']:,}")
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=10_000_000)
    ap.add_argument("--laz", action="store_true", help="Write and read LAZ instead of LAS.")
    ap.add_argument("--width", type=int, default=6000)
    ap.add_argument("--height", type=int, default=4000)
    ap.add_argument("--keep", default=None, help="Folder to keep the generated files in (default: none).")
    args = ap.parse_args()
    return speed(args)


if __name__ == "__main__":
    sys.exit(main())
