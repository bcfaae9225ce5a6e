"""The paper's Table 2 comparison on the synthetic satellite sample (issue 14 item 6, docs/rpc_synthetic.md).

    python benchmarks/bench_rpc_synthetic.py [--size small|full] [--seed N] [--work DIR] [--densities ...]
                                             [--methods ...] [--roi COL,ROW,W,H] [--json]

Runs the chain as a user does, each step a ``riverbed`` subprocess:

1. ``riverbed sample WORK/sample --satellite`` (raw pushbroom images with fitted RPCs, GT DSM, LiDAR);
2. ``riverbed rectify --rpc left.tif left.tif right.tif right.tif --heights LO,HI`` (the scene's height range
   from ``scene.json``, +- 5 m), the default pointing correction included;
3. per LiDAR density (``lidar.laz``, ``lidar_sparse.laz``, and ``lidar_thin.laz``: a quarter of the sparse one,
   drawn here with laspy): ``riverbed project`` onto the pair (default z-buffer and outlier removal);
4. ``riverbed match`` unguided (``--guide none``, the pair's disparity range), Gauss, diffusion and riverbed
   (``--range full --fusion none``: each guide alone on the cost volume, the paper's setting; same range), the
   fused default (``--sparse`` alone: riverbed + tubes + fusion); ``riverbed densify`` nearest, linear, guided
   (the LiDAR-only baselines);
5. ``riverbed dsm`` of each on the GT DSM's grid (``--bounds``, ``--resolution``), ``riverbed evaluate --dsm``
   against ``gt_dsm.tif``; ``riverbed evaluate`` of each disparity map against the exact GT disparity with the
   LiDAR pixels excluded (``--exclude``).

The ground-truth disparity is exact: every pixel of the rectified left image is mapped back to the raw left image
(``H_left^-1`` from ``pair.yaml``), its line of sight through the *rigorous* pushbroom camera cast onto the
scene itself, the surface point projected by the right camera and through ``H_right``
(``riverbed_cli.sample.satellite.ground_truth_disparity``; NaN where the right camera does not see it). LiDAR
shares are of the rectified left image's pixels (``riverbed project``'s ``lidar_share``).
"""

import argparse
import json
import math
import sys
import tempfile
import textwrap
from pathlib import Path

import laspy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_rpc_ventoux import riverbed  # noqa: E402  (runs the CLI as a user would)

from riverbed_cli.geometry.pairfile import load_pairfile  # noqa: E402
from riverbed_cli.io.disparity import write_disparity
from riverbed_cli.sample.satellite import ground_truth_disparity, satellite_scene

DENSITIES = ("lidar", "lidar_sparse", "lidar_thin")
#: name -> (kind, extra arguments); "match" methods get the LiDAR with --sparse, "densify" ones are LiDAR-only.
METHODS = {
    "unguided": ("match", ["--guide", "none"]),
    "gauss": ("match", ["--guide", "gauss", "--range", "full", "--fusion", "none"]),
    "diffusion": ("match", ["--guide", "diffusion", "--range", "full", "--fusion", "none"]),
    "riverbed": ("match", ["--guide", "riverbed", "--range", "full", "--fusion", "none"]),
    "fused default": ("match", []),
    "lidar nearest": ("densify", ["--method", "nearest"]),
    "lidar linear": ("densify", ["--method", "linear"]),
    "lidar guided": ("densify", ["--method", "guided"]),
}
THIN_SHARE = 0.25
HEIGHT_MARGIN = 5.0


def thin_laz(src, dst, share, seed=0):
    """A random ``share`` of the points of ``src`` written to ``dst`` (same header, CRS and point format)."""
    las = laspy.read(str(src))
    keep = np.random.default_rng([seed, 44]).random(len(las.points)) < share
    out = laspy.LasData(las.header)
    out.points = las.points[keep]
    out.write(str(dst), do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
    return int(keep.sum())


def run(work, size="small", seed=0, densities=DENSITIES, methods=tuple(METHODS), roi=None):
    """Steps 1-5 in ``work``; the summary (dict): sample, rectification, GT disparity, one row per (density,
    method) with DSM ``rmse``, ``nmad``, ``over_3res``, ``completeness`` and disparity ``bad1``, ``bad3``,
    ``avg`` (the unguided row is matched once and evaluated against each density's exclusion mask)."""
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    sample = work / "sample"
    gen = riverbed("sample", sample, "--satellite", "--size", size, "--seed", seed, "--overwrite", "--json")
    desc = json.loads((sample / "scene.json").read_text())
    lo, hi = desc["heights_m"]
    heights = f"{math.floor(lo - HEIGHT_MARGIN)},{math.ceil(hi + HEIGHT_MARGIN)}"
    left, right = sample / "left.tif", sample / "right.tif"
    extra = [] if roi is None else ["--roi", roi]
    rect = riverbed("rectify", "--rpc", left, left, right, right, "-o", work / "rect", "--heights", heights, *extra,
                    "--overwrite", "--json")
    pair_file = work / "rect" / "pair.yaml"
    pair = load_pairfile(pair_file, accept_rpc=True)
    _, _, cameras, scene = satellite_scene(size, seed)
    gt, gt_info = ground_truth_disparity(scene, cameras, pair)
    gt_path = work / "gt_disparity.tif"
    write_disparity(gt_path, gt.astype(np.float32), overwrite=True)
    rl, rr = work / "rect" / "left.tif", work / "rect" / "right.tif"
    dmin, dmax = int(math.floor(pair.disparity[0])), int(math.ceil(pair.disparity[1]))
    full_range = ["--min-disp", dmin, "--max-disp", dmax]
    g = desc["dsm"]
    grid = ["--bounds", *g["bounds"], "--resolution", g["resolution_m"]]
    summary = {"sample": {k: gen[k] for k in ("image", "gsd_m", "base_to_height", "heights_m", "rpc_check_rms_px",
                                              "rpc_check_max_px", "lidar_points", "lidar_sparse_points", "seconds")},
               "lidar_density_per_m2": {"lidar": desc["lidar"]["density_per_m2"],
                                        "lidar_sparse": desc["lidar"]["sparse_density_per_m2"],
                                        "lidar_thin": desc["lidar"]["sparse_density_per_m2"] * THIN_SHARE},
               "rectify": {k: rect[k] for k in ("width", "height", "heights", "disparity", "disparity_per_metre",
                                                "pointing_row_offset_px", "virtual_row_residual_max_px")},
               "gt_disparity": gt_info, "gt_dsm_cells": g["valid_cells"], "roi": roi, "size": size, "seed": seed,
               "rows": []}
    done = {}

    def evaluate(name, disp, sparse, density, seconds, lidar_share):
        if disp not in done:
            dsm = disp.with_name("dsm_" + disp.name)
            riverbed("dsm", disp, pair_file, "-o", dsm, *grid, "--overwrite", "--json")
            done[disp] = riverbed("evaluate", "--dsm", dsm, sample / "gt_dsm.tif", "--json")
        ev = done[disp]
        ed = riverbed("evaluate", disp, gt_path, "--exclude", sparse, "--json")
        summary["rows"].append({"density": density, "lidar_share": lidar_share, "method": name, "seconds": seconds,
                                **{k: ev[k] for k in ("rmse", "nmad", "median", "over_3res", "completeness")},
                                **{k: ed[k] for k in ("bad1", "bad3", "avg")}, "predicted": ed["density"]})

    unguided = None
    for density in densities:
        cloud = sample / f"{density}.laz"
        if density == "lidar_thin":
            cloud = work / "lidar_thin.laz"
            thin_laz(sample / "lidar_sparse.laz", cloud, THIN_SHARE, seed)
        sparse = work / f"sparse_{density}.tif"
        p = riverbed("project", cloud, pair_file, "-o", sparse, "--overwrite", "--json")
        share = p["lidar_share"]
        for name in methods:
            kind, args = METHODS[name]
            tag = name.replace(" ", "_")
            if name == "unguided":
                if unguided is None:
                    unguided = work / "unguided.tif"
                    m = riverbed("match", rl, rr, *args, *full_range, "-o", unguided, "--overwrite", "--json")
                    summary["unguided_seconds"] = m["seconds"]
                evaluate(name, unguided, sparse, density, summary["unguided_seconds"], share)
                continue
            out = work / f"{tag}_{density}.tif"
            if kind == "match":
                rng = full_range if "--range" in args else []
                m = riverbed("match", rl, rr, "--sparse", sparse, *args, *rng, "-o", out, "--overwrite", "--json")
                seconds = m["seconds"]
            else:
                img = ["--image", rl] if "guided" in args else []
                riverbed("densify", sparse, "-o", out, *args, *img, "--overwrite")
                seconds = None
            evaluate(name, out, sparse, density, seconds, share)
    return summary


def table(summary):
    lines = ["| LiDAR | pt/m² | share of pixels (%) | method | DSM RMSE (m) | DSM NMAD (m) | > 3 GSD (%) | "
             "completeness (%) | with a disparity (%) | bad1 (%) | bad3 (%) | mean error (px) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    dens = summary["lidar_density_per_m2"]
    for r in summary["rows"]:
        lidar = (f"{r['density']} | {dens[r['density']]:.2f} | {100 * r['lidar_share']:.1f}"
                 if r["method"] != "unguided" else f"— (without {r['density']}'s pixels) | — | —")
        lines.append(f"| {lidar} | {r['method']} | "
                     f"{r['rmse']:.3f} | {r['nmad']:.3f} | {r['over_3res']:.2f} | {r['completeness']:.1f} | "
                     f"{r['predicted']:.1f} | {r['bad1']:.2f} | {r['bad3']:.2f} | {r['avg']:.3f} |")
    return "\n".join(lines)


#: the markers of the generated blocks of docs/rpc_synthetic.md: the whole small sample, and the test's ROI
BEGIN = {"whole": "<!-- bench_rpc_synthetic: whole begin -->", "roi": "<!-- bench_rpc_synthetic: roi begin -->"}
END = {"whole": "<!-- bench_rpc_synthetic: whole end -->", "roi": "<!-- bench_rpc_synthetic: roi end -->"}
LIDAR_ONLY = ("lidar nearest", "lidar linear", "lidar guided")


def _rows(summary):
    """``{(density, method): row}``."""
    return {(r["density"], r["method"]): r for r in summary["rows"]}


def chain_text(summary):
    """The rectification, GT disparity and LiDAR figures of a run, as docs/rpc_synthetic.md states them."""
    r, gd = summary["rectify"], summary["gt_disparity"]
    shares = {}
    for row in summary["rows"]:
        shares[row["density"]] = row["lidar_share"]
    lo, hi = r["heights"]
    rms, mx = summary["sample"]["rpc_check_rms_px"], summary["sample"]["rpc_check_max_px"]
    out = [f"RPC check (the fit's error on its check grid, left / right): rms **{rms[0]:.4f} / {rms[1]:.4f} px**, "
           f"max {mx[0]:.3f} / {mx[1]:.3f} px. "
           f"`riverbed rectify --rpc ... --heights {lo:g},{hi:g}`: {r['width']} x {r['height']} rectified, d in "
           f"{r['disparity'][0]:.1f}–{r['disparity'][1]:.1f} px, **{r['disparity_per_metre']:.3f} px per metre** of "
           f"height; the affine model's virtual rows {r['virtual_row_residual_max_px']:.3f} px max; the pointing "
           f"correction measured **{r['pointing_row_offset_px']:+.3f} px** of rows (the RPCs have no pointing error: "
           f"this is the estimate's own error). GT disparity on {100 * gd['valid_share']:.1f} % of the rectified "
           f"pixels, rows {gd['row_error_rms_px']:.3f} px rms from the truth ({gd['row_error_max_px']:.3f} max). "
           "LiDAR through `riverbed project` on "
           + ", ".join(f"**{100 * v:.1f} %** of the image's pixels ({k})" for k, v in shares.items()) + "."]
    return "\n".join(textwrap.fill(t, 116, break_on_hyphens=False) for t in out)


def reading(summary):
    """The claims docs/rpc_synthetic.md makes of the whole table, with their figures."""
    rows = _rows(summary)
    dens = [d for d in DENSITIES if (d, "fused default") in rows]
    pct = {d: f"{100 * rows[d, 'fused default']['lidar_share']:.1f} %" for d in dens}
    u = rows[dens[0], "unguided"]
    f = [rows[d, "fused default"] for d in dens]
    name = {"rmse": "RMSE", "nmad": "NMAD", "over_3res": "> 3 GSD", "bad1": "bad1", "bad3": "bad3",
            "avg": "mean error"}
    ahead = [m for m in name if all(rows[d, "fused default"][m] < rows[d, "unguided"][m] for d in dens)]
    behind = [(d, m) for m in name if m not in ahead for d in dens
              if rows[d, "fused default"][m] >= rows[d, "unguided"][m]]
    lines = [f"- **Against unguided matching** the fused default is ahead at every density on "
             + ", ".join(name[m] for m in ahead) + f": DSM NMAD {u['nmad']:.2f} m unguided, "
             + " / ".join(f"{r['nmad']:.3f}" for r in f) + " m fused (" + " / ".join(pct[d] for d in dens)
             + " of the pixels)"
             + ("; behind it on " + ", ".join(f"{name[m]} at {pct[d]} ({rows[d, 'fused default'][m]:.3f} vs "
                                              f"{rows[d, 'unguided'][m]:.3f})" for d, m in behind) if behind else "")
             + ". Riverbed ahead of Gauss on bad1 at every density ("
             + ", ".join(f"{rows[d, 'riverbed']['bad1']:.1f} vs {rows[d, 'gauss']['bad1']:.1f} %" for d in dens)
             + ")."]
    for d in dens:
        fd = rows[d, "fused default"]
        best = {m: min(LIDAR_ONLY, key=lambda k, m=m: rows[d, k][m]) for m in ("rmse", "nmad", "bad1", "avg")}
        wins = [m for m in ("rmse", "nmad", "bad1", "avg") if fd[m] < rows[d, best[m]][m]]
        loses = [m for m in ("rmse", "nmad", "bad1", "avg") if m not in wins]
        lines.append(f"- **{d} ({pct[d]})**: the fused default against the best LiDAR-only interpolation of each "
                     "figure " + ("wins " + ", ".join(f"{name[m]} ({fd[m]:.3f} vs {rows[d, best[m]][m]:.3f}, "
                                                     f"{best[m]})" for m in wins) if wins else "wins none")
                     + ("; loses " + ", ".join(f"{name[m]} ({fd[m]:.3f} vs {rows[d, best[m]][m]:.3f}, {best[m]})"
                                                for m in loses) if loses else "") + ".")
    return "\n".join(textwrap.fill(t, 116, subsequent_indent="  ", break_on_hyphens=False) for t in lines)


def tables(summary):
    """The generated block of docs/rpc_synthetic.md for a run: the whole sample's (its chain, table and reading) or
    the test's ROI's (its chain and table)."""
    parts = [chain_text(summary), "", table(summary)]
    if summary.get("roi") is None:
        parts += ["", reading(summary)]
    return "\n".join(parts)


def write_docs(path, summary):
    """Rewrite the block of docs ``path`` that ``summary``'s configuration makes."""
    from datasets import rewrite_block

    kind = "whole" if summary.get("roi") is None else "roi"
    rewrite_block(path, BEGIN[kind], END[kind], tables(summary))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="small", choices=("small", "full"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", help="work folder (default: a temporary one, removed)")
    ap.add_argument("--densities", default=",".join(DENSITIES), help="comma-separated, of " + ", ".join(DENSITIES))
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated, of " + ", ".join(METHODS))
    ap.add_argument("--roi", help="COL,ROW,W,H of the left image to rectify (default: all of it)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--write", help="store the summary in this JSON file (benchmarks/results_rpc_synthetic*.json)")
    ap.add_argument("--docs", help="rewrite this Markdown file's block for the run's configuration")
    ap.add_argument("--rows", help="take the summary from this JSON file instead of running")
    a = ap.parse_args(argv)
    kw = {"size": a.size, "seed": a.seed, "densities": tuple(a.densities.split(",")),
          "methods": tuple(a.methods.split(",")), "roi": a.roi}
    if a.rows:
        summary = json.loads(Path(a.rows).read_text())
    elif a.work:
        summary = run(a.work, **kw)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            summary = run(tmp, **kw)
    if a.write:
        Path(a.write).write_text(json.dumps(summary, indent=1) + "\n")
    if a.docs:
        write_docs(a.docs, summary)
    if a.json:
        print(json.dumps(summary, indent=1))
    else:
        s, r, gd = summary["sample"], summary["rectify"], summary["gt_disparity"]
        print(f"sample {a.size} seed {a.seed}: {s['image']} px at {s['gsd_m']} m, B/H {s['base_to_height']}, RPC "
              f"check rms {s['rpc_check_rms_px']} px (max {s['rpc_check_max_px']}); rectified {r['width']} x "
              f"{r['height']}, d {[round(v, 2) for v in r['disparity']]}, {r['disparity_per_metre']:.3f} px/m, "
              f"pointing {r['pointing_row_offset_px']:.3f} px; GT disparity on {100 * gd['valid_share']:.1f} % "
              f"of the pixels (rows off by {gd['row_error_rms_px']:.3f} px rms); GT DSM cells "
              f"{summary['gt_dsm_cells']}")
        print(tables(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
