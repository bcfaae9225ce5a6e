"""Diffusion-based guidance (Shivakumar et al. 2019, as read in riverbed_cli/matching/diffusion.py)."""

import math

import numpy as np
import pytest

from riverbed_cli.errors import RiverbedError
from riverbed_cli.matching.diffusion import diffusion_modulate, diffusion_support
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar


def volume(H=11, W=13, D=21, seed=3):
    return np.random.default_rng(seed).integers(1, 60, (H, W, D)).astype(np.uint8)


def points(H=11, W=13, pts=((5, 6, 10.0),)):
    sparse = np.full((H, W), np.nan, np.float32)
    for y, x, d in pts:
        sparse[y, x] = d
    return sparse


def reference(cost, sparse, guide, d_min, radius, sigma_s, sigma_i, scale):
    """Per pixel and disparity, the smallest factor 1 - w * max(0, 1 - |d - d_p|) over the LiDAR pixels in the
    window (a LiDAR pixel only its own), applied as floor(f * C + 0.5) to the scaled cost."""
    H, W, D = cost.shape
    g = guide.reshape(H, W, -1).astype(np.float64)
    out = cost.astype(np.int64) * scale
    for y in range(H):
        for x in range(W):
            fac = np.ones(D)
            for yy in range(max(0, y - radius), min(H, y + radius + 1)):
                for xx in range(max(0, x - radius), min(W, x + radius + 1)):
                    dp = sparse[yy, xx]
                    if np.isnan(dp) or (np.isfinite(sparse[y, x]) and (yy, xx) != (y, x)):
                        continue
                    dd = ((g[y, x] - g[yy, xx]) ** 2).mean()
                    w = math.exp(-((yy - y) ** 2 + (xx - x) ** 2) / (2 * sigma_s**2) - dd / (2 * sigma_i**2))
                    for i in range(D):
                        share = 1 - abs(d_min + i - float(dp))
                        if share > 0:
                            fac[i] = min(fac[i], 1 - w * share)
            touched = fac < 1
            out[y, x, touched] = np.floor(fac[touched] * out[y, x, touched] + 0.5)
    return out


@pytest.mark.parametrize("channels", [1, 3])
def test_matches_reference(channels):
    rng = np.random.default_rng(channels)
    cost = volume()
    guide = rng.uniform(0, 60, (11, 13, channels)).astype(np.float32)
    sparse = points(pts=((5, 6, 10.0), (3, 4, 7.25), (6, 8, 12.5), (9, 1, 3.0)))
    got = diffusion_modulate(cost, sparse, guide, d_min=0, radius=3, sigma_s=3.0, sigma_i=10.0, cost_scale=4)
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, reference(cost, sparse, guide, 0, 3, 3.0, 10.0, 4))


def test_only_spread_disparities_change_and_only_downwards():
    cost = volume()
    guide = np.zeros((11, 13), np.float32)
    sparse = points(pts=((5, 6, 10.0),))
    out = diffusion_modulate(cost, sparse, guide, d_min=0, radius=2, cost_scale=4).astype(np.int64)
    plain = 4 * cost.astype(np.int64)
    changed = out != plain
    assert (out <= plain).all()
    ys, xs, ds = np.nonzero(changed)
    assert set(ds) == {10}  # an integer d_p lowers one disparity only
    assert ys.min() >= 3 and ys.max() <= 7 and xs.min() >= 4 and xs.max() <= 8  # the 5 x 5 neighbourhood
    assert out[5, 6, 10] == 0  # naive fusion at the LiDAR pixel: w = 1
    # farther neighbours are lowered less
    assert out[5, 7, 10] / plain[5, 7, 10] < out[5, 8, 10] / plain[5, 8, 10] < 1


def test_fractional_disparity_is_split_between_neighbours():
    cost = np.full((3, 3, 8), 40, np.uint8)
    out = diffusion_modulate(cost, points(3, 3, ((1, 1, 3.25),)), np.zeros((3, 3)), 0, radius=0, cost_scale=1)
    assert out[1, 1, 3] == 10 and out[1, 1, 4] == 30  # 40 * (1 - 0.75), 40 * (1 - 0.25)
    assert (np.delete(out[1, 1], [3, 4]) == 40).all()


def test_colour_edge_stops_the_spread():
    cost = np.full((7, 7, 12), 50, np.uint8)
    guide = np.zeros((7, 7), np.float32)
    guide[:, 4:] = 200  # another surface right of column 3
    out = diffusion_modulate(cost, points(7, 7, ((3, 2, 5.0),)), guide, 0, radius=3, sigma_i=10.0, cost_scale=1)
    assert out[3, 3, 5] < 50 and out[3, 4, 5] == 50


def test_strongest_reduction_wins_and_lidar_pixels_keep_their_own():
    cost = np.full((1, 7, 10), 60, np.uint8)
    sparse = points(1, 7, ((0, 1, 4.0), (0, 5, 4.0), (0, 3, 6.0)))
    out = diffusion_modulate(cost, sparse, np.zeros((1, 7)), 0, radius=2, sigma_s=2.0, cost_scale=1)
    w1 = math.exp(-1 / 8)  # distance 1; the other d = 4 point (distance 3) is outside the window
    assert out[0, 2, 4] == math.floor(60 * (1 - w1) + 0.5)
    assert out[0, 3, 4] == 60 and out[0, 3, 6] == 0  # a LiDAR pixel: only its own measurement


def test_support_and_errors():
    sparse = points(pts=((5, 6, 10.0), (5, 9, 4.0)))
    ref = diffusion_support(sparse, np.zeros((11, 13), np.float32), radius=2)
    assert ref[5, 6] == 10 and ref[5, 7] == 10 and ref[5, 8] == 4 and np.isnan(ref[0, 0])
    with pytest.raises(RiverbedError, match="radius"):
        diffusion_modulate(volume(), sparse, np.zeros((11, 13)), 0, radius=-1)
    with pytest.raises(RiverbedError, match="differ in size"):
        diffusion_modulate(volume(), sparse, np.zeros((10, 13)), 0)


def test_diffusion_guides_sgm_on_cones(cones):
    # measured at 5 %: unguided bad3 8.75 %, diffusion 2.5 %, riverbed 1.50 %
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    res = {g: evaluate_disparity(match_pair(left, right, sparse, 0, 59, guide=g).disparity, gt, exclude=sparse)
           for g in ("none", "diffusion", "riverbed")}
    assert res["diffusion"]["bad3"] < 0.6 * res["none"]["bad3"]
    assert res["riverbed"]["bad3"] < res["diffusion"]["bad3"] and res["riverbed"]["avg"] < res["diffusion"]["avg"]
