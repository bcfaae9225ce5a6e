"""The confidence fusion (riverbed_cli.matching.fusion): per pixel the better of stereo and LiDAR interpolation."""

import math
import threading

import numpy as np
import pytest
from scipy.special import erf

from riverbed_cli.errors import RiverbedError
from riverbed_cli.matching import pipeline
from riverbed_cli.matching.fusion import fuse_disparity, leave_one_out_residuals, lidar_kind, lidar_model
from riverbed_cli.matching.fusions.confidence import ConfidenceFusion
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar

H, W = 96, 192


def half_textured_scene(seed=0):
    """Truth, a stereo result right in the left (textured) half and wrong in the right (blank) half, and coarse LiDAR.

    Left half: 8 px checker steps of 4 px disparity (finer than the 16 px LiDAR grid: its interpolation is wrong
    there), stereo = truth + 0.5 px noise, left-right consistent. Right half: a plane (the interpolation is exact),
    stereo off by 7 px and failing its left-right check, as matches on a blank surface do.
    """
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    textured = x < W // 2
    truth = np.where(textured, 12 + 4 * (((x // 8) + (y // 8)) % 2), 10 + 0.03 * x + 0.02 * y)
    stereo = np.where(textured, truth + rng.normal(0, 0.5, truth.shape), truth + 7).astype(np.float32)
    status = np.where(textured, 0, 1).astype(np.int8)
    sparse = np.full((H, W), np.nan, np.float32)
    sparse[3::13, 2::13] = truth[3::13, 2::13]
    return truth, stereo, status, sparse, textured


@pytest.mark.parametrize("kind", ["auto", "planes"])
def test_fusion_takes_the_better_source_in_each_half(kind):
    truth, stereo, status, sparse, textured = half_textured_scene()
    # the stereo's error given (0.5 px, as constructed): estimated here it would absorb the LiDAR's own error on the
    # checker, which no LiDAR point resolves (docs/fusion.md, limits)
    out = fuse_disparity(stereo, status, sparse, stereo_sigma=0.5, lidar_kind=kind)
    # the fusion's LiDAR side: LiDAR 13 px apart is sparser than auto's 12 px, so auto takes the Delaunay fill
    assert lidar_kind(kind, int(np.isfinite(sparse).sum()), sparse.shape) == ("linear" if kind == "auto" else kind)
    lin = lidar_model(sparse, kind=kind).values
    err = np.abs(out.disparity - truth)
    err_stereo, err_lidar = np.abs(stereo - truth), np.abs(lin - truth)
    inner = np.zeros_like(textured)
    inner[:, 8:-8] = True
    # within about two LiDAR spacings (13 px) of the checker the LiDAR's error estimate still sees its steps, and the
    # stereo is kept there: the halves are judged beyond that
    inner[:, W // 2 - 32:W // 2 + 32] = False
    tex, blank = textured & inner, ~textured & inner
    # textured half: the stereo's precision, not the interpolation's errors at the steps
    assert err[tex].mean() <= 1.25 * err_stereo[tex].mean()
    assert err[tex].mean() < 0.25 * err_lidar[tex].mean()
    assert (err[tex] > 1).mean() <= 1.5 * (err_stereo[tex] > 1).mean() and (err_lidar[tex] > 1).mean() > 0.4
    # blank half: the interpolation (exact on a plane: local planes everywhere, the Delaunay fill inside the points'
    # hull, its nearest value beyond), not the stereo's 7 px error
    assert np.abs(out.disparity - lin)[blank].max() < 1e-3
    assert err[blank].max() < (0.25 if kind == "auto" else 1e-3)
    assert np.isfinite(out.disparity).all()
    # confidence: high where the stereo is kept with its small error, and the textured half's steps the least sure
    assert out.confidence.dtype == np.float32 and 0 <= out.confidence.min() and out.confidence.max() <= 1
    assert out.stats.stereo_sigma == 0.5
    assert out.confidence[blank].mean() > 0.9


def test_agreeing_sources_average_by_inverse_variance():
    # a plane: the interpolation is exact, the stereo noisy; where they agree the output is their weighted mean
    rng = np.random.default_rng(1)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    truth = 20 + 0.05 * x - 0.03 * y
    stereo = (truth + rng.normal(0, 0.5, truth.shape)).astype(np.float32)
    sparse = np.full((H, W), np.nan, np.float32)
    sparse[2::6, 2::6] = truth[2::6, 2::6]
    out = fuse_disparity(stereo, None, sparse, stereo_sigma=0.5, floor=0.25)
    # sigma_l is the floor (planar LiDAR) times the distance growth, 1 within the spacing: weights 1/0.25^2, 1/0.5^2
    model = lidar_model(sparse, floor=0.25)  # local planes: exact on a plane, beyond the points' hull too
    lin, sig_l = model.values.astype(np.float64), model.sigma
    assert np.abs(lin - truth).max() < 1e-4 and (sig_l == np.float32(0.25)).all()
    ws, wl = 1 / 0.25, 1 / sig_l.astype(np.float64) ** 2
    expect = (stereo * ws + lin * wl) / (ws + wl)
    np.testing.assert_allclose(out.disparity, expect.astype(np.float32), atol=1e-4)
    assert np.abs(out.disparity - truth).mean() < 0.5 * np.abs(stereo - truth).mean()
    assert out.stats.agree == 1.0
    # the confidence is erf(1 / (sigma sqrt 2)) of the combined sigma
    sig = 1 / np.sqrt(ws + wl)
    np.testing.assert_allclose(out.confidence, erf(1 / (sig * math.sqrt(2))).astype(np.float32), rtol=1e-5)


def test_leave_one_out_residuals_are_exact_on_a_plane_and_see_a_step():
    ys, xs = np.mgrid[0:10, 0:10]
    rows, cols = ys.ravel() * 5, xs.ravel() * 5
    plane = 3.0 + 0.1 * cols - 0.2 * rows
    res = leave_one_out_residuals(rows, cols, plane)
    assert res.max() < 1e-2  # the tiny ridge on the slopes only
    step = plane + np.where(cols >= 25, 10.0, 0.0)
    res = leave_one_out_residuals(rows, cols, step)
    near = (cols == 20) | (cols == 25)
    assert res[near].min() > 1.0 and np.median(res[cols <= 10]) < 1e-2


def test_fusion_is_the_default_with_lidar_and_none_reproduces_the_paper(cones):
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    fused = match_pair(left, right, sparse, 0, 63)
    plain = match_pair(left, right, sparse, 0, 63, fusion="none")
    assert fused.info["fusion"] == "confidence" and plain.info["fusion"] == "none"
    assert plain.confidence is None and fused.confidence.shape == gt.shape
    mf = evaluate_disparity(fused.disparity, gt, exclude=sparse)
    mp = evaluate_disparity(plain.disparity, gt, exclude=sparse)
    # measured: fused bad1 / bad3 / avg 3.183 / 1.499 / 0.269, the matcher alone 3.203 / 1.510 / 0.278
    # (bad1 of the surer half of the pixels by confidence 0.26 %, of the less sure half 10.4 %)
    assert mf["bad3"] <= mp["bad3"] and mf["avg"] <= mp["avg"] and mf["bad1"] <= mp["bad1"] * 1.02
    # the confidence ranks the errors: the surest half of the pixels has fewer bad pixels than the least sure half
    g = np.isfinite(gt) & ~np.isfinite(sparse)
    err = np.abs(fused.disparity - gt)[g]
    c = fused.confidence[g]
    assert (err[c >= np.median(c)] > 1).mean() < 0.1 * (err[c < np.median(c)] > 1).mean()
    unguided = match_pair(left, right, None, 0, 63, guide="none")
    assert unguided.info["fusion"] == "none"


def test_lidar_side_beside_the_matcher_gives_the_bits_of_after_it(cones):
    # match_pair runs the fusion's LiDAR side in a thread beside the matcher (images up to LIDAR_THREAD_MAX_PIXELS); run
    # after the matcher instead, in the calling thread (what tiles ask for), it gives the same output
    left, right, gt = cones
    assert gt.size <= pipeline.LIDAR_THREAD_MAX_PIXELS
    sparse = simulate_lidar(gt, 0.05, seed=0)
    beside = match_pair(left, right, sparse, 0, 63)
    after = match_pair(left, right, sparse, 0, 63, lidar_thread=False)
    assert np.array_equal(beside.disparity, after.disparity, equal_nan=True)
    assert np.array_equal(beside.confidence, after.confidence)
    assert beside.info["fusion_stats"] == after.info["fusion_stats"]


def test_an_error_of_the_lidar_side_reaches_the_caller_and_leaves_no_thread(cones, monkeypatch):
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)

    def fail(self, sparse, config, points=None):
        raise RiverbedError("the LiDAR side failed")

    monkeypatch.setattr(ConfidenceFusion, "prepare", fail)
    before = threading.active_count()
    with pytest.raises(RiverbedError, match="^the LiDAR side failed$"):
        match_pair(left, right, sparse, 0, 63)
    assert threading.active_count() == before


@pytest.mark.parametrize("extra, message", [
    (["--fusion", "confidence"], "riverbed: error: --fusion confidence needs --sparse (it combines the stereo with the "
                                 "LiDAR)\n"),
    (["--fusion-gate", "-1"], "riverbed: error: --fusion-gate: expected a positive number, got -1\n"),
    (["--guide", "none", "--confidence", "{tmp}/c.tif"],
     "riverbed: error: {tmp}/c.tif: no confidence with --fusion none (it comes from --fusion confidence, the default "
     "with --sparse)\n"),
])
def test_fusion_bad_inputs_are_one_line_errors(tmp_path, extra, message):
    from click.testing import CliRunner

    from riverbed_cli.cli.main import cli

    extra = [e.format(tmp=tmp_path) for e in extra]
    r = CliRunner().invoke(cli, ["match", "tests/data/cones/im2.png", "tests/data/cones/im6.png", "--max-disp", "59",
                                 *extra, "-o", str(tmp_path / "d.tif")])
    assert r.exit_code == 1 and r.output == message.format(tmp=tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_confidence_file_is_written_beside_the_disparity(cones, tmp_path):
    from click.testing import CliRunner

    from riverbed_cli.cli.main import cli
    from riverbed_cli.io.disparity import read_disparity, write_disparity

    write_disparity(tmp_path / "s.tif", simulate_lidar(cones[2], 0.05, seed=0))
    r = CliRunner().invoke(cli, ["match", "tests/data/cones/im2.png", "tests/data/cones/im6.png", "--sparse",
                                 str(tmp_path / "s.tif"), "--max-disp", "59", "--min-disp", "0", "-o",
                                 str(tmp_path / "d.tif"), "--confidence", str(tmp_path / "c.tif")])
    assert r.exit_code == 0, r.output
    conf, disp = read_disparity(tmp_path / "c.tif"), read_disparity(tmp_path / "d.tif")
    lib = match_pair(*cones[:2], read_disparity(tmp_path / "s.tif"), 0, 59)
    np.testing.assert_array_equal(conf, lib.confidence)
    np.testing.assert_array_equal(disp, lib.disparity)
    assert conf.dtype == np.float32 and 0 <= conf.min() and conf.max() <= 1


def test_confidence_of_a_tiled_match(cones, tmp_path):
    """Tiled, the confidence is streamed tile by tile as the disparities: each tile's is its own fusion's, and it
    ranks the errors as the untiled one does. PFM disparities take a streamed confidence too."""
    from click.testing import CliRunner

    from riverbed_cli.cli.main import cli
    from riverbed_cli.io.disparity import read_disparity, write_disparity
    from riverbed_cli.scale.tiles import match_tiled

    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    write_disparity(tmp_path / "s.tif", sparse)
    base = ["match", "tests/data/cones/im2.png", "tests/data/cones/im6.png", "--sparse", str(tmp_path / "s.tif"),
            "--max-disp", "59", "--min-disp", "0", "--tile", "128", "--overlap", "64"]
    for out in ("d.tif", "d.pfm"):
        r = CliRunner().invoke(cli, [*base, "-o", str(tmp_path / out), "--confidence", str(tmp_path / f"{out}.c.tif")])
        assert r.exit_code == 0, r.output
    conf = read_disparity(tmp_path / "d.tif.c.tif")
    ref = np.full(gt.shape, np.nan, np.float32)
    lib = match_tiled(left, right, sparse, 0, 59, tile=128, overlap=64, confidence_out=ref)
    assert lib.info["tiles"] == 12
    np.testing.assert_array_equal(conf, ref)
    np.testing.assert_array_equal(read_disparity(tmp_path / "d.pfm.c.tif"), ref)
    np.testing.assert_array_equal(read_disparity(tmp_path / "d.tif"), lib.disparity)
    assert np.isfinite(conf).all() and 0 <= conf.min() and conf.max() <= 1  # every tile holds LiDAR: all fused
    g = np.isfinite(gt) & ~np.isfinite(sparse)
    err, c = np.abs(lib.disparity - gt)[g], conf[g]
    assert (err[c >= np.median(c)] > 1).mean() < 0.1 * (err[c < np.median(c)] > 1).mean()
    untiled = match_pair(left, right, sparse, 0, 59).confidence
    assert abs(float(conf.mean()) - float(untiled.mean())) < 0.02


def test_median_of_is_numpys_median():
    # the same bits as np.median for odd and even sizes, both float widths, ties; NaN as NumPy
    from riverbed_cli.matching.fusion import median_of

    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 4, 7, 10, 1001, 20000):
        for dtype in (np.float32, np.float64):
            for values in ((rng.random(n) * 10).astype(dtype), np.round(rng.random(n) * 3, 1).astype(dtype)):
                got, want = median_of(values), np.median(values)
                assert got.dtype == want.dtype and got == want, (n, dtype, got, want)
    values = rng.random(101).astype(np.float32)
    values[7] = np.nan
    assert np.isnan(median_of(values))
