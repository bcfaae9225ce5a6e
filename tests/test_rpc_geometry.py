"""LiDAR onto an RPC pair and back (issue 14 steps 3-4): ``riverbed project`` and ``riverbed dsm`` on RPC pair files.

The synthetic pair is written here (no shared data): two cubic RPC models (an along-track pair, parallax in rows,
2 px per metre of height between the views, as in ``test_rpc_cli.py``), flat images (the geometry needs no
texture: ``--no-pointing-correction``), rectified by ``riverbed rectify --rpc``. Ground points are made *on the
rectified left pixel centres* (a pixel localised through ``H_left^-1`` and the left RPC at a height of a smooth
terrain), so the sparse map holds their exact disparities and ``riverbed dsm`` must give back their positions: the
numerical round trip through both affinities and both RPCs.
"""

import json

import laspy
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from pyproj import CRS, Transformer
from scipy.spatial import cKDTree

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.pairfile import load_pairfile
from riverbed_cli.geometry.rpc_geometry import (cloud_to_wgs84, ground_sample_distance, output_crs,
                                                 project_points_rpc, scene_utm, triangulate_rpc)
from riverbed_cli.geometry.rpc_rectify import apply_h
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.pointcloud import write_points
from rpc_synthetic import H0, coeffs, model  # noqa: E402  (tests/: synthetic RPC models)

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")

VENTOUX = "satellite_pleiades_ventoux_shareloc/tests/data"
SIZE = (240, 240)
UTM3D = CRS("EPSG:32631").to_3d()     # the scene's UTM zone with ellipsoidal heights


def run(args):
    return CliRunner().invoke(cli, [str(a) for a in args])


LEFT = model(coeffs(L=1.0, P=0.02, H=0.05, LP=0.0008), coeffs(L=0.01, P=-1.0, H=0.25, LL=0.0005))
RIGHT = model(coeffs(L=1.0, P=0.03, H=0.1, PP=0.0005), coeffs(L=0.012, P=-1.0, H=-0.25, LP=-0.0005),
              samp_off=120.0, line_off=120.0)


def write_tif(path, img, rpc):
    with rasterio.open(path, "w", driver="GTiff", width=img.shape[1], height=img.shape[0], count=1,
                       dtype=img.dtype, rpcs=rpc.to_gdal()) as ds:
        ds.write(img[None])


@pytest.fixture(scope="module")
def rect(tmp_path_factory):
    """The rectified synthetic pair: its folder and :class:`RPCPair`."""
    tmp = tmp_path_factory.mktemp("rpc_geometry")
    left, right = tmp / "left.tif", tmp / "right.tif"
    write_tif(left, np.full(SIZE[::-1], 700, np.uint16), LEFT)
    write_tif(right, np.full(SIZE[::-1], 700, np.uint16), RIGHT)
    out = tmp / "rect"
    r = run(["rectify", "--rpc", left, left, right, right, "-o", out, "--heights", "450,550",
             "--no-pointing-correction"])
    assert r.exit_code == 0, r.output
    return out, load_pairfile(out / "pair.yaml", accept_rpc=True)


def terrain(lon, lat):
    """A smooth terrain (m, ellipsoidal) over the synthetic scene: 500 m +- 30 m."""
    return H0 + 20.0 * np.sin((lon - 5.2) * 400.0) + 10.0 * np.cos((lat - 44.2) * 300.0)


def ground_on_pixel_centres(pair, n, seed=0, margin=30):
    """``n`` ground points on distinct rectified left pixel centres, on :func:`terrain` (fixed point in h), that
    also land in the right rectified image (its frame is the left one's: about half the left frame sees them)."""
    rng = np.random.default_rng(seed)
    x, y, lon, lat, h = _ground(pair, rng.choice((pair.height - 2 * margin) * (pair.width - 2 * margin), 4 * n,
                                                 replace=False), margin)
    _, _, xr, _ = pair.project(lon, lat, h)
    ok = np.flatnonzero((xr >= 0) & (xr <= pair.width - 1))[:n]
    assert ok.size == n
    return x[ok], y[ok], lon[ok], lat[ok], h[ok]


def _ground(pair, cells, margin):
    n = cells.size
    y = (cells // (pair.width - 2 * margin) + margin).astype(np.float64)
    x = (cells % (pair.width - 2 * margin) + margin).astype(np.float64)
    c, r = apply_h(np.linalg.inv(pair.rectification.H_left), x, y)
    h = np.full(n, H0)
    for _ in range(60):
        lon, lat = pair.rpc_left.localize(c, r, h)
        h = terrain(lon, lat)
    lon, lat = pair.rpc_left.localize(c, r, h)
    return x, y, lon, lat, h


def to_utm(lon, lat, h):
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True).transform(lon, lat)
    return np.stack([e, n, h], axis=1)


def test_project_triangulate_round_trip_float64(rect):
    _, pair = rect
    rng = np.random.default_rng(1)
    c, r = rng.uniform(0, 239, (2, 5000))
    h = rng.uniform(450, 550, 5000)
    lon, lat = LEFT.localize(c, r, h)
    x, y, d = project_points_rpc(pair, lon, lat, h)
    lon2, lat2, h2, res = triangulate_rpc(pair, x, y, d)
    # the rectified rows of the two views differ by the affine model's error (< 0.02 px here): that is the residual
    _, _, _, yr = pair.project(lon, lat, h)
    assert np.max(np.abs(yr - y)) < 0.02
    assert np.max(res) < 0.02
    assert np.max(np.abs(h2 - h)) < 0.01
    assert np.max(np.abs(lon2 - lon)) * 111e3 * np.cos(np.radians(44.2)) < 0.01
    assert np.max(np.abs(lat2 - lat)) * 111e3 < 0.01
    # the rectification undone gives back the raw left pixels
    cl, rl = apply_h(np.linalg.inv(pair.rectification.H_left), x, y)
    assert np.allclose((cl, rl), (c, r), atol=1e-9)
    # 1e-5 degree per raw pixel: 0.80 m east, 1.11 m north at 44.2 N; the rectification keeps the scale
    assert ground_sample_distance(pair) == pytest.approx(0.956, abs=0.01)
    assert scene_utm(pair) == "EPSG:32631"


def test_triangulate_exact_on_consistent_observations(rect):
    """Ground points on left pixel centres (the sparse map's positions): heights back within 1 cm; NaN in, NaN out."""
    _, pair = rect
    x, y, lon, lat, h = ground_on_pixel_centres(pair, 2000)
    xl, yl, d = project_points_rpc(pair, lon, lat, h)
    assert np.max(np.abs(xl - x)) < 1e-8 and np.max(np.abs(yl - y)) < 1e-8
    lon2, lat2, h2, res = triangulate_rpc(pair, x, y, d)
    assert np.max(np.abs(h2 - h)) < 0.01 and np.max(res) < 0.02
    assert np.isnan(triangulate_rpc(pair, np.array([np.nan]), np.array([1.0]), np.array([3.0]))[2]).all()


def write_cloud(path, xyz, crs=UTM3D):
    write_points(path, xyz, crs=crs, overwrite=True)
    las = laspy.read(str(path))
    return np.stack([las.x, las.y, las.z], axis=1)   # as written: 1 mm steps


def matched_errors(ref, back):
    """(N, 2): horizontal distance and |height difference| (m) of each ``ref`` point to its nearest ``back`` one
    (one to one: the points are a pixel, ~1 m, apart)."""
    assert len(ref) == len(back)
    dist, idx = cKDTree(back[:, :2]).query(ref[:, :2])
    assert np.unique(idx).size == len(ref)
    return np.stack([dist, np.abs(back[idx, 2] - ref[:, 2])], axis=1)


def test_project_and_dsm_cli_round_trip(rect, tmp_path):
    out, pair = rect
    x, y, lon, lat, h = ground_on_pixel_centres(pair, 3000, seed=2)
    cloud = tmp_path / "cloud.las"
    written = write_cloud(cloud, to_utm(lon, lat, h))
    sparse = tmp_path / "sparse.tif"
    r = run(["project", cloud, out / "pair.yaml", "-o", sparse, "--visibility", "none", "--outliers", "none",
             "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["points_read"] == 3000 and s["kept"] == 3000 and s["outside"] == 0 and s["behind_camera"] == 0
    assert s["size"] == [pair.width, pair.height] and s["crs"] == UTM3D.to_string()
    assert s["row_offset_px"]["max"] < 0.02
    disp = read_disparity(sparse)
    assert np.isfinite(disp).sum() == 3000
    lon_w, lat_w, h_w = cloud_to_wgs84(UTM3D)(*written.T)
    _, _, d_w = project_points_rpc(pair, lon_w, lat_w, h_w)
    np.testing.assert_allclose(disp[y.astype(int), x.astype(int)], d_w, atol=1e-4)
    # riverbed dsm on that sparse map: the points' positions back (default CRS: the scene's UTM zone)
    dsm, pts = tmp_path / "dsm.tif", tmp_path / "pts.las"
    r = run(["dsm", sparse, out / "pair.yaml", "-o", dsm, "--points", pts, "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["image_points"] == 3000 and s["crs"] == "EPSG:32631"
    las = laspy.read(str(pts))
    back = np.stack([las.x, las.y, las.z], axis=1)
    # every written point has its triangulated point within 1 cm horizontally, and its height within 1 cm
    err = matched_errors(written, back)
    assert np.max(err[:, 0]) < 0.01 and np.max(err[:, 1]) < 0.01
    with rasterio.open(dsm) as ds:
        assert ds.crs.to_epsg() == 32631 and ds.tags()["riverbed_heights"] == "ellipsoidal (WGS 84, m)"
        assert ds.res[0] == pytest.approx(float(f"{ground_sample_distance(pair):.3g}"))
        grid = ds.read(1)
    assert np.nanmin(grid) > h.min() - 0.01 and np.nanmax(grid) < h.max() + 0.01
    # --crs: another projected CRS (Lambert-93), the points converted to it
    dsm2 = tmp_path / "dsm_l93.tif"
    r = run(["dsm", sparse, out / "pair.yaml", "-o", dsm2, "--crs", "EPSG:2154", "--json"])
    assert r.exit_code == 0, r.output
    with rasterio.open(dsm2) as ds:
        assert ds.crs.to_epsg() == 2154
        e, n = Transformer.from_crs("EPSG:4326", "EPSG:2154", always_xy=True).transform(lon.mean(), lat.mean())
        assert ds.bounds.left < e < ds.bounds.right and ds.bounds.bottom < n < ds.bounds.top


def test_project_default_visibility_and_outliers_keep_the_surface(rect, tmp_path):
    out, pair = rect
    x, y, lon, lat, h = ground_on_pixel_centres(pair, 8000, seed=3)
    xyz = to_utm(lon, lat, h)
    # 20 points floating 15 m above the terrain: outliers (or hidden), and points below the surface are hidden
    xyz[:20, 2] += 15.0
    cloud = tmp_path / "cloud.las"
    write_cloud(cloud, xyz)
    sparse = tmp_path / "sparse.tif"
    r = run(["project", cloud, out / "pair.yaml", "-o", sparse, "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    total = (s["filtered"]["class"] + s["filtered"]["outliers"] + s["behind_camera"] + s["outside"]
             + s["row_offset"] + sum(s["occluded"].values()) + s["kept"])
    assert total == s["points_read"] == 8000
    assert s["kept"] > 0.95 * 8000
    disp = read_disparity(sparse)
    _, _, d = project_points_rpc(pair, lon, lat, h)
    got = disp[y.astype(int), x.astype(int)]
    ok = np.isfinite(got)
    # what is kept is the surface: the raised points are all gone or moved away from their pixel
    assert not np.any(ok[:20] & (np.abs(got[:20] - d[:20]) < 1))
    # the others are their own disparities (to the LAS file's 1 mm steps: 2 px per metre)
    assert np.max(np.abs(got[20:][ok[20:]] - d[20:][ok[20:]])) < 2.5e-3


def test_bad_inputs_one_line(rect, tmp_path):
    out, pair = rect
    pf = out / "pair.yaml"
    x, y, lon, lat, h = ground_on_pixel_centres(pair, 200, seed=4)
    far = tmp_path / "far.las"
    write_cloud(far, to_utm(lon + 0.2, lat, h))
    r = run(["project", far, pf, "-o", tmp_path / "s.tif"])
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {far}: no point lands in both images (200 read: 0 "
                                          f"filtered by class, 0 behind a camera, 200 outside the {pair.width}x"
                                          f"{pair.height} images, 0 off the row, 0 outliers)\n")
    flat = tmp_path / "flat2d.las"
    write_cloud(flat, to_utm(lon, lat, h), crs="EPSG:32631")
    r = run(["project", flat, pf, "-o", tmp_path / "s.tif"])
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {flat}: the cloud's CRS (WGS 84 / UTM zone 31N) is 2D: "
                                          "its heights' datum is unknown; give --crs with a vertical part (e.g. "
                                          "EPSG:32631+5773 for EGM96 heights) or a 3D CRS\n")
    good = tmp_path / "good.las"
    write_cloud(good, to_utm(lon, lat, h))
    r = run(["project", good, pf, "-o", tmp_path / "s.tif", "--visibility", "hpr"])
    assert (r.exit_code, r.output) == (1, "riverbed: error: visibility 'hpr' needs a camera centre: an RPC pair "
                                          "takes zbuffer or none\n")
    reg = tmp_path / "reg.txt"
    reg.write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    r = run(["project", good, pf, "-o", tmp_path / "s.tif", "--registration", reg])
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {pf}: --registration does not apply to an RPC pair "
                                          "file (the cloud's CRS places it)\n")
    assert not (tmp_path / "s.tif").exists()
    sparse = tmp_path / "sparse.tif"
    assert run(["project", good, pf, "-o", sparse, "--visibility", "none"]).exit_code == 0
    r = run(["dsm", sparse, pf, "-o", tmp_path / "d.tif", "--crs", "EPSG:99999"])
    assert (r.exit_code, r.output) == (1, "riverbed: error: --crs: unknown CRS 'EPSG:99999'\n")
    r = run(["dsm", sparse, pf, "-o", tmp_path / "d.tif", "--crs", "EPSG:4326"])
    assert (r.exit_code, r.output) == (1, "riverbed: error: --crs: WGS 84 is not a projected CRS (an RPC pair's DSM "
                                          "is gridded in metres)\n")
    assert not (tmp_path / "d.tif").exists()
    with pytest.raises(RiverbedError) as e:
        output_crs(pair, "EPSG:4979")
    assert str(e.value) == "--crs: WGS 84 is not a projected CRS (an RPC pair's DSM is gridded in metres)"
    with pytest.raises(RiverbedError) as e:
        cloud_to_wgs84(None, "c.las")
    assert str(e.value) == ("c.las: the cloud states no CRS: give --crs with its heights' datum (e.g. "
                            "EPSG:32631+5773 for UTM 31N + EGM96, or a 3D CRS for ellipsoidal heights)")


def test_ventoux_srtm_points_round_trip(shared_data, tmp_path, egm96):
    """Ground points on the SRTM surface at the Ventoux crops' rectified pixel centres -> project -> dsm."""
    from riverbed_cli.geometry.rpc_dem import read_dem
    from riverbed_cli.geometry.rpc_pair import footprint_bounds

    base = shared_data / VENTOUX / "rectification"
    hgt = shared_data / VENTOUX / "dtm/srtm_ventoux/srtm90_non_void_filled/N44E005.hgt"
    geoid, vertical = egm96, []
    out = tmp_path / "rect"
    r = run(["rectify", "--rpc", base / "left_image.tif", base / "left_image.geom", base / "right_image.tif",
             base / "right_image.geom", "-o", out, "--dem", hgt, *vertical])
    assert r.exit_code == 0, r.output
    pair = load_pairfile(out / "pair.yaml", accept_rpc=True)
    dem = read_dem(hgt, bounds=footprint_bounds(pair.rpc_left, pair.roi, pair.rpc_left.height_off), margin_deg=0.01,
                   vertical=vertical[1] if vertical else None)
    rng = np.random.default_rng(5)
    n = 5000
    cells = rng.choice(pair.width * pair.height, 4 * n, replace=False)
    x = (cells % pair.width).astype(np.float64)
    y = (cells // pair.width).astype(np.float64)
    c, rr = apply_h(np.linalg.inv(pair.rectification.H_left), x, y)
    inside = (c >= 0) & (c <= 499) & (rr >= 0) & (rr <= 499)
    x, y, c, rr = x[inside][:n], y[inside][:n], c[inside][:n], rr[inside][:n]
    lon, lat, h = pair.rpc_left.localize_dem(c, rr, dem, tol_m=1e-6)
    _, _, xr, yr = pair.project(lon, lat, h)
    ok = np.isfinite(h) & (xr >= 0) & (xr <= pair.width - 1) & (yr >= 0) & (yr <= pair.height - 1)
    assert ok.sum() > 0.99 * n
    x, y, lon, lat, h = x[ok], y[ok], lon[ok], lat[ok], h[ok]
    # library: exact pixel centres -> d -> triangulation: heights within 1 cm
    xl, yl, d = project_points_rpc(pair, lon, lat, h)
    assert np.max(np.abs(xl - x)) < 1e-6 and np.max(np.abs(yl - y)) < 1e-6
    lon2, lat2, h2, res = triangulate_rpc(pair, x, y, d)
    assert np.max(np.abs(h2 - h)) < 0.01 and np.max(res) < 0.02
    # CLI: a LAS in UTM 31N + EGM96 heights (a compound CRS, as LiDAR is delivered) -> project -> dsm
    e, nn = Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True).transform(lon, lat)
    crs = CRS("EPSG:32631+5773") if geoid is not None else UTM3D
    z = geoid.transform(lon, lat, h, direction="INVERSE")[2] if geoid is not None else h
    cloud = tmp_path / "srtm.las"
    written = write_cloud(cloud, np.stack([e, nn, z], axis=1), crs=crs)
    sparse = tmp_path / "sparse.tif"
    r = run(["project", cloud, out / "pair.yaml", "-o", sparse, "--visibility", "none", "--outliers", "none",
             "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["kept"] == len(x)
    pts = tmp_path / "pts.las"
    r = run(["dsm", sparse, out / "pair.yaml", "-o", tmp_path / "dsm.tif", "--points", pts])
    assert r.exit_code == 0, r.output
    las = laspy.read(str(pts))
    back = np.stack([las.x, las.y, las.z], axis=1)
    _, _, h_w = cloud_to_wgs84(crs)(*written.T)
    ref = np.stack([written[:, 0], written[:, 1], h_w], axis=1)
    err = matched_errors(ref, back)
    assert np.max(err[:, 0]) < 0.01 and np.max(err[:, 1]) < 0.01
