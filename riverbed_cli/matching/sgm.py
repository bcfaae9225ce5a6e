"""Aggregation: Semi-Global Matching (Hirschmueller 2008) over 4, 8 or 16 paths.

Each path cost follows ``L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d+-1) + P1, min_k L_r(p-r, k) + P2)
- min_k L_r(p-r, k)``, starting with ``L_r = C`` at the first pixel of every path. The aggregated cost is the sum over
paths. Costs and sums stay in ``uint16``.

Implementation: half of the directions are swept in one raster-order pass (top-left to bottom-right), the other half in
the reverse pass; each pass keeps the path costs of the last rows in a small ring buffer, so the cost volume is read
once per pass and the inner loop over disparities vectorises. The two passes are independent and run in parallel.
"""

import numpy as np
from numba import njit, prange

from ..errors import RiverbedError

# Directions (dx, dy) swept in the forward raster pass; the reverse pass sweeps their opposites.
_FORWARD_DIRS = {
    4: [(1, 0), (0, 1)],
    8: [(1, 0), (0, 1), (1, 1), (-1, 1)],
    16: [(1, 0), (0, 1), (1, 1), (-1, 1), (2, 1), (-2, 1), (1, 2), (-1, 2)],
}

def path_directions(paths):
    """All ``paths`` directions ``(dx, dy)`` (each path runs from ``p - r`` to ``p``)."""
    if paths not in _FORWARD_DIRS:
        raise RiverbedError(f"--paths must be 4, 8 or 16, not {paths}")
    fwd = _FORWARD_DIRS[paths]
    return fwd + [(-dx, -dy) for dx, dy in fwd]


# Path costs live in int16 (16 SIMD lanes): every path cost is at most max_cost + P2, and check_sgm_bounds keeps
# paths * (max_cost + P2) <= 65535, so a path cost is <= 16383 and each half-sum (half the paths) <= 32767.
_SENTINEL = 16384  # above any path cost; sentinel + P1 still fits int16


@njit(cache=True, boundscheck=False)
def _path_step(prev, cur, c, acc, P1, jump, mp):
    # One SGM step along a path for all disparities; prev/cur are padded by a sentinel at both ends.
    m = np.int16(_SENTINEL)
    for d in range(c.shape[0]):
        v = min(prev[d + 1], min(prev[d], prev[d + 2]) + P1)
        v = np.int16(c[d] + min(v, jump) - mp)
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    return m


@njit(cache=True, boundscheck=False)
def path_start(cur, c, acc):
    m = np.int16(_SENTINEL)
    for d in range(c.shape[0]):
        v = np.int16(c[d])
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    return m


@njit(cache=True)
def _sgm_pass(cost, out, dxs, dys, P1, P2, flip):
    H, W, D = cost.shape
    nd = dxs.shape[0]
    P1 = np.int16(P1)
    P2 = np.int16(P2)
    # Ring buffer of the last three rows of path costs (16-path directions reach two rows back).
    L = np.full((nd, 3, W, D + 2), np.int16(_SENTINEL), dtype=np.int16)
    Lmin = np.zeros((nd, 3, W), dtype=np.int16)
    for yy in range(H):
        y = H - 1 - yy if flip else yy
        slot = yy % 3
        for xx in range(W):
            x = W - 1 - xx if flip else xx
            c = cost[y, x]
            acc = out[y, x]  # the half-sum accumulates in place (int16 view: it stays <= 32767)
            acc[:] = 0
            for k in range(nd):
                px = xx - dxs[k]
                py = yy - dys[k]
                if px < 0 or px >= W or py < 0:
                    m = path_start(L[k, slot, xx], c, acc)
                else:
                    mp = Lmin[k, py % 3, px]
                    m = _path_step(L[k, py % 3, px], L[k, slot, xx], c, acc, P1, np.int16(mp + P2), mp)
                Lmin[k, slot, xx] = m


@njit(cache=True, boundscheck=False, inline="always")
def tube_value(prev, wq, j, P1):
    # min(L(j), L(j -+ 1) + P1) of the previous pixel's tube (wq wide) at its index j; outside it: the sentinel
    sent = np.int16(_SENTINEL)
    a = prev[j + 1] if 0 <= j < wq else sent
    b = prev[j] if 1 <= j <= wq else sent
    e = prev[j + 2] if -1 <= j < wq - 1 else sent
    return min(a, min(b, e) + P1)


@njit(cache=True, boundscheck=False)
def _tube_step(prev, wq, cur, c, acc, P1, jump, mp, s):
    # One step between tubes: disparity index d here is index d + s of the previous pixel's tube (wq wide); a
    # disparity outside that tube is unreachable there (the sentinel), not zero. prev is padded (prev[0] and
    # prev[wq + 1] hold the sentinel), so where d + s and its neighbours lie in [-1, wq] no check is needed.
    w = c.shape[0]
    m = np.int16(_SENTINEL)
    lo = min(w, max(0, -s))
    hi = max(lo, min(w, wq - s))
    for d in range(lo):
        v = np.int16(c[d] + min(tube_value(prev, wq, d + s, P1), jump) - mp)
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    for d in range(lo, hi):  # the overlap: as _path_step, shifted
        v = min(prev[d + s + 1], min(prev[d + s], prev[d + s + 2]) + P1)
        v = np.int16(c[d] + min(v, jump) - mp)
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    for d in range(hi, w):
        v = np.int16(c[d] + min(tube_value(prev, wq, d + s, P1), jump) - mp)
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    cur[w + 1] = np.int16(_SENTINEL)
    return m


@njit(cache=True)
def _sgm_pass_tube(flat, out, start, width, offset, dmax, dxs, dys, P1, P2, flip):
    # _sgm_pass on a tube volume: pixel (y, x) holds width[y, x] disparities from d_min + offset[y, x] at
    # flat[start[y, x]:] (and out, int16, at the same place); ring-buffer rows are dmax + 2 wide, a pixel uses its
    # first width + 2.
    H, W = start.shape
    nd = dxs.shape[0]
    P1 = np.int16(P1)
    P2 = np.int16(P2)
    sent = np.int16(_SENTINEL)
    L = np.full((nd, 3, W, dmax + 2), sent, dtype=np.int16)
    Lmin = np.zeros((nd, 3, W), dtype=np.int16)
    for yy in range(H):
        y = H - 1 - yy if flip else yy
        slot = yy % 3
        for xx in range(W):
            x = W - 1 - xx if flip else xx
            b = start[y, x]
            w = np.int64(width[y, x])
            op = np.int64(offset[y, x])
            c = flat[b:b + w]
            acc = out[b:b + w]  # the half-sum accumulates in place (int16 view: it stays <= 32767)
            acc[:] = 0
            for k in range(nd):
                px = xx - dxs[k]
                py = yy - dys[k]
                cur = L[k, slot, xx]
                if px < 0 or px >= W or py < 0:
                    m = path_start(cur, c, acc)
                    cur[w + 1] = sent
                else:
                    qy = H - 1 - py if flip else py
                    qx = W - 1 - px if flip else px
                    wq = np.int64(width[qy, qx])
                    sh = op - np.int64(offset[qy, qx])
                    mp = Lmin[k, py % 3, px]
                    prev = L[k, py % 3, px]
                    if sh == 0 and wq >= w:
                        m = _path_step(prev, cur, c, acc, P1, np.int16(mp + P2), mp)
                        cur[w + 1] = sent
                    else:
                        m = _tube_step(prev, wq, cur, c, acc, P1, np.int16(mp + P2), mp, sh)
                Lmin[k, slot, xx] = m


@njit(cache=True, parallel=True)
def _sgm_two_passes_tube(flat, fwd, bwd, start, width, offset, dmax, dxs, dys, P1, P2):
    for t in prange(2):
        if t == 0:
            _sgm_pass_tube(flat, fwd, start, width, offset, dmax, dxs, dys, P1, P2, False)
        else:
            _sgm_pass_tube(flat, bwd, start, width, offset, dmax, dxs, dys, P1, P2, True)


@njit(cache=True, parallel=True)
def _sgm_two_passes(cost, fwd, bwd, dxs, dys, P1, P2):
    for t in prange(2):
        if t == 0:
            _sgm_pass(cost, fwd, dxs, dys, P1, P2, False)
        else:
            _sgm_pass(cost, bwd, dxs, dys, P1, P2, True)


@njit(cache=True, parallel=True)
def _add_inplace(a, b):
    H = a.shape[0]
    for y in prange(H):
        ay = a[y]
        by = b[y]
        for x in range(ay.shape[0]):
            for d in range(ay.shape[1]):
                ay[x, d] = ay[x, d] + by[x, d]


def check_sgm_bounds(max_cost, p2, paths):
    """Raise if the summed path costs could overflow uint16 (each path cost is at most ``max_cost + P2``)."""
    bound = paths * (int(max_cost) + int(p2))
    if bound > 65535 or int(p2) >= 16384:
        raise RiverbedError(
            f"SGM sums could reach {bound} > 65535 with {paths} paths, max cost {max_cost} and P2 {p2}; "
            "lower P2 or the number of paths"
        )


def sgm_aggregate_passes(cost, p1, p2, paths=8, max_cost=None, tubes=None):
    """Forward and reverse half-sums of the path costs, ``(S_forward, S_reverse)``, both ``uint16 (H, W, D)``.

    Their sum is the aggregated cost; keeping them apart lets disparity selection fuse the addition.
    ``max_cost`` is a known upper bound of ``cost`` (spares a pass over the volume to find it). With ``tubes`` (a
    :class:`~riverbed_cli.matching.volume.TubeLayout`; ``cost`` and the results are flat tube volumes) the
    recurrence compares equal disparities of neighbours, and a disparity outside a neighbour's tube is unreachable
    there.
    """
    if (cost.ndim != (1 if tubes is not None else 3)) or cost.dtype not in (np.uint8, np.uint16):
        raise RiverbedError(f"cost volume must be uint8 or uint16 (H, W, D), got {cost.dtype} {cost.shape}")
    p1, p2 = int(p1), int(p2)
    if p1 < 0 or p2 < p1:
        raise RiverbedError(f"SGM penalties need 0 <= P1 <= P2 (got P1={p1}, P2={p2})")
    fwd_dirs = path_directions(paths)[: paths // 2]
    if max_cost is None:
        max_cost = int(cost.max()) if cost.size else 0
    check_sgm_bounds(max_cost, p2, paths)
    cost = np.ascontiguousarray(cost)
    dxs = np.array([d[0] for d in fwd_dirs], dtype=np.int64)
    dys = np.array([d[1] for d in fwd_dirs], dtype=np.int64)
    fwd = np.empty(cost.shape, dtype=np.uint16)
    bwd = np.empty(cost.shape, dtype=np.uint16)
    # the passes add path costs into int16 views of the uint16 results (a half-sum is <= 32767: the same bits)
    if tubes is None:
        _sgm_two_passes(cost, fwd.view(np.int16), bwd.view(np.int16), dxs, dys, np.int32(p1), np.int32(p2))
    else:
        if cost.size != tubes.size:
            raise RiverbedError(f"tube volume of {cost.size} costs does not match its layout ({tubes.size})")
        _sgm_two_passes_tube(cost, fwd.view(np.int16), bwd.view(np.int16), tubes.start, tubes.width, tubes.offset,
                             int(tubes.max_width), dxs, dys, np.int32(p1), np.int32(p2))
    return fwd, bwd


def sgm_aggregate(cost, p1, p2, paths=8):
    """Semi-Global Matching aggregation.

    Parameters
    ----------
    cost : (H, W, D) uint8 or uint16
        Matching cost volume (disparity innermost).
    p1, p2 : int
        Penalties for a disparity change of one, and of more than one, between neighbours along a path
        (in the units of ``cost``), ``0 <= p1 <= p2``.
    paths : {4, 8, 16}
        Number of path directions.

    Returns
    -------
    (H, W, D) uint16
        Sum over all paths of the path costs ``L_r``.
    """
    fwd, bwd = sgm_aggregate_passes(cost, p1, p2, paths)
    _add_inplace(fwd, bwd)
    return fwd
