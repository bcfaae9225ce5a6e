"""``riverbed rectify --rpc`` end to end: a synthetic RPC pair (core), the real Ventoux crops (data), bad inputs.

The synthetic pair: two RPC models written here (cubic polynomials with a unit denominator: an along-track pair,
parallax in rows, 2 px per metre of height between the views), a flat terrain at 500 m ellipsoidal height with a
blurred-noise texture on longitude and latitude, rendered through each model (every pixel localised at 500 m and
the texture sampled there). The left image carries its RPC in its GeoTIFF tags; the right one is a 260 x 250 crop
at (100, 50) of a larger image (a translation geotransform without CRS, as shareloc's crops) whose RPC file (GDAL
names in JSON) has a pointing error of 3 px in columns, which the command must find on tie points and remove.
"""

import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.pairfile import load_pairfile
from riverbed_cli.geometry.rpc import read_rpc
from riverbed_cli.geometry.rpc_pair import RPCPair, footprint_bounds, rpc_pair_to_dict
from riverbed_cli.geometry.rpc_rectify import apply_h, estimate_row_offset, resample, virtual_matches
from rpc_synthetic import H0, coeffs, model  # noqa: E402  (tests/: synthetic RPC models)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

# the rectified TIFFs have no geotransform (epipolar geometry): rasterio says so when the tests open them
pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")

VENTOUX = "satellite_pleiades_ventoux_shareloc/tests/data"
SIZE = (240, 240)                  # left image, W x H
CROP = (100, 50, 260, 250)         # right crop: col0, row0, W, H in the right full image
POINTING_COLS = 3.0                # the right RPC file's columns are this much short of the image's


def run(args):
    return CliRunner().invoke(cli, [str(a) for a in args])


# the left view looks forward (+1 px of rows per metre), the right one backward; a little roll and curvature
LEFT = model(coeffs(L=1.0, P=0.02, H=0.05, LP=0.0008), coeffs(L=0.01, P=-1.0, H=0.25, LL=0.0005))
RIGHT_FULL = model(coeffs(L=1.0, P=0.03, H=0.1, PP=0.0005), coeffs(L=0.012, P=-1.0, H=-0.25, LP=-0.0005),
                   samp_off=220.0, line_off=170.0)
RIGHT = RIGHT_FULL.shifted(CROP[0], CROP[1])            # the true model of the crop's pixels


def texture():
    """Blurred noise on a lon/lat grid (0.5e-5 degree texels) and the grid's origin."""
    rng = np.random.default_rng(7)
    tex = cv2.GaussianBlur(rng.normal(size=(1400, 1400)).astype(np.float32), (0, 0), 2.0)
    return (tex - tex.min()) / (tex.max() - tex.min()), (5.2 - 0.0035, 44.2 + 0.0035), 0.5e-5


def render(m, width, height, value=None):
    """The image of the flat terrain through model ``m`` (uint16)."""
    if value is not None:
        return np.full((height, width), value, np.uint16)
    tex, (lon0, lat0), step = texture()
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float64)
    lon, lat = m.localize(cols, rows, np.full(cols.shape, H0))
    mx = ((lon - lon0) / step).astype(np.float32)
    my = ((lat0 - lat) / step).astype(np.float32)
    out = cv2.remap(tex, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return (300 + 800 * np.clip(out, 0, 1)).astype(np.uint16)


def write_tif(path, img, rpc=None, transform=None):
    kw = {"rpcs": rpc.to_gdal()} if rpc is not None else {}
    if transform is not None:
        kw["transform"] = transform
    with rasterio.open(path, "w", driver="GTiff", width=img.shape[1], height=img.shape[0], count=1,
                       dtype=img.dtype, **kw) as ds:
        ds.write(img[None])


def synthetic_pair(folder, flat=False, right_rpc=None):
    """left.tif (RPC in its tags), right.tif (a crop), right_rpc.json (the full image's RPC, pointing error)."""
    folder.mkdir(exist_ok=True)
    left, right = folder / "left.tif", folder / "right.tif"
    write_tif(left, render(LEFT, *SIZE, 700 if flat else None), rpc=LEFT)
    write_tif(right, render(RIGHT, CROP[2], CROP[3], 700 if flat else None), transform=Affine.translation(*CROP[:2]))
    rpc = folder / "right_rpc.json"
    given = RIGHT_FULL.shifted(POINTING_COLS, 0.0) if right_rpc is None else right_rpc
    rpc.write_text(json.dumps(given.to_dict()))
    return left, right, rpc


@pytest.fixture(scope="module")
def pair_files(tmp_path_factory):
    return synthetic_pair(tmp_path_factory.mktemp("rpc_pair") / "in")


def rows_of(pair, m_right, lon, lat, h):
    """Rectified rows of ground points in the left image and, through ``m_right``, in the right one."""
    _, yl = apply_h(pair.rectification.H_left, *pair.rpc_left.project(lon, lat, h))
    _, yr = apply_h(pair.rectification.H_right, *m_right.project(lon, lat, h))
    return yl, yr


def test_synthetic_pair_rectified_recorded_and_pointing_corrected(pair_files, tmp_path):
    left, right, rpc = pair_files
    out = tmp_path / "out"
    r = run(["rectify", "--rpc", left, left, right, rpc, "-o", out, "--heights", "470,530", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert sorted(p.name for p in out.iterdir()) == ["left.tif", "pair.yaml", "right.tif"]
    assert s["crop_offsets"] == [[0.0, 0.0], [100.0, 50.0]] and s["roi"] == [0, 0, 240, 240]
    assert s["heights"] == [470.0, 530.0] and s["heights_from"] == "--heights (ellipsoidal)"
    # the affine model's error on these models: 0.012 px (the fit's, checked on a denser grid)
    assert s["virtual_row_residual_max_px"] < 0.02 and s["pointing_tie_points"] > 50
    pair = load_pairfile(out / "pair.yaml", accept_rpc=True)
    assert isinstance(pair, RPCPair) and pair.kind == "rpc"
    assert (pair.left, pair.right) == ((out / "left.tif").absolute(), (out / "right.tif").absolute())
    assert pair.image_size == (s["height"], s["width"]) and list(pair.disparity) == s["disparity"]
    assert pair.heights == (470.0, 530.0) and pair.roi == (0, 0, 240, 240)
    assert pair.rpc_left.to_dict() == LEFT.to_dict()            # read from the TIFF tags, recorded exactly
    assert pair.inputs["right_crop_offset"] == [100.0, 50.0] and pair.inputs["left_rpc"] == os.path.relpath(left, out)
    # the pair file reads back into the same dict (exact floats)
    import yaml
    assert rpc_pair_to_dict(pair, out) == yaml.safe_load((out / "pair.yaml").read_text())
    # virtual ground points: equal rows through the recorded models, d = x_left - x_right in range, growing with h
    g = np.random.default_rng(3).uniform(0, 239, (2, 400))
    hh = np.random.default_rng(4).uniform(470, 530, 400)
    lon, lat = pair.rpc_left.localize(g[0], g[1], hh)
    xl, yl, xr, yr = pair.project(lon, lat, hh)
    assert np.max(np.abs(yl - yr)) < 0.02
    d = xl - xr
    assert d.min() > pair.disparity[0] + 4 and d.max() < pair.disparity[1] - 4
    assert np.polyfit(hh, d, 1)[0] == pytest.approx(s["disparity_per_metre"], rel=1e-3)
    assert s["disparity_per_metre"] == pytest.approx(2.0, abs=0.1)
    # the pointing correction against the truth: through the crop's true model the rows agree (the file's model
    # was 3 px off); the uncorrected file model (crop offset applied) misses by ~3 px of rows
    lon, lat = pair.rpc_left.localize(g[0], g[1], H0)
    yl, yr = rows_of(pair, RIGHT, lon, lat, H0)
    assert np.max(np.abs(yl - yr)) < 0.05
    yl, yr = rows_of(pair, read_rpc(rpc).shifted(*CROP[:2]), lon, lat, H0)
    assert np.median(yl - yr) == pytest.approx(-s["pointing_row_offset_px"], abs=0.01)
    assert abs(s["pointing_row_offset_px"]) > 2.5
    # the images: the left one is the input resampled by H_left; the right one shares its rows (tie points)
    with rasterio.open(out / "left.tif") as ds:
        rect_left = ds.read(1)
    with rasterio.open(out / "right.tif") as ds:
        rect_right = ds.read(1)
    with rasterio.open(left) as ds:
        expected = resample(ds.read(1), pair.rectification.H_left, pair.rectification.size)
    np.testing.assert_array_equal(rect_left, expected)
    offset, n = estimate_row_offset(rect_left, rect_right, pair.disparity)
    assert abs(offset) < 0.05 and n > 50


def test_dem_heights_roi_and_no_pointing_correction(pair_files, tmp_path):
    left, right, rpc = pair_files
    lon0, lat0, lon1, lat1 = footprint_bounds(LEFT, (0, 0) + SIZE, H0)
    dem = tmp_path / "dem.tif"
    write_dem(dem, (lon0 - 0.01, lat1 + 0.01), "EPSG:4979", H0)
    out = tmp_path / "out"
    r = run(["rectify", "--rpc", left, left, right, rpc, "-o", out, "--dem", dem, "--roi", "20,30,150,120",
             "--no-pointing-correction", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    # the DEM's range under the ROI (flat: 500 m) +- 20 m
    assert s["heights"] == pytest.approx([480.0, 520.0], abs=1e-9)
    assert s["heights_from"] == "DEM dem.tif (ellipsoid) under the ROI +- 20 m"
    assert s["pointing_row_offset_px"] is None and s["pointing_tie_points"] == 0 and s["roi"] == [20, 30, 150, 120]
    pair = load_pairfile(out / "pair.yaml", accept_rpc=True)
    assert pair.rectification.info["right_rpc_shift_px"] == [0.0, 0.0]
    # without the correction the recorded right model is the file's (crop offset applied)
    assert pair.rpc_right.to_dict() == read_rpc(rpc).shifted(*CROP[:2]).to_dict()
    # the left ROI's corners lie inside the rectified frame
    cu, cv = apply_h(pair.rectification.H_left, np.array([20, 169, 20, 169]), np.array([30, 30, 149, 149]))
    assert cu.min() >= 0 and cv.min() >= 0 and cu.max() <= pair.width - 1 and cv.max() <= pair.height - 1
    # a DEM whose 2D CRS says nothing of its heights is read with --vertical
    dem2 = tmp_path / "dem2d.tif"
    write_dem(dem2, (lon0 - 0.01, lat1 + 0.01), "EPSG:4326", H0)
    r = run(["rectify", "--rpc", left, left, right, rpc, "-o", tmp_path / "out2", "--dem", dem2, "--vertical",
             "ellipsoid", "--no-pointing-correction", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["heights"] == pytest.approx([480.0, 520.0], abs=1e-9)


def write_dem(path, origin, crs, value, res=0.0005, n=60):
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs=crs,
                       transform=rasterio.transform.from_origin(*origin, res, res)) as ds:
        ds.write(np.full((1, n, n), value, np.float32))


def bad_cases(tmp):
    """(name, args after the four inputs or replacing them, expected message) for every bad input."""
    left, right, rpc = synthetic_pair(tmp / "in")
    lon0, lat0, lon1, lat1 = footprint_bounds(LEFT, (0, 0) + SIZE, H0)
    far = tmp / "far_dem.tif"
    write_dem(far, (lon0 + 0.1, lat1 + 0.1), "EPSG:4979", H0)
    flat2d = tmp / "dem2d.tif"
    write_dem(flat2d, (lon0 - 0.01, lat1 + 0.01), "EPSG:4326", H0)
    garbage = tmp / "garbage.txt"
    garbage.write_text("hello\n")
    away = tmp / "away.json"
    away_model = RIGHT_FULL.shifted(-5000.0, 0.0)
    away.write_text(json.dumps(away_model.to_dict()))
    _, _, x2, y2, _ = virtual_matches(LEFT, away_model.shifted(*CROP[:2]), (0, 0) + SIZE, (470.0, 530.0))
    fl, fr, frpc = synthetic_pair(tmp / "flat", flat=True)
    b = (lon0, lat0, lon1, lat1)        # the ROI's footprint at the model's mean height, which the DEM must cover
    with rasterio.open(far) as ds:
        fb = ds.bounds
    four = [left, left, right, rpc]
    h = ["--heights", "470,530"]
    return [
        ("missing RPC", [left, left, right, tmp / "nope.json", *h], f"{tmp / 'nope.json'}: file not found"),
        ("unreadable RPC", [left, left, right, garbage, *h],
         f"{garbage}: not an RPC file (no RPC tags, DIMAP, DigitalGlobe, RPB, OSSIM .geom, RPC00B text or rpcm JSON "
         "content)"),
        ("image without RPC", [left, left, right, right, *h],
         f"{right}: no RPC in this image (no RPC tags, no RPC sidecar file beside it)"),
        ("missing image", [tmp / "none.tif", left, right, rpc, *h], f"{tmp / 'none.tif'}: file not found"),
        ("no overlap", [left, left, right, away, *h],
         f"{right}: does not overlap the left image's ROI (its RPC sees the ROI's ground at cols "
         f"{x2.min():.0f}..{x2.max():.0f}, rows {y2.min():.0f}..{y2.max():.0f}, outside this 260x250 image)"),
        ("ROI outside", [*four, *h, "--roi", "200,0,100,100"],
         f"{left}: --roi 200,0,100,100 is outside the 240x240 image (it covers cols 200..299, rows 0..99)"),
        ("ROI negative", [*four, *h, "--roi", "-1,0,100,100"],
         f"{left}: --roi -1,0,100,100 is outside the 240x240 image (it covers cols -1..98, rows 0..99)"),
        ("ROI malformed", [*four, *h, "--roi", "1,2,3"],
         "--roi: expected COL,ROW,W,H (four integers, px), got '1,2,3'"),
        ("ROI tiny", [*four, *h, "--roi", "0,0,4,100"],
         "--roi: width and height must be at least 8 px, got '0,0,4,100'"),
        ("DEM not covering", [*four, "--dem", far],
         f"{far}: the DEM (lon {fb.left:.4f}..{fb.right:.4f}, lat {fb.bottom:.4f}..{fb.top:.4f}) does not cover the "
         f"region (lon {b[0]:.4f}..{b[2]:.4f}, lat {b[1]:.4f}..{b[3]:.4f})"),
        ("DEM datum unknown", [*four, "--dem", flat2d],
         f"{flat2d}: heights in an unknown vertical datum (the CRS WGS 84 is 2D): say whether they are ellipsoidal "
         "or e.g. EGM96 (EPSG:5773)"),
        ("--vertical unknown", [*four, *h, "--vertical", "EPSG:99999"],
         "--vertical: unknown vertical datum 'EPSG:99999'"),
        ("DEM --vertical not vertical", [*four, "--dem", flat2d, "--vertical", "EPSG:32631"],
         f"{flat2d}: 'EPSG:32631' is not a vertical CRS"),
        ("both heights", [*four, *h, "--dem", flat2d],
         "give the terrain's height range by one of --dem DEM, --heights LO,HI or --lidar CLOUD (or none: from tie "
         "points)"),
        ("heights reversed", [*four, "--heights", "530,470"], "--heights: LO must be below HI, got '530,470'"),
        ("heights not numbers", [*four, "--heights", "low,high"],
         "--heights: expected LO,HI (two finite heights, m), got 'low,high'"),
        ("pinhole option", [*four, *h, "--alpha", "1"], "--alpha does not apply with --rpc"),
        ("max pixels", [*four, *h, "--max-pixels", "1000"],
         "the rectified ROI would be 262x262 px, more than --max-pixels 1000"),
        ("no texture", [fl, fl, fr, frpc, *h],
         f"{fl}: too few features in the rectified images to estimate the RPC pointing error (with {fr}; "
         "--no-pointing-correction rectifies without it)"),
    ]


def test_every_bad_input_is_one_line_exit_1_nothing_written(tmp_path):
    cases = bad_cases(tmp_path)
    for name, args, message in cases:
        out = tmp_path / "out"
        r = run(["rectify", "--rpc", *args, "-o", out])
        assert (r.exit_code, r.output) == (1, f"riverbed: error: {message}\n"), name
        assert not out.exists(), name
    # an existing OUTDIR stays empty
    out = tmp_path / "existing"
    out.mkdir()
    r = run(["rectify", "--rpc", *cases[4][1], "-o", out])
    assert r.exit_code == 1 and list(out.iterdir()) == []


def test_rpc_options_need_rpc_and_outputs_are_not_overwritten(pair_files, tmp_path):
    left, right, rpc = pair_files
    r = run(["rectify", left, left, right, rpc, "-o", tmp_path / "o", "--roi", "0,0,50,50"])
    assert (r.exit_code, r.output) == (1, "riverbed: error: --roi needs --rpc\n")
    r = run(["rectify", left, left, right, rpc, "-o", tmp_path / "o", "--no-pointing-correction"])
    assert (r.exit_code, r.output) == (1, "riverbed: error: --no-pointing-correction needs --rpc\n")
    out = tmp_path / "out"
    args = ["rectify", "--rpc", left, left, right, rpc, "-o", out, "--heights", "470,530", "--no-pointing-correction"]
    assert run(args).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    r = run([*args, "--roi", "0,0,100,100"])
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {out / 'left.tif'}: output exists; pass --overwrite "
                                          "to replace it\n")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    r = run([*args, "--roi", "0,0,100,100", "--overwrite"])
    assert r.exit_code == 0 and load_pairfile(out / "pair.yaml", accept_rpc=True).roi == (0, 0, 100, 100)


def test_rpc_pair_files_refused_by_pinhole_commands_and_validated(pair_files, tmp_path):
    left, right, rpc = pair_files
    out = tmp_path / "out"
    assert run(["rectify", "--rpc", left, left, right, rpc, "-o", out, "--heights", "470,530",
                "--no-pointing-correction"]).exit_code == 0
    pf = out / "pair.yaml"
    # project and dsm take RPC pair files (tests/test_rpc_geometry.py): here they get past the pair file
    r = run(["project", tmp_path / "cloud.laz", pf, "-o", tmp_path / "sparse.tif"])
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {tmp_path / 'cloud.laz'}: file not found\n")
    r = run(["dsm", tmp_path / "disp.tif", pf, "-o", tmp_path / "dsm.tif"])
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {tmp_path / 'disp.tif'}: file not found\n")
    with pytest.raises(RiverbedError) as e:
        load_pairfile(pf)
    assert str(e.value) == f"{pf}: an RPC pair file: this use needs a pinhole pair file (P_left, P_right)"
    import yaml
    data = yaml.safe_load(pf.read_text())
    bad = tmp_path / "bad.yaml"
    cases = [
        (lambda d: d["rpc"]["right"].pop("LINE_OFF"), "rpc.right: not a complete RPC model: LINE_OFF missing"),
        (lambda d: d.update(extra=1), "unknown key 'extra' (RPC pair file keys: left, right, rpc, rectification, "
                                      "inputs)"),
        (lambda d: d["rectification"]["H_left"][2].__setitem__(0, 0.5),
         "rectification.H_left: not an invertible affinity (last row [0, 0, 1])"),
        (lambda d: d["rectification"].pop("roi"), "rectification.roi: missing"),
        (lambda d: d["rectification"].update(width=0), "rectification.width: expected a positive integer, got 0"),
        (lambda d: d["rpc"].pop("left"), "rpc: expected a mapping with the RPC models 'left' and 'right'"),
    ]
    for change, message in cases:
        d = json.loads(json.dumps(data))
        change(d)
        bad.write_text(yaml.safe_dump(d))
        with pytest.raises(RiverbedError) as e:
            load_pairfile(bad, accept_rpc=True)
        assert str(e.value) == f"{bad}: {message}"


def ventoux_rectify_args(shared_data, out):
    base = shared_data / VENTOUX / "rectification"
    hgt = shared_data / VENTOUX / "dtm/srtm_ventoux/srtm90_non_void_filled/N44E005.hgt"
    return hgt, ["rectify", "--rpc", base / "left_image.tif", base / "left_image.geom", base / "right_image.tif",
                 base / "right_image.geom", "-o", out, "--dem", hgt, "--json"]


def test_ventoux_without_the_egm96_grid_is_one_line(shared_data, tmp_path, no_egm96_grid):
    out = tmp_path / "out"
    hgt, args = ventoux_rectify_args(shared_data, out)
    r = run(args)
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {hgt}: heights are EGM96 height and PROJ's grid "
                                          "us_nga_egm96_15.tif is not available offline (install Debian's proj-data, "
                                          "or point PROJ_DATA at a folder with it)\n")
    assert not out.exists()


def test_ventoux_crops_rectified_read_back_and_matched(shared_data, tmp_path, egm96):
    from bench_rpc_rectify import sift_parallax

    out = tmp_path / "out"
    _, args = ventoux_rectify_args(shared_data, out)
    r = run(args)
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["crop_offsets"] == [[5000.0, 5000.0], [4915.0, 5162.0]]
    assert (s["width"], s["height"]) == (613, 614)
    # the library's figures (benchmarks/bench_rpc_rectify.py's committed results, docs/rpc.md's table), to their
    # last digit: the same computation
    rect = json.loads((Path(__file__).resolve().parents[1] / "benchmarks" / "results_rpc_rectify.json").read_text())
    assert s["heights"] == pytest.approx(rect["heights"], abs=1e-6)
    assert s["disparity"] == pytest.approx(rect["disparity"], abs=1e-6)
    assert s["pointing_row_offset_px"] == pytest.approx(rect["pointing_row_offset_px"], abs=1e-6)
    assert s["pointing_tie_points"] == rect["orb_tie_points"]
    assert s["virtual_row_residual_max_px"] < 0.01  # on the command's own 21 x 21 x 7 grid
    pair = load_pairfile(out / "pair.yaml", accept_rpc=True)
    assert pair.image_size == (614, 613) and pair.roi == (0, 0, 500, 500)
    # virtual ground points (left crop x heights in the range) project to equal rows through the recorded models
    rng = np.random.default_rng(0)
    c, rw = rng.uniform(0, 499, (2, 2000))
    hh = rng.uniform(*pair.heights, 2000)
    lon, lat = pair.rpc_left.localize(c, rw, hh)
    xl, yl, xr, yr = pair.project(lon, lat, hh)
    assert np.max(np.abs(yl - yr)) < 0.05
    assert pair.disparity[0] <= (xl - xr).min() and (xl - xr).max() <= pair.disparity[1]
    # the written images share their rows: independent SIFT tie points refined by Lucas-Kanade
    with rasterio.open(out / "left.tif") as ds:
        rl = ds.read(1)
    with rasterio.open(out / "right.tif") as ds:
        rr = ds.read(1)
    assert rl.dtype == rr.dtype == np.uint16
    sift = sift_parallax(rl, rr, *pair.disparity, lk=True)
    assert sift["matches"] > 300 and sift["dy_median_abs"] < 0.2 and sift["dy_p95_abs"] < 0.5
    assert sift == pytest.approx(rect["sift_lk"], rel=1e-6)  # the written images are the library's
    # riverbed match takes the rectified pair with the pair file's disparity range (--pair): it agrees with SIFT's
    # disparities
    disp = tmp_path / "disp.tif"
    r = run(["match", out / "left.tif", out / "right.tif", "--pair", out / "pair.yaml", "-o", disp, "--json"])
    assert r.exit_code == 0, r.output
    got = json.loads(r.stdout)
    assert [got["d_min"], got["d_max"]] == [int(np.floor(pair.disparity[0])), int(np.ceil(pair.disparity[1]))]
    from riverbed_cli.io.disparity import read_disparity

    d = read_disparity(disp)
    a, b = (cv2.SIFT_create().detectAndCompute(cv2.normalize(im, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8),
                                               None) for im in (rl, rr))
    good = [m for m, m2 in (p for p in cv2.BFMatcher().knnMatch(a[1], b[1], k=2) if len(p) == 2)
            if m.distance < 0.75 * m2.distance]
    pa = np.array([a[0][m.queryIdx].pt for m in good])
    pb = np.array([b[0][m.trainIdx].pt for m in good])
    ok = np.abs(pa[:, 1] - pb[:, 1]) < 1
    err = d[np.round(pa[ok, 1]).astype(int), np.round(pa[ok, 0]).astype(int)] - (pa[ok, 0] - pb[ok, 0])
    assert ok.sum() > 300 and np.median(np.abs(err)) < 0.5 and np.mean(np.abs(err) < 1) > 0.9


def test_without_a_height_source_the_range_comes_from_tie_points(pair_files, tmp_path):
    """No --dem, --heights nor --lidar: the pair rectified over the model's height domain, its tie points' disparity
    range turned into heights (+- 20 m) holds the flat terrain, far inside the domain."""
    left, right, rpc = pair_files
    r = run(["rectify", "--rpc", left, left, right, rpc, "-o", tmp_path / "out", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["heights_from"].startswith("tie points (") and s["heights_from"].endswith(" over the RPCs' height "
                                                                                      "domain) +- 20 m")
    lo, hi = s["heights"]
    domain = LEFT.height_off - LEFT.height_scale, LEFT.height_off + LEFT.height_scale
    assert lo < H0 - 20 and H0 + 20 < hi and hi - lo < 0.25 * (domain[1] - domain[0])
    # textureless images show no height range
    flat = synthetic_pair(tmp_path / "flat", flat=True)
    r = run(["rectify", "--rpc", flat[0], flat[0], flat[1], flat[2], "-o", tmp_path / "none"])
    assert (r.exit_code, r.output) == (1, "riverbed: error: 0 tie points between the images: too few to find the "
                                          "terrain's height range; give --dem, --heights or --lidar\n")
    assert not (tmp_path / "none").exists()


def test_ventoux_from_tie_points_alone_gives_the_dsm_the_dem_gives(shared_data, tmp_path, egm96):
    """The real Pleiades crops rectified without a DEM (the height range from tie points: 465.5..600.7 m around the
    SRTM's 472.2..577.6), matched over the pair file's range (--pair) and triangulated: the DSM is the one the SRTM
    route gives (measured: median 0.011 m, NMAD 0.21 m apart)."""
    hgt, args = ventoux_rectify_args(shared_data, tmp_path / "dem")
    base = args[:args.index("-o")]
    dsms = []
    for name, extra in (("tie", []), ("dem", ["--dem", hgt])):
        out = tmp_path / name
        r = run([*base, "-o", out, "--json", *extra])
        assert r.exit_code == 0, r.output
        s = json.loads(r.output)
        if name == "tie":
            assert s["heights_from"].startswith("tie points (")
            assert s["heights"] == pytest.approx([465.5, 600.7], abs=1.0)
        for step in (["match", out / "left.tif", out / "right.tif", "--pair", out / "pair.yaml", "-o", out / "d.tif"],
                     ["dsm", out / "d.tif", out / "pair.yaml", "-o", out / "dsm.tif", "--resolution", "1"]):
            r = run(step)
            assert r.exit_code == 0, r.output
        dsms.append(out / "dsm.tif")
    e = json.loads(run(["evaluate", "--dsm", *dsms, "--json"]).stdout)
    assert abs(e["median"]) < 0.05 and e["nmad"] < 0.25 and e["completeness"] > 99
