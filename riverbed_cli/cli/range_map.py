"""``riverbed range-map``: per-pixel disparity ranges for ``riverbed match --range-map`` from a disparity map (a
previous run, or a coarser one)."""

import logging
import math
import time

import click
import numpy as np

from ..errors import RiverbedError
from ..io.atomic import check_output
from ..io.disparity import write_range_map
from ..io.images import header_size, read_image
from ..matching.lidar_input import check_disparity_values
from ..matching.tubes import MAX_RANGE_WINDOW, ranges_from_disparity, spacing_window
from .options import (check_raster_pixels, input_path, json_opt, output_opt, overwrite_opt, parsed_value,
                      print_json, read_disparity_named)

log = logging.getLogger(__name__)


def _window(text):
    # --window: "auto" or an integer 0..MAX_RANGE_WINDOW
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"expected 'auto' or an integer, got '{text}'") from None
    if not 0 <= value <= MAX_RANGE_WINDOW:
        raise ValueError(f"expected 0 to {MAX_RANGE_WINDOW}, got {value}")
    return value


def _margin(text):
    # --margin: a finite number >= 0 (FloatRange lets nan and inf through)
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"expected a number >= 0, got '{text}'") from None
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"expected a finite number >= 0, got '{text}'")
    return value


@click.command("range-map")
@click.argument("disparity", type=input_path())
@output_opt
@click.option("--window", default="2", show_default=True, callback=parsed_value(_window, "--window"),
              help="Half side (px of DISPARITY, 0-256) of the window whose disparities bound each pixel's range; "
                   "'auto': the mean spacing of DISPARITY's values, rounded up (a sparse map: one projected by "
                   "`riverbed project` from a coarse DSM).")
@click.option("--margin", default="4.0", callback=parsed_value(_margin, "--margin"), show_default=True,
              help="Disparity (px of the image to match) added on both sides of the window's min and max (for a "
                   "run at half resolution: --window 4 --margin 8, as the tube holes' coarse match).")
@click.option("--like", "like", type=input_path(), default=None,
              help="The left image to match, when DISPARITY is of that image downsampled by an integer factor (a "
                   "coarse run): the ranges are made at its size, the disparities times the factor.")
@click.option("--min-disp", type=int, default=None, help="Clip the ranges to this smallest disparity (the match's).")
@click.option("--max-disp", type=int, default=None, help="Clip the ranges to this largest disparity (the match's).")
@click.option("--scale", "disp_scale", type=float, default=None, help="Stored value per pixel for an 8-bit PNG.")
@json_opt
@overwrite_opt
def range_map_cmd(disparity, output, window, margin, like, min_disp, max_disp, disp_scale, as_json, overwrite):
    """Write OUTPUT (a 2-band .tif: min and max disparity per pixel) from DISPARITY of the left image.

    Each pixel's range is the min and max of the disparities within --window px, widened by --margin px; NaN where
    the window holds none (the match's nominal range there). Give OUTPUT to `riverbed match --range-map`.
    Disparity d = x_left - x_right (px).
    """
    if not output.lower().endswith((".tif", ".tiff")):
        raise RiverbedError("range map must be written to a .tif file", output)
    check_output(output, overwrite, inputs=[disparity, like])
    if min_disp is not None and max_disp is not None and min_disp > max_disp:
        raise RiverbedError(f"--min-disp {min_disp} is above --max-disp {max_disp}")
    t0 = time.perf_counter()
    check_raster_pixels(disparity, "disparity map")
    disp = read_disparity_named(disparity, disp_scale, "--scale")
    try:  # a corrupt value (+-1e30) would become ranges no match can search
        check_disparity_values(disp, disp.shape[1], "disparity map")
    except RiverbedError as e:
        raise RiverbedError(str(e), disparity) from None
    shape = None
    if like:
        size = header_size(like)  # the header only; an image GDAL cannot open is read the usual way
        shape = (size[1], size[0]) if size else read_image(like).shape[:2]
    if window == "auto":
        try:
            window = spacing_window(disp)
        except RiverbedError as e:
            raise RiverbedError(f"--window auto: {e}", disparity) from None
    try:
        lo, hi = ranges_from_disparity(disp, shape, window, margin)
    except RiverbedError as e:
        raise RiverbedError(str(e), disparity) from None
    if min_disp is not None or max_disp is not None:
        lo, hi = (np.clip(a, min_disp, max_disp) for a in (lo, hi))
    known = np.isfinite(lo)
    if not known.any():
        raise RiverbedError("no valid disparity: the range map would be empty", disparity)
    write_range_map(output, lo, hi, overwrite=overwrite, tags={"riverbed_range_window": window,
                                                               "riverbed_range_margin": margin})
    width = (hi - lo)[known] + 1
    summary = {"output": str(output), "size": [int(lo.shape[1]), int(lo.shape[0])],
               "factor": int(lo.shape[1] // disp.shape[1]), "known_share": round(float(known.mean()), 4),
               "min": round(float(lo[known].min()), 3), "max": round(float(hi[known].max()), 3),
               "window": int(window), "mean_width": round(float(width.mean()), 3),
               "seconds": round(time.perf_counter() - t0, 4)}
    if as_json:
        print_json(summary)
    else:
        log.info("%s: ranges of %.1f px on average at %.1f %% of the pixels", output, summary["mean_width"],
                 100 * summary["known_share"])
