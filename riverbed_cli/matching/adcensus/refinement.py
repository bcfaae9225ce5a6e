"""AD-Census stage 6, selection and multi-step refinement (:func:`refine`).

Left-right check (right disparities taken from the same volume, ``min_d S(x_r + d, d)``; outliers differing by more
than ``lr_threshold``) with outliers split into *mismatches* (some right pixel on the epipolar line maps back to
``p``, or the match leaves the right image: *out of view*, nothing there to be occluded behind) and *occlusions* (none
does); iterative region voting (5 iterations; an outlier takes the most voted reliable disparity of its support region
if more than ``vote_ts = 20`` reliable pixels vote and the winner has more than ``vote_th = 0.4`` of the votes; updates
of one iteration are applied together, so the result does not depend on the pixel order); proper interpolation (the
nearest reliable pixel in each of 16 directions; occlusions take the smallest of those disparities, mismatches the one
of the most similar colour); depth-discontinuity adjustment (on disparity edges, the left or right neighbour's
disparity when that neighbour's own cost is lower); parabola sub-pixel fit. (The 3 x 3 median filter follows in
:func:`adcensus_disparity`.)

With guidance, a winner inside the disparity interval the guide vouches for (riverbed's band at its homogeneous
pixels, the LiDAR disparity for Gauss, ...; ``support`` of :func:`refine`) counts as reliable: occluded pixels and
pixels whose match leaves the right image fail the left-right check by construction, and without this rule the
refinement overwrites exactly the disparities LiDAR fixed (measured in docs/riverbed_plus.md).
"""

import math
import time

import numpy as np
from numba import prange

from ...runtime.kernel import kernel
from .cost import u8_image
from .params import ADCensusParams


@kernel(inline=True)
def _lr_status_row(best, rbest, d_min, pad, lr_threshold, status):
    # One row's left-right outcome from the left winners (indices d - d_min) and the right ones (rbest, reversed
    # and padded): 0 consistent, 1 mismatch, 2 occlusion.
    W = best.shape[0]
    # back[x]: some right pixel's winner maps back to left pixel x (the epipolar line meets D_R)
    back = np.zeros(W, dtype=np.bool_)
    for xr in range(W):
        rbv = rbest[W - 1 - xr + pad]
        if rbv >= 0:
            back[xr + d_min + rbv] = True
    for x in range(W):
        bi = best[x]
        xr = x - (d_min + bi)
        if xr < 0 or xr >= W:
            # out of view: no right pixel to be occluded behind; filled like a mismatch (by colour), not with
            # the smallest neighbouring disparity (measured: AD-Census dev bad3 7.99 -> 7.17 %)
            status[x] = 1
        elif abs(bi - rbest[W - 1 - xr + pad]) > lr_threshold:
            status[x] = 1 if back[x] else 2


@kernel(parallel=True)
def wta_lr_kernel(fwd, bwd, d_min, lr_threshold):
    # Winner index of the left image, and status: 0 reliable, 1 mismatch, 2 occlusion.
    H, W, D = fwd.shape
    best = np.empty((H, W), dtype=np.int32)
    status = np.zeros((H, W), dtype=np.int8)
    pad = D + abs(d_min) + 1
    n = W + 2 * pad
    for y in prange(H):
        s = np.empty(D, dtype=np.int32)
        # right-image winner min_i S(x_r + d_min + i, i), kept reversed and padded (x_r at W - 1 - x_r + pad), so
        # the disparities of one left pixel update a contiguous slice; strict < keeps the smallest i on ties.
        rcost = np.full(n, 2147483647, dtype=np.int32)
        rbest = np.full(n, -1, dtype=np.int32)
        fy = fwd[y]
        by = bwd[y]
        for x in range(W):
            fx = fy[x]
            bx = by[x]
            bv = np.int32(2147483647)
            for i in range(D):
                v = np.int32(fx[i]) + np.int32(bx[i])
                s[i] = v
                bv = min(bv, v)
            bi = 0
            while s[bi] != bv:
                bi += 1
            best[y, x] = bi
            j0 = W - 1 - (x - d_min) + pad
            rc = rcost[j0:j0 + D]
            rb = rbest[j0:j0 + D]
            for i in range(D):
                v = s[i]
                o = rc[i]
                better = v < o
                rc[i] = v if better else o
                rb[i] = np.int32(i) if better else rb[i]
        _lr_status_row(best[y], rbest, d_min, pad, lr_threshold, status[y])
    return best, status


@kernel(parallel=True)
def wta_lr_tube_kernel(fwd, bwd, d_min, lr_threshold, start, width, offset, n_disp):
    # wta_lr_kernel on a tube volume: winners as indices d - d_min over the nominal n_disp disparities; a right
    # pixel's winner is taken over the left pixels whose tube holds the disparity.
    H, W = start.shape
    best = np.empty((H, W), dtype=np.int32)
    status = np.zeros((H, W), dtype=np.int8)
    pad = n_disp + abs(d_min) + 1
    n = W + 2 * pad
    dmax = 1
    for y in range(H):
        for x in range(W):
            dmax = max(dmax, np.int64(width[y, x]))
    for y in prange(H):
        s = np.empty(dmax, dtype=np.int32)
        rcost = np.full(n, 2147483647, dtype=np.int32)
        rbest = np.full(n, -1, dtype=np.int32)
        for x in range(W):
            b = start[y, x]
            D = np.int64(width[y, x])
            o = np.int64(offset[y, x])
            bv = np.int32(2147483647)
            for i in range(D):
                v = np.int32(fwd[b + i]) + np.int32(bwd[b + i])
                s[i] = v
                bv = min(bv, v)
            bi = 0
            while s[bi] != bv:
                bi += 1
            best[y, x] = o + bi
            j0 = W - 1 - (x - d_min) + pad + o
            rc = rcost[j0:j0 + D]
            rb = rbest[j0:j0 + D]
            for i in range(D):
                v = s[i]
                better = v < rc[i]
                rc[i] = v if better else rc[i]
                rb[i] = np.int32(o + i) if better else rb[i]
        _lr_status_row(best[y], rbest, d_min, pad, lr_threshold, status[y])
    return best, status


@kernel(inline=True)
def _vote_row(hist, votes, arms, yy, x, sign):
    # add (sign 1) or remove (sign -1) the votes of row yy's horizontal segment through column x
    row = votes[yy, x - np.int64(arms[yy, x, 0]):x + np.int64(arms[yy, x, 1]) + 1]
    for k in range(row.shape[0]):
        hist[row[k]] += sign


@kernel
def _vote_column(votes, arms, D, ts, th, new_votes, x, hist):
    # Region voting down column x (Jacobi: every outlier votes with the reliable pixels of the iteration's start).
    # The support region of (y, x) is the union of the horizontal segments of the rows of its vertical arm, so
    # walking down the column the histogram is updated by the rows entering and leaving the arm instead of being
    # rebuilt for every outlier. votes = winner + 1 at reliable pixels, 0 at outliers (bin 0 collects them).
    H = votes.shape[0]
    hist[:] = 0
    changed = 0
    a = 0
    b = -1  # rows a..b are in the histogram (empty when b < a)
    for y in range(H):
        new_votes[y, x] = votes[y, x]
        if votes[y, x] != 0:
            continue
        na = y - np.int64(arms[y, x, 2])
        nb = y + np.int64(arms[y, x, 3])
        if b < a or na > b or nb < a:
            for yy in range(a, b + 1):
                _vote_row(hist, votes, arms, yy, x, -1)
            for yy in range(na, nb + 1):
                _vote_row(hist, votes, arms, yy, x, 1)
        else:
            for yy in range(na, a):
                _vote_row(hist, votes, arms, yy, x, 1)
            for yy in range(a, na):
                _vote_row(hist, votes, arms, yy, x, -1)
            for yy in range(b + 1, nb + 1):
                _vote_row(hist, votes, arms, yy, x, 1)
            for yy in range(nb + 1, b + 1):
                _vote_row(hist, votes, arms, yy, x, -1)
        a = na
        b = nb
        n = 0
        bi = 0
        bc = 0
        for i in range(1, D + 1):
            h = hist[i]
            n += h
            if h > bc:
                bc = h
                bi = i
        if n > ts and bc > th * n:
            new_votes[y, x] = bi
            changed += 1
    return changed


@kernel(parallel=True)
def _vote_kernel(votes, arms, D, ts, th, new_votes):
    W = votes.shape[1]
    changed = np.zeros(W, dtype=np.int64)
    for x in prange(W):
        changed[x] = _vote_column(votes, arms, D, ts, th, new_votes, x, np.empty(D + 1, dtype=np.int32))
    return changed.sum()


@kernel
def _vote_kernel_serial(votes, arms, D, ts, th, new_votes):
    hist = np.empty(D + 1, dtype=np.int32)
    changed = 0
    for x in range(votes.shape[1]):
        changed += _vote_column(votes, arms, D, ts, th, new_votes, x, hist)
    return changed


def region_voting(best, status, arms, D, iterations=5, ts=20, th=0.4):
    """Iterative region voting (stage 6); returns new ``(best, status)`` (outliers that won a vote become 0)."""
    votes = np.where(status == 0, best + 1, 0).astype(np.int32)
    spare = np.empty_like(votes)
    for it in range(int(iterations)):
        # later iterations see few outliers: run them on one thread (no parallel region to synchronise)
        kernel = _vote_kernel if it == 0 else _vote_kernel_serial
        changed = kernel(votes, arms, int(D), int(ts), float(th), spare)
        votes, spare = spare, votes
        if changed == 0:
            break
    won = (status > 0) & (votes > 0)
    best = np.where(won, votes - 1, best).astype(best.dtype)
    status = np.where(won, np.int8(0), status).astype(status.dtype)
    return best, status


_ANGLES = np.arange(16) * (np.pi / 8)
_DIR_COS = np.cos(_ANGLES)
_DIR_SIN = np.sin(_ANGLES)


@kernel(parallel=True)
def _interp_kernel(best, status, img, reach, dcos, dsin):
    H, W = best.shape
    out = best.copy()
    for y in prange(H):
        for x in range(W):
            st = status[y, x]
            if st == 0:
                continue
            found = -1
            score = 1 << 30
            for k in range(16):
                for m in range(1, reach + 1):
                    yy = y + np.int64(math.floor(m * dsin[k] + 0.5))
                    xx = x + np.int64(math.floor(m * dcos[k] + 0.5))
                    if yy < 0 or yy >= H or xx < 0 or xx >= W:
                        break
                    if status[yy, xx] == 0:
                        b = best[yy, xx]
                        if st == 2:
                            sc = b  # occlusion: the smallest disparity (background)
                        else:
                            sc = 0  # mismatch: the most similar colour
                            for ch in range(img.shape[2]):
                                sc += abs(np.int32(img[y, x, ch]) - np.int32(img[yy, xx, ch]))
                        if sc < score:
                            score = sc
                            found = b
                        break
            if found >= 0:
                out[y, x] = found
    return out


@kernel(inline=True)
def _adjusted(best, fwd, bwd, y, x, threshold):
    # Depth-discontinuity adjustment at (y, x): on a disparity edge (Sobel |gx| + |gy| > threshold), the left or
    # right neighbour's disparity when that neighbour's own optimised cost is lower.
    H, W = best.shape
    b = best[y, x]
    if y == 0 or y == H - 1 or x == 0 or x == W - 1:
        return b
    gx = (best[y - 1, x + 1] - best[y - 1, x - 1]) + 2 * (best[y, x + 1] - best[y, x - 1]) + \
         (best[y + 1, x + 1] - best[y + 1, x - 1])
    gy = (best[y + 1, x - 1] - best[y - 1, x - 1]) + 2 * (best[y + 1, x] - best[y - 1, x]) + \
         (best[y + 1, x + 1] - best[y - 1, x + 1])
    if abs(gx) + abs(gy) <= threshold:
        return b
    out = b
    c0 = np.int32(fwd[y, x, b]) + np.int32(bwd[y, x, b])
    for xn in (x - 1, x + 1):
        bn = best[y, xn]
        cn = np.int32(fwd[y, xn, bn]) + np.int32(bwd[y, xn, bn])
        if cn < c0:
            c0 = cn
            out = bn
    return out


@kernel(parallel=True)
def _final_kernel(best, fwd, bwd, d_min, adjust, threshold, subpixel):
    # discontinuity adjustment (optional) and parabola sub-pixel fit on the optimised cost, in one pass
    H, W = best.shape
    D = fwd.shape[2]
    disp = np.empty((H, W), dtype=np.float32)
    for y in prange(H):
        for x in range(W):
            b = _adjusted(best, fwd, bwd, y, x, threshold) if adjust else best[y, x]
            val = np.float32(d_min + b)
            if subpixel and b > 0 and b < D - 1:
                a = np.int32(fwd[y, x, b - 1]) + np.int32(bwd[y, x, b - 1])
                m = np.int32(fwd[y, x, b]) + np.int32(bwd[y, x, b])
                c = np.int32(fwd[y, x, b + 1]) + np.int32(bwd[y, x, b + 1])
                den = a - 2 * m + c
                if den > 0 and m <= a and m <= c:
                    val += np.float32(0.5 * (a - c) / den)
            disp[y, x] = val
    return disp


_UNREACHABLE = 2147483647  # the optimised cost of a disparity outside a pixel's tube


@kernel(inline=True)
def _tube_cost(fwd, bwd, start, width, offset, y, x, k):
    # optimised cost of absolute disparity index k at (y, x); unreachable outside the pixel's tube
    i = np.int64(k) - np.int64(offset[y, x])
    if i < 0 or i >= width[y, x]:
        return np.int32(_UNREACHABLE)
    b = start[y, x] + i
    return np.int32(fwd[b]) + np.int32(bwd[b])


@kernel(parallel=True)
def _final_tube_kernel(best, fwd, bwd, d_min, adjust, threshold, subpixel, start, width, offset):
    # _final_kernel on a tube volume: a cost outside a pixel's tube is unreachable (no swap towards it, any
    # reachable neighbour beats it; no sub-pixel fit unless both neighbours of the winner are in the tube)
    H, W = best.shape
    disp = np.empty((H, W), dtype=np.float32)
    for y in prange(H):
        for x in range(W):
            b = best[y, x]
            if adjust and 0 < y < H - 1 and 0 < x < W - 1:
                gx = (best[y - 1, x + 1] - best[y - 1, x - 1]) + 2 * (best[y, x + 1] - best[y, x - 1]) + \
                     (best[y + 1, x + 1] - best[y + 1, x - 1])
                gy = (best[y + 1, x - 1] - best[y - 1, x - 1]) + 2 * (best[y + 1, x] - best[y - 1, x]) + \
                     (best[y + 1, x + 1] - best[y - 1, x + 1])
                if abs(gx) + abs(gy) > threshold:
                    c0 = _tube_cost(fwd, bwd, start, width, offset, y, x, b)
                    out = b
                    for xn in (x - 1, x + 1):
                        bn = best[y, xn]
                        cn = _tube_cost(fwd, bwd, start, width, offset, y, xn, bn)
                        if cn < c0:
                            c0 = cn
                            out = bn
                    b = out
            val = np.float32(d_min + b)
            if subpixel:
                i = np.int64(b) - np.int64(offset[y, x])
                if 0 < i < width[y, x] - 1:
                    k = start[y, x] + i
                    a = np.int32(fwd[k - 1]) + np.int32(bwd[k - 1])
                    m = np.int32(fwd[k]) + np.int32(bwd[k])
                    c = np.int32(fwd[k + 1]) + np.int32(bwd[k + 1])
                    den = a - 2 * m + c
                    if den > 0 and m <= a and m <= c:
                        val += np.float32(0.5 * (a - c) / den)
            disp[y, x] = val
    return disp


def refine(fwd, bwd, d_min, img, arms, params=None, subpixel=True, return_status=False, support=None,
           tubes=None, n_disp=None):
    """Multi-step refinement (module docstring) of the optimised cost ``fwd + bwd``.

    ``support`` (optional ``(lo, hi)`` float maps, NaN where none) is the disparity interval that LiDAR guidance
    vouches for at each pixel; a winner within it (``+- lr_threshold``) counts as reliable even when the left-right
    check fails -- occluded pixels and pixels whose match leaves the right image fail that check by construction,
    and guidance is the only evidence they have.

    Returns
    -------
    disparity : (H, W) float32
        Dense, before the median filter (an outlier with no reliable pixel in any of the 16 directions keeps its
        winner-takes-all disparity; with ``interpolate=False`` the outliers left after voting do too).
    info : dict
        Pixel counts: ``outliers`` (left-right check), ``occlusions`` (among them), ``after_voting``; with
        ``return_status`` also ``status``, the (H, W) int8 left-right outcome (0 consistent, 1 mismatch, 2 occlusion).
    """
    p = params or ADCensusParams()
    t = {}
    t0 = time.perf_counter()
    if tubes is not None:
        D = int(n_disp)
        best, status = wta_lr_tube_kernel(fwd, bwd, int(d_min), int(p.lr_threshold), tubes.start, tubes.width,
                                          tubes.offset, D)
    else:
        D = fwd.shape[2]
        best, status = wta_lr_kernel(fwd, bwd, int(d_min), int(p.lr_threshold))
    info = {"outliers": int((status > 0).sum()), "occlusions": int((status == 2).sum())}
    if support is not None:
        lo, hi = support
        d = best + int(d_min)
        with np.errstate(invalid="ignore"):
            vouched = (status > 0) & (d >= lo - p.lr_threshold) & (d <= hi + p.lr_threshold)
        status[vouched] = 0
        info["vouched"] = int(vouched.sum())
    t["left_right"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if return_status:
        info["status"] = status.copy()
    if p.vote_iterations > 0:
        best, status = region_voting(best, status, arms, D, p.vote_iterations, p.vote_ts, p.vote_th)
    info["after_voting"] = int((status > 0).sum())
    t["voting"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if p.interpolate:
        best = _interp_kernel(best, status, u8_image(img, "left"), max(best.shape), _DIR_COS, _DIR_SIN)
    if tubes is not None:
        disp = _final_tube_kernel(best, fwd, bwd, int(d_min), bool(p.discontinuity), float(p.edge_threshold),
                                  bool(subpixel), tubes.start, tubes.width, tubes.offset)
    else:
        disp = _final_kernel(best, fwd, bwd, int(d_min), bool(p.discontinuity), float(p.edge_threshold),
                             bool(subpixel))
    t["interpolation_subpixel"] = time.perf_counter() - t0
    info["seconds"] = {k: round(v, 4) for k, v in t.items()}
    return disp, info
