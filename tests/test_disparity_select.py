import cv2
import numpy as np
import pytest

from riverbed_cli.matching.disparity import median_filter, select_disparity


def test_wta_and_parabola_match_numpy():
    rng = np.random.default_rng(4)
    S = rng.integers(0, 1000, (5, 6, 9)).astype(np.uint16)
    d = select_disparity(S, d_min=-2, subpixel=True)
    s = S.astype(np.float64)
    i = s.argmin(axis=2)
    expect = (i - 2).astype(np.float64)
    for y in range(5):
        for x in range(6):
            k = i[y, x]
            if 0 < k < 8:
                a, b, c = s[y, x, k - 1], s[y, x, k], s[y, x, k + 1]
                if a - 2 * b + c > 0:
                    expect[y, x] += 0.5 * (a - c) / (a - 2 * b + c)
    np.testing.assert_allclose(d, expect, atol=1e-5)
    np.testing.assert_array_equal(select_disparity(S, -2, subpixel=False), i - 2)


def test_split_volumes_are_added():
    rng = np.random.default_rng(5)
    a = rng.integers(0, 500, (4, 5, 6)).astype(np.uint16)
    b = rng.integers(0, 500, (4, 5, 6)).astype(np.uint16)
    np.testing.assert_array_equal(select_disparity(a, 0, aggregated2=b), select_disparity(a + b, 0))


def test_subpixel_recovers_parabola_vertex():
    d = np.arange(10, dtype=np.float64)
    S = np.round(100 * (d - 4.3) ** 2 + 7).astype(np.uint16)[None, None, :]
    assert abs(select_disparity(S, 0)[0, 0] - 4.3) < 0.01


def test_left_right_check_marks_inconsistent_pixels():
    # One row, disparities 0..2. Every left pixel prefers d = 1, except x = 5 (prefers d = 0, cost 5) and x = 7
    # (prefers d = 2, cost 1). Right pixel 5 is seen by left 5 at d = 0 (cost 5), left 6 at d = 1 (cost 10) and
    # left 7 at d = 2 (cost 1): it picks d = 2, so left 5 (d = 0, |0 - 2| > 1) fails the check while left 6
    # (|1 - 2| <= 1) and left 7 pass. Left 0 at d = 1 leaves the right image.
    S = np.full((1, 8, 3), 100, dtype=np.uint16)
    S[0, :, 1] = 10
    S[0, 5] = [5, 50, 50]
    S[0, 7] = [50, 50, 1]
    disp = select_disparity(S, 0, subpixel=False, lr_check=True)
    np.testing.assert_array_equal(np.isnan(disp[0]), [True, False, False, False, False, True, False, False])
    np.testing.assert_array_equal(disp[0, [1, 2, 3, 4, 6, 7]], [1, 1, 1, 1, 1, 2])
    assert np.isfinite(select_disparity(S, 0, subpixel=False, lr_check=False)).all()


def test_median_equals_opencv_without_nan():
    rng = np.random.default_rng(6)
    disp = rng.random((20, 30)).astype(np.float32) * 50
    np.testing.assert_array_equal(median_filter(disp, 3), cv2.medianBlur(disp, 3))
    # the NaN-aware kernel agrees with OpenCV where there is nothing to ignore
    from riverbed_cli.matching.disparity import median_kernel
    np.testing.assert_array_equal(median_kernel(disp, 1), cv2.medianBlur(disp, 3))
    np.testing.assert_array_equal(median_kernel(disp, 2), cv2.medianBlur(disp, 5))


def test_median_ignores_nan_neighbours():
    disp = np.arange(25, dtype=np.float32).reshape(5, 5)
    disp[2, 1] = np.nan
    out = median_filter(disp, 3)
    assert np.isnan(out[2, 1])
    nb = [disp[y, x] for y in (1, 2, 3) for x in (1, 2, 3) if not np.isnan(disp[y, x])]
    assert out[2, 2] == np.float32(np.median(nb))


@pytest.mark.parametrize("size", [3, 5])
def test_median_with_nan_equals_the_nan_aware_kernel_everywhere(size):
    # median_filter takes OpenCV's median where a window holds no NaN and the kernel's where one does: the same bits
    # as the kernel over every pixel, NaN at the borders (replicated) and in blocks included
    from riverbed_cli.matching.disparity import median_kernel

    rng = np.random.default_rng(size)
    for density in (0.002, 0.05, 0.3, 0.9):
        disp = (rng.random((37, 53)) * 60).astype(np.float32)
        disp[rng.random(disp.shape) < density] = np.nan
        disp[0, 5] = disp[36, 52] = disp[10, 0] = np.nan
        disp[20:24, 30:41] = np.nan
        disp[5, 7:9] = 12.5  # ties
        out = median_filter(disp, size)
        np.testing.assert_array_equal(out, median_kernel(disp, size // 2))
        assert np.array_equal(np.isnan(out), np.isnan(disp))
