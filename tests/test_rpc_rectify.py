"""RPC pair rectification, s2p style (docs/rpc.md): the affine model on the Ventoux RPCs, and the real pair."""

import sys
from pathlib import Path

import numpy as np
import pytest

from riverbed_cli.geometry.rpc import read_rpc
from riverbed_cli.geometry.rpc_rectify import (affine_fundamental_matrix, apply_h, rectify_rpc_pair,
                                               rectifying_similarities, resample, virtual_matches,
                                               with_row_offset)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

RPC_DIR = Path(__file__).parent / "data" / "rpc"
# the Ventoux crops' offsets in their full images (their TIFF geotransforms), and SRTM's range there + EGM96
LEFT_OFF, RIGHT_OFF, HEIGHTS = (5000, 5000), (4915, 5162), (472.0, 578.0)


def ventoux_models():
    return (read_rpc(RPC_DIR / "left_image.geom").shifted(*LEFT_OFF),
            read_rpc(RPC_DIR / "right_image.geom").shifted(*RIGHT_OFF))


def test_affine_fundamental_matrix_of_exact_affine_cameras():
    rng = np.random.default_rng(0)
    X = rng.uniform(-100, 100, (50, 3))
    M1 = np.array([[1.0, 0.1, 0.3, 10], [0.05, 1.0, -0.2, 5]])
    M2 = np.array([[0.9, -0.1, 0.5, -3], [0.1, 1.1, 0.25, 7]])
    p1 = X @ M1[:, :3].T + M1[:, 3]
    p2 = X @ M2[:, :3].T + M2[:, 3]
    F = affine_fundamental_matrix(p1[:, 0], p1[:, 1], p2[:, 0], p2[:, 1])
    h2 = np.column_stack([p2, np.ones(50)])
    h1 = np.column_stack([p1, np.ones(50)])
    assert np.max(np.abs(np.einsum("ij,jk,ik->i", h2, F, h1))) < 1e-9
    S1, S2 = rectifying_similarities(F)
    _, v1 = apply_h(S1, p1[:, 0], p1[:, 1])
    _, v2 = apply_h(S2, p2[:, 0], p2[:, 1])
    assert np.max(np.abs(v1 - v2)) < 1e-9
    # similarities: orthogonal rows of equal norm, determinant > 0 (no mirror)
    for S in (S1, S2):
        A = S[:2, :2]
        assert abs(A[0] @ A[1]) < 1e-12 and np.linalg.det(A) > 0


def test_ventoux_models_rectified_rows_and_disparity_convention():
    left, right = ventoux_models()
    rect = rectify_rpc_pair(left, right, (0, 0, 500, 500), HEIGHTS)
    assert rect.info["virtual_row_residual_max_px"] < 0.01
    # denser virtual matches than the fit: rows still shared, d = x_left - x_right in the range and growing with h
    x1, y1, x2, y2, h = virtual_matches(left, right, (0, 0, 500, 500), HEIGHTS, n=31, n_heights=7)
    u1, v1 = apply_h(rect.H_left, x1, y1)
    u2, v2 = apply_h(rect.H_right, x2, y2)
    assert np.max(np.abs(v1 - v2)) < 0.01
    d = u1 - u2
    assert d.min() >= rect.disparity[0] + 4.9 and d.max() <= rect.disparity[1] - 4.9    # 5 px margins
    assert np.polyfit(h, d, 1)[0] == pytest.approx(rect.info["disparity_per_metre"], rel=1e-6)
    assert rect.info["disparity_per_metre"] > 0.5
    # the left ROI lies inside the left output frame
    cu, cv = apply_h(rect.H_left, np.array([0, 499, 0, 499]), np.array([0, 0, 499, 499]))
    assert cu.min() >= 0 and cv.min() >= 0 and cu.max() <= rect.size[0] - 1 and cv.max() <= rect.size[1] - 1
    moved = with_row_offset(rect, -4.8)
    _, v2m = apply_h(moved.H_right, x2, y2)
    np.testing.assert_allclose(v2m, v2 - 4.8, atol=1e-9)


def test_resample_follows_the_affinity():
    img = np.zeros((50, 60), np.uint16)
    img[20, 30] = 1000
    H = np.array([[1.0, 0, 5], [0, 1, -3], [0, 0, 1]])
    out = resample(img, H, (70, 50))
    assert out.dtype == np.uint16 and out[17, 35] == 1000 and out.sum() > 1000 - 1


def test_real_ventoux_pair_vertical_parallax_and_shareloc_grids(shared_data):
    from bench_rpc_rectify import run

    out, rl, rr = run(shared_data)
    assert out["dem_vertical"] in ("EPSG:5773", "ellipsoid")
    assert out["check_row_residual_max_px"] < 0.01
    # independent SIFT tie points (refined by Lucas-Kanade): the targets
    assert out["sift_lk"]["matches"] > 300
    assert out["sift_lk"]["dy_median_abs"] < 0.2 and out["sift_lk"]["dy_p95_abs"] < 0.5
    # without the pointing correction the RPCs are ~4.8 px apart in rows: the measurement can fail
    assert out["sift_before_pointing_correction"]["dy_median_abs"] > 4
    # shareloc's correspondences share our rows, and its left grid is ours up to a similarity
    grids = out["shareloc_before_pointing_correction"]
    assert grids["nodes_inside"] > 200
    assert grids["row_difference_of_shareloc_matches_max_abs"] < 0.05
    assert grids["grid_difference_after_similarity_max_px"] < 0.01
