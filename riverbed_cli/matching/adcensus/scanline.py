"""AD-Census stage 5, scanline optimisation (:func:`scanline_optimize`).

4 paths (left/right/up/down) of the SGM recursion with penalties from colour differences along the path,
``D1 = D_c(p, p - r)`` in the left image and ``D2 = D_c(p - d, p - d - r)`` in the right: ``(P1, P2) = (Pi1, Pi2)`` if
both are below ``tau_so``, divided by 4 if one is, by 10 if neither (paper: ``Pi1 = 1.0, Pi2 = 3.0, tau_so = 15``;
``D2 = D1`` where the right pixels leave the image). The result is the *sum* of the four paths (the paper's mean
times 4: same minimum, same sub-pixel vertex).
"""

import numpy as np
from numba import get_num_threads, prange

from ...errors import RiverbedError
from ...runtime.kernel import kernel
from ..kernels.row_handover import block_end, block_size, new_progress, next_row, pass_threads, publish
from ..sgm_pass import path_start, tube_value
from .cost import u8_image

_SENTINEL = 16384


@kernel(inline=True)
def _colour_dist(img, y0, x0, y1, x1):
    m = 0
    for ch in range(img.shape[2]):
        v = abs(np.int32(img[y0, x0, ch]) - np.int32(img[y1, x1, ch]))
        if v > m:
            m = v
    return m


@kernel(inline=True)
def _so_step(prev, cur, c, acc, p1, p2, mp):
    m = np.int16(_SENTINEL)
    for d in range(c.shape[0]):
        v = min(prev[d + 1], min(prev[d], prev[d + 2]) + p1[d])
        v = min(v, mp + p2[d])
        v = np.int16(c[d] + v - mp)
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    return m


_so_start = path_start  # a path starts with its own cost, as in SGM


@kernel(inline=True)
def _row_penalties(flags, bad_l, p1tab, p2tab, P1, P2, pad):
    # P1/P2 along a reversed, padded row of right-image flags (0: colour difference < tau_so, 1: >= tau_so,
    # 2: unknown, the right pixel or its predecessor leaves the image, then D2 = D1), for a left flag bad_l.
    # Reversed, so that the D disparities of a pixel read a contiguous slice (disparity d at x reads x - d).
    W = flags.shape[0]
    for j in range(P1.shape[0]):
        xr = W - 1 - (j - pad)
        f = flags[xr] if (xr >= 0 and xr < W) else np.int8(2)
        cat = bad_l + (bad_l if f == 2 else f)
        P1[j] = p1tab[cat]
        P2[j] = p2tab[cat]


@kernel(inline=True)
def _row_edges(left, right, y, py, first, step, tau, p1tab, p2tab, P1, P2, pad, fh, fv, bh, bv):
    # Row y's colour edges towards the previous pixel of each path (horizontal: the column before in pass order;
    # vertical: row py; 2 where a path starts) in the right (fh, fv) and left (bh, bv) images, and the penalty
    # rows they select: P1/P2[path (0 horizontal, 1 vertical), left flag].
    W = fh.shape[0]
    for x in range(W):
        qx = x - step
        if qx < 0 or qx >= W:
            fh[x] = 2
            bh[x] = 0
        else:
            fh[x] = 1 if _colour_dist(right, y, x, y, qx) >= tau else 0
            bh[x] = 1 if _colour_dist(left, y, x, y, qx) >= tau else 0
        if first:
            fv[x] = 2
            bv[x] = 0
        else:
            fv[x] = 1 if _colour_dist(right, y, x, py, x) >= tau else 0
            bv[x] = 1 if _colour_dist(left, y, x, py, x) >= tau else 0
    for b in range(2):
        _row_penalties(fh, b, p1tab, p2tab, P1[0, b], P2[0, b], pad)
        _row_penalties(fv, b, p1tab, p2tab, P1[1, b], P2[1, b], pad)


@kernel(inline=True)
def _row_scratch(W, n):
    # a thread's rows of penalties, [path (0 horizontal, 1 vertical), left flag (0/1)] -> reversed padded penalty
    # rows of n, and of colour-edge flags (_row_edges)
    return (np.empty((2, 2, n), dtype=np.int16), np.empty((2, 2, n), dtype=np.int16), np.empty(W, dtype=np.int8),
            np.empty(W, dtype=np.int8), np.empty(W, dtype=np.int8), np.empty(W, dtype=np.int8))


@kernel
def _so_pass(cost, out, left, right, d_min, p1tab, p2tab, tau, flip, Lv, mv, progress, claim, threads):
    # Two of the four paths in one raster pass: forward (flip False) runs left->right and top->bottom, the reverse
    # pass right->left and bottom->top. This thread takes rows from claim; the vertical paths' rows (Lv, mv: a slot
    # per row in flight and the one before) are shared by the pass's threads, which hand rows over as SGM's do
    # (kernels.row_handover: a block of a row once the row before has done its columns).
    H, W, D = cost.shape
    step = -1 if flip else 1
    slots = Lv.shape[0]
    Lh = np.full((2, D + 2), np.int16(_SENTINEL), dtype=np.int16)
    acc = np.empty(D, dtype=np.int16)
    pad = D + abs(d_min) + 1
    n = W + 2 * pad
    P1, P2, fh, fv, bh, bv = _row_scratch(W, n)
    block = block_size(W, threads)
    while True:
        yy = next_row(claim, progress, H, W, slots, 1, threads)
        if yy >= H:
            break
        y = H - 1 - yy if flip else yy
        py = y - step
        vs = yy % slots
        vp = (yy - 1) % slots
        _row_edges(left, right, y, py, yy == 0, step, tau, p1tab, p2tab, P1, P2, pad, fh, fv, bh, bv)
        hs = 0
        mh = np.int16(0)
        b0 = 0
        while b0 < W:  # one block (the whole row on one thread)
            end = block_end(progress, yy, b0, W, block, 0, W) if threads > 1 else W
            for xx in range(b0, end):
                x = W - 1 - xx if flip else xx
                c = cost[y, x]
                j0 = W - 1 - (x - d_min) + pad  # reversed index of x_r = x - d_min (disparity index 0)
                acc[:] = 0
                if xx == 0:
                    mh = _so_start(Lh[hs], c, acc)
                else:
                    b = bh[x]
                    mh = _so_step(Lh[1 - hs], Lh[hs], c, acc, P1[0, b, j0:j0 + D], P2[0, b, j0:j0 + D], mh)
                hs = 1 - hs
                if yy == 0:
                    mv[vs, x] = _so_start(Lv[vs, x], c, acc)
                else:
                    b = bv[x]
                    mv[vs, x] = _so_step(Lv[vp, x], Lv[vs, x], c, acc, P1[1, b, j0:j0 + D], P2[1, b, j0:j0 + D],
                                         mv[vp, x])
                o = out[y, x]
                for d in range(D):
                    o[d] = np.uint16(acc[d])
            b0 = end
            if threads > 1:
                publish(progress, yy, end)


@kernel
def _vertical_rows(H, W, width, threads):
    # a pass's shared buffers: the vertical paths' rows (a slot per row in flight and the one before), their minima,
    # its progress and its row counter
    slots = 2 if threads == 1 else threads + 2
    return (np.full((slots, W, width), np.int16(_SENTINEL), dtype=np.int16), np.zeros((slots, W), dtype=np.int16),
            new_progress(H, threads), np.zeros(1, np.int64))


@kernel
def _shared_rows(H, W, width, nf, nb):
    # the buffers of each pass on several threads, shared by them (tiny stand-ins for a pass on one thread)
    return (_vertical_rows(H, W, width, nf) if nf > 1 else _vertical_rows(0, 0, 1, 1),
            _vertical_rows(H, W, width, nb) if nb > 1 else _vertical_rows(0, 0, 1, 1))


@kernel
def _thread_rows(t, nf, nb, shared_f, shared_b, H, W, width):
    # iteration t of the passes' loop (the forward pass's nf threads, then the reverse pass's nb): its pass (0, 1),
    # the pass's thread count and buffers; a pass on one thread makes its own (in its core's cache)
    p = 0 if t < nf else 1
    n = nf if p == 0 else nb
    return p, n, (shared_f if p == 0 else shared_b) if n > 1 else _vertical_rows(H, W, width, 1)


@kernel(parallel=True)
def _so_two_passes(cost, fwd, bwd, left, right, d_min, p1tab, p2tab, tau, threads):
    H, W, D = cost.shape
    nf, nb = pass_threads(H, threads)
    shared_f, shared_b = _shared_rows(H, W, D + 2, nf, nb)
    for t in prange(nf + nb):
        p, n, rows = _thread_rows(t, nf, nb, shared_f, shared_b, H, W, D + 2)
        Lv, mv, progress, claim = rows
        _so_pass(cost, fwd if p == 0 else bwd, left, right, d_min, p1tab, p2tab, tau, p == 1, Lv, mv, progress, claim,
                 n)


@kernel(inline=True)
def _so_tube_step(prev, wq, cur, c, acc, p1, p2, mp, s):
    # _so_step between tubes: index d here is index d + s of the previous pixel's tube (wq wide, padded by the
    # sentinel at prev[0] and prev[wq + 1]); a disparity outside that tube is unreachable there, not zero.
    w = c.shape[0]
    m = np.int16(_SENTINEL)
    lo = min(w, max(0, -s))
    hi = max(lo, min(w, wq - s))
    for d in range(lo):
        v = min(tube_value(prev, wq, d + s, p1[d]), mp + p2[d])
        v = np.int16(c[d] + v - mp)
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    if hi > lo:  # the overlap: as _so_step, shifted
        pv = prev[lo + s:hi + s + 2]
        cv = cur[lo + 1:hi + 1]
        for k in range(hi - lo):
            d = lo + k
            v = min(pv[k + 1], min(pv[k], pv[k + 2]) + p1[d])
            v = min(v, mp + p2[d])
            v = np.int16(c[d] + v - mp)
            cv[k] = v
            acc[d] += v
            m = min(m, v)
    for d in range(hi, w):
        v = min(tube_value(prev, wq, d + s, p1[d]), mp + p2[d])
        v = np.int16(c[d] + v - mp)
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    cur[w + 1] = np.int16(_SENTINEL)
    return m


@kernel
def _so_pass_tube(flat, out, start, width, offset, dmax, n_disp, left, right, d_min, p1tab, p2tab, tau, flip, Lv, mv,
                  progress, claim, threads):
    # _so_pass on a tube volume: pixel (y, x) holds width[y, x] disparities from d_min + offset[y, x] at
    # flat[start[y, x]:]; path rows are dmax + 2 wide, a pixel uses its first width + 2 (the last one the sentinel).
    H, W = start.shape
    step = -1 if flip else 1
    sent = np.int16(_SENTINEL)
    slots = Lv.shape[0]
    Lh = np.full((2, dmax + 2), sent, dtype=np.int16)
    acc_all = np.empty(dmax, dtype=np.int16)
    pad = n_disp + abs(d_min) + 1
    n = W + 2 * pad
    P1, P2, fh, fv, bh, bv = _row_scratch(W, n)
    block = block_size(W, threads)
    while True:
        yy = next_row(claim, progress, H, W, slots, 1, threads)
        if yy >= H:
            break
        y = H - 1 - yy if flip else yy
        py = y - step
        vs = yy % slots
        vp = (yy - 1) % slots
        _row_edges(left, right, y, py, yy == 0, step, tau, p1tab, p2tab, P1, P2, pad, fh, fv, bh, bv)
        hs = 0
        mh = np.int16(0)
        c0 = 0
        while c0 < W:  # one block (the whole row on one thread)
            end = block_end(progress, yy, c0, W, block, 0, W) if threads > 1 else W
            for xx in range(c0, end):
                x = W - 1 - xx if flip else xx
                b0 = start[y, x]
                w = np.int64(width[y, x])
                o = np.int64(offset[y, x])
                c = flat[b0:b0 + w]
                acc = acc_all[:w]
                acc[:] = 0
                j0 = W - 1 - (x - d_min) + pad + o  # reversed index of the tube's first disparity
                if xx == 0:
                    mh = _so_start(Lh[hs], c, acc)
                    Lh[hs, w + 1] = sent
                else:
                    q = x - step
                    b = bh[x]
                    mh = _so_tube_step(Lh[1 - hs], np.int64(width[y, q]), Lh[hs], c, acc, P1[0, b, j0:j0 + w],
                                       P2[0, b, j0:j0 + w], mh, o - np.int64(offset[y, q]))
                hs = 1 - hs
                if yy == 0:
                    mv[vs, x] = _so_start(Lv[vs, x], c, acc)
                    Lv[vs, x, w + 1] = sent
                else:
                    b = bv[x]
                    mv[vs, x] = _so_tube_step(Lv[vp, x], np.int64(width[py, x]), Lv[vs, x], c, acc,
                                              P1[1, b, j0:j0 + w], P2[1, b, j0:j0 + w], mv[vp, x],
                                              o - np.int64(offset[py, x]))
                ob = out[b0:b0 + w]
                for d in range(w):
                    ob[d] = np.uint16(acc[d])
            c0 = end
            if threads > 1:
                publish(progress, yy, end)


@kernel(parallel=True)
def _so_two_passes_tube(flat, fwd, bwd, start, width, offset, dmax, n_disp, left, right, d_min, p1tab, p2tab, tau,
                        threads):
    H, W = start.shape
    nf, nb = pass_threads(H, threads)
    shared_f, shared_b = _shared_rows(H, W, dmax + 2, nf, nb)
    for t in prange(nf + nb):
        p, n, rows = _thread_rows(t, nf, nb, shared_f, shared_b, H, W, dmax + 2)
        Lv, mv, progress, claim = rows
        _so_pass_tube(flat, fwd if p == 0 else bwd, start, width, offset, dmax, n_disp, left, right, d_min, p1tab,
                      p2tab, tau, p == 1, Lv, mv, progress, claim, n)


def so_penalties(pi1, pi2, scale):
    """``(P1, P2)`` tables (int16) indexed by the number of colour differences ``>= tau_so`` (0, 1 or 2)."""
    p1 = np.array([round(scale * pi1), round(scale * pi1 / 4), round(scale * pi1 / 10)], dtype=np.int16)
    p2 = np.array([round(scale * pi2), round(scale * pi2 / 4), round(scale * pi2 / 10)], dtype=np.int16)
    return p1, p2


def scanline_optimize(cost, left, right, d_min, pi1=1.0, pi2=3.0, tau_so=15, scale=256, max_cost=None, out=None,
                      tubes=None, *, threads=None):
    """Scanline optimisation over 4 paths (module docstring).

    Parameters
    ----------
    cost : (H, W, D) uint16
        Aggregated (possibly guided) cost in units of ``1 / scale``.
    left, right : (H, W, C) uint8
        The images (colour differences along the paths).
    pi1, pi2 : float
        Penalties in the paper's cost units (``P = round(scale * pi / {1, 4, 10})``).
    out : (fwd, bwd), optional
        Two uint16 volumes of the shape of ``cost`` to write into (e.g. the aggregation's scratch volumes).
    tubes : TubeLayout, optional
        Per-pixel tubes (:class:`~riverbed_cli.matching.volume.TubeLayout`; ``cost`` and the results are flat tube
        volumes): the recursion compares equal disparities of neighbours, and a disparity outside the previous
        pixel's tube is unreachable there (the sentinel, not zero), so only the ``P2`` jump from its minimum reaches
        it. Penalties are those of the dense volume at the same disparity.
    threads : int, optional
        Threads for the two passes, half each (default: Numba's); a pass's rows go to its threads as SGM's do
        (:mod:`~riverbed_cli.matching.kernels.row_handover`). The result is the same bits on any count.

    Returns
    -------
    (fwd, bwd) : two (H, W, D) uint16
        Sums of the left->right + top->bottom paths and of the right->left + bottom->top paths; their sum is the
        optimised cost.
    """
    left = u8_image(left, "left")
    right = u8_image(right, "right")
    if tubes is not None:
        if cost.ndim != 1 or cost.dtype not in (np.uint8, np.uint16) or cost.size != tubes.size or \
                tubes.shape != left.shape[:2]:
            raise RiverbedError(f"tube cost volume must be flat uint8/uint16 of {tubes.size} costs for "
                                f"{tubes.shape}, got {cost.dtype} {cost.shape}")
    elif cost.ndim != 3 or cost.dtype not in (np.uint8, np.uint16) or cost.shape[:2] != left.shape[:2]:
        raise RiverbedError(f"cost volume must be uint8/uint16 (H, W, D) of the image size, got {cost.shape}")
    p1, p2 = so_penalties(pi1, pi2, scale)
    if not 0 <= p1[0] <= p2[0]:
        raise RiverbedError(f"scanline penalties need 0 <= Pi1 <= Pi2 (got {pi1}, {pi2})")
    if max_cost is None:
        max_cost = int(cost.max(initial=0))
    if int(max_cost) + int(p2[0]) >= _SENTINEL:
        raise RiverbedError(f"scanline optimisation: max cost {max_cost} + P2 {p2[0]} does not fit int16 paths")
    cost = np.ascontiguousarray(cost)
    if tubes is not None:
        fwd = np.empty(cost.shape, dtype=np.uint16)
        bwd = np.empty(cost.shape, dtype=np.uint16)
        n_disp = int((tubes.offset + tubes.width).max(initial=1))
        _so_two_passes_tube(cost, fwd, bwd, tubes.start, tubes.width, tubes.offset, int(tubes.max_width), n_disp,
                            left, right, int(d_min), p1, p2, int(tau_so), int(threads or get_num_threads()))
        return fwd, bwd
    if out is not None and all(o.shape == cost.shape and o.dtype == np.uint16 and o is not cost for o in out):
        fwd, bwd = out
    else:
        fwd = np.empty(cost.shape, dtype=np.uint16)
        bwd = np.empty(cost.shape, dtype=np.uint16)
    _so_two_passes(cost, fwd, bwd, left, right, int(d_min), p1, p2, int(tau_so), int(threads or get_num_threads()))
    return fwd, bwd
