"""``riverbed dsm``: triangulate disparity maps (and merge LiDAR) into a point cloud and a DSM GeoTIFF."""

import time

import click
import numpy as np
from tqdm import tqdm

from ..errors import RiverbedError
from ..io.atomic import check_output
from ..io.disparity import read_disparity
from ..io.images import read_image
from ..io.lidar import lidar_info, resolve_crs
from ..geometry.pairfile import load_pairfile, load_registration
from ..io.pointcloud import check_pointcloud_path, write_points
from ..io.raster import parse_creation_options, write_geotiff
from ..products.dsm import AGGREGATIONS, build_dsm, hillshade
from ..products.visualize import hillshade_picture, write_picture
from .options import json_opt, overwrite_opt, print_json, progress_enabled


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
@click.option("--bounds", nargs=4, type=float, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="DSM extent [default: all points].")
@click.option("--nodata", type=float, default=float("nan"), show_default=True, help="Value of empty cells.")
@click.option("--fill-holes", type=int, default=0, show_default=True,
              help="Fill enclosed gaps up to N cells across (GDAL inverse-distance); filled cells are flagged in a "
                   "second band (1 = filled).")
@click.option("--crs", default=None,
              help="CRS of the output [default: the pair's, else the LiDAR file's]; assigned, not reprojected.")
@click.option("--co", "creation", multiple=True, metavar="KEY=VALUE",
              help="GDAL COG creation option (repeatable) [default: COMPRESS=DEFLATE, BLOCKSIZE=256, OVERVIEWS=AUTO].")
@click.option("--lidar", "clouds", multiple=True, type=click.Path(dir_okay=False),
              help="LAS/LAZ cloud merged into the DSM (repeatable; LiDAR wins where both have points).")
@click.option("--registration", type=click.Path(dir_okay=False), default=None,
              help="4x4 LiDAR -> world transform for --lidar (YAML/JSON/text) [default: the first pair's].")
@click.option("--hillshade", "hillshade_png", type=click.Path(dir_okay=False), default=None,
              help="Also write a hillshade PNG of the DSM.")
@json_opt
@overwrite_opt
def dsm_cmd(disp_pair, output, points_out, resolution, agg, bounds, nodata, fill_holes, crs, creation, clouds,
            registration, hillshade_png, as_json, overwrite):
    """Triangulate DISP PAIR couples (disparity map of the left image, pair file) into a DSM.

    Every valid disparity is triangulated exactly (float64) with the pair's cameras, the pair's origin added back;
    the points of all couples (and of --lidar clouds) are merged into one north-up DSM, a cloud-optimised GeoTIFF.
    """
    t0 = time.perf_counter()
    if len(disp_pair) % 2:
        raise RiverbedError("give DISP PAIR couples: a disparity map and its pair file each")
    if not output.lower().endswith((".tif", ".tiff")):
        raise RiverbedError("DSM output must be a .tif file", output)
    check_output(output, overwrite)
    if points_out:
        check_pointcloud_path(points_out)
        check_output(points_out, overwrite)
    if hillshade_png:
        check_output(hillshade_png, overwrite)
    co = parse_creation_options(creation)

    sources = []
    for disp_path, pair_path in zip(disp_pair[::2], disp_pair[1::2]):
        pair = load_pairfile(pair_path)
        disp = read_disparity(disp_path)
        if pair.image_size is not None and pair.image_size != disp.shape:
            raise RiverbedError(f"disparity map is {disp.shape[1]}x{disp.shape[0]} but the pair's images are "
                                f"{pair.width}x{pair.height} (WxH) ({pair_path})", disp_path)
        image = None
        if pair.left is not None and pair.left.exists():
            image = read_image(pair.left)
            if image.shape[:2] != disp.shape:
                raise RiverbedError(f"left image {pair.left} is not the size of the disparity map", disp_path)
        sources.append((disp, pair, image))
    reg = load_registration(registration) if registration else None

    if crs is None:
        crs = next((p.crs for _, p, _ in sources if p.crs), None)
        if crs is None and clouds:
            found = resolve_crs(lidar_info(clouds[0]))
            crs = found.to_wkt() if found is not None else None

    blocks = []

    def sink(xyz, rgb):
        if points_out:
            blocks.append((xyz, rgb))

    total = sum(d.shape[0] for d, _, _ in sources)
    with tqdm(total=total, desc="dsm", unit="row", disable=not progress_enabled() or not total, leave=False) as bar:
        result = build_dsm(sources, clouds, resolution, agg, bounds, fill_holes, point_sink=sink,
                           lidar_registration=reg, progress=bar.update)

    dsm = result.dsm
    if not np.isnan(nodata):
        dsm = np.where(np.isnan(dsm), np.float32(nodata), dsm)
    bands = [dsm] if not fill_holes else [dsm, result.filled.astype(np.float32)]
    write_geotiff(output, np.stack(bands), result.grid.transform, crs, nodata, co, overwrite,
                  band_descriptions=["height", "filled"][: len(bands)],
                  tags={"riverbed_aggregation": agg, "riverbed_merge_rule": "lidar wins where both exist"})
    if points_out:
        xyz = np.concatenate([b[0] for b in blocks]) if blocks else np.zeros((0, 3))
        rgbs = [b[1] for b in blocks]
        rgb = np.concatenate(rgbs) if blocks and all(r is not None for r in rgbs) else None
        write_points(points_out, xyz, rgb, crs, overwrite=overwrite)
    if hillshade_png:
        res = result.grid.resolution
        write_picture(hillshade_png, hillshade_picture(hillshade(result.dsm, res), result.dsm, res),
                      overwrite=overwrite)
    summary = {"output": str(output), **result.stats, "crs": crs if crs is None or len(str(crs)) < 40 else "wkt",
               "seconds": round(time.perf_counter() - t0, 3)}
    if as_json:
        print_json(summary)
