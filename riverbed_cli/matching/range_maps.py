"""Per-pixel search ranges besides the LiDAR's tubes: a user's range map checked, and the tube rule's holes given
ranges by a coarse unguided match.

Stage: ``(range map (lo, hi) float, NaN: the nominal range; or the pair and the holes of the tubes) -> inclusive int32
tube ends``. Conventions: the left image is the reference, ``d = x_left - x_right`` (px).
"""

import math

import cv2
import numpy as np

from ..errors import RiverbedError
from .tubes import HOLE_FACTOR, hole_bounds, range_map_summary


def check_range_map_shape(lo, hi, shape):
    """:class:`RiverbedError` unless both bands of a range map are of ``shape``."""
    if tuple(lo.shape) != tuple(shape) or tuple(hi.shape) != tuple(shape):
        raise RiverbedError(f"range map is {lo.shape[1] if len(lo.shape) > 1 else '?'}x{lo.shape[0]} but the images "
                            f"are {shape[1]}x{shape[0]} (WxH)")


def check_range_summary(known, crossed, low, high, d_min, d_max):
    """:class:`RiverbedError` for a range map with no valid pixel, min > max, or a range outside ``[d_min, d_max]``
    (from its :func:`~riverbed_cli.matching.tubes.range_map_summary`)."""
    if not known:
        raise RiverbedError("range map has no valid pixel (all NaN)")
    if crossed:
        raise RiverbedError(f"range map has min > max at {crossed} pixels")
    if low < d_min or high > d_max:
        raise RiverbedError(f"range map spans [{low:.2f}, {high:.2f}], outside the nominal range [{d_min}, {d_max}]")


def check_range_map(range_map, shape, d_min, d_max):
    """A per-pixel range ``(lo, hi)`` (float arrays, NaN: the nominal range) checked for a match of ``shape`` over
    ``[d_min, d_max]`` (:class:`RiverbedError` for another size, no valid pixel, min > max, or a range outside the
    nominal one), as inclusive int32 tube ends."""
    lo, hi = (np.asarray(a) for a in range_map)
    check_range_map_shape(lo, hi, shape)
    check_range_summary(*range_map_summary(lo, hi), d_min, d_max)
    return range_map_ends(lo, hi, d_min, d_max)


def range_map_ends(lo, hi, d_min, d_max):
    """Inclusive int32 ends of a checked range map (a crop of one, say): ``floor(lo)``, ``ceil(hi)``, and
    ``[d_min, d_max]`` where the map has no range."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    known = np.isfinite(lo) & np.isfinite(hi)
    return (np.where(known, np.floor(lo), d_min).astype(np.int32),
            np.where(known, np.ceil(hi), d_max).astype(np.int32))


#: the coarse match of the tube rule's holes: unguided census SGM on the whole range. Without the left-right check:
#: with it, the windows lost the disparities of textureless and occluded parts and the ranges got worse (Wood2 holes:
#: bad3 5.14 % against 1.16 %, docs/tubes.md)
COARSE_MATCH = {"matcher": "sgm", "guide": "none", "range": "full", "fusion": "none", "lr_check": False}


def _shrunk(left, right, d_min, d_max, factor):
    # the pair shrunk factor times (area averaging) and [d_min, d_max] / factor; None below 16 px at that scale
    H, W = left.shape[:2]
    h, w = H // factor, W // factor
    if min(h, w) < 16:
        return None
    small = [cv2.resize(np.ascontiguousarray(im), (w, h), interpolation=cv2.INTER_AREA) for im in (left, right)]
    return small, int(math.floor(d_min / factor)), int(math.ceil(d_max / factor))


def coarse_match(left, right, d_min, d_max, factor, config, match, settings):
    """``match`` (:func:`~riverbed_cli.matching.pipeline.match_pair`) of the pair shrunk ``factor`` times (area
    averaging) over ``[d_min, d_max] / factor``, with ``settings`` over ``config``'s: its disparity, (h, w) float32
    in coarse px; None for a pair smaller than 16 px at that scale. The coarse matches of the tube holes and of the
    LiDAR check."""
    shrunk = _shrunk(left, right, d_min, d_max, factor)
    if shrunk is None:
        return None
    (small_left, small_right), lo, hi = shrunk
    return match(small_left, small_right, None, lo, hi, params=config, **settings).disparity


def coarse_to_fine_match(left, right, d_min, d_max, factor, config, match, settings):
    """:func:`coarse_match` searched in tubes: the pair shrunk ``factor`` times is first matched at half that
    resolution over the whole range (:data:`COARSE_MATCH`), and the match at ``1 / factor`` searches only round it
    (:func:`~riverbed_cli.matching.tubes.hole_bounds`: the coarse disparities within ``HOLE_WINDOW`` of its pixels,
    ``HOLE_MARGIN`` px beyond); ``settings`` over ``config``'s, with the tubes. (h, w) float32 in coarse px; None
    for a pair smaller than 16 px at ``factor``."""
    shrunk = _shrunk(left, right, d_min, d_max, factor)
    if shrunk is None:
        return None
    (small_left, small_right), lo, hi = shrunk
    first = coarse_match(small_left, small_right, lo, hi, 2, config, match, COARSE_MATCH)
    if first is not None:  # (None: too small for a first pass, the whole range searched)
        ends = hole_bounds(first, small_left.shape[:2], lo, hi, factor=2)
        settings = dict(settings, range="tube", range_map=tuple(e.astype(np.float32) for e in ends))
    return match(small_left, small_right, None, lo, hi, params=config, **settings).disparity


def coarse_hole_ranges(left, right, d_min, d_max, config, match):
    """Per-pixel ranges ``(lo, hi)`` (inclusive int32, full resolution) from an unguided match of the pair at
    ``1 / HOLE_FACTOR`` resolution, for the tube rule's holes (:func:`~riverbed_cli.matching.tubes.hole_bounds`).

    The coarse match (:func:`coarse_match`) is census SGM over the nominal range divided by the factor, with no
    left-right check, guidance, tubes or fusion; the other settings are ``config``'s; ``match`` is
    :func:`~riverbed_cli.matching.pipeline.match_pair`. A pair smaller than 16 px at that scale gets the nominal
    range.
    """
    H, W = left.shape[:2]
    disparity = coarse_match(left, right, d_min, d_max, HOLE_FACTOR, config, match, COARSE_MATCH)
    if disparity is None:
        return np.full((H, W), d_min, np.int32), np.full((H, W), d_max, np.int32)
    return hole_bounds(disparity, (H, W), d_min, d_max, HOLE_FACTOR)


def fill_tube_holes(left, right, lo, hi, hole, d_min, d_max, config, match):
    """The tubes ``(lo, hi)`` with the ``hole`` pixels (no LiDAR within reach) given the coarse match's ranges
    (:func:`coarse_hole_ranges`, with ``config``'s settings and ``match``), for ``tube.holes`` ``coarse``."""
    if not hole.any():
        return lo, hi
    clo, chi = coarse_hole_ranges(left, right, d_min, d_max, config, match)
    return np.where(hole, clo, lo), np.where(hole, chi, hi)
