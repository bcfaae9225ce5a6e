"""Disparity selection and refinement: winner-takes-all, sub-pixel fit, left-right check, median filter.

Input is the aggregated cost ``S`` (``H x W x D``, disparity ``d = d_min + i`` at index ``i``); output is a float32
disparity map of the left image, ``d = x_left - x_right``, NaN where invalid.
"""

import cv2
import numpy as np
from numba import prange

from ..errors import RiverbedError
from ..runtime.kernel import kernel
from .kernels.lanes import LANES, lanes_find, lanes_sum, lanes_sum_wide, lanes_vote, lanes_vote_half
from .volume import band_pair_rows, band_pairs, volume_layout


@kernel(inline=True)
def _pick(s, si, D, o, d_min, subpixel):
    # winner index of the D costs at s[si:] and its disparity d_min + o + index, parabola-refined inside the range
    bi = 0
    bv = s[si]
    for i in range(1, D):
        if s[si + i] < bv:
            bv = s[si + i]
            bi = i
    return bi, _refine(s, si, D, bi, d_min + o, subpixel)


@kernel(inline=True)
def _refine(s, si, D, bi, d0, subpixel):
    # the disparity d0 + bi of winner bi (the first minimum of the D costs at s[si:], indexed from there: no array
    # view per pixel), parabola-refined inside the range
    val = np.float32(d0 + bi)
    if subpixel and bi > 0 and bi < D - 1:
        a = np.int64(s[si + bi - 1])
        bv = np.int64(s[si + bi])
        c = np.int64(s[si + bi + 1])
        den = a - 2 * bv + c
        if den > 0:
            val += np.float32(0.5 * (a - c) / den)
    return val


@kernel(inline=True)
def _vote_right(s, D, x, o, d_min, W, right_cost, right_best):
    # Right-image winner: min over d of S(y, xr + d, d), accumulated while scanning the row (as d - d_min).
    for i in range(D):
        xr = x - (d_min + o + i)
        if xr >= 0 and xr < W and s[i] < right_cost[xr]:
            right_cost[xr] = s[i]
            right_best[xr] = o + i


@kernel(inline=True)
def _lr_reject(disp_row, best_left, right_best, d_min, W, lr_threshold, mark_failures, status_row):
    # mark_failures: record the failure in status_row (1) and leave the disparity; else invalidate it
    for x in range(W):
        xr = x - (d_min + best_left[x])
        if xr < 0 or xr >= W or abs(best_left[x] - right_best[xr]) > lr_threshold:
            if mark_failures:
                status_row[x] = 1
            else:
                disp_row[x] = np.nan


@kernel(inline=True)
def _dense_row(fwd, bwd, y, W, D, d_min, subpixel, lr_check, lr_threshold, mark_failures, disp, status):
    # row y of a dense selection: fwd and bwd flat (pixel (y, x) at (y * W + x) * D), status (H, W or 1)
    s = np.empty(D, dtype=np.int32)
    best_left = np.empty(W, dtype=np.int64)
    right_cost = np.full(W, 2147483647, dtype=np.int64)
    right_best = np.zeros(W, dtype=np.int64)
    for x in range(W):
        b = (y * W + x) * D
        for i in range(D):
            s[i] = np.int32(fwd[b + i]) + np.int32(bwd[b + i])
        bi, disp[y, x] = _pick(s, 0, D, 0, d_min, subpixel)
        best_left[x] = bi
        if lr_check:
            _vote_right(s, D, x, 0, d_min, W, right_cost, right_best)
    if lr_check:
        _lr_reject(disp[y], best_left, right_best, d_min, W, lr_threshold, mark_failures, status[y])


@kernel(inline=True)
def _tube_winner(fwd, bwd, n, b, D, o, d_min, subpixel, s, si):
    # the summed costs of a pixel's tube (D disparities from d_min + o at b) into s[si:] and its winner: (index,
    # disparity). The sums and the winner come a chunk of LANES disparities at a time (the sums fit uint16:
    # sgm.check_sgm_bounds).
    span = (D + LANES - 1) // LANES * LANES
    if b + span <= n:  # every lane inside the volume
        if span == LANES:
            bi = lanes_find(s, si, lanes_sum(fwd, bwd, b, s, si, D))
        else:  # the winner found in registers as the sums go
            bi = lanes_sum_wide(fwd, bwd, b, s, si, D, span) & 0xFFFFFFFF
        return bi, _refine(s, si, D, bi, d_min + o, subpixel)
    for i in range(D):
        s[si + i] = fwd[b + i] + bwd[b + i]
    return _pick(s, si, D, o, d_min, subpixel)


@kernel(inline=True)
def _tube_row(fwd, bwd, y, start, width, offset, wmax, d_min, subpixel, disp):
    # row y of a tube selection without the left-right check: pixel (y, x) holds width[y, x] (<= wmax) disparities
    # from d_min + offset[y, x]
    n = fwd.shape[0]
    s = np.empty((wmax + LANES - 1) // LANES * LANES, dtype=np.uint16)
    for x in range(start.shape[1]):
        disp[y, x] = _tube_winner(fwd, bwd, n, start[y, x], np.int64(width[y, x]), np.int64(offset[y, x]), d_min,
                                  subpixel, s, 0)[1]


@kernel(inline=True)
def _tube_lr_row(fwd, bwd, y, start, width, offset, wmax, d_min, subpixel, lr_threshold, mark_failures, disp, status):
    # _tube_row with the left-right check. A row's sums are kept for the right image's votes, which go LANES
    # disparities at a time (lanes.lanes_vote), the pixels taken 0, 16, 32, ..., then 1, 17, ...: a pixel's votes
    # read and write the right pixels beside its row neighbour's, and read right after that neighbour's store they
    # waited for it (no store-to-load forwarding); LANES pixels apart they do not overlap. The lowest disparity wins
    # a tie, as in the scalar scan in row order: the same bits as _vote_right.
    W = start.shape[1]
    n = fwd.shape[0]
    span_max = (wmax + LANES - 1) // LANES * LANES
    rs = np.empty(W * span_max + LANES, dtype=np.uint16)  # the row's sums, pixel x at x * span_max
    best_left = np.empty(W, dtype=np.int64)  # winner as d - d_min
    reach = 0  # the row's largest disparity, as d - d_min + 1
    for x in range(W):
        D = np.int64(width[y, x])
        o = np.int64(offset[y, x])
        bi, disp[y, x] = _tube_winner(fwd, bwd, n, start[y, x], D, o, d_min, subpixel, rs, x * span_max)
        best_left[x] = o + bi
        reach = max(reach, o + D)
    # right pixels xr = x - d lie in [-(d_min + reach - 1), W - 1 - d_min]: padded so that every chunk's whole
    # vector lies inside
    pad = max(0, d_min + reach - 1) + LANES
    right_cost = np.full(pad + W + max(0, -d_min) + LANES, 2147483647, dtype=np.int32)
    right_best = np.zeros(right_cost.shape[0], dtype=np.int32)
    for x0 in range(LANES):
        for x in range(x0, W, LANES):
            D = np.int64(width[y, x])
            o = np.int64(offset[y, x])
            if D <= LANES // 2:  # most tubes: half the lanes
                xr0 = x - (d_min + o)
                lanes_vote_half(rs, x * span_max, D, right_cost, right_best, pad + xr0, xr0, W, o)
                continue
            for i in range(0, D, LANES):
                xr0 = x - (d_min + o + i)
                lanes_vote(rs, x * span_max + i, D - i, right_cost, right_best, pad + xr0, xr0, W, o + i)
    _lr_reject(disp[y], best_left, right_best[pad:], d_min, W, lr_threshold, mark_failures, status[y])


@kernel(inline=True)
def select_row(fwd, bwd, y, W, D, start, width, offset, wmax, d_min, subpixel, lr_check, lr_threshold, mark_failures,
               disp, status):
    """Row ``y`` of the disparity selection (:func:`select_disparity`) into ``disp`` and ``status``: the sums of
    the half-sums ``fwd`` and ``bwd`` (flat uint16), of a dense volume (``D > 0``: pixel ``(y, x)`` at ``(y * W +
    x) * D``) or a tube volume (``D == 0``, the layout's ``start``, ``width``, ``offset``, widest ``wmax``); the
    left-right check where ``lr_check``, marked in ``status`` where ``mark_failures`` (else NaN in ``disp``). Rows are
    independent: any thread may select any row once both half-sums hold it."""
    if D > 0:
        _dense_row(fwd, bwd, y, W, D, d_min, subpixel, lr_check, lr_threshold, mark_failures, disp, status)
    elif lr_check:
        _tube_lr_row(fwd, bwd, y, start, width, offset, wmax, d_min, subpixel, lr_threshold, mark_failures, disp,
                     status)
    else:
        _tube_row(fwd, bwd, y, start, width, offset, wmax, d_min, subpixel, disp)


@kernel(parallel=True)
def _select_kernel(fwd, bwd, H, W, D, start, width, offset, wmax, d_min, subpixel, lr_check, lr_threshold,
                   mark_failures):
    # every row's select_row, in parallel
    disp = np.empty((H, W), dtype=np.float32)
    status = np.zeros((H, W if mark_failures else 1), dtype=np.int8)  # mark_failures: 1 where the check fails
    m = band_pairs(H)
    for i in prange(m):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            select_row(fwd, bwd, y, W, D, start, width, offset, wmax, d_min, subpixel, lr_check, lr_threshold,
                       mark_failures, disp, status)
    return disp, status


def finish_selection(disp, status, lr_check, return_status):
    """:func:`select_disparity`'s result from the selection's ``disp`` and ``status``."""
    if not return_status:
        return disp
    if lr_check:
        disp[status > 0] = np.nan
    return disp, status


def select_disparity(aggregated, d_min, subpixel=True, lr_check=False, lr_threshold=1, aggregated2=None,
                     tubes=None, return_status=False):
    """Winner-takes-all disparity with optional sub-pixel fit and left-right consistency check.

    Parameters
    ----------
    aggregated : (H, W, D) uint16
        Aggregated cost; ``aggregated2`` (same shape), if given, is added to it on the fly (the two SGM half-sums).
    d_min : int
        Disparity at index 0.
    subpixel : bool
        Refine each winner by the vertex of the parabola through the costs at ``i - 1, i, i + 1`` (offset within
        +-0.5 px); winners at the ends of the range stay integer.
    lr_check : bool
        Mark pixels NaN whose integer disparity differs by more than ``lr_threshold`` px from the disparity the right
        image selects at ``x - d`` (right disparities taken from the same cost volume: min over d of S(x_r + d, d)).
    tubes : TubeLayout, optional
        Per-pixel tubes (:class:`~riverbed_cli.matching.volume.TubeLayout`; the volumes are flat): a right pixel's
        winner is taken over the left pixels whose tube holds the disparity.

    return_status : bool
        Check left-right consistency and return the outcome instead of invalidating: ``(disparity, status)`` with
        ``status`` (H, W) int8, 0 consistent, 1 failing (the disparity is kept). With ``lr_check`` as well, failing
        pixels are both marked and NaN.

    Returns
    -------
    (H, W) float32
        Disparity of the left image in pixels, NaN where the left-right check fails.
    """
    if aggregated2 is None:
        aggregated2 = np.zeros_like(aggregated)
    if aggregated.shape != aggregated2.shape:
        raise RiverbedError(f"cost volumes differ in shape: {aggregated.shape} vs {aggregated2.shape}")
    shape = tubes.shape if tubes is not None else aggregated.shape[:2]
    flat, W, D, start, width, offset = volume_layout(np.ascontiguousarray(aggregated), shape, tubes)
    wmax = int(tubes.max_width) if tubes is not None else D
    disp, status = _select_kernel(flat, np.ascontiguousarray(aggregated2).reshape(-1), shape[0], W, D, start, width,
                                  offset, wmax, int(d_min), bool(subpixel), bool(lr_check or return_status),
                                  int(lr_threshold), bool(return_status))
    return finish_selection(disp, status, lr_check, return_status)


@kernel(inline=True)
def _median_at(disp, y, x, r, buf):
    # NaN-aware median of the (2 r + 1)^2 window around (y, x), border replicated; NaN at a NaN pixel
    H, W = disp.shape
    if np.isnan(disp[y, x]):
        return np.float32(np.nan)
    n = 0
    for yy in range(y - r, y + r + 1):
        for xx in range(x - r, x + r + 1):
            # replicated border, as OpenCV's medianBlur
            v = disp[min(max(yy, 0), H - 1), min(max(xx, 0), W - 1)]
            if not np.isnan(v):
                buf[n] = v
                n += 1
    # insertion sort: n is at most a few dozen
    for i in range(1, n):
        v = buf[i]
        j = i - 1
        while j >= 0 and buf[j] > v:
            buf[j + 1] = buf[j]
            j -= 1
        buf[j + 1] = v
    if n % 2 == 1:
        return buf[n // 2]
    return np.float32(0.5) * (buf[n // 2 - 1] + buf[n // 2])


@kernel(parallel=True)
def median_kernel(disp, r):
    """NaN-aware median of ``disp`` over ``(2 r + 1)^2`` windows, border replicated (:func:`median_filter`)."""
    H, W = disp.shape
    out = np.empty_like(disp)
    for y in prange(H):
        buf = np.empty((2 * r + 1) * (2 * r + 1), dtype=np.float32)
        for x in range(W):
            out[y, x] = _median_at(disp, y, x, r, buf)
    return out


@kernel(parallel=True)
def _median_where(disp, r, where, out):
    # median_kernel's value at the pixels where `where` is set, into out
    H, W = disp.shape
    for y in prange(H):
        buf = np.empty((2 * r + 1) * (2 * r + 1), dtype=np.float32)
        for x in range(W):
            if where[y, x]:
                out[y, x] = _median_at(disp, y, x, r, buf)


def median_filter(disp, size=3):
    """Median filter of a disparity map over a ``size x size`` window, ignoring NaN neighbours.

    Invalid (NaN) pixels stay invalid; the border is replicated (as OpenCV's ``medianBlur``, which does the work
    when the map has no NaN and ``size`` is 3 or 5). ``size`` <= 1 returns a copy.
    """
    size = int(size)
    if size <= 1:
        return disp.copy()
    if size % 2 == 0:
        raise RiverbedError(f"median size must be odd, got {size}")
    disp = np.ascontiguousarray(disp, dtype=np.float32)
    if size not in (3, 5):
        return median_kernel(disp, size // 2)
    out = cv2.medianBlur(disp, size)
    nan = np.isnan(disp)
    if nan.any():
        # OpenCV's median is exact in every window without a NaN (its sorting network is not NaN-aware); the windows
        # that hold one - the NaN mask dilated by the window, replicated borders included - get the NaN-aware median:
        # after a left-right check (13-30 % NaN on the speed pair) 2.8-7x faster than the kernel over every pixel
        near = cv2.dilate(nan.view(np.uint8), np.ones((size, size), np.uint8))
        _median_where(disp, size // 2, near, out)
    return out
