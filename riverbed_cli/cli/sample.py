"""``riverbed sample``: generate the synthetic aerial block (rectified pair, LiDAR, ground-truth disparity and DSM),
or with ``--satellite`` the synthetic satellite pair (raw images with RPCs, ground-truth DSM, LiDAR)."""

import logging

import click

from ..sample import SIZES, STAGES, generate_block
from ..sample.satellite import SATELLITE_STAGES, generate_satellite
from .options import json_opt, overwrite_opt, print_json, progress_bar

log = logging.getLogger(__name__)


@click.command("sample")
@click.argument("outdir", type=click.Path(file_okay=False))
@click.option("--size", type=click.Choice(list(SIZES)), default="small", show_default=True,
              help="small: 720x540 pair (the copy in sample_data/block); full: 2000x1500 pair, larger scene.")
@click.option("--satellite", is_flag=True,
              help="Write the synthetic satellite pair instead (docs/rpc_synthetic.md): raw pushbroom images with "
                   "RPC tags (left.tif, right.tif), gt_dsm.tif (EPSG:32632, ellipsoidal heights), lidar.laz and "
                   "lidar_sparse.laz; --size small: 480x480 images, full: 1200x1000.")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Seed of the scene layout, camera attitudes, image noise and LiDAR (same seed, same files).")
@overwrite_opt
@json_opt
def sample_cmd(outdir, size, satellite, seed, overwrite, as_json):
    """Generate a synthetic aerial block into OUTDIR (created if missing).

    Writes left.png and right.png (a rectified pair rendered by ray casting), pair.yaml, lidar.laz (airborne
    LiDAR, EPSG:32632), gt_disparity.tif (d = x_left - x_right, NaN unknown), gt_dsm.tif (surface heights on a
    north-up grid), scene.json (sun, cameras, scanner, layout) and MANIFEST.md. Deterministic for a seed.

    With --satellite: a satellite stereo pair over the same kind of scene instead (docs/rpc_synthetic.md):
    left.tif and right.tif (raw pushbroom images with RPC tags), gt_dsm.tif (EPSG:32632, ellipsoidal
    heights), lidar.laz, lidar_sparse.laz (EPSG:32632 3D), scene.json (cameras, RPC fit errors) and MANIFEST.md.
    """
    if satellite:
        command = f"riverbed sample {outdir} --satellite --size {size} --seed {seed}"
        stages, generate = SATELLITE_STAGES, generate_satellite
    else:
        command = f"riverbed sample {outdir} --size {size} --seed {seed}"
        stages, generate = STAGES, generate_block
    with progress_bar(len(stages), desc="sample", unit="stage", leave=False) as bar:
        summary = generate(outdir, size, seed, overwrite, command=command, progress=lambda stage: bar.update())
    if as_json:
        print_json(summary)
    else:
        log.info("%s: %d files, %.1f MB, %s s", outdir, len(summary["files"]), summary["bytes"] / 1e6,
                 summary["seconds"]["total"])
