"""``riverbed densify``: a dense disparity map from the sparse LiDAR alone (the LiDAR-only baselines)."""

import logging
import time

import click

from ..errors import RiverbedError
from ..io.atomic import check_output
from ..io.disparity import disparity_format, write_disparity
from ..io.images import read_image
from ..matching.lidar_input import check_disparity_values
from ..products.densify import METHODS, densify
from .options import (check_raster_pixels, input_path, json_opt, output_opt, overwrite_opt, print_json,
                      read_disparity_named)

log = logging.getLogger(__name__)


@click.command("densify")
@click.argument("sparse", type=input_path())
@output_opt
@click.option("--method", type=click.Choice(METHODS), default="linear", show_default=True,
              help="nearest: the nearest LiDAR pixel; linear: Delaunay interpolation (nearest outside the hull); "
                   "guided: a joint-bilateral weighted average over similar colour (needs --image).")
@click.option("--image", type=input_path(), default=None, help="The left image (for --method guided).")
@click.option("--sparse-scale", type=float, default=None, help="Stored value per pixel for an 8-bit PNG SPARSE.")
@json_opt
@overwrite_opt
def densify_cmd(sparse, output, method, image, sparse_scale, as_json, overwrite):
    """Interpolate the sparse LiDAR disparities SPARSE (of the left image) into a dense map OUTPUT, no matching.

    The baseline a fusion must beat. Disparity d = x_left - x_right (px); OUTPUT format by extension.
    """
    disparity_format(output)
    check_output(output, overwrite, inputs=[sparse, image])
    if method == "guided" and not image:
        raise RiverbedError("--method guided needs --image LEFT")
    t0 = time.perf_counter()
    check_raster_pixels(sparse, "sparse map")
    sp = read_disparity_named(sparse, sparse_scale, "--sparse-scale")
    try:  # a corrupt value (+-1e30) would be copied into the output
        check_disparity_values(sp, sp.shape[1])
    except RiverbedError as e:
        raise RiverbedError(str(e), sparse) from None
    img = read_image(image) if image else None
    if img is not None and img.shape[:2] != sp.shape:
        raise RiverbedError(f"image is {img.shape[1]}x{img.shape[0]} but the sparse map is {sp.shape[1]}x"
                            f"{sp.shape[0]} (WxH)", image)
    try:
        disp = densify(sp, method, img if method == "guided" else None)
    except RiverbedError as e:
        raise RiverbedError(str(e), sparse if e.path is None else e.path) from None
    write_disparity(output, disp, overwrite=overwrite, tags={"riverbed_densify": method})
    summary = {"output": str(output), "method": method, "size": [int(sp.shape[1]), int(sp.shape[0])],
               "lidar_points": int((sp == sp).sum()), "seconds": round(time.perf_counter() - t0, 4)}
    if as_json:
        print_json(summary)
    else:
        log.info("%s: %s interpolation of %d LiDAR pixels", output, method, summary["lidar_points"])
