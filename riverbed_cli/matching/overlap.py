"""Where a match is possible at all: the overlap rule, applied to every match by :func:`keep_to_overlap` and
:func:`keep_fusion_to_lidar` (docs/rectify.md, "the overlap").

A pixel ``(y, x)`` of the left (reference) image can be matched only if at least one disparity ``d`` of its searched
range (``[d_min, d_max]``, or its tube) puts its candidate ``x - d`` inside the right image (``0 <= x - d < W``) and,
when the right image has a valid area (a rectified frame's area that its source covers), on a valid right pixel; a
left pixel outside the left image's own valid area has nothing to match. A pixel whose tube (the LiDAR's bound on
its disparity, narrower than the range) reaches outside needs the tube's middle inside: beyond that its true match
most likely lies outside, and the stereo would pick a wrong one inside. Every other pixel is *outside the overlap*.
On frame pairs this is most of the image: with 27 % forward overlap, about 70 % of a rectified left frame.

The rule, for every matcher, guided or not, fused or not:

- outside the overlap, and wherever the matcher's choice puts the match beyond the right image's edge (the
  smoothness term carrying its neighbours on), there is no stereo: NaN, and a failing left-right status;
- with LiDAR guiding the cost, such a pixel keeps the guided matcher's value inside the LiDAR's coverage (the points'
  convex hull and one mean spacing around it): the guidance carried along the image, an interpolation of the LiDAR;
- the fusion fills a pixel without stereo from the LiDAR only inside the same coverage, and none of its values lies
  beyond the searched range (``[d_min - 1, d_max + 1]``: the sub-pixel refinement reaches half a pixel beyond its
  ends); what it drops is NaN with confidence 0.

``riverbed project`` keeps only LiDAR points seen in both images, so on a real pair nothing outside the overlap is
filled; a benchmark's LiDAR, sampled from the ground truth over the whole left image, covers the left edge whose
match lies outside the right image, and fills it.
"""

import math
from dataclasses import replace

import cv2
import numpy as np
from numba import prange

from ..runtime.kernel import kernel

#: How far (px) beyond the searched range a disparity may lie: the sub-pixel refinement's reach, with room.
RANGE_SLACK = 1.0


def matchable_mask(shape, d_min, d_max, right_valid=None, left_valid=None, tubes=None):
    """Pixels of the left image that have at least one candidate inside the right image (and its valid area).

    Parameters
    ----------
    shape : (H, W)
        Size of the (equal-size) rectified images.
    d_min, d_max : int
        The searched disparity range, inclusive, ``d = x_left - x_right`` (px).
    right_valid, left_valid : (H, W) bool arrays, optional
        The images' valid areas (True: the pixel shows the scene); None: every pixel.
    tubes : TubeLayout, optional
        Each pixel's own searched range (:class:`~riverbed_cli.matching.volume.TubeLayout`, tubes inside
        ``[d_min, d_max]``): its candidates are those of its tube. A tube narrower than ``[d_min, d_max]`` is the
        LiDAR's bound on the true disparity: the pixel needs its middle candidate inside (when the middle of the
        bound falls outside, the true match most likely does too).

    Returns
    -------
    (H, W) bool
        True where a match is possible.
    """
    H, W = int(shape[0]), int(shape[1])
    lo, hi = int(d_min), int(d_max)
    if tubes is not None:
        offset, width = tubes.offset, tubes.width
    else:  # one range for every pixel: a 1 x 1 layout the kernel reads for all
        offset, width = np.zeros((1, 1), np.int32), np.full((1, 1), hi - lo + 1, np.int32)
    valid = np.ones((1, 1), np.bool_) if right_valid is None else np.ascontiguousarray(right_valid, np.bool_)
    out = _matchable(np.ascontiguousarray(offset, np.int32), np.ascontiguousarray(width, np.int32), np.int64(lo),
                     np.int64(hi - lo + 1), valid, np.int64(H), np.int64(W))
    if left_valid is not None:
        out &= np.asarray(left_valid, np.bool_)
    return out


@kernel(parallel=True)
def _matchable(offset, width, d_min, nominal, right_valid, H, W):
    # Per row, the running count of valid right pixels: a pixel with range [lo, hi] (d_min + offset, width wide) is
    # matchable when its candidate columns [x - hi, x - lo] (cut to the image) hold at least one, or, for a tube
    # narrower than the ``nominal`` range, when its middle candidate is valid. ``offset``, ``width`` of shape (1, 1):
    # one range for every pixel; ``right_valid`` of shape (1, 1): no valid area. Rows in parallel, O(W) per row.
    per_pixel = offset.shape[0] == H and offset.shape[1] == W
    masked = right_valid.shape[0] == H
    out = np.empty((H, W), np.bool_)
    for y in prange(H):
        count = np.zeros(W + 1, np.int32)
        for x in range(W):
            count[x + 1] = count[x] + (1 if (not masked or right_valid[y, x]) else 0)
        for x in range(W):
            k = offset[y, x] if per_pixel else offset[0, 0]
            w = width[y, x] if per_pixel else width[0, 0]
            lo = d_min + k
            hi = lo + w - 1
            if w < nominal:  # a tube from the LiDAR: its middle inside, else the truth likely lies outside
                mid = (lo + hi) // 2
                out[y, x] = x - mid >= 0 and x - mid <= W - 1 and (not masked or right_valid[y, x - mid])
            else:
                a = max(x - hi, 0)
                b = min(x - lo, W - 1)
                out[y, x] = b >= a and count[b + 1] - count[a] > 0
    return out


def matchable_mask_reference(shape, d_min, d_max, right_valid=None, left_valid=None, tubes=None):
    """:func:`matchable_mask` as the plain loop over every candidate (for tests)."""
    H, W = int(shape[0]), int(shape[1])
    out = np.zeros((H, W), np.bool_)
    for y in range(H):
        for x in range(W):
            if left_valid is not None and not left_valid[y, x]:
                continue
            lo, hi = int(d_min), int(d_max)
            if tubes is not None:
                lo = int(d_min) + int(tubes.offset[y, x])
                hi = lo + int(tubes.width[y, x]) - 1
            inside = [0 <= x - d < W and (right_valid is None or right_valid[y, x - d]) for d in range(lo, hi + 1)]
            narrow = tubes is not None and hi - lo < int(d_max) - int(d_min)
            out[y, x] = inside[(hi - lo) // 2] if narrow else any(inside)
    return out


def lidar_coverage(points, shape, reach=None):
    """Pixels inside the convex hull of the LiDAR ``points`` (``(rows, cols, values)``) or within ``reach`` px of
    it (default: the points' mean spacing, ``sqrt(hull area / points)``), where the LiDAR's interpolation is an
    interpolation: (H, W) bool (all False for fewer than three points)."""
    rows, cols = np.asarray(points[0]), np.asarray(points[1])
    out = np.zeros(shape, np.uint8)
    if rows.size >= 3:
        hull = cv2.convexHull(np.stack([cols, rows], axis=1).astype(np.int32))
        cv2.fillConvexPoly(out, hull, 1)
        if reach is None:
            reach = math.sqrt(max(float(cv2.contourArea(hull)), 1.0) / rows.size)
        r = int(round(reach))
        if r >= 1:
            out = cv2.dilate(out, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return out.astype(np.bool_)


def match_outside(disparity, right_valid=None):
    """Pixels whose disparity puts their match outside the right image (``x - d`` more than half a pixel beyond
    its columns) or on an invalid pixel of it: the matcher's cost there is padding, not a measurement."""
    H, W = disparity.shape
    with np.errstate(invalid="ignore"):
        xr = np.arange(W, dtype=np.float32)[None, :] - disparity
        out = (xr < -0.5) | (xr > W - 0.5)
    if right_valid is not None:
        col = np.clip(np.rint(np.nan_to_num(xr, nan=0.0)), 0, W - 1).astype(np.intp)
        out |= np.isfinite(disparity) & ~np.take_along_axis(np.asarray(right_valid, np.bool_), col, axis=1)
    return out


def outside_searched_range(disparity, d_min, d_max):
    """Pixels whose disparity lies further than :data:`RANGE_SLACK` beyond the searched ``[d_min, d_max]``."""
    with np.errstate(invalid="ignore"):
        return (disparity < d_min - RANGE_SLACK) | (disparity > d_max + RANGE_SLACK)


def keep_to_overlap(out, d_min, d_max, valid_areas=None, tubes=None, kept=None):
    """Invalidate, in a matcher's output ``out`` (:class:`~riverbed_cli.matching.matchers.MatcherOutput`, changed in
    place), the pixels outside the overlap and the choices whose match lies outside the right image; their left-right
    status becomes failing.

    ``valid_areas``: ``(left_valid, right_valid)`` or None; ``tubes``: the searched tubes (None: ``[d_min, d_max]``
    everywhere). ``kept``: with LiDAR guiding the cost, its coverage (:func:`lidar_coverage`, (H, W) bool): there
    such a pixel keeps the guided matcher's value, the LiDAR's guidance carried along the image's paths (an
    image-guided interpolation of the LiDAR, not a stereo measurement, hence its failing status).
    Returns ``(outside, no_stereo)``: the pixels without any candidate (the overlap's complement) and every pixel
    the output leaves without a disparity, (H, W) bool each."""
    left_valid, right_valid = valid_areas if valid_areas is not None else (None, None)
    outside = ~matchable_mask(out.disparity.shape, d_min, d_max, right_valid, left_valid, tubes=tubes)
    unmatched = outside | match_outside(out.disparity, right_valid)
    if unmatched.any():
        drop = unmatched if kept is None else unmatched & ~kept
        if left_valid is not None:
            drop |= ~np.asarray(left_valid, np.bool_)
        out.disparity[drop] = np.nan
        if out.status is not None:
            out.status[unmatched] = np.maximum(out.status[unmatched], 1)
    return outside, ~np.isfinite(out.disparity)


def keep_fusion_to_lidar(fused, no_stereo, points, d_min, d_max, valid_areas=None, coverage=None):
    """A fusion's output (:class:`~riverbed_cli.matching.fusion.FusionOutput`) without what it cannot know: a pixel
    with no stereo (``no_stereo``) keeps the LiDAR's value only inside the coverage of the LiDAR ``points``
    (:func:`lidar_coverage`, or ``coverage`` if already made: an interpolation, not an extrapolation of its planes)
    and inside the left image's valid area; no value lies beyond the searched range. Dropped pixels are NaN with
    confidence 0, and counted in the stats' ``invalid``."""
    shape = fused.disparity.shape
    if coverage is None:
        coverage = lidar_coverage(points, shape)
    dropped = no_stereo & ~coverage
    if valid_areas is not None and valid_areas[0] is not None:
        dropped |= ~np.asarray(valid_areas[0], np.bool_)
    dropped |= outside_searched_range(fused.disparity, d_min, d_max)
    if not dropped.any():
        return fused
    fused.disparity[dropped] = np.nan
    if fused.confidence is not None:
        fused.confidence[dropped] = 0.0
    if fused.stats is not None:  # the dropped pixels had no stereo: they were the interpolation's
        gone = float(dropped.mean())
        fused.stats = replace(fused.stats, lidar=round(max(0.0, fused.stats.lidar - gone), 4), invalid=round(gone, 4),
                              mean_confidence=round(float(fused.confidence.mean()), 4))
    return fused
