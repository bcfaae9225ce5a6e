"""The overlap rule (riverbed_cli.matching.overlap): no disparity where no match is possible, no fill beyond the LiDAR."""

from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image, read_valid_area, write_png_file
from riverbed_cli.io.windowed import valid_area_source
from riverbed_cli.matching.fusion import FusionOutput, FusionStats
from riverbed_cli.matching.overlap import (keep_fusion_to_lidar, lidar_coverage, match_outside, matchable_mask,
                                           matchable_mask_reference)
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.matching.volume import TubeLayout

RAW = Path(__file__).resolve().parents[1] / "sample_data" / "block" / "raw"
H, W, D = 60, 160, 24  # a fronto-parallel pair: the right image is the left one shifted by D px


def shifted_pair(seed=0, d=D):
    """A textured left image and the right one seen D px further right (``right[x] = left[x + d]``): left pixels
    ``x < d`` show what the right image does not, and right pixels ``x >= W - d`` what the left one does not."""
    rng = np.random.default_rng(seed)
    wide = rng.integers(0, 256, (H, W + d), dtype=np.uint8)
    wide = np.repeat(np.repeat(wide[::2, ::2], 2, axis=0), 2, axis=1)[:H, :W + d]  # 2 px texture: SGM-friendly
    return np.ascontiguousarray(wide[:, :W]), np.ascontiguousarray(wide[:, d:])


@pytest.mark.parametrize("lo,hi", [(0, 5), (20, 28), (-6, 3), (150, 170), (-170, -150)])
def test_matchable_mask_is_the_plain_loop(lo, hi):
    rng = np.random.default_rng(lo + 1000)
    right_valid = rng.random((7, 40)) > 0.3
    left_valid = rng.random((7, 40)) > 0.2
    for rv, lv in ((None, None), (right_valid, None), (right_valid, left_valid)):
        np.testing.assert_array_equal(matchable_mask((7, 40), lo, hi, rv, lv),
                                      matchable_mask_reference((7, 40), lo, hi, rv, lv))


def test_matchable_mask_with_tubes_is_the_plain_loop():
    rng = np.random.default_rng(3)
    d_min, d_max = 2, 30
    lo = rng.integers(d_min, d_max + 1, (9, 50))
    hi = np.minimum(lo + rng.integers(0, 12, lo.shape), d_max)
    hi[:, ::7] = d_max  # some tubes as wide as the range: at least one candidate inside suffices there
    lo[:, ::7] = d_min
    tubes = TubeLayout.from_bounds(lo, hi, d_min)
    right_valid = rng.random((9, 50)) > 0.2
    for rv in (None, right_valid):
        got = matchable_mask((9, 50), d_min, d_max, rv, tubes=tubes)
        np.testing.assert_array_equal(got, matchable_mask_reference((9, 50), d_min, d_max, rv, tubes=tubes))
    # a narrow tube is matchable while its middle lies inside, a full-width one while one candidate is inside
    got = matchable_mask((9, 50), d_min, d_max, tubes=tubes)
    x = np.arange(50)[None, :]
    narrow = (hi - lo) < d_max - d_min
    mid = (lo + hi) // 2
    assert not got[narrow & (x < mid)].any() and got[narrow & (x >= mid)].all()
    assert got[~narrow & (x >= d_min)].all() and not got[~narrow & (x < d_min)].any()


def test_match_outside_marks_choices_beyond_the_right_image():
    disp = np.array([[0.0, 2.0, 2.4, np.nan, 3.0, -1.0]], np.float32)
    # x - d: 0, -1, -0.4, -, 1, 6 (beyond the last column 5 by more than half a pixel)
    np.testing.assert_array_equal(match_outside(disp), [[False, True, False, False, False, True]])
    right_valid = np.array([[True, False, True, True, True, True]])
    np.testing.assert_array_equal(match_outside(disp, right_valid), [[False, True, False, False, True, True]])


@pytest.mark.parametrize("params", [dict(guide="none"), dict(guide="none", lr_check=True),
                                    dict(matcher="adcensus", guide="none")])
def test_unguided_match_leaves_the_pixels_outside_the_overlap_invalid(params):
    left, right = shifted_pair()
    res = match_pair(left, right, None, D - 4, D + 4, **params)
    d = res.disparity
    # every candidate of x < D - 4 lies left of the right image; x < D: the true match does
    assert np.isnan(d[:, :D - 4]).all()
    assert res.info["outside_overlap"] == pytest.approx((D - 4) / W, abs=1e-6)
    x = np.arange(W)[None, :]
    assert not (np.isfinite(d) & (x - d < -0.5)).any()  # no output whose match lies outside the right image
    inner = d[4:-4, D + 8:-8]
    assert np.nanmean(np.abs(inner - D) <= 1) > 0.97 and np.isfinite(inner).mean() > 0.9


def test_fusion_fills_outside_the_overlap_only_where_the_lidar_covers_it():
    left, right = shifted_pair()
    truth = np.full((H, W), float(D), np.float32)
    y, x = np.mgrid[0:H, 0:W]
    everywhere = np.where((y % 6 == 0) & (x % 6 == 0), truth, np.nan).astype(np.float32)
    # LiDAR as riverbed project gives it: only points seen in both images (x >= D)
    projected = np.where(x >= D, everywhere, np.nan).astype(np.float32)
    res = match_pair(left, right, projected)
    d, conf = res.disparity, res.confidence
    assert res.info["fusion"] == "confidence"
    # the points' coverage (their hull and one spacing, 6 px, around it) starts 6 px left of the first column
    # holding a point: left of it there is no stereo and nothing to interpolate
    first = int(np.ceil(D / 6) * 6) - 6
    assert np.isnan(d[:, :first]).all() and (conf[:, :first] == 0).all()
    assert np.isfinite(d[:55, first:]).all()  # (the rounded corners below the last row of points aside)
    assert res.info["fusion_stats"]["invalid"] == pytest.approx(np.isnan(d).mean(), abs=1e-4)
    assert np.nanmax(np.abs(d[:, first:] - D)) <= 1.0
    # LiDAR over the whole left image (a benchmark's, sampled from the ground truth): its interpolation there
    res = match_pair(left, right, everywhere)
    d = res.disparity
    assert np.isfinite(d[:H - 5, :W - 5]).all()
    assert np.nanmax(np.abs(d - D)) <= 1.0


def test_fusion_never_extrapolates_beyond_the_searched_range():
    stereo = np.full((4, 10), np.nan, np.float32)
    stereo[:, 5:] = 20.0
    # the LiDAR side's planes reach 31 at the left: beyond [18, 25] (+1 px for the sub-pixel refinement)
    values = np.tile(np.linspace(31.0, 20.0, 10, dtype=np.float32), (4, 1))
    fused = FusionOutput(values.copy(), np.full((4, 10), 0.9, np.float32), FusionStats(0.3, 0.5, 0.5, 0.0, 0.9))
    points = (np.array([0, 0, 3, 3]), np.array([0, 9, 0, 9]), np.zeros(4))
    out = keep_fusion_to_lidar(fused, ~np.isfinite(stereo), points, 18, 25)
    keep = values <= 26.0
    np.testing.assert_array_equal(np.isfinite(out.disparity), keep)
    assert (out.confidence[~keep] == 0).all() and out.stats.invalid == pytest.approx(np.mean(~keep), abs=1e-4)
    # without LiDAR around, no fill at all where the stereo has none
    fused = FusionOutput(values.copy(), np.full((4, 10), 0.9, np.float32))
    out = keep_fusion_to_lidar(fused, ~np.isfinite(stereo), (np.array([0, 1, 2]), np.array([9, 9, 9]), None), 18, 32)
    np.testing.assert_array_equal(np.isfinite(out.disparity), np.isfinite(stereo))


def test_lidar_coverage_is_the_points_hull_and_one_spacing_around_it():
    points = (np.array([2, 2, 8]), np.array([1, 9, 5]), None)
    cov = lidar_coverage(points, (12, 12), reach=0)
    assert cov[2, 1] and cov[2, 9] and cov[8, 5] and cov[4, 5]
    assert not cov[8, 1] and not cov[0, 0] and not cov[10, 5]
    assert not lidar_coverage((np.array([1, 2]), np.array([1, 2]), None), (5, 5)).any()
    # default reach: the mean spacing, sqrt(hull area / points) = sqrt(24 / 3) = 2.8 -> 3 px
    wide = lidar_coverage(points, (20, 20))
    np.testing.assert_array_equal(wide, lidar_coverage(points, (20, 20), reach=3))
    assert wide[11, 5] and not wide[12, 5] and wide[2, 12] and not wide[2, 13]


def test_valid_areas_restrict_the_match():
    left, right = shifted_pair()
    right_valid = np.ones((H, W), bool)
    right_valid[:, 60:90] = False  # a black band of the rectified right image
    left_valid = np.ones((H, W), bool)
    left_valid[:, -10:] = False
    res = match_pair(left, right, None, D, D, guide="none", valid_areas=(left_valid, right_valid))
    d = res.disparity
    x = np.arange(W)
    band = (x - D >= 60) & (x - D < 90)
    assert np.isnan(d[:, band]).all() and np.isnan(d[:, -10:]).all()
    assert np.isfinite(d[:, D:][:, ~band[D:] & (x[D:] < W - 10)]).mean() > 0.95


def test_written_valid_area_round_trips(tmp_path):
    rng = np.random.default_rng(1)
    valid = rng.random((20, 30)) > 0.3
    for name, img in (("grey.png", rng.integers(0, 255, (20, 30), dtype=np.uint8)),
                      ("rgb16.png", rng.integers(0, 65535, (20, 30, 3), dtype=np.uint16))):
        write_png_file(tmp_path / name, img, valid=valid)
        np.testing.assert_array_equal(read_valid_area(tmp_path / name), valid)
        back = read_image(tmp_path / name)
        assert back.dtype == img.dtype and (back == (img if img.ndim == 3 else img[:, :, None])).all()
    write_png_file(tmp_path / "plain.png", np.zeros((4, 5), np.uint8))
    assert read_valid_area(tmp_path / "plain.png") is None
    write_png_file(tmp_path / "full.png", np.zeros((4, 5), np.uint8), valid=np.ones((4, 5), bool))
    assert read_valid_area(tmp_path / "full.png") is None  # all valid: no area to keep to
    # a TIFF's mask as GDAL gives it (here its nodata), read whole or by windows
    data = np.where(valid, 7, 0).astype(np.uint8)
    with rasterio.open(tmp_path / "m.tif", "w", driver="GTiff", width=30, height=20, count=1, dtype="uint8",
                       nodata=0) as ds:
        ds.write(data, 1)
    np.testing.assert_array_equal(read_valid_area(tmp_path / "m.tif"), valid)
    src = valid_area_source(tmp_path / "m.tif")
    np.testing.assert_array_equal(src[3:9, 5:25], valid[3:9, 5:25])
    with rasterio.open(tmp_path / "n.tif", "w", driver="GTiff", width=30, height=20, count=1, dtype="uint8") as ds:
        ds.write(data, 1)
    assert valid_area_source(tmp_path / "n.tif") is None and read_valid_area(tmp_path / "n.tif") is None


def test_rectified_frames_keep_their_valid_area_through_match(tmp_path):
    """rectify --alpha 1 (every source pixel kept: black corners) writes the valid areas as alpha; match leaves
    every pixel outside the left one, and every pixel whose candidates all fall outside the right one, invalid,
    whole or in tiles."""
    raw = RAW

    def run(*args):
        r = CliRunner().invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output
        return r

    run("rectify", raw / "frame0.png", raw / "frame0.yaml", raw / "frame1.png", raw / "frame1.yaml",
        "-o", tmp_path / "r", "--alpha", "1", "--size", "600x400")
    lv, rv = (read_valid_area(tmp_path / "r" / f"{s}.png") for s in ("left", "right"))
    assert lv is not None and rv is not None and 0.6 < lv.mean() < 0.99 and 0.6 < rv.mean() < 0.99
    for tile in ("0", "160"):
        out = tmp_path / f"d{tile}.tif"
        run("match", tmp_path / "r" / "left.png", tmp_path / "r" / "right.png", "--min-disp", 20, "--max-disp", 80,
            "--tile", tile, "--overlap", 32, "-o", out)
        d = read_disparity(out)
        assert not np.isfinite(d[~lv]).any()
        assert not np.isfinite(d[~matchable_mask(d.shape, 20, 80, rv)]).any()
        assert not match_outside(d, rv).any()
        assert np.isfinite(d[lv]).mean() > 0.5


def test_guided_matcher_keeps_its_value_outside_the_overlap_only_inside_the_lidar():
    """Outside the overlap a LiDAR-guided matcher's value is the LiDAR's guidance carried along the image (the
    paper's method, no fusion): kept inside the LiDAR's coverage, invalid beyond it."""
    left, right = shifted_pair()
    y, x = np.mgrid[0:H, 0:W]
    everywhere = np.where((y % 6 == 0) & (x % 6 == 0), np.float32(D), np.float32(np.nan)).astype(np.float32)
    paper = dict(guide="riverbed", range="full", fusion="none", lidar_offset="none", lidar_check="off")
    d = match_pair(left, right, everywhere, **paper).disparity
    assert np.isfinite(d[:55, :D]).all() and np.abs(d[:55, :D] - D).max() <= 1.0
    projected = np.where(x >= D, everywhere, np.nan).astype(np.float32)
    d = match_pair(left, right, projected, **paper).disparity
    first = int(np.ceil(D / 6) * 6) - 6
    assert np.isnan(d[:, :first]).all()
