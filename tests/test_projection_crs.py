"""A cloud's CRS against the pair's: a compound CRS (horizontal + heights) is compared by its parts."""

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
import yaml
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.geometry.projection import crs_name
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.pointcloud import write_points

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
    # another vertical datum is converted by PROJ, which needs EGM2008's grid here (not installed: one line)
    assert out == (f"riverbed: error: {dem}: heights are EGM2008 height (the pair's: EGM96 height) and PROJ's grid "
                   "us_nga_egm08_25.tif is not available offline (install Debian's proj-data, or point PROJ_DATA at "
                   "a folder with it)\n")
    assert not (tmp_path / "s.tif").exists()


def _egm96_pair(tmp_path):
    pair = yaml.safe_load((BLOCK / "pair.yaml").read_text())
    pair["crs"] = "EPSG:32632+5773"  # heights above EGM96
    for side in ("left", "right"):
        pair[side] = str(BLOCK / pair[side])
    (tmp_path / "egm96_pair.yaml").write_text(yaml.safe_dump(pair))
    return tmp_path / "egm96_pair.yaml"


def _ellipsoidal_cloud(tmp_path):
    """The sample LiDAR's heights taken as EGM96 and written as WGS 84 ellipsoidal heights (+N, the geoid's
    undulation there: 41.5 m) in a 3-D UTM 32N CRS."""
    import laspy
    from pyproj import CRS, Transformer

    las = laspy.read(BLOCK / "lidar.laz")
    x, y, z = (np.asarray(v, np.float64) for v in (las.x, las.y, las.z))
    to_ell = Transformer.from_crs("EPSG:32632+5773", CRS("EPSG:32632").to_3d(), always_xy=True)
    h = to_ell.transform(x, y, z)[2]
    write_points(tmp_path / "ell.laz", np.c_[x, y, h], crs=CRS("EPSG:32632").to_3d(),
                 classification=np.asarray(las.classification))
    return tmp_path / "ell.laz", float(np.median(h - z))


def test_heights_on_another_datum_are_converted(tmp_path, egm96):
    """A pair on EGM96 heights, a cloud with ellipsoidal heights: PROJ converts them, and the cloud projects as the
    same cloud given on EGM96 heights does (the DSM would otherwise sit 41.5 m off)."""
    pair = _egm96_pair(tmp_path)
    cloud, undulation = _ellipsoidal_cloud(tmp_path)
    assert undulation == pytest.approx(41.5, abs=0.1)
    code, out = project(tmp_path, cloud, pair, out="ell.tif")
    assert code == 0, out
    assert json.loads(out)["heights_converted"] == {"from": "ellipsoidal", "to": "EGM96 height"}
    code, out = project(tmp_path, BLOCK / "lidar.laz", pair, out="egm.tif")
    assert code == 0, out
    assert "heights_converted" not in json.loads(out)
    a, b = (read_disparity(tmp_path / n) for n in ("ell.tif", "egm.tif"))
    both = np.isfinite(a) & np.isfinite(b)
    assert both.sum() > 0.999 * max(np.isfinite(a).sum(), np.isfinite(b).sum())
    assert np.abs(a[both] - b[both]).max() < 1e-3
    # unconverted (a pair that states no datum takes the heights as they are), the points land 35 px off
    code, out = project(tmp_path, cloud, out="plain.tif")
    assert code == 0, out
    c = read_disparity(tmp_path / "plain.tif")
    both = np.isfinite(c) & np.isfinite(b)
    assert np.median(np.abs(c[both] - b[both])) == pytest.approx(35.0, abs=0.5)


def test_a_missing_geoid_grid_is_one_line(tmp_path, no_egm96_grid):
    cloud, _ = _ellipsoidal_cloud(tmp_path)
    code, out = project(tmp_path, cloud, _egm96_pair(tmp_path))
    assert (code, out) == (1, f"riverbed: error: {cloud}: heights are ellipsoidal (the pair's: EGM96 height) and "
                              "PROJ's grid us_nga_egm96_15.tif is not available offline (install Debian's proj-data, "
                              "or point PROJ_DATA at a folder with it)\n")
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


def test_a_vertical_datum_stated_in_the_orientations_reaches_the_dsm(tmp_path):
    """Orientation files on UTM 32N + EGM96 heights: rectify keeps the compound CRS in pair.yaml, and the DSM
    GeoTIFF carries it (and --json names it)."""
    raw = BLOCK / "raw"
    for k in (0, 1):
        doc = yaml.safe_load((raw / f"frame{k}.yaml").read_text())
        doc["crs"] = "EPSG:32632+5773"
        (tmp_path / f"frame{k}.yaml").write_text(yaml.safe_dump(doc))
    run = CliRunner().invoke
    r = run(cli, ["rectify", str(raw / "frame0.png"), str(tmp_path / "frame0.yaml"), str(raw / "frame1.png"),
                  str(tmp_path / "frame1.yaml"), "-o", str(tmp_path / "rect")])
    assert r.exit_code == 0, r.output
    assert yaml.safe_load((tmp_path / "rect" / "pair.yaml").read_text())["crs"] == "EPSG:32632+5773"
    rect = tmp_path / "rect"
    r = run(cli, ["match", str(rect / "left.png"), str(rect / "right.png"), "--pair", str(rect / "pair.yaml"),
                  "-o", str(tmp_path / "d.tif")])
    assert r.exit_code == 0, r.output
    r = run(cli, ["dsm", str(tmp_path / "d.tif"), str(rect / "pair.yaml"), "-o", str(tmp_path / "dsm.tif"), "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["crs"] == "EPSG:32632+5773"
    with rasterio.open(tmp_path / "dsm.tif") as ds:
        from pyproj import CRS

        crs = CRS.from_wkt(ds.crs.to_wkt())
    assert crs.is_compound and crs.name == "WGS 84 / UTM zone 32N + EGM96 height"
