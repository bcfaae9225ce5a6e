"""The LiDAR disparities entering a match: checked, the disparity range derived from them, cut to the range.

Stage: ``(sparse map (H, W) float, NaN where there is no LiDAR; the images' shape; the range) -> (the map cut to the
range as float32, its points (rows, columns, values) and its LiDAR shares)``, for :func:`~.pipeline.match_pair`,
the tiled match and the block. Conventions: the left image is the reference, ``d = x_left - x_right`` (px).
"""

import logging
import math

import numpy as np
from numba import prange

from ..errors import RiverbedError
from ..geometry.coverage import lidar_share_of_row_ends
from ..runtime.kernel import kernel
from .volume import band_pair_rows, band_pairs

log = logging.getLogger(__name__)

#: disparities (LiDAR, range maps) beyond this many image widths are no disparity of the pair but a corrupt value
#: (a stray +-1e30): refused, naming the file, rather than searched or copied
ABSURD_WIDTHS = 4


def check_disparity_values(values, width, what="sparse map"):
    """:class:`RiverbedError` when a finite value of ``values`` (any array, NaN ignored) lies beyond
    ``+-ABSURD_WIDTHS * width`` px: ``what`` (a map of an image ``width`` px wide) is corrupt."""
    limit = ABSURD_WIDTHS * max(int(width), 1)
    values = np.asarray(values)
    with np.errstate(invalid="ignore"):
        bad = np.abs(values) > limit  # False for NaN
    n = int(np.count_nonzero(bad))
    if n:
        example = float(values[bad].flat[0])
        raise RiverbedError(f"{what} holds {n} disparit{'y' if n == 1 else 'ies'} beyond +-{limit} px (e.g. "
                            f"{example:g}; {ABSURD_WIDTHS} times the image width of {width} px): a corrupt value, "
                            "not a disparity of this pair")


def clamp_to_width(d_min, d_max, width):
    """``(d_min, d_max)`` cut to what a pair ``width`` px wide can match, ``|d| <= width - 1`` (a pixel's match at a
    larger disparity lies outside the other image, and the volume would grow for nothing), with a warning when it
    cuts; :class:`RiverbedError` when no disparity of the range is left. An end that is None (not given: derived
    later) stays None; an empty range (``d_min > d_max``) is left for the caller to report."""
    top = max(int(width) - 1, 0)
    if d_min is not None and d_max is not None and d_min > d_max:
        return d_min, d_max
    if (d_min is not None and d_min > top) or (d_max is not None and d_max < -top):
        raise RiverbedError(f"disparity range [{d_min}, {d_max}] lies beyond what images {width} px wide can match "
                            f"(|d| <= {top})")
    lo = None if d_min is None else max(d_min, -top)
    hi = None if d_max is None else min(d_max, top)
    if (lo, hi) != (d_min, d_max):
        show = lambda v: "auto" if v is None else str(v)  # noqa: E731
        log.warning("disparity range [%s, %s] clamped to [%s, %s]: the images are %d px wide", show(d_min),
                    show(d_max), show(lo), show(hi), width)
    return lo, hi


def disparity_range_from_sparse(sparse, margin=None):
    """Inclusive integer range ``(d_min, d_max)`` covering the sparse disparities plus a margin.

    The margin (px) defaults to ``max(8, 15 % of the LiDAR span)``: LiDAR misses parts of the scene (occlusions,
    dark surfaces) whose disparities may lie a little beyond what it saw. Corrupt values are refused where the LiDAR
    enters (:func:`check_disparity_values`: ``match_pair``, ``match_tiled``, ``match_files``, a block's project stage).
    """
    vals = sparse[np.isfinite(sparse)]
    if vals.size == 0:
        raise RiverbedError("sparse map has no valid disparities")
    lo, hi = float(vals.min()), float(vals.max())
    if margin is None:
        margin = max(8.0, 0.15 * (hi - lo))
    return int(math.floor(lo - margin)), int(math.ceil(hi + margin))


def resolve_disparity_range(d_min, d_max, sparse_values, width=None):
    """``(d_min, d_max)`` as ints, the missing ends derived from the sparse disparities (any array, NaN ignored);
    with ``width`` (the images', px) clamped to what they can match (:func:`clamp_to_width`)."""
    if d_min is None or d_max is None:
        if sparse_values is None:
            raise RiverbedError("give the disparity range (--min-disp/--max-disp, or --pair with the pair file "
                                "riverbed rectify wrote), or --sparse or --range-map to derive it from")
        lo, hi = disparity_range_from_sparse(sparse_values)
        d_min = lo if d_min is None else d_min
        d_max = hi if d_max is None else d_max
    d_min, d_max = int(d_min), int(d_max)
    if d_max < d_min:
        raise RiverbedError(f"empty disparity range: --min-disp {d_min} > --max-disp {d_max}")
    if width is not None:
        d_min, d_max = clamp_to_width(d_min, d_max, width)
    return d_min, d_max


def prepare_sparse(sparse, shape, d_min, d_max):
    """The sparse map as float32, checked against the image ``shape``; disparities outside ``[d_min, d_max]``
    become NaN (with a warning)."""
    return prepare_lidar(sparse, shape, d_min, d_max)[0]


def prepare_lidar(sparse, shape, d_min, d_max):
    """:func:`prepare_sparse` and what a match needs of its LiDAR, from one pass over the map: ``(sparse, points,
    share, share_all)`` with ``points`` the :func:`~riverbed_cli.geometry.coverage.lidar_points` of the prepared
    map (the points inside the range), ``share`` their :func:`lidar_share` and ``share_all`` that of every finite
    point (the tube rule's spacing counts them all)."""
    sparse = np.asarray(sparse, dtype=np.float32)
    if sparse.shape != shape:
        raise RiverbedError(
            f"sparse map is {sparse.shape[1] if sparse.ndim > 1 else '?'}x{sparse.shape[0]} (WxH) but the images are "
            f"{shape[1]}x{shape[0]}"
        )
    per_row, cut = _cut_to_range(sparse, float(d_min), float(d_max))
    n, n_in = int(per_row[:, 0].sum()), int(per_row[:, 1].sum())
    if n == 0:
        raise RiverbedError("sparse map has no valid disparities")
    if n_in < n:  # the values outside the range: dropped below, unless corrupt
        check_disparity_values(sparse[np.isfinite(sparse)], shape[1])
    check_inside(n_in, n, d_min, d_max, lambda: sparse[np.isfinite(sparse)])
    out = cut if n_in < n else sparse
    points = _points_of_rows(out, per_row)
    share = lidar_share_of_row_ends(n_in, per_row[:, 4], per_row[:, 5], shape)
    share_all = share if n_in == n else lidar_share_of_row_ends(n, per_row[:, 2], per_row[:, 3], shape)
    return out, points, share, share_all


@kernel(parallel=True)
def _cut_to_range(sparse, d_min, d_max):
    # In one pass: a copy with NaN outside [d_min, d_max] and per row the finite values and those inside, with the
    # first and last column of each (-1: none). NumPy's masks, sums and np.where took 1 ms on 740 x 500 px, and the
    # points and the shares another pass each; one kernel, as each cached kernel costs a fresh process 3-4 ms to load.
    # The row's pass is branch-free (it vectorises: 0.5x the time of the loop that tracked the ends as it went);
    # the ends come after, from scans that stop at the first and last hit.
    H, W = sparse.shape
    per_row = np.empty((H, 6), np.int64)
    out = np.empty((H, W), np.float32)
    nan = np.float32(np.nan)
    m = band_pairs(H)
    for i in prange(m):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            row = sparse[y]
            cut = out[y]
            finite = inside_n = 0
            for x in range(W):
                v = np.float64(row[x])
                inside = (v >= d_min) & (v <= d_max)  # False for NaN and +-inf
                cut[x] = row[x] if inside else nan
                finite += np.int64(abs(v) < np.inf)
                inside_n += np.int64(inside)
            f0 = f1 = i0 = i1 = -1
            if finite:
                f0, f1 = _row_ends(row, -np.inf, np.inf)
            if inside_n:
                i0, i1 = _row_ends(row, d_min, d_max)
            per_row[y, 0], per_row[y, 1], per_row[y, 2], per_row[y, 3], per_row[y, 4], per_row[y, 5] = (
                finite, inside_n, f0, f1, i0, i1)
    return per_row, out


@kernel(inline=True)
def _row_ends(row, lo, hi):
    # the first and last column of a row whose value is finite and within [lo, hi] (-1, -1: none)
    W = row.shape[0]
    first = last = -1
    for x in range(W):
        v = np.float64(row[x])
        if v >= lo and v <= hi and abs(v) < np.inf:
            first = x
            break
    if first >= 0:
        for x in range(W - 1, first - 1, -1):
            v = np.float64(row[x])
            if v >= lo and v <= hi and abs(v) < np.inf:
                last = x
                break
    return first, last


@kernel(parallel=True)
def _points_of_rows(sparse, per_row):
    # lidar_points of a map whose finite values are those counted inside by _cut_to_range: rows, columns (int64)
    # and values (float64) in row-major order, each row filled from its running total
    H = sparse.shape[0]
    at = np.zeros(H + 1, np.int64)
    for y in range(H):
        at[y + 1] = at[y] + per_row[y, 1]
    rows = np.empty(at[H], np.int64)
    cols = np.empty(at[H], np.int64)
    values = np.empty(at[H], np.float64)
    m = band_pairs(H)
    for i in prange(m):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            k = at[y]
            for x in range(max(per_row[y, 4], 0), per_row[y, 5] + 1):
                v = sparse[y, x]
                if np.isfinite(v):
                    rows[k] = y
                    cols[k] = x
                    values[k] = np.float64(v)
                    k += 1
    return rows, cols, values


def check_inside(n_in, n, d_min, d_max, values):
    """Raise when none of the ``n`` LiDAR disparities lies in ``[d_min, d_max]``, warn when only ``n_in`` do
    (``values()``: the disparities, for the message)."""
    if n_in == 0:
        vals = values()
        raise RiverbedError(
            f"disparity range [{d_min}, {d_max}] excludes all sparse disparities (they span "
            f"[{vals.min():.2f}, {vals.max():.2f}])"
        )
    if n_in < n:
        log.warning("%d of %d sparse disparities lie outside [%d, %d]: they guide no cost (tubes keep the pixels "
                    "only they reach at the range's end)", n - n_in, n, d_min, d_max)
