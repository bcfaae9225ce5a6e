"""AD-Census stages 2 and 3: cross-based support regions (:func:`cross_arms`) and the aggregation over them
(:func:`cross_aggregate`, :func:`adcensus_aggregate`).

**Support regions**: from every pixel ``p`` four arms (left, right, up, down) extend to ``p_l`` while
``D_c(p_l, p) < tau1`` and ``D_c(p_l, p_l + r) < tau1`` (``p_l + r`` the arm's previous pixel), ``D_s(p_l, p) < L1``,
and ``D_c(p_l, p) < tau2`` once ``D_s(p_l, p) > L2``; ``D_c`` is the largest absolute difference over colour channels,
``D_s`` the distance in pixels (paper: ``L1 = 34, L2 = 17, tau1 = 20, tau2 = 6``; arms are at most ``L1 - 1`` long).
Only the left (reference) image's crosses are used.

**Aggregation**: ``iterations`` (4) passes of the average over the support region; odd iterations (1st, 3rd) take
``U(p)`` = the horizontal segments of the pixels on ``p``'s vertical arm (sum horizontally, then vertically), even ones
the vertical segments of the pixels on the horizontal arm. Sums are exact integers (orthogonal integral images); the
average is ``int(sum * float32(1 / |U(p)|) + 0.5)``, in the volume's cost units. :func:`adcensus_aggregate` fuses
stages 1 and 3: each row's cost is computed in cache and summed along its segments at once, and the normalising pass
of one iteration runs together with the first pass of the next, so the cost volume is never stored and the volume is
swept 5 times instead of 9.
"""

import numpy as np
from numba import prange

from ...errors import RiverbedError
from ...runtime.kernel import kernel
from .cost import cost_inputs, cost_kernel, cost_row, u8_image
from .params import ADCensusParams


@kernel(parallel=True)
def _arms_inputs(img, tau1):
    # planar float32 channels (a grey image is repeated into all three), and the adjacency tests
    # adjh[y, x]: D_c((y, x), (y, x + 1)) < tau1, adjv[y, x]: D_c((y, x), (y + 1, x)) < tau1 (1 / 0)
    H, W, C = img.shape
    F = np.empty((3, H, W), dtype=np.float32)
    adjh = np.zeros((H, W), dtype=np.int32)
    adjv = np.zeros((H, W), dtype=np.int32)
    for y in prange(H):
        for x in range(W):
            for ch in range(3):
                F[ch, y, x] = img[y, x, ch if ch < C else 0]
        for x in range(W):
            h = np.int32(0)
            v = np.int32(0)
            for ch in range(C):
                a = np.float32(img[y, x, ch])
                if x + 1 < W:
                    h = max(h, np.int32(abs(a - np.float32(img[y, x + 1, ch]))))
                if y + 1 < H:
                    v = max(v, np.int32(abs(a - np.float32(img[y + 1, x, ch]))))
            adjh[y, x] = x + 1 < W and h < tau1
            adjv[y, x] = y + 1 < H and v < tau1
    return F, adjh, adjv


@kernel(inline=True)
def _grow(p0, p1, p2, q0, q1, q2, adj, alive, length, n, k, l2, tau1, tau2):
    # step k of n arms at once: arm j is still alive if its k-th pixel q passes D_c(q, p) < tau1, the adjacency
    # test with its predecessor, and D_c(q, p) < tau2 once k > L2. Branch-free over j (vectorises).
    near = k <= l2
    grown = np.int32(0)
    for j in range(n):
        dc = max(abs(q0[j] - p0[j]), max(abs(q1[j] - p1[j]), abs(q2[j] - p2[j])))
        ok = np.int32((dc < tau1) & (adj[j] != 0) & (near | (dc < tau2)))
        a = alive[j] & ok
        alive[j] = a
        length[j] += a
        grown |= a
    return grown


@kernel(parallel=True)
def _arms_kernel(F, adjh, adjv, l1, l2, tau1, tau2):
    # One image row at a time, all arms of one direction grow together, one step k at a time, until none grows.
    C, H, W = F.shape
    arms = np.zeros((H, W, 4), dtype=np.uint8)
    for y in prange(H):
        alive = np.empty(W, dtype=np.int32)
        length = np.empty(W, dtype=np.int32)
        p0 = F[0, y]
        p1 = F[1, y]
        p2 = F[2, y]
        # left: the arm pixel of x is x - k
        alive[:] = 1
        length[:] = 0
        for k in range(1, min(l1, W)):
            alive[k - 1] = 0
            n = W - k
            if _grow(p0[k:], p1[k:], p2[k:], p0[:n], p1[:n], p2[:n], adjh[y, :n], alive[k:], length[k:], n, k, l2,
                     tau1, tau2) == 0:
                break
        for x in range(W):
            arms[y, x, 0] = length[x]
        # right: x + k
        alive[:] = 1
        length[:] = 0
        for k in range(1, min(l1, W)):
            alive[W - k] = 0
            n = W - k
            if _grow(p0[:n], p1[:n], p2[:n], p0[k:], p1[k:], p2[k:], adjh[y, k - 1:W - 1], alive[:n], length[:n], n,
                     k, l2, tau1, tau2) == 0:
                break
        for x in range(W):
            arms[y, x, 1] = length[x]
        # up: row y - k
        alive[:] = 1
        length[:] = 0
        for k in range(1, min(l1, y + 1)):
            r = y - k
            if _grow(p0, p1, p2, F[0, r], F[1, r], F[2, r], adjv[r], alive, length, W, k, l2, tau1, tau2) == 0:
                break
        for x in range(W):
            arms[y, x, 2] = length[x]
        # down: row y + k
        alive[:] = 1
        length[:] = 0
        for k in range(1, min(l1, H - y)):
            r = y + k
            if _grow(p0, p1, p2, F[0, r], F[1, r], F[2, r], adjv[r - 1], alive, length, W, k, l2, tau1,
                     tau2) == 0:
                break
        for x in range(W):
            arms[y, x, 3] = length[x]
    return arms


def cross_arms(img, l1=34, l2=17, tau1=20, tau2=6):
    """Arm lengths of the cross-based support region of every pixel (module docstring).

    Parameters
    ----------
    img : (H, W) or (H, W, C) uint8
        The reference (left) image.

    Returns
    -------
    (H, W, 4) uint8
        Arm lengths (pixels, not counting ``p``) to the left, right, up and down, each at most ``l1 - 1``.
    """
    img = u8_image(img, "guide")
    if not 1 <= l1 <= 128 or not 0 <= l2 <= l1:
        raise RiverbedError(f"cross arm limits L1={l1}, L2={l2} out of range (need 0 <= L2 <= L1 <= 128)")
    F, adjh, adjv = _arms_inputs(img, np.float32(tau1))
    return _arms_kernel(F, adjh, adjv, int(l1), int(l2), np.float32(tau1), np.float32(tau2))


@kernel
def _counts_kernel(arms):
    # prefix sums of the segment lengths along columns (hv) and rows (vh)
    H, W, _ = arms.shape
    ch = np.zeros((H + 1, W), dtype=np.int32)
    cv = np.zeros((H, W + 1), dtype=np.int32)
    for y in range(H):
        for x in range(W):
            ch[y + 1, x] = ch[y, x] + np.int32(arms[y, x, 0]) + np.int32(arms[y, x, 1]) + 1
            cv[y, x + 1] = cv[y, x] + np.int32(arms[y, x, 2]) + np.int32(arms[y, x, 3]) + 1
    hv = np.empty((H, W), dtype=np.int32)
    vh = np.empty((H, W), dtype=np.int32)
    for y in range(H):
        for x in range(W):
            hv[y, x] = ch[y + np.int64(arms[y, x, 3]) + 1, x] - ch[y - np.int64(arms[y, x, 2]), x]
            vh[y, x] = cv[y, x + np.int64(arms[y, x, 1]) + 1] - cv[y, x - np.int64(arms[y, x, 0])]
    return hv, vh


def support_counts(arms):
    """Pixel counts ``|U(p)|`` of the two support regions, ``(horizontal_first, vertical_first)``, both int32: the
    sum of the horizontal segment lengths over the vertical arm, and of the vertical ones over the horizontal arm."""
    return _counts_kernel(np.ascontiguousarray(arms))


@kernel(inline=True)
def _segment_sums(pre, lo, hi, out, f, norm):
    # out[d] = pre[hi, d] - pre[lo, d], or that times f (float32 1 / |U(p)|) rounded half up when norm
    D = out.shape[0]
    pa = pre[lo]
    pb = pre[hi]
    if norm:
        half = np.float32(0.5)
        for d in range(D):
            out[d] = np.uint16(np.float32(pb[d] - pa[d]) * f + half)
    else:
        for d in range(D):
            out[d] = pb[d] - pa[d]


@kernel(inline=True)
def _prefix_step(p0, p1, sx):
    # One step of a running sum over disparity rows: p1 = p0 + sx (int32).
    for d in range(p0.shape[0]):
        p1[d] = p0[d] + np.int32(sx[d])


@kernel(inline=True)
def _prefix(rows, pre):
    # Prefix sums along the first axis: pre[0] = 0, pre[x + 1] = pre[x] + rows[x].
    for d in range(pre.shape[1]):
        pre[0, d] = 0
    for x in range(rows.shape[0]):
        _prefix_step(pre[x], pre[x + 1], rows[x])


@kernel(inline=True)
def _row_segments(pre, arms_row, out_row, inv_row, norm):
    # every pixel x of a row: the sum (or with norm, the average) over its horizontal segment, from the row's prefix
    for x in range(out_row.shape[0]):
        lo = x - np.int64(arms_row[x, 0])
        hi = x + np.int64(arms_row[x, 1]) + 1
        _segment_sums(pre, lo, hi, out_row[x], inv_row[x], norm)


@kernel(parallel=True)
def _hstage(src, arms, out, inv, first_norm, chain):
    # One horizontal stage per row, in cache: segment sums of src (normalised with inv when first_norm); when chain,
    # the raw segment sums of that result (the first pass of the next iteration, also horizontal) go to out.
    H, W, D = src.shape
    for y in prange(H):
        pre = np.empty((W + 1, D), dtype=np.int32)
        _prefix(src[y], pre)
        if chain:
            mid = np.empty((W, D), dtype=np.uint16)
            _row_segments(pre, arms[y], mid, inv[y], first_norm)
            _prefix(mid, pre)
            _row_segments(pre, arms[y], out[y], inv[y], False)
        else:
            _row_segments(pre, arms[y], out[y], inv[y], first_norm)


@kernel(parallel=True)
def _cost_hstage(left, right, cl, cr, d_min, ad_lut, cen_lut, outside, arms, out):
    # The AD-Census cost of each row, computed in cache and summed along the horizontal segments (the first pass of
    # the first aggregation iteration) without ever storing the cost volume.
    H, W, D = out.shape
    for y in prange(H):
        row = np.empty((W, D), dtype=np.uint16)
        cost_row(left, right, cl, cr, y, d_min, ad_lut, cen_lut, outside, row)
        pre = np.empty((W + 1, D), dtype=np.int32)
        _prefix(row, pre)
        _row_segments(pre, arms[y], out[y], np.ones(W, dtype=np.float32), False)


@kernel(parallel=True)
def _vstage(src, arms, out, inv, first_norm, chain, strip):
    # The vertical counterpart of _hstage, on strips of columns (prefix sums of a strip stay in L2 cache).
    H, W, D = src.shape
    ns = (W + strip - 1) // strip
    for s in prange(ns):
        x0 = s * strip
        x1 = min(W, x0 + strip)
        sw = x1 - x0
        pre = np.empty((sw, H + 1, D), dtype=np.int32)
        mid = np.empty((sw, H, D), dtype=np.uint16)
        for j in range(sw):
            for d in range(D):
                pre[j, 0, d] = 0
        for y in range(H):
            for j in range(sw):
                _prefix_step(pre[j, y], pre[j, y + 1], src[y, x0 + j])
        for y in range(H):
            for j in range(sw):
                x = x0 + j
                lo = y - np.int64(arms[y, x, 2])
                hi = y + np.int64(arms[y, x, 3]) + 1
                if chain:
                    _segment_sums(pre[j], lo, hi, mid[j, y], inv[y, x], first_norm)
                else:
                    _segment_sums(pre[j], lo, hi, out[y, x], inv[y, x], first_norm)
        if chain:
            for j in range(sw):
                pj = pre[j]
                mj = mid[j]
                for y in range(H):
                    _prefix_step(pj[y], pj[y + 1], mj[y])
            for y in range(H):
                for j in range(sw):
                    x = x0 + j
                    lo = y - np.int64(arms[y, x, 2])
                    hi = y + np.int64(arms[y, x, 3]) + 1
                    _segment_sums(pre[j], lo, hi, out[y, x], np.float32(1.0), False)


_STRIP = 4  # columns per strip: the strip's prefix sums (H x 4 x D int32) stay in L2 cache


def cross_aggregate(cost, arms, iterations=4, counts=None, inplace=False, work=None):
    """Cross-based cost aggregation (module docstring).

    Parameters
    ----------
    cost : (H, W, D) uint16
        Cost volume.
    arms : (H, W, 4) uint8
        :func:`cross_arms`.
    iterations : int
        Number of aggregation passes; odd ones horizontal-first, even ones vertical-first.
    counts : (hv, vh) int32, optional
        :func:`support_counts` of ``arms``.
    inplace : bool
        Write the result into ``cost`` (its values are no longer needed) to save one volume of memory.
    work : list of arrays, optional
        Up to two scratch volumes of the shape of ``cost`` to reuse (uint16, or uint32 when sums of the costs could
        exceed uint16); missing ones are allocated and appended, so the caller can reuse them afterwards.

    Returns
    -------
    (H, W, D) uint16
        ``int(sum_{q in U(p)} C(q) * float32(1 / |U(p)|) + 0.5)`` iterated; the input is left unchanged unless
        ``inplace``.

    Implementation: iteration ``k`` is a raw pass (segment sums) and a normalising pass in the other direction;
    the normalising pass of iteration ``k`` and the raw pass of ``k + 1`` run in the same direction, so they are
    fused per row / per strip of columns and the intermediate averages never make a round trip through memory
    (``iterations + 1`` sweeps over the volume instead of ``2 * iterations``).
    """
    if cost.ndim != 3 or cost.dtype != np.uint16:
        raise RiverbedError(f"cost volume must be (H, W, D) uint16, got {cost.dtype} {cost.shape}")
    if arms.shape != cost.shape[:2] + (4,):
        raise RiverbedError(f"arms {arms.shape} do not match the cost volume {cost.shape}")
    if iterations <= 0:
        return cost if inplace else cost.copy()
    if counts is None:
        inv = inverse_counts(arms)  # odd iterations (horizontal first), even ones (vertical first)
    else:
        inv = [(np.float32(1.0) / c.astype(np.float32)).astype(np.float32) for c in counts]
    one = np.ones(arms.shape[:2], dtype=np.float32)
    seg = 2 * int(arms.max(initial=0)) + 1
    # raw segment sums stay exact in uint16 when every segment sum of a cost fits
    raw_dtype = np.uint16 if int(cost.max(initial=0)) * seg <= 65535 else np.uint32
    work = [] if work is None else work
    good = [w for w in work if w.shape == cost.shape and w.dtype == raw_dtype]
    while len(good) < (2 if iterations > 1 else 1):
        good.append(np.empty(cost.shape, dtype=raw_dtype))
        work.append(good[-1])
    a, b = good[0], (good[1] if iterations > 1 else None)
    out = cost if inplace else np.empty(cost.shape, dtype=np.uint16)
    # stage 0: raw horizontal sums of the cost; stage j: normalise iteration j, raw pass of iteration j + 1;
    # stage `iterations`: normalise the last iteration. Stages alternate horizontal / vertical.
    _hstage(cost, arms, a, one, False, False)
    return _aggregate_stages(a, b, out, arms, iterations, inv)


def _aggregate_stages(a, b, out, arms, iterations, inv):
    # stages 1 .. iterations of cross_aggregate, from the raw horizontal sums in a
    src = a
    for j in range(1, iterations + 1):
        last = j == iterations
        dst = out if last else (b if src is a else a)
        f = inv[(j - 1) % 2]
        if j % 2 == 1:
            _vstage(src, arms, dst, f, True, not last, _STRIP)
        else:
            _hstage(src, arms, dst, f, True, not last)
        src = dst
    return out


def inverse_counts(arms):
    """``float32(1) / |U(p)|`` of both support regions (:func:`support_counts`), as float32 maps."""
    hv, vh = support_counts(arms)
    return [(np.float32(1.0) / hv.astype(np.float32)).astype(np.float32),
            (np.float32(1.0) / vh.astype(np.float32)).astype(np.float32)]


def adcensus_aggregate(left, right, census_left, census_right, d_min, d_max, arms, params=None, work=None):
    """AD-Census cost (:func:`adcensus_cost`) and cross-based aggregation (:func:`cross_aggregate`) in one go.

    Equal to ``cross_aggregate(adcensus_cost(...), arms, params.iterations)``, but each row's cost is computed in
    cache and summed along its horizontal segments at once: the cost volume is never stored. ``work`` as for
    :func:`cross_aggregate` (uint16 scratch volumes, reusable afterwards).

    Returns
    -------
    (H, W, D) uint16
        Aggregated cost in units of ``1 / params.scale``.
    """
    p = params or ADCensusParams()
    args = cost_inputs(left, right, census_left, census_right, d_min, d_max, p.lambda_ad, p.lambda_census,
                        p.scale, p.outside)
    H, W = census_left.shape
    shape = (H, W, int(d_max) - int(d_min) + 1)
    if arms.shape != (H, W, 4):
        raise RiverbedError(f"arms {arms.shape} do not match the images {(H, W)}")
    seg = 2 * int(arms.max(initial=0)) + 1
    if 2 * p.scale * seg > 65535:
        raise RiverbedError(f"AD-Census scale {p.scale} too large for arms of {seg} px (segment sums overflow uint16)")
    work = [] if work is None else work
    good = [w for w in work if w.shape == shape and w.dtype == np.uint16]
    while len(good) < 2:
        good.append(np.empty(shape, dtype=np.uint16))
        work.append(good[-1])
    a, b = good[0], good[1]
    if p.iterations <= 0:
        out = np.empty(shape, dtype=np.uint16)
        cost_kernel(*args, out)
        return out
    _cost_hstage(*args, arms, a)
    return _aggregate_stages(a, b, np.empty(shape, dtype=np.uint16), arms, p.iterations, inverse_counts(arms))

