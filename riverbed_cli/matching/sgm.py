"""Aggregation: Semi-Global Matching (Hirschmueller 2008) over 4, 8 or 16 paths.

Each path cost follows ``L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d+-1) + P1, min_k L_r(p-r, k) + P2)
- min_k L_r(p-r, k)``, starting with ``L_r = C`` at the first pixel of every path. The aggregated cost is the sum over
paths. Costs and sums stay in ``uint16``.

Implementation: half of the directions are swept in one raster-order pass (top-left to bottom-right), the other half in
the reverse pass; each pass keeps the path costs of the last rows in a small ring buffer, so the cost volume is read
once per pass; a step works on whole chunks of ``LANES`` disparities at once (:mod:`.lanes`), dense and tube volumes
alike. A pass sweeps each row one direction at a time, every pixel adding into its own slot of a row of half-sums:
only the horizontal direction's steps depend on each other, so the CPU overlaps the others' (one pixel at a time,
with every direction's steps into one shared scratch, was 12-25 % slower). The last direction stores each pixel's
half-sum straight into the pass's result (masked to its tube; a copy of the row's half-sums after the sweep took a
fifth of the pass). The common steps (one chunk, or a wide tube beside a wide tube, the neighbour's entry within
reach) run in lean loops of their own, the rare cases in the pass's loop. At 4 paths on tubes a pixel's two
directions go in one step where both are common ones, one chunk or wide (:func:`.lanes.lanes_step_pair`,
:func:`.lanes.lanes_step_wide_pair`: the cost loaded once, no half-sum between them); the column's sweep takes the
rest. Where the row's neighbour's tube starts at the same disparity and takes as many chunks (nearly every step: the
tubes are made per cell, and a hole's pixels all search the whole range), the steps go in runs whose row path costs
stay in registers (:func:`.lanes_runs.lanes_run_pair`). The two passes are independent and run in parallel.
"""

import numpy as np
from numba import njit, prange

from ..errors import RiverbedError
from .kernels.lanes import (LANES, SENTINEL, lanes_copy, lanes_fill, lanes_first, lanes_reduce, lanes_step,
                            lanes_step_min, lanes_step_out, lanes_step_pair, lanes_step_wide, lanes_step_wide_out,
                            lanes_step_wide_pair)
from .kernels.atomics import exchange, load_acquire, store_release
from .disparity import finish_selection, select_row
from .kernels.lanes_runs import RUN_CHUNKS_MAX, lanes_run_pair
from .volume import band_pair_rows, band_pairs, volume_layout

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


# Path costs live in int16: every path cost is at most max_cost + P2, and check_sgm_bounds keeps
# paths * (max_cost + P2) <= 65535, so a path cost is <= 16383 and each half-sum (half the paths) <= 32767.
_SENTINEL = SENTINEL  # above any path cost; sentinel + P1 still fits int16
# Each ring-buffer entry: _GUARD sentinels (never written), the path costs in whole chunks of LANES (the sentinel past
# the tube), then one chunk of sentinels. A step reads its neighbour's entry shifted by the difference of their tube
# offsets; within these bounds every disparity outside the neighbour's tube reads the sentinel, with no test.
_GUARD = LANES
_NO_PROGRESS = np.zeros(0, np.int64)  # a pass that tells no other thread how far it is


@njit(cache=True, boundscheck=False)
def path_start(cur, c, acc):
    m = np.int16(_SENTINEL)
    for d in range(c.shape[0]):
        v = np.int16(c[d])
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    return m


@njit(cache=True, boundscheck=False, inline="always")
def tube_value(prev, wq, j, P1):
    # min(L(j), L(j -+ 1) + P1) of the previous pixel's tube (wq wide) at its index j; outside it: the sentinel
    sent = np.int16(_SENTINEL)
    a = prev[j + 1] if 0 <= j < wq else sent
    b = prev[j] if 1 <= j <= wq else sent
    e = prev[j + 2] if -1 <= j < wq - 1 else sent
    return min(a, min(b, e) + P1)


@njit(cache=True, boundscheck=False)
def _step_scalar(L, acc, cur, cost, b, w, span, prev, wq, s, P1, jump, mp, first, keep):
    # The step of _sgm_pass one disparity at a time, for what its vector steps cannot reach: the last pixels of the
    # volume (their lanes would read past its end) and shifts past the guard of the neighbour's entry. keep as in
    # lanes_step (0: the pixel's first direction starts the half-sum).
    sent = np.int16(_SENTINEL)
    m = sent
    for i in range(span):
        if i >= w:
            v = sent
        elif first:
            v = np.int16(cost[b + i])
        else:
            v = np.int16(cost[b + i] + min(tube_value(L[prev - 1:], wq, i + s, P1), jump) - mp)
        L[cur + i] = v
        acc[i] = (acc[i] & keep) + v
        m = min(m, v)
    return m


@njit(cache=True, boundscheck=False)
def _wide_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, dx, cbase, pbase, R, RA, P1, P2, keep, out, last,
                done):
    # As _common_steps, for tubes wider than one chunk (a pixel no LiDAR reaches, beside others alike): every chunk in
    # one step (lanes_step_wide), while the neighbour's entry holds every chunk's reads; stops at a pixel whose
    # directions went paired (done)
    n = flat.shape[0]
    sent = np.int16(_SENTINEL)
    while xx < W:
        ux, b, w = _pixel_layout(rb, rws, xx)
        px = xx - dx
        span = (w + LANES - 1) // LANES * LANES
        if w <= LANES or b + span > n or px < 0 or px >= W or done[ux]:
            return xx
        up = np.uint64(px)
        s = ros[ux] - rop[up]
        if s < 1 - _GUARD or s > (rwp[up] + LANES - 1) // LANES * LANES + LANES - 1 - span:
            return xx
        cur = (cbase + xx) * R + _GUARD
        mp = Lmin[np.uint64(pbase + px)]
        pi = (pbase + px) * R + _GUARD + s - 1
        if last:
            m = lanes_step_wide_out(L, acc, cur, flat, b, xx * RA, w, span, pi, P1, np.int16(mp + P2), mp, out, b)
        else:
            m = lanes_step_wide(L, acc, cur, flat, b, xx * RA, w, span, pi, P1, np.int16(mp + P2), mp, keep)
        lanes_fill(L, cur + span, sent)
        Lmin[np.uint64(cbase + xx)] = m
        xx += 1
    return xx


@njit(cache=True, inline="always")
def _reaches(s, wq, span):
    # whether a step over span disparities (whole chunks) shifted by s against its neighbour's tube (wq wide) reads
    # only inside the neighbour's ring-buffer entry (its guard and sentinel chunk included)
    return 1 - _GUARD <= s <= (wq + LANES - 1) // LANES * LANES + LANES - 1 - span


@njit(cache=True, inline="always")
def _pair_entries(Lmin, cbase0, cbase1, pbase1, xx, R):
    # a paired step's two ring-buffer entries and its two neighbours' minima (the row's pixel xx - 1, the column's
    # pixel xx of the row before)
    return ((cbase0 + xx) * R + _GUARD, (cbase1 + xx) * R + _GUARD, Lmin[np.uint64(cbase0 + xx - 1)],
            Lmin[np.uint64(pbase1 + xx)])


@njit(cache=True, inline="always")
def _paired(L, Lmin, m, cur0, cur1, at0, at1, span, done, ux):
    # after a paired step: the sentinel chunk after both entries, both minima (m: the first in the low 16 bits) at
    # Lmin[at0] and Lmin[at1], the pixel done
    sent = np.int16(_SENTINEL)
    lanes_fill(L, cur0 + span, sent)
    lanes_fill(L, cur1 + span, sent)
    Lmin[np.uint64(at0)] = np.int16(m & 0xFFFF)
    Lmin[np.uint64(at1)] = np.int16(m >> 16)
    done[ux] = 1


@njit(cache=True, boundscheck=False)
def _pair_steps(L, flat, Lmin, rb, rws, ros, rwp1, rop1, xx, W, cbase0, cbase1, pbase1, R, P1, P2, out, done):
    # 4 paths: both of a pass's directions of each pixel at once (lanes_step_pair: the row's from pixel xx - 1, the
    # column's from the row before), from pixel xx on while both are common steps (one chunk, the neighbours'
    # entries within reach); marks those pixels done. Returns the first pixel that is not.
    n = flat.shape[0]
    while xx < W:
        ux, b, w = _pixel_layout(rb, rws, xx)
        if w > LANES or b + LANES > n or xx < 1:
            return xx
        up = np.uint64(xx - 1)
        s0 = ros[ux] - ros[up]
        s1 = ros[ux] - rop1[ux]
        if not (_reaches(s0, rws[up], LANES) and _reaches(s1, rwp1[ux], LANES)):
            return xx
        if s0 == 0 and rws[up] <= LANES:  # nearly every step: a run of them, the row's costs in registers
            xx = lanes_run_pair(L, flat, Lmin, rb, rws, ros, rwp1, rop1, done, out, xx, W, n, _GUARD, cbase0, cbase1,
                                pbase1, R, P1, P2, 1)
            continue
        cur0, cur1, mp0, mp1 = _pair_entries(Lmin, cbase0, cbase1, pbase1, xx, R)
        m = lanes_step_pair(L, cur0, flat, b, w, (cbase0 + xx - 1) * R + _GUARD + s0 - 1, P1, np.int16(mp0 + P2), mp0,
                            cur1, (pbase1 + xx) * R + _GUARD + s1 - 1, np.int16(mp1 + P2), mp1, out, b)
        _paired(L, Lmin, m, cur0, cur1, cbase0 + xx, cbase1 + xx, LANES, done, ux)
        xx += 1
    return xx


@njit(cache=True, boundscheck=False)
def _wide_pair_steps(L, flat, Lmin, rb, rws, ros, rwp1, rop1, xx, W, cbase0, cbase1, pbase1, R, P1, P2, out, done):
    # As _pair_steps, for tubes wider than one chunk (every chunk in one step, lanes_step_wide_pair) while both
    # neighbours' entries hold every chunk's reads
    n = flat.shape[0]
    while xx < W:
        ux, b, w = _pixel_layout(rb, rws, xx)
        span = (w + LANES - 1) // LANES * LANES
        if w <= LANES or b + span > n or xx < 1:
            return xx
        up = np.uint64(xx - 1)
        s0 = ros[ux] - ros[up]
        s1 = ros[ux] - rop1[ux]
        if not (_reaches(s0, rws[up], span) and _reaches(s1, rwp1[ux], span)):
            return xx
        chunks = span // LANES
        if s0 == 0 and (rws[up] + LANES - 1) // LANES == chunks and chunks <= RUN_CHUNKS_MAX:
            # a run along the row (a hole's pixels, or a block of wide tubes), its path costs in registers
            xx = lanes_run_pair(L, flat, Lmin, rb, rws, ros, rwp1, rop1, done, out, xx, W, n, _GUARD, cbase0, cbase1,
                                pbase1, R, P1, P2, chunks)
            continue
        cur0, cur1, mp0, mp1 = _pair_entries(Lmin, cbase0, cbase1, pbase1, xx, R)
        m = lanes_step_wide_pair(L, cur0, flat, b, w, span, (cbase0 + xx - 1) * R + _GUARD + s0 - 1, P1,
                                 np.int16(mp0 + P2), mp0, cur1, (pbase1 + xx) * R + _GUARD + s1 - 1,
                                 np.int16(mp1 + P2), mp1, out, b)
        _paired(L, Lmin, m, cur0, cur1, cbase0 + xx, cbase1 + xx, span, done, ux)
        xx += 1
    return xx


@njit(cache=True, inline="always")
def _wholly_outside(j, wq):
    # whether a chunk whose first disparity is index j of the neighbour's tube (wq wide) reads only outside it: its
    # LANES disparities and their neighbours, indices j - 1 .. j + LANES
    return j + LANES < 0 or j - 1 >= wq


@njit(cache=True, inline="always")
def _chunks_reach(s, span, wq, spanq):
    # whether each LANES-chunk of a tube (span wide, shifted by s against its neighbour's tube of wq disparities,
    # spanq in whole chunks) reads either within the neighbour's entry (its guard and sentinel chunk included) or
    # wholly outside its tube
    for i in range(0, span, LANES):
        j = i + s
        if not (_wholly_outside(j, wq) or 1 - _GUARD <= j <= spanq - 1):
            return False
    return True


@njit(cache=True, inline="always")
def _pixel_layout(rb, rws, xx):
    # pixel xx's unsigned index (no negative-index wrap-around code), the start of its tube and its width
    ux = np.uint64(xx)
    return ux, rb[ux], rws[ux]


@njit(cache=True, boundscheck=False)
def _common_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, dx, cbase, pbase, R, RA, P1, P2, keep, out,
                  last):
    # Steps of one direction from pixel xx on while each is the common one: a tube of one chunk whose neighbour's
    # entry is within reach (in the row before, py >= 0). Returns the first pixel that is not. A loop of its own
    # (LLVM inlines it), so that its few values stay in registers: inside the pass's loop, among the rare cases'
    # values, a fifth of a step's instructions were stack loads and stores.
    n = flat.shape[0]
    sent = np.int16(_SENTINEL)
    while xx < W:
        ux, b, w = _pixel_layout(rb, rws, xx)
        px = xx - dx
        if w > LANES or b + LANES > n or px < 0 or px >= W:
            return xx
        up = np.uint64(px)
        s = ros[ux] - rop[up]
        if s < 1 - _GUARD or s > (rwp[up] + LANES - 1) // LANES * LANES - 1:
            return xx
        cur = (cbase + xx) * R + _GUARD
        mp = Lmin[np.uint64(pbase + px)]
        pi = (pbase + px) * R + _GUARD + s - 1
        if last:  # the pass's last direction: the half-sums straight to its result
            m = lanes_step_out(L, acc, cur, flat, b, xx * RA, w, pi, P1, np.int16(mp + P2), mp, out, b)
        else:
            m = lanes_step(L, acc, cur, flat, b, xx * RA, w, pi, P1, np.int16(mp + P2), mp, keep)
        lanes_fill(L, cur + LANES, sent)
        Lmin[np.uint64(cbase + xx)] = m
        xx += 1
    return xx


@njit(cache=True, boundscheck=False)
def _sgm_pass(flat, out, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, flip, progress):
    # Half of the paths over a dense volume (D > 0: pixel (y, x) holds D disparities at (y * W + x) * D) or a tube
    # volume (D == 0: pixel (y, x) holds width[y, x] disparities from d_min + offset[y, x] at start[y, x]); the
    # half-sum goes to out (int16, same layout). Steps between pixels of different offsets compare equal
    # disparities; a disparity outside the neighbour's tube is unreachable there (the sentinel). Every direction
    # reaches back to the previous pixel of the row or to an earlier row, so a row can be swept direction by
    # direction; its first direction starts each pixel's half-sum (keep 0), the others add to it. After each row,
    # progress[flip] (if progress is not empty) says how many rows of out are done, for another thread to read.
    nd = dxs.shape[0]
    P1 = np.int16(P1)
    P2 = np.int16(P2)
    sent = np.int16(_SENTINEL)
    zero = np.int16(0)
    every = np.int16(-1)
    C = (wmax + LANES - 1) // LANES
    R = _GUARD + (C + 1) * LANES
    RA = C * LANES
    # ring buffer of the last three rows of path costs (16-path directions reach two rows back), flat
    # ... and a block of sentinels never written after them: the neighbour's path costs for a chunk that lies wholly
    # outside the neighbour's tube (every disparity it reads is unreachable there)
    outside = nd * 3 * W * R
    L = np.full(outside + 3 * LANES, sent, dtype=np.int16)
    Lmin = np.zeros(nd * 3 * W, dtype=np.int16)
    acc = np.zeros(W * RA + LANES, dtype=np.int16)  # the row's half-sums, RA per pixel (sweep order)
    mv = np.empty(LANES, np.int16)  # a wide tube's running minimum over its chunks
    n = flat.shape[0]
    starts, widths, offsets = start.reshape(-1), width.reshape(-1), offset.reshape(-1)
    # the layout of the last three rows in sweep order (start, width, offset), beside the ring buffer
    rb = np.empty(W, np.int64)
    rw = np.empty((3, W), np.int64)
    ro = np.empty((3, W), np.int64)
    paired = nd == 2 and D == 0 and dxs[0] == 1 and dys[0] == 0 and dxs[1] == 0 and dys[1] == 1
    done = np.zeros(W, np.uint8)  # pixels whose directions went paired (_pair_steps)
    for yy in range(H):
        y = H - 1 - yy if flip else yy
        slot = yy % 3
        for xx in range(W):
            x = W - 1 - xx if flip else xx
            if D > 0:
                rb[xx] = (y * W + x) * D
                rw[slot, xx] = D
                ro[slot, xx] = 0
            else:
                pix = np.uint64(y * W + x)  # unsigned flat indices: no negative-index wrap-around code
                rb[xx] = starts[pix]
                rw[slot, xx] = np.int64(widths[pix])
                ro[slot, xx] = np.int64(offsets[pix])
        # 4 paths on a tube volume: the row's and the column's direction of a pixel in one step where both are
        # common ones (no half-sum between them); the column's sweep then takes the pixels left
        pair = paired and yy >= 1
        if pair:
            done[:] = 0
        ps = (yy - 1) % 3  # the row before's slot: the column's neighbours in a paired step
        for k in range(nd):
            keep = zero if k == 0 else every
            last = k == nd - 1
            dx = dxs[k]
            py = yy - dys[k]
            pslot = py % 3
            # a row's direction (dy 0) reads only its own row: one slot for every row, whose entries stay in cache
            # (cycled over three slots like the others, its steps took 2-7 % longer at 4 paths)
            rowdir = dys[k] == 0
            cbase = (k * 3 + (0 if rowdir else slot)) * W
            pbase = (k * 3 + (0 if rowdir else pslot)) * W
            rws, ros, rwp, rop = rw[slot], ro[slot], rw[pslot], ro[pslot]  # this row's layout and the neighbours'
            xx = 0
            while xx < W:
                if pair:
                    if k == 0:
                        x0 = xx
                        xx = _pair_steps(L, flat, Lmin, rb, rws, ros, rw[ps], ro[ps], xx, W, cbase, (3 + slot) * W,
                                         (3 + ps) * W, R, P1, P2, out, done)
                        xx = _wide_pair_steps(L, flat, Lmin, rb, rws, ros, rw[ps], ro[ps], xx, W, cbase, (3 + slot) * W,
                                              (3 + ps) * W, R, P1, P2, out, done)
                        if xx != x0:  # (also where they reached the row's end)
                            continue
                    elif done[xx]:  # the paired pixels' run in a tight loop of its own (0.95-0.97x the pass)
                        while xx < W and done[xx]:
                            xx += 1
                        continue
                    # wide tubes not paired in their lean loop (it stops at paired ones); one-chunk ones below
                    x0 = xx
                    xx = _wide_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, dx, cbase, pbase, R, RA,
                                     P1, P2, keep, out, last, done)
                    if xx != x0:
                        continue
                elif py >= 0:
                    # the common steps in lean loops of their own (the neighbour's entry within reach: one chunk,
                    # then wide tubes); this loop takes the pixel where both stop
                    x0 = -1
                    while x0 != xx and xx < W:
                        x0 = xx
                        xx = _common_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, dx, cbase, pbase, R,
                                           RA, P1, P2, keep, out, last)
                        xx = _wide_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, dx, cbase, pbase, R, RA,
                                         P1, P2, keep, out, last, done)
                    if xx >= W:
                        break
                cur = (cbase + xx) * R + _GUARD
                px = xx - dx
                prev = (pbase + px) * R + _GUARD
                ai = xx * RA
                b = rb[xx]
                w = rws[xx]
                span = (w + LANES - 1) // LANES * LANES
                safe = b + span <= n  # every lane's cost and result lie inside the volume
                if px < 0 or px >= W or py < 0:
                    if safe:
                        m = sent
                        for i in range(0, span, LANES):
                            m = min(m, lanes_first(L, acc, cur + i, flat, b + i, ai + i, w - i, keep))
                    else:
                        m = _step_scalar(L, acc[ai:], cur, flat, b, w, span, cur, w, 0, P1, sent, zero, True, keep)
                else:
                    q = pbase + px
                    wq = rwp[px]
                    s = ros[xx] - rop[px]
                    mp = Lmin[q]
                    jump = np.int16(mp + P2)
                    spanq = (wq + LANES - 1) // LANES * LANES
                    if safe and 1 - _GUARD <= s <= spanq + LANES - 1 - span:  # a wide tube (one chunk: above)
                        m = lanes_step_wide(L, acc, cur, flat, b, ai, w, span, prev + s - 1, P1, jump, mp, keep)
                    elif safe and _chunks_reach(s, span, wq, spanq):
                        # tubes far apart (a pixel searching the whole range beside a narrow tube): chunk by chunk,
                        # those wholly outside the neighbour's tube from the block of sentinels
                        for i in range(0, span, LANES):
                            j = i + s
                            pi = outside if _wholly_outside(j, wq) else prev + j - 1
                            lanes_step_min(L, acc, cur + i, flat, b + i, ai + i, w - i, pi, P1, jump, mp, keep, mv,
                                           i == 0)
                        m = lanes_reduce(mv)
                    else:
                        m = _step_scalar(L, acc[ai:], cur, flat, b, w, span, prev, wq, s, P1, jump, mp, False, keep)
                lanes_fill(L, cur + span, sent)
                Lmin[cbase + xx] = m
                if last:  # the pixel's half-sums to the result (the lean loops store them there themselves)
                    if safe:
                        for i in range(0, span, LANES):
                            lanes_copy(acc, ai + i, out, b + i, w - i)
                    else:
                        for i in range(w):
                            out[b + i] = acc[ai + i]
                xx += 1
        if progress.shape[0] > 0:
            store_release(progress, np.int64(flip), yy + 1)


@njit(cache=True, parallel=True)
def _sgm_two_passes(flat, fwd, bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2):
    for t in prange(2):
        if t == 0:
            _sgm_pass(flat, fwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, False, _NO_PROGRESS)
        else:
            _sgm_pass(flat, bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, True, _NO_PROGRESS)


@njit(cache=True, parallel=True)
def _sgm_select_kernel(flat, fwd, bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, d_min, subpixel,
                       lr_check, lr_threshold, keep):
    # _sgm_two_passes, each row's disparity selected as soon as both passes hold it. A pass tells how many rows it
    # has done (progress, -1 before it starts); once its own pass is over, a thread selects the rows from its far
    # end (the rows the other pass did first), as long as the other pass holds them and no one took them, and stops
    # at the first it cannot select; the rows left go to both threads after. No thread waits for another: run one
    # after the other (a single thread), the first selects nothing and the second everything.
    fu, bu = fwd.view(np.uint16), bwd.view(np.uint16)  # the half-sums as the selection reads them
    disp = np.empty((H, W), dtype=np.float32)
    status = np.zeros((H, W if keep else 1), dtype=np.int8)  # keep: 1 where the check fails
    taken = np.zeros(H, np.int64)  # 1: a thread has selected (or is selecting) the row
    progress = np.full(2, -1, np.int64)
    for t in prange(2):
        store_release(progress, t, 0)
        if t == 0:
            _sgm_pass(flat, fwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, False, progress)
        else:
            _sgm_pass(flat, bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, True, progress)
        other = 1 - t
        for k in range(H):
            y = H - 1 - k if t == 0 else k
            # the forward pass's thread takes rows from the bottom (the reverse pass's first), the other from the top
            if load_acquire(progress, other) < k + 1 or exchange(taken, y, 1) != 0:
                break
            select_row(fu, bu, y, W, D, start, width, offset, wmax, d_min, subpixel, lr_check, lr_threshold, keep,
                       disp, status)
    m = band_pairs(H)
    for i in prange(m):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            if taken[y] == 0:
                select_row(fu, bu, y, W, D, start, width, offset, wmax, d_min, subpixel, lr_check, lr_threshold,
                           keep, disp, status)
    return disp, status


def sgm_aggregate_select(cost, p1, p2, d_min, paths=8, max_cost=None, tubes=None, subpixel=True, lr_check=False,
                         lr_threshold=1, return_status=False):
    """:func:`sgm_aggregate_passes` followed by :func:`.disparity.select_disparity` of its two half-sums (the same
    arguments; ``d_min`` the disparity at index 0), in one kernel: each row's disparity is selected as soon as both
    passes have done it, by the thread whose pass ended first while the other pass goes on, so that its core does
    not wait idle (run side by side, the reverse pass took 1.1-2x the forward pass's time on the speed pairs). The
    same result as the two functions, bit for bit; aggregation and selection 0.83-0.99x of their time on the speed
    pairs' 4-path tube volumes (docs/tubes.md).

    Returns the disparity (H, W) float32, or ``(disparity, status)`` with ``return_status`` (as
    :func:`.disparity.select_disparity`).
    """
    fwd, bwd, args = _passes_setup(cost, p1, p2, paths, max_cost, tubes)
    check = bool(lr_check or return_status)
    disp, status = _sgm_select_kernel(*args, int(d_min), bool(subpixel), check, int(lr_threshold),
                                      bool(return_status))
    return finish_selection(disp, status, lr_check, return_status)


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
    fwd, bwd, args = _passes_setup(cost, p1, p2, paths, max_cost, tubes)
    _sgm_two_passes(*args)
    return fwd, bwd


def _passes_setup(cost, p1, p2, paths, max_cost, tubes):
    # the checks, the two uint16 results and _sgm_two_passes's arguments (the results as int16 views: a half-sum is
    # <= 32767, the same bits)
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
    shape = tubes.shape if tubes is not None else cost.shape[:2]
    flat, W, D, start, width, offset = volume_layout(cost, shape, tubes)
    wmax = int(tubes.max_width) if tubes is not None else D
    return fwd, bwd, (flat, fwd.reshape(-1).view(np.int16), bwd.reshape(-1).view(np.int16), shape[0], W, D, start,
                      width, offset, wmax, dxs, dys, np.int32(p1), np.int32(p2))


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
