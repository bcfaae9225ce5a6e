import numpy as np
import pytest

from riverbed_cli.errors import RiverbedError
from riverbed_cli.matching.sgm import path_directions, sgm_aggregate


def sgm_reference(cost, P1, P2, paths):
    """Pure numpy SGM: each path recursion written out, L_r = C at the first pixel of a path."""
    H, W, D = cost.shape
    C = cost.astype(np.int64)
    total = np.zeros((H, W, D), dtype=np.int64)
    for dx, dy in path_directions(paths):
        L = np.zeros((H, W, D), dtype=np.int64)
        ys = range(H) if dy >= 0 else range(H - 1, -1, -1)
        xs = list(range(W)) if dx >= 0 else list(range(W - 1, -1, -1))
        for y in ys:
            for x in xs:
                py, px = y - dy, x - dx
                if 0 <= py < H and 0 <= px < W:
                    prev = L[py, px]
                    best = prev.copy()
                    best[1:] = np.minimum(best[1:], prev[:-1] + P1)
                    best[:-1] = np.minimum(best[:-1], prev[1:] + P1)
                    best = np.minimum(best, prev.min() + P2)
                    L[y, x] = C[y, x] + best - prev.min()
                else:
                    L[y, x] = C[y, x]
        total += L
    return total


def test_directions_are_distinct_and_opposite():
    for n in (4, 8, 16):
        dirs = path_directions(n)
        assert len(set(dirs)) == n
        assert all((-dx, -dy) in dirs for dx, dy in dirs)


@pytest.mark.parametrize("paths", [4, 8, 16])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_sgm_matches_reference_exactly(paths, dtype):
    rng = np.random.default_rng(paths)
    cost = rng.integers(0, 63, (9, 12, 7)).astype(dtype)
    got = sgm_aggregate(cost, 7, 40, paths)
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, sgm_reference(cost, 7, 40, paths))


def test_sgm_single_disparity_and_thin_images():
    rng = np.random.default_rng(3)
    for shape in [(1, 9, 5), (9, 1, 5), (4, 5, 1)]:
        cost = rng.integers(0, 63, shape).astype(np.uint8)
        np.testing.assert_array_equal(sgm_aggregate(cost, 3, 20, 8), sgm_reference(cost, 3, 20, 8))


def test_sgm_refuses_possible_overflow():
    cost = np.full((4, 4, 3), 4000, dtype=np.uint16)
    with pytest.raises(RiverbedError, match="SGM sums could reach 65600 > 65535 with 16 paths"):
        sgm_aggregate(cost, 10, 100, 16)


def test_sgm_refuses_bad_penalties():
    with pytest.raises(RiverbedError, match=r"SGM penalties need 0 <= P1 <= P2 \(got P1=20, P2=10\)"):
        sgm_aggregate(np.zeros((2, 2, 2), np.uint8), 20, 10)
