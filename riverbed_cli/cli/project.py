"""``riverbed project``: LiDAR point cloud + pair file -> sparse disparity map of the left image."""

import json
import logging

import click
import numpy as np

from ..errors import RiverbedError
from ..geometry import visibility as vis
from ..geometry.projection import (NOISE_CLASSES, OUTLIERS, SIDES, VISIBILITY, disparity_offset_in_metres,
                                   image_shape, project_cloud)
from ..io.atomic import check_output
from ..io.disparity import disparity_format, write_disparity
from ..io.lidar import lidar_info
from ..io.windowed import image_bits, open_windowed
from ..geometry.pairfile import load_pairfile, load_registration
from ..matching.config import MatchConfig
from ..matching.guides.riverbed import riverbed_window
from ..matching.lidar_offset import offset_estimate_windowed
from .options import input_path, json_opt, output_opt, overwrite_opt, print_json, progress_bar

log = logging.getLogger(__name__)


def _classes(ctx, param, value):
    if value is None:
        return None
    text = value.strip().lower()
    if text in ("", "none"):
        return ()
    out = []
    for tok in text.split(","):
        try:
            c = int(tok)
        except ValueError:
            raise click.BadParameter(f"'{value}' is not a comma-separated list of class numbers") from None
        if not 0 <= c <= 255:
            raise click.BadParameter(f"class {c} is outside 0..255")
        out.append(c)
    return tuple(out)


def _footprint(ctx, param, value):
    if value == "auto":
        return value
    try:
        r = int(value)
    except ValueError:
        raise click.BadParameter(f"'{value}' is neither 'auto' nor an integer") from None
    if not 0 <= r <= 50:
        raise click.BadParameter(f"footprint must be between 0 and 50 px, got {r}")
    return r


@click.command("project")
@click.argument("cloud", type=input_path())
@click.argument("pair", type=input_path())
@output_opt
@click.option("--registration", type=input_path(), default=None,
              help="LiDAR -> world 4x4 transform (text, YAML or JSON) overriding the pair file's.")
@click.option("--classes", callback=_classes, default=None,
              help="Keep only these ASPRS classes, comma-separated (default: all).")
@click.option("--drop-classes", callback=_classes, default=",".join(map(str, NOISE_CLASSES)),
              show_default=True, help="Drop these classes ('none': drop nothing).")
@click.option("--outliers", type=click.Choice(OUTLIERS), default="sor", show_default=True,
              help="Statistical outlier removal on the points that land in the image.")
@click.option("--visibility", type=click.Choice(VISIBILITY), default="zbuffer", show_default=True,
              help="Hidden point removal: z-buffer with a footprint; surface: the ray to the camera against a "
                   "height grid of the LiDAR (aerial/nadir frames, z up); surface+zbuffer: both; or Katz et al. "
                   "2007 HPR (docs/projection.md).")
@click.option("--side", type=click.Choice(SIDES), default="both", show_default=True,
              help="Drop points hidden in the left view, the right view, or either.")
@click.option("--footprint", default=str(vis.ZBUFFER_RADIUS), callback=_footprint, show_default=True,
              help="Z-buffer splat radius in px, or auto: per point, the distance to its 4th nearest "
                   "neighbour of the same surface (1..8 px).")
@click.option("--edge-reach", type=click.FloatRange(0.0, 1.0), default=vis.ZBUFFER_EDGE_REACH, show_default=True,
              help="Z-buffer: share of a splat's radius that hides on its own; below 1, a point farther out is "
                   "hidden only when nearer points surround it (keeps the background beside depth edges; for "
                   "LiDAR seen from about the camera's viewpoint, see docs/projection.md).")
@click.option("--crs", default=None, help="CRS of the cloud when its file states none (e.g. EPSG:2154).")
@click.option("--chunk-size", type=click.IntRange(1000), default=1_000_000, show_default=True,
              help="Points read at a time.")
@json_opt
@overwrite_opt
def project_cmd(cloud, pair, output, registration, classes, drop_classes, outliers, visibility, side,
                footprint, edge_reach, crs, chunk_size, as_json, overwrite):
    """Project the LiDAR CLOUD (LAS/LAZ/COPC, KITTI .bin) through PAIR (a pair file) into sparse OUTPUT.

    CLOUD may also be a DSM (single-band GeoTIFF .tif, or SRTM .hgt): one point per valid cell, at its centre.
    Its sparse disparities give `riverbed range-map --window auto` the per-pixel ranges `match --range-map`
    searches (a coarse DSM bounding the match).

    PAIR may be an RPC pair file (riverbed rectify --rpc): the cloud's CRS (3D, or compound with its heights'
    datum) is converted to WGS 84 by pyproj, and --visibility takes zbuffer or none.

    d = x_left - x_right (px) on the left image; per pixel the nearest point. OUTPUT format by extension: .tif
    (float32, NaN invalid, counts in the tags), .pfm, or .png (KITTI 16-bit: 1/256 px steps).
    """
    disparity_format(output)
    check_output(output, overwrite, inputs=[cloud, pair, registration])
    geometry = load_pairfile(pair, accept_rpc=True, command="riverbed project")
    if getattr(geometry, "kind", None) == "rpc" and registration:
        raise RiverbedError("--registration does not apply to an RPC pair file (the cloud's CRS places it)", pair)
    try:
        shape = image_shape(geometry)
    except RiverbedError as e:
        raise RiverbedError(str(e), pair if e.path is None else None) from None
    reg = load_registration(registration) if registration else None
    total = lidar_info(cloud).point_count
    with progress_bar(total, desc="project", unit="pt", unit_scale=True, leave=False) as bar:
        sparse, stats = project_cloud(cloud, geometry, registration=reg, classes=classes,
                                      drop_classes=drop_classes or (), outliers=outliers, side=side,
                                      visibility=visibility, footprint=footprint, edge_reach=edge_reach, crs=crs,
                                      shape=shape,
                                      chunk_size=chunk_size, progress=bar.update)
    stats.window = riverbed_window(stats.lidar_share, MatchConfig())  # the window riverbed match would use
    keys = ("points_read", "filtered", "behind_camera", "outside", "row_offset", "occluded", "kept")
    counts = {k: stats[k] for k in keys}
    tags = {"riverbed_lidar_share": f"{stats['lidar_share']:.6f}", "riverbed_window": stats["window"],
            "riverbed_points_read": stats["points_read"], "riverbed_points_kept": stats["kept"],
            "riverbed_counts": json.dumps(counts), "riverbed_pair": str(pair), "riverbed_cloud": str(cloud)}
    if stats.get("crs"):
        tags["riverbed_crs"] = stats["crs"]
    offset = lidar_offset_report(geometry, sparse)
    if offset is not None:
        tags["riverbed_lidar_offset"] = json.dumps(offset)
    write_disparity(output, sparse, overwrite=overwrite, tags=tags)

    summary = {"output": str(output), **stats.to_dict(), **({"lidar_offset": offset} if offset else {})}
    if as_json:
        print_json(summary)
    else:
        log.info("%s: %d of %d points kept, LiDAR share %.4f, window %d", output, stats["kept"],
                 stats["points_read"], stats["lidar_share"], stats["window"])


def lidar_offset_report(geometry, sparse):
    """The LiDAR's disparity offset against the pair's images (when the pair file names them), in px and in metres
    (``riverbed match`` removes it, docs/lidar_faults.md); None without images or points. A significant one is
    also a warning naming a possible vertical-datum or height-offset mismatch."""
    paths = [getattr(geometry, side, None) for side in ("left", "right")]
    if not all(p is not None and p.is_file() for p in paths):
        return None
    rows, cols = np.nonzero(np.isfinite(sparse))
    if len(rows) == 0:
        return None
    srcs = [open_windowed(p, "image") for p in paths]
    est = offset_estimate_windowed(*srcs, rows, cols, sparse[rows, cols], image_bits(*srcs), warn=False)
    vertical, along = disparity_offset_in_metres(geometry, rows, cols, sparse[rows, cols], est.estimated)
    out = {**est.to_dict(), "vertical_m": None if vertical is None else round(vertical, 3),
           "along_rays_m": None if along is None else round(along, 3)}
    if est.applied:
        log.warning("the LiDAR lies %+.2f m (%+.2f px) off the surface the images see: another vertical datum or a "
                    "height offset? riverbed match removes it (--lidar-offset none keeps it)", vertical or 0.0,
                    est.applied)
    return out
