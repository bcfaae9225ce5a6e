"""``riverbed rectify``: a rectified pair and its pair file from two raw frames and their orientations, or (``--rpc``)
from two satellite images and their RPC models."""

import logging

import click
from click.core import ParameterSource

from ..errors import RiverbedError
from ..geometry.rectify import check_alpha, parse_size, rectify_files
from ..geometry.rpc_pair import parse_heights, parse_roi, rectify_rpc_files
from ..io.images import MAX_PIXELS
from .options import input_path, json_opt, overwrite_opt, parsed_value, print_json

log = logging.getLogger(__name__)


def _size(ctx, param, value):
    if value is None:
        return None
    try:
        return parse_size(value)
    except ValueError as e:
        raise click.BadParameter(str(e)) from None


def _alpha(ctx, param, value):
    try:
        return check_alpha(value)
    except ValueError as e:
        raise click.BadParameter(str(e)) from None


#: Options of one mode only: (parameter, option, mode it belongs to).
PINHOLE_ONLY = (("alpha", "--alpha"), ("size", "--size"))
RPC_ONLY = (("roi", "--roi"), ("vertical", "--vertical"), ("pointing", "--no-pointing-correction"))


@click.command("rectify")
@click.argument("left_img", type=input_path())
@click.argument("left_orient", type=input_path())
@click.argument("right_img", type=input_path())
@click.argument("right_orient", type=input_path())
@click.option("-o", "--outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder (created if missing): left.png, right.png, pair.yaml (with --rpc: left.tif, "
                   "right.tif, pair.yaml).")
@click.option("--rpc", "rpc", is_flag=True, default=False,
              help="Satellite images: LEFT_ORIENT and RIGHT_ORIENT are RPC models (any format; the image itself "
                   "for GeoTIFF RPC tags); docs/rpc.md.")
@click.option("--roi", default=None, metavar="COL,ROW,W,H", callback=parsed_value(parse_roi, "--roi"),
              help="[--rpc] Region of the left image to rectify (px; default the whole image).")
@click.option("--dem", type=input_path(), default=None,
              help="DEM of the terrain: the pair's disparity range is that of its cells both images see +- 4 px "
                   "(--rpc: a geographic DEM, e.g. SRTM .hgt; the height range is its range under the ROI +- 20 m).")
@click.option("--heights", default=None, metavar="LO,HI", callback=parsed_value(parse_heights, "--heights"),
              help="The terrain's height range instead of a DEM (m; --rpc: ellipsoidal unless --vertical).")
@click.option("--lidar", type=input_path(), multiple=True, metavar="CLOUD",
              help="LiDAR (LAS/LAZ, repeatable) instead of a DEM: the range of its points both images see +- 4 px "
                   "(--rpc: the height range of its points under the ROI +- 20 m, noise classes 7 and 18 dropped). "
                   "None of --dem, --heights, --lidar: the range the tie points show.")
@click.option("--lidar-crs", default=None, metavar="CRS",
              help="CRS of the --lidar clouds (or --dem) when their files do not state it (--rpc: 3D, or compound "
                   "with the heights' datum, e.g. EPSG:32631+5773).")
@click.option("--vertical", default=None, metavar="DATUM",
              help="[--rpc] Vertical datum of --dem when its file does not say, or of --heights: ellipsoid or a "
                   "vertical CRS (EPSG:5773 = EGM96).")
@click.option("--no-pointing-correction", "pointing", flag_value=False, default=True,
              help="[--rpc] Do not measure and remove the RPCs' relative pointing error (tie points).")
@click.option("--alpha", type=float, default=0.0, show_default=True, callback=_alpha,
              help="stereoRectify's free scaling: 0 only pixels valid in both images (no black border), "
                   "1 every source pixel kept, -1 OpenCV's default.")
@click.option("--size", default=None, callback=_size, metavar="WxH",
              help="Rectified image size in pixels (default: the raw frame size).")
@click.option("--max-pixels", type=int, default=MAX_PIXELS, show_default=True,
              help="Refuse images larger than this (width x height; with --rpc: the rectified frame).")
@overwrite_opt
@json_opt
@click.pass_context
def rectify_cmd(ctx, left_img, left_orient, right_img, right_orient, outdir, rpc, roi, dem, heights, lidar,
                lidar_crs, vertical, pointing, alpha, size, max_pixels, overwrite, as_json):
    """Rectify raw frames LEFT_IMG and RIGHT_IMG with their orientation files (YAML; docs/rectify.md).

    Writes OUTDIR/left.png and OUTDIR/right.png (rows shared, d = x_left - x_right = f B / depth >= 0) and
    OUTDIR/pair.yaml (P_left, P_right over world minus origin, origin, crs): the exact cameras of the written
    images. OpenCV stereoRectify + initUndistortRectifyMap + remap (bicubic). Each image is turned about its
    optical axis (by 0, 90, 180 deg) so that the baseline runs along the rows with the right camera to the
    right (d >= 0): e.g. both by 180 deg when RIGHT_IMG was taken behind LEFT_IMG. LEFT_IMG always gives
    left.png.

    With --rpc: LEFT_ORIENT and RIGHT_ORIENT are the images' RPC models; a region of interest (--roi) of
    LEFT_IMG is rectified the s2p way (affine epipolar geometry, the RPCs' pointing error removed on tie points)
    into OUTDIR/left.tif, OUTDIR/right.tif and OUTDIR/pair.yaml (both RPCs, the rectification, ROI, heights,
    disparity range). The height range comes from --dem, --heights or --lidar, or without them from tie points.
    """
    if max_pixels is not None and max_pixels < 1:
        raise RiverbedError("--max-pixels must be positive")
    given = {name for name in ctx.params if ctx.get_parameter_source(name) is not ParameterSource.DEFAULT}
    wrong = PINHOLE_ONLY if rpc else RPC_ONLY
    for name, option in wrong:
        if name in given:
            raise RiverbedError(f"{option} {'does not apply with' if rpc else 'needs'} --rpc")
    if rpc:
        summary = rectify_rpc_files(left_img, left_orient, right_img, right_orient, outdir, roi=roi, dem=dem,
                                    heights=heights, vertical=vertical, pointing=pointing, overwrite=overwrite,
                                    max_pixels=max_pixels, lidar=list(lidar) or None, lidar_crs=lidar_crs)
        if as_json:
            print_json(summary)
        else:
            log.info("%s: %dx%d, d in %.1f..%.1f px, heights %.1f..%.1f m, pointing %s px of rows, virtual rows "
                     "within %.4f px", outdir, summary["width"], summary["height"], *summary["disparity"],
                     *summary["heights"], summary["pointing_row_offset_px"], summary["virtual_row_residual_max_px"])
        return
    summary = rectify_files(left_img, left_orient, right_img, right_orient, outdir, overwrite=overwrite,
                            alpha=alpha, size=size, max_pixels=max_pixels, heights=heights,
                            dem=dem, lidar=lidar, lidar_crs=lidar_crs)
    if as_json:
        print_json(summary)
    else:
        log.info("%s: %dx%d, f = %.4f px, baseline %.4f, d = %.4f / depth, turned %s deg, valid %s", outdir,
                 summary["width"], summary["height"], summary["focal_px"], summary["baseline"], summary["fB"],
                 summary["turn_deg"], summary["valid_share"])
