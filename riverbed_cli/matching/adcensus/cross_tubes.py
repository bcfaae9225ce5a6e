"""AD-Census stage 3 on a tube volume: cross-based aggregation of per-pixel disparity tubes
(:func:`cross_aggregate_tube`), exact against :func:`.cross.cross_aggregate` of the full-range cost.

On a tube volume the aggregated cost at (p, d), d in p's tube, is the full-range aggregation at (p, d), exactly:
every stage of the aggregation is a sum over segments, so stage j's value at (p, d) needs the previous stage's
values at (q, d) for every q on p's segment. Going backwards from the tubes, each stage's source layout is the
*support layout*: at q the interval hull of the tubes (at the next stage) of every p whose segment holds q
(:func:`support_layouts`). The raw cost is computed on the first of them (AD-Census costs at any (q, d) come from
the images), and every stage sums only disparities that all pixels of the segment hold: a running sum along the
row (column) that restarts where the previous pixel's tube does not hold the disparity, differenced at the
segment's ends.
"""

import numpy as np
from numba import prange

from ...errors import RiverbedError
from ...runtime.kernel import kernel
from ..volume import TubeLayout
from .cross import inverse_counts


def stage_plan(iterations):
    """The segment-sum stages of :func:`.cross.cross_aggregate`, in order: ``(horizontal, normalise,
    inverse_index)`` per stage; iteration ``k`` (1-based) is a raw pass then a normalising pass, horizontal first
    for odd ``k``, and normalises by ``1 / |U(p)|`` of :func:`.cross.support_counts` ``[(k - 1) % 2]``."""
    plan = []
    for k in range(1, int(iterations) + 1):
        h_first = k % 2 == 1
        plan.append((h_first, False, 0))
        plan.append((not h_first, True, (k - 1) % 2))
    return plan


@kernel(parallel=True)
def _dilate_rows(lo, hi, back, ahead):
    # (lo, hi) at q: min / max over the p of q's row whose segment [x - back, x + ahead] holds q. Every p's segment
    # holds p, so the result contains the input.
    H, W = lo.shape
    olo = lo.copy()
    ohi = hi.copy()
    for y in prange(H):
        for x in range(W):
            a = x - np.int64(back[y, x])
            b = x + np.int64(ahead[y, x]) + 1
            v = lo[y, x]
            u = hi[y, x]
            rl = olo[y, a:b]
            rh = ohi[y, a:b]
            for i in range(b - a):
                rl[i] = min(rl[i], v)
                rh[i] = max(rh[i], u)
    return olo, ohi


def _dilate(lo, hi, arms, horizontal):
    # the support hull through one stage's segments (vertical ones on the transposed maps, rows stay contiguous)
    if horizontal:
        return _dilate_rows(lo, hi, np.ascontiguousarray(arms[:, :, 0]), np.ascontiguousarray(arms[:, :, 1]))
    t = _dilate_rows(np.ascontiguousarray(lo.T), np.ascontiguousarray(hi.T), np.ascontiguousarray(arms[:, :, 2].T),
                     np.ascontiguousarray(arms[:, :, 3].T))
    return np.ascontiguousarray(t[0].T), np.ascontiguousarray(t[1].T)


def support_layouts(tubes, arms, iterations, d_min):
    """Layouts of every stage of the tube aggregation (module section "tubes").

    Parameters
    ----------
    tubes : TubeLayout
        The tubes the aggregated cost is wanted on.
    arms : (H, W, 4) uint8
        :func:`cross_arms`.
    iterations : int
    d_min : int
        Disparity at offset 0.

    Returns
    -------
    list of TubeLayout
        ``2 * iterations + 1`` layouts: index 0 the raw cost's, index ``j`` stage ``j``'s output (the last is
        ``tubes``); each contains the next one pixel by pixel.
    """
    if arms.shape != tubes.shape + (4,):
        raise RiverbedError(f"arms {arms.shape} do not match the tubes {tubes.shape}")
    lo = (tubes.offset + np.int32(d_min)).astype(np.int32)
    hi = (lo + tubes.width - 1).astype(np.int32)
    out = [tubes]
    for horizontal, _, _ in reversed(stage_plan(iterations)):
        lo, hi = _dilate(lo, hi, arms, horizontal)
        out.append(TubeLayout.from_bounds(lo, hi, d_min))
    return out[::-1]


@kernel(inline=True)
def _run_step(src, sb, w, o, run, rb, rp, wp, op):
    # running sums of one pixel's tube (w wide from offset o; source at src[sb:], result at run[rb:]): each
    # disparity continues the previous pixel's run (its tube wp wide from op, at run[rp:]) where that pixel holds it
    # and restarts elsewhere. A segment whose pixels all hold d then sums to run(end) - run(before its start).
    lo = min(w, max(0, op - o))
    hi = max(lo, min(w, op + wp - o))
    sv = src[sb:sb + w]
    rv = run[rb:rb + w]
    for i in range(lo):
        rv[i] = sv[i]
    if hi > lo:
        pv = run[rp + o - op + lo:rp + o - op + hi]
        sl = sv[lo:hi]
        rl = rv[lo:hi]
        for i in range(hi - lo):
            rl[i] = pv[i] + sl[i]
    for i in range(hi, w):
        rv[i] = sv[i]


@kernel(inline=True)
def _seg_out(run, eb, ew, eo, pb, pw, po, has_before, out, ob, w, o, f, norm):
    # out[ob + i] for disparity index o + i: the segment's sum run(end) - run(before), end's tube at run[eb:] (ew
    # wide from eo), the pixel before the segment at run[pb:] (pw wide from po; absent when not has_before)
    half = np.float32(0.5)
    ev = run[eb + o - eo:eb + o - eo + w]
    ov = out[ob:ob + w]
    lo = w
    hi = w
    if has_before:
        lo = min(w, max(0, po - o))
        hi = max(lo, min(w, po + pw - o))
    if hi > lo:
        pv = run[pb + o - po + lo:pb + o - po + hi]
        el = ev[lo:hi]
        ol = ov[lo:hi]
        if norm:
            for i in range(hi - lo):
                ol[i] = np.uint16(np.float32(el[i] - pv[i]) * f + half)
        else:
            for i in range(hi - lo):
                ol[i] = el[i] - pv[i]
    if norm:
        for i in range(lo):
            ov[i] = np.uint16(np.float32(ev[i]) * f + half)
        for i in range(hi, w):
            ov[i] = np.uint16(np.float32(ev[i]) * f + half)
    else:
        for i in range(lo):
            ov[i] = ev[i]
        for i in range(hi, w):
            ov[i] = ev[i]


@kernel(parallel=True)
def _tube_hstage(src, sstart, swidth, soff, out, ostart, owidth, ooff, arms, inv, norm):
    # one horizontal segment-sum stage from a tube volume on layout s to one on layout o (o inside s)
    H, W = sstart.shape
    for y in prange(H):
        r0 = sstart[y, 0]
        n = sstart[y, W - 1] + swidth[y, W - 1] - r0
        run = np.empty(n, dtype=np.int64)
        for x in range(W):
            rb = sstart[y, x] - r0
            if x == 0:
                _run_step(src, sstart[y, x], swidth[y, x], soff[y, x], run, rb, 0, 0, 0)
            else:
                _run_step(src, sstart[y, x], swidth[y, x], soff[y, x], run, rb, sstart[y, x - 1] - r0,
                          swidth[y, x - 1], soff[y, x - 1])
        for x in range(W):
            a = x - np.int64(arms[y, x, 0])
            e = x + np.int64(arms[y, x, 1])
            hb = a > 0
            p = a - 1 if hb else 0
            _seg_out(run, sstart[y, e] - r0, swidth[y, e], soff[y, e], sstart[y, p] - r0, swidth[y, p], soff[y, p],
                     hb, out, ostart[y, x], owidth[y, x], ooff[y, x], inv[y, x], norm)


@kernel(parallel=True)
def _tube_vruns(src, sstart, swidth, soff, run):
    # running sums down the columns, on the source layout; rows in raster order within strips of columns (one per
    # thread), so consecutive tubes are read and written one after the other
    H, W = sstart.shape
    ns = 8
    for k in prange(ns):
        x0 = k * W // ns
        x1 = (k + 1) * W // ns
        for y in range(H):
            for x in range(x0, x1):
                if y == 0:
                    _run_step(src, sstart[y, x], swidth[y, x], soff[y, x], run, sstart[y, x], 0, 0, 0)
                else:
                    _run_step(src, sstart[y, x], swidth[y, x], soff[y, x], run, sstart[y, x], sstart[y - 1, x],
                              swidth[y - 1, x], soff[y - 1, x])


@kernel(parallel=True)
def _tube_vout(run, sstart, swidth, soff, out, ostart, owidth, ooff, arms, inv, norm):
    H, W = sstart.shape
    for y in prange(H):
        for x in range(W):
            a = y - np.int64(arms[y, x, 2])
            e = y + np.int64(arms[y, x, 3])
            hb = a > 0
            p = a - 1 if hb else 0
            _seg_out(run, sstart[e, x], swidth[e, x], soff[e, x], sstart[p, x], swidth[p, x], soff[p, x], hb, out,
                     ostart[y, x], owidth[y, x], ooff[y, x], inv[y, x], norm)


def cross_aggregate_tube(cost, arms, iterations, layouts):
    """Cross-based aggregation of a tube volume (module section "tubes").

    Parameters
    ----------
    cost : (layouts[0].size,) uint16
        Flat cost volume on the first support layout (:func:`support_layouts`).
    arms : (H, W, 4) uint8
        :func:`cross_arms`.
    iterations : int
    layouts : list of TubeLayout
        :func:`support_layouts` ``(tubes, arms, iterations, d_min)``.

    Returns
    -------
    (layouts[-1].size,) uint16
        The aggregated cost on the tubes: at every tube disparity equal to :func:`cross_aggregate` of the full-range
        cost, bit for bit.
    """
    if cost.ndim != 1 or cost.dtype != np.uint16 or cost.size != layouts[0].size:
        raise RiverbedError(f"tube cost volume must be flat uint16 of {layouts[0].size} costs, got {cost.dtype} "
                            f"{cost.shape}")
    plan = stage_plan(iterations)
    if len(layouts) != len(plan) + 1 or arms.shape != layouts[0].shape + (4,):
        raise RiverbedError(f"{len(layouts)} layouts / arms {arms.shape} do not fit {iterations} iterations")
    if not plan:
        return cost.copy()
    inv = inverse_counts(arms)
    one = np.ones(arms.shape[:2], dtype=np.float32)
    seg = 2 * int(arms.max(initial=0)) + 1
    raw_dtype = np.uint16 if int(cost.max(initial=0)) * seg <= 65535 else np.uint32
    src = cost
    for j, (horizontal, norm, k) in enumerate(plan):
        s, o = layouts[j], layouts[j + 1]
        out = np.empty(o.size, dtype=np.uint16 if norm else raw_dtype)
        f = inv[k] if norm else one
        if horizontal:
            _tube_hstage(src, s.start, s.width, s.offset, out, o.start, o.width, o.offset, arms, f, norm)
        else:
            run = np.empty(s.size, dtype=np.int32 if src.dtype == np.uint16 else np.int64)
            _tube_vruns(src, s.start, s.width, s.offset, run)
            _tube_vout(run, s.start, s.width, s.offset, out, o.start, o.width, o.offset, arms, f, norm)
            del run
        src = out
    return src
