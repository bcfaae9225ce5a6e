"""Does the fused DSM beat both of its inputs? The sample aerial block through the commands, as a user runs them.

Usage: python benchmarks/bench_sample_dsm.py [--block sample_data/block] [--work DIR]

One pair of the bundled sample block (``sample_data/block``: LAZ, pair file, ground-truth DSM): ``riverbed project``,
then DSMs (``riverbed dsm``, all with ``--fill-holes 3`` on the ground-truth DSM's grid) from

* the default fused match (``riverbed match --sparse``: riverbed guidance, tubes, confidence fusion),
* the same without fusion (``--fusion none``: the paper's method),
* unguided matching (``--guide none``),
* the LiDAR alone, two ways: the LAZ rasterised (``riverbed dsm --lidar``, no disparity: per-cell max, noise classes
  dropped; ``--fill-holes`` fills enclosed gaps only, and the LiDAR's empty cells form one region, so it stays
  sparse) and the linear interpolation of its sparse disparities triangulated (``riverbed densify`` then
  ``riverbed dsm``: the complete LiDAR-only DSM),
* the fused match with low-confidence points dropped (``--confidence`` / ``--min-confidence 0.5``), and merged
  with the LAZ (``riverbed dsm --lidar``: LiDAR heights in the cells it hits),

each compared with the ground-truth DSM by ``riverbed evaluate --dsm``: RMSE, NMAD, share of cells off by more than
3 GSD, completeness. Prints a markdown table.
"""

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import rasterio


def riverbed(*args):
    r = subprocess.run(["riverbed", *map(str, args)], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"riverbed {' '.join(map(str, args))} failed:\n{r.stderr}")
    return r.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--block", default=str(Path(__file__).resolve().parents[1] / "sample_data" / "block"))
    ap.add_argument("--work", default=None)
    args = ap.parse_args()
    b = Path(args.block)
    w = Path(args.work or tempfile.mkdtemp(prefix="sample_dsm_"))
    w.mkdir(parents=True, exist_ok=True)
    with rasterio.open(b / "gt_dsm.tif") as ds:
        bounds = list(ds.bounds)
        res = ds.res[0]
    grid = ["--bounds", *bounds, "--resolution", res, "--fill-holes", 3, "--overwrite"]
    riverbed("project", b / "lidar.laz", b / "pair.yaml", "-o", w / "sparse.tif", "--overwrite")
    lr = [b / "left.png", b / "right.png"]
    riverbed("match", *lr, "--sparse", w / "sparse.tif", "-o", w / "fused.tif", "--confidence", w / "conf.tif",
             "--overwrite")
    riverbed("match", *lr, "--sparse", w / "sparse.tif", "--fusion", "none", "-o", w / "paper.tif", "--overwrite")
    riverbed("match", *lr, "--sparse", w / "sparse.tif", "--guide", "none", "-o", w / "unguided.tif", "--overwrite")
    riverbed("densify", w / "sparse.tif", "-o", w / "linear.tif", "--method", "linear", "--overwrite")
    dsms = {}
    for name in ("fused", "paper", "unguided", "linear"):
        riverbed("dsm", w / f"{name}.tif", b / "pair.yaml", "-o", w / f"dsm_{name}.tif", *grid)
        dsms[name] = w / f"dsm_{name}.tif"
    riverbed("dsm", w / "fused.tif", b / "pair.yaml", "-o", w / "dsm_fused_conf.tif", "--confidence", w / "conf.tif",
             "--min-confidence", 0.5, *grid)
    dsms["fused_conf"] = w / "dsm_fused_conf.tif"
    # the sample's LiDAR is in world coordinates (its pair file has no registration)
    riverbed("dsm", "--lidar", b / "lidar.laz", "-o", w / "dsm_lidar.tif", *grid)
    dsms["lidar"] = w / "dsm_lidar.tif"
    # the fused points and the LiDAR merged (LiDAR wins in the cells it hits)
    riverbed("dsm", w / "fused.tif", b / "pair.yaml", "--lidar", b / "lidar.laz", "-o", w / "dsm_fused_lidar.tif",
             *grid)
    dsms["fused_lidar"] = w / "dsm_fused_lidar.tif"
    labels = {"fused": "riverbed + fusion (default)", "fused_conf": "riverbed + fusion, confidence >= 0.5",
              "paper": "riverbed, no fusion (the paper)", "unguided": "unguided SGM",
              "lidar": "LiDAR alone: LAZ rasterised (per-cell max)",
              "fused_lidar": "riverbed + fusion, LiDAR merged (dsm --lidar)",
              "linear": "LiDAR alone: linear interpolation, triangulated"}
    print("| DSM of the sample pair | RMSE m | NMAD m | > 3 GSD % | completeness % |\n|---|---:|---:|---:|---:|")
    for name in ("fused", "fused_conf", "fused_lidar", "paper", "unguided", "lidar", "linear"):
        m = json.loads(riverbed("evaluate", "--dsm", dsms[name], b / "gt_dsm.tif", "--json"))
        print(f"| {labels[name]} | {m['rmse']:.3f} | {m['nmad']:.3f} | {m['over_3res']:.2f} | "
              f"{m['completeness']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
