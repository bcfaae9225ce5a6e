"""``riverbed dsm``: triangulate disparity maps (and merge LiDAR) into a point cloud and a DSM GeoTIFF."""

import time

import click
import numpy as np

from ..errors import RiverbedError
from ..io.atomic import check_outputs
from ..io.lidar import resolve_crs
from ..geometry.pairfile import load_registration
from ..geometry.projection import crs_name
from ..io.pointcloud import check_pointcloud_path
from ..io.raster import parse_creation_options
from ..products.dsm import (AGGREGATIONS, build_dsm, check_bounds, check_creation_options, check_fill_holes,
                            check_min_confidence)
from ..products.dsm_files import MERGE_RULE, RPC_HEIGHTS, dsm_crs, read_couples, write_dsm_outputs
from .options import json_opt, overwrite_opt, print_json, progress_bar


class Number(click.ParamType):
    """A number of ``option``: text that is none is a one-line ``riverbed: error:`` (exit code 1), not a usage
    error."""

    name = "float"

    def __init__(self, option, hint=""):
        self.option, self.hint = option, hint

    def convert(self, value, param, ctx):
        try:
            return float(value)
        except (TypeError, ValueError):
            raise RiverbedError(f"{self.option}: '{value}' is not a number{self.hint}") from None


@click.command("dsm")
@click.argument("disp_pair", nargs=-1, type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="DSM GeoTIFF (.tif).")
@click.option("--points", "points_out", type=click.Path(dir_okay=False), default=None,
              help="Also write the triangulated points: .las/.laz (RGB, CRS) or .ply (binary).")
@click.option("--resolution", type=float, default=None,
              help="Cell size in CRS units [default: the left image's ground sample distance at the median depth; "
                   "LiDAR alone: twice the mean point spacing].")
@click.option("--agg", type=click.Choice(AGGREGATIONS), default="max", show_default=True,
              help="Per-cell aggregation of the heights.")
@click.option("--bounds", nargs=4, type=Number("--bounds", " (give XMIN YMIN XMAX YMAX)"), default=None,
              metavar="XMIN YMIN XMAX YMAX", help="DSM extent [default: all points].")
@click.option("--nodata", type=float, default=float("nan"), show_default=True, help="Value of empty cells.")
@click.option("--fill-holes", type=int, default=0, show_default=True,
              help="Fill enclosed gaps up to N cells across (GDAL inverse-distance); filled cells are flagged in a "
                   "second band (1 = filled).")
@click.option("--keep-lattice", is_flag=True, default=False,
              help="Leave the image points' sampling lattice open: by default an empty cell with at least 6 of its "
                   "8 neighbours holding heights takes their median (docs/dsm.md).")
@click.option("--crs", default=None,
              help="CRS of the output [default: the pair's, else the LiDAR file's]; assigned, not reprojected (RPC "
                   "pairs: a projected CRS the points are converted to, default the scene's UTM zone).")
@click.option("--co", "creation", multiple=True, metavar="KEY=VALUE",
              help="GDAL COG creation option (repeatable; BLOCKSIZE a multiple of 16 from 128 to 4096; tried before "
                   "the work) [default: COMPRESS=DEFLATE, BLOCKSIZE=256, OVERVIEWS=AUTO].")
@click.option("--lidar", "clouds", multiple=True, type=click.Path(dir_okay=False),
              help="LAS/LAZ cloud merged into the DSM (repeatable; LiDAR wins where both have points).")
@click.option("--registration", type=click.Path(dir_okay=False), default=None,
              help="4x4 LiDAR -> world transform for --lidar (YAML/JSON/text) [default: the first pair's].")
@click.option("--hillshade", "hillshade_png", type=click.Path(dir_okay=False), default=None,
              help="Also write a hillshade PNG of the DSM.")
@click.option("--confidence", "confidences", multiple=True, type=click.Path(dir_okay=False), metavar="CONF.tif",
              help="Per-pixel confidence of a DISP (single-band float32 TIFF of its size, 0..1, NaN none), one per "
                   "DISP PAIR couple in their order (repeatable); needs --min-confidence.")
@click.option("--min-confidence", type=Number("--min-confidence"), default=None, metavar="X",
              help="Drop the points whose pixel's --confidence is below X (0..1) or NaN.")
@click.option("--change-map", "change_out", type=click.Path(dir_okay=False), default=None,
              help="Also write where the surface differs from the LiDAR's (.tif on the DSM's grid: median height "
                   "change, m, match minus LiDAR, at the LiDAR points riverbed match's check dropped in changed "
                   "regions; NaN elsewhere); needs --sparse and --lidar-mask per couple (docs/lidar_faults.md).")
@click.option("--sparse", "sparses", multiple=True, type=click.Path(dir_okay=False), metavar="SPARSE.tif",
              help="The LiDAR disparities a DISP was matched with (riverbed match --sparse), one per couple in their "
                   "order (repeatable), for --change-map.")
@click.option("--lidar-mask", "masks", multiple=True, type=click.Path(dir_okay=False), metavar="MASK.png",
              help="The LiDAR mask of a DISP's match (riverbed match --lidar-mask), one per couple in their order "
                   "(repeatable), for --change-map.")
@json_opt
@overwrite_opt
def dsm_cmd(disp_pair, output, points_out, resolution, agg, bounds, nodata, fill_holes, keep_lattice, crs, creation,
            clouds, registration, hillshade_png, confidences, min_confidence, change_out, sparses, masks, as_json,
            overwrite):
    """Triangulate DISP PAIR couples (disparity map of the left image, pair file) into a DSM.

    Every valid disparity is triangulated exactly (float64) with the pair's cameras, the pair's origin added back;
    the points of all couples (and of --lidar clouds) are merged into one north-up DSM, a cloud-optimised GeoTIFF.
    With --confidence and --min-confidence, the points of pixels whose confidence is below X (or NaN) are dropped
    before the point cloud and the DSM (--json: confidence_dropped). An RPC pair file (riverbed rectify --rpc):
    the two RPC rays are intersected, the points converted to --crs (a projected CRS; default: the UTM zone of the
    scene), heights above the WGS 84 ellipsoid.
    """
    t0 = time.perf_counter()
    if len(disp_pair) % 2:
        raise RiverbedError("give DISP PAIR couples: a disparity map and its pair file each")
    # Every check that needs no input read comes first: a bad option never costs the work, nor leaves a file.
    if not output.lower().endswith((".tif", ".tiff")):
        raise RiverbedError("DSM output must be a .tif file", output)
    if points_out:
        check_pointcloud_path(points_out)
    if hillshade_png and not hillshade_png.lower().endswith(".png"):
        raise RiverbedError("hillshade must be a .png file", hillshade_png)
    if change_out and not change_out.lower().endswith((".tif", ".tiff")):
        raise RiverbedError("the change map must be a .tif file", change_out)
    check_outputs([output, points_out, hillshade_png, change_out], overwrite,
                  inputs=[*disp_pair, *clouds, registration, *confidences, *sparses, *masks])
    if bounds is not None:
        bounds = check_bounds(bounds)
    check_fill_holes(fill_holes)
    if fill_holes and nodata in (0.0, 1.0):
        raise RiverbedError(f"--nodata {nodata:g} is a value of the 'filled' band (0 or 1) that --fill-holes writes; "
                            "choose another (e.g. -9999)")
    if np.isfinite(nodata) and abs(nodata) > float(np.finfo(np.float32).max):
        raise RiverbedError(f"--nodata {nodata:g} does not fit in the DSM's float32")
    if crs is not None:
        try:
            resolve_crs(None, crs)  # an unknown CRS is refused now, not after the work
        except RiverbedError as e:
            raise RiverbedError(f"--crs: {e}") from None
    n_couples = len(disp_pair) // 2
    if min_confidence is not None:
        min_confidence = check_min_confidence(min_confidence, "--min-confidence")
        if not confidences:
            raise RiverbedError("--min-confidence needs --confidence CONF.tif (the disparity's per-pixel confidence)")
    elif confidences:
        raise RiverbedError("--confidence needs --min-confidence X (the lowest confidence kept, 0 to 1)")
    if confidences and len(confidences) != n_couples:
        raise RiverbedError(f"give one --confidence per DISP PAIR couple ({n_couples} couples, "
                            f"{len(confidences)} --confidence)")
    if change_out and (len(sparses) != n_couples or len(masks) != n_couples):
        raise RiverbedError(f"--change-map needs one --sparse and one --lidar-mask per DISP PAIR couple ({n_couples} "
                            f"couples, {len(sparses)} --sparse, {len(masks)} --lidar-mask)")
    if (sparses or masks) and not change_out:
        raise RiverbedError("--sparse and --lidar-mask are read for --change-map FILE.tif; give it")
    co = parse_creation_options(creation)
    check_creation_options(co, bands=2 if fill_holes else 1, nodata=nodata)

    sources, confs, changes = read_couples(disp_pair, confidences, sparses, masks)
    reg = load_registration(registration) if registration else None
    crs, rpc = dsm_crs(sources, crs, clouds)
    total = sum(d.shape[0] for d, _, _ in sources)
    with progress_bar(total, bool(total), desc="dsm", unit="row", leave=False) as bar:
        result = build_dsm(sources, clouds, resolution, agg, bounds, fill_holes, lattice=not keep_lattice,
                           lidar_registration=reg, progress=bar.update, keep_points=bool(points_out),
                           confidence=confs if confidences else None, min_confidence=min_confidence)
    change_stats = write_dsm_outputs(
        result, crs, output, points=points_out, changes=changes, change_out=change_out, hillshade_png=hillshade_png,
        filled_band=bool(fill_holes), nodata=nodata, creation=co, overwrite=overwrite,
        tags={"riverbed_aggregation": agg, "riverbed_merge_rule": MERGE_RULE,
              **({"riverbed_heights": RPC_HEIGHTS} if rpc else {})})
    summary = {"output": str(output), **result.stats, "crs": crs_name(crs),
               **({"change_map": {"output": str(change_out), **change_stats}} if change_out else {}),
               "seconds": round(time.perf_counter() - t0, 3)}
    if as_json:
        print_json(summary)
