"""DSM stage on real data from the shared folder (RIVERBED_DATA)."""

import json

import laspy
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from riverbed_cli.cli.main import cli

IGN = "lidar_ign_lidarhd_nimes/data/subsampled_nimes.laz"
SRTM = "dsm_srtm_demcompare/data_samples"


def test_ign_lidar_alone_equals_plain_cell_maximum(shared_data, tmp_path):
    out = tmp_path / "ign.tif"
    r = CliRunner().invoke(cli, ["-q", "dsm", "--lidar", str(shared_data / IGN), "--crs", "EPSG:2154",
                                 "--resolution", "1", "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    las = laspy.read(shared_data / IGN)
    keep = ~np.isin(np.asarray(las.classification), (7, 18))
    x, y, z = np.asarray(las.x)[keep], np.asarray(las.y)[keep], np.asarray(las.z)[keep]
    assert s["lidar_points"] == keep.sum()
    with rasterio.open(out) as ds:
        assert ds.crs.to_epsg() == 2154 and ds.res == (1.0, 1.0)
        dsm = ds.read(1)
        # The plain per-cell maximum, written out with numpy on the same grid.
        rows, cols = rasterio.transform.rowcol(ds.transform, x, y, op=np.floor)
    ref = np.full(dsm.shape, -np.inf)
    np.maximum.at(ref, (np.asarray(rows, int), np.asarray(cols, int)), z)
    ref[np.isinf(ref)] = np.nan
    np.testing.assert_array_equal(np.isnan(dsm), np.isnan(ref))
    assert np.nanmax(np.abs(dsm - ref)) < 1e-3  # float32 storage of heights of ~50-100 m


def test_evaluate_dsm_on_different_grids(shared_data):
    ref = shared_data / SRTM / "srtm_ref.tif"
    other = shared_data / SRTM / "srtm_blurred_and_shifted.tif"
    r = CliRunner().invoke(cli, ["evaluate", "--dsm", str(ref), str(ref), "--json"])
    same = json.loads(r.output)
    assert same["rmse"] == 0.0 and same["completeness"] == 100.0 and same["n"] > 990000
    r = CliRunner().invoke(cli, ["evaluate", "--dsm", str(other), str(ref), "--json"])
    assert r.exit_code == 0, r.output
    m = json.loads(r.output)
    # the second grid is shifted and smaller: reprojected onto the reference, it misses a border strip
    assert 98.0 < m["completeness"] < 100.0 and m["rmse"] > 10
    assert "over_3res" not in m  # a geographic grid has no metric cell size


@pytest.mark.parametrize("bad", ["missing.tif"])
def test_evaluate_dsm_errors(tmp_path, shared_data, bad):
    r = CliRunner().invoke(cli, ["evaluate", "--dsm", str(tmp_path / bad), str(shared_data / SRTM / "srtm_ref.tif")])
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {tmp_path / bad}: file not found\n")
