"""Tiled matching: the tiling must not show in the result, and LiDAR-driven tile ranges must hold the truth."""

import json
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.io.disparity import read_disparity, write_disparity
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar
from riverbed_cli.scale.match_plan import Tile, check_tiling, lidar_ranges, tile_grid
from riverbed_cli.scale.tiles import match_tiled

BORDER = 4  # census half-height/width: the image border where crops and the whole image differ anyway


def same(a, b):
    """Pixels where two disparity maps agree within 0.01 px, or are both invalid (outside the overlap)."""
    return (np.abs(a - b) <= 0.01) | (np.isnan(a) & np.isnan(b))


@pytest.mark.parametrize("guide", ["none", "riverbed"])
def test_tiling_is_invisible(cones, guide):
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    full = match_pair(left, right, sparse, 0, 59, guide=guide, fusion="none").disparity
    tiled = match_tiled(left, right, sparse, 0, 59, guide=guide, tile=128, overlap=160, lidar_range=False,
                        fusion="none")
    assert tiled.info["tiles"] == 12
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    agree = same(tiled.disparity[inner], full[inner])
    assert agree.mean() >= 0.999, f"{100 * agree.mean():.3f} % agree"


def test_lidar_ranges_are_tight_and_hold_the_truth(cones):
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    # one range per tile (range "tile"): LiDAR tile ranges against the global one
    full = match_tiled(left, right, sparse, 0, 63, tile=128, overlap=64, lidar_range=False, range="tile")
    narrow = match_tiled(left, right, sparse, 0, 63, tile=128, overlap=64, lidar_range=True, range="tile")
    assert narrow.info["tile_ranges"]["lidar"] == 12
    assert narrow.info["disparity_evaluations"] < 0.8 * full.info["disparity_evaluations"]
    m_full = evaluate_disparity(full.disparity, gt, exclude=sparse)
    m_narrow = evaluate_disparity(narrow.disparity, gt, exclude=sparse)
    assert m_narrow["bad3"] <= m_full["bad3"] + 0.1 and m_narrow["avg"] <= m_full["avg"] + 0.02


def test_tiles_without_lidar_inherit_from_neighbours():
    sparse = np.full((300, 300), np.nan, np.float32)
    sparse[10:90:7, 10:90:7] = 40.0  # LiDAR only in the top-left tile
    tiles = lidar_ranges(tile_grid(300, 300, 100), sparse, 0, 200, reach=0)
    by = {(t.y0, t.x0): t for t in tiles}
    assert by[0, 0].source == "lidar" and by[0, 0].d_min < 40 < by[0, 0].d_max
    assert by[0, 100].source == by[100, 100].source == "neighbours"
    assert (by[200, 200].d_min, by[200, 200].d_max) == (by[0, 0].d_min, by[0, 0].d_max)
    assert all(isinstance(t, Tile) for t in tiles)


def test_tile_size_is_checked():
    with pytest.raises(RiverbedError, match=r"--tile: expected 'auto' or an integer >= 16 \(px\), got 8; 0 never"):
        tile_grid(100, 100, 8)
    with pytest.raises(RiverbedError, match="--tile: a tile grid needs a side in px, not 0"):
        tile_grid(100, 100, 0)
    assert len(tile_grid(100, 100, np.int64(32))) == 16  # a side numpy computed is a side
    assert check_tiling("96", 0) == 96 and check_tiling("auto", 8) == "auto" and check_tiling(0, 8) == 0


def test_windowed_sources_give_the_same_result(cones, tmp_path):
    import rasterio

    from riverbed_cli.io.disparity import write_disparity
    from riverbed_cli.io.windowed import WindowedRaster, open_windowed

    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    for name, img in (("l.tif", left), ("r.tif", right)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            ds = rasterio.open(tmp_path / name, "w", driver="GTiff", width=img.shape[1], height=img.shape[0], count=3,
                               dtype="uint8", tiled=True, blockxsize=64, blockysize=64)
        with ds:
            ds.write(np.moveaxis(img, -1, 0))
    write_disparity(tmp_path / "s.tif", sparse)
    srcs = [open_windowed(tmp_path / n, k) for n, k in (("l.tif", "image"), ("r.tif", "image"), ("s.tif", "disparity"))]
    assert all(isinstance(s, WindowedRaster) for s in srcs)
    np.testing.assert_array_equal(srcs[0][10:20, 30:45], left[10:20, 30:45])
    a = match_tiled(left, right, sparse, tile=128, overlap=64).disparity
    b = match_tiled(*srcs, tile=128, overlap=64).disparity
    np.testing.assert_array_equal(a, b)


def test_16_bit_tiles_share_one_scale(cones):
    left, right, gt = cones
    # 12-bit data in 16-bit containers: tiles whose own maximum is lower must not be scaled differently
    l16, r16 = ((img.astype(np.uint16) * 16) for img in (left, right))
    sparse = simulate_lidar(gt, 0.05, seed=0)
    full = match_pair(l16, r16, sparse, 0, 59, fusion="none").disparity
    tiled = match_tiled(l16, r16, sparse, 0, 59, tile=128, overlap=160, lidar_range=False, fusion="none").disparity
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    assert same(tiled[inner], full[inner]).mean() >= 0.999


def test_match_command_tiles_tiff_inputs(cones, tmp_path):
    import json

    import rasterio
    from click.testing import CliRunner

    from riverbed_cli.cli.main import cli
    from riverbed_cli.io.disparity import read_disparity, write_disparity

    left, right, gt = cones
    for name, img in (("l.tif", left), ("r.tif", right)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            ds = rasterio.open(tmp_path / name, "w", driver="GTiff", width=img.shape[1], height=img.shape[0],
                               count=3, dtype="uint8", tiled=True, blockxsize=64, blockysize=64)
        with ds:
            ds.write(np.moveaxis(img, -1, 0))
    sparse = simulate_lidar(gt, 0.05, seed=0)
    write_disparity(tmp_path / "s.tif", sparse)
    common = [str(tmp_path / "l.tif"), str(tmp_path / "r.tif"), "--sparse", str(tmp_path / "s.tif"),
              "--min-disp", "0", "--max-disp", "59", "--global-range", "--fusion", "none"]  # the matcher's tiles
    r = CliRunner().invoke(cli, ["match", *common, "--tile", "128", "--overlap", "160", "-o", str(tmp_path / "t.tif"),
                                 "--json", "--color", str(tmp_path / "t.png")])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["tiles"] == 12
    r = CliRunner().invoke(cli, ["match", *common, "--tile", "0", "-o", str(tmp_path / "u.tif")])
    assert r.exit_code == 0, r.output
    a, b = read_disparity(tmp_path / "t.tif"), read_disparity(tmp_path / "u.tif")
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    assert same(a[inner], b[inner]).mean() >= 0.999
    assert (tmp_path / "t.png").is_file()
    r = CliRunner().invoke(cli, ["match", *common, "--tile", "8", "-o", str(tmp_path / "x.tif")])
    assert r.exit_code == 1
    # the settings table's validator: the message a block manifest's tile gets (tests/test_block.py)
    assert r.output == "riverbed: error: --tile: expected 'auto' or an integer >= 16 (px), got 8; 0 never tiles\n"
    for tile, overlap, message in (("big", "16", "--tile: expected 'auto' or an integer >= 16 (px), got 'big'"),
                                   ("64", "-1", "--overlap: expected an integer >= 0, got -1")):
        r = CliRunner().invoke(cli, ["match", *common, "--tile", tile, "--overlap", overlap, "-o",
                                     str(tmp_path / "y.tif")])
        assert r.exit_code == 1 and r.output.startswith(f"riverbed: error: {message}"), r.output


def test_tile_auto_tiles_under_a_small_budget(tmp_path, cones, monkeypatch):
    """--tile auto with a budget the whole image does not fit: tiles are used, and the map equals the untiled one
    away from the borders (every tile searches the global range)."""
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    write_disparity(tmp_path / "s.tif", sparse)
    common = ["tests/data/cones/im2.png", "tests/data/cones/im6.png", "--sparse", str(tmp_path / "s.tif"),
              "--min-disp", "0", "--max-disp", "59", "--global-range", "--json", "--fusion", "none"]
    r = CliRunner().invoke(cli, ["match", *common, "--tile", "0", "-o", str(tmp_path / "whole.tif")])
    assert r.exit_code == 0, r.output
    # with tubes (~11 disparities a pixel on Cones) the whole image's volumes take ~12 MiB: 4 MiB do not hold them
    monkeypatch.setenv("RIVERBED_TILE_BUDGET_MIB", "4")
    r = CliRunner().invoke(cli, ["match", *common, "--overlap", "96", "-o", str(tmp_path / "tiled.tif")])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["tiles"] > 1 and s["tile"] < 450
    monkeypatch.setenv("RIVERBED_TILE_BUDGET_MIB", "150")  # a tube crop: ~118 MiB, the full range: ~190: untiled
    r = CliRunner().invoke(cli, ["match", *common, "-o", str(tmp_path / "fits.tif")])
    assert r.exit_code == 0 and "tiles" not in json.loads(r.output)
    a, b = read_disparity(tmp_path / "tiled.tif"), read_disparity(tmp_path / "whole.tif")
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    assert same(a[inner], b[inner]).mean() >= 0.999


def test_tube_tiles_are_sized_for_the_tubes_only_for_sgm():
    # SGM's tube tiles count the tubes' volume; AD-Census's exact tube aggregation holds 1.6-3.8x the tubes' costs,
    # so its tiles are planned for the nominal volume (as with --range full): smaller tiles under the same budget.
    from riverbed_cli.matching.pipeline import make_config
    from riverbed_cli.scale.match_plan import plan_tiles, tube_widths

    H, W = 3000, 3000
    rng = np.random.default_rng(0)
    n = H * W // 100
    rows, cols = rng.integers(0, H, n), rng.integers(0, W, n)
    vals = (100 + 0.01 * cols).astype(np.float32)
    share = 0.01
    sgm = tube_widths(make_config(None, guide="riverbed"), (rows, cols, vals), (H, W), 0, 300, share)
    ad = tube_widths(make_config(None, guide="riverbed", matcher="adcensus"), (rows, cols, vals), (H, W), 0, 300,
                     share)
    assert ad is None and sgm is not None
    assert 4 < float(sgm[0].mean()) < 40
    budget = 256 * 2**20
    tubes = plan_tiles(H, W, None, 0, 300, "auto", 64, False, budget=budget, widths=sgm)
    nominal = plan_tiles(H, W, None, 0, 300, "auto", 64, False, budget=budget, widths=ad)
    assert tubes.size > 2 * nominal.size


def test_tiled_tube_matches_report_their_tubes(cones):
    # One tile on the global range searches exactly the untiled match's tubes: the same statistics. Tiles on their
    # LiDAR ranges clip the tubes to them: no pixel is left on the nominal range, and no tube is wider.
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    whole = match_pair(left, right, sparse, 0, 59, guide="riverbed", fusion="none")
    one = match_tiled(left, right, sparse, 0, 59, guide="riverbed", fusion="none", tile=0, lidar_range=False)
    assert whole.info["range"] == one.info["range"] == "tube"
    assert one.info["tubes"] == whole.info["tubes"]
    assert np.array_equal(one.disparity, whole.disparity, equal_nan=True)
    tiled = match_tiled(left, right, sparse, 0, 59, guide="riverbed", fusion="none", tile=128, overlap=64)
    t = tiled.info["tubes"]
    assert tiled.info["range"] == "tube" and t["nominal"] == 60 and t["full_share"] == 0.0
    assert 2 < t["mean_width"] <= whole.info["tubes"]["mean_width"] and t["max_width"] <= 60
    ranges = match_tiled(left, right, sparse, 0, 59, guide="riverbed", fusion="none", tile=128, overlap=64,
                         range="full")
    assert ranges.info["range"] == "tile" and "tubes" not in ranges.info.to_dict()


def test_tiled_matches_check_the_lidar_against_the_range_as_untiled_ones(cones, caplog):
    # LiDAR wholly outside the range is an error for a tiled match too (it used to run unguided); LiDAR partly
    # outside is reported once, not per tile
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    for run in (match_pair, match_tiled):
        with pytest.raises(RiverbedError) as e:
            run(left, right, sparse, 60, 70)
        assert str(e.value) == "disparity range [60, 70] excludes all sparse disparities (they span [9.25, 55.00])"
    n, n_out = int(np.isfinite(sparse).sum()), int((sparse > 39).sum())
    caplog.clear()
    with caplog.at_level("WARNING", logger="riverbed_cli"):
        # the LiDAR check off: its dropped points would change the count (test_lidar_check.py)
        match_tiled(left, right, sparse, 0, 39, tile=128, overlap=32, fusion="none", lidar_check="off")
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert warned == [f"{n_out} of {n} sparse disparities lie outside [0, 39]: they guide no cost (tubes keep the "
                      "pixels only they reach at the range's end)"]


def test_prepare_sparse_keeps_the_finite_values_inside_the_range():
    # one pass of counts and one copy: the same map as NumPy's masks (bounds inclusive, inf and NaN no LiDAR)
    from riverbed_cli.matching.lidar_input import prepare_sparse

    rng = np.random.default_rng(3)
    sparse = np.where(rng.random((40, 50)) < 0.2, rng.uniform(-5.0, 45.0, (40, 50)), np.nan).astype(np.float32)
    sparse[0, :6] = [np.inf, -np.inf, 0.0, 39.0, 39.00001, -0.00001]
    kept = prepare_sparse(sparse, (40, 50), 0, 39)
    inside = np.isfinite(sparse) & (sparse >= 0) & (sparse <= 39)
    assert np.array_equal(kept, np.where(inside, sparse, np.float32(np.nan)), equal_nan=True)
    assert kept.dtype == np.float32 and np.isnan(sparse).sum() < np.isnan(kept).sum()
    assert kept[0, 2] == 0.0 and kept[0, 3] == 39.0 and np.isnan(kept[0, [0, 1, 4, 5]]).all()
    whole = np.where(inside, sparse, np.float32(np.nan))
    assert prepare_sparse(whole, (40, 50), 0, 39) is whole  # all inside: the map itself, no copy
    with pytest.raises(RiverbedError) as e:
        prepare_sparse(np.full((40, 50), np.inf, np.float32), (40, 50), 0, 39)
    assert str(e.value) == "sparse map has no valid disparities"


def test_a_tiled_match_guides_with_the_points_the_whole_check_keeps():
    # a tiled match checks its LiDAR once for the whole pair and keeps the result as the check's byte per pixel over
    # the given map (CheckedSparse), not as a float copy: the same points as the untiled check, window by window
    from riverbed_cli.io.windowed import sparse_points_any
    from riverbed_cli.matching.config import MatchConfig
    from riverbed_cli.scale.tiles import CheckedSparse, prepare_lidar_whole
    from test_lidar_check import constructed

    left, right, sparse, _ = constructed()
    stale = sparse.copy()
    stale[40:110, 70:170] += 8  # a region whose LiDAR shows an older surface
    whole = match_pair(left, right, stale)
    kept = np.where(whole.lidar_check.dropped > 0, np.nan, stale)
    assert (whole.lidar_check.dropped == 2).sum() == np.isfinite(stale[40:110, 70:170]).sum() == 425
    lidar = prepare_lidar_whole(left, right, stale, sparse_points_any(stale), None, None, MatchConfig())
    assert isinstance(lidar.sparse, CheckedSparse) and (lidar.check.dropped == whole.lidar_check.dropped).all()
    assert np.array_equal(np.asarray(lidar.sparse), kept, equal_nan=True)
    assert np.array_equal(lidar.sparse[35:97, 60:201], kept[35:97, 60:201], equal_nan=True)
    assert np.array_equal(lidar.points[2], kept[np.isfinite(kept)])
    tiled = match_tiled(left, right, stale, tile=128, overlap=32)
    assert tiled.info["tiles"] == 4 and (tiled.lidar_check.dropped == whole.lidar_check.dropped).all()


def test_the_checks_reference_in_small_tiles_drops_the_same_points(monkeypatch):
    # the reference's tiles are bounded apart (REFERENCE_BUDGET, REFERENCE_OVERLAP: a whole-range pass at the
    # match's own budget set a tiled match's peak memory); cut into several tiles it finds the same change
    from riverbed_cli.scale import tiles
    from test_lidar_check import constructed

    left, right, sparse, _ = constructed(H=200, W=320)
    stale = sparse.copy()
    stale[40:110, 70:170] += 8
    whole = match_pair(left, right, stale)
    counts, plain = [], tiles.match_tiled

    def counted(*args, **kwargs):
        res = plain(*args, **kwargs)
        counts.append(res.info["tiles"])
        return res

    monkeypatch.setattr(tiles, "REFERENCE_BUDGET", 2**20)  # the smallest tiles (128 px)
    monkeypatch.setattr(tiles, "match_tiled", counted)
    res = counted(left, right, stale, tile=128, overlap=32)
    assert counts == [2, 6]  # the reference in two tiles of its own (whole at the match's budget), then the match's 6
    assert (res.lidar_check.dropped == whole.lidar_check.dropped).all()
    assert (whole.lidar_check.dropped[40:110, 70:170][np.isfinite(sparse[40:110, 70:170])] == 2).all()
