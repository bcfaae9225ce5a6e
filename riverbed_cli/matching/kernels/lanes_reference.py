"""The vector steps of :mod:`.lanes` as plain loops: what each computes, lane by lane, for a reader and for the tests
(``tests/test_lanes.py`` runs every step against its statement here on random data): the SGM steps, the paired
steps of 4-path passes, the selection's sums, its search and the right image's votes, the census cost and transform.

The same arguments as the steps, the same arrays modified in place, the same value returned. Lanes run ``d = 0 ..
LANES - 1``; ``lanes`` of them are valid (``<= 0``: none); path costs are int16 (their sums wrap as int16 does),
costs are widened to int16, the selection's sums are uint16.
"""

import numpy as np

from .lanes import SENTINEL
from .vector_ir import LANES


def _i16(v):
    # an int16 result as the vector code's wraps it
    return np.int16(((int(v) + 0x8000) & 0xFFFF) - 0x8000)


def _step_values(L, cost, ci, lanes, prev, p1, jump, mp):
    # cost + min(a, min(b, e) + p1, jump) - mp per lane, the sentinel past the valid lanes
    out = []
    for d in range(LANES):
        if d < lanes:
            b, a, e = int(L[prev + d]), int(L[prev + d + 1]), int(L[prev + d + 2])
            out.append(_i16(int(cost[ci + d]) + min(a, min(b, e) + int(p1), int(jump)) - int(mp)))
        else:
            out.append(np.int16(SENTINEL))
    return out


def _store(L, acc, cur, ai, sum_mask, values):
    # the path costs to L, and joined to the half-sum acc (sum_mask -1: added, 0: started), every lane
    for d, v in enumerate(values):
        L[cur + d] = v
        acc[ai + d] = _i16((int(acc[ai + d]) & int(sum_mask)) + int(v))


def lanes_first(L, acc, cur, cost, ci, ai, lanes, sum_mask):
    """:func:`.lanes.lanes_first`: a path's first pixel, its path costs its costs."""
    values = [_i16(int(cost[ci + d])) if d < lanes else np.int16(SENTINEL) for d in range(LANES)]
    _store(L, acc, cur, ai, sum_mask, values)
    return min(values)


def lanes_step(L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, sum_mask):
    """:func:`.lanes.lanes_step`: one SGM step on ``LANES`` disparities."""
    values = _step_values(L, cost, ci, lanes, prev, p1, jump, mp)
    _store(L, acc, cur, ai, sum_mask, values)
    return min(values)


def lanes_step_out(L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, out, oi):
    """:func:`.lanes.lanes_step_out`: the step in a pass's last direction, the half-sums to ``out`` (valid lanes)."""
    values = _step_values(L, cost, ci, lanes, prev, p1, jump, mp)
    for d, v in enumerate(values):
        L[cur + d] = v
        if d < lanes:
            out[oi + d] = _i16(int(acc[ai + d]) + int(v))
    return min(values)


def lanes_step_min(L, acc, cur, cost, ci, ai, lanes, prev, p1, jump, mp, sum_mask, mv, first):
    """:func:`.lanes.lanes_step_min`: the step of one chunk, its lanes joined to the running minimum ``mv``."""
    values = _step_values(L, cost, ci, lanes, prev, p1, jump, mp)
    _store(L, acc, cur, ai, sum_mask, values)
    for d, v in enumerate(values):
        mv[d] = v if first else min(mv[d], v)


def lanes_step_wide(L, acc, cur, cost, ci, ai, lanes, span, prev, p1, jump, mp, sum_mask):
    """:func:`.lanes.lanes_step_wide`: the step over ``span`` disparities, a chunk at a time."""
    return min(lanes_step(L, acc, cur + i, cost, ci + i, ai + i, lanes - i, prev + i, p1, jump, mp, sum_mask)
               for i in range(0, span, LANES))


def lanes_step_wide_out(L, acc, cur, cost, ci, ai, lanes, span, prev, p1, jump, mp, out, oi):
    """:func:`.lanes.lanes_step_wide_out`: :func:`lanes_step_wide` in a pass's last direction."""
    return min(lanes_step_out(L, acc, cur + i, cost, ci + i, ai + i, lanes - i, prev + i, p1, jump, mp, out, oi + i)
               for i in range(0, span, LANES))


def lanes_reduce(mv):
    """:func:`.lanes.lanes_reduce`: the minimum of ``mv[0:LANES]``."""
    return min(mv[:LANES])


def lanes_fill(arr, index, value):
    """:func:`.lanes.lanes_fill`."""
    arr[index:index + LANES] = value


def lanes_copy(src, si, dst, di, lanes):
    """:func:`.lanes.lanes_copy`: the valid lanes copied, the others left as they are."""
    for d in range(min(max(lanes, 0), LANES)):
        dst[di + d] = src[si + d]


def lanes_sum(a, b, ai, out, oi, lanes):
    """:func:`.lanes.lanes_sum`: the selection's sums of the valid lanes, 65535 past them; their minimum."""
    sums = [np.uint16((int(a[ai + d]) + int(b[ai + d])) & 0xFFFF) if d < lanes else np.uint16(65535)
            for d in range(LANES)]
    out[oi:oi + LANES] = sums
    return min(sums)


def lanes_sum_wide(a, b, ai, out, oi, lanes, span):
    """:func:`.lanes.lanes_sum_wide`: the sums over ``span`` disparities; ``minimum << 32 | index`` of the first
    disparity holding the minimum."""
    best, at = 65536, 0
    for i in range(0, span, LANES):
        lanes_sum(a, b, ai + i, out, oi + i, lanes - i)
        for d in range(LANES):
            if int(out[oi + i + d]) < best:
                best, at = int(out[oi + i + d]), i + d
    return (best << 32) | at


def _pair_chunk(L, cur, cost, ci, lanes, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out, oi):
    # the two directions one after the other (the second reads L after the first has stored), their sum to out
    mins = []
    both = []
    for c, p, j, m in ((cur, prev, jump, mp), (cur2, prev2, jump2, mp2)):
        values = _step_values(L, cost, ci, lanes, p, p1, j, m)
        L[c:c + LANES] = values
        both.append(values)
        mins.append(min(values))
    for d in range(min(max(lanes, 0), LANES)):
        out[oi + d] = _i16(int(both[0][d]) + int(both[1][d]))
    return mins


def _pair_minima(m1, m2):
    # the first minimum in the low 16 bits of an int32, the second in the high ones
    return np.int32(((int(m1) & 0xFFFF) | ((int(m2) & 0xFFFF) << 16)) - ((int(m2) & 0x8000) << 17))


def lanes_step_pair(L, cur, cost, ci, lanes, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out, oi):
    """:func:`.lanes.lanes_step_pair`: one pixel's steps in two directions, the sum of their path costs to ``out``."""
    return _pair_minima(*_pair_chunk(L, cur, cost, ci, lanes, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out, oi))


def lanes_step_wide_pair(L, cur, cost, ci, lanes, span, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out, oi):
    """:func:`.lanes.lanes_step_wide_pair`: :func:`lanes_step_pair` over ``span`` disparities, a chunk at a time."""
    m1 = m2 = np.int16(SENTINEL)
    for i in range(0, span, LANES):
        a, b = _pair_chunk(L, cur + i, cost, ci + i, lanes - i, prev + i, p1, jump, mp, cur2 + i, prev2 + i, jump2,
                           mp2, out, oi + i)
        m1, m2 = min(m1, a), min(m2, b)
    return _pair_minima(m1, m2)


def lanes_find(arr, index, value):
    """:func:`.lanes.lanes_find`: the first lane holding ``value``, ``LANES`` if none."""
    for d in range(LANES):
        if arr[index + d] == value:
            return d
    return LANES


def lanes_vote(sums, si, lanes, cost, best, top, xr0, W, d0, n=LANES):
    """:func:`.lanes.lanes_vote` (``n`` lanes; ``LANES // 2``: :func:`.lanes.lanes_vote_half`): each candidate
    replaces the right pixel's best where lower, or equal with a lower index."""
    for lane in range(min(lanes, n)):
        xr = xr0 - lane
        if not 0 <= xr < W:
            continue
        s, d = int(sums[si + lane]), d0 + lane
        if s < cost[top - lane] or (s == cost[top - lane] and d < best[top - lane]):
            cost[top - lane], best[top - lane] = s, d


def lanes_census(flat, fi, a, row, top, scale, n=LANES):
    """:func:`.lanes.lanes_census` (``n`` lanes; ``LANES // 2``: :func:`.lanes.lanes_census_half`): Hamming
    distances to the right image's census row, scaled, every lane."""
    for i in range(n):
        flat[fi + i] = np.uint16((bin(int(a) ^ int(row[top - i])).count("1") * int(scale)) & 0xFFFF)


def lanes_census_bits(pad, ci, offsets, out, oi):
    """:func:`.lanes.lanes_census_bits`: each pixel's word, one bit per neighbour (darker than the centre), in the
    window's order."""
    for i in range(LANES):
        word = 0
        for k in offsets:
            word = ((word << 1) | int(pad[ci + i + k] < pad[ci + i])) & 0xFFFFFFFFFFFFFFFF
        out[oi + i] = np.uint64(word)
