import numpy as np
import pytest

from riverbed_cli.errors import RiverbedError
from riverbed_cli.matching.census import census_cost, census_transform, parse_census_window, popcount64


def census_reference(img, w, h):
    """Brute force: bits in row-major window order, set where neighbour < centre, border replicated."""
    H, W = img.shape
    out = np.zeros((H, W), dtype=np.uint64)
    for y in range(H):
        for x in range(W):
            bits = 0
            for dy in range(-(h // 2), h // 2 + 1):
                for dx in range(-(w // 2), w // 2 + 1):
                    if dy == 0 and dx == 0:
                        continue
                    yy = min(max(y + dy, 0), H - 1)
                    xx = min(max(x + dx, 0), W - 1)
                    bits = (bits << 1) | int(img[yy, xx] < img[y, x])
            out[y, x] = bits
    return out


def cost_reference(cl, cr, d_min, d_max, outside):
    H, W = cl.shape
    D = d_max - d_min + 1
    cost = np.zeros((H, W, D), dtype=np.int64)
    for y in range(H):
        for x in range(W):
            for i in range(D):
                xr = x - (d_min + i)
                cost[y, x, i] = outside if not 0 <= xr < W else bin(int(cl[y, x]) ^ int(cr[y, xr])).count("1")
    return cost


@pytest.mark.parametrize("win", [(3, 3), (5, 5), (9, 7), (7, 9)])
def test_census_transform_matches_brute_force(win):
    rng = np.random.default_rng(1)
    # few levels: many ties, which must not set bits; 37 columns: two 16-pixel chunks (lanes.lanes_census_bits)
    # and the row's last pixels one at a time
    img = rng.integers(0, 8, (13, 37)).astype(np.float32)
    np.testing.assert_array_equal(census_transform(img, win), census_reference(img, *win))


def test_census_uses_all_64_bits_for_9x7():
    img = np.zeros((9, 9), dtype=np.float32)
    img[4, 4] = 1.0  # every neighbour darker than the centre
    assert census_transform(img, (9, 7))[4, 4] == np.uint64(2**62 - 1)


@pytest.mark.parametrize("d_min,d_max", [(0, 6), (-3, 4), (5, 9)])
def test_census_cost_matches_brute_force(d_min, d_max):
    rng = np.random.default_rng(2)
    cl = rng.integers(0, 2**62, (6, 11), dtype=np.uint64)
    cr = rng.integers(0, 2**62, (6, 11), dtype=np.uint64)
    got = census_cost(cl, cr, d_min, d_max, outside_cost=15)
    assert got.dtype == np.uint8
    np.testing.assert_array_equal(got, cost_reference(cl, cr, d_min, d_max, 15))
    scaled = census_cost(cl, cr, d_min, d_max, outside_cost=15, scale=4)
    assert scaled.dtype == np.uint16
    np.testing.assert_array_equal(scaled, 4 * cost_reference(cl, cr, d_min, d_max, 15))


def test_popcount_high_bits():
    for v in [0, 1, 2**63, 2**64 - 1, 0x5555555555555555, 12345678901234567]:
        assert popcount64(np.uint64(v)) == bin(v).count("1")


@pytest.mark.parametrize("spec,msg", [
    ("9x8", "census window 9x8: width and height must be odd and positive"),
    ("11x9", "census window 11x9 has 98 bits; at most 64 fit (e.g. 9x7)"),
    ("nine", "census window 'nine' is not WIDTHxHEIGHT, e.g. 9x7"),
])
def test_census_window_errors(spec, msg):
    with pytest.raises(RiverbedError) as e:
        parse_census_window(spec)
    assert str(e.value) == msg


@pytest.mark.parametrize("d_min", [-30, 0, 9])
def test_tube_census_cost_equals_the_reference_tube_by_tube(d_min):
    """Tubes up to 40 wide (several 16-lane chunks, lanes.lanes_census) and right pixels past both image borders:
    every pixel's tube holds the reference costs of its own disparities, uint8 and scaled uint16 volumes alike."""
    from riverbed_cli.matching.volume import TubeLayout

    rng = np.random.default_rng(abs(d_min) + 1)
    H, W, D = 6, 75, 40
    img = rng.integers(0, 255, (H, W + 30)).astype(np.float32)
    cl, cr = census_transform(img[:, 30:], (9, 7)), census_transform(img[:, :W], (9, 7))
    lo = rng.integers(0, D, (H, W))
    hi = np.minimum(D - 1, lo + rng.integers(0, D, (H, W)))
    layout = TubeLayout.from_bounds(d_min + lo, d_min + hi, d_min)
    ref = cost_reference(cl, cr, d_min, d_min + D - 1, 6)
    expected = np.concatenate([ref[y, x, lo[y, x]:hi[y, x] + 1] for y in range(H) for x in range(W)])
    for scale in (1, 4):
        tube = census_cost(cl, cr, d_min, None, 6, scale, tubes=layout)
        assert tube.dtype == (np.uint8 if scale == 1 else np.uint16)
        np.testing.assert_array_equal(tube, expected * scale)
