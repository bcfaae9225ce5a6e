"""SGM's pass (:mod:`.sgm`): half of the paths swept over the rows in raster order, on one thread or several.

A row is swept one direction at a time (the lean loops below take the common steps; module :mod:`.sgm` tells how).
Its path costs go to a ring buffer of the last rows, shared by the threads of the pass: each thread takes the next
row and sweeps it in blocks, every direction over a block before the next, as soon as the rows before it have done
the pixels the block's steps read (:mod:`.kernels.row_handover`). Every path cost is the same whichever thread
computes it: the result does not depend on the count. On one thread per pass a row is one block and nothing is
published (the two-core layout: one pass per core).
"""

import numpy as np

from ..runtime.kernel import kernel
from .kernels.atomics import store_release
from .kernels.lanes import (LANES, SENTINEL, lanes_copy, lanes_fill, lanes_first, lanes_reduce, lanes_step,
                            lanes_step_min, lanes_step_out, lanes_step_pair, lanes_step_wide, lanes_step_wide_out,
                            lanes_step_wide_pair)
from .kernels.lanes_runs import RUN_CHUNKS_MAX, lanes_run_pair
from .kernels.row_handover import block_end, block_size, new_progress, next_row, publish

# Path costs live in int16: every path cost is at most max_cost + P2, and check_sgm_bounds keeps
# paths * (max_cost + P2) <= 65535, so a path cost is <= 16383 and each half-sum (half the paths) <= 32767.
_SENTINEL = SENTINEL  # above any path cost; sentinel + P1 still fits int16
# Each ring-buffer entry: _GUARD sentinels (never written), the path costs in whole chunks of LANES (the sentinel past
# the tube), then one chunk of sentinels. A step reads its neighbour's entry shifted by the difference of their tube
# offsets; within these bounds every disparity outside the neighbour's tube reads the sentinel, with no test.
_GUARD = LANES


@kernel(boundscheck=False)
def path_start(cur, c, acc):
    m = np.int16(_SENTINEL)
    for d in range(c.shape[0]):
        v = np.int16(c[d])
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    return m


@kernel(inline=True, boundscheck=False)
def tube_value(prev, wq, j, P1):
    # min(L(j), L(j -+ 1) + P1) of the previous pixel's tube (wq wide) at its index j; outside it: the sentinel
    sent = np.int16(_SENTINEL)
    a = prev[j + 1] if 0 <= j < wq else sent
    b = prev[j] if 1 <= j <= wq else sent
    e = prev[j + 2] if -1 <= j < wq - 1 else sent
    return min(a, min(b, e) + P1)


@kernel(boundscheck=False)
def _step_scalar(L, acc, cur, cost, b, w, span, prev, wq, s, P1, jump, mp, first, sum_mask):
    # The step of _sgm_pass one disparity at a time, for what its vector steps cannot reach: the last pixels of the
    # volume (their lanes would read past its end) and shifts past the guard of the neighbour's entry. sum_mask as in
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
        acc[i] = (acc[i] & sum_mask) + v
        m = min(m, v)
    return m


@kernel(boundscheck=False)
def _wide_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, end, dx, cbase, pbase, R, RA, P1, P2, sum_mask, out,
                last, done):
    # As _common_steps, for tubes wider than one chunk (a pixel no LiDAR reaches, beside others alike): every chunk in
    # one step (lanes_step_wide), while the neighbour's entry holds every chunk's reads; stops at a pixel whose
    # directions went paired (done)
    n = flat.shape[0]
    sent = np.int16(_SENTINEL)
    while xx < end:
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
            m = lanes_step_wide(L, acc, cur, flat, b, xx * RA, w, span, pi, P1, np.int16(mp + P2), mp, sum_mask)
        lanes_fill(L, cur + span, sent)
        Lmin[np.uint64(cbase + xx)] = m
        xx += 1
    return xx


@kernel(inline=True)
def _reaches(s, wq, span):
    # whether a step over span disparities (whole chunks) shifted by s against its neighbour's tube (wq wide) reads
    # only inside the neighbour's ring-buffer entry (its guard and sentinel chunk included)
    return 1 - _GUARD <= s <= (wq + LANES - 1) // LANES * LANES + LANES - 1 - span


@kernel(inline=True)
def _pair_entries(Lmin, cbase0, cbase1, pbase1, xx, R):
    # a paired step's two ring-buffer entries and its two neighbours' minima (the row's pixel xx - 1, the column's
    # pixel xx of the row before)
    return ((cbase0 + xx) * R + _GUARD, (cbase1 + xx) * R + _GUARD, Lmin[np.uint64(cbase0 + xx - 1)],
            Lmin[np.uint64(pbase1 + xx)])


@kernel(inline=True)
def _paired(L, Lmin, m, cur0, cur1, at0, at1, span, done, ux):
    # after a paired step: the sentinel chunk after both entries, both minima (m: the first in the low 16 bits) at
    # Lmin[at0] and Lmin[at1], the pixel done
    sent = np.int16(_SENTINEL)
    lanes_fill(L, cur0 + span, sent)
    lanes_fill(L, cur1 + span, sent)
    Lmin[np.uint64(at0)] = np.int16(m & 0xFFFF)
    Lmin[np.uint64(at1)] = np.int16(m >> 16)
    done[ux] = 1


@kernel(boundscheck=False)
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


@kernel(boundscheck=False)
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


@kernel(inline=True)
def _wholly_outside(j, wq):
    # whether a chunk whose first disparity is index j of the neighbour's tube (wq wide) reads only outside it: its
    # LANES disparities and their neighbours, indices j - 1 .. j + LANES
    return j + LANES < 0 or j - 1 >= wq


@kernel(inline=True)
def _chunks_reach(s, span, wq, spanq):
    # whether each LANES-chunk of a tube (span wide, shifted by s against its neighbour's tube of wq disparities,
    # spanq in whole chunks) reads either within the neighbour's entry (its guard and sentinel chunk included) or
    # wholly outside its tube
    for i in range(0, span, LANES):
        j = i + s
        if not (_wholly_outside(j, wq) or 1 - _GUARD <= j <= spanq - 1):
            return False
    return True


@kernel(inline=True)
def _pixel_layout(rb, rws, xx):
    # pixel xx's unsigned index (no negative-index wrap-around code), the start of its tube and its width
    ux = np.uint64(xx)
    return ux, rb[ux], rws[ux]


@kernel(boundscheck=False)
def _common_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, end, dx, cbase, pbase, R, RA, P1, P2, sum_mask,
                  out, last):
    # Steps of one direction from pixel xx on (up to end) while each is the common one: a tube of one chunk whose
    # neighbour's entry is within reach (in the row before, py >= 0). Returns the first pixel that is not. A loop of
    # its own (LLVM inlines it), so that its few values stay in registers: inside the pass's loop, among the rare
    # cases' values, a fifth of a step's instructions were stack loads and stores.
    n = flat.shape[0]
    sent = np.int16(_SENTINEL)
    while xx < end:
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
            m = lanes_step(L, acc, cur, flat, b, xx * RA, w, pi, P1, np.int16(mp + P2), mp, sum_mask)
        lanes_fill(L, cur + LANES, sent)
        Lmin[np.uint64(cbase + xx)] = m
        xx += 1
    return xx


@kernel
def pass_ring(H, W, nd, wmax, threads):
    """The buffers a pass's ``threads`` share (:func:`sgm_rows`): the ring buffer of path costs ``L`` and of their
    minima ``Lmin`` (per direction: a slot per row in flight and two rows back, and one per thread for the row's own
    direction), the rows' layouts ``rw``, ``ro`` (width and offset per slot), ``progress`` (per row, several threads
    only) and the counter ``claim`` the threads take rows from."""
    C = (wmax + LANES - 1) // LANES
    R = _GUARD + (C + 1) * LANES
    slots = 3 if threads == 1 else threads + 3
    per = slots + threads
    # after the entries: a block of sentinels never written, the neighbour's path costs for a chunk that lies wholly
    # outside the neighbour's tube (every disparity it reads is unreachable there)
    L = np.full(nd * per * W * R + 3 * LANES, np.int16(_SENTINEL), dtype=np.int16)
    Lmin = np.zeros(nd * per * W, dtype=np.int16)
    rw = np.empty((slots, W), np.int64)
    ro = np.empty((slots, W), np.int64)
    progress = new_progress(H, threads)
    claim = np.zeros(1, np.int64)
    return L, Lmin, rw, ro, progress, claim


@kernel(boundscheck=False)
def sgm_rows(flat, out, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, flip, L, Lmin, rw, ro, progress, claim,
             threads, thread, rows_done, done_base):
    """Half of the paths over a dense volume (D > 0: pixel (y, x) holds D disparities at (y * W + x) * D) or a tube
    volume (D == 0: pixel (y, x) holds width[y, x] disparities from d_min + offset[y, x] at start[y, x]); the
    half-sum goes to out (int16, same layout). ``flip``: the reverse pass (rows and pixels from the far end). This
    is thread ``thread`` of the pass's ``threads``, with the buffers of :func:`pass_ring`: it takes rows from
    ``claim`` until none is left, and sets ``rows_done[done_base + y]`` to 1 after row y (image rows).

    Steps between pixels of different offsets compare equal disparities; a disparity outside the neighbour's tube is
    unreachable there (the sentinel). Every direction reaches back to the previous pixel of the row or to an earlier
    row, so a row (or a block of it) can be swept direction by direction; its first direction starts each pixel's
    half-sum (sum_mask 0), the others add to it."""
    nd = dxs.shape[0]
    P1 = np.int16(P1)
    P2 = np.int16(P2)
    zero = np.int16(0)
    every = np.int16(-1)
    C = (wmax + LANES - 1) // LANES
    R = _GUARD + (C + 1) * LANES
    RA = C * LANES
    slots = rw.shape[0]
    per = slots + threads  # ring-buffer slots per direction: the rows', then one per thread for its row's direction
    outside = nd * per * W * R
    acc = np.zeros(W * RA + LANES, dtype=np.int16)  # the row's half-sums, RA per pixel (sweep order)
    mv = np.empty(LANES, np.int16)  # a wide tube's running minimum over its chunks
    starts, widths, offsets = start.reshape(-1), width.reshape(-1), offset.reshape(-1)
    rb = np.empty(W, np.int64)  # the row's tube starts in sweep order (rw, ro: widths and offsets, per slot)
    paired = nd == 2 and D == 0 and dxs[0] == 1 and dys[0] == 0 and dxs[1] == 0 and dys[1] == 1
    done = np.zeros(W, np.uint8)  # pixels whose directions went paired (_pair_steps)
    several = threads > 1
    block = block_size(W, threads)
    back1 = W  # the least dx of the directions reaching one row back, and two (W: none)
    back2 = W
    for k in range(nd):
        if dys[k] == 1:
            back1 = min(back1, dxs[k])
        elif dys[k] == 2:
            back2 = min(back2, dxs[k])
    while True:
        yy = next_row(claim, progress, H, W, slots, 2, threads)  # 16 paths read two rows back
        if yy >= H:
            break
        y = H - 1 - yy if flip else yy
        slot = yy % slots
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
        ps = (yy - 1) % slots  # the row before's slot: the column's neighbours in a paired step
        b0 = 0
        while b0 < W:  # one block (the whole row on one thread)
            end = block_end(progress, yy, b0, W, block, back1, back2) if several else W
            for k in range(nd):
                sum_mask = zero if k == 0 else every
                last = k == nd - 1
                dx = dxs[k]
                py = yy - dys[k]
                pslot = py % slots
                # a row's direction (dy 0) reads only its own row: one slot per thread, whose entries stay in cache
                # (cycled over the rows' slots like the others, its steps took 2-7 % longer at 4 paths)
                rowdir = dys[k] == 0
                cbase = (k * per + (slots + thread if rowdir else slot)) * W
                pbase = (k * per + (slots + thread if rowdir else pslot)) * W
                rws, ros, rwp, rop = rw[slot], ro[slot], rw[pslot], ro[pslot]  # this row's layout, the neighbours'
                xx = b0
                while xx < end:
                    if pair:
                        if k == 0:
                            x0 = xx
                            xx = _pair_steps(L, flat, Lmin, rb, rws, ros, rw[ps], ro[ps], xx, end, cbase,
                                             (per + slot) * W, (per + ps) * W, R, P1, P2, out, done)
                            xx = _wide_pair_steps(L, flat, Lmin, rb, rws, ros, rw[ps], ro[ps], xx, end, cbase,
                                                  (per + slot) * W, (per + ps) * W, R, P1, P2, out, done)
                            if xx != x0:  # (also where they reached the block's end)
                                continue
                        elif done[xx]:  # the paired pixels' run in a tight loop of its own (0.95-0.97x the pass)
                            while xx < end and done[xx]:
                                xx += 1
                            continue
                        # wide tubes not paired in their lean loop (it stops at paired ones); one-chunk ones below
                        x0 = xx
                        xx = _wide_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, end, dx, cbase, pbase, R,
                                         RA, P1, P2, sum_mask, out, last, done)
                        if xx != x0:
                            continue
                    elif py >= 0:
                        # the common steps in lean loops of their own (the neighbour's entry within reach: one
                        # chunk, then wide tubes); this loop takes the pixel where both stop
                        x0 = -1
                        while x0 != xx and xx < end:
                            x0 = xx
                            xx = _common_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, end, dx, cbase,
                                               pbase, R, RA, P1, P2, sum_mask, out, last)
                            xx = _wide_steps(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, end, dx, cbase,
                                             pbase, R, RA, P1, P2, sum_mask, out, last, done)
                        if xx >= end:
                            break
                    _rare_step(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, dx, py, cbase, pbase, R, RA, P1,
                               P2, sum_mask, out, last, outside, mv)
                    xx += 1
            b0 = end
            if several:
                publish(progress, yy, end)
        store_release(rows_done, done_base + y, 1)


@kernel(inline=True, boundscheck=False)
def _rare_step(L, acc, flat, Lmin, rb, rws, ros, rwp, rop, xx, W, dx, py, cbase, pbase, R, RA, P1, P2, sum_mask, out,
               last, outside, mv):
    # one direction's step of pixel xx where the lean loops stop: a path's first pixel, tubes far apart, the
    # volume's last pixels
    n = flat.shape[0]
    sent = np.int16(_SENTINEL)
    zero = np.int16(0)
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
                m = min(m, lanes_first(L, acc, cur + i, flat, b + i, ai + i, w - i, sum_mask))
        else:
            m = _step_scalar(L, acc[ai:], cur, flat, b, w, span, cur, w, 0, P1, sent, zero, True, sum_mask)
    else:
        q = pbase + px
        wq = rwp[px]
        s = ros[xx] - rop[px]
        mp = Lmin[q]
        jump = np.int16(mp + P2)
        spanq = (wq + LANES - 1) // LANES * LANES
        if safe and 1 - _GUARD <= s <= spanq + LANES - 1 - span:  # a wide tube (one chunk: the lean loops)
            m = lanes_step_wide(L, acc, cur, flat, b, ai, w, span, prev + s - 1, P1, jump, mp, sum_mask)
        elif safe and _chunks_reach(s, span, wq, spanq):
            # tubes far apart (a pixel searching the whole range beside a narrow tube): chunk by chunk, those wholly
            # outside the neighbour's tube from the block of sentinels
            for i in range(0, span, LANES):
                j = i + s
                pi = outside if _wholly_outside(j, wq) else prev + j - 1
                lanes_step_min(L, acc, cur + i, flat, b + i, ai + i, w - i, pi, P1, jump, mp, sum_mask, mv, i == 0)
            m = lanes_reduce(mv)
        else:
            m = _step_scalar(L, acc[ai:], cur, flat, b, w, span, prev, wq, s, P1, jump, mp, False, sum_mask)
    lanes_fill(L, cur + span, sent)
    Lmin[cbase + xx] = m
    if last:  # the pixel's half-sums to the result (the lean loops store them there themselves)
        if safe:
            for i in range(0, span, LANES):
                lanes_copy(acc, ai + i, out, b + i, w - i)
        else:
            for i in range(w):
                out[b + i] = acc[ai + i]
