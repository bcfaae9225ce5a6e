"""Local-plane interpolation (riverbed_cli.geometry.planes), the fusion's LiDAR side: nearest points from the
labelled distance transform, natural neighbours from the cells that touch, planes exact on a plane."""

import numpy as np
import pytest
from scipy import ndimage

from riverbed_cli.geometry.coverage import lidar_points
from riverbed_cli.geometry.interpolation import delaunay_graph
from riverbed_cli.geometry.planes import natural_neighbours, nearest_labels, plane_fill, plane_fit
from riverbed_cli.matching.fusion import lidar_model
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.densify import densify
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar


def random_points(shape, n, seed=0):
    rng = np.random.default_rng(seed)
    flat = np.sort(rng.choice(shape[0] * shape[1], n, replace=False))  # row-major, as lidar_points gives them
    return flat // shape[1], flat % shape[1]


def test_nearest_labels_name_a_nearest_point_at_the_transforms_distance():
    shape = (120, 170)
    rows, cols = random_points(shape, 300)
    anchor, dist = nearest_labels(rows, cols, shape)
    assert anchor.dtype == np.int32 and dist.dtype == np.float32 and anchor.min() >= 0
    assert (anchor[rows, cols] == np.arange(rows.size)).all() and (dist[rows, cols] == 0).all()
    mask = np.ones(shape, bool)
    mask[rows, cols] = False
    edt = ndimage.distance_transform_edt(mask)
    # the 5 x 5 mask's distances: within 2 % of the Euclidean ones
    assert np.all(np.abs(dist - edt) <= 0.02 * edt + 1e-3)
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    to_anchor = np.hypot(rows[anchor] - ys, cols[anchor] - xs)
    # the point it names is a nearest one (99.6 % of the pixels here), or one farther by a few per cent where two
    # are almost equally near (measured: at most 3 %, 0.36 px at 10 px)
    assert np.all(to_anchor <= edt * 1.04 + 1e-3)
    assert (np.abs(to_anchor - edt) < 1e-6).mean() > 0.99


def test_natural_neighbours_of_a_square_grid_are_the_four_axis_neighbours():
    # an odd spacing: the cells are squares of 9 x 9 pixels (no pixel is equally near two points), which meet their
    # diagonal neighbours at a corner only; with an even one the pixel at the corner is equally near four points and
    # takes one of them, which then also touches its diagonal neighbour (either diagonal is a Delaunay edge there)
    shape = (58, 76)
    ys, xs = np.mgrid[4:58:9, 4:76:9]
    rows, cols = ys.ravel(), xs.ravel()
    anchor, _ = nearest_labels(rows, cols, shape)
    nb, count, nearest = natural_neighbours(anchor, rows, cols)
    grid = {(r, c): i for i, (r, c) in enumerate(zip(rows, cols))}
    for i, (r, c) in enumerate(zip(rows, cols)):
        axis = sorted(grid[p] for p in ((r - 9, c), (r + 9, c), (r, c - 9), (r, c + 9)) if p in grid)
        if len(axis) == 2:  # a corner point: a plane needs a third, the nearest of its neighbours' neighbours
            axis.append(grid[(r + 9 if r == 4 else r - 9, c + 9 if c == 4 else c - 9)])
        # nearest first, ties by the lower index
        assert nb[i, :count[i]].tolist() == axis and (nb[i, count[i]:] == -1).all()
    assert (nearest == 9).all()


def test_natural_neighbours_are_delaunay_edges():
    shape = (200, 260)
    rows, cols = random_points(shape, 1500, seed=3)
    anchor, _ = nearest_labels(rows, cols, shape)
    nb, count, nearest = natural_neighbours(anchor, rows, cols)
    pairs = {(i, int(q)) for i in range(rows.size) for q in nb[i, :count[i]]}
    # symmetric, but for the third neighbour a point in an image corner takes from its neighbours' neighbours
    assert all((q, i) in pairs or count[i] == 3 for i, q in pairs)
    ptr, nbr = delaunay_graph(rows, cols, shape)
    edges = {(i, int(q)) for i in range(rows.size) for q in nbr[ptr[i]:ptr[i + 1]]}
    # the discrete cells: the same graph but for near-degenerate quads (cells that meet at about a corner)
    assert len(pairs & edges) >= 0.98 * len(pairs) and len(pairs & edges) >= 0.93 * len(edges)
    # the nearest point is always a natural neighbour
    d2 = (rows[:, None] - rows[None]) ** 2 + (cols[:, None] - cols[None]) ** 2
    np.fill_diagonal(d2, 10 ** 9)
    np.testing.assert_allclose(nearest, np.sqrt(d2.min(axis=1)))


def test_plane_fit_recovers_a_plane_and_plane_fill_is_exact_on_it():
    shape = (90, 140)
    rows, cols = random_points(shape, 250, seed=1)
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    truth = 30 + 0.07 * xs - 0.04 * ys
    sparse = np.full(shape, np.nan, np.float32)
    sparse[rows, cols] = truth[rows, cols]
    fill = plane_fill(sparse)
    # everywhere, beyond the points' hull too (where a linear fill takes the nearest value)
    assert np.abs(fill.values - truth).max() < 1e-3
    r, c, v = (np.asarray(a, np.float64) for a in lidar_points(sparse))
    for self_weight, weighted in ((1.0, True), (0.0, False)):
        c0, ga, gb = plane_fit(r, c, v, fill.neighbours, fill.count, 6, self_weight, weighted)
        # exact but for the slopes' tiny ridge, felt where a point's neighbours are almost collinear
        np.testing.assert_allclose(c0, v, atol=5e-3)
        np.testing.assert_allclose(ga, 0.07, atol=1e-3)
        np.testing.assert_allclose(gb, -0.04, atol=1e-3)
        assert np.median(np.abs(c0 - v)) < 1e-4


def test_plane_fill_keeps_the_lidar_and_its_sigma_sees_a_step():
    shape = (80, 120)
    rows, cols = random_points(shape, 400, seed=2)
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    truth = np.where(xs < 60, 10.0, 30.0)
    sparse = np.full(shape, np.nan, np.float32)
    sparse[rows, cols] = truth[rows, cols] + np.random.default_rng(0).normal(0, 0.1, rows.size)
    model = lidar_model(sparse)
    assert (model.values[rows, cols] == sparse[rows, cols]).all()
    step = np.abs(xs - 60) < 3
    far = np.abs(xs - 60) > 20
    # the leave-one-out planes across the step miss by about 10 px; on either flat side by the noise
    assert np.median(model.sigma[step]) > 3.0 and np.median(model.sigma[far]) < 0.3


def test_planes_on_cones_alone_and_in_the_fusion(cones):
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    m = {k: evaluate_disparity(densify(sparse, k), gt, exclude=sparse) for k in ("nearest", "linear", "planes")}
    # alone, planes fit across depth edges: between the linear fill and the nearest in bad3 (measured 3.84 / 4.48 /
    # 3.05 %), behind both in mean error (0.436 / 0.516 / 0.380 px)
    assert m["nearest"]["bad3"] < m["planes"]["bad3"] < 5.0 and m["planes"]["avg"] < 0.56
    # in the fusion the LiDAR's sigma leaves the edges to the stereo: planes do as well as the linear fill there
    # (measured bad1 / bad3 / mean 3.18 / 1.50 / 0.269 either way)
    fused = {k: evaluate_disparity(match_pair(left, right, sparse, 0, 59, fusion_lidar=k).disparity, gt,
                                   exclude=sparse) for k in ("planes", "linear")}
    assert fused["planes"]["avg"] == pytest.approx(fused["linear"]["avg"], rel=0.02)
    assert fused["planes"]["bad3"] == pytest.approx(fused["linear"]["bad3"], abs=0.05)
    assert fused["planes"]["avg"] < min(m[k]["avg"] for k in m)


def test_auto_takes_planes_for_lidar_denser_than_one_point_per_12_px_square():
    from riverbed_cli.errors import RiverbedError
    from riverbed_cli.matching.fusion import lidar_kind

    assert lidar_kind("auto", 100, (120, 120)) == "planes"  # 12 px apart on average: still planes
    assert lidar_kind("auto", 99, (120, 120)) == "linear"
    assert lidar_kind("auto", 0, (120, 120)) == "linear"
    assert lidar_kind("linear", 10 ** 6, (120, 120)) == "linear" and lidar_kind("planes", 1, (120, 120)) == "planes"
    message = r"^unknown fusion LiDAR interpolation 'cubic' \(use auto, planes, linear\)$"
    with pytest.raises(RiverbedError, match=message):
        lidar_kind("cubic", 100, (120, 120))


@pytest.mark.parametrize("points", [[(5, 7)], [(5, 7), (20, 30)], [(3, 3), (10, 10), (17, 17)]])
def test_planes_with_one_two_or_collinear_points(points):
    sparse = np.full((30, 40), np.nan, np.float32)
    for k, (r, c) in enumerate(points):
        sparse[r, c] = 10.0 + k
    fill = plane_fill(sparse)
    at = tuple(np.array(points).T)
    assert np.isfinite(fill.values).all() and (fill.values[at] == sparse[at]).all()
    if len(points) == 1:  # flat at its value
        assert (fill.values == 10.0).all()
    model = lidar_model(sparse, kind="planes")
    assert np.isfinite(model.values).all() and np.isfinite(model.sigma).all() and (model.sigma > 0).all()
