"""``match_files``: ``riverbed match`` as a library call on files: read, match (whole or in tiles), write.

Inputs are checked before any work, outputs written to a temporary name and renamed; TIFF inputs are read by
windows, and a tiled match into a ``.tif`` streams its tiles into the file (the whole map is never in memory).
"""

import contextlib
import logging
import os

import numpy as np

from .. import runtime
from ..errors import RiverbedError
from ..io.atomic import atomic_output, check_outputs, releases_claims
from ..io.disparity import disparity_format, read_disparity, write_disparity
from ..io.images import check_pair, read_image
from ..io.windowed import TiffSink, WindowedRaster, is_tiff, open_range_map, sparse_points_any, valid_area_source
from ..matching.fusion import lidar_kind
from ..matching.lidar_check import lidar_mask as lidar_mask_of
from ..matching.lidar_input import ABSURD_WIDTHS, check_disparity_values, clamp_to_width, disparity_range_from_sparse
from ..matching.pipeline import check_lidar_count, match_pair, resolve_fusion, warm_up
from ..matching.registry import get_guide
from ..runtime.heap import match_heap_bytes
from ..products.visualize import disparity_picture, write_picture, write_png
from .match_plan import check_tiling, plan_match, scan_range_map
from .tiles import match_tiled

log = logging.getLogger(__name__)


def open_inputs(left, right, sparse, sparse_scale, max_pixels):
    """Images and sparse map: TIFFs as windowed rasters (read tile by tile), other formats read whole."""
    srcs = []
    for path in (left, right):
        if os.path.isfile(path) and is_tiff(path):
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
        if sparse_scale is None and os.path.isfile(sparse) and is_tiff(sparse):
            sparse_src = WindowedRaster(sparse, "disparity")
        else:
            try:
                sparse_src = read_disparity(sparse, scale=sparse_scale)
            except RiverbedError as e:  # the reader names evaluate's option
                if "--gt-scale" not in str(e):
                    raise
                raise RiverbedError(str(e)[len(f"{e.path}: "):].replace("--gt-scale", "--sparse-scale"),
                                    e.path) from None
        H, W = srcs[0].shape[:2]
        if sparse_src.shape[:2] != (H, W):
            raise RiverbedError(f"sparse map is {sparse_src.shape[1]}x{sparse_src.shape[0]} but the images are "
                                f"{W}x{H} (WxH)", sparse)
    return srcs[0], srcs[1], sparse_src


#: the tag of a confidence map
CONFIDENCE_TAG = "probability that the disparity is within 1 px of the truth"


def _range_for_plan(vals, min_disp, max_disp, width):
    """The global range the tiling is planned for (the matcher resolves it again the same way); ``vals``: the
    LiDAR disparities (or None)."""
    if min_disp is not None and max_disp is not None:
        return min_disp, max_disp
    if vals.size == 0:
        return None  # match_pair reports the empty map
    lo, hi = disparity_range_from_sparse(vals)
    return clamp_to_width(lo if min_disp is None else min_disp, hi if max_disp is None else max_disp, width)


def _heap_estimate(H, W, plan, overlap):
    # the heap the match (its first tile) will take: prefault_heap's size
    if plan is None:
        return 0
    pixels = min(H * W, (plan.tile + 2 * overlap) ** 2) if plan.tiled else H * W
    if plan.tube_width is not None:
        width = plan.tube_width
    elif plan.tiled:
        width = max(t[5] - t[4] + 1 for t in plan.tiles)
    else:
        width = plan.d_max - plan.d_min + 1
    return match_heap_bytes(pixels, width)


@releases_claims
def match_files(left, right, output, config, sparse=None, sparse_scale=None, min_disp=None, max_disp=None,
                max_pixels=None, tile="auto", overlap=128, lidar_range=True, color_png=None, overwrite=False,
                progress=None, range_map=None, confidence=None, lidar_mask=None):
    """Match the files ``left`` (reference) and ``right`` into the disparity file ``output``.

    ``config`` is a :class:`~riverbed_cli.matching.config.MatchConfig`; ``tile`` ``"auto"``, 0 (never) or a side
    in px (:func:`~riverbed_cli.scale.match_plan.plan_tiles`); ``progress(n_total)`` is called once with the number of
    steps and returns a callable advanced after each (or None); ``range_map`` a 2-band TIFF of per-pixel min and
    max disparity (:func:`~riverbed_cli.io.windowed.open_range_map`), searched instead of the LiDAR's tubes;
    ``confidence`` a ``.tif`` path for the fusion's per-pixel confidence (float32 in [0, 1]: the estimated
    probability that the disparity is within 1 px of the truth; :mod:`~riverbed_cli.matching.fusion`);
    ``lidar_mask`` a ``.png`` path for what the LiDAR did per pixel (uint8,
    :func:`~riverbed_cli.matching.lidar_check.lidar_mask`: 0 none, 1 used, 2 outlier, 3 changed region, 4 changed
    area). Returns the ``--json`` summary (a dict).
    """
    disparity_format(output)  # refuse what cannot be written, or would clobber, before any work
    if color_png and not color_png.lower().endswith(".png"):
        raise RiverbedError("colour preview must be a .png file", color_png)
    if confidence and not confidence.lower().endswith((".tif", ".tiff")):
        raise RiverbedError("confidence must be written to a .tif file", confidence)
    if lidar_mask and not lidar_mask.lower().endswith(".png"):
        raise RiverbedError("the LiDAR mask must be written to a .png file", lidar_mask)
    if lidar_mask and not sparse:
        raise RiverbedError("--lidar-mask needs --sparse (it maps what the LiDAR did)", lidar_mask)
    # claimed (locked against another run) until written; never one of the inputs, nor two outputs in one file
    check_outputs([output, color_png, confidence, lidar_mask], overwrite, inputs=[left, right, sparse, range_map])
    guide = get_guide(config.guide)
    if guide.needs_sparse and not sparse:
        raise RiverbedError(f"--guide {config.guide} needs --sparse")
    fusion = resolve_fusion(config, guide, bool(sparse))
    if confidence and fusion == "none":  # before any work
        raise RiverbedError("no confidence with --fusion none (it comes from --fusion confidence, the default with "
                            "--sparse)", confidence)
    if fusion == "none":  # no LiDAR side beside the matcher: its idle workers may spin (runtime/openmp.py)
        runtime.spin_between_regions()
    tile = check_tiling(tile, overlap)
    # the inputs before the range: a broken image is reported as such, not as a range to give
    left_src, right_src, sparse_src = open_inputs(left, right, sparse, sparse_scale, max_pixels)
    H, W = left_src.shape[:2]
    # the images' valid areas (a rectified frame's alpha): pixels outside them are not matched (matching/overlap.py)
    valid = tuple(valid_area_source(p) for p in (left, right))
    if (min_disp is None or max_disp is None) and not sparse and not range_map:
        if max_disp is None:
            raise RiverbedError("give --max-disp (and --min-disp), --pair (the pair file riverbed rectify wrote), or "
                                "--sparse or --range-map to derive the disparity range from")
        min_disp = 0
    min_disp, max_disp = clamp_to_width(min_disp, max_disp, W)  # one warning here rather than one per tile
    if guide.uses_window and config.guidance.window != "auto" and config.guidance.window > min(H, W):
        raise RiverbedError(f"--window {config.guidance.window} is larger than the image ({W}x{H} px)")
    rmap = scan = None
    if range_map:
        rmap = open_range_map(range_map)  # read by windows: a tiled match reads each tile's
        try:  # before any work
            scan = scan_range_map(rmap, (H, W))  # the one read that checks the map and plans the tiles
            if scan.known:  # a +-1e9 is a corrupt map, not a range to search
                lo, hi = scan.span()
                if max(abs(lo), abs(hi)) > ABSURD_WIDTHS * W:
                    raise RiverbedError(f"range map values span [{lo:g}, {hi:g}] px, out of range for images {W} px "
                                        f"wide (at most +-{ABSURD_WIDTHS * W} px, {ABSURD_WIDTHS} times the width)")
            if (max_disp is None or min_disp is None) and scan.known:
                min_disp = scan.span()[0] if min_disp is None else min_disp
                max_disp = scan.span()[1] if max_disp is None else max_disp
                min_disp, max_disp = clamp_to_width(min_disp, max_disp, W)
            scan.check(min_disp, max_disp)
        except RiverbedError as e:
            if e.path is not None:  # names its file already
                raise
            raise RiverbedError(str(e), range_map) from None
    # the same plan as blocks' (match_plan.plan_match): untiled when the whole range (with tubes: their volume)
    # fits, else tiles sized for the widest LiDAR range; the LiDAR points are read once for it and the match. Made of
    # the LiDAR as given, for the choice to tile and the memory: match_tiled plans again after its offset and check
    plan = None
    points = sparse_points_any(sparse_src) if sparse_src is not None else None
    if points is not None:
        try:
            check_disparity_values(points[2], W)
            check_lidar_count(len(points[0]), config)
        except RiverbedError as e:
            raise RiverbedError(str(e), sparse) from None
    rng = _range_for_plan(points[2] if points else None, min_disp, max_disp, W)
    if rng is not None:
        plan = plan_match((H, W), points, rng[0], rng[1], config, sparse=sparse_src, tile=tile, overlap=overlap,
                          lidar_range=lidar_range, scan=scan)
    # load the kernels this run uses now (start-up, not matching time), while a thread faults in the heap the match
    # will take (runtime/heap.py)
    # the fusion's LiDAR side by the density of the whole map (tiles of the same density decide alike)
    kind = lidar_kind(config.fuse.lidar, len(points[0]), (H, W)) if points is not None else None
    with runtime.prefault_heap(_heap_estimate(H, W, plan, overlap)):
        warm_up(config=config, fusion_lidar=kind)
    runtime.start_up_done()  # the program's collector back on, start-up's objects frozen (runtime/collector.py)
    if plan is not None and plan.tiled:
        return _match_tiled(left_src, right_src, sparse_src, min_disp, max_disp, config, plan.tile, overlap,
                            lidar_range, output, color_png, overwrite, progress, rmap, confidence, scan, valid,
                            points, lidar_mask)

    step = progress(3) if progress else None
    left_img, right_img = (np.asarray(s[:, :]) if isinstance(s, WindowedRaster) else s for s in (left_src, right_src))
    sparse_map = sparse_src[:, :] if isinstance(sparse_src, WindowedRaster) else sparse_src
    if step:
        step()
    try:
        whole_map = tuple(b[:, :] for b in rmap) if rmap is not None else None
        areas = tuple(None if v is None else np.asarray(v[:, :]) for v in valid)
        result = match_pair(left_img, right_img, sparse_map, min_disp, max_disp, params=config,
                            range_map=whole_map, valid_areas=areas)
    except RiverbedError as e:
        # Name the file the problem comes from when it is the sparse map or the range map.
        if sparse and "sparse" in str(e) and e.path is None:
            raise RiverbedError(str(e), sparse) from None
        if range_map and "range map" in str(e) and e.path is None:
            raise RiverbedError(str(e), range_map) from None
        raise
    if step:
        step()
    info = result.info
    tags = {"riverbed_matcher": config.matcher, "riverbed_guide": config.guide, "riverbed_window": info["window"],
            "riverbed_d_min": info["d_min"], "riverbed_d_max": info["d_max"],
            "riverbed_lidar_share": f"{info['lidar_share']:.6f}"}
    write_disparity(output, result.disparity, overwrite=overwrite, tags=tags)
    if confidence:
        write_disparity(confidence, result.confidence, overwrite=overwrite,
                        tags={"riverbed_confidence": CONFIDENCE_TAG})
    if color_png:
        write_picture(color_png, disparity_picture(result.disparity), overwrite=overwrite)
    if lidar_mask:
        write_png(lidar_mask, lidar_mask_of(sparse_map, result.lidar_check), overwrite=overwrite)
    if step:
        step()
    log.info("%s: %dx%d, d in [%d, %d], guide %s, %.3f s", output, *info["size"], info["d_min"], info["d_max"],
             config.guide, info["seconds"])
    return {"output": str(output), **info.to_dict()}


def _match_tiled(left_src, right_src, sparse_src, min_disp, max_disp, config, size, overlap, lidar_range, output,
                 color_png, overwrite, progress, range_map=None, confidence=None, range_scan=None, valid=None,
                 points=None, lidar_mask=None):
    H, W = left_src.shape[:2]
    n_tiles = -(-H // size) * -(-W // size)
    step = progress(n_tiles) if progress else None
    advance = (lambda n: step()) if step else None
    with contextlib.ExitStack() as stack:
        conf_sink = None
        if confidence:  # streamed as the disparities, renamed into place only when every tile is done
            conf_sink = stack.enter_context(TiffSink(stack.enter_context(atomic_output(confidence, overwrite)), H, W,
                                                     tags={"riverbed_confidence": CONFIDENCE_TAG}))
        if output.lower().endswith((".tif", ".tiff")):
            # Stream tiles into the GeoTIFF: the whole disparity map is never in memory.
            with atomic_output(output, overwrite) as tmp, TiffSink(tmp, H, W) as sink:
                result = match_tiled(left_src, right_src, sparse_src, min_disp, max_disp, params=config, tile=size,
                                     overlap=overlap, lidar_range=lidar_range, progress=advance, out=sink,
                                     range_map=range_map, confidence_out=conf_sink, range_scan=range_scan,
                                     valid_areas=valid, points=points)
                sink.update_tags(riverbed_guide=config.guide, riverbed_window=result.info["window"],
                                 riverbed_tiles=result.info["tiles"])
            disp = None
        else:
            result = match_tiled(left_src, right_src, sparse_src, min_disp, max_disp, params=config, tile=size,
                                 overlap=overlap, lidar_range=lidar_range, progress=advance, range_map=range_map,
                                 confidence_out=conf_sink, range_scan=range_scan, valid_areas=valid, points=points)
            disp = result.disparity
            write_disparity(output, disp, overwrite=overwrite, tags={"riverbed_guide": config.guide})
    if color_png:
        if disp is None:
            step_px = max(1, max(H, W) // 4096)  # a preview: read the written map back decimated
            disp = read_disparity(output)[::step_px, ::step_px]
        write_picture(color_png, disparity_picture(disp), overwrite=overwrite)
    if lidar_mask:  # the check ran once for the whole pair: its mask too, where the given LiDAR has points
        have = np.zeros((H, W), bool)
        have[points[0], points[1]] = True
        write_png(lidar_mask, lidar_mask_of(have, result.lidar_check), overwrite=overwrite)
    info = result.info.to_dict()
    log.info("%s: %dx%d in %d tiles of %d px, %.1f s", output, W, H, info["tiles"], size, info["seconds"])
    return {"output": str(output), **info}
