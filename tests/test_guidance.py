import math

import numpy as np
import pytest

from riverbed_cli.matching.guidance import (
    auto_window,
    gauss_modulate,
    homogeneous_owners,
    lidar_share,
    ownership_weights,
    riverbed_modulate,
)


def cost_volume(H=9, W=9, D=21, seed=7):
    return np.random.default_rng(seed).integers(1, 40, (H, W, D)).astype(np.uint8)


def one_point(H=9, W=9, y=4, x=4, d=10.0):
    sparse = np.full((H, W), np.nan, dtype=np.float32)
    sparse[y, x] = d
    return sparse


@pytest.mark.parametrize("form", ["additive", "product"])
def test_gauss_minimum_at_lidar_disparity(form):
    cost = cost_volume()
    out = gauss_modulate(cost, one_point(d=10.0), d_min=0, form=form, cost_scale=4)
    assert out[4, 4].argmin() == 10
    # costs grow away from d_m: the far ends are above the plain (scaled) cost
    assert out[4, 4, 0] > 4 * cost[4, 4, 0] and out[4, 4, 20] > 4 * cost[4, 4, 20]
    if form == "product":
        assert out[4, 4, 10] == 0  # k (1 - exp(0)) F = 0 at d_m


def test_gauss_formula_values():
    cost = cost_volume()
    out = gauss_modulate(cost, one_point(d=10.0), d_min=0, k=10, c=1, form="product", cost_scale=4)
    d = np.arange(21)
    expect = np.floor(4 * 10 * (1 - np.exp(-((d - 10.0) ** 2) / 2)) * cost[4, 4] + 0.5)
    np.testing.assert_array_equal(out[4, 4], expect)
    wall_scale = cost[4, 4].mean()
    add = gauss_modulate(cost, one_point(d=10.0), d_min=0, k=10, c=1, form="additive", cost_scale=4)
    expect = np.floor(4 * (cost[4, 4] + 10 * wall_scale * (1 - np.exp(-((d - 10.0) ** 2) / 2))) + 0.5)
    np.testing.assert_array_equal(add[4, 4], expect)


@pytest.mark.parametrize("fn", ["gauss", "riverbed"])
def test_untouched_pixels_unchanged(fn):
    cost = cost_volume()
    sparse = one_point()
    guide = np.zeros((9, 9), np.float32)
    guide[:, 6:] = 200  # a different surface: not homogeneous with the LiDAR point
    if fn == "gauss":
        out = gauss_modulate(cost, sparse, 0, cost_scale=4)
        touched = np.isfinite(sparse)
    else:
        out = riverbed_modulate(cost, sparse, guide, 0, window=5, cost_scale=4)
        touched = homogeneous_owners(sparse, guide, 5)[0] >= 0
        assert touched.sum() == 25 - 5  # the 5x5 window minus the column of the other surface
    np.testing.assert_array_equal(out[~touched], 4 * cost[~touched].astype(np.uint16))
    assert (out[touched] != 4 * cost[touched]).any(axis=-1).all()


def test_riverbed_band_is_flat_and_walls_continuous():
    # A homogeneous pixel at distance 2 px (same colour): W = 1 - exp(-4 / 128) ~ 0.031, band half-width 3 W.
    cost = np.full((9, 9, 41), 20, dtype=np.uint8)
    guide = np.zeros((9, 9), np.float32)
    owner, dis = homogeneous_owners(one_point(d=20.0), guide, 5)
    w = float(dis[4, 6])
    assert owner[4, 6] == 0 and w == pytest.approx(1 - math.exp(-4 / 128), rel=1e-5)

    def modulated(dm):
        return riverbed_modulate(cost, one_point(d=dm), guide, 0, window=5, band=3.0, cost_scale=64)[4, 6] / 64

    out = modulated(20.0)
    assert out.argmin() == 20 and out[20] == pytest.approx(w * 20, abs=1 / 64)  # inside the band: W * F
    # continuity: moving d_m by tiny steps across the band edge changes every cost by a tiny amount
    half = 3.0 * w
    for dm in (21 - half - 1e-3, 21 - half + 1e-3):
        assert np.abs(modulated(dm) - modulated(dm + 1e-4)).max() < 0.05
    # walls rise monotonically away from the band
    assert (np.diff(out[:20]) <= 0).all() and (np.diff(out[21:]) >= 0).all()


def test_ownership_rules():
    guide = np.zeros((12, 12), np.float32)
    sparse = np.full((12, 12), np.nan, np.float32)
    sparse[5, 3] = 7.0
    sparse[5, 6] = 9.0  # inside the first point's window: keeps its own disparity
    owner, dis = homogeneous_owners(sparse, guide, 7)
    assert owner[5, 3] == 0 and owner[5, 6] == 1 and dis[5, 3] == 0 and dis[5, 6] == 0
    # a pixel between them belongs to the nearer (more similar) one
    assert owner[5, 4] == 0 and owner[5, 5] == 1
    # outside every window: no owner
    assert owner[0, 11] == -1 and np.isinf(dis[0, 11])


def test_homogeneous_means_similar_not_dissimilar():
    # Eq. 3 as printed (W > gamma) would pick the *least* similar pixels; we keep 1 - W >= gamma.
    guide = np.zeros((9, 9), np.float32)
    guide[4, 5] = 255.0  # very different colour right next to the LiDAR pixel
    owner, dis = homogeneous_owners(one_point(), guide, 5, gamma=0.3)
    assert owner[4, 5] == -1
    assert owner[4, 3] == 0 and dis[4, 3] <= 0.7


def test_lidar_share_uses_covered_area():
    sparse = np.full((100, 100), np.nan, np.float32)
    sparse[10:30:2, 10:30:2] = 5  # 100 points on a 19x19 block
    assert lidar_share(sparse) == pytest.approx(100 / 361)
    sparse2 = np.full((100, 100), np.nan, np.float32)
    sparse2[::10, ::10] = 5
    assert lidar_share(sparse2) == pytest.approx(100 / 8281)


@pytest.mark.parametrize("share,seed", [(0.05, 0), (0.002, 1), (0.0004, 2), (0.3, 3)])
def test_prepare_lidar_gives_the_points_and_shares_of_the_separate_passes(share, seed):
    # match_pair's one pass over the map: the cut map, its points and both shares as lidar_points and lidar_share
    # give them (bit for bit), with points outside the range, +-inf and rows without any
    from riverbed_cli.geometry.coverage import lidar_points
    from riverbed_cli.matching.lidar_input import prepare_lidar, prepare_sparse

    rng = np.random.default_rng(seed)
    shape = (47, 61)
    sparse = np.where(rng.random(shape) < share, rng.uniform(-10, 50, shape), np.nan).astype(np.float32)
    sparse[3, 3], sparse[4, 7], sparse[40, 50] = np.inf, -np.inf, 20.0
    cut, points, inside_share, all_share = prepare_lidar(sparse, shape, 0, 39)
    np.testing.assert_array_equal(cut, prepare_sparse(sparse, shape, 0, 39))
    for got, want in zip(points, lidar_points(cut)):
        np.testing.assert_array_equal(got, want)
        assert got.dtype == want.dtype
    assert inside_share == lidar_share(cut)
    assert all_share == lidar_share(sparse)


def test_lidar_share_from_row_ends_equals_the_hull_of_every_point():
    # lidar_share_of_points takes the hull of each row's two end points when the points come sorted by row: the
    # same share as OpenCV's hull of all of them, sorted, shuffled, or with columns out of order within the rows
    import cv2

    from riverbed_cli.geometry.coverage import lidar_share_of_points

    def every_point(rows, cols, shape):
        hull = cv2.convexHull(np.stack([cols, rows], axis=1).astype(np.int32))[:, 0, :]
        edges = np.abs(np.diff(np.vstack([hull, hull[:1]]), axis=0))
        x, y = hull[:, 0].astype(float), hull[:, 1].astype(float)
        area = abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2 + np.gcd(*edges.T).sum() / 2 + 1
        return rows.size / max(area, rows.size)

    rng = np.random.default_rng(0)
    for density in (0.01, 0.05, 0.3, 0.9):
        for _ in range(20):
            H, W = rng.integers(5, 80, 2)
            rows, cols = np.nonzero(rng.random((H, W)) < density)
            if rows.size < 3:
                continue
            shuffled = rng.permutation(rows.size)
            for r, c in ((rows, cols), (rows[shuffled], cols[shuffled]), (rows, cols[::-1].copy())):
                assert lidar_share_of_points(r, c, (H, W)) == every_point(r, c, (H, W))
            # and from the map itself (its finite pixels: inf is no LiDAR)
            sparse = np.full((H, W), np.nan, np.float32)
            sparse[rows, cols] = 3.0
            sparse[rng.random((H, W)) < 0.01] = np.inf
            r, c = np.nonzero(np.isfinite(sparse))
            if r.size >= 3:
                assert lidar_share(sparse) == every_point(r, c, (H, W))
    line = np.full((40, 40), np.nan, np.float32)
    line[7, 3:30] = 1.0  # collinear points: the hull is the segment (27 pixels)
    assert lidar_share(line) == 1.0
    few = np.full((10, 20), np.nan, np.float32)
    assert lidar_share(few) == 0.0
    few[2, 3] = few[8, 15] = 1.0  # fewer than three points: their share of the whole image
    assert lidar_share(few) == 2 / 200


@pytest.mark.parametrize("p,s", [(0.05, 9), (0.0123, 19), (0.0016, 25), (0.5, 5), (1e-6, 25)])
def test_auto_window(p, s):
    assert auto_window(p) == s


def owners_reference(sparse, guide, window, sigma_xy=8.0, sigma_i=8.0, gamma=0.3):
    """Brute force: every pixel takes the most similar LiDAR point whose window covers it (ties: lower index)."""
    H, W = sparse.shape
    g = guide.reshape(H, W, -1).astype(np.float64)
    rows, cols = np.nonzero(np.isfinite(sparse))
    owner = np.full((H, W), -1)
    dis = np.full((H, W), np.inf)
    half = window // 2
    for j, (r0, c0) in enumerate(zip(rows, cols)):
        owner[r0, c0], dis[r0, c0] = j, 0.0
    lidar = np.isfinite(sparse)
    for r in range(H):
        for c in range(W):
            if lidar[r, c]:
                continue
            for j, (r0, c0) in enumerate(zip(rows, cols)):
                if abs(r - r0) <= half and abs(c - c0) <= half:
                    dd = ((g[r, c] - g[r0, c0]) ** 2).mean()
                    w = 1 - np.exp(-((r - r0) ** 2 + (c - c0) ** 2) / (2 * sigma_xy**2) - dd / (2 * sigma_i**2))
                    if w <= 1 - gamma and w < dis[r, c]:
                        owner[r, c], dis[r, c] = j, w
    return owner, dis


# windows of one, two and three 16-pixel chunks (lanes.py), grey, RGB (its fused distances) and two channels, the
# chunks at the rows' ends masked
@pytest.mark.parametrize("window,channels", [(5, 1), (9, 3), (21, 3), (25, 1), (35, 2)])
def test_ownership_matches_brute_force(window, channels):
    rng = np.random.default_rng(window)
    H, W = 57, 41  # four of the threads' shares of rows (volume.band_pair_rows): windows reach across their edges
    guide = rng.integers(0, 40, (H, W, channels)).astype(np.float32)
    sparse = np.where(rng.random((H, W)) < 0.04, rng.uniform(0, 30, (H, W)), np.nan).astype(np.float32)
    owner, dis = homogeneous_owners(sparse, guide, window)
    ref_owner, ref_dis = owners_reference(sparse, guide, window)
    np.testing.assert_array_equal(owner, ref_owner)
    np.testing.assert_allclose(dis, ref_dis, rtol=1e-5)


# the matcher hands a uint8 left image over as it is (io.images.guide_source): the same owners and weights as its
# float32 copy, grey and RGB
@pytest.mark.parametrize("channels", [1, 3])
def test_ownership_of_a_uint8_guide_equals_its_float_copy(channels):
    rng = np.random.default_rng(channels)
    H, W = 45, 67
    guide = rng.integers(0, 256, (H, W, channels)).astype(np.uint8)
    guide[10:30, 20:50] = guide[10, 20]  # a flat patch: ties between points
    sparse = np.where(rng.random((H, W)) < 0.05, rng.uniform(0, 30, (H, W)), np.nan).astype(np.float32)
    owner, dis = homogeneous_owners(sparse, guide, 9)
    ref_owner, ref_dis = homogeneous_owners(sparse, guide.astype(np.float32), 9)
    assert (owner >= 0).mean() > 0.2
    np.testing.assert_array_equal(owner, ref_owner)
    np.testing.assert_array_equal(dis, ref_dis)
    if channels == 1:  # a grey image as read (H x W)
        np.testing.assert_array_equal(homogeneous_owners(sparse, guide[:, :, 0], 9)[0], ref_owner)


def test_ownership_weights_are_libm_bits():
    # the polynomial with its rounding check gives float32(-expm1(-e)) to the bit; libm where it cannot be sure
    rng = np.random.default_rng(3)
    e = np.concatenate([rng.uniform(0, 1.3, 200_000), rng.uniform(0, 1e-3, 50_000), np.geomspace(1e-12, 40, 1000),
                        [0.0, 1.25, -math.log(0.3), 2.0, 30.0, np.inf]])
    w = ownership_weights(e)
    expect = np.array([np.float32(np.inf) if math.isinf(v) else np.float32(-math.expm1(-v)) for v in e], np.float32)
    np.testing.assert_array_equal(w, expect)
    assert w[-6] == 0.0 and not np.signbit(w[-6])  # a LiDAR pixel's W is +0


def walls_reference(F, dm, w, lidar_pixel, k, c, band, form, scale, wall_scale, max_cost, d_min=0):
    """Riverbed eq. 6 (docs/method.md reading) evaluated directly, disparity by disparity, in float64."""
    out = []
    for i, f in enumerate(F.astype(np.float64)):
        d = d_min + i
        q = scale * f
        half = band * w
        t = max(dm - half - d, d - (dm + half), 0.0)
        g = 1.0 - math.exp(-t * t / (2.0 * c * c))
        if form == "additive":
            v = (1.0 if lidar_pixel else w) * q + scale * k * wall_scale * g
        else:
            v = ((0.0 if lidar_pixel else w) + k * g) * q
        out.append(min(v, max_cost))
    return np.array(out)


# the walls are computed in float32 (lanes_guidance.lanes_walls), the band's edges relative to d_min: as close to
# eq. 6 at disparities in the thousands (satellite pairs) as near 0
@pytest.mark.parametrize("d_min", [0, 4093])
@pytest.mark.parametrize("form", ["additive", "product"])
def test_riverbed_walls_equal_eq6_value_by_value(form, d_min):
    """Every modulated cost of every owned pixel against a direct evaluation of eq. 6 (to the uint16 rounding)."""
    rng = np.random.default_rng(11)
    H, W, D = 11, 13, 40
    cost = rng.integers(0, 63, (H, W, D)).astype(np.uint8)
    sparse = np.full((H, W), np.nan, np.float32)
    sparse[3, 4], sparse[7, 9] = d_min + 12.3, d_min + 27.8
    guide = rng.uniform(100, 110, (H, W)).astype(np.float32)
    k, c, band, scale, wall_scale, max_cost = 10.0, 1.5, 3.0, 4, 20.0, 6000
    owner, dis = homogeneous_owners(sparse, guide, 7)
    out = riverbed_modulate(cost, sparse, guide, d_min, 7, k=k, c=c, band=band, form=form, cost_scale=scale,
                            max_cost=max_cost, wall_scale=wall_scale)
    values = [float(sparse[3, 4]), float(sparse[7, 9])]
    n = 0
    for y in range(H):
        for x in range(W):
            if owner[y, x] < 0:
                np.testing.assert_array_equal(out[y, x], cost[y, x].astype(np.uint16) * scale)  # untouched
                continue
            ref = walls_reference(cost[y, x], values[owner[y, x]], float(dis[y, x]), dis[y, x] == 0, k, c, band,
                                  form, scale, wall_scale, max_cost, d_min)
            np.testing.assert_allclose(out[y, x], ref, atol=1.0)  # rounded to the nearest stored unit
            n += 1
    assert n > 20  # owned pixels were checked


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_prepare_lidar_equals_numpy(seed):
    """The LiDAR map's one-pass kernel (lidar_input._cut_to_range) against NumPy: the copy cut to the range, and per row
    the finite values and those inside with their first and last columns; rows empty, all infinite, ends on the
    range's bounds."""
    from riverbed_cli.matching.lidar_input import _cut_to_range, prepare_lidar

    rng = np.random.default_rng(seed)
    H, W = 40, 53
    m = np.where(rng.random((H, W)) < rng.uniform(0.02, 0.5), rng.uniform(-20, 100, (H, W)), np.nan).astype(np.float32)
    m[rng.integers(0, H, 9), rng.integers(0, W, 9)] = np.inf
    m[rng.integers(0, H, 9), rng.integers(0, W, 9)] = -np.inf
    m[5, :], m[6, :] = np.nan, np.inf
    m[7, 0], m[7, W - 1], m[8, 3] = 0.0, 79.0, 79.00001
    per_row, cut = _cut_to_range(m, 0.0, 79.0)
    inside = (m >= 0) & (m <= 79)
    np.testing.assert_array_equal(cut, np.where(inside, m, np.nan))
    for y in range(H):
        fin, ins = np.flatnonzero(np.isfinite(m[y])), np.flatnonzero(inside[y])
        ends = [(a[0], a[-1]) if a.size else (-1, -1) for a in (fin, ins)]
        assert tuple(per_row[y]) == (fin.size, ins.size, *ends[0], *ends[1])
    sparse, (rows, cols, values), _, _ = prepare_lidar(m, (H, W), 0, 79)
    r, c = np.nonzero(inside)
    np.testing.assert_array_equal(rows, r)
    np.testing.assert_array_equal(cols, c)
    np.testing.assert_array_equal(values, m[r, c].astype(np.float64))
