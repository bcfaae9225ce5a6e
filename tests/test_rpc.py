"""RPC models: every format read (through GDAL, shareloc, json), projection, localisation, DEMs (docs/rpc.md)."""

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import RPCTransformer

from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.rpc import RPCModel, read_rpc
from riverbed_cli.geometry.rpc_dem import DEM, geoid_to_ellipsoid_transformer, read_dem

RPC_DIR = Path(__file__).parent / "data" / "rpc"
LEFT_GEOM = RPC_DIR / "left_image.geom"
DIMAP = RPC_DIR / "RPC_PHR1B_P_201308051042194_SEN_690908101-001.XML"
RPCM_FILES = "rpc_rpcm_testfiles/tests/test_rpc_files"
VENTOUX = "satellite_pleiades_ventoux_shareloc/tests/data"


def centre_projection(m):
    """project(offsets) written out from the model's numbers: at L = P = H = 0 only the constant terms remain."""
    return (m.samp_off + m.samp_scale * m.samp_num_coeff[0] / m.samp_den_coeff[0],
            m.line_off + m.line_scale * m.line_num_coeff[0] / m.line_den_coeff[0])


def check_model(m):
    col, row = m.project(m.long_off, m.lat_off, m.height_off)
    c0, r0 = centre_projection(m)
    assert abs(col - c0) < 1e-9 and abs(row - r0) < 1e-9
    # round trip over 90 % of the model's image domain and +-half its height range
    u = np.random.default_rng(0).uniform(-0.9, 0.9, (3, 2000))
    cols, rows = m.samp_off + m.samp_scale * u[0], m.line_off + m.line_scale * u[1]
    h = m.height_off + 0.5 * m.height_scale * u[2]
    lon, lat = m.localize(cols, rows, h)
    c2, r2 = m.project(lon, lat, h)
    assert np.isfinite(lon).all()
    assert np.max(np.hypot(c2 - cols, r2 - rows)) < 1e-6


def test_ossim_geom_read_through_shareloc_and_same_model_as_the_dimap_file():
    geom, dimap = read_rpc(LEFT_GEOM), read_rpc(DIMAP)
    assert geom.format == "ossim-geom-shareloc" and dimap.format == "dimap-gdal"
    # the .geom file says samp_off 19207.5 / line_off 21109.5; DIMAP v2 says 19208.5 / 21110.49999999999 (1-based)
    assert geom.samp_off == 19207.5 and geom.line_off == 21109.5
    assert dimap.samp_off == pytest.approx(19207.5, abs=1e-9) and dimap.line_off == pytest.approx(21109.5, abs=1e-9)
    for key in ("lat_off", "long_off", "height_off", "samp_scale", "line_scale"):
        assert getattr(geom, key) == pytest.approx(getattr(dimap, key), rel=1e-12)
    for key in ("line_num_coeff", "line_den_coeff", "samp_num_coeff", "samp_den_coeff"):
        np.testing.assert_allclose(getattr(geom, key), getattr(dimap, key), rtol=0, atol=1e-14)
    check_model(geom)
    check_model(dimap)


def test_projection_agrees_with_shareloc_and_gdal_up_to_their_pixel_conventions():
    from shareloc.geomodels import GeoModel

    m = read_rpc(LEFT_GEOM)
    rng = np.random.default_rng(1)
    lon = m.long_off + m.long_scale * rng.uniform(-0.8, 0.8, 200)
    lat = m.lat_off + m.lat_scale * rng.uniform(-0.8, 0.8, 200)
    h = m.height_off + rng.uniform(-300, 300, 200)
    col, row = m.project(lon, lat, h)
    # shareloc's default topleftconvention puts (0, 0) at the first pixel's corner: +0.5 px
    row_s, col_s, _ = GeoModel(str(LEFT_GEOM)).inverse_loc(lon, lat, h)
    assert np.max(np.abs(col_s - (col + 0.5))) < 1e-8 and np.max(np.abs(row_s - (row + 0.5))) < 1e-8
    # GDAL's RPC transformer works in raster space (corner at 0): +0.5 px as well
    with RPCTransformer(m.to_gdal()) as tr:
        row_g, col_g = tr.rowcol(lon, lat, zs=h, op=lambda x: x)
    assert np.max(np.abs(np.asarray(col_g) - (col + 0.5))) < 1e-6
    assert np.max(np.abs(np.asarray(row_g) - (row + 0.5))) < 1e-6


def _write_rpc00b_text(path, m):
    lines = [f"{k.upper()}: {getattr(m, k)!r}" for k in ("line_off", "samp_off", "lat_off", "long_off",
                                                         "height_off", "line_scale", "samp_scale", "lat_scale",
                                                         "long_scale", "height_scale")]
    for key in ("line_num_coeff", "line_den_coeff", "samp_num_coeff", "samp_den_coeff"):
        lines += [f"{key.upper()}_{i + 1}: {c!r}" for i, c in enumerate(getattr(m, key))]
    path.write_text("\n".join(lines) + "\n")


def _write_rpb(path, m):
    names = {"line_off": "lineOffset", "samp_off": "sampOffset", "lat_off": "latOffset", "long_off": "longOffset",
             "height_off": "heightOffset", "line_scale": "lineScale", "samp_scale": "sampScale",
             "lat_scale": "latScale", "long_scale": "longScale", "height_scale": "heightScale"}
    out = ['satId = "TEST";', 'bandId = "P";', 'SpecId = "RPC00B";', "BEGIN_GROUP = IMAGE", "\terrBias = 1.0;",
           "\terrRand = 0.1;"]
    out += [f"\t{v} = {getattr(m, k)!r};" for k, v in names.items()]
    for key, name in (("line_num_coeff", "lineNumCoef"), ("line_den_coeff", "lineDenCoef"),
                      ("samp_num_coeff", "sampNumCoef"), ("samp_den_coeff", "sampDenCoef")):
        out.append(f"\t{name} = (\n" + ",\n".join(f"\t\t\t{c!r}" for c in getattr(m, key)) + ");")
    out += ["END_GROUP = IMAGE", "END;"]
    path.write_text("\n".join(out) + "\n")


@pytest.mark.parametrize("fmt", ["rpc-txt-gdal", "rpb-gdal", "gdal-image", "rpcm-json", "json"])
def test_every_written_format_reads_back_the_same_model(tmp_path, fmt):
    m = read_rpc(LEFT_GEOM)
    if fmt == "rpc-txt-gdal":
        path = tmp_path / "some_RPC.TXT"
        _write_rpc00b_text(path, m)
    elif fmt == "rpb-gdal":
        path = tmp_path / "image.RPB"
        _write_rpb(path, m)
    elif fmt == "gdal-image":
        path = tmp_path / "image.tif"
        with rasterio.open(path, "w", driver="GTiff", width=4, height=3, count=1, dtype="uint8",
                           rpcs=m.to_gdal()) as ds:
            ds.write(np.zeros((1, 3, 4), np.uint8))
    elif fmt == "rpcm-json":
        path = tmp_path / "x.json"
        names = {"row_offset": "line_off", "col_offset": "samp_off", "lat_offset": "lat_off",
                 "lon_offset": "long_off", "alt_offset": "height_off", "row_scale": "line_scale",
                 "col_scale": "samp_scale", "lat_scale": "lat_scale", "lon_scale": "long_scale",
                 "alt_scale": "height_scale", "row_num": "line_num_coeff", "row_den": "line_den_coeff",
                 "col_num": "samp_num_coeff", "col_den": "samp_den_coeff"}
        path.write_text(json.dumps({"img": "x.tif", "rpc": {k: (list(getattr(m, v)) if "coeff" in v else
                                                               getattr(m, v)) for k, v in names.items()}}))
    else:
        path = tmp_path / "x.json"
        path.write_text(json.dumps(m.to_dict()))
    back = read_rpc(path)
    assert back.format == fmt
    for key in ("line_off", "samp_off", "lat_off", "long_off", "height_off", "line_scale", "samp_scale",
                "lat_scale", "long_scale", "height_scale"):
        assert getattr(back, key) == pytest.approx(getattr(m, key), rel=1e-12), key
    for key in ("line_num_coeff", "line_den_coeff", "samp_num_coeff", "samp_den_coeff"):
        np.testing.assert_allclose(getattr(back, key), getattr(m, key), rtol=1e-12, atol=1e-18)


def test_crop_shift_moves_the_projection_by_the_crop_offset():
    m = read_rpc(LEFT_GEOM)
    crop = m.shifted(5000, 5000)
    c, r = m.project(m.long_off + 0.01, m.lat_off - 0.01, 600.0)
    cc, rc = crop.project(m.long_off + 0.01, m.lat_off - 0.01, 600.0)
    assert cc == pytest.approx(c - 5000, abs=1e-9) and rc == pytest.approx(r - 5000, abs=1e-9)


def test_bad_rpc_files_give_one_line_errors(tmp_path):
    with pytest.raises(RiverbedError) as e:
        read_rpc(tmp_path / "missing.geom")
    assert str(e.value) == f"{tmp_path / 'missing.geom'}: file not found"
    vrt = tmp_path / "rpc.xml"
    vrt.write_text('<VRTDataset rasterXSize="3" rasterYSize="3"><Metadata domain="RPC"/></VRTDataset>')
    with pytest.raises(RiverbedError) as e:
        read_rpc(vrt)
    assert str(e.value) == (f"{vrt}: unsupported RPC XML (root element <VRTDataset>; riverbed reads DIMAP "
                            "<Dimap_Document> and DigitalGlobe <isd> files)")
    junk = tmp_path / "notes.txt"
    junk.write_text("hello\n")
    with pytest.raises(RiverbedError) as e:
        read_rpc(junk)
    assert str(e.value) == (f"{junk}: not an RPC file (no RPC tags, DIMAP, DigitalGlobe, RPB, OSSIM .geom, RPC00B "
                            "text or rpcm JSON content)")
    cut = tmp_path / "cut.geom"
    cut.write_text("".join(ln for ln in LEFT_GEOM.read_text().splitlines(True) if "samp_num_coeff_05" not in ln))
    with pytest.raises(RiverbedError) as e:
        read_rpc(cut)
    assert str(e.value) == f"{cut}: not a complete ossim RPC model (KeyError: 'samp_num_coeff_05')"
    txt = tmp_path / "x_RPC.TXT"
    _write_rpc00b_text(txt, read_rpc(LEFT_GEOM))
    txt.write_text(txt.read_text().replace("SAMP_NUM_COEFF_7:", "SAMP_NUM_COEF_7:"))
    with pytest.raises(RiverbedError) as e:
        read_rpc(txt)
    assert str(e.value) == f"{txt}: an RPC text file GDAL cannot read (RPC00B keys missing)"
    img = tmp_path / "plain.tif"
    with rasterio.open(img, "w", driver="GTiff", width=2, height=2, count=1, dtype="uint8") as ds:
        ds.write(np.zeros((1, 2, 2), np.uint8))
    with pytest.raises(RiverbedError) as e:
        read_rpc(img)
    assert str(e.value) == f"{img}: no RPC in this image (no RPC tags, no RPC sidecar file beside it)"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**read_rpc(LEFT_GEOM).to_dict(), "LINE_SCALE": 0}))
    with pytest.raises(RiverbedError) as e:
        read_rpc(bad)
    assert str(e.value) == f"{bad}: LINE_SCALE: must be finite and non-zero, got 0.0"


def test_localize_far_outside_the_domain_is_nan_not_garbage():
    m = read_rpc(LEFT_GEOM)
    lon, lat = m.localize([m.samp_off, m.samp_off + 1e9], [m.line_off, m.line_off], [m.height_off] * 2)
    assert np.isfinite(lon[0]) and np.isnan(lon[1]) and np.isnan(lat[1])


def _tilted_dem(tmp_path, vertical_crs="EPSG:4979"):
    """A synthetic DEM over the Ventoux model's centre: h = 400 + 3000 * (lon - lon0) m, ellipsoidal."""
    m = read_rpc(LEFT_GEOM)
    lon0, lat0 = m.long_off, m.lat_off
    res = 0.0005
    cols = np.arange(200)
    lon_c = lon0 - 0.05 + (cols + 0.5) * res
    heights = np.tile(400.0 + 3000.0 * (lon_c - lon0), (200, 1))
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=200, height=200, count=1, dtype="float64",
                       crs=vertical_crs, transform=rasterio.transform.from_origin(lon0 - 0.05, lat0 + 0.05, res, res),
                       nodata=-9999) as ds:
        ds.write(heights[None])
    return m, path


def test_localize_dem_lands_on_the_terrain_and_projects_back(tmp_path):
    m, path = _tilted_dem(tmp_path)
    dem = read_dem(path)
    assert dem.vertical == "ellipsoid"
    cols = m.samp_off + np.linspace(-2000, 2000, 7)
    rows = m.line_off + np.linspace(-1500, 1500, 7)
    lon, lat, h = m.localize_dem(cols, rows, dem)
    # on the plane h = 400 + 3000 (lon - lon0), exactly (the DEM is linear in lon: bilinear is exact)
    np.testing.assert_allclose(h, 400.0 + 3000.0 * (lon - m.long_off), atol=2e-4)
    c2, r2 = m.project(lon, lat, h)
    assert np.max(np.hypot(c2 - cols, r2 - rows)) < 1e-6
    # a pixel whose line of sight misses the DEM
    lon, lat, h = m.localize_dem([m.samp_off + 15000], [m.line_off], dem)
    assert np.isnan(lon[0]) and np.isnan(h[0])


def test_dem_vertical_datum_rules(tmp_path):
    _, path = _tilted_dem(tmp_path, vertical_crs="EPSG:4326")
    with pytest.raises(RiverbedError) as e:
        read_dem(path)
    assert str(e.value) == (f"{path}: heights in an unknown vertical datum (the CRS WGS 84 is 2D): say whether they "
                            "are ellipsoidal or e.g. EGM96 (EPSG:5773)")
    assert read_dem(path, vertical="ellipsoid").vertical == "ellipsoid"
    with pytest.raises(RiverbedError) as e:
        read_dem(path, vertical="EPSG:32632")
    assert str(e.value) == f"{path}: 'EPSG:32632' is not a vertical CRS"
    with pytest.raises(RiverbedError) as e:
        read_dem(path, bounds=(10.0, 40.0, 10.1, 40.1), vertical="ellipsoid")
    assert str(e.value) == (f"{path}: the DEM (lon 5.2346..5.3346, lat 44.0872..44.1872) does not cover the region "
                            "(lon 10.0000..10.1000, lat 40.0000..40.1000)")


def test_dem_bilinear_between_pixel_centres():
    dem = DEM(heights=np.array([[0.0, 10.0], [20.0, 30.0]]), transform=rasterio.transform.from_origin(0, 2, 1, 1),
              source="", vertical="ellipsoid")
    # pixel centres at lon 0.5, 1.5 and lat 1.5 (row 0), 0.5 (row 1)
    np.testing.assert_allclose(dem.height([0.5, 1.5, 1.0, 0.75], [1.5, 0.5, 1.0, 1.5]), [0.0, 30.0, 15.0, 2.5])
    assert np.isnan(dem.height(0.4, 1.0))


def test_egm96_conversion(egm96):
    # EGM96 undulation at Mont Ventoux (44.2 N, 5.2 E): about +50.9 m
    _, _, h = egm96.transform(5.195, 44.206, 500.0)
    assert h == pytest.approx(550.86, abs=0.05)


def test_egm96_without_its_grid_is_a_clear_error(no_egm96_grid):
    with pytest.raises(RiverbedError) as e:
        geoid_to_ellipsoid_transformer("EPSG:5773")
    assert str(e.value) == ("heights are EGM96 height and PROJ's grid us_nga_egm96_15.tif is not available offline "
                            "(install Debian's proj-data, or point PROJ_DATA at a folder with it)")


# --- the shared real data ---------------------------------------------------------------------------------------

def test_every_shared_rpc_file_is_read(shared_data):
    files = sorted((shared_data / RPCM_FILES).iterdir())
    files += [shared_data / VENTOUX / p for p in ("rectification/left_image.geom", "rectification/right_image.geom",
                                                 "rpc/phr_ventoux/RPC_PHR1B_P_201308051042194_SEN_690908101-001.XML")]
    formats = {}
    for path in files:
        if path.name == "rpc_unsupported.xml":
            continue
        m = read_rpc(path)
        check_model(m)
        formats[path.name] = m.format
    assert formats == {
        "20191015_073816_ssc1d3_0011_basic_l1a_panchromatic_dn_RPC.TXT": "rpc-txt-gdal",
        "JAX_068_001_RGB.json": "rpcm-json", "rpc_IKONOS.txt": "rpc-txt-gdal",
        "rpc_PLANET_L1A.txt": "rpc-txt-gdal", "rpc_PLANET_L1B.txt": "rpc-txt-gdal",
        "rpc_PLEIADES.xml": "dimap-gdal", "rpc_SPOT6.xml": "dimap-gdal", "rpc_WV1.xml": "digitalglobe-xml-gdal",
        "rpc_WV2.xml": "digitalglobe-xml-gdal", "rpc_WV3.xml": "digitalglobe-xml-gdal",
        "left_image.geom": "ossim-geom-shareloc", "right_image.geom": "ossim-geom-shareloc",
        "RPC_PHR1B_P_201308051042194_SEN_690908101-001.XML": "dimap-gdal"}


def test_shared_offsets_as_in_the_files(shared_data):
    d = shared_data / RPCM_FILES
    # DIMAP v2 counts from 1 (GDAL subtracts 1); RPC00B text, DigitalGlobe and rpcm's JSON count from 0
    pleiades = read_rpc(d / "rpc_PLEIADES.xml")
    assert (pleiades.samp_off, pleiades.line_off) == (19999.5, 18087.5)      # file: 20000.5, 18088.5
    ikonos = read_rpc(d / "rpc_IKONOS.txt")
    assert (ikonos.samp_off, ikonos.line_off, ikonos.lat_off) == (6334.0, 5124.0, -34.903)
    wv2 = read_rpc(d / "rpc_WV2.xml")
    assert (wv2.samp_off, wv2.line_off) == (14104.0, 10108.0)
    jax = read_rpc(d / "JAX_068_001_RGB.json")
    assert (jax.samp_off, jax.line_off, jax.height_off) == (371.692595898949, 405.51806724276, -21.0)
    assert jax.line_num_coeff[:2] == (-0.00077350474, 1.515268776621)


def test_shared_unsupported_rpc_file_one_line_error(shared_data):
    path = shared_data / RPCM_FILES / "rpc_unsupported.xml"
    with pytest.raises(RiverbedError) as e:
        read_rpc(path)
    assert str(e.value) == (f"{path}: unsupported RPC XML (root element <VRTDataset>; riverbed reads DIMAP "
                            "<Dimap_Document> and DigitalGlobe <isd> files)")


def test_srtm_without_the_egm96_grid_is_refused_not_read_as_ellipsoidal(shared_data, no_egm96_grid):
    hgt = shared_data / VENTOUX / "dtm/srtm_ventoux/srtm90_non_void_filled/N44E005.hgt"
    with pytest.raises(RiverbedError, match="us_nga_egm96_15.tif is not available offline"):
        read_dem(hgt)


def test_ventoux_crop_corners_on_srtm(shared_data, egm96):
    base = shared_data / VENTOUX
    hgt = base / "dtm/srtm_ventoux/srtm90_non_void_filled/N44E005.hgt"
    dem = read_dem(hgt, bounds=(5.18, 44.19, 5.21, 44.22))
    assert dem.vertical == "EPSG:5773"
    offset = 50.86
    raw = read_dem(hgt, vertical="ellipsoid", bounds=(5.18, 44.19, 5.21, 44.22))
    np.testing.assert_allclose(dem.heights - raw.heights, offset, atol=0.1)
    left = read_rpc(base / "rectification/left_image.geom").shifted(5000, 5000)
    c = np.array([0.0, 499.0, 0.0, 499.0])
    r = np.array([0.0, 0.0, 499.0, 499.0])
    lon, lat, h = left.localize_dem(c, r, dem)
    # the MANIFEST's check: corners at 44.204-44.208 N, 5.193-5.197 E, SRTM 440-545 m (orthometric)
    assert np.all((lat > 44.204) & (lat < 44.2085)) and np.all((lon > 5.193) & (lon < 5.197))
    assert np.all((h - offset > 430) & (h - offset < 550))
    c2, r2 = left.project(lon, lat, h)
    assert np.max(np.hypot(c2 - c, r2 - r)) < 1e-6
    assert np.all(np.abs(dem.height(lon, lat) - h) < 1e-3)


def test_rpcmodel_from_dict_refuses_incomplete():
    with pytest.raises(RiverbedError) as e:
        RPCModel.from_dict({"LINE_OFF": 1}, "x.rpc")
    assert str(e.value) == "x.rpc: not a complete RPC model: SAMP_OFF missing"
