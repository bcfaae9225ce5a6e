"""``riverbed block``: run project -> match -> dsm for every pair of a block manifest and merge one DSM
(``riverbed block MANIFEST``, i.e. ``riverbed block run MANIFEST``), or write the manifest of a satellite scene split
into overlapping ROIs (``riverbed block split-rpc``)."""

import logging

import click

from ..errors import RiverbedError
from ..geometry.rectify import parse_size
from ..geometry.rpc_pair import parse_heights, parse_roi
from ..scale.block import plan_block, run_block
from ..scale.block.split import MIN_RIGHT_SHARE, write_split_manifest
from .options import input_path, json_opt, overwrite_opt, parsed_value, print_json, progress_bar

log = logging.getLogger(__name__)

#: The subcommand ``riverbed block ARGS`` runs when ARGS does not start with a subcommand's name.
DEFAULT = "run"


class BlockGroup(click.Group):
    """``riverbed block``: its first argument names a subcommand (``run``, ``split-rpc``); anything else (a
    manifest, an option, ``--help``) goes to ``run``, so ``riverbed block MANIFEST -o OUTDIR`` runs a manifest."""

    def parse_args(self, ctx, args):
        if not args or args[0] not in self.commands:
            args = [DEFAULT, *args]
        return super().parse_args(ctx, args)


@click.group("block", cls=BlockGroup)
def block_cmd():
    """Run a block manifest (riverbed block MANIFEST -o OUTDIR; riverbed block --help), or write one
    (riverbed block split-rpc --help)."""


def _roi_size(text):
    """``"N"`` (square) or ``"WxH"`` -> (W, H) px."""
    text = str(text).strip()
    if text.isdigit():
        return int(text), int(text)
    try:
        return parse_size(text)
    except ValueError:
        raise ValueError(f"expected N or WIDTHxHEIGHT in pixels, e.g. 2000 or 2000x1500, got '{text}'") from None


@block_cmd.command("split-rpc")
@click.argument("left_img", type=input_path())
@click.argument("left_rpc", type=input_path())
@click.argument("right_img", type=input_path())
@click.argument("right_rpc", type=input_path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The block manifest to write (YAML; paths in it relative to its folder).")
@click.option("--cloud", "clouds", multiple=True, type=input_path(),
              help="LiDAR of the scene (LAS/LAZ; repeatable): every pair's cloud. None: the images alone, over "
                   "each ROI's height range (--dem, --heights, or its tie points).")
@click.option("--size", default="2000", show_default=True, callback=parsed_value(_roi_size, "--size"), metavar="N|WxH",
              help="ROI size in pixels of the left image (e.g. 2000, or 2000x1500). The affine rectification's "
                   "residual grows as the size squared: 0.075 px at 2000 px on Pleiades, 0.1 px near 2300, 0.5 px "
                   "near 5200 (docs/rpc_roi_size.md).")
@click.option("--overlap", type=click.IntRange(0), default=100, show_default=True,
              help="Pixels neighbouring ROIs share at least (their DSMs overlap by that much ground).")
@click.option("--region", default=None, metavar="COL,ROW,W,H", callback=parsed_value(parse_roi, "--region"),
              help="Split only this region of the left image (px; default the whole image).")
@click.option("--dem", type=input_path(), default=None,
              help="Each ROI's height range from this DEM (as rectify --rpc --dem); default: from the clouds, or "
                   "without them from tie points.")
@click.option("--heights", default=None, metavar="LO,HI", callback=parsed_value(parse_heights, "--heights"),
              help="Each ROI's height range as given (m, ellipsoidal unless --vertical).")
@click.option("--vertical", default=None, metavar="DATUM",
              help="Vertical datum of --dem when its file does not say, or of --heights (EPSG:5773 = EGM96).")
@click.option("--no-pointing-correction", "pointing", flag_value=False, default=True,
              help="Rectify each ROI without measuring the RPCs' relative pointing error.")
@click.option("--crs", default=None, metavar="CRS",
              help="The block's CRS (defaults.crs) [default: the UTM zone of the region's centre].")
@click.option("--resolution", type=click.FloatRange(min=0, min_open=True), default=None,
              help="The block's DSM cell in metres (defaults.resolution) [default: each pair's ground sample "
                   "distance, the merged DSM their median].")
@click.option("--min-share", type=click.FloatRange(0, 1), default=MIN_RIGHT_SHARE, show_default=True,
              help="Leave out ROIs whose ground the right image sees less than this share of.")
@overwrite_opt
@json_opt
def split_rpc_cmd(left_img, left_rpc, right_img, right_rpc, output, clouds, size, overlap, region, dem, heights,
                  vertical, pointing, crs, resolution, min_share, overwrite, as_json):
    """Write a block manifest that splits the satellite pair LEFT_IMG / RIGHT_IMG (RPC models LEFT_RPC /
    RIGHT_RPC, as riverbed rectify --rpc takes them) into overlapping ROIs of the left image.

    One rpc: pair per ROI (--size, sharing at least --overlap px with its neighbours, together covering the
    image or --region exactly), named roi_ROW_COL; ROIs the right image does not see (--min-share) are left out.
    Then riverbed block MANIFEST -o OUTDIR rectifies, matches and triangulates every ROI on dask and merges their
    points into one DSM (defaults.crs: one UTM zone for all). docs/rpc.md.
    """
    summary = write_split_manifest(output, left_img, left_rpc, right_img, right_rpc, clouds, size, overlap,
                                   region=region, dem=dem, heights=heights, vertical=vertical, pointing=pointing,
                                   crs=crs, resolution=resolution, min_share=min_share, overwrite=overwrite)
    if as_json:
        print_json(summary)
    else:
        log.info("%s: %d ROIs of %dx%d px (overlap >= %d px), %d left out; crs %s", output, summary["pairs"],
                 *summary["size"], overlap, len(summary["left_out"]), summary["crs"])


@block_cmd.command(DEFAULT)
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
def block_run_cmd(manifest, outdir, workers, threads_per_worker, scheduler, retries, as_json, overwrite):
    """Run every pair of the block MANIFEST (YAML) and merge their points into OUTDIR/dsm.tif.

    riverbed block MANIFEST is riverbed block run MANIFEST; riverbed block split-rpc writes a manifest of a
    satellite scene split into ROIs.

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
        - {rpc: {left: l.tif, left_rpc: l.geom, right: r.tif, right_rpc: r.geom, roi: [0, 0, 2000, 2000],
                 dem: srtm.hgt}, cloud: lidar/*.laz}    # satellite: the ROI rectified first
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
    with progress_bar(0, bool(plan.to_run), desc="block", unit="tile", leave=False) as bar:
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
