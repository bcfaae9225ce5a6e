"""``riverbed match``: dense disparity of a rectified pair, optionally guided by sparse LiDAR disparities."""

import logging
import os

import click
import numpy as np
import psutil
from tqdm import tqdm

from ..errors import RiverbedError
from ..io.atomic import check_output
from ..io.disparity import _kind as disparity_format
from ..io.disparity import read_disparity, write_disparity
from ..io.images import MAX_PIXELS, check_pair, read_image
from ..matching.pipeline import GUIDES, MATCHERS, MatchParams, disparity_range_from_sparse, match_pair, warm_up
from ..products.visualize import colorize_disparity, write_png
from ..scale.tiles import TILE_BUDGET, TiffSink, WindowedRaster, auto_tile, match_tiled, sparse_points_any, tile_grid
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
@click.option("--tile", default="auto", show_default=True,
              help="Tile side (px) for large images, 'auto' (from the disparity range and free memory; untiled when "
                   "the image fits one tile) or 0 (never tile). Tiles of TIFF inputs are read by windows.")
@click.option("--overlap", type=int, default=128, show_default=True, help="Tile overlap (px).")
@click.option("--lidar-range/--global-range", default=True, show_default=True,
              help="With tiles and --sparse: each tile searches only the disparities its LiDAR allows.")
@json_opt
@overwrite_opt
def match_cmd(left, right, output, sparse, sparse_scale, matcher, guide, window, min_disp, max_disp, census_win, paths,
              p1, p2, subpixel, median, lr_check, color_png, max_pixels, tile, overlap, lidar_range, as_json,
              overwrite):
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

    if tile != "auto" and not (tile.isdigit() and (int(tile) == 0 or int(tile) >= 16)):
        raise RiverbedError(f"--tile must be auto, 0 or a size of at least 16 px, not '{tile}'")
    if overlap < 0:
        raise RiverbedError(f"--overlap must be >= 0, got {overlap}")
    params = MatchParams(guide=guide, window=window, census=census_win, paths=int(paths), p1=p1, p2=p2,
                         subpixel=subpixel, median=median, lr_check=lr_check, matcher=matcher)
    left_src, right_src, sparse_src = _open_inputs(left, right, sparse, sparse_scale, max_pixels)
    plan = _tiling(left_src, sparse_src, min_disp, max_disp, tile, overlap)
    if plan is not None:
        return _match_tiled_cmd(left_src, right_src, sparse_src, min_disp, max_disp, params, plan, overlap,
                                lidar_range, output, color_png, as_json, overwrite)

    stages = ["read", "match", "write"]
    with tqdm(total=len(stages), desc="match", unit="stage", disable=not progress_enabled(), leave=False) as bar:
        left_img, right_img = (np.asarray(s[:, :]) if isinstance(s, WindowedRaster) else s
                               for s in (left_src, right_src))
        sparse_map = sparse_src
        if isinstance(sparse_map, WindowedRaster):
            sparse_map = sparse_map[:, :]
        bar.update()

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


def _is_tiff(path):
    with open(path, "rb") as f:
        return f.read(4) in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def _open_inputs(left, right, sparse, sparse_scale, max_pixels):
    """Images and sparse map: TIFFs as windowed rasters (read tile by tile), other formats read whole."""
    srcs = []
    for path in (left, right):
        if os.path.isfile(path) and _is_tiff(path):
            src = WindowedRaster(path, "image")
            if src.shape[0] * src.shape[1] > max_pixels:
                raise RiverbedError(f"image has {src.shape[0] * src.shape[1]} pixels, more than --max-pixels "
                                    f"{max_pixels}", path)
        else:
            src = read_image(path, max_pixels)
        srcs.append(src)
    if srcs[0].shape[:2] != srcs[1].shape[:2]:
        if isinstance(srcs[0], np.ndarray) and isinstance(srcs[1], np.ndarray):
            check_pair(srcs[0], srcs[1], left, right)
        raise RiverbedError(f"left and right images differ in size: {srcs[0].shape[0]}x{srcs[0].shape[1]} vs "
                            f"{srcs[1].shape[0]}x{srcs[1].shape[1]} (height x width; left image {left})", right)
    sparse_src = None
    if sparse:
        if sparse_scale is None and os.path.isfile(sparse) and _is_tiff(sparse):
            sparse_src = WindowedRaster(sparse, "disparity")
        else:
            sparse_src = read_disparity(sparse, scale=sparse_scale)
        H, W = srcs[0].shape[:2]
        if sparse_src.shape[:2] != (H, W):
            raise RiverbedError(f"sparse map is {sparse_src.shape[1]}x{sparse_src.shape[0]} but the images are "
                                f"{W}x{H} (WxH)", sparse)
    return srcs[0], srcs[1], sparse_src


def _tiling(left_src, sparse_src, min_disp, max_disp, tile, overlap):
    """The tile size to use, or None to match the image whole."""
    if tile == "0":
        return None
    H, W = left_src.shape[:2]
    if tile != "auto":
        return int(tile) if max(H, W) > int(tile) else None
    if min_disp is not None and max_disp is not None:
        span = max_disp - min_disp
    else:
        _, _, vals = sparse_points_any(sparse_src)
        if vals.size == 0:
            return None  # match_pair reports the empty map
        lo, hi = disparity_range_from_sparse(vals)
        span = (hi if max_disp is None else max_disp) - (lo if min_disp is None else min_disp)
    budget = min(TILE_BUDGET, psutil.virtual_memory().available // 4)
    size = auto_tile(max(span, 0), overlap, budget)
    return size if max(H, W) > size else None


def _match_tiled_cmd(left_src, right_src, sparse_src, min_disp, max_disp, params, size, overlap, lidar_range, output,
                     color_png, as_json, overwrite):
    from ..io.atomic import atomic_output

    H, W = left_src.shape[:2]
    warm_up(params.matcher, (params.guide,))
    n_tiles = len(tile_grid(H, W, size))
    with tqdm(total=n_tiles, desc="match", unit="tile", disable=not progress_enabled(), leave=False) as bar:
        if output.lower().endswith((".tif", ".tiff")):
            # Stream tiles into the GeoTIFF: the whole disparity map is never in memory.
            with atomic_output(output, overwrite) as tmp, TiffSink(tmp, H, W) as sink:
                result = match_tiled(left_src, right_src, sparse_src, min_disp, max_disp, params, size, overlap,
                                     lidar_range, progress=bar.update, out=sink)
                sink.update_tags(riverbed_guide=params.guide, riverbed_window=result.info["window"],
                                 riverbed_tiles=result.info["tiles"])
            disp = None
        else:
            result = match_tiled(left_src, right_src, sparse_src, min_disp, max_disp, params, size, overlap,
                                 lidar_range, progress=bar.update)
            disp = result.disparity
            write_disparity(output, disp, overwrite=overwrite, tags={"riverbed_guide": params.guide})
    if color_png:
        if disp is None:
            step = max(1, max(H, W) // 4096)  # a preview: read the written map back decimated
            disp = read_disparity(output)[::step, ::step]
        write_png(color_png, colorize_disparity(disp), overwrite=overwrite)
    info = {k: v for k, v in result.info.items() if k != "tile_ranges"}
    info["tile_ranges"] = result.info["tile_ranges"]
    if as_json:
        print_json({"output": str(output), **info})
    else:
        log.info("%s: %dx%d in %d tiles of %d px, %.1f s", output, W, H, info["tiles"], size, info["seconds"])
