"""A DSM raster as a point cloud: ``riverbed project DSM.tif PAIR`` and ranges for ``match --range-map`` from it.

On the bundled sample block (sample_data/block, synthetic, made by this project): its ground-truth DSM projects onto
its ground-truth disparity, and a coarse DSM (16 x 16 cell means, 3.2 m) bounds an unguided match better than the
full range (docs/tubes.md, "Range maps from a coarse DSM").
"""

import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import Affine

from riverbed_cli.cli.main import cli
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.lidar import lidar_info, read_lidar
from riverbed_cli.io.windowed import read_range_map
from riverbed_cli.products.evaluate import evaluate_disparity

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_dsm_ranges import BLOCK, coarse_dsm  # noqa: E402  (the sample block's GT DSM averaged over k x k cells)


def run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    return r.exit_code, r.output


def write_raster(path, bands, transform=None, crs="EPSG:32632", nodata=None):
    bands = np.atleast_3d(bands).transpose(2, 0, 1) if bands.ndim == 2 else bands
    profile = dict(driver="GTiff", width=bands.shape[2], height=bands.shape[1], count=bands.shape[0],
                   dtype="float32", nodata=nodata)
    if transform is not None:
        profile.update(transform=transform, crs=crs)
    with warnings.catch_warnings():  # the raster without a geotransform is written on purpose
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", **profile) as ds:
            ds.write(bands.astype(np.float32))


def test_dsm_cells_read_as_points(tmp_path):
    # a rotated grid: each valid cell's centre through the whole affine transform, its height as z; nodata and NaN
    # cells are no points
    t = Affine(2.0, 0.5, 1000.0, 0.25, -2.0, 5000.0)
    z = np.array([[10.0, -9999.0, 12.0], [np.nan, 14.0, 15.0]])
    write_raster(tmp_path / "d.tif", z, t, nodata=-9999.0)
    pts = read_lidar(tmp_path / "d.tif")
    want = [(t * (c + 0.5, r + 0.5)) + (z[r, c],) for r, c in [(0, 0), (0, 2), (1, 1), (1, 2)]]
    np.testing.assert_allclose(pts["xyz"], np.array(want), rtol=0, atol=1e-9)
    assert pts["classification"].tolist() == [0, 0, 0, 0] and pts["rgb"] is None
    info = lidar_info(tmp_path / "d.tif")
    assert info.point_count == 4 and info.crs.to_epsg() == 32632 and info.version == "dsm"
    np.testing.assert_allclose(info.maxs, np.array(want).max(axis=0))


def test_the_ground_truth_dsm_projects_onto_the_ground_truth_disparity(tmp_path):
    code, out = run("project", BLOCK / "gt_dsm.tif", BLOCK / "pair.yaml", "-o", tmp_path / "s.tif", "--json")
    assert code == 0, out
    s = json.loads(out)
    assert s["points_read"] == 389880 and s["kept"] > 300000
    gt, sparse = read_disparity(BLOCK / "gt_disparity.tif"), read_disparity(tmp_path / "s.tif")
    both = np.isfinite(gt) & np.isfinite(sparse)
    err = np.abs(gt - sparse)[both]
    # the figures docs/projection.md states (deterministic): 321 843 pixels, median 0.0034 px; 0.17 % off by more
    # than 1 px (the DSM's 0.2 m cells at edges)
    assert both.sum() == 321843 and np.median(err) == pytest.approx(0.0034, abs=5e-5)
    assert (err > 1).mean() == pytest.approx(0.0017, abs=5e-5)


@pytest.fixture(scope="module")
def coarse_dsm_ranges(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("coarse_dsm")
    coarse_dsm(tmp / "coarse.tif", 16)  # 0.2 m cells -> 3.2 m: one point per ~17 x 17 px of the left image
    code, out = run("project", tmp / "coarse.tif", BLOCK / "pair.yaml", "-o", tmp / "s.tif", "--json")
    assert code == 0, out
    code, out = run("range-map", tmp / "s.tif", "--window", "auto", "--margin", "2", "-o", tmp / "ranges.tif",
                    "--json")
    assert code == 0, out
    return tmp, json.loads(out)


def test_window_auto_is_the_points_spacing(coarse_dsm_ranges):
    tmp, s = coarse_dsm_ranges
    sparse = read_disparity(tmp / "s.tif")
    assert s["window"] == math.ceil(math.sqrt(sparse.size / np.isfinite(sparse).sum())) == 18
    assert s["known_share"] > 0.99 and s["mean_width"] < 10  # against 64 disparities of the full range below


def test_coarse_dsm_ranges_beat_the_full_range(coarse_dsm_ranges):
    tmp, _ = coarse_dsm_ranges
    gt = read_disparity(BLOCK / "gt_disparity.tif")
    lo, hi = read_range_map(tmp / "ranges.tif")
    known = np.isfinite(gt)
    assert ((gt >= lo) & (gt <= hi))[known].mean() > 0.93  # measured 0.942
    left, right = BLOCK / "left.png", BLOCK / "right.png"
    errors = {}
    for name, extra in (("full", []), ("map", ["--range-map", tmp / "ranges.tif"])):
        code, out = run("match", left, right, "--guide", "none", "--min-disp", 0, "--max-disp", 63, *extra,
                        "-o", tmp / f"{name}.tif")
        assert code == 0, out
        errors[name] = evaluate_disparity(read_disparity(tmp / f"{name}.tif"), gt)
    # measured: full range bad3 7.59 % / avg 0.857 px (98.6 % dense: the left edge, where a match may lie outside
    # the right image, is invalid), in the coarse DSM's ranges 4.25 % / 0.685 px
    assert errors["map"]["bad3"] < 0.7 * errors["full"]["bad3"]
    assert errors["map"]["avg"] < 0.85 * errors["full"]["avg"]


def test_bad_dsms_one_line_errors_and_no_output(tmp_path):
    t = Affine(1.0, 0.0, 0.0, 0.0, -1.0, 10.0)
    write_raster(tmp_path / "rgb.tif", np.ones((3, 4, 4)), t)
    write_raster(tmp_path / "plain.tif", np.ones((4, 4)))
    write_raster(tmp_path / "empty.tif", np.full((4, 4), -9999.0), t, nodata=-9999.0)
    cases = {"rgb.tif": "a DSM must have one band (heights), this raster has 3",
             "plain.tif": "the raster has no geotransform: not a DSM",
             "empty.tif": "the DSM has no valid cell (all nodata or NaN)"}
    for name, message in cases.items():
        out = tmp_path / f"out_{name}"
        code, text = run("project", tmp_path / name, BLOCK / "pair.yaml", "-o", out)
        assert code == 1
        assert text.strip().splitlines() == [f"riverbed: error: {tmp_path / name}: {message}"]
        assert not out.exists()
    code, text = run("range-map", tmp_path / "rgb.tif", "--window", "300", "-o", tmp_path / "r.tif")
    assert code == 1 and text.strip() == "riverbed: error: --window: expected 0 to 256, got 300"
