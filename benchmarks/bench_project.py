"""Speed and memory of ``riverbed project`` on 10 million points, against reading the file with laspy alone.

Usage: python benchmarks/bench_project.py [--points N] [--laz] [--width 6000] [--height 4000] [--keep DIR]
       python benchmarks/bench_project.py --visibility [--kitti DATA_DIR]

Generates, in a temporary folder, an aerial-like scene: a hilly terrain with flat-roofed buildings in a
UTM-like frame (origin 500000, 5000000), sampled at random and stored in 5 m strips (as a flight line would
be; LAS 1.4 point format 6, 1 mm scale; ``--laz`` for LAZ), and a pair file for a nadir camera 1000 m above it
(f = 10000 px, 300 m baseline, ``--width`` x ``--height`` px) that sees the whole cloud. Then, each in a fresh
subprocess (peak RSS as VmHWM and RSS after the imports, from /proc/self/status):

- ``laspy``: read the file in 1-million-point chunks and compute the float64 coordinates (the decoding floor);
- ``project``: the full ``riverbed project`` (CLI, default options: SOR, z-buffer visibility in both views);
- ``project --outliers none --visibility none``: streaming projection and the nearest point per pixel only.

Prints a markdown table (seconds, points per second, RSS, and ``project``'s own stage times).

``--visibility`` instead compares the hidden point removal methods on the round-trip scene of
tests/test_cli_project.py (Middlebury Cones ground truth as LiDAR at 5, 10 and 30 % of the pixels, hidden
points behind the surface at 20 % of the others, outliers above it): share of hidden points removed, of
visible points kept, of points hidden in the right view removed; then on the bundled sample aerial block
(sample_data/block: synthetic LiDAR and ground-truth disparity), the kept points whose disparity is wrong.
With ``--kitti DATA_DIR`` also on the real KITTI frame: points kept and removed, and the median photometric
error |I_L(x) - I_R(x - d)| of each set (hidden points match badly).
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


def visibility_table(kitti_dir=None):
    sys.path.insert(0, str(ROOT / "tests"))
    from test_cli_project import build_scene, score  # the round-trip scene of the tests

    from riverbed_cli.geometry.projection import project_cloud
    from riverbed_cli.io.disparity import read_disparity
    from riverbed_cli.geometry.pairfile import load_pairfile

    gt = read_disparity(ROOT / "tests/data/cones/disp2.png", scale=4)
    confs = [("none (nearest point per pixel only)", {"visibility": "none"})]
    confs += [("z-buffer, footprint auto (default: tolerance 1 px, slope 0.5)", {})]
    confs += [("z-buffer, footprint auto, tolerance 2 px, slope 1", {"tolerance": 2.0, "slope": 1.0})]
    confs += [(f"z-buffer, footprint {r}", {"footprint": r}) for r in (2, 3, 4)]
    confs += [(f"HPR, gamma {g}", {"visibility": "hpr", "hpr_gamma": g}) for g in (3.0, 3.5, 4.0)]
    print("| LiDAR share | method | hidden removed | visible kept | hidden in the right view removed | "
          "max error (px) | seconds |\n|---:|---|---:|---:|---:|---:|---:|")
    for share in (0.05, 0.1, 0.3):
        with tempfile.TemporaryDirectory(prefix="vis_") as tmp:
            sc = build_scene(Path(tmp), gt, share=share)
            for name, kw in confs:
                sparse, st = project_cloud(Path(tmp) / "scene.las", sc["pair"], **kw)
                m = score(sparse, gt, sc)
                print(f"| {100 * share:.0f} % | {name} | {100 * m['hidden_removed']:.2f} % | "
                      f"{100 * m['visible_kept']:.1f} % | {100 * m['right_occluded_removed']:.1f} % | "
                      f"{m['max_error']:.4f} | {st['stage_seconds']['visibility']:.2f} |")
    block = ROOT / "sample_data" / "block"
    pair = load_pairfile(block / "pair.yaml")
    gt = read_disparity(block / "gt_disparity.tif")
    print("\n| sample aerial block: method | kept | removed | kept with error > 1 px | > 0.5 px |\n"
          "|---|---:|---:|---:|---:|")
    for name, kw in confs:
        sparse, st = project_cloud(block / "lidar.laz", pair, **kw)
        ok = np.isfinite(sparse) & np.isfinite(gt)
        err = np.abs(sparse[ok] - gt[ok])
        removed = st["occluded"]["left"] + st["occluded"]["right"]
        print(f"| {name} | {st['kept']} | {removed} | {(err > 1).sum()} ({100 * (err > 1).mean():.2f} %) | "
              f"{(err > 0.5).sum()} |")
    if kitti_dir is None:
        return 0
    import cv2

    from riverbed_cli.geometry.cameras import kitti_pair

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from kitti_lidar_demo import KITTI, photometric

    base = Path(kitti_dir) / KITTI
    pair = kitti_pair(base / "calib.txt")
    L, R = cv2.imread(str(base / "left.png")), cv2.imread(str(base / "right.png"))
    shape = L.shape[:2]
    ref, _ = project_cloud(base / "lidar.bin", pair, visibility="none", shape=shape)
    print("\n| KITTI: method | kept | removed | median abs dI kept | median abs dI removed |\n"
          "|---|---:|---:|---:|---:|")
    print(f"| none | {np.isfinite(ref).sum()} | 0 | {photometric(L, R, ref):.2f} | - |")
    for name, kw in confs[1:]:
        sparse, st = project_cloud(base / "lidar.bin", pair, shape=shape, **kw)
        removed = np.where(np.isfinite(ref) & ~np.isfinite(sparse), ref, np.nan)
        print(f"| {name} | {st['kept']} | {np.isfinite(removed).sum()} | {photometric(L, R, sparse):.2f} | "
              f"{photometric(L, R, removed):.2f} |")
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=10_000_000)
    ap.add_argument("--laz", action="store_true", help="Write and read LAZ instead of LAS.")
    ap.add_argument("--width", type=int, default=6000)
    ap.add_argument("--height", type=int, default=4000)
    ap.add_argument("--keep", default=None, help="Folder to keep the generated files in (default: none).")
    ap.add_argument("--visibility", action="store_true", help="Compare hidden point removal methods instead.")
    ap.add_argument("--kitti", default=None, help="With --visibility: the shared data folder (KITTI).")
    args = ap.parse_args()
    return visibility_table(args.kitti) if args.visibility else speed(args)


if __name__ == "__main__":
    sys.exit(main())
