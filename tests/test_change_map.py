"""The change map (products/change_map.py, ``riverbed dsm --change-map``): a LiDAR showing a building the images no
longer see is found where it stood, with its height; bad inputs are one line."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from test_dsm import nadir_pair
from test_lidar_check import constructed

from riverbed_cli.cli.main import cli
from riverbed_cli.geometry.pairfile import write_pairfile
from riverbed_cli.io.disparity import write_disparity

F, BASE, FLY = 100.0, 4.0, 40.0  # ground (z = 0) at d = F BASE / FLY = 10 px, the constructed pair's disparity


def height(d):
    return FLY - F * BASE / d


@pytest.fixture
def stale_building(tmp_path):
    """The constructed pair (flat ground at 10 px) with LiDAR that still shows a building (+8 px) torn down since,
    matched by ``riverbed match --lidar-mask``; the pair file of a nadir pair that puts that ground at z = 0."""
    left, right, sparse, _ = constructed(d=10.0)
    region = np.zeros(sparse.shape, bool)
    region[40:110, 70:170] = True
    cv2.imwrite(str(tmp_path / "l.png"), left)
    cv2.imwrite(str(tmp_path / "r.png"), right)
    write_disparity(tmp_path / "s.tif", np.where(region, sparse + 8, sparse))
    write_pairfile(tmp_path / "pair.yaml", nadir_pair(f=F, B=BASE, H=FLY, W=240, Hh=160))
    r = CliRunner().invoke(cli, ["match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "--sparse",
                                 str(tmp_path / "s.tif"), "-o", str(tmp_path / "d.tif"), "--lidar-mask",
                                 str(tmp_path / "m.png")])
    assert r.exit_code == 0, r.output
    return tmp_path, region


def test_the_torn_down_building_is_found_with_its_height(stale_building):
    tmp, region = stale_building
    args = ["dsm", str(tmp / "d.tif"), str(tmp / "pair.yaml"), "-o", str(tmp / "dsm.tif"), "--change-map",
            str(tmp / "change.tif"), "--sparse", str(tmp / "s.tif"), "--lidar-mask", str(tmp / "m.png"), "--json"]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)["change_map"]
    want = height(10.0) - height(18.0)  # the ground now minus the LiDAR's roof: -17.8 m
    assert s["median"] == pytest.approx(want, abs=1.0) and s["points"] >= 0.95 * (70 * 100 / 16)
    with rasterio.open(tmp / "change.tif") as ds, rasterio.open(tmp / "dsm.tif") as dsm:
        change = ds.read(1)
        assert ds.transform == dsm.transform and ds.shape == dsm.shape and ds.crs == dsm.crs
        assert ds.descriptions == ("height change (m), match minus LiDAR",)
        rows, cols = np.nonzero(np.isfinite(change))
        xs, ys = rasterio.transform.xy(ds.transform, rows, cols)
    assert np.allclose(change[rows, cols], want, atol=1.0)
    # every changed cell lies over the building's footprint (x 70..170 px, y 40..110 px; 0.4 m a pixel)
    pair_x = (np.asarray(xs) - 500000.0) / (FLY / F) + 120
    pair_y = -(np.asarray(ys) - 5000000.0) / (FLY / F) + 80
    assert pair_x.min() >= 69 and pair_x.max() <= 171 and pair_y.min() >= 39 and pair_y.max() <= 111


def test_bad_change_map_inputs_are_one_line(stale_building, tmp_path):
    tmp, _ = stale_building
    base = ["dsm", str(tmp / "d.tif"), str(tmp / "pair.yaml"), "-o", str(tmp_path / "x.tif")]
    cases = [
        (["--change-map", str(tmp_path / "c.png"), "--sparse", str(tmp / "s.tif"), "--lidar-mask", str(tmp / "m.png")],
         "the change map must be a .tif file"),
        (["--change-map", str(tmp_path / "c.tif"), "--sparse", str(tmp / "s.tif")],
         "--change-map needs one --sparse and one --lidar-mask per DISP PAIR couple (1 couples, 1 --sparse, "
         "0 --lidar-mask)"),
        (["--sparse", str(tmp / "s.tif"), "--lidar-mask", str(tmp / "m.png")],
         "--sparse and --lidar-mask are read for --change-map FILE.tif; give it"),
        (["--change-map", str(tmp_path / "c.tif"), "--sparse", str(tmp / "s.tif"), "--lidar-mask", str(tmp / "l.png")],
         "l.png: not a LiDAR mask: values up to"),
    ]
    for extra, message in cases:
        r = CliRunner().invoke(cli, [*base, *extra])
        # a clean exit (SystemExit 1), not an exception the runner caught (which would be a traceback for a user)
        assert r.exit_code == 1 and message in r.output and isinstance(r.exception, SystemExit), r.output
        assert r.output.count("\n") == 1
        assert not (tmp_path / "x.tif").exists() and not (tmp_path / "c.tif").exists()


def test_a_block_writes_each_pairs_change_map_and_merges_them(tmp_path):
    # the sample block's pair with its earlier LiDAR (sample_data/block/scene.json: a 7.42 m building built since),
    # twice (the merge takes both): each pair's change.tif finds the building, its stats say how much (measured: 134
    # cells, median +6.19 m), and the block's change.tif merges them onto the merged DSM's grid
    import yaml

    sample = Path(__file__).resolve().parents[1] / "sample_data" / "block"
    truth = json.loads((sample / "scene.json").read_text())["lidar_earlier"]["removed_building"]
    entry = {"pair": str(sample / "pair.yaml"), "cloud": str(sample / "lidar_earlier.laz")}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump({"pairs": [{**entry, "name": "a"}, {**entry, "name": "b"}]}))
    r = CliRunner().invoke(cli, ["block", str(tmp_path / "m.yaml"), "-o", str(tmp_path / "out"), "--workers", "0",
                                 "--json"])
    assert r.exit_code == 0, r.output
    merged = json.loads(r.stdout)["merged"]
    x0, y0, x1, y1 = truth["bounds"]
    for name in ("pairs/a/change.tif", "pairs/b/change.tif", "change.tif"):
        with rasterio.open(tmp_path / "out" / name) as ds:
            change = ds.read(1)
            rows, cols = np.nonzero(np.isfinite(change))
            xs, ys = (np.asarray(a) for a in rasterio.transform.xy(ds.transform, rows, cols))
        assert 120 <= len(rows) <= 150 and 5.5 <= float(np.median(change[rows, cols])) <= 7.0, name
        assert ((xs >= x0 - 1) & (xs <= x1 + 1) & (ys >= y0 - 1) & (ys <= y1 + 1)).mean() >= 0.95, name
    with rasterio.open(tmp_path / "out" / "change.tif") as ds, rasterio.open(tmp_path / "out" / "dsm.tif") as dsm:
        assert ds.transform == dsm.transform and ds.shape == dsm.shape
    assert merged["change_map"]["pairs"] == 2 and 120 <= merged["change_map"]["cells"] <= 150
    done = json.loads((tmp_path / "out" / "pairs" / "a" / "done.json").read_text())["stats"]
    assert done["lidar_check"]["regions"] == 1 and 120 <= done["change_map"]["cells"] <= 150
