"""The synthetic aerial block (``riverbed sample``): determinism, exact geometry, file formats, LiDAR, and that
LiDAR guidance pays on it."""

import json
import math
import subprocess
import warnings
from pathlib import Path

import laspy
import numpy as np
import pytest
import rasterio

from gates import assert_catches, assert_within, off_gate
from riverbed_cli import sample as S
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.geometry.pairfile import load_pairfile
from conftest import PYTHON

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "block"
COMMAND = "riverbed sample sample_data/block --size small --seed 0"


@pytest.fixture(scope="module")
def block():
    """The small block, generated in memory (seed 0)."""
    return S.make_block("small", 0)


@pytest.fixture(scope="module")
def written(block, tmp_path_factory):
    """The same block written to a temporary folder, with the committed copy's command line in its manifest."""
    out = tmp_path_factory.mktemp("sample") / "block"
    S.write_block(block, out, command=COMMAND)
    return out


@pytest.fixture(scope="module")
def pair(written):
    return load_pairfile(written / "pair.yaml")


# -- determinism ------------------------------------------------------------------------------------------------------
def _las_arrays(path):
    las = laspy.read(path)
    dims = ("X", "Y", "Z", "intensity", "return_number", "number_of_returns", "classification", "scan_angle",
            "point_source_id", "gps_time", "red", "green", "blue")
    return las.header, {d: np.asarray(las[d]) for d in dims}


def test_regenerates_the_committed_copy(written):
    """Regenerating ``sample_data/block`` gives the committed files: text and images exactly, rasters and point
    records array for array."""
    assert sorted(p.name for p in SAMPLE.iterdir()) == sorted(S.FILES)
    for name in ("pair.yaml", "scene.json", "MANIFEST.md"):
        assert (written / name).read_text() == (SAMPLE / name).read_text(), name
    for name in ("left.png", "right.png"):
        np.testing.assert_array_equal(read_image(written / name), read_image(SAMPLE / name), err_msg=name)
    for name in ("gt_disparity.tif", "gt_dsm.tif"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(written / name) as a, rasterio.open(SAMPLE / name) as b:
                assert (a.crs, a.transform, a.nodata is None or np.isnan(a.nodata) or a.nodata) == \
                    (b.crs, b.transform, b.nodata is None or np.isnan(b.nodata) or b.nodata), name
                np.testing.assert_array_equal(a.read(1), b.read(1), err_msg=name)
    for name in ("lidar.laz", "lidar_earlier.laz"):
        ha, a = _las_arrays(written / name)
        hb, b = _las_arrays(SAMPLE / name)
        assert (ha.point_count, list(ha.offsets), list(ha.scales)) == \
            (hb.point_count, list(hb.offsets), list(hb.scales)), name
        for dim in a:
            np.testing.assert_array_equal(a[dim], b[dim], err_msg=f"{name} {dim}")


def test_seed_changes_the_scene():
    s0, s1 = S.build_scene("small", 0), S.build_scene("small", 1)
    assert s0.height.shape == s1.height.shape
    assert np.abs(s0.height - s1.height).mean() > 0.5  # other terrain, other houses


# -- geometry ---------------------------------------------------------------------------------------------------------
def test_pair_file_is_an_exactly_rectified_pair(block, pair):
    assert pair.exactly_rectified
    assert pair.crs == "EPSG:32632"
    np.testing.assert_array_equal(pair.origin, S.ORIGIN)
    assert (pair.width, pair.height) == (720, 540)
    np.testing.assert_array_equal(pair.P_left, block.P_left)
    np.testing.assert_array_equal(pair.P_right, block.P_right)
    # The cameras that rendered the images are the pair's cameras.
    for cam, P in ((block.left_cam, pair.P_left), (block.right_cam, pair.P_right)):
        np.testing.assert_allclose(cam.P, P, rtol=0, atol=1e-10 * np.abs(P).max())
    assert pair.baseline == pytest.approx(block.spec.baseline, abs=1e-9)
    assert pair.focal == pytest.approx(block.spec.focal, rel=1e-12)
    # Realistic aerial numbers: flying height 300-800 m, GSD 0.1-0.3 m, a UTM origin.
    depth = pair.project(block.hits_left.reshape(-1, 3)[::97])[3]
    assert 300 < np.median(depth) < 800
    assert 0.1 < np.median(depth) / pair.focal < 0.3
    assert 400_000 < pair.origin[0] < 600_000 and 4_000_000 < pair.origin[1] < 6_000_000


def test_hit_points_reproject_to_pixel_centres_and_gt_disparity(block, pair):
    H, W = block.gt_disparity.shape
    X = block.hits_left.reshape(-1, 3)
    assert np.isfinite(X).all()  # every pixel sees the scene
    rows, cols = np.divmod(np.arange(H * W), W)
    xl, yl, xr, depth = pair.project(X)
    assert np.abs(xl - cols).max() < 1e-6
    assert np.abs(yl - rows).max() < 1e-6
    d = block.gt_disparity.ravel()
    v = np.isfinite(d)
    assert np.abs((xl - xr)[v] - d[v]).max() < 1e-6
    assert (depth > 0).all()


def test_triangulating_gt_disparity_gives_the_hit_points(block, pair, written):
    H, W = block.gt_disparity.shape
    X = block.hits_left.reshape(-1, 3)
    rows, cols = np.divmod(np.arange(H * W), W)
    d = block.gt_disparity.ravel()
    v = np.isfinite(d)
    T = pair.triangulate(cols[v], rows[v], d[v])
    assert np.abs(T - X[v]).max() < 1e-6
    # From the float32 file: the error is the float32 rounding of d (~2e-6 px) times dZ/dd (~1.3 m/px).
    stored = read_disparity(written / "gt_disparity.tif").ravel()
    np.testing.assert_array_equal(np.isfinite(stored), v)
    T32 = pair.triangulate(cols[v], rows[v], stored[v])
    assert np.abs(T32 - X[v]).max() < 1e-5


def test_hit_points_lie_on_the_surface(block):
    X = block.hits_left.reshape(-1, 3)
    dz = np.abs(S.surface_height(block.scene, X[:, 0], X[:, 1]) - X[:, 2])
    assert np.percentile(dz, 99.9) < 1e-9
    assert dz.max() < 1e-4  # walls: steep cells turn tiny horizontal rounding into a little height


def test_gt_visibility_matches_rays_from_the_right_camera(block):
    """Cast rays through the right-image positions of left surface points: visible points are hit again (to 1 mm),
    occluded ones lie behind a nearer surface. Also: occlusions exist (walls) and are a few percent at most."""
    rng = np.random.default_rng(0)
    d = block.gt_disparity
    cam = block.right_cam
    Kinv = np.linalg.inv(cam.K)
    for mask, visible in ((np.isfinite(d), True), (block.occluded, False)):
        r, c = np.nonzero(mask)
        pick = rng.choice(len(r), min(3000, len(r)), replace=False)
        r, c = r[pick], c[pick]
        X = block.hits_left[r, c]
        xr, yr, _ = cam.project(X)
        ray = np.stack([xr, yr, np.ones_like(xr)], axis=1) @ Kinv.T @ cam.R
        ray /= np.linalg.norm(ray, axis=1)[:, None]
        t = S.cast_rays(block.scene, np.broadcast_to(cam.C, ray.shape), ray)
        dist = np.linalg.norm(X - cam.C, axis=1)
        if visible:
            assert np.abs(t - dist).max() < 1e-3
        else:
            assert (t < dist - 1e-3).all()
    assert 0.005 < block.occluded.mean() < 0.05
    assert np.nanmin(d) > 0 and np.nanmax(d) - np.nanmin(d) > 10


def test_any_frame_camera_renders_exactly(block):
    """A window of a raw, tilted frame (issue 5's rectification input) has exact geometry too."""
    img, cam, hits = S.render_frame(block, 2, window=(500, 300, 48, 32))
    assert img.shape == (32, 48, 3) and img.dtype == np.uint8
    assert abs(block.frames[2][1][0]) + abs(block.frames[2][1][1]) > 0  # not an ideal nadir attitude
    x, y, _ = cam.project(hits.reshape(-1, 3))
    rows, cols = np.divmod(np.arange(32 * 48), 48)
    assert np.abs(x - cols).max() < 1e-6 and np.abs(y - rows).max() < 1e-6


# -- files ------------------------------------------------------------------------------------------------------------
def test_laz_reads_back_with_crs_classes_and_scan_pattern(written, block):
    las = laspy.read(written / "lidar.laz")
    h = las.header
    assert h.parse_crs().to_epsg() == 32632
    assert (h.version.major, h.version.minor, h.point_format.id) == (1, 4, 7)
    np.testing.assert_array_equal(h.scales, [0.001, 0.001, 0.001])
    assert h.offsets[0] % 1000 == 0 and h.offsets[1] % 1000 == 0 and h.offsets[0] >= 500_000
    xyz = np.stack([las.x, las.y, las.z], axis=1)
    np.testing.assert_allclose(xyz, block.lidar["xyz"] + S.ORIGIN, atol=0.0006)  # within the LAS scale
    cls = np.asarray(las.classification)
    counts = {int(c): int(n) for c, n in zip(*np.unique(cls, return_counts=True))}
    assert set(counts) <= {1, 2, 5, 6, 7, 9} and {2, 5, 6} <= set(counts)
    n = len(cls)
    assert 5 <= counts.get(7, 0) <= 0.002 * n  # a few noise points
    assert 0 < counts.get(9, 0) < 0.002 * n  # water: few returns
    assert np.unique(np.asarray(las.point_source_id)).size >= 2  # a few strips
    assert np.asarray(las.red).max() > 255  # 16-bit colour from the orthophoto
    # Zig-zag: the scan angle sweeps back and forth, many times.
    ang = np.asarray(las.scan_angle)[np.asarray(las.point_source_id) == 1].astype(float)
    turns = np.count_nonzero(np.diff(np.sign(np.diff(ang))) != 0)
    assert turns > 100
    # Range noise of 3-5 cm: first-return ground points against the surface (robust spread).
    local = xyz - S.ORIGIN
    ground = (cls == 2) & (np.asarray(las.return_number) == 1)
    dz = local[ground, 2] - S.surface_height(block.scene, local[ground, 0], local[ground, 1])
    dz = dz[np.isfinite(dz)]  # noise may push a point at the scene's edge just outside it
    nmad = 1.4826 * np.median(np.abs(dz - np.median(dz)))
    assert 0.03 < nmad < 0.05
    # Outliers exist: unclassified points far above or below the surface (birds, multipath).
    un = cls == 1
    dz1 = local[un, 2] - S.surface_height(block.scene, local[un, 0], local[un, 1])
    assert np.count_nonzero(np.abs(dz1) > 3) >= 5


def test_lidar_gaps_on_water_and_dark_roofs(block):
    lid = block.lidar
    mats = S.materials_at(block.scene, lid["xyz"])
    first = (lid["return_number"] == 1) & (lid["kind"] == 0)
    area = np.bincount(block.scene.material.ravel(), minlength=11) * block.scene.cell**2
    density = np.bincount(mats[first], minlength=11) / np.maximum(area, 1e-9)
    assert density[S.WATER] < 0.1 * density[S.GRASS]
    assert density[S.TAR] < 0.5 * density[S.ROOF]


def test_gt_dsm_georeference_and_values(written, block):
    with rasterio.open(written / "gt_dsm.tif") as ds:
        assert ds.crs.to_epsg() == 32632
        t = ds.transform
        assert t.b == 0 and t.d == 0 and t.a == pytest.approx(0.2) and t.e == pytest.approx(-0.2)  # north-up
        assert ds.nodata == S.NODATA
        assert ds.overviews(1)
        dsm = ds.read(1)
        rows, cols = np.nonzero(dsm != ds.nodata)
        xs, ys = rasterio.transform.xy(t, rows, cols, offset="center")
    ox, oy, oz = S.ORIGIN
    xs, ys = np.asarray(xs) - ox, np.asarray(ys) - oy
    assert 0.2 < (dsm == S.NODATA).mean() < 0.6  # the rotated footprint inside its bounding box
    np.testing.assert_allclose(dsm[rows, cols], S.surface_height(block.scene, xs, ys) + oz, atol=1e-4)
    # Against the camera geometry: left-pixel surface points within 2 cm of a cell centre, on gentle surfaces.
    X = block.hits_left.reshape(-1, 3)
    fc = (X[:, 0] + ox - t.c) / t.a - 0.5
    fr = (X[:, 1] + oy - t.f) / t.e - 0.5
    near = (np.abs(fc - np.round(fc)) < 0.1) & (np.abs(fr - np.round(fr)) < 0.1)
    r, c = np.round(fr[near]).astype(int), np.round(fc[near]).astype(int)
    dz = dsm[r, c] - (X[near, 2] + oz)
    assert near.sum() > 1000
    assert np.median(np.abs(dz)) < 0.01 and np.mean(np.abs(dz) < 0.05) > 0.95


def test_scene_json_describes_cameras_sun_and_grid(written, block):
    desc = json.loads((written / "scene.json").read_text())
    assert desc["seed"] == 0 and desc["crs"] == "EPSG:32632"
    assert len(desc["frames"]) == 3
    for f, (cam, _) in zip(desc["frames"], block.frames):
        np.testing.assert_allclose(f["centre"], cam.C + S.ORIGIN)
        R = np.array(f["R"])
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    # 60 % along-track overlap: consecutive centres one baseline apart.
    c = np.array([f["centre"] for f in desc["frames"]])
    assert np.linalg.norm(c[1] - c[0]) == pytest.approx(0.4 * 1200 * 0.2)
    assert desc["sun"]["elevation_deg"] == S.SUN_ELEVATION
    assert desc["dsm"]["nodata"] == S.NODATA and desc["dsm"]["resolution_m"] == 0.2


# -- LiDAR density and guidance ---------------------------------------------------------------------------------------
def test_lidar_density_is_1_to_5_percent_of_image_pixels(written, pair):
    las = laspy.read(written / "lidar.laz")
    keep = (np.asarray(las.return_number) == 1) & ~np.isin(np.asarray(las.classification), (7, 18))
    xyz = np.stack([las.x, las.y, las.z], axis=1)[keep] - pair.origin
    xl, yl, _, _ = pair.project(xyz)
    inside = (np.round(xl) >= 0) & (np.round(xl) < 720) & (np.round(yl) >= 0) & (np.round(yl) < 540)
    share = inside.sum() / (720 * 540)
    assert 0.01 <= share <= 0.05


#: Measured with the current code (seed 0, 2 cores, LiDAR projected with HPR visibility, the LiDAR check on): bad1 %,
#: bad3 %, avg px over the 365352 GT pixels without LiDAR, per (guide, fusion).
GUIDANCE = {
    ("none", "none"): {"bad1": 16.602, "bad3": 6.868, "avg": 0.8239},
    ("riverbed", "confidence"): {"bad1": 4.680, "bad3": 1.726, "avg": 0.2446},
    ("riverbed", "none"): {"bad1": 4.879, "bad3": 1.741, "avg": 0.2597},
}


@pytest.fixture(scope="module")
def matched(written, pair):
    from riverbed_cli.geometry.projection import project_cloud
    from riverbed_cli.matching.pipeline import match_pair
    from riverbed_cli.products.evaluate import evaluate_disparity

    sparse, _ = project_cloud(written / "lidar.laz", pair, visibility="hpr")
    gt = read_disparity(written / "gt_disparity.tif")
    left, right = read_image(written / "left.png"), read_image(written / "right.png")
    out = {"sparse": sparse, "gt": gt}
    for guide, fusion in GUIDANCE:
        r = match_pair(left, right, sparse, guide=guide, **({} if fusion == "confidence" else {"fusion": fusion}))
        assert r.info.fusion == fusion  # riverbed's default: the confidence fusion
        out[guide, fusion] = evaluate_disparity(r.disparity, gt, exclude=sparse)
    return out


def test_projected_lidar_agrees_with_gt(matched):
    sparse, gt = matched["sparse"], matched["gt"]
    m = np.isfinite(sparse) & np.isfinite(gt)
    err = np.abs(sparse[m] - gt[m])
    assert m.sum() > 5000
    assert np.median(err) < 0.05  # 4 cm range noise is ~0.03 px of disparity
    assert np.mean(err > 1) < 0.05


def test_guidance_gates_catch_a_5_percent_regression():
    assert_catches(GUIDANCE)


def test_the_guidance_gates_catch_a_real_regression(written, pair, matched):
    """Not only arithmetic: riverbed run with a worse setting (a 5 px window instead of the auto one: measured bad3
    2.04 against 1.73 %) falls outside the committed gates; the default (the fixture's run) is inside them."""
    from riverbed_cli.matching.pipeline import match_pair
    from riverbed_cli.products.evaluate import evaluate_disparity

    case = ("riverbed", "confidence")
    assert off_gate({case: matched[case]}, {case: GUIDANCE[case]}) == []
    left, right = read_image(written / "left.png"), read_image(written / "right.png")
    r = match_pair(left, right, matched["sparse"], guide="riverbed", window=5)
    worse = evaluate_disparity(r.disparity, matched["gt"], exclude=matched["sparse"])
    assert off_gate({case: worse}, {case: GUIDANCE[case]})


def test_plain_sgm_struggles_and_guidance_pays(matched):
    """Plain SGM really struggles (shadows, water, solar panels, walls); riverbed guidance cuts bad3 by 4x, with
    the confidence fusion (the default) and without it. Each figure within 2 % of its measurement (tests/gates.py)."""
    got = {case: matched[case] for case in GUIDANCE}
    assert_within(got, GUIDANCE)
    # plain SGM leaves the left edge, where a match may lie outside the right image, invalid; guided, the LiDAR covers it
    assert all(m["n"] == 365352 for m in got.values())
    assert {c: round(m["density"], 3) for c, m in got.items()} == {
        ("none", "none"): 99.428, ("riverbed", "confidence"): 100.0, ("riverbed", "none"): 100.0}


# -- command line -----------------------------------------------------------------------------------------------------
def test_cli_refuses_to_overwrite_and_missing_parent(written, tmp_path):
    from click.testing import CliRunner

    from riverbed_cli.cli.main import cli

    runner = CliRunner()
    r = runner.invoke(cli, ["sample", str(written)])
    assert r.exit_code == 1 and "exists; pass --overwrite" in r.output
    r = runner.invoke(cli, ["sample", str(tmp_path / "missing" / "block")])
    assert r.exit_code == 1 and "does not exist" in r.output
    assert not (tmp_path / "missing").exists()
    r = runner.invoke(cli, ["sample", str(tmp_path / "x"), "--size", "huge"])
    assert r.exit_code == 1  # a usage error: one line, exit code 1


def test_python_m_sample_writes_the_block(tmp_path):
    out = tmp_path / "blk"
    p = subprocess.run([*PYTHON, "-m", "riverbed_cli.sample", str(out), "--json"], capture_output=True,
                       text=True, timeout=600, check=False)
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    assert set(summary["files"]) == set(S.FILES)
    assert summary["crs"] == "EPSG:32632" and summary["image"] == [720, 540]
    assert math.isclose(summary["gsd_m"], 0.2)
    np.testing.assert_array_equal(read_image(out / "left.png"), read_image(SAMPLE / "left.png"))
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary folder left behind
