"""Metrics against hand-computed answers, the visualisations, and the ``riverbed evaluate`` command."""

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.cameras import PairGeometry
from riverbed_cli.geometry.pairfile import write_pairfile
from riverbed_cli.io.disparity import read_disparity, write_disparity
from riverbed_cli.io.raster import write_geotiff
from riverbed_cli.products.dsm import hillshade
from riverbed_cli.products.dsm_compare import compare_dsm, difference_limit, difference_map
from riverbed_cli.products.evaluate import evaluate_disparity, evaluation_mask
from riverbed_cli.products.visualize import (ERROR_BINS, MISSING_COLOUR, PAD, PANEL_HEIGHT, PANEL_WIDTH,
                                             TITLE_HEIGHT, colorize_disparity, difference_picture,
                                             disparity_picture, error_map, error_map_picture, hillshade_picture,
                                             write_picture, write_png)

DATA = Path(__file__).parent / "data"
NAN = np.nan
KEYS = ["bad1", "bad2", "bad3", "avg", "rmse", "density", "d1", "n"]

# Errors |disp - gt| by pixel:   0.5  1.5  2.5  3.5  (none)
#                                4    6    (no gt)   0    0
GT = np.array([[10, 10, 10, 10, 10], [100, 100, NAN, 40, 5]], np.float32)
DISP = np.array([[10.5, 11.5, 12.5, 13.5, NAN], [104, 106, 7, 40, 5]], np.float32)


def _cli():
    # main.py imports match.py, which is being rewritten concurrently; import lazily so the library tests run.
    from riverbed_cli.cli.main import cli

    return cli


def test_metrics_by_hand():
    m = evaluate_disparity(DISP, GT)
    assert list(m) == KEYS
    # 9 GT pixels, 8 predicted. e > 1: 1.5 2.5 3.5 4 6 + the missing one = 6.
    assert m["bad1"] == pytest.approx(100 * 6 / 9)
    assert m["bad2"] == pytest.approx(100 * 5 / 9)
    assert m["bad3"] == pytest.approx(100 * 4 / 9)
    # The missing prediction is not in avg / rmse.
    assert m["avg"] == pytest.approx(18 / 8)
    assert m["rmse"] == pytest.approx(math.sqrt((0.25 + 2.25 + 6.25 + 12.25 + 16 + 36) / 8))
    assert m["density"] == pytest.approx(100 * 8 / 9)
    # D1: missing, 3.5 (> 0.5 = 5 % of 10), 6 (> 5 % of 100); 4 px on gt 100 is within 5 %.
    assert m["d1"] == pytest.approx(100 * 3 / 9)
    assert m["n"] == 9 and type(m["n"]) is int
    assert all(type(m[k]) is float for k in KEYS[:-1])


@pytest.mark.parametrize("as_mask", [False, True])
def test_exclusion(as_mask):
    sparse = np.full(GT.shape, NAN, np.float32)
    sparse[0, 4], sparse[1, 1] = 10.0, 100.0  # the missing prediction and the 6 px error are LiDAR pixels
    exclude = np.isfinite(sparse) if as_mask else sparse
    m = evaluate_disparity(DISP, GT, exclude=exclude)
    # Left: 0.5 1.5 2.5 3.5 4 0 0.
    assert m == pytest.approx({
        "bad1": 100 * 4 / 7, "bad2": 100 * 3 / 7, "bad3": 100 * 2 / 7, "avg": 12 / 7,
        "rmse": math.sqrt(37 / 7), "density": 100.0, "d1": 100 * 1 / 7, "n": 7,
    })


def test_max_disp():
    m = evaluate_disparity(DISP, GT, max_disp=50)
    # gt 100 left out. Left: 0.5 1.5 2.5 3.5 (none) 0 0.
    assert m == pytest.approx({
        "bad1": 100 * 4 / 7, "bad2": 100 * 3 / 7, "bad3": 100 * 2 / 7, "avg": 8 / 6,
        "rmse": math.sqrt(3.5), "density": 100 * 6 / 7, "d1": 100 * 2 / 7, "n": 7,
    })
    assert evaluation_mask(GT, max_disp=50).sum() == 7


def test_thresholds_are_strict_and_zero_gt_counts():
    gt = np.array([[0.0, 2.0, 3.0]])
    disp = np.array([[1.0, 4.0, 6.0]])  # errors exactly 1, 2, 3
    m = evaluate_disparity(disp, gt)
    assert m["bad1"] == pytest.approx(200 / 3) and m["bad2"] == pytest.approx(100 / 3)
    assert (m["bad3"], m["d1"]) == (0.0, 0.0)
    assert m["n"] == 3  # gt = 0 is a valid disparity


def test_no_prediction_at_all():
    m = evaluate_disparity(np.full((2, 2), NAN), np.ones((2, 2)))
    assert math.isnan(m["avg"]) and math.isnan(m["rmse"])
    assert (m["bad1"], m["bad3"], m["d1"], m["density"], m["n"]) == (100.0, 100.0, 100.0, 0.0, 4)


def test_errors():
    with pytest.raises(RiverbedError) as e:
        evaluate_disparity(np.zeros((2, 5)), np.zeros((2, 4)))
    assert str(e.value) == "disparity and ground truth differ in shape: 2x5 vs 2x4"
    with pytest.raises(RiverbedError) as e:
        evaluate_disparity(np.zeros((2, 2)), np.full((2, 2), NAN))
    assert str(e.value).startswith("no ground-truth pixels to evaluate")
    with pytest.raises(RiverbedError, match="exclusion map and ground truth differ in shape: 3x2 vs 2x2"):
        evaluate_disparity(np.zeros((2, 2)), np.zeros((2, 2)), exclude=np.zeros((3, 2)))


# --- pictures -------------------------------------------------------------------------------------

def test_error_map_colours():
    rgb = error_map(DISP, GT)
    assert rgb.dtype == np.uint8 and rgb.shape == (2, 5, 3)
    assert tuple(rgb[0, 0]) == (171, 217, 233)  # 0.5 px: (0.25, 0.5]
    assert tuple(rgb[0, 1]) == (254, 224, 144)  # 1.5 px: (1, 2]
    assert tuple(rgb[1, 1]) == (244, 109, 67)   # 6 px: (4, 8]
    assert tuple(rgb[1, 3]) == (49, 54, 149)    # exact
    assert tuple(rgb[0, 4]) == (255, 0, 255)    # GT but no prediction
    assert tuple(rgb[1, 2]) == (0, 0, 0)        # no GT
    masked = error_map(DISP, GT, mask=evaluation_mask(GT, max_disp=50))
    assert tuple(masked[1, 1]) == (0, 0, 0) and tuple(masked[0, 0]) == (171, 217, 233)


def test_colorize_disparity():
    d = np.array([[2.0, 4.0, NAN, 6.0, 100.0]])
    turbo = cv2.cvtColor(cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None], cv2.COLORMAP_TURBO),
                         cv2.COLOR_BGR2RGB)[0]
    rgb = colorize_disparity(d, vmin=2, vmax=6)
    assert rgb.dtype == np.uint8 and rgb.shape == (1, 5, 3)
    assert tuple(rgb[0, 0]) == tuple(turbo[0])
    assert tuple(rgb[0, 1]) == tuple(turbo[128])  # 0.5 * 255 = 127.5 rounds to 128
    assert tuple(rgb[0, 2]) == (0, 0, 0)
    assert tuple(rgb[0, 3]) == tuple(rgb[0, 4]) == tuple(turbo[255])  # clipped
    auto = colorize_disparity(d)  # default range: finite min .. max
    assert tuple(auto[0, 0]) == tuple(turbo[0]) and tuple(auto[0, 4]) == tuple(turbo[255])


def test_write_png(tmp_path):
    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[0, 0] = (255, 0, 0)
    p = tmp_path / "e.png"
    write_png(p, rgb)
    assert tuple(cv2.imread(str(p))[0, 0]) == (0, 0, 255)  # BGR on disk: red
    with pytest.raises(RiverbedError) as e:
        write_png(p, rgb)
    assert str(e.value) == f"{p}: output exists; pass --overwrite to replace it"
    with pytest.raises(RiverbedError, match="must be a .png file"):
        write_png(tmp_path / "e.jpg", rgb)


# --- pictures with a legend (what riverbed writes) ------------------------------------------------------------------

def _read_rgb(path):
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def _data(rgb, box):
    r, c, h, w = box
    return rgb[r:r + h, c:c + w]


def _panel_colours(picture):
    """The exact colours in the legend panel beside the map."""
    r, c, h, w = picture.box
    panel = picture.rgb[r:, c + w + PAD:c + w + PAD + PANEL_WIDTH]
    return {tuple(int(v) for v in px) for px in panel.reshape(-1, 3)}


def _dark_pixels(strip):
    return int((strip.min(axis=2) < 128).sum())


TURBO = cv2.cvtColor(cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None], cv2.COLORMAP_TURBO),
                     cv2.COLOR_BGR2RGB)[0]


def test_error_map_picture_has_a_legend():
    pic = error_map_picture(DISP, GT)
    assert pic.title == "disparity error |d - gt| (px), bad3 44.44 %, mean 2.25 px, n 9 px"
    # The map's pixels at 1:1, below the title strip, unchanged; white around them.
    assert pic.box == (TITLE_HEIGHT, PAD, 2, 5)
    np.testing.assert_array_equal(pic.data, error_map(DISP, GT))
    assert (pic.rgb[TITLE_HEIGHT + 2:, PAD:PAD + 5] == 255).all() and (pic.rgb[TITLE_HEIGHT:, :PAD] == 255).all()
    # Larger than the map by the title and the legend panel (a 2-row map gets the smallest panel).
    assert pic.rgb.dtype == np.uint8 and pic.rgb.shape[0] == TITLE_HEIGHT + PANEL_HEIGHT[0] + PAD
    assert pic.rgb.shape[1] >= PAD + 5 + PAD + PANEL_WIDTH
    # The colour bar shows every bin's colour; the swatches explain magenta and black; the title is drawn.
    assert {c for _, c in ERROR_BINS} | {MISSING_COLOUR, (0, 0, 0)} <= _panel_colours(pic)
    assert _dark_pixels(pic.rgb[:TITLE_HEIGHT]) > 100
    nothing = error_map_picture(np.full(GT.shape, NAN), GT)
    assert nothing.title == "disparity error |d - gt| (px), bad3 100.00 %, mean n/a px, n 9 px"


def test_error_map_picture_metrics_are_those_of_the_shown_pixels():
    mask = evaluation_mask(GT, max_disp=50)
    pic = error_map_picture(DISP, GT, mask)
    # bad3 2/7, mean 8/6 px over the 7 pixels shown (test_max_disp).
    assert pic.title == "disparity error |d - gt| (px), bad3 28.57 %, mean 1.33 px, n 7 px"
    np.testing.assert_array_equal(pic.data, error_map(DISP, GT, mask))
    given = error_map_picture(DISP, GT, mask, metrics=evaluate_disparity(DISP, GT, max_disp=50))
    assert given.title == pic.title
    np.testing.assert_array_equal(given.rgb, pic.rgb)
    # Another metric value draws another title strip; the legend panel stays the same.
    other = error_map_picture(DISP, GT)
    assert not np.array_equal(other.rgb[:TITLE_HEIGHT], pic.rgb[:TITLE_HEIGHT])
    panel = (slice(TITLE_HEIGHT, None), slice(PAD + 5 + PAD, PAD + 5 + PAD + PANEL_WIDTH))
    np.testing.assert_array_equal(other.rgb[panel], pic.rgb[panel])


def test_difference_picture_has_a_legend():
    ref = np.zeros((2, 3))
    dsm = np.array([[0.0, 1.0, NAN], [-1.0, 0.5, 2.0]])
    # dz 0 1 -1 0.5 2: median 0.5, NMAD 1.4826 * 0.5, RMSE sqrt(6.25 / 5), 5 of 6 reference cells covered.
    pic = difference_picture(dsm, ref)
    assert pic.title == ("DSM - reference dz (m), median +0.500 m, NMAD 0.741 m, RMSE 1.118 m, "
                         "completeness 83.3 %")
    assert difference_limit(dsm, ref) == pytest.approx(3 * 1.4826 * 0.5)
    np.testing.assert_array_equal(pic.data, difference_map(dsm, ref))
    assert tuple(pic.data[0, 0]) == (255, 255, 255) and tuple(pic.data[0, 2]) == (0, 0, 0)
    # The bar runs from blue (-limit) to red (+limit); the no-data swatch is black.
    assert {(0, 0, 255), (255, 0, 0), (0, 0, 0)} <= _panel_colours(pic)
    assert pic.rgb.shape[0] == TITLE_HEIGHT + PANEL_HEIGHT[0] + PAD
    # A given limit saturates the colours there; given metrics make the same title.
    one = difference_picture(dsm, ref, compare_dsm(dsm, ref, (0.5,), resolution=0.5), limit=1.0)
    assert one.title == pic.title
    np.testing.assert_array_equal(one.data, difference_map(dsm, ref, 1.0))
    assert tuple(one.data[1, 0]) == (0, 0, 255) and tuple(one.data[1, 2]) == (255, 0, 0)
    assert difference_limit(np.full((2, 2), NAN), np.zeros((2, 2))) == 0.1


def test_disparity_picture_has_a_legend():
    d = np.array([[2.0, 4.0, NAN, 6.0, 100.0]])
    pic = disparity_picture(d, vmin=2, vmax=6)
    assert pic.title == "disparity d = x_left - x_right (px), 80.0 % matched, 2.0 .. 6.0 px"
    np.testing.assert_array_equal(pic.data, colorize_disparity(d, vmin=2, vmax=6))
    # The bar (about 220 px for 256 Turbo levels) shows most of them, from both ends; the swatch is black.
    colours = _panel_colours(pic)
    shown = [k for k in range(256) if tuple(int(v) for v in TURBO[k]) in colours]
    assert len(shown) > 180 and shown[0] < 5 and shown[-1] > 250 and (0, 0, 0) in colours
    assert disparity_picture(d).title == "disparity d = x_left - x_right (px), 80.0 % matched, 2.0 .. 100.0 px"
    none = disparity_picture(np.full((3, 4), NAN))
    assert none.title == "disparity d = x_left - x_right (px), 0.0 % matched"
    assert (none.data == 0).all()


def test_hillshade_picture_flat_and_relief():
    flat = np.full((60, 80), 12.0)
    flat[0, 0] = NAN
    pic = hillshade_picture(hillshade(flat, 0.5), flat, 0.5)
    assert pic.title == "DSM hillshade (sun 315° az, 45° alt), height 12.00 .. 12.00 m, 0.5 m cells"
    assert pic.box == (TITLE_HEIGHT, PAD, 60, 80) and pic.rgb.shape[0] == TITLE_HEIGHT + PANEL_HEIGHT[0] + PAD
    # A flat DSM is shaded uniformly: 255 sin(45 deg) = 180 in all three channels; no data black.
    grey = pic.data.reshape(-1, 3)
    assert tuple(pic.data[0, 0]) == (0, 0, 0) and {tuple(v) for v in grey[1:]} == {(180, 180, 180)}
    roof = flat.copy()
    roof[20:40, 30:50] = 20.0
    relief = hillshade_picture(hillshade(roof, 0.5), roof, 0.5)
    assert relief.title == "DSM hillshade (sun 315° az, 45° alt), height 12.00 .. 20.00 m, 0.5 m cells"
    for k in range(3):
        np.testing.assert_array_equal(relief.data[..., k], hillshade(roof, 0.5))
    # The roof's edges are shaded apart from the flat roof and ground (which of them is lit is test_dsm's matter).
    assert relief.data[30, 40, 0] == relief.data[50, 10, 0] == 180
    north, south = relief.data[20, 40, 0], relief.data[39, 40, 0]
    assert north != 180 and south != 180 and north != south
    # The scale bar: 50 m = 100 cells of 0.5 m, drawn at the map's scale in the panel.
    r, c, h, w = relief.box
    panel = relief.rgb[r:, c + w + PAD:c + w + PAD + PANEL_WIDTH]
    assert 99 <= max(int((row == 0).all(axis=1).sum()) for row in panel[:40]) <= 101
    with pytest.raises(RiverbedError) as e:
        hillshade_picture(hillshade(roof, 0.5)[:5], roof, 0.5)
    assert str(e.value) == "hillshade must be uint8 HxW like the DSM, got uint8 5x80 for a 60x80 DSM"


def test_write_picture(tmp_path):
    pic = disparity_picture(np.array([[1.0, 2.0]]))
    p = tmp_path / "d.png"
    write_picture(p, pic)
    np.testing.assert_array_equal(_read_rgb(p), pic.rgb)
    with pytest.raises(RiverbedError) as e:
        write_picture(p, pic)
    assert str(e.value) == f"{p}: output exists; pass --overwrite to replace it"
    with pytest.raises(RiverbedError) as e:
        write_picture(tmp_path / "d.jpg", pic)
    assert str(e.value) == f"{tmp_path / 'd.jpg'}: image output must be a .png file, not '.jpg'"
    assert sorted(f.name for f in tmp_path.iterdir()) == ["d.png"]


# --- CLI ------------------------------------------------------------------------------------------

@pytest.fixture
def pair(tmp_path):
    write_disparity(tmp_path / "disp.pfm", DISP)
    write_disparity(tmp_path / "gt.tif", GT)
    return tmp_path


def test_cli_json(pair):
    r = CliRunner().invoke(_cli(), ["evaluate", str(pair / "disp.pfm"), str(pair / "gt.tif"), "--json"])
    assert r.exit_code == 0, r.output
    m = json.loads(r.stdout)
    assert list(m) == KEYS
    assert m["n"] == 9
    assert m["bad1"] == pytest.approx(100 * 6 / 9) and m["avg"] == pytest.approx(2.25)


def test_cli_json_nan_is_null(tmp_path):
    write_disparity(tmp_path / "d.tif", np.full((2, 2), NAN))
    write_disparity(tmp_path / "g.tif", np.ones((2, 2)))
    r = CliRunner().invoke(_cli(), ["evaluate", str(tmp_path / "d.tif"), str(tmp_path / "g.tif"), "--json"])
    assert r.exit_code == 0, r.output
    assert '"avg": null' in r.stdout
    assert json.loads(r.stdout)["rmse"] is None and json.loads(r.stdout)["density"] == 0.0


def test_cli_text_table_with_exclude_and_max_disp(pair):
    sparse = np.full(GT.shape, NAN, np.float32)
    sparse[0, 4] = 10.0
    write_disparity(pair / "lidar.tif", sparse)
    r = CliRunner().invoke(_cli(), ["evaluate", str(pair / "disp.pfm"), str(pair / "gt.tif"),
                                    "--exclude", str(pair / "lidar.tif"), "--max-disp", "50"])
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert [line.split()[0] for line in lines] == KEYS
    # Left: 0.5 1.5 2.5 3.5 0 0 -> bad1 3/6, avg 8/6.
    assert lines[0].split()[1:3] == ["50.000", "%"]
    assert lines[3].split()[1:3] == ["1.333", "px"]
    assert lines[5].split()[1:3] == ["100.000", "%"]
    assert lines[7].split()[1] == "6"


def test_cli_missing_file(pair):
    missing = pair / "nope.pfm"
    r = CliRunner().invoke(_cli(), ["evaluate", str(missing), str(pair / "gt.tif")])
    assert r.exit_code == 1
    assert r.stderr == f"riverbed: error: {missing}: file not found\n"


def test_cli_8bit_gt_needs_scale(pair):
    gt8 = str(DATA / "cones" / "disp2.png")
    r = CliRunner().invoke(_cli(), ["evaluate", gt8, gt8])
    assert r.exit_code == 1
    assert r.stderr == (
        f"riverbed: error: {gt8}: 8-bit PNG disparity: give its scale "
        "(e.g. --gt-scale 4 for Middlebury quarter size)\n"
    )


def test_cli_real_gt_against_itself():
    gt8 = str(DATA / "cones" / "disp2.png")
    r = CliRunner().invoke(_cli(), ["evaluate", gt8, gt8, "--gt-scale", "4", "--disp-scale", "4", "--json"])
    assert r.exit_code == 0, r.output
    m = json.loads(r.stdout)
    assert m == {"bad1": 0.0, "bad2": 0.0, "bad3": 0.0, "avg": 0.0, "rmse": 0.0, "density": 100.0, "d1": 0.0,
                 "n": 375 * 450 - 5429}


def test_cli_shape_mismatch(pair):
    write_disparity(pair / "small.tif", np.ones((2, 4)))
    r = CliRunner().invoke(_cli(), ["evaluate", str(pair / "small.tif"), str(pair / "gt.tif")])
    assert r.exit_code == 1
    assert r.stderr == (f"riverbed: error: {pair / 'gt.tif'}: ground truth is 2x5 but disparity "
                        f"{pair / 'small.tif'} is 2x4\n")


def test_cli_error_map_and_overwrite(pair):
    out = pair / "err.png"
    args = ["evaluate", str(pair / "disp.pfm"), str(pair / "gt.tif"), "--error-map", str(out)]
    r = CliRunner().invoke(_cli(), args)
    assert r.exit_code == 0, r.output
    rgb = _read_rgb(out)
    # The written picture: the error map at 1:1 below its title, the legend beside it.
    picture = error_map_picture(DISP, GT)
    np.testing.assert_array_equal(rgb, picture.rgb)
    assert picture.box == (TITLE_HEIGHT, PAD, 2, 5)
    np.testing.assert_array_equal(_data(rgb, picture.box), error_map(DISP, GT))
    assert tuple(_data(rgb, picture.box)[0, 4]) == (255, 0, 255)
    before = out.read_bytes()

    r = CliRunner().invoke(_cli(), args)
    assert r.exit_code == 1
    assert r.stderr == f"riverbed: error: {out}: output exists; pass --overwrite to replace it\n"
    assert r.stdout == ""  # refused before evaluating
    assert out.read_bytes() == before

    r = CliRunner().invoke(_cli(), args + ["--overwrite", "--max-disp", "50"])
    assert r.exit_code == 0, r.output
    rgb = _read_rgb(out)
    data = _data(rgb, (TITLE_HEIGHT, PAD, 2, 5))
    assert tuple(data[1, 1]) == (0, 0, 0)  # gt 100 > --max-disp: not drawn
    np.testing.assert_array_equal(data, error_map(DISP, GT, evaluation_mask(GT, max_disp=50)))
    # The title carries the metrics of the evaluated pixels (those of test_max_disp).
    np.testing.assert_array_equal(rgb, error_map_picture(DISP, GT, evaluation_mask(GT, max_disp=50)).rgb)
    assert not np.array_equal(rgb[:TITLE_HEIGHT], error_map_picture(DISP, GT).rgb[:TITLE_HEIGHT])


def test_cli_dsm_error_map_has_a_legend(tmp_path):
    from rasterio.transform import from_origin

    ref = np.zeros((40, 50), np.float32)
    dsm = np.full((40, 50), 0.25, np.float32)
    dsm[10:20, 10:30] = 3.0
    dsm[30:, :] = NAN
    for name, z in (("dsm.tif", dsm), ("ref.tif", ref)):
        write_geotiff(tmp_path / name, z, from_origin(500000.0, 5000020.0, 0.5, 0.5), "EPSG:32632", float("nan"))
    out = tmp_path / "dz.png"
    r = CliRunner().invoke(_cli(), ["evaluate", "--dsm", str(tmp_path / "dsm.tif"), str(tmp_path / "ref.tif"),
                                    "--error-map", str(out), "--json"])
    assert r.exit_code == 0, r.output
    m = json.loads(r.stdout)
    assert m["median"] == pytest.approx(0.25) and m["completeness"] == pytest.approx(75.0)
    picture = difference_picture(dsm, ref, m)
    # 1500 cells compared of 2000: 200 at 3 m, 1300 at 0.25 m; RMSE sqrt((200 * 9 + 1300 / 16) / 1500).
    assert picture.title == ("DSM - reference dz (m), median +0.250 m, NMAD 0.000 m, RMSE 1.120 m, "
                             "completeness 75.0 %")
    rgb = _read_rgb(out)
    np.testing.assert_array_equal(rgb, picture.rgb)
    np.testing.assert_array_equal(_data(rgb, (TITLE_HEIGHT, PAD, 40, 50)), difference_map(dsm, ref))
    # NMAD 0: the colours saturate at 0.1 m, so 0.25 and 3 m above the reference are both pure red.
    assert {tuple(v) for v in _data(rgb, picture.box)[:30].reshape(-1, 3)} == {(255, 0, 0)}
    assert rgb.shape[0] > 40 + TITLE_HEIGHT and rgb.shape[1] > 50 + PANEL_WIDTH


def _nadir_pair(f=1000.0, B=50.0, height=400.0, W=120, H=100):
    """A rectified nadir pair 400 m above ground (as in test_dsm): x right = east, image rows = south."""
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    R = np.diag([1.0, -1.0, -1.0])
    C = np.array([0.0, 0.0, height])
    return PairGeometry(K @ np.c_[R, -R @ C], K @ np.c_[R, -R @ (C + [B, 0, 0])],
                        origin=np.array([500000.0, 5000000.0, 0.0]), crs="EPSG:32632", width=W, height=H)


@pytest.mark.parametrize("roof", [False, True])
def test_cli_dsm_hillshade_picture(tmp_path, roof):
    """``riverbed dsm --hillshade``: the hillshade of the written DSM at 1:1, its height range in the title."""
    write_pairfile(tmp_path / "pair.yaml", _nadir_pair())
    disp = np.full((100, 120), 1000 * 50 / 400.0, np.float32)  # ground at 0 m
    if roof:
        disp[30:60, 40:80] = 1000 * 50 / 370.0  # a roof at 30 m
    write_disparity(tmp_path / "d.tif", disp)
    out = tmp_path / "hs.png"
    r = CliRunner().invoke(_cli(), ["dsm", str(tmp_path / "d.tif"), str(tmp_path / "pair.yaml"), "-o",
                                    str(tmp_path / "dsm.tif"), "--hillshade", str(out)])
    assert r.exit_code == 0, r.output
    z = read_disparity(tmp_path / "dsm.tif")  # the DSM band (float32, NaN no data)
    rgb = _read_rgb(out)
    picture = hillshade_picture(hillshade(z, 0.4), z, 0.4)
    top = "30.00" if roof else "0.00"
    assert picture.title == f"DSM hillshade (sun 315° az, 45° alt), height 0.00 .. {top} m, 0.4 m cells"
    np.testing.assert_array_equal(rgb, picture.rgb)
    assert picture.box == (TITLE_HEIGHT, PAD) + z.shape
    assert rgb.shape[0] == TITLE_HEIGHT + max(z.shape[0], PANEL_HEIGHT[0]) + PAD
    assert rgb.shape[1] >= PAD + z.shape[1] + PAD + PANEL_WIDTH
    data = _data(rgb, picture.box)[np.isfinite(z)]
    if roof:
        assert len({tuple(v) for v in data}) > 2  # the roof's edges shade apart from the flat parts
    else:
        assert {tuple(v) for v in data} == {(180, 180, 180)}  # flat: 255 sin(45 deg) everywhere
