"""The LiDAR's disparity offset against the images (matching/lidar_offset.py): the kernel against its plain loop, a
known offset recovered on a constructed pair and on a real one, the rule for removing it, the setting."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.io.disparity import read_disparity, write_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.matching.config import validate_setting
from riverbed_cli.matching.lidar_offset import (MIN_OFFSET, correct_lidar, estimate_offset, patch_costs,
                                                patch_costs_reference, shift_points)
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.settings import SettingError
from conftest import DATA, REPO, RIVERBED

REINDEER = REPO / "sample_data" / "reindeer"


def textured_pair(d=12.4, H=120, W=200, seed=3):
    """A pair of blurred noise whose right view is the left one shifted by ``d`` px (sub-pixel: linear)."""
    import cv2

    rng = np.random.default_rng(seed)
    left = cv2.GaussianBlur(rng.uniform(0, 255, (H, W)).astype(np.float32), (0, 0), 1.2)
    xs = np.arange(W, dtype=np.float32)[None, :] + np.float32(d)  # right(x) = left(x + d)
    right = cv2.remap(left, np.repeat(xs, H, 0), np.repeat(np.arange(H, dtype=np.float32)[:, None], W, 1),
                      cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    to8 = lambda a: np.clip(a, 0, 255).astype(np.uint8)  # noqa: E731
    return to8(left), to8(right)


def test_patch_costs_equal_their_plain_loop():
    left, right = textured_pair()
    g = [im.astype(np.float32) for im in (left, right)]
    rng = np.random.default_rng(0)
    rows, cols = rng.integers(0, 120, 300), rng.integers(0, 200, 300)
    vals = rng.uniform(0, 40, 300).astype(np.float32)
    offsets = np.arange(-3, 3.01, 0.375)
    fast = patch_costs(*g, rows, cols, vals, offsets)
    slow = patch_costs_reference(*g, rows, cols, vals, offsets)
    assert fast.shape == (300, len(offsets))
    np.testing.assert_allclose(fast, slow, atol=2e-5)
    assert 0.2 < (fast == 1.0).mean() < 0.8  # patches leaving the image cost the cap, the others less
    flat = patch_costs(np.full((40, 40), 9, np.float32), np.full((40, 40), 9, np.float32), [20], [30], [3.0], [0.0])
    assert flat[0, 0] == 1.0  # a flat patch says nothing


@pytest.mark.parametrize("bias", [0.0, 3.0, -2.3, 3.6])  # within the search (4 px for one disparity)
def test_a_known_offset_is_recovered_on_a_constructed_pair(bias):
    left, right = textured_pair(d=12.4)
    rows, cols = np.mgrid[10:110:5, 30:190:5].reshape(2, -1)
    vals = np.full(rows.size, 12.4 + bias, np.float32)
    offset, gain, n, search, spread = estimate_offset(left, right, rows, cols, vals)
    assert n == rows.size and search == 4.0 and spread < 0.5  # the blocks on the 1 px grid: within half a pixel
    assert offset == pytest.approx(bias, abs=0.1)
    assert (gain > 0.3) if bias else (gain < 0.01)


def test_the_offset_is_removed_at_1_5_px_and_not_below():
    left, right = textured_pair(d=12.4)
    sparse = np.full(left.shape, np.nan, np.float32)
    sparse[10:110:5, 30:190:5] = 12.4 + 1.2
    out, est = correct_lidar(left, right, sparse)
    assert out is sparse and est.applied == 0.0 and est.estimated == pytest.approx(1.2, abs=0.1)
    sparse[10:110:5, 30:190:5] = 12.4 + 2.0
    out, est = correct_lidar(left, right, sparse)
    assert est.mode == "auto" and est.applied == est.estimated >= MIN_OFFSET
    assert est.applied == pytest.approx(2.0, abs=0.1)
    np.testing.assert_allclose(out[10:110:5, 30:190:5], 12.4 + 2.0 - est.applied, atol=1e-5)
    assert np.isnan(out).sum() == np.isnan(sparse).sum()
    out, est = correct_lidar(left, right, sparse, "none")
    assert out is sparse and est.to_dict() == {"mode": "none", "applied": 0.0, "estimated": None, "points": 0,
                                               "gain": None, "search": None, "spread": None}
    out, est = correct_lidar(left, right, sparse, "1,-2,2.5")
    assert est.mode == "forced" and est.applied == 2.5
    np.testing.assert_allclose(out[12:112:5, 29:189:5], 12.4 + 2.0 - 2.5)  # moved back by (-1, +2) px


def test_shift_points_moves_the_points_back():
    sparse = np.full((6, 7), np.nan, np.float32)
    sparse[2, 3] = 5.0
    sparse[0, 6] = 1.0
    out = shift_points(sparse, 1, -2)  # registered 1 px right and 2 px up of the truth: put back left and down
    assert np.argwhere(np.isfinite(out)).tolist() == [[2, 5], [4, 2]]
    assert out[4, 2] == 5.0 and out[2, 5] == 1.0
    assert shift_points(sparse, 0.4, -0.3) is sparse


def test_a_biased_lidar_on_a_real_pair_is_corrected_and_matches_like_a_clean_one():
    """Reindeer (the bundled half-size pair, 5 % of its GT as LiDAR): +4 px on every LiDAR disparity made the default
    match 90 % bad; with the offset removed it matches as the clean LiDAR does."""
    left, right = read_image(REINDEER / "left.png"), read_image(REINDEER / "right.png")
    gt, sparse = read_disparity(REINDEER / "gt.png", scale=2), read_disparity(REINDEER / "lidar_5pct.tif")
    clean = match_pair(left, right, sparse)
    biased = match_pair(left, right, sparse + 4)
    kept = match_pair(left, right, sparse + 4, lidar_offset="none", lidar_check="off")
    e = {k: evaluate_disparity(r.disparity, gt, exclude=sparse) for k, r in
         (("clean", clean), ("biased", biased), ("kept", kept))}
    est = biased.info["lidar_offset"]
    assert clean.info["lidar_offset"]["applied"] == 0.0
    # the ground truth sits 0.2 px off its images (unguided stereo sees the same): the estimate is the bias + that
    assert est["estimated"] - clean.info["lidar_offset"]["estimated"] == pytest.approx(4.0, abs=0.05)
    assert e["kept"]["bad3"] > 80
    assert e["biased"]["bad3"] == pytest.approx(e["clean"]["bad3"], rel=0.05)
    # corrected to the images, the LiDAR sits where they put it, 0.2 px off the ground truth it was sampled from: the
    # mean error against that ground truth grows by about that much, no more
    assert 0 < e["biased"]["avg"] - e["clean"]["avg"] < abs(clean.info["lidar_offset"]["estimated"])


def test_the_setting_on_the_command_line_and_in_json(tmp_path):
    sparse = read_disparity(REINDEER / "lidar_5pct.tif")
    write_disparity(tmp_path / "biased.tif", sparse - 3)
    args = ["match", REINDEER / "left.png", REINDEER / "right.png", "--sparse", tmp_path / "biased.tif", "--json"]
    r = CliRunner().invoke(cli, [*map(str, args), "-o", str(tmp_path / "d.tif")])
    assert r.exit_code == 0, r.output
    info = json.loads(r.output[r.output.index("{"):])
    assert info["lidar_offset"]["mode"] == "auto" and info["lidar_offset"]["applied"] == pytest.approx(-3.2, abs=0.1)
    r = CliRunner().invoke(cli, [*map(str, args), "-o", str(tmp_path / "e.tif"), "--lidar-offset", "none"])
    assert json.loads(r.output[r.output.index("{"):])["lidar_offset"]["mode"] == "none"
    r = CliRunner().invoke(cli, [*map(str, args), "-o", str(tmp_path / "f.tif"), "--lidar-offset", "1,x"])
    assert r.exit_code == 1
    assert r.output.endswith("--lidar-offset: expected auto, none, DD or DX,DY,DD (px; DX and DY at most 64), "
                             "got '1,x'\n")
    assert not (tmp_path / "f.tif").exists()


@pytest.mark.parametrize("value, expected", [("auto", "auto"), ("none", "none"), (2, 2.0), ("-1.5", -1.5),
                                             ("1, 2, 3", "1,2,3")])
def test_setting_values(value, expected):
    assert validate_setting("lidar_offset", value) == expected


@pytest.mark.parametrize("value", ["inf", "1,2", "65,0,1", True, "", "auto,1"])
def test_setting_refuses(value):
    with pytest.raises(SettingError, match="expected auto, none, DD or DX,DY,DD"):
        validate_setting("lidar_offset", value)


def test_an_error_that_varies_over_the_image_is_not_removed_as_one_offset():
    """A LiDAR +3 px off on the left half and -3 px on the right (as an old coarse DEM used as LiDAR is, locally):
    no single offset explains it, and none is removed."""
    left, right = textured_pair(d=12.4)
    sparse = np.full(left.shape, np.nan, np.float32)
    sparse[10:110:5, 30:190:5] = 12.4
    sparse[:, :110] += 3.0
    sparse[:, 110:] -= 3.0
    out, est = correct_lidar(left, right, sparse)
    assert out is sparse and est.applied == 0.0 and est.spread > 2.5


def test_a_tiled_match_estimates_once_and_every_tile_takes_the_corrected_lidar(tmp_path):
    """Windowed (TIFF) LiDAR +5 px off, matched in 12 tiles: one estimate for all of them, reported in the tiled info,
    and the result as the clean LiDAR's within a few hundredths of bad3 (none of the tiles' own estimates)."""
    from riverbed_cli.io.windowed import WindowedRaster
    from riverbed_cli.scale.tiles import match_tiled

    left, right = read_image(REINDEER / "left.png"), read_image(REINDEER / "right.png")
    gt, sparse = read_disparity(REINDEER / "gt.png", scale=2), read_disparity(REINDEER / "lidar_5pct.tif")
    write_disparity(tmp_path / "biased.tif", sparse + 5)
    clean = match_tiled(left, right, sparse, tile=192)
    biased = match_tiled(left, right, WindowedRaster(tmp_path / "biased.tif", "disparity"), tile=192)
    assert biased.info["tiles"] == clean.info["tiles"] == 12
    est = biased.info["lidar_offset"]
    assert est["mode"] == "auto" and est["applied"] - clean.info["lidar_offset"]["estimated"] == pytest.approx(5, abs=0.05)
    e = [evaluate_disparity(r.disparity, gt, exclude=sparse)["bad3"] for r in (clean, biased)]
    assert e[1] == pytest.approx(e[0], abs=0.1) and e[0] < 1.5
    forced = match_tiled(left, right, sparse + 5, tile=192, lidar_offset=5.0)
    assert forced.info["lidar_offset"] == {"mode": "forced", "applied": 5.0, "estimated": None, "points": 0,
                                           "gain": None, "search": None, "spread": None}
    np.testing.assert_array_equal(np.isnan(forced.disparity), np.isnan(clean.disparity))


def test_project_reports_a_raised_cloud_in_metres(tmp_path):
    """The sample block's LiDAR raised by 2 m (another vertical datum, say): `riverbed project` reports the offset the
    images see, in px and in metres, with one warning; `riverbed match` removes it."""
    import subprocess

    import laspy

    block = REPO / "sample_data" / "block"
    las = laspy.read(block / "lidar.laz")
    las.z = las.z + 2.0
    las.write(tmp_path / "raised.laz")
    r = subprocess.run([*RIVERBED, "project", str(tmp_path / "raised.laz"),
                        str(block / "pair.yaml"), "-o", str(tmp_path / "s.tif"), "--json"], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)["lidar_offset"]
    assert est["vertical_m"] == pytest.approx(2.0, abs=0.1) and est["applied"] == pytest.approx(1.6, abs=0.1)
    assert r.stderr == (f"riverbed: WARNING: the LiDAR lies {est['vertical_m']:+.2f} m ({est['applied']:+.2f} px) off "
                        "the surface the images see: another vertical datum or a height offset? riverbed match "
                        "removes it (--lidar-offset none keeps it)\n")
    clean = CliRunner().invoke(cli, ["project", str(block / "lidar.laz"), str(block / "pair.yaml"), "-o",
                                     str(tmp_path / "c.tif"), "--json"])
    assert abs(json.loads(clean.output)["lidar_offset"]["vertical_m"]) < 0.1
