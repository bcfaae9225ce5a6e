"""Metrics against hand-computed answers, the visualisations, and the ``riverbed evaluate`` command."""

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.errors import RiverbedError
from riverbed_cli.io.disparity import write_disparity
from riverbed_cli.products.evaluate import evaluate_disparity, evaluation_mask
from riverbed_cli.products.visualize import colorize_disparity, error_map, write_png

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
    assert "Traceback" not in r.output


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
    rgb = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(rgb, error_map(DISP, GT))
    assert tuple(rgb[0, 4]) == (255, 0, 255)
    before = out.read_bytes()

    r = CliRunner().invoke(_cli(), args)
    assert r.exit_code == 1
    assert r.stderr == f"riverbed: error: {out}: output exists; pass --overwrite to replace it\n"
    assert r.stdout == ""  # refused before evaluating
    assert out.read_bytes() == before

    r = CliRunner().invoke(_cli(), args + ["--overwrite", "--max-disp", "50"])
    assert r.exit_code == 0, r.output
    rgb = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    assert tuple(rgb[1, 1]) == (0, 0, 0)  # gt 100 > --max-disp: not drawn
