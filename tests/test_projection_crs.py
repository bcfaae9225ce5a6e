"""A cloud's CRS against the pair's: a compound CRS (horizontal + heights) is compared by its parts."""

import json
from pathlib import Path

import pytest
import rasterio
import yaml
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.geometry.projection import crs_name

BLOCK = Path(__file__).resolve().parents[1] / "sample_data" / "block"


def dem_with_crs(tmp_path, crs, name="dem.tif"):
    """The sample block's ground-truth DSM written again with another CRS label (same numbers)."""
    with rasterio.open(BLOCK / "gt_dsm.tif") as src:
        data, profile = src.read(1), src.profile
    profile.update(crs=crs)
    path = tmp_path / name
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data, 1)
    return path


def project(tmp_path, cloud, pair=BLOCK / "pair.yaml", out="s.tif"):
    r = CliRunner().invoke(cli, ["project", str(cloud), str(pair), "-o", str(tmp_path / out), "--json"])
    return r.exit_code, r.output


def test_a_compound_crs_with_the_pairs_horizontal_part_is_accepted(tmp_path):
    code, out = project(tmp_path, dem_with_crs(tmp_path, "EPSG:32632+3855"))
    assert code == 0, out
    s = json.loads(out)
    assert s["crs"] == "WGS 84 / UTM zone 32N + EGM2008 height" and s["kept"] > 10_000
    # the same points as the plain EPSG:32632 DEM
    code, out = project(tmp_path, dem_with_crs(tmp_path, "EPSG:32632", "plain.tif"), out="p.tif")
    assert code == 0 and json.loads(out)["kept"] == s["kept"]


def test_another_horizontal_crs_or_height_datum_is_one_line(tmp_path):
    dem = dem_with_crs(tmp_path, "EPSG:32633+3855")
    code, out = project(tmp_path, dem)
    assert code == 1
    assert out == (f"riverbed: error: {dem}: the cloud's CRS ('WGS 84 / UTM zone 33N + EGM2008 height') differs from "
                   "the pair's (EPSG:32632); reproject the cloud, or pass --crs if the file states a wrong one\n")
    pair = yaml.safe_load((BLOCK / "pair.yaml").read_text())
    pair["crs"] = "EPSG:32632+5773"  # heights above EGM96
    for side in ("left", "right"):
        pair[side] = str(BLOCK / pair[side])
    (tmp_path / "pair.yaml").write_text(yaml.safe_dump(pair))
    dem = dem_with_crs(tmp_path, "EPSG:32632+3855", "egm2008.tif")
    code, out = project(tmp_path, dem, tmp_path / "pair.yaml")
    assert code == 1
    assert out == (f"riverbed: error: {dem}: the cloud's heights (EGM2008 height) are on another vertical datum than "
                   "the pair's (EGM96 height); convert the cloud's heights first\n")
    assert not (tmp_path / "s.tif").exists()


@pytest.mark.parametrize("given, name", [
    (None, None), ("EPSG:2154", "EPSG:2154"),
    ("EPSG:32632+3855", "EPSG:32632+3855"),  # short strings as given
    (rasterio.crs.CRS.from_string("EPSG:32632+3855").to_wkt(), "WGS 84 / UTM zone 32N + EGM2008 height"),
    (rasterio.crs.CRS.from_epsg(32632).to_wkt(), "EPSG:32632"),
    ("+proj=tmerc +lat_0=0 +lon_0=25 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs",
     "+proj=tmerc +lat_0=0 +lon_0=25 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs")])
def test_json_names_the_crs(given, name):
    assert crs_name(given) == name
