"""Every SGM and selection step of matching/kernels/lanes.py against its plain statement (kernels/lanes_reference.py)
on random data: the arrays it writes and the value it returns, for no, some, all and more than LANES valid lanes."""

import numpy as np
import pytest
from numba import njit

from riverbed_cli.matching.kernels import lanes, lanes_reference as ref
from riverbed_cli.matching.kernels.vector_ir import LANES


@njit
def _first(L, acc, cur, cost, ci, ai, n, keep):
    return lanes.lanes_first(L, acc, cur, cost, ci, ai, n, keep)


@njit
def _step(L, acc, cur, cost, ci, ai, n, prev, p1, jump, mp, keep):
    return lanes.lanes_step(L, acc, cur, cost, ci, ai, n, prev, p1, jump, mp, keep)


@njit
def _step_out(L, acc, cur, cost, ci, ai, n, prev, p1, jump, mp, out, oi):
    return lanes.lanes_step_out(L, acc, cur, cost, ci, ai, n, prev, p1, jump, mp, out, oi)


@njit
def _step_min(L, acc, cur, cost, ci, ai, n, prev, p1, jump, mp, keep, mv, first):
    lanes.lanes_step_min(L, acc, cur, cost, ci, ai, n, prev, p1, jump, mp, keep, mv, first)
    return lanes.lanes_reduce(mv)


@njit
def _step_wide(L, acc, cur, cost, ci, ai, n, span, prev, p1, jump, mp, keep):
    return lanes.lanes_step_wide(L, acc, cur, cost, ci, ai, n, span, prev, p1, jump, mp, keep)


@njit
def _step_wide_out(L, acc, cur, cost, ci, ai, n, span, prev, p1, jump, mp, out, oi):
    return lanes.lanes_step_wide_out(L, acc, cur, cost, ci, ai, n, span, prev, p1, jump, mp, out, oi)


@njit
def _fill_copy(arr, index, value, src, si, dst, di, n):
    lanes.lanes_fill(arr, index, value)
    lanes.lanes_copy(src, si, dst, di, n)


@njit
def _sum(a, b, ai, out, oi, n):
    return lanes.lanes_sum(a, b, ai, out, oi, n)


@njit
def _sum_wide(a, b, ai, out, oi, n, span):
    return lanes.lanes_sum_wide(a, b, ai, out, oi, n, span)


COUNTS = [-3, 0, 1, 7, LANES - 1, LANES, LANES + 5]


def _arrays(rng, dtype):
    size = 6 * LANES
    L = rng.integers(0, 900, size).astype(np.int16)
    acc = rng.integers(0, 3000, size).astype(np.int16)
    cost = rng.integers(0, 255 if dtype == np.uint8 else 2000, size).astype(dtype)
    return L, acc, cost


def _both(fn, reference, *args):
    # the step on copies of the arrays, its statement on other copies: the same arrays, the same value
    a = [x.copy() if isinstance(x, np.ndarray) else x for x in args]
    b = [x.copy() if isinstance(x, np.ndarray) else x for x in args]
    got, want = fn(*a), reference(*b)
    for x, y in zip(a, b):
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y)
    return got, want


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("n", COUNTS)
def test_the_sgm_steps_are_their_statements(dtype, n):
    rng = np.random.default_rng(n + 10 + 100 * (dtype == np.uint8))
    for _ in range(5):
        L, acc, cost = _arrays(rng, dtype)
        p1, mp = np.int16(rng.integers(1, 20)), np.int16(rng.integers(0, 300))
        jump = np.int16(mp + rng.integers(20, 200))
        cur, ci, ai, prev = np.int64(3 * LANES), np.int64(5), np.int64(LANES + 3), np.int64(1)
        for keep in (np.int16(0), np.int16(-1)):
            got, want = _both(_first, ref.lanes_first, L, acc, cur, cost, ci, ai, np.int64(n), keep)
            assert got == want
            got, want = _both(_step, ref.lanes_step, L, acc, cur, cost, ci, ai, np.int64(n), prev, p1, jump, mp,
                              keep)
            assert got == want
            mv = rng.integers(0, 900, LANES).astype(np.int16)
            for first in (True, False):
                a = [L.copy(), acc.copy(), mv.copy()]
                got = _step_min(a[0], a[1], cur, cost, ci, ai, np.int64(n), prev, p1, jump, mp, keep, a[2], first)
                b = [L.copy(), acc.copy(), mv.copy()]
                ref.lanes_step_min(b[0], b[1], cur, cost, ci, ai, n, prev, p1, jump, mp, keep, b[2], first)
                for x, y in zip(a, b):
                    np.testing.assert_array_equal(x, y)
                assert got == ref.lanes_reduce(b[2])
        out = rng.integers(0, 900, 4 * LANES).astype(np.int16)
        got, want = _both(_step_out, ref.lanes_step_out, L, acc, cur, cost, ci, ai, np.int64(n), prev, p1, jump, mp,
                          out, np.int64(7))
        assert got == want


@pytest.mark.parametrize("n", [0, 5, LANES, LANES + 1, 2 * LANES - 1, 2 * LANES, 3 * LANES])
def test_the_wide_steps_are_their_statements(n):
    rng = np.random.default_rng(n)
    span = np.int64(max(LANES, -(-n // LANES) * LANES))
    for dtype in (np.uint8, np.uint16):
        size = 10 * LANES
        L = rng.integers(0, 900, size).astype(np.int16)
        acc = rng.integers(0, 3000, size).astype(np.int16)
        cost = rng.integers(0, 250, size).astype(dtype)
        p1, mp = np.int16(7), np.int16(rng.integers(0, 300))
        jump = np.int16(mp + 90)
        cur, ci, ai, prev = np.int64(5 * LANES), np.int64(2), np.int64(LANES), np.int64(0)
        for keep in (np.int16(0), np.int16(-1)):
            got, want = _both(_step_wide, ref.lanes_step_wide, L, acc, cur, cost, ci, ai, np.int64(n), span, prev,
                              p1, jump, mp, keep)
            assert got == want
        out = rng.integers(0, 900, 6 * LANES).astype(np.int16)
        got, want = _both(_step_wide_out, ref.lanes_step_wide_out, L, acc, cur, cost, ci, ai, np.int64(n), span,
                          prev, p1, jump, mp, out, np.int64(3))
        assert got == want


@pytest.mark.parametrize("n", COUNTS)
def test_fill_copy_and_the_selections_sums_are_their_statements(n):
    rng = np.random.default_rng(n + 10)
    arr = rng.integers(0, 100, 3 * LANES).astype(np.int16)
    src = rng.integers(0, 100, 3 * LANES).astype(np.int16)
    dst = rng.integers(0, 100, 3 * LANES).astype(np.int16)
    a = [arr.copy(), dst.copy()]
    _fill_copy(a[0], np.int64(4), np.int16(-9), src, np.int64(2), a[1], np.int64(5), np.int64(n))
    b = [arr.copy(), dst.copy()]
    ref.lanes_fill(b[0], 4, np.int16(-9))
    ref.lanes_copy(src, 2, b[1], 5, n)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    for levels in (30000, 40):  # few levels: ties, the first index of the minimum wins
        s1 = rng.integers(0, levels, 8 * LANES).astype(np.uint16)
        s2 = rng.integers(0, levels, 8 * LANES).astype(np.uint16)
        out = np.zeros(8 * LANES, np.uint16)
        got, want = _both(_sum, ref.lanes_sum, s1, s2, np.int64(3), out, np.int64(1), np.int64(n))
        assert got == want
        span = np.int64(max(LANES, -(-max(n, 0) // LANES) * LANES))
        got, want = _both(_sum_wide, ref.lanes_sum_wide, s1, s2, np.int64(3), out, np.int64(1), np.int64(n), span)
        assert got == want


@njit
def _step_pair(L, cur, cost, ci, n, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out, oi):
    return lanes.lanes_step_pair(L, cur, cost, ci, n, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out, oi)


@njit
def _step_wide_pair(L, cur, cost, ci, n, span, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out, oi):
    return lanes.lanes_step_wide_pair(L, cur, cost, ci, n, span, prev, p1, jump, mp, cur2, prev2, jump2, mp2, out, oi)


@njit
def _find(arr, index, value):
    return lanes.lanes_find(arr, index, value)


@njit
def _vote(sums, si, n, cost, best, top, xr0, W, d0, half):
    if half:
        lanes.lanes_vote_half(sums, si, n, cost, best, top, xr0, W, d0)
    else:
        lanes.lanes_vote(sums, si, n, cost, best, top, xr0, W, d0)


@njit
def _census(flat, fi, a, row, top, scale, half):
    if half:
        lanes.lanes_census_half(flat, fi, a, row, top, scale)
    else:
        lanes.lanes_census(flat, fi, a, row, top, scale)


@njit
def _census_bits(pad, ci, offsets, out, oi):
    lanes.lanes_census_bits(pad, ci, offsets, out, oi)


@pytest.mark.parametrize("n", [-1, 0, 3, LANES, LANES + 4, 2 * LANES, 3 * LANES - 2])
def test_the_paired_steps_are_their_statements(n):
    rng = np.random.default_rng(n + 20)
    span = np.int64(max(LANES, -(-max(n, 0) // LANES) * LANES))
    for dtype in (np.uint8, np.uint16):
        L = rng.integers(0, 900, 14 * LANES).astype(np.int16)
        cost = rng.integers(0, 250, 6 * LANES).astype(dtype)
        out = rng.integers(0, 900, 6 * LANES).astype(np.int16)
        mp, mp2 = np.int16(rng.integers(0, 300)), np.int16(rng.integers(0, 300))
        args = (np.int64(4), np.int16(6), np.int16(mp + 80), mp, np.int64(8 * LANES), np.int64(LANES // 2),
                np.int16(mp2 + 120), mp2, out, np.int64(2))
        cur = np.int64(4 * LANES)
        if n <= LANES:  # the pair step reads one chunk
            got, want = _both(_step_pair, ref.lanes_step_pair, L, cur, cost, np.int64(3), np.int64(n), *args)
            assert got == want
        got, want = _both(_step_wide_pair, ref.lanes_step_wide_pair, L, cur, cost, np.int64(3), np.int64(n), span,
                          *args)
        assert got == want


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_find_votes_and_census_are_their_statements(seed):
    rng = np.random.default_rng(seed)
    arr = rng.integers(0, 6, 3 * LANES).astype(np.uint16)
    for v in range(7):
        assert _find(arr, np.int64(5), np.uint16(v)) == ref.lanes_find(arr, 5, v)
    W = 40
    for half in (False, True):
        for n in (0, 3, LANES // 2, LANES, LANES + 3):
            for xr0 in (2, 20, W + 5):
                sums = rng.integers(0, 50, 4 * LANES).astype(np.uint16)
                cost = rng.integers(0, 60, 4 * LANES).astype(np.int32)
                best = rng.integers(0, 30, 4 * LANES).astype(np.int32)
                got_c, got_b = cost.copy(), best.copy()
                _vote(sums, np.int64(3), np.int64(n), got_c, got_b, np.int64(2 * LANES), np.int64(xr0), np.int64(W),
                      np.int64(7), half)
                ref.lanes_vote(sums, 3, n, cost, best, 2 * LANES, xr0, W, 7, LANES // 2 if half else LANES)
                np.testing.assert_array_equal(got_c, cost)
                np.testing.assert_array_equal(got_b, best)
        row = rng.integers(0, 2 ** 63, 3 * LANES, dtype=np.int64).astype(np.uint64)
        a = np.uint64(rng.integers(0, 2 ** 63))
        for scale in (1, 3):
            got = np.zeros(3 * LANES, np.uint16)
            want = got.copy()
            _census(got, np.int64(4), a, row, np.int64(2 * LANES), np.uint16(scale), half)
            ref.lanes_census(want, 4, a, row, 2 * LANES, scale, LANES // 2 if half else LANES)
            np.testing.assert_array_equal(got, want)
    pad = rng.integers(0, 5, (9, 40)).astype(np.float32).reshape(-1)  # few levels: equal neighbours too
    for hh, hw in ((1, 1), (3, 4), (4, 4)):  # 8, 62 and 80 neighbours (more than 64: the first ones shift out)
        offsets = np.array([dy * 40 + dx for dy in range(-hh, hh + 1) for dx in range(-hw, hw + 1)
                            if (dy, dx) != (0, 0)], np.int64)
        got = np.zeros(2 * LANES, np.uint64)
        want = got.copy()
        ci = 4 * 40 + 5
        _census_bits(pad, np.int64(ci), offsets, got, np.int64(3))
        ref.lanes_census_bits(pad, ci, offsets, want, 3)
        np.testing.assert_array_equal(got, want)
