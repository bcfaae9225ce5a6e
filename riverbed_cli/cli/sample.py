"""``riverbed sample``: generate the synthetic aerial block (rectified pair, LiDAR, ground-truth disparity and DSM)."""

import logging

import click
from tqdm import tqdm

from ..sample import SIZES, STAGES, generate_block
from .options import json_opt, overwrite_opt, print_json, progress_enabled

log = logging.getLogger(__name__)


@click.command("sample")
@click.argument("outdir", type=click.Path(file_okay=False))
@click.option("--size", type=click.Choice(list(SIZES)), default="small", show_default=True,
              help="small: 720x540 pair (the copy in sample_data/block); full: 2000x1500 pair, larger scene.")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Seed of the scene layout, camera attitudes, image noise and LiDAR (same seed, same files).")
@overwrite_opt
@json_opt
def sample_cmd(outdir, size, seed, overwrite, as_json):
    """Generate a synthetic aerial block into OUTDIR (created if missing).

    Writes left.png and right.png (a rectified pair rendered by ray casting), pair.yaml, lidar.laz (airborne
    LiDAR, EPSG:32632), gt_disparity.tif (d = x_left - x_right, NaN unknown), gt_dsm.tif (surface heights on a
    north-up grid), scene.json (sun, cameras, scanner, layout) and MANIFEST.md. Deterministic for a seed.
    """
    command = f"riverbed sample {outdir} --size {size} --seed {seed}"
    with tqdm(total=len(STAGES), desc="sample", unit="stage", disable=not progress_enabled(), leave=False) as bar:
        summary = generate_block(outdir, size, seed, overwrite, command=command, progress=lambda stage: bar.update())
    if as_json:
        print_json(summary)
    else:
        log.info("%s: %d files, %.1f MB, %s s", outdir, len(summary["files"]), summary["bytes"] / 1e6,
                 summary["seconds"]["total"])
