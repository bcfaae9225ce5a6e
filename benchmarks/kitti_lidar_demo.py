"""The real LiDAR case: KITTI object frame -> pair file -> sparse LiDAR disparities -> guided matching.

    python benchmarks/kitti_lidar_demo.py DATA_DIR --write benchmarks/results_kitti_lidar.json \\
        --docs docs/projection.md [--png docs]

DATA_DIR is the shared data folder (``../shared/data``); the KITTI frame stays there (CC BY-NC-SA: never
copied into the repository). Runs the real CLI (``riverbed pair kitti``, ``riverbed project``, ``riverbed
match``, ``riverbed densify``) and measures:

- the projection counts and the photometric check: median |I_left(x, y) - I_right(x - d, y)| at the LiDAR
  pixels, against the same with the disparity off by +-3 px;
- held-out accuracy: half of the LiDAR pixels (seeded) guide ``match``; every map is scored on the other half
  (LiDAR as sparse ground truth): unguided matching on the same range, riverbed with the default fusion, with the
  LiDAR check off and without the fusion (``--fusion none``), and the LiDAR-only interpolations of the guiding half
  (``riverbed densify`` nearest, linear, guided);
- what the LiDAR check dropped of the guiding half, and how much of it lies at a LiDAR depth edge.

``--write`` stores the figures (the committed result file), ``--docs`` rewrites docs/projection.md's KITTI block
from it (``tests/test_kitti_lidar.py`` gates the runs against the file, ``tests/test_projection_doc.py`` checks the
doc); ``--png FOLDER`` also writes kitti_guided.png and kitti_unguided.png: colourised maps guided by *all* LiDAR
pixels and unguided, on one colour scale.
"""

import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.io.disparity import read_disparity, write_disparity
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.visualize import colorize_disparity, write_png

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import rows_main  # noqa: E402

KITTI = "kitti_object_stereo_lidar_stereorcnn/demo"


def run(args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    if r.exit_code != 0:
        raise SystemExit(f"riverbed {' '.join(map(str, args))} failed:\n{r.output}")
    return r.stdout


def photometric(left, right, sparse, offset=0.0):
    """Median |I_L(x, y) - I_R(x - d + offset, y)| over the LiDAR pixels (grey, linear interpolation in x)."""
    L = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY).astype(np.float64)
    R = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY).astype(np.float64)
    rows, cols = np.nonzero(np.isfinite(sparse))
    xs = cols - sparse[rows, cols].astype(np.float64) + offset
    ok = (xs >= 0) & (xs <= R.shape[1] - 1)
    rows, cols, xs = rows[ok], cols[ok], xs[ok]
    x0 = np.floor(xs).astype(int)
    x1 = np.minimum(x0 + 1, R.shape[1] - 1)
    f = xs - x0
    return float(np.median(np.abs(L[rows, cols] - (R[rows, x0] * (1 - f) + R[rows, x1] * f))))


def pipeline(data_dir, work):
    """Pair file, sparse map and photometric figures; returns (paths, summary)."""
    base = Path(data_dir) / KITTI
    left, right = base / "left.png", base / "right.png"
    pair, sparse = work / "kitti.yaml", work / "lidar.tif"
    run(["pair", "kitti", base / "calib.txt", "-o", pair, "--left", left, "--right", right, "--overwrite"])
    stats = json.loads(run(["project", base / "lidar.bin", pair, "-o", sparse, "--json", "--overwrite"]))
    s = read_disparity(sparse)
    L, R = cv2.imread(str(left)), cv2.imread(str(right))
    photo = {f"{o:+d}" if o else "0": photometric(L, R, s, o) for o in (0, -3, 3)}
    paths = {"left": left, "right": right, "pair": pair, "sparse": sparse}
    return paths, {"project": stats, "photometric": photo}


def edge_share(sparse, dropped, reach=8, step=3.0):
    """Share of the ``dropped`` LiDAR pixels with another LiDAR point within ``reach`` px at least ``step`` px
    nearer (a larger disparity): points behind a depth edge, which the LiDAR sees and the camera may not."""
    near = cv2.dilate(np.nan_to_num(sparse, nan=-1e9).astype(np.float32), np.ones((2 * reach + 1,) * 2, np.uint8))
    rows, cols = np.nonzero(dropped)
    if rows.size == 0:
        return 0.0
    return float(np.mean(near[rows, cols] >= sparse[rows, cols] + step))


BEGIN, END = "<!-- kitti_lidar_demo: begin -->", "<!-- kitti_lidar_demo: end -->"
#: the matches of the held-out comparison: (name, options); the guided ones take the guiding half, the default (the
#: second) also writes its LiDAR mask
MATCHES = (("unguided census-SGM", ["--guide", "none"]),
           ("riverbed (default: LiDAR check, fusion)", []),
           ("riverbed, LiDAR check off", ["--lidar-check", "off"]),
           ("riverbed, no fusion", ["--fusion", "none"]))
#: the LiDAR-only interpolations of the guiding half (riverbed densify --method)
DENSIFY = ("nearest", "linear", "guided")


def held_out(paths, work):
    """Half of the LiDAR pixels (rng seed 0) guide, the other half scores: per method its ``evaluate_disparity``
    figures; with what the default's LiDAR check dropped. Returns ``(rows, check, run)``, ``run`` the maps by method,
    the range searched (``lo``, ``hi``) and the held-out ``truth``."""
    sparse = read_disparity(paths["sparse"])
    lo, hi = int(np.floor(np.nanmin(sparse))) - 4, int(np.ceil(np.nanmax(sparse))) + 4
    rng = np.random.default_rng(0)
    held = np.isfinite(sparse) & (rng.random(sparse.shape) < 0.5)
    guide_half = np.where(held, np.nan, sparse)
    truth = np.where(held, sparse, np.nan)
    write_disparity(work / "half.tif", guide_half, overwrite=True)
    common = [paths["left"], paths["right"], "--min-disp", lo, "--max-disp", hi, "--overwrite"]
    rows, maps, check = [], {}, None
    for i, (name, extra) in enumerate(MATCHES):
        guided = [] if "--guide" in extra else ["--sparse", work / "half.tif"]
        if i == 1:  # the default: what its LiDAR check did, per pixel
            extra = [*extra, "--lidar-mask", work / "mask.png"]
        info = json.loads(run(["match", *common, *guided, *extra, "-o", work / f"run_{i}.tif", "--json"]))
        disp = read_disparity(work / f"run_{i}.tif")
        rows.append({"method": name, "kind": "stereo", **_figures(evaluate_disparity(disp, truth))})
        maps[name] = disp
        if i == 1:
            check = info["lidar_check"]
    for method in DENSIFY:
        out = work / f"densify_{method}.tif"
        run(["densify", work / "half.tif", "-o", out, "--method", method, "--image", paths["left"], "--overwrite"])
        rows.append({"method": f"LiDAR only: {method} interpolation", "kind": "lidar",
                     **_figures(evaluate_disparity(read_disparity(out), truth))})
    mask = cv2.imread(str(work / "mask.png"), cv2.IMREAD_UNCHANGED)
    check = {k: check[k] for k in ("points", "compared", "disagree", "outliers", "changed", "regions")}
    check["at_depth_edges"] = round(edge_share(guide_half, (mask == 2) | (mask == 3)), 4)
    return rows, check, {"maps": maps, "lo": lo, "hi": hi, "truth": truth}


def _figures(m):
    return {"bad1": round(m["bad1"], 3), "bad3": round(m["bad3"], 3), "avg": round(m["avg"], 4), "n": int(m["n"]),
            "density": round(m["density"], 3)}


def measure(data, png=None):
    """The figures of the committed result file (module docstring); ``png``: a folder for the two maps."""
    work = Path(tempfile.mkdtemp(prefix="kitti_"))
    paths, summary = pipeline(data, work)
    st = summary["project"]
    rows, check, done = held_out(paths, work)
    maps, lo, hi = done["maps"], done["lo"], done["hi"]
    result = {"project": {k: st[k] for k in ("points_read", "behind_camera", "outside", "row_offset", "occluded",
                                             "kept", "window", "lidar_share", "row_offset_px")}
              | {"outliers": st["filtered"]["outliers"], "d_range": [round(v, 1) for v in st["d_range"]]},
              "photometric": {k: round(v, 2) for k, v in summary["photometric"].items()},
              "held_out": rows, "check": check}
    if png:
        out = Path(png)
        out.mkdir(parents=True, exist_ok=True)
        sparse = read_disparity(paths["sparse"])
        write_disparity(work / "all.tif", sparse, overwrite=True)
        run(["match", paths["left"], paths["right"], "--min-disp", lo, "--max-disp", hi, "--sparse", work / "all.tif",
             "-o", work / "all_guided.tif", "--overwrite"])
        for name, disp in (("kitti_unguided.png", maps[MATCHES[0][0]]),
                           ("kitti_guided.png", read_disparity(work / "all_guided.tif"))):
            write_png(out / name, colorize_disparity(disp, lo, hi), overwrite=True)
    return result


def tables(result):
    """docs/projection.md's KITTI block: the projection, the photometric check, the held-out table, the check."""
    p, ph, c = result["project"], result["photometric"], result["check"]
    occ = p["occluded"]
    n = result["held_out"][0]["n"]
    out = [f"`riverbed project lidar.bin` (defaults): {p['kept']:,} of {p['points_read']:,} points kept "
           f"({p['behind_camera']:,} behind the camera, {p['outside']:,} outside the image, {p['outliers']:,} "
           f"outliers, {occ['same_pixel']} beaten in their pixel, {occ['left']} hidden in the left view, "
           f"{occ['right']} in the right), LiDAR share {100 * p['lidar_share']:.1f} %, suggested window "
           f"{p['window']}, d {p['d_range'][0]}–{p['d_range'][1]} px; right-row offsets of the kept points: median "
           f"{p['row_offset_px']['median']:.2f} px, maximum {p['row_offset_px']['max']:.2f} px, {p['row_offset']} "
           "dropped.", "",
           f"- **Photometric check**: median |I_left(x, y) - I_right(x - d, y)| (grey, linear interpolation) at the "
           f"LiDAR pixels is **{ph['0']:.2f}**, against **{ph['-3']:.2f}** at `x - d - 3` and **{ph['+3']:.2f}** at "
           "`x - d + 3`: the disparities agree with the images.",
           "- **Guided vs unguided and LiDAR only** (half of the LiDAR pixels, seeded, guide or are interpolated; "
           f"every map is scored on the other half, {n:,} LiDAR pixels: LiDAR shares are of image pixels, errors "
           "of the held-out LiDAR pixels):", "",
           "| method | >1 px | >3 px | mean abs error (px) | scored pixels with a disparity |",
           "|---|---:|---:|---:|---:|"]
    for r in result["held_out"]:
        out.append(f"| {r['method']} | {r['bad1']:.1f} % | {r['bad3']:.1f} % | {r['avg']:.2f} | "
                   f"{r['density']:.1f} % |")
    out += ["", reading(result["held_out"])]
    out += ["", f"The default's LiDAR check judged {c['compared']:,} of the guiding half's {c['points']:,} points "
            f"against the images, found {c['disagree']:,} contradicted and dropped {c['outliers']} as outliers and "
            f"{c['changed']} in {c['regions']} changed regions; {100 * c['at_depth_edges']:.0f} % of the dropped "
            "points lie at a LiDAR depth edge (another LiDAR point within 8 px, more than 3 px nearer)."]
    return "\n".join(out)


METRICS = {"bad1": ">1 px", "bad3": ">3 px", "avg": "mean error"}


def reading(rows):
    """Which figures the fused default wins against unguided stereo, each LiDAR-only fill and the check turned off,
    from the rows (a sentence of the doc)."""
    by = {r["method"]: r for r in rows}
    d = by[MATCHES[1][0]]

    def versus(name):
        won = [t for k, t in METRICS.items() if d[k] < by[name][k]]
        lost = [t for k, t in METRICS.items() if d[k] > by[name][k]]
        if not lost:
            return "wins on every figure" if len(won) == len(METRICS) else f"wins on {', '.join(won) or 'none'}"
        if not won:
            return "loses on every figure" if len(lost) == len(METRICS) else f"loses on {', '.join(lost)}"
        return f"wins on {', '.join(won)}, loses on {', '.join(lost)}"

    fills = [r["method"] for r in rows if r["kind"] == "lidar"]
    parts = [f"{name.split(': ')[1].split(' ')[0]}: {versus(name)}" for name in fills]
    return (f"Against unguided stereo the fused default {versus(MATCHES[0][0])}; against the LiDAR-only fills "
            f"({'; '.join(parts)}) it is judged on held-out LiDAR pixels, by the sensor the fills interpolate (the "
            "KITTI 2015 frame of docs/benchmarks.md has camera ground truth). Against the same run with the LiDAR "
            f"check off it {versus(MATCHES[2][0])}.")


def main():
    rows_main(__doc__, measure, tables, BEGIN, END, options=[("--png", "also write the two colourised maps here")])


if __name__ == "__main__":
    main()
