"""``riverbed rectify``: raw frames + orientation files -> rectified pair and pair file.

On the sample block's raw frames (``sample_data/block/raw``): matched features share their rows, the pair file's
cameras are the exact cameras of the written images (LiDAR points land where the inverse rectification says, to
1e-3 px), distortion is removed, pairs whose baseline points left or along the columns come out turned, bad
orientation files give one-line errors, and ``riverbed match`` runs on the result.

The measuring functions here (:func:`row_agreement`, :func:`camera_check`, :func:`content_agreement`,
:func:`distortion_case`, :func:`match_chain`) are what ``benchmarks/bench_rectify.py`` runs for docs/rectify.md's
tables; each test holds its measurement to the committed figure (:func:`assert_figures`).
"""

import json
import math
from pathlib import Path

import cv2
import laspy
import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from scipy.ndimage import map_coordinates

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry import rectify as RC
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.geometry.pairfile import load_pairfile

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data" / "block"
RAW = SAMPLE / "raw"
W, H = 1200, 800  # raw frame size of the small block
F0, Y0, F1, Y1 = RAW / "frame0.png", RAW / "frame0.yaml", RAW / "frame1.png", RAW / "frame1.yaml"

#: benchmarks/bench_rectify.py's committed figures (docs/rectify.md's tables)
RESULTS = REPO / "benchmarks" / "results_rectify.json"
#: How close a measurement must come to its committed figure. SIFT, ORB, Lucas-Kanade, RANSAC (OpenCV seeds its
#: generator with a constant), remap and the matcher are deterministic: on one machine a run repeats the committed
#: figure to its rounding. 2 % of it, or the absolute floor of its kind for figures near zero, leaves room for another
#: CPU's floating-point paths only; any change of the method or of its inputs moves the figures by more.
REL = 0.02
#: absolute floors: px figures of matched features, counts, and the remap maps' errors (float32 maps: their
#: rounding, ~6e-5 px at 1000 px, is what those measure)
FLOOR_PX, FLOOR_COUNT, FLOOR_MAP = 0.003, 2, 1e-5


def committed(*keys):
    """A figure, or a group of them, of the committed benchmarks/results_rectify.json, by its keys."""
    value = json.loads(RESULTS.read_text())
    for key in keys:
        value = value[key]
    return value


def assert_near(got, want, floor=FLOOR_PX, what=""):
    """``got`` within :data:`REL` of the committed ``want``, or within ``floor`` of it. Two-sided: a figure that got
    much better is a change to review too (run the benchmark and commit its figures)."""
    assert abs(got - want) <= max(REL * abs(want), floor), f"{what}: measured {got}, committed {want}"


def assert_figures(got, want, floor=FLOOR_PX, what=""):
    """Every figure of the committed dict ``want`` in ``got`` by :func:`assert_near` (counts, ints, with
    :data:`FLOOR_COUNT`; lists element by element); strings, booleans and None equal."""
    for key, value in want.items():
        pairs = zip(got[key], value) if isinstance(value, list) else [(got[key], value)]
        for g, v in pairs:
            if v is None or isinstance(v, (str, bool)):
                assert g == v, f"{what} {key}: measured {g}, committed {v}"
            else:
                assert_near(g, v, FLOOR_COUNT if isinstance(v, int) else floor, f"{what} {key}")


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


# -- fixtures ------------------------------------------------------------------------------------------------
def load_raw():
    """The committed raw frames 0 and 1 and their orientations."""
    imgs = [read_image(RAW / f"frame{k}.png") for k in (0, 1)]
    orients = [RC.load_orientation(RAW / f"frame{k}.yaml", (W, H)) for k in (0, 1)]
    return imgs, orients


def load_lidar():
    """World coordinates (float64) of the sample block's LiDAR points; classes 1 and 7 (noise) dropped."""
    las = laspy.read(SAMPLE / "lidar.laz")
    keep = np.isin(np.asarray(las.classification), (2, 5, 6, 9))
    return np.c_[np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)][keep]


@pytest.fixture(scope="module")
def raw():
    return load_raw()


@pytest.fixture(scope="module")
def lidar():
    return load_lidar()


@pytest.fixture(scope="module")
def rectified(raw):
    imgs, (o0, o1) = raw
    return RC.rectify(imgs[0], o0, imgs[1], o1)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """``riverbed rectify`` on the raw frames (the command line), with its JSON summary."""
    out = tmp_path_factory.mktemp("rect") / "pair"
    r = _run("rectify", F0, Y0, F1, Y1,
             "-o", out, "--json")
    assert r.exit_code == 0, r.output
    return out, json.loads(r.output)


def _in_both(pair, X):
    xl, yl, xr, depth = pair.project(X - pair.origin)
    inside = (depth > 0) & (xl >= 0) & (xl <= pair.width - 1) & (yl >= 0) & (yl <= pair.height - 1)
    return inside & (xr >= 0) & (xr <= pair.width - 1), xl, yl, xr


def _d_range(pair, X, margin=3.0):
    both, xl, _, xr = _in_both(pair, X)
    d = (xl - xr)[both]
    return float(d.min()) - margin, float(d.max()) + margin


# -- the measurement of rows ---------------------------------------------------------------------------------
def row_agreement(left, right, d_range, grid=3):
    """Rows of matched features of a rectified pair.

    SIFT features, Lowe's ratio test (0.75), RANSAC on the fundamental matrix (1 px) to drop outliers, and
    matches whose disparity lies outside ``d_range`` (false matches along a row, which RANSAC on F keeps) are
    dropped. Each left keypoint, rounded to a pixel, is then tracked into the right image by Lucas-Kanade
    (15 px window, from the SIFT match) for a sub-pixel position. Returns the count, the median, 95th
    percentile and mean of ``dy = y_left - y_right`` (|dy| for the first two), the same for the raw SIFT
    positions, and the largest |median dy| over a ``grid x grid`` partition of the left image (the systematic
    part: a rectification error is a smooth field, feature noise is not), the grid spanning the matched area.
    """
    grey = [cv2.cvtColor(i, cv2.COLOR_RGB2GRAY) if i.ndim == 3 else i for i in (left, right)]
    sift = cv2.SIFT_create()
    kl, dl = sift.detectAndCompute(grey[0], None)
    kr, dr = sift.detectAndCompute(grey[1], None)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(dl, dr, k=2)
    good = [m for m, n in (p for p in knn if len(p) == 2) if m.distance < 0.75 * n.distance]
    pl = np.float64([kl[m.queryIdx].pt for m in good])
    pr = np.float64([kr[m.trainIdx].pt for m in good])
    _, mask = cv2.findFundamentalMat(pl, pr, cv2.FM_RANSAC, 1.0, 0.999)
    d = pl[:, 0] - pr[:, 0]
    keep = mask.ravel().astype(bool) & (d >= d_range[0]) & (d <= d_range[1])
    pl, pr = pl[keep], pr[keep]
    sift_dy = np.abs(pl[:, 1] - pr[:, 1])
    p0 = np.round(pl).astype(np.float32)
    p1 = (pr + (p0 - pl)).astype(np.float32)
    q, status, _ = cv2.calcOpticalFlowPyrLK(
        grey[0], grey[1], p0.reshape(-1, 1, 2), p1.reshape(-1, 1, 2).copy(), winSize=(15, 15), maxLevel=0,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4),
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    q = q.reshape(-1, 2).astype(np.float64)
    ok = (status.ravel() == 1) & (np.hypot(*(q - p1).T) < 1.5)
    dy = p0[ok, 1] - q[ok, 1]
    # Regions: a grid over the matched area (the overlap of the two frames).
    lo, hi = p0[ok].min(axis=0), p0[ok].max(axis=0) + 1
    gx, gy = (np.minimum((p0[ok] - lo) * grid // (hi - lo), grid - 1)).T
    cell = gy * grid + gx
    regional = [float(np.median(dy[cell == c])) for c in range(grid * grid) if (cell == c).sum() >= 10]
    return {"n": int(ok.sum()), "median": float(np.median(np.abs(dy))),
            "p95": float(np.percentile(np.abs(dy), 95)), "mean": float(dy.mean()),
            "regional_max": float(np.max(np.abs(regional))), "regions": len(regional),
            "sift_n": len(sift_dy), "sift_median": float(np.median(sift_dy)),
            "sift_p95": float(np.percentile(sift_dy, 95))}


def _report(name, s):
    print(f"\n{name}: {s['n']} matches, |dy| median {s['median']:.3f} px, p95 {s['p95']:.3f} px, mean "
          f"{s['mean']:+.3f} px, largest regional median {s['regional_max']:.3f} px over {s['regions']} "
          "regions; "
          f"raw SIFT positions ({s['sift_n']}): median {s['sift_median']:.3f}, p95 {s['sift_p95']:.3f}")


#: Rows agree when the median |dy| and the largest regional median are within this (px) ...
ROWS_AGREE_PX = 0.1
#: ... and the mean dy (a shift of one image) within this (px).
ROWS_MEAN_PX = 0.03


def rows_agree(s):
    """Whether :func:`row_agreement`'s figures ``s`` say the rows agree (:data:`ROWS_AGREE_PX`,
    :data:`ROWS_MEAN_PX`)."""
    return s["median"] <= ROWS_AGREE_PX and s["regional_max"] <= ROWS_AGREE_PX and abs(s["mean"]) <= ROWS_MEAN_PX


def rows_of(r, lidar):
    """:func:`row_agreement` of a rectified pair ``r`` (:class:`~riverbed_cli.geometry.rectify.Rectified`), the
    disparities kept those of the LiDAR in it (3 px around)."""
    return row_agreement(r.left, r.right, _d_range(r.pair, lidar))


def generator_rows(lidar):
    """:func:`row_agreement` of the generator's own rectified pair (sample_data/block/left.png, right.png: rendered in
    rectified geometry, rows exact by construction): the spread of feature noise alone."""
    pair = load_pairfile(SAMPLE / "pair.yaml")
    return row_agreement(read_image(SAMPLE / "left.png"), read_image(SAMPLE / "right.png"), _d_range(pair, lidar))


#: The wrong orientation the row measurement must catch: the right frame's omega off by this (deg).
OMEGA_OFF_DEG = 0.005


def omega_off(o, deg=OMEGA_OFF_DEG):
    """Orientation ``o`` with its omega off by ``deg``."""
    om, ph, ka = o.omega_phi_kappa
    R = np.diag([1.0, -1, -1]) @ RC.opk_to_matrix(om + deg, ph, ka)
    return RC.FrameOrientation(K=o.K, dist=o.dist, R=R, centre=o.centre, width=o.width, height=o.height, crs=o.crs,
                               origin=o.origin)


# -- (a) rows of matched features ----------------------------------------------------------------------------
def test_rectified_rows_agree_on_matched_features(written, lidar):
    """The sample block's raw frames rectify to a pair whose matched features share their rows, as closely as the
    generator's exactly rectified pair (its spread, the p95 above all, is feature noise, not geometry)."""
    out, _ = written
    pair = load_pairfile(out / "pair.yaml")
    s = row_agreement(read_image(out / "left.png"), read_image(out / "right.png"), _d_range(pair, lidar))
    _report("rectified raw frames", s)
    ref = generator_rows(lidar)
    _report("generator's rectified pair (reference)", ref)
    assert s["regions"] == 9
    assert rows_agree(s) and rows_agree(ref), (s, ref)
    assert s["median"] <= ref["median"] + 0.03  # as good as rows that agree exactly, within feature noise
    assert_figures(s, committed("rows", "rectified"), what="rectified")
    assert_figures(ref, committed("rows", "generator"), what="generator")


def test_row_check_catches_a_wrong_orientation(raw, lidar):
    """The row measurement can fail: the right frame's omega off by 0.005 deg (0.26 px of rows) is caught."""
    imgs, (o0, o1) = raw
    s = rows_of(RC.rectify(imgs[0], o0, imgs[1], omega_off(o1)), lidar)
    _report(f"right omega + {OMEGA_OFF_DEG} deg", s)
    assert not rows_agree(s)
    assert s["regional_max"] > 0.15
    assert_figures(s, committed("rows", "omega"), what="omega")


# -- (b) the pair file's cameras are the cameras of the written images ---------------------------------------
def _map_back(maps, x, y):
    """Raw-frame pixel of rectified pixels ``(x, y)``: the remap maps, bilinearly interpolated."""
    mx, my = maps
    return (map_coordinates(mx.astype(np.float64), [y, x], order=1),
            map_coordinates(my.astype(np.float64), [y, x], order=1))


def _raw_pixel(o, X):
    """Raw-frame pixels of world points with OpenCV's projectPoints (independent of riverbed's projection)."""
    rvec, _ = cv2.Rodrigues(o.R)
    pts, _ = cv2.projectPoints((X - o.centre).reshape(-1, 1, 3), rvec, np.zeros(3), o.K, o.dist)
    return pts.reshape(-1, 2)


def camera_check(r, orients, X, tol=1e-3):
    """LiDAR points ``X`` projected with the pair of ``r`` land, through the inverse rectification (the remap maps),
    on their raw pixels (OpenCV's projectPoints with ``orients``), within ``tol`` px. Returns ``worst_px`` (the
    largest error, left and right image) and ``points`` (the points inside each image)."""
    pair = r.pair
    xl, yl, xr, depth, yr, _ = pair.project(X - pair.origin, full=True)
    assert (depth > 0).all() and (xl - xr > 0).all()  # d = f B / depth > 0 for every point in front
    np.testing.assert_array_equal(yl, yr)  # an exactly rectified pair: one row for both images
    worst, points = [], []
    for i, (x, y) in enumerate(((xl, yl), (xr, yr))):
        inside = (x >= 1) & (x <= pair.width - 2) & (y >= 1) & (y <= pair.height - 2)
        assert inside.sum() > 5000
        u, v = _map_back(r.maps[i], x[inside], y[inside])
        ref = _raw_pixel(orients[i], X[inside])
        err = np.hypot(u - ref[:, 0], v - ref[:, 1])
        worst.append(float(err.max()))
        points.append(int(inside.sum()))
    assert max(worst) < tol, worst
    return {"worst_px": worst, "points": points}


def test_written_pair_file_is_the_cameras_of_the_written_images(written, rectified, raw, lidar):
    out, summary = written
    pair = load_pairfile(out / "pair.yaml")
    assert pair.exactly_rectified
    assert (pair.width, pair.height) == (W, H) and pair.crs == "EPSG:32632"
    np.testing.assert_array_equal(pair.origin, [501230.0, 5002470.0, 200.0])
    assert pair.left == (out / "left.png").absolute() and pair.right == (out / "right.png").absolute()
    # The file holds exactly the in-memory cameras, and the images are the in-memory images ...
    np.testing.assert_array_equal(pair.P_left, rectified.pair.P_left)
    np.testing.assert_array_equal(pair.P_right, rectified.pair.P_right)
    np.testing.assert_array_equal(read_image(out / "left.png"), rectified.left)
    np.testing.assert_array_equal(read_image(out / "right.png"), rectified.right)
    # ... which are the raw frames resampled at the maps ...
    imgs, orients = raw
    for img, maps, rect in zip(imgs, rectified.maps, (rectified.left, rectified.right)):
        again = cv2.remap(img, *maps, RC.INTERPOLATION, borderMode=cv2.BORDER_CONSTANT)
        np.testing.assert_array_equal(again, rect)
    # ... and a world point's rectified pixel maps back to its raw pixel (OpenCV's projectPoints).
    check = camera_check(rectified, orients, lidar)
    print(f"\nLiDAR points: rectified pixel -> raw pixel vs projectPoints, worst {max(check['worst_px']):.2e} px")
    assert_figures(check, committed("cameras", "plain"), FLOOR_MAP, "cameras")
    assert summary["turn_deg"] == [0, 0] and summary["valid_share"] == [1.0, 1.0]
    assert summary["fB"] == pytest.approx(pair.focal * pair.baseline, rel=1e-12)
    assert pair.baseline == pytest.approx(96.0, abs=1e-6)  # frames 0 and 1 of the flight line


def content_agreement(rectified, raw_left, o):
    """SIFT features of the rectified left image and of its raw frame ``raw_left`` (orientation ``o``), matched
    (ratio test 0.75), against the homography the pair file's camera and the orientation predict (same projection
    centre): ``features`` (the matches within 1 px of it) and ``median_px`` (their median error)."""
    sift = cv2.SIFT_create()
    k1, d1 = sift.detectAndCompute(rectified.left, None)
    k2, d2 = sift.detectAndCompute(raw_left, None)
    good = [m for m, n in cv2.BFMatcher().knnMatch(d1, d2, k=2) if m.distance < 0.75 * n.distance]
    p1 = np.float64([k1[m.queryIdx].pt for m in good])
    p2 = np.float64([k2[m.trainIdx].pt for m in good])
    Hm = o.K @ o.R @ np.linalg.inv(rectified.pair.P_left[:, :3])  # rectified pixel -> raw pixel
    q = np.c_[p1, np.ones(len(p1))] @ Hm.T
    err = np.hypot(*(q[:, :2] / q[:, 2:] - p2).T)
    ok = err < 1.0
    return {"features": int(ok.sum()), "median_px": float(np.median(err[ok]))}


def test_rectified_image_content_matches_its_camera(rectified, raw):
    """Independent of the maps: SIFT features of the rectified left image and of raw frame 0 are related by
    the homography that the pair file's camera and frame 0's orientation predict (same projection centre).
    A half-pixel convention error would show as 0.5 px."""
    imgs, orients = raw
    c = content_agreement(rectified, imgs[0], orients[0])
    print(f"\nraw <-> rectified features: {c['features']}, median {c['median_px']:.3f} px")
    assert c["features"] > 1000 and c["median_px"] < 0.1
    assert_figures(c, committed("content"), what="raw <-> rectified features")


# -- distortion ----------------------------------------------------------------------------------------------
DIST = np.array([-0.3, 0.2, 5e-4, -5e-4, 0.0])  # k1, k2, p1, p2, k3: ~12 px at the corners


def _distort_frame(img, K, dist):
    """The frame a camera with ``dist`` would have recorded: each distorted pixel samples the pinhole frame at
    its undistorted position (Brown model inverted by fixed-point iteration)."""
    h, w = img.shape[:2]
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xd, yd = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    k1, k2, p1, p2, k3 = dist
    x, y = xd.copy(), yd.copy()
    for _ in range(30):
        r2 = x * x + y * y
        rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        x = (xd - 2 * p1 * x * y - p2 * (r2 + 2 * x * x)) / rad
        y = (yd - p1 * (r2 + 2 * y * y) - 2 * p2 * x * y) / rad
    r2 = x * x + y * y
    rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    assert np.abs(x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd).max() < 1e-12
    mx = (x * K[0, 0] + K[0, 2]).astype(np.float32)
    my = (y * K[1, 1] + K[1, 2]).astype(np.float32)
    return cv2.remap(img, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def with_distortion(o, dist):
    """Orientation ``o`` with the distortion coefficients ``dist`` (k1, k2, p1, p2, k3)."""
    return RC.FrameOrientation(K=o.K, dist=np.asarray(dist, np.float64), R=o.R, centre=o.centre, width=o.width,
                               height=o.height, crs=o.crs, origin=o.origin)


def distortion_case(raw, lidar, dist=DIST):
    """The raw frames as a camera with ``dist`` would have recorded them, rectified with their distortion model and
    without it. Returns the frames (``distorted``), the rectification with the model (``rect``), its
    :func:`camera_check` (``cameras``) and :func:`rows_of` both rectifications (``rows``, ``rows_without_model``)."""
    imgs, orients = raw
    distorted = [_distort_frame(img, o.K, dist) for img, o in zip(imgs, orients)]
    o_d = [with_distortion(o, dist) for o in orients]
    rect = RC.rectify(distorted[0], o_d[0], distorted[1], o_d[1])
    plain = [with_distortion(o, np.zeros(5)) for o in o_d]
    return {"distorted": distorted, "rect": rect, "cameras": camera_check(rect, o_d, lidar),
            "rows": rows_of(rect, lidar),
            "rows_without_model": rows_of(RC.rectify(distorted[0], plain[0], distorted[1], plain[1]), lidar)}


def test_radial_distortion_is_removed(raw, lidar, tmp_path):
    case = distortion_case(raw, lidar)
    distorted = case["distorted"]
    files = []
    for k, img in enumerate(distorted):
        data = yaml.safe_load((RAW / f"frame{k}.yaml").read_text())
        k1, k2, p1, p2, k3 = (float(v) for v in DIST)
        data["interior"]["distortion"] = {"k1": k1, "k2": k2, "k3": k3, "p1": p1, "p2": p2}
        (tmp_path / f"d{k}.yaml").write_text(yaml.safe_dump(data))
        cv2.imwrite(str(tmp_path / f"d{k}.png"), img)
        files += [tmp_path / f"d{k}.png", tmp_path / f"d{k}.yaml"]
    r = _run("rectify", *files, "-o", tmp_path / "out", "--json")
    assert r.exit_code == 0, r.output
    # the files the command read hold the orientations the case rectified with: the same images
    o_d = [RC.load_orientation(tmp_path / f"d{k}.yaml", (W, H)) for k in (0, 1)]
    np.testing.assert_array_equal(o_d[0].dist, DIST)
    np.testing.assert_array_equal(read_image(tmp_path / "out" / "left.png"), case["rect"].left)
    np.testing.assert_array_equal(read_image(tmp_path / "out" / "right.png"), case["rect"].right)
    s = case["rows"]
    _report(f"distorted frames (k1 {DIST[0]}, k2 {DIST[1]}), worst map error {max(case['cameras']['worst_px']):.1e} "
            "px", s)
    assert rows_agree(s), s
    # Ignoring the distortion leaves rows apart by up to pixels: the check sees it.
    s_bad = case["rows_without_model"]
    _report("distorted frames rectified without their distortion", s_bad)
    assert not rows_agree(s_bad) and s_bad["p95"] > 1.0
    assert_figures(case["cameras"], committed("cameras", "distorted"), FLOOR_MAP, "distorted cameras")
    assert_figures(s, committed("rows", "distorted"), what="distorted")
    assert_figures(s_bad, committed("rows", "distorted_without_model"), what="distorted without the model")


# -- baselines that point the other way ----------------------------------------------------------------------
def test_baseline_to_the_left_turns_the_images_by_180(raw, rectified, lidar):
    """Frame 1 as LEFT: its partner lies to the left, so both rectified images are turned by 180 deg; the left
    image is then the usual right image turned, and every disparity stays positive."""
    imgs, (o0, o1) = raw
    turn = np.array([[-1.0, 0, W - 1], [0, -1.0, H - 1], [0, 0, 1]])
    for preturn in (True, False):  # the turn given to stereoRectify, and the fallback after it
        r = RC.rectify(imgs[1], o1, imgs[0], o0, _preturn=preturn)
        assert r.info["turn_deg"] == [180, 180]
        camera_check(r, (o1, o0), lidar)
        for a, b in ((r.left, rectified.right), (r.right, rectified.left)):
            diff = np.abs(a.astype(int) - np.rot90(b, 2).astype(int))
            assert diff.max() <= 1 and diff.mean() < 0.01  # the maps agree to float32 rounding
        np.testing.assert_allclose(r.pair.P_left, turn @ rectified.pair.P_right, rtol=0,
                                   atol=1e-12 * np.abs(r.pair.P_left).max())


def test_baseline_along_the_columns_turns_the_images_by_90(raw, rectified, lidar, tmp_path):
    """Frames stored turned by 90 deg (principal point in px, orientation as a rotation matrix): the baseline
    runs along their columns; the output is turned back and equals the usual rectified pair."""
    imgs, orients = raw
    Q = np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]])  # camera axes of np.rot90: x' = y, y' = -x
    files = []
    for k, (img, o) in enumerate(zip(imgs, orients)):
        cv2.imwrite(str(tmp_path / f"t{k}.png"), np.ascontiguousarray(np.rot90(img)))
        data = {"interior": {"width": H, "height": W, "focal_length_px": float(o.K[0, 0]),
                             "principal_point_px": [float(o.K[1, 2]), float(W - 1 - o.K[0, 2])]},
                "exterior": {"centre": o.centre.tolist(),
                             "rotation": (np.diag([1.0, -1, -1]) @ Q @ o.R).tolist()},
                "crs": "EPSG:32632", "origin": o.origin.tolist()}
        (tmp_path / f"t{k}.yaml").write_text(yaml.safe_dump(data))
        files += [tmp_path / f"t{k}.png", tmp_path / f"t{k}.yaml"]
    r = _run("rectify", *files, "-o", tmp_path / "out", "--json")
    assert r.exit_code == 0, r.output
    summary = json.loads(r.output)
    assert summary["turn_deg"] in ([90, 90], [-90, -90])
    assert (summary["width"], summary["height"]) == (W, H)
    pair = load_pairfile(tmp_path / "out" / "pair.yaml")
    scale = np.abs(pair.P_left).max()
    np.testing.assert_allclose(pair.P_left, rectified.pair.P_left, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(pair.P_right, rectified.pair.P_right, rtol=0, atol=1e-12 * scale)
    diff = np.abs(read_image(tmp_path / "out" / "left.png").astype(int) - rectified.left.astype(int))
    assert diff.max() <= 1 and diff.mean() < 0.01  # the maps agree to float32 rounding
    o_t = [RC.load_orientation(tmp_path / f"t{k}.yaml", (H, W)) for k in (0, 1)]
    for preturn in (True, False):  # without the turn, stereoRectify's vertical case and the fallback
        r_mem = RC.rectify(read_image(files[0]), o_t[0], read_image(files[2]), o_t[1], _preturn=preturn)
        np.testing.assert_allclose(r_mem.pair.P_left, rectified.pair.P_left, rtol=0, atol=1e-12 * scale)
        camera_check(r_mem, o_t, lidar)


def test_strips_flown_in_opposite_directions(raw, rectified, lidar):
    """Frame 1 stored as if flown the other way (kappa + 180 deg, image turned): stereoRectify alone would
    average the two attitudes into a camera turned by 90 deg (negative focal length); with the turn, the right
    image is turned back and the pair equals the usual one."""
    imgs, (o0, o1) = raw
    K = o1.K
    K_turned = np.array([[K[0, 0], 0, W - 1 - K[0, 2]], [0, K[1, 1], H - 1 - K[1, 2]], [0, 0, 1]])
    o1t = RC.FrameOrientation(K=K_turned, dist=o1.dist, R=np.diag([-1.0, -1, 1]) @ o1.R, centre=o1.centre,
                              width=W, height=H, crs=o1.crs, origin=o1.origin)
    assert abs(o1t.omega_phi_kappa[2] - o1.omega_phi_kappa[2]) == pytest.approx(180)
    r = RC.rectify(imgs[0], o0, np.ascontiguousarray(np.rot90(imgs[1], 2)), o1t)
    assert r.info["turn_deg"] == [0, 180]
    scale = np.abs(r.pair.P_left).max()
    np.testing.assert_allclose(r.pair.P_left, rectified.pair.P_left, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(r.pair.P_right, rectified.pair.P_right, rtol=0, atol=1e-12 * scale)
    diff = np.abs(r.right.astype(int) - rectified.right.astype(int))
    assert diff.max() <= 1 and diff.mean() < 0.01
    camera_check(r, (o0, o1t), lidar)
    with pytest.raises(RiverbedError, match="non-positive rectified focal length"):
        RC.rectify(imgs[0], o0, np.ascontiguousarray(np.rot90(imgs[1], 2)), o1t, _preturn=False)


# -- orientation files ---------------------------------------------------------------------------------------
def test_omega_phi_kappa_convention():
    """M = R3(kappa) R2(phi) R1(omega), object -> image (Wolf & Dewitt's elements); signs as documented."""
    rng = np.random.default_rng(5)
    for w, p, k in rng.uniform(-170, 170, (20, 3)) * np.array([1, 0.5, 1]):
        M = RC.opk_to_matrix(w, p, k)
        sw, cw, sp, cp, sk, ck = (f(math.radians(a)) for a in (w, p, k) for f in (math.sin, math.cos))
        ref = [[cp * ck, sw * sp * ck + cw * sk, -cw * sp * ck + sw * sk],
               [-cp * sk, -sw * sp * sk + cw * ck, cw * sp * sk + sw * ck],
               [sp, -sw * cp, cw * cp]]
        np.testing.assert_allclose(M, ref, atol=1e-15)
        np.testing.assert_allclose(RC.matrix_to_opk(M), (w, p, k), atol=1e-9)
    np.testing.assert_array_equal(RC.opk_to_matrix(0, 0, 0), np.eye(3))
    look = lambda M: -M[2]  # noqa: E731 - the viewing direction (image -z) in object coordinates
    assert look(RC.opk_to_matrix(5, 0, 0))[1] > 0  # omega > 0 looks towards +Y (north)
    assert look(RC.opk_to_matrix(0, 5, 0))[0] < 0  # phi > 0 looks towards -X (west)
    # kappa 90: image x points north
    np.testing.assert_allclose(RC.opk_to_matrix(0, 0, 90)[0], [0, 1, 0], atol=1e-15)


def test_sample_orientations_are_the_scene_cameras():
    """raw/frameK.yaml hold the cameras that rendered the frames (scene.json), mm values included."""
    scene = json.loads((SAMPLE / "scene.json").read_text())
    origin = np.array(scene["origin"])
    for k in (0, 1):
        o = RC.load_orientation(RAW / f"frame{k}.yaml")
        f = scene["frames"][k]
        np.testing.assert_array_equal(o.K, f["K"])
        np.testing.assert_array_equal(o.centre, f["centre"])
        np.testing.assert_allclose(o.R, f["R"], rtol=0, atol=1e-15)
        assert (o.width, o.height, o.crs) == (f["width"], f["height"], "EPSG:32632")
        np.testing.assert_array_equal(o.origin, origin)
        assert read_image(RAW / f"frame{k}.png").shape == (f["height"], f["width"])


def test_committed_raw_frame_regenerates():
    """raw/frame0.png is render_frame(block, 0) in grey: the generator reproduces the committed file."""
    from types import SimpleNamespace

    from riverbed_cli import sample as S

    spec = S.SIZES["small"]
    scene = S.build_scene(spec, 0)
    block = SimpleNamespace(spec=spec, seed=0, scene=scene, frames=S.exposures(scene, spec, 0))
    img, cam, _ = S.render_frame(block, 0)
    np.testing.assert_array_equal(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), read_image(RAW / "frame0.png"))
    assert yaml.safe_load((RAW / "frame0.yaml").read_text()) == yaml.safe_load(
        yaml.safe_dump(S.raw_orientation(block, 0)))


def test_pixel_and_mm_forms_agree(tmp_path):
    base = {"interior": {"width": 1200, "height": 800, "pixel_size_mm": 0.004, "focal_length_mm": 12.0,
                         "principal_point_mm": [0.02, -0.01]},
            "exterior": {"centre": [1.0, 2.0, 600.0], "omega_phi_kappa_deg": [0.1, -0.2, 20.0]}}
    px = {"interior": {"focal_length_px": 3000.0, "principal_point_px": [604.5, 402.0]},
          "exterior": {"centre": [1.0, 2.0, 600.0], "rotation": RC.opk_to_matrix(0.1, -0.2, 20.0).tolist()}}
    a, b = RC.orientation_from_dict(base), RC.orientation_from_dict(px)
    np.testing.assert_allclose(a.K, b.K, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.R, b.R, rtol=0, atol=1e-15)
    np.testing.assert_allclose(a.omega_phi_kappa, (0.1, -0.2, 20.0), atol=1e-12)
    px["exterior"]["rotation"] = np.round(RC.opk_to_matrix(0.1, -0.2, 20.0), 6).tolist()  # as printed
    np.testing.assert_allclose(RC.orientation_from_dict(px).R, a.R, rtol=0, atol=1e-6)


GOOD = {"interior": {"width": 1200, "height": 800, "pixel_size_mm": 0.004, "focal_length_mm": 12.0,
                     "principal_point_mm": [0.0, 0.0]},
        "exterior": {"centre": [501184.9, 5002453.6, 840.6], "omega_phi_kappa_deg": [0.0, 0.0, 20.0]},
        "crs": "EPSG:32632"}


def _edit(path, value):
    def apply(d):
        keys = path.split(".")
        for key in keys[:-1]:
            d = d[key]
        if value is _DELETE:
            del d[keys[-1]]
        else:
            d[keys[-1]] = value
    return apply


_DELETE = object()
BAD = [
    (_edit("interior", _DELETE), "interior: missing"),
    (_edit("camera", "x"), "camera: unknown key (orientation file keys: interior, exterior, crs, origin)"),
    (_edit("interior.focal_length_px", 3000), "interior.focal_length_px: give only one of focal_length_mm or "
                                              "focal_length_px"),
    (_edit("interior.focal_length_mm", _DELETE), "interior: missing focal_length_mm or focal_length_px"),
    (_edit("interior.focal_length_mm", -12), "interior.focal_length_mm: must be positive, got -12"),
    (_edit("interior.focal_length_mm", "twelve"),
     "interior.focal_length_mm: expected a number, got 'twelve'"),
    (_edit("interior.pixel_size_mm", _DELETE), "interior.pixel_size_mm: missing (needed for "
                                               "interior.focal_length_mm)"),
    (_edit("interior.principal_point_mm", _DELETE),
     "interior: missing principal_point_mm or principal_point_px"),
    (_edit("interior.principal_point_mm", [0.0]),
     "interior.principal_point_mm: expected 2 numbers, got 1 numbers"),
    (_edit("interior.width", 1000), "interior.width: 1000 px, but the image is 1200 px"),
    (_edit("interior.height", 0), "interior.height: expected a positive integer (pixels), got 0"),
    (_edit("interior.distortion", {"k1": 0.1, "k4": 0.0}), "interior.distortion.k4: unknown key "
                                                          "(interior.distortion keys: k1, k2, k3, p1, p2)"),
    (_edit("interior.distortion", {"k1": float("nan")}), "interior.distortion.k1: not finite: nan"),
    (_edit("exterior.centre", [1.0, 2.0]), "exterior.centre: expected 3 numbers, got 2 numbers"),
    (_edit("exterior.centre", _DELETE), "exterior.centre: missing (projection centre X, Y, Z)"),
    (_edit("exterior.omega_phi_kappa_deg", [0, "x", 0]), "exterior.omega_phi_kappa_deg: entry [1] is not a "
                                                         "number: 'x'"),
    (_edit("exterior.omega_phi_kappa_deg", _DELETE), "exterior: missing omega_phi_kappa_deg or rotation"),
    (_edit("exterior.rotation", np.eye(3).tolist()),
     "exterior.rotation: give only one of omega_phi_kappa_deg or rotation"),
    (_edit("crs", "EPSG:4326"),
     "crs: EPSG:4326 is geographic (degrees); projection centres need a projected CRS"),
    (_edit("crs", "EPSG:999999"), "crs: unknown CRS 'EPSG:999999'"),
    (_edit("origin", [1, 2]), "origin: expected 3 numbers, got 2 numbers"),
]


@pytest.mark.parametrize("edit, message", BAD, ids=[m.split(":")[0] + str(i) for i, (_, m) in enumerate(BAD)])
def test_bad_orientation_files_give_one_line_errors(edit, message, tmp_path):
    data = json.loads(json.dumps(GOOD))
    edit(data)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    r = _run("rectify", F0, bad, F1, Y1, "-o", tmp_path / "o")
    assert r.exit_code == 1
    assert r.output == f"riverbed: error: {bad}: {message}\n"
    assert not (tmp_path / "o").exists()


def _yaml_file(tmp_path, name, data):
    p = tmp_path / name
    p.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return p


def test_orientation_file_and_pair_errors(tmp_path):
    f0, f1 = RAW / "frame0.png", RAW / "frame1.png"
    y1 = RAW / "frame1.yaml"
    cases = []
    p = tmp_path / "missing.yaml"
    cases.append((p, y1, f"{p}: file not found"))
    p = _yaml_file(tmp_path, "list.yaml", "- 1\n- 2\n")
    cases.append((p, y1, f"{p}: not an orientation file (expected a mapping with interior and exterior)"))
    p = _yaml_file(tmp_path, "broken.yaml", "interior: [1, 2\n")
    cases.append((p, y1, f"{p}: invalid YAML at line 2, column 1: expected ',' or ']', but got "
                         "'<stream end>'"))
    rot = json.loads(json.dumps(GOOD))
    del rot["exterior"]["omega_phi_kappa_deg"]
    rot["exterior"]["rotation"] = [[1, 0, 0], [0, 1, 0], [0, 0.1, 1]]
    p = _yaml_file(tmp_path, "rot.yaml", rot)
    cases.append((p, y1, f"{p}: exterior.rotation: not a rotation matrix (M M^T differs from the identity "
                         "by 0.1)"))
    rot["exterior"]["rotation"] = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]
    p = _yaml_file(tmp_path, "refl.yaml", rot)
    cases.append((p, y1, f"{p}: exterior.rotation: determinant -1 (a reflection, not a rotation)"))
    # Pair-level problems name the right orientation file.
    left = yaml.safe_load((RAW / "frame0.yaml").read_text())
    right = yaml.safe_load(y1.read_text())
    for key, value, message in (
            ("crs", "EPSG:32633", "crs: EPSG:32633 differs from the left orientation's EPSG:32632"),
            ("origin", [0.0, 0.0, 0.0],
             "origin: (0, 0, 0) differs from the left orientation's (501230, 5002470, 200)")):
        p = _yaml_file(tmp_path, f"r_{key}.yaml", {**right, key: value})
        cases.append((RAW / "frame0.yaml", p, f"{p}: {message}"))
    same = json.loads(json.dumps(right))
    same["exterior"]["centre"] = left["exterior"]["centre"]
    p = _yaml_file(tmp_path, "same.yaml", same)
    cases.append((RAW / "frame0.yaml", p, f"{p}: exterior.centre: the two projection centres coincide (no "
                                          "baseline)"))
    below = json.loads(json.dumps(left))
    below["exterior"]["centre"][2] -= 100.0  # straight below frame 0: the epipole is its principal point
    p = _yaml_file(tmp_path, "below.yaml", below)
    o = RC.load_orientation(RAW / "frame0.yaml")
    e = o.K @ o.R @ np.array([0.0, 0.0, -100.0])
    epi = e[:2] / e[2]
    cases.append((Y0, p, f"{Y0}: the epipole lies inside the left image, at ({epi[0]:.1f}, {epi[1]:.1f}): "
                          "the cameras look along the baseline, which planar rectification (stereoRectify) "
                          "cannot handle"))
    for i, (yl, yr, message) in enumerate(cases):
        r = _run("rectify", f0, yl, f1, yr, "-o", tmp_path / f"o{i}")
        assert (r.exit_code, r.output) == (1, f"riverbed: error: {message}\n")
        assert not (tmp_path / f"o{i}").exists()


def test_cli_options_and_outputs(written, raw, tmp_path):
    out, summary = written
    assert sorted(p.name for p in out.iterdir()) == ["left.png", "pair.yaml", "right.png"]  # no temporaries
    assert summary["files"] == {n: (out / n).stat().st_size for n in ("left.png", "right.png", "pair.yaml")}
    assert "images turned by 0 (left) and 0 deg (right)" in (out / "pair.yaml").read_text().splitlines()[1]
    args = ["rectify", F0, Y0, F1, Y1]
    r = _run(*args, "-o", out)
    assert r.exit_code == 1 and r.output == f"riverbed: error: {out / 'left.png'}: output exists; pass " \
                                            "--overwrite to replace it\n"
    assert _run(*args, "-o", out, "--overwrite").exit_code == 0
    r = _run(*args, "-o", tmp_path / "no" / "such")
    no = tmp_path / "no"
    assert r.output == f"riverbed: error: {no / 'such'}: folder {no} does not exist\n"
    assert _run(*args, "-o", tmp_path / "x", "--size", "12x").exit_code == 1
    assert _run(*args, "-o", tmp_path / "x", "--alpha", "1.5").exit_code == 1
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((400, 600), np.uint8))
    r = _run("rectify", F0, Y0, small, Y1, "-o", tmp_path / "s")
    assert r.output == f"riverbed: error: {Y1}: interior.width: 1200 px, but the image is 600 px\n"
    sizeless = yaml.safe_load((RAW / "frame1.yaml").read_text())
    inner = sizeless["interior"]
    del inner["width"], inner["height"], inner["principal_point_mm"]
    inner["principal_point_px"] = [599.5, 399.5]
    r = _run("rectify", F0, Y0, small, _yaml_file(tmp_path, "s.yaml", sizeless), "-o", tmp_path / "s")
    assert r.output == (f"riverbed: error: {small}: image is 600x400 but {F0} is 1200x800 (WxH); "
                        "stereoRectify needs frames of one camera size\n")
    assert not (tmp_path / "s").exists()
    # alpha 1 keeps every source pixel (black corners), alpha 0 none of the border: f shrinks from 0 to 1.
    imgs, (o0, o1) = raw
    r1 = RC.rectify(imgs[0], o0, imgs[1], o1, alpha=1.0)
    assert r1.info["focal_px"] < summary["focal_px"] and min(r1.info["valid_share"]) < 1.0
    r2 = RC.rectify(imgs[0], o0, imgs[1], o1, size=(600, 400))
    assert r2.left.shape == (400, 600)
    assert r2.info["focal_px"] == pytest.approx(summary["focal_px"] / 2, rel=1e-2)


# -- (d) the chain runs on the result ------------------------------------------------------------------------
def match_chain(lidar, out):
    """``riverbed rectify --size 600x400`` of the raw frames into ``out``, then ``riverbed match`` over the LiDAR's
    range (3 px around it): the disparities at the LiDAR points inside both images against the LiDAR's, projected
    through the written pair file. Returns ``points`` (the compared points with a disparity), ``median_px`` (median
    |d - d_lidar|) and ``within_1px`` (% of them within 1 px)."""
    r = _run("rectify", F0, Y0, F1, Y1, "-o", out, "--size", "600x400")
    assert r.exit_code == 0, r.output
    pair = load_pairfile(out / "pair.yaml")
    assert (pair.width, pair.height) == (600, 400) and read_image(pair.left).shape == (400, 600)
    lo, hi = _d_range(pair, lidar)
    r = _run("match", pair.left, pair.right, "--min-disp", math.floor(lo), "--max-disp", math.ceil(hi),
             "-o", out / "disp.tif", "--json")
    assert r.exit_code == 0, r.output
    disp = read_disparity(out / "disp.tif")
    both, xl, yl, xr = _in_both(pair, lidar)
    cols, rows = np.round(xl[both]).astype(int), np.round(yl[both]).astype(int)
    got = disp[rows, cols]
    err = np.abs(got - (xl - xr)[both])
    err = err[np.isfinite(err)]
    return {"points": int(err.size), "median_px": float(np.median(err)), "within_1px": float(100 * (err < 1).mean())}


def test_match_runs_on_the_rectified_pair(lidar, tmp_path):
    """Half-size rectification (--size), load_pairfile, then ``riverbed match``: the disparities agree with
    the LiDAR's projected through the pair file (points inside both images)."""
    c = match_chain(lidar, tmp_path / "half")
    print(f"\nmatch on the rectified pair: {c['points']} LiDAR pixels, median |d - d_lidar| {c['median_px']:.3f} px, "
          f"within 1 px: {c['within_1px']:.1f} %")
    assert c["points"] > 2000 and c["median_px"] < 0.5 and c["within_1px"] > 70
    want = committed("chain")
    assert_near(c["points"], want["points"], FLOOR_COUNT, "compared points")
    assert_near(c["median_px"], want["median_px"], FLOOR_PX, "median |d - d_lidar|")
    assert_near(c["within_1px"], want["within_1px"], 0.1, "within 1 px (%)")


def test_rgb_16_bit_frames(raw, rectified, tmp_path):
    """RGB and 16-bit frames keep their channels and depth; geometry does not depend on them."""
    imgs, _ = raw
    files = []
    for k, img in enumerate(imgs):
        rgb16 = np.repeat(img[:, :, None].astype(np.uint16) * 257, 3, axis=2)
        cv2.imwrite(str(tmp_path / f"c{k}.png"), rgb16)
        files += [tmp_path / f"c{k}.png", RAW / f"frame{k}.yaml"]
    r = _run("rectify", *files, "-o", tmp_path / "out")
    assert r.exit_code == 0, r.output
    left = read_image(tmp_path / "out" / "left.png")
    assert left.dtype == np.uint16 and left.shape == (H, W, 3)
    assert np.abs(left[:, :, 1].astype(float) / 257 - rectified.left).max() <= 1.0
    pair = load_pairfile(tmp_path / "out" / "pair.yaml")
    np.testing.assert_array_equal(pair.P_left, rectified.pair.P_left)


def test_the_pair_file_holds_the_tie_points_range_and_match_pair_searches_it(written, lidar, tmp_path):
    """``rectify`` writes the disparity range its tie points show into pair.yaml; ``riverbed match --pair`` searches
    it (the same map as --min-disp/--max-disp given by hand). The range is the committed one (whole pixels: the
    tie points' span floored and ceiled), around the LiDAR's disparities seen in both images."""
    out, summary = written
    pair = load_pairfile(out / "pair.yaml")
    d_min, d_max = committed("tie_points", "sample", "disparity")
    assert pair.disparity == tuple(float(v) for v in summary["tie_points"]["disparity"]) == (d_min, d_max)
    lo, hi = _d_range(pair, lidar, margin=0.0)
    assert pair.disparity[0] < lo and hi < pair.disparity[1]
    r = _run("match", out / "left.png", out / "right.png", "--pair", out / "pair.yaml", "-o", tmp_path / "a.tif",
             "--json")
    assert r.exit_code == 0, r.output
    assert [json.loads(r.stdout)[k] for k in ("d_min", "d_max")] == [d_min, d_max]
    r = _run("match", out / "left.png", out / "right.png", "--min-disp", d_min, "--max-disp", d_max,
             "-o", tmp_path / "b.tif")
    assert r.exit_code == 0, r.output
    assert np.array_equal(read_disparity(tmp_path / "a.tif"), read_disparity(tmp_path / "b.tif"), equal_nan=True)
    # --min-disp/--max-disp given win over the pair file's
    r = _run("match", out / "left.png", out / "right.png", "--pair", out / "pair.yaml", "--min-disp", d_min + 3,
             "-o", tmp_path / "c.tif", "--json")
    assert [json.loads(r.stdout)[k] for k in ("d_min", "d_max")] == [d_min + 3, d_max]


def test_match_pair_without_a_range_is_one_line(tmp_path):
    bare = tmp_path / "pair.yaml"
    text = (SAMPLE / "pair.yaml").read_text()
    bare.write_text("\n".join(line for line in text.splitlines() if not line.startswith(("left", "right"))))
    assert load_pairfile(bare).disparity is None
    r = _run("match", SAMPLE / "left.png", SAMPLE / "right.png", "--pair", bare, "-o", tmp_path / "d.tif")
    assert r.exit_code == 1
    assert r.output.strip().endswith(
        f"error: {bare}: no disparity range in the pair file (riverbed rectify writes one when it finds tie points);"
        " give --min-disp/--max-disp, --sparse or --range-map")
    assert not (tmp_path / "d.tif").exists()


@pytest.mark.parametrize("given, expected, source", [
    (["--lidar", SAMPLE / "lidar.laz"], [487, 519], "lidar.laz (11772 points seen by both images)"),
    (["--dem", SAMPLE / "gt_dsm.tif"], [487, 518], "gt_dsm.tif (322600 points seen by both images)"),
    (["--heights", "225,275"], [482, 535], "--heights 225,275"),
], ids=["lidar", "dem", "heights"])
def test_the_range_from_the_terrain(tmp_path, lidar, given, expected, source):
    """--lidar / --dem: the disparities of the points both images see (the LiDAR's 491.6..513.9 px) +- 4 px;
    --heights: the left rays cut at both heights (the sample's LiDAR lies within 225..275 m)."""
    r = _run("rectify", F0, Y0, F1, Y1, "-o", tmp_path / "out", "--json", *given)
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert (s["disparity"], s["disparity_from"]) == (expected, source)
    pair = load_pairfile(tmp_path / "out" / "pair.yaml")
    assert list(pair.disparity) == expected
    lo, hi = _d_range(pair, lidar, margin=0.0)
    assert expected[0] <= lo and hi <= expected[1]
    assert 225 < lidar[:, 2].min() and lidar[:, 2].max() < 275


def test_the_terrain_from_two_sources_or_above_the_cameras_is_one_line(tmp_path):
    r = _run("rectify", F0, Y0, F1, Y1, "-o", tmp_path / "out", "--heights", "190,260", "--lidar", SAMPLE / "lidar.laz")
    assert (r.exit_code, r.output) == (1, "riverbed: error: give the terrain by one of --heights LO,HI, --dem DEM or "
                                          "--lidar CLOUD (or none: the range from tie points)\n")
    r = _run("rectify", F0, Y0, F1, Y1, "-o", tmp_path / "out", "--heights", "900,1000")
    assert (r.exit_code, r.output) == (1, "riverbed: error: --heights: the cameras do not look down on the terrain "
                                          "at 900 m (the plane is not in front of the left camera everywhere in its "
                                          "view)\n")
    assert not (tmp_path / "out").exists()
