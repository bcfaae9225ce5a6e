"""LiDAR-only baselines (riverbed densify): exact on hand-computed cases, one-line errors for bad input."""

import math

import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.io.disparity import read_disparity, write_disparity
from riverbed_cli.products.densify import densify
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar


def test_nearest_and_linear_by_hand():
    sparse = np.full((3, 5), np.nan, np.float32)
    sparse[1, 0], sparse[1, 4] = 10.0, 30.0
    near = densify(sparse, "nearest")
    np.testing.assert_array_equal(near[1], [10, 10, 10, 30, 30])  # x = 2 is a tie: the first found
    sparse[0, 2] = 20.0
    sparse[2, 2] = 20.0
    lin = densify(sparse, "linear")
    # on the segment (0, 1)-(2, 0)... inside the hull the plane through the triangle's corners
    assert lin[1, 1] == pytest.approx(15.0) and lin[1, 3] == pytest.approx(25.0) and lin[1, 2] == pytest.approx(20.0)
    assert lin[0, 0] == 10.0  # outside the hull: the nearest


def test_guided_is_the_bilateral_weighted_average():
    sparse = np.full((5, 5), np.nan, np.float32)
    sparse[2, 0], sparse[2, 4] = 10.0, 30.0
    img = np.zeros((5, 5), np.float32)
    img[:, 3:] = 100.0  # the right point's colour differs from the pixel at x = 1
    d = densify(sparse, "guided", img, radius=4, sigma_s=2.0, sigma_i=8.0)
    ws = [math.exp(-1 / 8.0), math.exp(-9 / 8.0 - 100.0 ** 2 / 128.0)]  # x = 1: distances 1 and 3
    assert d[2, 1] == pytest.approx((10 * ws[0] + 30 * ws[1]) / sum(ws), rel=1e-5)
    assert d[2, 4] == pytest.approx(30.0, abs=1e-3) and d[2, 0] == pytest.approx(10.0, abs=1e-3)


def test_baselines_on_cones(cones):
    left, _, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    m = {k: evaluate_disparity(densify(sparse, k, left), gt, exclude=sparse) for k in ("nearest", "linear", "guided")}
    # measured (docs/benchmarks.md): bad3 3.05 / 3.84 / 1.48 %, mean 0.380 / 0.436 / 0.255 px
    assert m["guided"]["bad3"] < m["nearest"]["bad3"] < m["linear"]["bad3"] < 4.5
    assert abs(m["guided"]["avg"] - 0.255) < 0.03 and abs(m["nearest"]["avg"] - 0.380) < 0.04


def test_bad_input_one_line_errors(tmp_path, cones):
    left, _, gt = cones
    empty = tmp_path / "empty.tif"
    write_disparity(empty, np.full(gt.shape, np.nan, np.float32))
    small = tmp_path / "small.tif"
    write_disparity(small, simulate_lidar(gt, 0.05, 0)[:100])
    img = "tests/data/cones/im2.png"
    cases = [
        ([str(empty)], f"{empty}: sparse map has no valid disparities"),
        ([str(small), "--method", "guided", "--image", img],
         f"{img}: image is 450x375 but the sparse map is 450x100 (WxH)"),
        ([str(small), "--method", "guided"], "--method guided needs --image LEFT"),
    ]
    for args, message in cases:
        out = tmp_path / "out.tif"
        r = CliRunner().invoke(cli, ["densify", *args, "-o", str(out)])
        assert r.exit_code == 1 and r.stderr == f"riverbed: error: {message}\n", r.stderr
        assert not out.exists()
    with pytest.raises(RiverbedError, match="guide image is 450x375 but the sparse map is 450x100"):
        densify(read_disparity(small), "guided", left)
    with pytest.raises(RiverbedError, match="unknown densify method 'cubic'"):
        densify(read_disparity(small), "cubic")


def test_linear_fill_is_exact_on_a_plane_and_agrees_with_scipy_where_the_triangulation_is_unique():
    # any Delaunay triangulation reproduces a plane exactly inside the hull
    from scipy.interpolate import LinearNDInterpolator

    rng = np.random.default_rng(3)
    H, W = 120, 160
    sparse = np.full((H, W), np.nan, np.float32)
    r, c = rng.integers(0, H, 600), rng.integers(0, W, 600)
    sparse[r, c] = (5 + 0.2 * c - 0.1 * r).astype(np.float32)
    out = densify(sparse, "linear")
    rr, cc = np.nonzero(np.isfinite(sparse))
    ref = LinearNDInterpolator(np.c_[cc, rr].astype(float), sparse[rr, cc].astype(float))
    ys, xs = np.mgrid[0:H, 0:W]
    expect = ref(xs.ravel().astype(float), ys.ravel().astype(float)).reshape(H, W)
    inside = np.isfinite(expect)
    np.testing.assert_allclose(out[inside], (5 + 0.2 * xs - 0.1 * ys)[inside], atol=1e-4)
    # five points in general position (no four co-circular): one triangulation, the same values as scipy's
    sparse = np.full((40, 40), np.nan, np.float32)
    for y, x, v in ((2, 3, 1.0), (5, 35, 9.0), (30, 4, 4.0), (37, 33, 2.0), (18, 21, 7.0)):
        sparse[y, x] = v
    rr, cc = np.nonzero(np.isfinite(sparse))
    ref = LinearNDInterpolator(np.c_[cc, rr].astype(float), sparse[rr, cc].astype(float))
    ys, xs = np.mgrid[0:40, 0:40]
    expect = ref(xs.ravel().astype(float), ys.ravel().astype(float)).reshape(40, 40)
    inside = np.isfinite(expect)
    np.testing.assert_allclose(densify(sparse, "linear")[inside], expect[inside], atol=1e-5)


@pytest.mark.parametrize("layout", ["random", "grid", "clustered", "two rows", "one row"])
def test_linear_fill_nearest_points_are_exact_and_the_fill_is_deterministic(layout):
    # the greedy walk on the Delaunay graph finds each pixel's nearest LiDAR point: its distance equals the Euclidean
    # distance transform's everywhere (ties may pick another point at the same distance); grid layouts are full of
    # co-circular quadruples and pixels on shared triangle edges
    from scipy import ndimage

    from riverbed_cli.geometry.interpolation import linear_fill

    rng = np.random.default_rng({"random": 0, "grid": 1, "clustered": 2, "two rows": 3, "one row": 4}[layout])
    H, W = 70, 90
    sparse = np.full((H, W), np.nan, np.float32)
    if layout == "random":
        sparse.ravel()[rng.choice(H * W, 300, replace=False)] = rng.uniform(0, 40, 300)
    elif layout == "grid":
        sparse[3::7, 5::6] = rng.uniform(0, 40, sparse[3::7, 5::6].shape)
    elif layout == "clustered":
        sparse[10:16, 60:70] = rng.uniform(0, 40, (6, 10))
        sparse[50, 5] = 7.0
    elif layout == "two rows":  # two collinear runs: long slivers and pixels far outside the hull
        sparse[20, 10:80:3] = rng.uniform(0, 40, sparse[20, 10:80:3].shape)
        sparse[24, 15:75:5] = rng.uniform(0, 40, sparse[24, 15:75:5].shape)
    else:  # one scan line: no triangle at all (OpenCV returns an empty tuple), nearest everywhere
        sparse[30, 4:88:6] = rng.uniform(0, 40, sparse[30, 4:88:6].shape)
    fill = linear_fill(sparse)
    edt = ndimage.distance_transform_edt(~np.isfinite(sparse))
    np.testing.assert_allclose(fill.distance, edt, atol=1e-4)
    rows, cols = np.nonzero(np.isfinite(sparse))
    ys, xs = np.mgrid[0:H, 0:W]
    np.testing.assert_allclose(np.hypot(rows[fill.anchor] - ys, cols[fill.anchor] - xs), fill.distance, atol=1e-4)
    assert (fill.values[rows, cols] == sparse[rows, cols]).all() and np.isfinite(fill.values).all()
    again = linear_fill(sparse)
    assert (again.values == fill.values).all() and (again.anchor == fill.anchor).all()
    # outside the hull each pixel takes its nearest point's value
    outside = edt > 0
    if layout != "one row":  # (no hull: scipy's interpolator refuses collinear points)
        outside &= ~np.isfinite(densify_inside(sparse))
    assert (fill.values[outside] == sparse[rows, cols][fill.anchor[outside]]).all()


def densify_inside(sparse):
    """The linear interpolation inside the closed hull of the LiDAR pixels by scipy (NaN outside)."""
    from scipy.interpolate import LinearNDInterpolator

    rr, cc = np.nonzero(np.isfinite(sparse))
    ref = LinearNDInterpolator(np.c_[cc, rr].astype(float), sparse[rr, cc].astype(float))
    ys, xs = np.mgrid[0:sparse.shape[0], 0:sparse.shape[1]]
    return ref(xs.ravel().astype(float), ys.ravel().astype(float)).reshape(sparse.shape)
