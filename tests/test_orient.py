"""``riverbed orient``: Orthority, OpenSfM / ODM and COLMAP exports into riverbed orientation files.

Core tests read the tiny hand-made exports in ``tests/data/orient`` (two frames, one camera, written from the truth
below) and check every bad-input message; data tests import Orthority's NGI and ODM test data (RIVERBED_DATA) and
rectify pairs with the imported orientations, measuring the rows of matched features. The measuring functions
(:func:`ngi_rows`, :func:`odm_rows`, :func:`odm_against_orthority`) are what ``benchmarks/bench_rectify.py`` runs for
docs/rectify.md's import tables; the data tests hold their figures to the committed ones.
"""

import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from pyproj import CRS, Proj, Transformer

from riverbed_cli.cli.main import cli
from riverbed_cli.geometry.orientation import load_orientation, opk_to_matrix
from riverbed_cli.geometry.orientation_import import read_opensfm, read_orthority
from test_rectify import FLOOR_PX, assert_figures, committed

DATA = Path(__file__).parent / "data" / "orient"

# -- the truth the exports in tests/data/orient were written from ---------------------------------------------
WIDTH, HEIGHT, FOCAL_PX = 600, 400, 500.0
#: principal point (riverbed: pixel centres at integer coordinates): offsets 0.003, -0.0015 of the larger side
PRINCIPAL_PX = (299.5 + 600 * 0.003, 199.5 - 600 * 0.0015)
#: k1, k2, p1, p2, k3
DIST = (-0.1, 0.02, 0.0004, -0.0002, -0.003)
FRAMES = {"frame_a.tif": ((500100.0, 4100200.0, 1500.0), (1.5, -2.25, 30.0)),
          "frame_b.tif": ((500700.0, 4100210.0, 1490.0), (-0.75, 1.25, 32.5))}
UTM33 = "EPSG:32633"


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _orient(*args):
    r = _run("orient", *args)
    assert r.exit_code == 0, r.output
    return r


def _angle_deg(A, B):
    """Angle of the rotation between two rotation matrices (degrees)."""
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(A @ B.T) - 1) / 2))))


# -- core: round trips ----------------------------------------------------------------------------------------
EXPORTS = {  # name -> (inputs, extra args, crs written, centre tolerance (m), rotation tolerance)
    "orthority_csv": (["orthority/int_param.yaml", "orthority/ext_xyz_opk.csv"], [],
                      "+proj=utm +zone=33 +datum=WGS84 +units=m +no_defs", 1e-9, 1e-9),
    "orthority_geojson": (["orthority/int_param.yaml", "orthority/ext_param.geojson"], [], UTM33, 1e-9, 1e-9),
    # written from the truth through PROJ (UTM -> geodetic -> topocentric) and read back through it: the round
    # trip holds to 2e-8 m and 1e-9 in the matrix
    "opensfm": (["opensfm/reconstruction.json"], ["--crs", UTM33], UTM33, 1e-7, 1e-8),
    "opensfm_folder": (["opensfm"], ["--crs", UTM33], UTM33, 1e-7, 1e-8),
    "colmap": (["colmap/cameras.txt", "colmap/images.txt"], [], None, 1e-9, 1e-9),
    "colmap_folder": (["colmap"], [], None, 1e-9, 1e-9),
}


@pytest.mark.parametrize("export", list(EXPORTS))
def test_each_format_gives_back_the_orientations_it_was_written_from(tmp_path, export):
    inputs, extra, crs, centre_tol, rotation_tol = EXPORTS[export]
    out = tmp_path / "out"
    r = _orient(*[DATA / p for p in inputs], *extra, "-o", out, "--json")
    summary = json.loads(r.stdout)
    assert summary["crs"] == crs and len(summary["frames"]) == 2
    assert sorted(p.name for p in out.iterdir()) == ["frame_a.yaml", "frame_b.yaml"]
    for name, (centre, opk) in FRAMES.items():
        o = load_orientation(out / (name[:-4] + ".yaml"), image_size=(WIDTH, HEIGHT))
        assert o.crs == crs
        assert np.abs(o.centre - centre).max() < centre_tol
        assert np.abs(o.M - opk_to_matrix(*opk)).max() < rotation_tol
        assert np.allclose(o.K, [[FOCAL_PX, 0, PRINCIPAL_PX[0]], [0, FOCAL_PX, PRINCIPAL_PX[1]], [0, 0, 1]],
                           rtol=0, atol=1e-9)
        # COLMAP's frame_b has a SIMPLE_RADIAL camera (k1 only); OPENCV has no k3
        expected = DIST if not export.startswith("colmap") else (DIST[:4] + (0.0,) if name == "frame_a.tif"
                                                                  else (DIST[0], 0.0, 0.0, 0.0, 0.0))
        assert np.abs(o.dist - expected).max() < 1e-12


def test_colmap_images_without_points_lines_read_the_same(tmp_path):
    lines = (DATA / "colmap/images.txt").read_text().splitlines()
    images = tmp_path / "images.txt"
    images.write_text("\n".join(line for line in lines if line.split()[:1] != ["312.5"] and line) + "\n")
    shutil.copy(DATA / "colmap/cameras.txt", tmp_path / "cameras.txt")
    a, b = tmp_path / "a", tmp_path / "b"
    _orient(tmp_path / "cameras.txt", images, "-o", a)
    _orient(DATA / "colmap", "-o", b)
    for name in ("frame_a.yaml", "frame_b.yaml"):
        assert (a / name).read_text() == (b / name).read_text()


def test_colmap_world_takes_the_crs_given(tmp_path):
    _orient(DATA / "colmap", "--crs", UTM33, "-o", tmp_path / "out")
    assert load_orientation(tmp_path / "out" / "frame_a.yaml").crs == UTM33


def _pix4d_rpy(lat, lon, alt, roll, pitch, yaw, crs):
    """Orthority's roll/pitch/yaw conversion written out (Pix4D's convention): camera -> grid
    ``C_En Rz(yaw) Ry(pitch) Rx(roll) C_bB``, ``C_En`` from grid north at the point; returns ``M``, its transpose."""
    r, p, y = (math.radians(a) for a in (roll, pitch, yaw))
    Rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    Ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    Rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    to_grid = Transformer.from_crs("EPSG:4979", crs, always_xy=True)
    north = np.subtract(to_grid.transform(lon, lat + 1e-7, alt), to_grid.transform(lon, lat - 1e-7, alt))
    north /= np.linalg.norm(north)
    down = np.array([0.0, 0.0, -1.0])
    C_En = np.stack([north, np.cross(down, north), down], axis=1)
    C_bB = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    return (C_En @ Rz @ Ry @ Rx @ C_bB).T


def test_latitude_longitude_roll_pitch_yaw_follow_orthority(tmp_path):
    frames = read_orthority(DATA / "orthority/int_param.yaml", DATA / "orthority/ext_lla_rpy.csv")
    o = frames["frame_a.tif"]
    assert o.crs == UTM33  # the UTM zone of the positions
    x, y, z = Transformer.from_crs("EPSG:4979", UTM33, always_xy=True).transform(15.01, 37.05, 1500.0)
    assert np.abs(o.centre - [x, y, z]).max() < 1e-9
    # Orthority's finite difference over 1e-7 deg of latitude limits the agreement to 2e-9
    assert np.abs(o.M - _pix4d_rpy(37.05, 15.01, 1500.0, 2.5, -3.0, 120.0, UTM33)).max() < 1e-8


def test_images_selects_by_name_or_stem(tmp_path):
    out = tmp_path / "out"
    r = _orient(DATA / "colmap", "-o", out, "--images", "frame_b", "--json")
    assert [f["image"] for f in json.loads(r.stdout)["frames"]] == ["frame_b.tif"]
    assert [p.name for p in out.iterdir()] == ["frame_b.yaml"]


def test_outputs_are_kept_without_overwrite_and_written_together(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "frame_b.yaml").write_text("mine\n")
    r = _run("orient", DATA / "colmap", "-o", out)
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {out / 'frame_b.yaml'}: output exists; pass "
                                          "--overwrite to replace it\n")
    assert sorted(p.name for p in out.iterdir()) == ["frame_b.yaml"]  # frame_a.yaml not written either
    assert (out / "frame_b.yaml").read_text() == "mine\n"
    _orient(DATA / "colmap", "-o", out, "--overwrite")
    assert load_orientation(out / "frame_b.yaml").width == WIDTH


# -- core: bad input, one line each ---------------------------------------------------------------------------
def _edit(tmp_path, source, old, new, name=None):
    """A copy of ``tests/data/orient/SOURCE`` in tmp_path with ``old`` replaced by ``new`` (once, must be there)."""
    text = (DATA / source).read_text()
    assert old in text, old
    path = tmp_path / (name or Path(source).name)
    path.write_text(text.replace(old, new, 1))
    return path


def _colmap(tmp_path, cameras=None, images=None):
    c = _edit(tmp_path, "colmap/cameras.txt", *cameras) if cameras else shutil.copy(DATA / "colmap/cameras.txt",
                                                                                       tmp_path / "cameras.txt")
    i = _edit(tmp_path, "colmap/images.txt", *images) if images else shutil.copy(DATA / "colmap/images.txt",
                                                                                   tmp_path / "images.txt")
    return [c, i]


def _orthority(tmp_path, interior=None, exterior="ext_xyz_opk.csv", edit=None):
    i = _edit(tmp_path, "orthority/int_param.yaml", *interior) if interior else DATA / "orthority/int_param.yaml"
    e = _edit(tmp_path, f"orthority/{exterior}", *edit) if edit else DATA / f"orthority/{exterior}"
    return [i, e]


def _opensfm(tmp_path, edit):
    return [_edit(tmp_path, "opensfm/reconstruction.json", *edit)]


CAM = "[0].cameras.v2 test brown 0.8333"
BAD = {  # name -> (inputs(tmp_path), extra args, message after "riverbed: error: ", {placeholder})
    "orthority_missing_focal": (
        lambda t: _orthority(t, interior=("  focal_len: 5.0\n", "")), [],
        "{0}: test camera.focal_len: missing"),
    "orthority_fisheye": (
        lambda t: _orthority(t, interior=("type: brown", "type: fisheye")), [],
        "{0}: test camera.type: camera model 'fisheye' is not supported (riverbed reads pinhole, brown and opencv: "
        "OpenCV's Brown model, no fisheye)"),
    "orthority_mm_without_sensor_size": (
        lambda t: _orthority(t, interior=("  focal_len: 5.0\n  sensor_size: [6.0, 4.0]\n", "  focal_len: 120.0\n")),
        [], "{0}: test camera.focal_len: 120.0 is read as normalised by the larger image side (a field of view of "
            "0.48 deg): give sensor_size in the units of focal_len"),
    "orthority_unmodelled_coefficient": (
        lambda t: _orthority(t, interior=("type: brown", "type: opencv\n  k4: 0.01")), [],
        "{0}: test camera.k4: 0.01 is not zero; riverbed's distortion model has k1, k2, k3, p1, p2 only"),
    "orthority_unknown_key": (
        lambda t: _orthority(t, interior=("  cx:", "  c_x:")), [],
        "{0}: test camera.c_x: unknown key for a brown camera (keys: type, im_size, focal_len, sensor_size, cx, cy, "
        "name, k1, k2, p1, p2, k3)"),
    "csv_missing_column": (
        lambda t: _orthority(t, edit=(",kappa\n", ",kapa\n")), [],
        "{1}: header: needs filename, x y z (or latitude longitude altitude) and omega phi kappa (or roll pitch "
        "yaw); it has filename, x, y, z, omega, phi, kapa"),
    "csv_not_a_number": (
        lambda t: _orthority(t, edit=(",1.5,", ",1.5deg,")), [],
        "{1}: line 2: omega: expected a number, got '1.5deg'"),
    "csv_short_row": (
        lambda t: _orthority(t, edit=(",32.5\n", "\n")), [],
        "{1}: line 3: expected 7 fields (filename, x, y, z, omega, phi, kappa), got 6"),
    "csv_degrees_read_as_radians": (
        lambda t: _orthority(t), ["--radians"],
        "{1}: line 2: omega/phi/kappa: 30.0 is outside +-6.28319: not an angle in radians (are they degrees?)"),
    "csv_camera_not_in_interior": (
        lambda t: _orthority(t, exterior="ext_lla_rpy.csv", edit=('"test camera"', '"other camera"')), [],
        "{1}: line 2: camera: camera 'other camera' is not in int_param.yaml (it has: test camera)"),
    "csv_roll_pitch_yaw_without_crs": (
        lambda t: _orthority(t, exterior="ext_lla_rpy.csv", edit=("latitude longitude altitude", "x y z")), [],
        "{1}: roll, pitch, yaw need the CRS of x, y, z: give --crs or a .prj file beside the CSV"),
    "geojson_degrees": (
        lambda t: _orthority(t, exterior="ext_param.geojson", edit=("0.5235987755982988", "30.0")), [],
        "{1}: features[0].properties.opk: 30.0 is outside +-6.28319: not an angle in radians (are they degrees?)"),
    "geojson_missing_xyz": (
        lambda t: _orthority(t, exterior="ext_param.geojson", edit=('"xyz"', '"xy"')), [],
        "{1}: features[0].properties.xyz: missing"),
    "image_not_in_export": (
        lambda t: _orthority(t), ["--images", "frame_c.tif"],
        "{1}: image 'frame_c.tif' is not in the export (it has 2: frame_a.tif, frame_b.tif)"),
    "opensfm_fisheye": (
        lambda t: _opensfm(t, ('"projection_type": "brown"', '"projection_type": "fisheye"')), [],
        f"{{0}}: {CAM}.projection_type: camera model 'fisheye' is not supported (riverbed reads perspective, "
        "simple_radial, radial, brown: OpenCV's Brown model, no fisheye or spherical)"),
    "opensfm_focal_in_pixels": (
        lambda t: _opensfm(t, ('"focal_x": 0.8333333333333334', '"focal_x": 500.0')), [],
        f"{{0}}: {CAM}.focal_x: 500.0 is read as normalised by the larger image side (a field of view of 0.11 deg): "
        "OpenSfM's focal lengths are normalised, not in pixels or mm"),
    "opensfm_not_georeferenced": (
        lambda t: _opensfm(t, ('"reference_lla"', '"reference"')), [],
        "{0}: [0].reference_lla: missing (the reconstruction is not georeferenced)"),
    "opensfm_missing_translation": (
        lambda t: _opensfm(t, ('"translation"', '"translations"')), [],
        "{0}: [0].shots.frame_a.tif.translation: missing"),
    "opensfm_geographic_crs": (
        lambda t: [DATA / "opensfm/reconstruction.json"], ["--crs", "EPSG:4326"],
        "--crs: EPSG:4326 is not a projected CRS (riverbed's centres are easting, northing, height in metres)"),
    "opensfm_unknown_crs": (
        lambda t: [DATA / "opensfm/reconstruction.json"], ["--crs", "EPSG:999999"],
        "--crs: unknown CRS 'EPSG:999999'"),
    "colmap_fisheye": (
        lambda t: _colmap(t, cameras=("1 OPENCV 600 400 500.0 500.0", "1 OPENCV_FISHEYE 600 400 500.0 500.0")), [],
        "{0}: line 3: camera model OPENCV_FISHEYE is not supported (riverbed reads SIMPLE_PINHOLE, PINHOLE, "
        "SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV: OpenCV's Brown model)"),
    "colmap_parameter_count": (
        lambda t: _colmap(t, cameras=("SIMPLE_RADIAL 600 400 500.0 301.8 199.1 -0.1", "RADIAL 600 400 500.0 "
                                      "301.8 199.1 -0.1")), [],
        "{0}: line 4: RADIAL has 5 parameters (f cx cy k1 k2), got 4"),
    "colmap_non_square_pixels": (
        lambda t: _colmap(t, cameras=("500.0 500.0", "500.0 510.0")), [],
        "{0}: line 3: fx, fy: non-square pixels (fx 500 px, fy 510 px); riverbed's orientation files hold one focal "
        "length"),
    "colmap_focal_in_mm": (
        lambda t: _colmap(t, cameras=("SIMPLE_RADIAL 600 400 500.0", "SIMPLE_RADIAL 600 400 8.8")), [],
        "{0}: line 4: focal length: a focal length of 8.8 px for a 600x400 image (field of view 177 deg) is "
        "implausible: wrong units?"),
    "colmap_unknown_camera": (
        lambda t: _colmap(t, images=(" 2 frame_b.tif", " 3 frame_b.tif")), [],
        "{1}: line 6: camera 3 is not in cameras.txt"),
    "colmap_quaternion": (
        lambda t: _colmap(t, images=("1 0.007560003064195956 ", "1 0.5 ")), [],
        "{1}: line 4: QW QX QY QZ: not a unit quaternion (norm 1.11801)"),
    "unknown_format": (
        lambda t: [shutil.copy(DATA / "colmap/cameras.txt", t / "export.dat")], [],
        "{0}: cannot tell the export format from the file name; give --format"),
    "missing_file": (
        lambda t: [t / "reconstruction.json"], [],
        "{0}: no such file"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_naming_the_file(tmp_path, case):
    make, extra, message = BAD[case]
    inputs = make(tmp_path)
    r = _run("orient", *inputs, *extra, "-o", tmp_path / "out")
    assert (r.exit_code, r.output) == (1, "riverbed: error: " + message.format(*inputs) + "\n")
    assert not (tmp_path / "out").exists()


# -- data: Orthority's NGI and ODM test data ------------------------------------------------------------------
def _rows_of_matches(left, right, ratio=0.75):
    """Median |dy| (px) of SIFT matches between two rectified images (files): Lowe's ratio test, then RANSAC on the
    fundamental matrix (2 px) to drop wrong matches; returns the median and the number of matches kept."""
    a, b = (cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in (left, right))
    sift = cv2.SIFT_create(nfeatures=8000)
    ka, da = sift.detectAndCompute(a, (a > 0).astype(np.uint8))
    kb, db = sift.detectAndCompute(b, (b > 0).astype(np.uint8))
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    pa = np.array([ka[m.queryIdx].pt for m in good])
    pb = np.array([kb[m.trainIdx].pt for m in good])
    _, inliers = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 2.0, 0.999)
    keep = inliers.ravel().astype(bool)
    return float(np.median(np.abs(pb[keep, 1] - pa[keep, 1]))), int(keep.sum())


def _csv_rows(path):
    """Orthority's CSV as ``{name: [x, y, z, omega, phi, kappa]}`` (comma or space separated, quoted names)."""
    lines = path.read_text().splitlines()
    sep = "," if "," in lines[0] else None
    return {line.split(sep)[0].strip("'\""): [float(v) for v in line.split(sep)[1:7]] for line in lines[1:]}


NGI = ("3324c_2015_1004_05_0182_RGB", "3324c_2015_1004_05_0184_RGB")


def test_ngi_csv_and_geojson_give_the_same_orientations(shared_data, tmp_path):
    ngi = shared_data / "aerial_ngi_orthority" / "ngi"
    from_csv = read_orthority(ngi / "ngi_int_param.yaml", ngi / "ngi_xyz_opk.csv")
    from_geojson = read_orthority(ngi / "ngi_int_param.yaml", ngi / "ngi_ext_param.geojson")
    table = _csv_rows(ngi / "ngi_xyz_opk.csv")
    assert set(from_csv) == set(from_geojson) == set(table)
    for name, row in table.items():
        a, b = from_csv[name], from_geojson[name]
        assert np.array_equal(a.K, b.K) and np.array_equal(a.dist, b.dist)
        assert (a.width, a.height) == (b.width, b.height) == (640, 1152)
        assert a.K[0, 0] == pytest.approx(120.0 * 640 / 92.16, abs=1e-9)
        assert tuple(a.K[:2, 2]) == (319.5, 575.5)
        # the CSV is the GeoJSON rounded to the millimetre and 0.001 deg: they agree to that rounding
        assert np.abs(a.centre - row[:3]).max() < 1e-9
        assert np.abs(b.centre - row[:3]).max() <= 0.0005 + 1e-9
        assert np.abs(np.subtract(b.omega_phi_kappa, a.omega_phi_kappa)).max() <= 0.0005 + 1e-9
        assert np.abs(np.subtract(a.omega_phi_kappa, row[3:])).max() < 1e-9
    crs = [CRS.from_user_input(frames[NGI[0]].crs) for frames in (from_csv, from_geojson)]
    assert crs[0].equals(crs[1], ignore_axis_order=True)


def _rectify(left_img, left_orient, right_img, right_orient, outdir, *extra):
    r = _run("rectify", left_img, left_orient, right_img, right_orient, "-o", outdir, *extra)
    assert r.exit_code == 0, r.output
    return outdir / "left.png", outdir / "right.png"


def ngi_rows(data, tmp_path):
    """The NGI frames 0182 + 0184 imported from Orthority's CSV (``riverbed orient``) and rectified: the rows of their
    matched features, and with the right frame's rotation transposed (``Mᵀ`` fed as ``M``). Returns ``{"ngi": {...},
    "ngi_transposed": {...}}``, each ``median_px`` and ``matches`` (:func:`_rows_of_matches`)."""
    ngi = Path(data) / "aerial_ngi_orthority" / "ngi"
    out = tmp_path / "orient"
    _orient(ngi / "ngi_int_param.yaml", ngi / "ngi_xyz_opk.csv", "-o", out, "--images", ",".join(NGI))
    images = [ngi / f"{name}.tif" for name in NGI]
    orients = [out / f"{name}.yaml" for name in NGI]
    table = _csv_rows(ngi / "ngi_xyz_opk.csv")
    for name, path in zip(NGI, orients):  # centres as in the CSV, to the millimetre
        assert np.abs(load_orientation(path).centre - table[name][:3]).max() < 0.0005
    data = yaml.safe_load(orients[1].read_text())
    M = opk_to_matrix(*data["exterior"].pop("omega_phi_kappa_deg"))
    data["exterior"]["rotation"] = M.T.tolist()
    transposed = tmp_path / "transposed.yaml"
    transposed.write_text(yaml.safe_dump(data))
    rows = {}
    for name, right in (("ngi", orients[1]), ("ngi_transposed", transposed)):
        dy, kept = _rows_of_matches(*_rectify(images[0], orients[0], images[1], right, tmp_path / name))
        rows[name] = {"median_px": dy, "matches": kept}
    return rows


def test_ngi_pair_rectified_from_the_import_shares_its_rows(shared_data, tmp_path):
    rows = ngi_rows(shared_data, tmp_path)
    assert rows["ngi"]["matches"] > 300 and rows["ngi_transposed"]["matches"] > 300
    # rows within half a pixel; with the rotation transposed, pixels apart
    assert rows["ngi"]["median_px"] < 0.5 and rows["ngi_transposed"]["median_px"] > 1.0
    for name, row in rows.items():
        assert_figures(row, committed("orient", name), what=name)


def odm_against_orthority(data):
    """The ODM block's orientations from OpenSfM's reconstruction.json against Orthority's conversion of it
    (``odm_xyz_opk.csv``): the meridian convergence at the reference point (``convergence_deg``), the spans over the
    frames of the distances between the centres (``centres_m``) and of the angles between the rotations
    (``rotations_deg``), and the largest of each once Orthority's offsets are turned by the convergence and scaled by
    the map's scale factor (``corrected_centres_m``, ``corrected_rotations_deg``)."""
    odm = Path(data) / "aerial_ngi_orthority" / "odm"
    ours = read_opensfm(odm / "opensfm" / "reconstruction.json")
    table = _csv_rows(odm / "odm_xyz_opk.csv")
    assert set(ours) == set(table) and {o.crs for o in ours.values()} == {"EPSG:32651"}
    # Orthority adds the topocentric offsets to the reference point's UTM coordinates as they are; the grid is
    # turned by the meridian convergence there and scaled by the map's scale factor
    ref = json.loads((odm / "opensfm" / "reconstruction.json").read_text())[0]["reference_lla"]
    x0, y0 = Transformer.from_crs("EPSG:4326", "EPSG:32651", always_xy=True).transform(ref["longitude"],
                                                                                      ref["latitude"])
    origin = np.array([x0, y0, ref["altitude"]])
    factors = Proj("EPSG:32651").get_factors(ref["longitude"], ref["latitude"])
    g, k = math.radians(factors.meridian_convergence), factors.meridional_scale
    turn = np.array([[math.cos(g), -math.sin(g), 0.0], [math.sin(g), math.cos(g), 0.0], [0.0, 0.0, 1.0]])
    raw_centres, raw_angles, centres, angles = [], [], [], []
    for name, o in ours.items():
        C, M = np.array(table[name][:3]), opk_to_matrix(*table[name][3:])
        raw_centres.append(np.linalg.norm(o.centre - C))
        raw_angles.append(_angle_deg(o.M, M))
        centres.append(np.abs(o.centre - (origin + np.diag([k, k, 1.0]) @ turn @ (C - origin))).max())
        angles.append(_angle_deg(o.M, M @ turn.T))
    return {"convergence_deg": abs(math.degrees(g)), "centres_m": [min(raw_centres), max(raw_centres)],
            "rotations_deg": [min(raw_angles), max(raw_angles)], "corrected_centres_m": max(centres),
            "corrected_rotations_deg": max(angles)}


def test_odm_reconstruction_against_orthority_conversion(shared_data):
    got = odm_against_orthority(shared_data)
    # our rotations differ from Orthority's by the meridian convergence, which Orthority leaves out
    assert abs(np.array(got["rotations_deg"]) - got["convergence_deg"]).max() < 0.001
    # once Orthority's offsets are turned and scaled the two agree to millimetres and thousandths of a degree: the
    # CSV's rounding to 1 mm and 0.001 deg, and the vertical at each camera rather than at the reference point
    assert got["centres_m"][0] > 1.0 and 0.001 < got["corrected_centres_m"] < 0.005
    assert 0.001 < got["corrected_rotations_deg"] < 0.002
    # PROJ's arithmetic, deterministic: the committed figures to 1e-4 of their unit (m, deg) or 2 %
    assert_figures(got, committed("orient", "odm_vs_orthority"), 1e-4, "ODM against Orthority")


def odm_rows(data, tmp_path):
    """The ODM images 0140 + 0142 imported from OpenSfM's reconstruction.json and rectified (``--alpha -1 --size
    1600x1200``): the rows of their matched features, ``median_px`` and ``matches`` (:func:`_rows_of_matches`)."""
    odm = Path(data) / "aerial_ngi_orthority" / "odm"
    out = tmp_path / "orient"
    _orient(odm / "opensfm", "-o", out, "--images", "100_0005_0140.tif,100_0005_0142.tif")
    # oblique views 90 deg apart in heading: OpenCV's own scaling (alpha -1) on a larger frame keeps the overlap
    left, right = _rectify(odm / "images" / "100_0005_0140.tif", out / "100_0005_0140.yaml",
                           odm / "images" / "100_0005_0142.tif", out / "100_0005_0142.yaml", tmp_path / "pair",
                           "--alpha", "-1", "--size", "1600x1200")
    dy, kept = _rows_of_matches(left, right)
    return {"median_px": dy, "matches": kept}


def test_odm_pair_rectified_from_the_import_shares_its_rows(shared_data, tmp_path):
    row = odm_rows(shared_data, tmp_path)
    assert row["matches"] > 200 and row["median_px"] < 0.5
    assert_figures(row, committed("orient", "odm"), FLOOR_PX, "ODM 0140 + 0142")
