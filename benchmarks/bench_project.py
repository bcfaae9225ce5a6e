"""Speed and memory of ``riverbed project`` on 10 million points, against reading the file with laspy alone.

    python benchmarks/bench_project.py --write benchmarks/results_project.json --docs docs/projection.md

Generates, in a temporary folder, an aerial-like scene: a hilly terrain with flat-roofed buildings in a
UTM-like frame (origin 500000, 5000000), sampled at random and stored in 5 m strips (as a flight line would
be; LAS 1.4 point format 6, 1 mm scale), written as LAS and as LAZ, and a pair file for a nadir camera 1000 m
above it (f = 10000 px, 300 m baseline, 6000 x 4000 px) that sees the whole cloud. Then, for each file, each run
in a fresh subprocess after one warm-up run that compiles or loads the kernels (peak RSS as VmHWM and RSS after the
imports, from /proc/self/status):

- ``laspy``: read the file in 1-million-point chunks and compute the float64 coordinates (the decoding floor);
- ``project``: the full ``riverbed project`` (CLI, default options: SOR, z-buffer visibility in both views);
- ``project --outliers none --visibility none``: streaming projection and the nearest point per pixel only.

``--write`` stores the figures (the committed result file), ``--docs`` rewrites docs/projection.md's speed block
from it (``tests/test_projection_doc.py`` checks the doc). ``--points N`` for a smaller cloud.

The hidden point removal methods are compared by ``bench_hidden_points.py``.
"""

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import rows_main  # noqa: E402

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


RUNS = (("laspy read (chunks of 1M, float64 xyz)", None),
        ("`riverbed project` (defaults: SOR, z-buffer both views)", []),
        ("`riverbed project --outliers none --visibility none`", ["--outliers", "none", "--visibility", "none"]))
BEGIN, END = "<!-- bench_project: begin -->", "<!-- bench_project: end -->"


def measure(data=None, points=None, width=6000, height=4000):
    """The figures of the committed result file (module docstring); ``data`` is not used (the scene is made)."""
    n = int(points or 10_000_000)
    out = {"points": n, "width": width, "height": height, "files": []}
    for laz in (False, True):
        with tempfile.TemporaryDirectory(prefix="bench_project_") as tmp:
            folder = Path(tmp)
            cloud, pair = make_scene(folder, n, laz, width, height)
            sub(PROJECT, "project", cloud, pair, "-o", folder / "warm.tif", "--json", "--overwrite")
            runs = []
            for name, extra in RUNS:
                r = sub(LASPY_READ, cloud) if extra is None else sub(
                    PROJECT, "project", cloud, pair, "-o", folder / "s.tif", "--json", "--overwrite", *extra)
                st = r.get("stats")
                runs.append({"run": name, "seconds": round(r["seconds"], 2), "rss_mib": round(r["rss_kb"] / 1024),
                             "base_mib": round(r["base_kb"] / 1024),
                             "stages": {k: round(v, 2) for k, v in st["stage_seconds"].items()} if st else None})
                if extra == []:
                    counts = {k: st[k] for k in ("kept", "lidar_share")} | dict(st["occluded"]) | {
                        "outliers": st["filtered"]["outliers"]}
            out["files"].append({"format": "LAZ" if laz else "LAS", "mib": round(cloud.stat().st_size / 2**20),
                                 "runs": runs, "counts": counts})
    return out


def tables(result):
    """docs/projection.md's speed block: the table and the counts of the default run."""
    n = result["points"]
    lines = ["| file | run | seconds | points/s | peak RSS (MiB) | stages (s) |", "|---|---|---:|---:|---:|---|"]
    for f in result["files"]:
        for i, r in enumerate(f["runs"]):
            name = f"{f['format']} ({f['mib']} MiB)" if i == 0 else f["format"]
            stages = ", ".join(f"{k} {v:.1f}" for k, v in r["stages"].items()) if r["stages"] else ""
            lines.append(f"| {name} | {r['run']} | {r['seconds']:.1f} | {n / r['seconds'] / 1e6:.2f} M | "
                         f"{r['rss_mib']} | {stages} |")
    c = result["files"][0]["counts"]
    pixels = result["width"] * result["height"]
    las = result["files"][0]["runs"]
    lines += ["", f"{n / 1e6:g} million points, a {result['width']} x {result['height']} frame: {c['kept']:,} pixels "
              f"get a disparity (share {100 * c['lidar_share']:.0f} %); {c['same_pixel']:,} points lose their pixel "
              f"to a nearer one, {c['left']:,} are hidden in the left view and {c['right']:,} in the right (next to "
              f"the buildings' walls), {c['outliers']:,} are outliers. The imports alone take "
              f"{las[1]['base_mib']} MiB (riverbed) and {las[0]['base_mib']} MiB (laspy); the default run's peak is "
              f"{1024 ** 2 * las[1]['rss_mib'] / pixels:.0f} bytes per image pixel."]
    return "\n".join(lines)


def main():
    rows_main(__doc__, measure, tables, BEGIN, END, options=[("--points", "points in the cloud (10,000,000)")])


if __name__ == "__main__":
    main()
