"""``riverbed rectify``: a rectified pair and its pair file from two raw frames and their orientations."""

import logging

import click

from ..errors import RiverbedError
from ..geometry.rectify import check_alpha, parse_size, rectify_files
from ..io.images import MAX_PIXELS
from .options import input_path, json_opt, overwrite_opt, print_json

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


@click.command("rectify")
@click.argument("left_img", type=input_path())
@click.argument("left_orient", type=input_path())
@click.argument("right_img", type=input_path())
@click.argument("right_orient", type=input_path())
@click.option("-o", "--outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder (created if missing): left.png, right.png, pair.yaml.")
@click.option("--alpha", type=float, default=0.0, show_default=True, callback=_alpha,
              help="stereoRectify's free scaling: 0 only pixels valid in both images (no black border), "
                   "1 every source pixel kept, -1 OpenCV's default.")
@click.option("--size", default=None, callback=_size, metavar="WxH",
              help="Rectified image size in pixels (default: the raw frame size).")
@click.option("--max-pixels", type=int, default=MAX_PIXELS, show_default=True,
              help="Refuse images larger than this (width x height).")
@overwrite_opt
@json_opt
def rectify_cmd(left_img, left_orient, right_img, right_orient, outdir, alpha, size, max_pixels, overwrite,
                as_json):
    """Rectify raw frames LEFT_IMG and RIGHT_IMG with their orientation files (YAML; docs/rectify.md).

    Writes OUTDIR/left.png and OUTDIR/right.png (rows shared, d = x_left - x_right = f B / depth >= 0) and
    OUTDIR/pair.yaml (P_left, P_right over world minus origin, origin, crs): the exact cameras of the written
    images. OpenCV stereoRectify + initUndistortRectifyMap + remap (bicubic). Each image is turned about its
    optical axis (by 0, 90, 180 deg) so that the baseline runs along the rows with the right camera to the
    right (d >= 0): e.g. both by 180 deg when RIGHT_IMG was taken behind LEFT_IMG. LEFT_IMG always gives
    left.png.
    """
    if max_pixels is not None and max_pixels < 1:
        raise RiverbedError("--max-pixels must be positive")
    summary = rectify_files(left_img, left_orient, right_img, right_orient, outdir, overwrite=overwrite,
                            alpha=alpha, size=size, max_pixels=max_pixels)
    if as_json:
        print_json(summary)
    else:
        log.info("%s: %dx%d, f = %.4f px, baseline %.4f, d = %.4f / depth, turned %s deg, valid %s", outdir,
                 summary["width"], summary["height"], summary["focal_px"], summary["baseline"], summary["fB"],
                 summary["turn_deg"], summary["valid_share"])
