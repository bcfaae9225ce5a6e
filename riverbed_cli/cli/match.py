"""``riverbed match``: dense disparity of a rectified pair, optionally guided by sparse LiDAR disparities."""

import logging

import click
from tqdm import tqdm

from ..errors import RiverbedError
from ..io.atomic import check_output
from ..io.disparity import _kind as disparity_format
from ..io.disparity import read_disparity, write_disparity
from ..io.images import MAX_PIXELS, check_pair, read_image
from ..matching.pipeline import GUIDES, MATCHERS, MatchParams, match_pair, warm_up
from ..products.visualize import colorize_disparity, write_png
from .options import input_path, json_opt, output_opt, overwrite_opt, print_json, progress_enabled

log = logging.getLogger(__name__)


def _window(ctx, param, value):
    if value is None or value == "auto":
        return "auto"
    try:
        s = int(value)
    except ValueError:
        raise click.BadParameter(f"'{value}' is neither 'auto' nor an integer") from None
    if s < 1 or s % 2 == 0:
        raise click.BadParameter(f"window must be a positive odd number, got {s}")
    return s


@click.command("match")
@click.argument("left", type=input_path())
@click.argument("right", type=input_path())
@output_opt
@click.option("--sparse", type=input_path(), default=None,
              help="Sparse LiDAR disparities of the left image (.tif/.pfm/.png; NaN, inf or 0 = none).")
@click.option("--sparse-scale", type=float, default=None, help="Stored value per pixel for an 8-bit PNG --sparse.")
@click.option("--matcher", type=click.Choice(MATCHERS), default="sgm", show_default=True,
              help="sgm: census cost + Semi-Global Matching; adcensus: AD-Census (Mei et al. 2011: AD + census cost, "
                   "cross-based aggregation, scanline optimisation, multi-step refinement).")
@click.option("--guide", type=click.Choice(GUIDES), default=None,
              help="Cost-volume guidance: gauss (Poggi et al.), riverbed (the paper), diffusion (Shivakumar et al. "
                   "2019), riverbed+ (riverbed extended through cross-based support regions to the pixels failing "
                   "a first pass's left-right check; docs/riverbed_plus.md). Default: riverbed with --sparse, "
                   "else none.")
@click.option("--window", default="auto", callback=_window, show_default=True,
              help="Riverbed window side s (odd), or auto: smallest odd s with s*s*p >= 4 (p = LiDAR share), "
                   "within [5, 25].")
@click.option("--min-disp", type=int, default=None,
              help="Smallest disparity searched (px, inclusive; default: from --sparse, else 0).")
@click.option("--max-disp", type=int, default=None,
              help="Largest disparity searched (px, inclusive; default: from --sparse with a margin).")
@click.option("--census", "census_win", default="9x7", show_default=True, help="Census window WIDTHxHEIGHT.")
@click.option("--paths", type=click.Choice(["4", "8", "16"]), default="8", show_default=True,
              help="SGM path directions.")
@click.option("--p1", type=int, default=MatchParams.p1, show_default=True,
              help="SGM penalty for a 1 px disparity change (Hamming units; --matcher sgm).")
@click.option("--p2", type=int, default=MatchParams.p2, show_default=True,
              help="SGM penalty for a larger disparity change (Hamming units; --matcher sgm).")
@click.option("--subpixel/--no-subpixel", default=True, show_default=True, help="Parabola sub-pixel fit.")
@click.option("--median", type=int, default=3, show_default=True, help="Median filter size (1 or 0: off).")
@click.option("--lr-check/--no-lr-check", default=False, show_default=True,
              help="Invalidate pixels failing the left-right consistency check (1 px; --matcher sgm: AD-Census always "
                   "checks and refills them in its refinement).")
@click.option("--color", "color_png", type=click.Path(dir_okay=False), default=None,
              help="Also write a colourised disparity preview PNG.")
@click.option("--max-pixels", type=int, default=MAX_PIXELS, show_default=True,
              help="Refuse images larger than this (width x height).")
@json_opt
@overwrite_opt
def match_cmd(left, right, output, sparse, sparse_scale, matcher, guide, window, min_disp, max_disp, census_win, paths,
              p1, p2, subpixel, median, lr_check, color_png, max_pixels, as_json, overwrite):
    """Match rectified images LEFT (reference) and RIGHT into a disparity map OUTPUT.

    Disparity d = x_left - x_right (px). OUTPUT format by extension: .tif (float32, NaN invalid), .pfm
    (Middlebury, inf invalid) or .png (KITTI 16-bit, d*256, 0 invalid).
    """
    # Refuse to clobber, or to compute what cannot be written, before doing any work.
    disparity_format(output)
    check_output(output, overwrite)
    if color_png:
        if not color_png.lower().endswith(".png"):
            raise RiverbedError("colour preview must be a .png file", color_png)
        check_output(color_png, overwrite)
    if guide is None:
        guide = "riverbed" if sparse else "none"
    if guide != "none" and not sparse:
        raise RiverbedError(f"--guide {guide} needs --sparse")
    if (min_disp is None or max_disp is None) and not sparse:
        if max_disp is None:
            raise RiverbedError("give --max-disp (and --min-disp) or --sparse to derive the disparity range from")
        min_disp = 0

    stages = ["read", "match", "write"]
    with tqdm(total=len(stages), desc="match", unit="stage", disable=not progress_enabled(), leave=False) as bar:
        left_img = read_image(left, max_pixels)
        right_img = read_image(right, max_pixels)
        check_pair(left_img, right_img, left, right)
        sparse_map = None
        if sparse:
            sparse_map = read_disparity(sparse, scale=sparse_scale)
            if sparse_map.shape != left_img.shape[:2]:
                raise RiverbedError(
                    f"sparse map is {sparse_map.shape[1]}x{sparse_map.shape[0]} but the images are "
                    f"{left_img.shape[1]}x{left_img.shape[0]} (WxH)", sparse)
        bar.update()

        params = MatchParams(guide=guide, window=window, census=census_win, paths=int(paths), p1=p1, p2=p2,
                             subpixel=subpixel, median=median, lr_check=lr_check, matcher=matcher)
        warm_up(matcher, (guide,))  # load the compiled kernels now: start-up, not matching time
        try:
            result = match_pair(left_img, right_img, sparse_map, min_disp, max_disp, params)
        except RiverbedError as e:
            # Name the file the problem comes from when it is the sparse map.
            if sparse and "sparse" in str(e) and e.path is None:
                raise RiverbedError(str(e), sparse) from None
            raise
        bar.update()

        info = result.info
        tags = {"riverbed_matcher": matcher, "riverbed_guide": guide, "riverbed_window": info["window"],
                "riverbed_d_min": info["d_min"],
                "riverbed_d_max": info["d_max"], "riverbed_lidar_share": f"{info['lidar_share']:.6f}"}
        write_disparity(output, result.disparity, overwrite=overwrite, tags=tags)
        if color_png:
            write_png(color_png, colorize_disparity(result.disparity), overwrite=overwrite)
        bar.update()

    summary = {"output": str(output), **info}
    if as_json:
        print_json(summary)
    else:
        log.info("%s: %dx%d, d in [%d, %d], guide %s, %.3f s", output, *info["size"], info["d_min"], info["d_max"],
                 guide, info["seconds"])
