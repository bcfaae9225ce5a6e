"""``riverbed block``: run project -> match -> dsm for every pair of a block manifest and merge one DSM."""

import logging

import click
from tqdm import tqdm

from ..errors import RiverbedError
from ..scale.block import plan_block, run_block
from .options import input_path, json_opt, print_json, progress_enabled

log = logging.getLogger(__name__)


@click.command("block")
@click.argument("manifest", type=input_path())
@click.option("-o", "--output", "outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder: OUTDIR/dsm.tif (merged DSM) and OUTDIR/pairs/NAME/ (per-pair products).")
@click.option("--workers", type=click.IntRange(0), default=None,
              help="Worker processes of the local dask cluster [default: CPUs / threads per worker]; 0: run the "
                   "pairs one after the other in this process, without dask.")
@click.option("--threads-per-worker", type=click.IntRange(1), default=1, show_default=True,
              help="Dask threads per worker; each task gets CPUs / (workers x threads) Numba threads.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Address of a running dask scheduler (tcp://host:8786) instead of a local cluster; its workers "
                   "must see the same paths and have riverbed installed.")
@click.option("--retries", type=click.IntRange(0), default=2, show_default=True,
              help="Redo a task this many times after a crash or a lost worker (bad input is not retried).")
@json_opt
@click.option("--overwrite", is_flag=True, default=False,
              help="Write into a folder that is not empty or holds another manifest's block (the block still replaces "
                   "only its own files: pairs/NAME/ of its pairs, dsm.tif, block.json).")
def block_cmd(manifest, outdir, workers, threads_per_worker, scheduler, retries, as_json, overwrite):
    """Run every pair of the block MANIFEST (YAML) and merge their points into OUTDIR/dsm.tif.

    Per pair: project its LiDAR, match (in tiles when the images are larger than the tile), triangulate; outputs
    in OUTDIR/pairs/NAME/ (sparse.tif, disparity.tif, points.laz, dsm.tif, done.json). A second run skips the
    pairs whose done.json verifies (outputs' sha256, same settings and inputs). A failing pair is reported and the
    others go on; the exit code is 1 if any pair failed. OUTDIR may be new, empty or this manifest's earlier
    output; anything else needs --overwrite.

    \b
    MANIFEST (paths relative to it; per-pair keys override defaults):
      defaults: {resolution: 0.5, crs: EPSG:32632, agg: max, guide: riverbed, tile: 1024, overlap: 128}
      pairs:
        - {pair: a/pair.yaml, cloud: lidar/*.laz}
        - {pair: b/pair.yaml, cloud: [lidar/1.laz, lidar/2.laz], name: b, window: 7}
    Settings: resolution crs agg (block-wide, defaults only); guide matcher window census paths p1 p2 subpixel
    median lr_check min_disp max_disp max_pixels; tile overlap lidar_range; outliers visibility side footprint
    classes drop_classes registration lidar_crs.
    """
    if scheduler is not None and workers is not None:
        raise RiverbedError("give --workers (a local cluster) or --scheduler (a running one), not both")
    plan = plan_block(manifest, outdir, overwrite)
    n_pairs = len(plan.jobs)
    settled = [n_pairs - len(plan.to_run)]
    # Tiles are counted as each pair's projection plans them.
    with tqdm(total=0, desc="block", unit="tile", disable=not progress_enabled() or not plan.to_run,
              leave=False) as bar:
        bar.set_postfix_str(f"pairs {settled[0]}/{n_pairs}")

        def progress(kind, name, n=1):
            if kind == "plan":
                bar.total += n
                bar.refresh()
            elif kind == "tile":
                bar.update(1)
            else:
                settled[0] += 1
                bar.set_postfix_str(f"pairs {settled[0]}/{n_pairs}")

        result = run_block(plan, workers, threads_per_worker, scheduler, retries, progress)

    if as_json:
        print_json(result.summary())
    for p in result.pairs:
        if p["status"] == "failed":
            where = f" in {p['stage']}" if p.get("stage") else ""
            click.echo(f"riverbed: error: pair {p['name']} failed{where}: {p['error']}", err=True)
    if result.merged.get("status") == "failed":
        click.echo(f"riverbed: error: merged DSM: {result.merged['error']}", err=True)
    counts = {s: sum(p["status"] == s for p in result.pairs) for s in ("done", "skipped", "failed")}
    log.info("%d pairs: %d done, %d skipped, %d failed; merged DSM %s (%s), %.1f s", n_pairs, counts["done"],
             counts["skipped"], counts["failed"], result.merged.get("output"), result.merged.get("status"),
             result.seconds)
    if result.failed:
        raise SystemExit(1)
