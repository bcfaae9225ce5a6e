"""``riverbed pair`` and ``riverbed project`` end to end: the exact round trip on real Middlebury geometry.

The scene: Middlebury 2003 Cones (quarter size, tests/data/cones) with a made-up but plausible calibration.
Cones comes without one; Middlebury's notes for its 2005/2006 sets give f ~ 3740 px at full size and a 160 mm
baseline, so the test writes a Middlebury 2014 style calib.txt for the full-size frame (1800 x 1500, f = 3740
px, principal point at the image centre, doffs = 100 px) and imports it with ``--scale 0.25``: f = 935 px,
doffs = 25 px, depths Z = f B / (d + doffs) = 149.6 / (d + 25) between 1.9 m and 4.4 m.

Points are triangulated from the ground-truth disparities, moved into a world frame (the camera looks down
from (500123.4, 5000456.7, 305.0) in a UTM-like frame, heading 30 deg, 5 deg tilt; origin 500000, 5000000,
300) and then into a LiDAR frame that differs from the world by a rotation (0.8 deg about z, 0.3 deg about x)
and a translation; the pair file carries that registration. LAS coordinates are stored with a 0.0001 m scale:
the largest disparity error it can cause is |dd/dZ| * dZ = f B / Z^2 * sqrt(3) * 0.00005 m
= 149.6 / 1.87^2 * 8.7e-5 = 0.0037 px (a 0.001 m scale would give 0.037 px, too coarse for the 0.01 px
check; measured: 0.0020 px). Pixel positions move by at most f / Z * 8.7e-5 = 0.04 px, so each point stays in
its pixel (the jitter is at most 0.25 px).
"""

import functools
import json
import math
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.io.disparity import read_disparity, read_disparity_tags
from riverbed_cli.geometry.pairfile import load_pairfile, write_pairfile

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_visibility as bv  # noqa: E402

@functools.cache
def round_trips():
    """The round trip's committed figures by options (benchmarks/results_visibility.json, docs/projection.md), read
    once when a test asks: the benchmark imports this module to build the scene before the file exists."""
    rows = json.loads((Path(__file__).resolve().parents[1] / "benchmarks" / "results_visibility.json").read_text())
    return {r["options"]: r for r in rows if r["scene"] == "Cones round trip"}


def round_trip(options):
    return round_trips()[options]


def assert_round_trip(m, options):
    """The projection is deterministic: the command's figures are the library's to 1e-6."""
    want = round_trip(options)
    assert {k: m[k] for k in bv.REQUIRED} == pytest.approx({k: want[k] for k in bv.REQUIRED}, abs=1e-6), options


CALIB = """cam0=[3740 0 899.5; 0 3740 749.5; 0 0 1]
cam1=[3740 0 999.5; 0 3740 749.5; 0 0 1]
doffs=100
baseline=160
width=1800
height=1500
ndisp=290
isint=0
vmin=37
vmax=220
"""
ORIGIN = np.array([500000.0, 5000000.0, 300.0])
CAMERA = np.array([500123.4, 5000456.7, 305.0])


def run(args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def rot(axis, deg):
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def right_occluded(gt, tol=0.5):
    """Left pixels whose point is hidden in the right view (dense GT: ordering violated by a nearer pixel)."""
    W = gt.shape[1]
    xr = np.where(np.isfinite(gt), np.arange(W)[None, :] - gt, np.inf)
    # Smallest right-image x of the pixels strictly to the right, per row.
    suffix = np.minimum.accumulate(xr[:, ::-1], axis=1)[:, ::-1]
    after = np.full_like(suffix, np.inf)
    after[:, :-1] = suffix[:, 1:]
    return np.isfinite(gt) & (after < xr - tol)


def write_las(path, xyz, classes, scale=0.0001):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = classes.astype(np.uint8)
    las.write(str(path))


def build_scene(folder, gt, share=0.1, hidden_share=0.2, n_outliers=300, seed=7):
    """Write calib.txt, pair files and scene.las into ``folder``; return what the test needs to check.

    Visible points: a random ``share`` of the GT pixels, jittered by up to 0.25 px, on the GT surface. Hidden
    points: behind the GT surface (depth x 1.1 .. 1.6) at a random ``hidden_share`` of the other GT pixels,
    and one behind every tenth visible point on its own ray. Outliers: isolated points 0.6 to 3 m above the
    surface (on the view rays, 30 to 70 % of the way from the surface to the camera). Also noise-class points
    (class 7), points behind the camera (above it) and points outside the image.
    """
    rng = np.random.default_rng(seed)
    (folder / "calib.txt").write_text(CALIB)
    r = run(["pair", "middlebury", folder / "calib.txt", "-o", folder / "cam.yaml", "--scale", "0.25",
             "--left", "tests/data/cones/im2.png", "--right", "tests/data/cones/im6.png"])
    assert r.exit_code == 0, r.output
    cam = load_pairfile(folder / "cam.yaml")
    H, W = gt.shape
    assert cam.image_size == (H, W) and abs(cam.focal - 935) < 1e-12

    # Camera -> world (local, origin subtracted): looking down, heading 30 deg, tilted 5 deg.
    R_wc = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])  # camera x east, y south, z down
    R_wc = rot(2, 30) @ R_wc @ rot(0, 5)
    c_local = CAMERA - ORIGIN
    T_cw = np.eye(4)  # local world -> camera
    T_cw[:3, :3] = R_wc.T
    T_cw[:3, 3] = -R_wc.T @ c_local
    reg = np.eye(4)  # LiDAR -> world
    reg[:3, :3] = rot(2, 0.8) @ rot(0, 0.3)
    reg[:3, 3] = ORIGIN - reg[:3, :3] @ (ORIGIN + np.array([12.3, -45.6, 1.2]))
    pair = cam.replace(P_left=cam.P_left @ T_cw, P_right=cam.P_right @ T_cw, origin=ORIGIN, registration=reg,
                       crs="EPSG:32632")
    write_pairfile(folder / "pair.yaml", pair)

    def to_lidar(cam_xyz):
        local = cam_xyz @ R_wc.T + c_local
        world = local + ORIGIN
        return (world - reg[:3, 3]) @ np.linalg.inv(reg[:3, :3]).T

    rows, cols = np.nonzero(np.isfinite(gt))
    pick = rng.random(rows.size)
    vis = pick < share
    hid = (pick >= share) & (pick < share + hidden_share)
    vr, vc = rows[vis], cols[vis]
    jit = rng.uniform(-0.25, 0.25, (2, vr.size))
    visible = cam.triangulate(vc + jit[0], vr + jit[1], gt[vr, vc])

    hr, hc = rows[hid], cols[hid]
    ray_r, ray_c = vr[::10], vc[::10]
    hr, hc = np.concatenate([hr, ray_r]), np.concatenate([hc, ray_c])
    surface = cam.triangulate(hc.astype(float), hr.astype(float), gt[hr, hc])
    hidden = surface * rng.uniform(1.1, 1.6, hr.size)[:, None]  # same ray, farther: behind the surface

    orr, occ_ = rng.integers(0, H, n_outliers), rng.integers(0, W, n_outliers)
    ok = np.isfinite(gt[orr, occ_])
    orr, occ_ = orr[ok], occ_[ok]
    up = cam.triangulate(occ_.astype(float), orr.astype(float), gt[orr, occ_])
    outliers = up * rng.uniform(0.3, 0.7, orr.size)[:, None]  # on the view ray, 30-70 % of the way up

    noise = visible[:50] * 0.9
    behind = np.column_stack([rng.uniform(-1, 1, 40), rng.uniform(-1, 1, 40), rng.uniform(-3, -0.5, 40)])
    outside = np.column_stack([rng.uniform(5, 8, 40), rng.uniform(-1, 1, 40), rng.uniform(2, 3, 40)])
    parts = [(visible, 2), (hidden, 2), (outliers, 1), (noise, 7), (behind, 1), (outside, 1)]
    xyz = np.vstack([to_lidar(p) for p, _ in parts])
    classes = np.concatenate([np.full(len(p), c) for p, c in parts])
    order = rng.permutation(len(xyz))  # interleave everything across chunks
    write_las(folder / "scene.las", xyz[order], classes[order])
    # Visible in both views: not hidden in the right view, and inside the right image.
    expected_visible = ~right_occluded(gt)[vr, vc] & (vc + jit[0] - gt[vr, vc] >= -0.5)
    return {"visible_rc": (vr, vc), "expected_visible": expected_visible, "n_hidden": hr.size,
            "hidden_rc": (hr, hc), "n_outliers": orr.size, "outlier_rc": (orr, occ_), "n_noise": 50,
            "n_behind": 40, "n_outside": 40, "n_points": len(xyz), "pair": pair}


@pytest.fixture(scope="module")
def scene(tmp_path_factory, cones):
    folder = tmp_path_factory.mktemp("scene")
    return folder, build_scene(folder, cones[2]), cones[2]


def score(sparse, gt, sc):
    """Round-trip figures of a sparse map against the scene."""
    vr, vc = sc["visible_rc"]
    exp = sc["expected_visible"]
    got = np.isfinite(sparse[vr, vc])
    err = np.abs(sparse[vr, vc][got] - gt[vr, vc][got])
    kept_pixels = np.isfinite(sparse)
    on_visible = np.zeros_like(kept_pixels)
    on_visible[vr, vc] = True
    hr, hc = sc["hidden_rc"]
    # A hidden point survives if its pixel holds a disparity that is not the visible sample's (or no sample).
    hidden_left = np.isfinite(sparse[hr, hc]) & ~(on_visible[hr, hc]
                                                   & (np.abs(sparse[hr, hc] - gt[hr, hc]) <= 0.01))
    orr, occ_ = sc["outlier_rc"]
    out_left = np.isfinite(sparse[orr, occ_]) & (np.abs(sparse[orr, occ_] - gt[orr, occ_]) > 0.5)
    return {
        "max_error": float(err.max()) if err.size else None,
        "visible_kept": float((got & exp).sum() / exp.sum()),
        "right_occluded_removed": float((~got & ~exp).sum() / max((~exp).sum(), 1)),
        "wrongly_kept": int((got & ~exp).sum()),
        "hidden_removed": 1.0 - float(hidden_left.sum() / sc["n_hidden"]),
        "outliers_removed": 1.0 - float(out_left.sum() / max(sc["n_outliers"], 1)),
        "stray_pixels": int((kept_pixels & ~on_visible).sum()),
    }


def test_round_trip_exact_hidden_and_outliers_removed(scene):
    folder, sc, gt = scene
    out = folder / "sparse.tif"
    r = run(["project", folder / "scene.las", folder / "pair.yaml", "-o", out, "--json", "--overwrite"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    sparse = read_disparity(out)
    m = score(sparse, gt, sc)
    assert_round_trip(m, "defaults")
    for key, (bound, how) in bv.REQUIRED.items():  # the doc's "required" row
        assert m[key] <= bound if how == "max" else m[key] >= bound, (key, m[key])
    # Counts: every point read is accounted for once.
    assert s["points_read"] == sc["n_points"]
    assert s["filtered"]["class"] == sc["n_noise"] and s["behind_camera"] == sc["n_behind"]
    assert s["outside"] >= sc["n_outside"] and s["row_offset"] == 0
    total = (s["filtered"]["class"] + s["filtered"]["outliers"] + s["behind_camera"] + s["outside"]
             + s["row_offset"] + sum(s["occluded"].values()) + s["kept"])
    assert total == s["points_read"]
    assert s["kept"] == int(np.isfinite(sparse).sum())
    assert s["filtered"]["outliers"] >= sc["n_outliers"]
    assert s["crs"] == "EPSG:32632"
    tags = read_disparity_tags(out)
    assert float(tags["riverbed_lidar_share"]) == pytest.approx(s["lidar_share"], abs=1e-6)
    assert int(tags["riverbed_window"]) == s["window"] and int(tags["riverbed_points_kept"]) == s["kept"]


def test_without_sor_the_outliers_take_pixels(scene):
    folder, sc, gt = scene
    out = folder / "nosor.pfm"
    r = run(["project", folder / "scene.las", folder / "pair.yaml", "-o", out, "--outliers", "none",
             "--overwrite"])
    assert r.exit_code == 0, r.output
    m = score(read_disparity(out), gt, sc)
    assert_round_trip(m, "`--outliers none`")
    assert m["outliers_removed"] < 0.5  # floating points in front of the surface win their pixels


def test_hpr_and_sides(scene):
    folder, sc, gt = scene
    res = {}
    for args in (["--visibility", "hpr"], ["--side", "left"], ["--side", "right"]):
        out = folder / f"v{len(res)}.tif"
        r = run(["project", folder / "scene.las", folder / "pair.yaml", "-o", out, "--json", "--overwrite",
                 *args])
        assert r.exit_code == 0, r.output
        res[" ".join(args)] = (json.loads(r.stdout), score(read_disparity(out), gt, sc))
    _, m = res["--visibility hpr"]
    assert_round_trip(m, "`--visibility hpr`")
    assert m["max_error"] <= 0.01 and m["hidden_removed"] >= 0.98 and m["outliers_removed"] == 1.0
    s, m = res["--side left"]
    assert_round_trip(m, "`--side left`")
    assert s["occluded"]["right"] == 0 and m["hidden_removed"] >= 0.99
    assert m["right_occluded_removed"] < round_trip("defaults")["right_occluded_removed"] - 0.1
    s, m = res["--side right"]
    assert s["occluded"]["left"] == 0 and m["right_occluded_removed"] >= 0.9


def test_class_filters_and_registration_override(scene, tmp_path):
    folder, sc, _ = scene
    base = ["project", folder / "scene.las", folder / "pair.yaml", "--json", "--outliers", "none",
            "--visibility", "none"]
    r = run([*base, "-o", tmp_path / "a.tif", "--drop-classes", "none"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["filtered"]["class"] == 0
    r = run([*base, "-o", tmp_path / "b.tif", "--classes", "1"])  # outliers, behind, outside only
    s = json.loads(r.output)
    assert s["filtered"]["class"] == sc["n_points"] - sc["n_outliers"] - sc["n_behind"] - sc["n_outside"]
    # The same registration from a text file gives the same map; a wrong one moves the points.
    reg = sc["pair"].registration
    (tmp_path / "reg.txt").write_text("\n".join(" ".join(repr(float(v)) for v in row) for row in reg) + "\n")
    r = run([*base, "-o", tmp_path / "c.tif", "--registration", tmp_path / "reg.txt"])
    assert r.exit_code == 0, r.output
    r = run([*base, "-o", tmp_path / "d.tif"])
    same = read_disparity(tmp_path / "c.tif"), read_disparity(tmp_path / "d.tif")
    assert np.array_equal(*same, equal_nan=True)
    shifted = reg.copy()
    shifted[0, 3] += 0.05
    (tmp_path / "reg2.txt").write_text("\n".join(" ".join(repr(float(v)) for v in row) for row in shifted))
    r = run([*base, "-o", tmp_path / "e.tif", "--registration", tmp_path / "reg2.txt"])
    assert r.exit_code == 0, r.output
    assert not np.array_equal(read_disparity(tmp_path / "e.tif"), read_disparity(tmp_path / "d.tif"),
                              equal_nan=True)


def test_png_and_pfm_outputs_and_crs_check(scene, tmp_path):
    folder = scene[0]
    ref = None
    for ext in (".tif", ".pfm", ".png"):
        out = tmp_path / f"s{ext}"
        r = run(["project", folder / "scene.las", folder / "pair.yaml", "-o", out])
        assert r.exit_code == 0 and r.output == "", r.output
        d = read_disparity(out)
        if ref is None:
            ref = d
        assert np.array_equal(np.isfinite(d), np.isfinite(ref))
        assert np.nanmax(np.abs(d - ref)) <= (1 / 512 if ext == ".png" else 0)  # KITTI PNG: 1/256 px steps
    # The LAS states no CRS: --crs sets it, and it must agree with the pair's EPSG:32632.
    r = run(["project", folder / "scene.las", folder / "pair.yaml", "-o", tmp_path / "x.tif", "--crs",
             "EPSG:2154"])
    assert r.exit_code == 1
    assert r.output == (f"riverbed: error: {folder / 'scene.las'}: the cloud's CRS (EPSG:2154) differs from "
                        "the pair's (EPSG:32632); reproject the cloud, or pass --crs if the file states a "
                        "wrong one\n")
    assert not (tmp_path / "x.tif").exists()


@pytest.fixture()
def bad(tmp_path):
    (tmp_path / "notyaml.yaml").write_text("P_left: [1, 2\n")
    (tmp_path / "short.yaml").write_text("P_left: [[1, 0, 0, 0], [0, 1, 0, 0]]\n"
                                         "P_right: [[1, 0, 0, -1], [0, 1, 0, 0], [0, 0, 1, 0]]\n")
    (tmp_path / "reg.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    (tmp_path / "regbad.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 0 0\n0 0 0 1\n")
    far = np.array([[0.0, 0.0, -5.0], [100.0, 0.0, 5.0], [0.0, 0.0, 5.0]])
    write_las(tmp_path / "away.las", far[:2], np.array([1, 1]))
    write_las(tmp_path / "one.las", far[2:], np.array([1]))
    pair = "P_left: [[100, 0, 50, 0], [0, 100, 50, 0], [0, 0, 1, 0]]\n" \
           "P_right: [[100, 0, 50, -10], [0, 100, 50, 0], [0, 0, 1, 0]]\nwidth: 100\nheight: 100\n"
    (tmp_path / "pair.yaml").write_text(pair)
    (tmp_path / "nosize.yaml").write_text(pair.replace("width: 100\nheight: 100\n", ""))
    return tmp_path


PROJECT_CASES = {
    "missing cloud": (["{w}/nope.las", "{w}/pair.yaml"], "{w}/nope.las: file not found"),
    "cloud format": (["{w}/pair.yaml", "{w}/pair.yaml"],
                     "{w}/pair.yaml: unsupported point cloud format '.yaml' "
                     "(use .las, .laz, KITTI .bin, or a DSM .tif/.hgt)"),
    "missing pair": (["{w}/one.las", "{w}/nope.yaml"], "{w}/nope.yaml: file not found"),
    "bad yaml": (["{w}/one.las", "{w}/notyaml.yaml"],
                 ("{w}/notyaml.yaml: invalid YAML at line 2, column 1: expected ',' or ']', but got "
                  "'<stream end>'")),
    "bad pair": (["{w}/one.las", "{w}/short.yaml"],
                 "{w}/short.yaml: P_left: expected a 3x4 matrix, got 2 rows"),
    "registration": (["{w}/one.las", "{w}/pair.yaml", "--registration", "{w}/regbad.txt"],
                     "{w}/regbad.txt: registration: the 3x3 block is singular (not an invertible transform)"),
    "nothing lands": (["{w}/away.las", "{w}/pair.yaml"],
                      ("{w}/away.las: no point lands in both images (2 read: 0 filtered by class, 1 behind a "
                       "camera, 1 outside the 100x100 images, 0 off the row, 0 outliers)")),
    "no size": (["{w}/one.las", "{w}/nosize.yaml"],
                ("{w}/nosize.yaml: the pair file gives neither width/height nor a left image to take the "
                 "size from")),
    "all filtered": (["{w}/one.las", "{w}/pair.yaml", "--classes", "2"],
                     ("{w}/one.las: no point lands in both images (1 read: 1 filtered by class, 0 behind a "
                      "camera, 0 outside the 100x100 images, 0 off the row, 0 outliers)")),
    "format": (["{w}/one.las", "{w}/pair.yaml", "-o", "{w}/out.xyz"],
               "{w}/out.xyz: unsupported disparity format '.xyz' (use .pfm, .png or .tif)"),
}


@pytest.mark.parametrize("case", PROJECT_CASES)
def test_project_bad_input_one_line_error_and_no_output(bad, case):
    args, msg = PROJECT_CASES[case]
    args = [a.format(w=bad) for a in args]
    out = bad / "out.tif"
    if "-o" not in args:
        args += ["-o", str(out)]
    r = run(["project", *args])
    assert r.exit_code == 1, r.output
    assert r.output == f"riverbed: error: {msg.format(w=bad)}\n"
    assert not out.exists() and not (bad / "out.xyz").exists()
    assert not list(bad.glob(".*tmp*"))


def test_project_one_point_and_existing_output(bad):
    out = bad / "one.tif"
    r = run(["project", bad / "one.las", bad / "pair.yaml", "-o", out, "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["kept"] == 1 and s["d_range"] == [2.0, 2.0]  # f B / Z = 100 * 0.1 / 5
    d = read_disparity(out)
    assert d[50, 50] == 2.0 and np.isfinite(d).sum() == 1
    out.write_bytes(b"precious")
    r = run(["project", bad / "one.las", bad / "pair.yaml", "-o", out])
    assert r.exit_code == 1
    assert r.output == f"riverbed: error: {out}: output exists; pass --overwrite to replace it\n"
    assert out.read_bytes() == b"precious"


def test_pair_middlebury_and_kitti_commands(tmp_path):
    (tmp_path / "calib.txt").write_text(CALIB)
    out = tmp_path / "p.json"
    r = run(["pair", "middlebury", tmp_path / "calib.txt", "-o", out, "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["left"] == "im0.png" and s["right"] == "im1.png" and s["width"] == 1800
    assert s["baseline"] == pytest.approx(0.16) and s["focal"] == 3740.0 and s["exactly_rectified"]
    pair = load_pairfile(out)
    assert pair.left == (tmp_path / "im0.png").absolute()
    assert pair.P_right[0, 2] - pair.P_left[0, 2] == 100.0
    assert pair.P_right[0, 3] == pytest.approx(-3740 * 0.16)
    # Half size: pixel quantities halve (pixel-centre convention for the principal point), the world does not.
    r = run(["pair", "middlebury", tmp_path / "calib.txt", "-o", tmp_path / "half.yaml", "--scale", "0.5"])
    half = load_pairfile(tmp_path / "half.yaml")
    assert half.focal == 1870.0 and half.P_left[0, 2] == 449.5 and (half.width, half.height) == (900, 750)
    assert half.baseline == pytest.approx(0.16)
    r = run(["pair", "middlebury", tmp_path / "calib.txt", "-o", tmp_path / "p.txt"])
    assert r.exit_code == 1
    assert r.output == f"riverbed: error: {tmp_path / 'p.txt'}: pair file must end in .yaml, .yml or .json\n"
    (tmp_path / "bad.txt").write_text(CALIB.replace("doffs=100", "doffs=90"))
    r = run(["pair", "middlebury", tmp_path / "bad.txt", "-o", tmp_path / "b.yaml"])
    bad = tmp_path / "bad.txt"
    assert r.output == f"riverbed: error: {bad}: doffs 90 disagrees with cam1 cx - cam0 cx = 100\n"
    r = run(["pair", "kitti", tmp_path / "calib.txt", "-o", tmp_path / "k.yaml"])
    assert r.exit_code == 1
    calib = tmp_path / "calib.txt"
    assert r.output == f"riverbed: error: {calib}: not a KITTI object calibration: no 'P2:' line\n"
    assert not (tmp_path / "k.yaml").exists() and not (tmp_path / "b.yaml").exists()
