"""docs/rectify.md's figures: its generated blocks are what benchmarks/bench_rectify.py makes of the committed
benchmarks/results_rectify.json, the claims its text makes hold on those figures, the constants its text states are
the code's, and no other figure stands in its text."""

import json
import math
import re
import sys

import numpy as np
import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_rectify as br  # noqa: E402
import test_orient as TO  # noqa: E402
import test_rectify as TR  # noqa: E402

from riverbed_cli.geometry import frame_range, tie_points  # noqa: E402
from riverbed_cli.sample.spec import SIZES  # noqa: E402

R = json.loads((REPO / "benchmarks" / "results_rectify.json").read_text())
DOC = (REPO / "docs" / "rectify.md").read_text()
FLAT = " ".join(DOC.split())  # the text with its line breaks as spaces


@pytest.mark.parametrize("table, begin, end", br.TABLES,
                         ids=[b.split("bench_rectify ")[1].split(":")[0] for _, b, _ in br.TABLES])
def test_each_generated_block_is_the_committed_results(table, begin, end):
    block = DOC.split(begin)[1].split(end)[0]
    assert block.strip() == table(R).strip()


def test_every_case_is_measured():
    assert list(R["rows"]) == [k for k, _ in br.ROWS] and list(R["tie_points"]) == [k for k, _, _ in br.CHECKS]
    assert set(R["orient"]) == {k for k, _, _ in br.IMPORTS} | {"odm_vs_orthority"}
    assert all(R["rows"][k]["regions"] == 9 for k in R["rows"])


def test_rows_agree_and_the_measurement_can_fail():
    """'the rectified frames, with or without distortion, pass, as close as the generator's exact rows (the p95 is
    feature noise, not geometry); both wrong rectifications fail. Lucas-Kanade's positions spread less than SIFT's
    own.'"""
    rows = R["rows"]
    for case in ("rectified", "generator", "distorted"):
        assert TR.rows_agree(rows[case]), case
        assert rows[case]["median"] <= rows["generator"]["median"] + 0.03, case
        assert rows[case]["p95"] <= rows["generator"]["p95"] + 0.05, case
        assert rows[case]["median"] < rows[case]["sift_median"] and rows[case]["p95"] < rows[case]["sift_p95"], case
    for case in ("omega", "distorted_without_model"):
        assert not TR.rows_agree(rows[case]), case
    # each fails by the systematic part, the regional medians, not by noise alone
    assert rows["omega"]["regional_max"] > 2 * TR.ROWS_AGREE_PX
    assert rows["distorted_without_model"]["regional_max"] > 10 * TR.ROWS_AGREE_PX


def test_the_cameras_of_the_written_images_and_the_chain():
    """'the maps are float32: their rounding is what remains'; 'a half-pixel convention error would show as 0.5 px';
    '`riverbed match` on the result agrees with the LiDAR's disparities'."""
    ulp = float(np.spacing(np.float32(TR.W)))  # one float32 step at the frame's width
    for case in ("plain", "distorted"):
        assert max(R["cameras"][case]["worst_px"]) < ulp, case
    assert R["content"]["median_px"] < 0.1 and R["content"]["features"] > 1000
    chain = R["chain"]
    assert chain["median_px"] < 0.5 and chain["within_1px"] > 70 and chain["points"] > 2000


def test_the_tie_point_check():
    """'With the right orientations the tie points' rows agree to a tenth of a pixel and the range holds all or nearly
    all of the reference's disparities; with a transposed rotation the rectified images show too few tie points, or
    rows pixels apart, and `rectify` warns.' And on the NGI frames 'the range holds nearly all of the DEM's
    disparities'."""
    t = R["tie_points"]
    for case in ("sample", "ngi"):
        assert t[case]["warning"] is None and t[case]["dy_median_px"] < 0.1, case
        assert t[case]["tie_points"] >= tie_points.MIN_POINTS
    assert t["sample"]["reference_inside"] == 100.0 and t["ngi"]["reference_inside"] > 99.5
    assert t["sample_transposed"] == {"tie_points": 0, "warning": "too few tie points"}
    assert t["ngi_transposed"]["warning"] == "rows differ"
    assert t["ngi_transposed"]["dy_median_px"] > tie_points.WARN_PX


def test_the_imported_orientations():
    """'lie on rows within half a pixel; with the right frame's rotation transposed, pixels apart'; 'the rotations
    [differ] by the meridian convergence'; 'they agree to millimetres and thousandths of a degree'."""
    o = R["orient"]
    assert o["ngi"]["median_px"] < 0.5 and o["odm"]["median_px"] < 0.5 and o["ngi_transposed"]["median_px"] > 1.0
    v = o["odm_vs_orthority"]
    assert max(abs(a - v["convergence_deg"]) for a in v["rotations_deg"]) < 0.001
    assert v["centres_m"][0] > 1.0 and v["corrected_centres_m"] < 0.005 and v["corrected_rotations_deg"] < 0.002


def test_the_constants_the_text_states():
    """The rule constants and the inputs of the cases are the code's."""
    spec = SIZES["small"]
    assert f"{spec.baseline / spec.flying_height:g} on the sample block, {100 * spec.overlap:.0f} % overlap" in FLAT
    o = TR.RC.load_orientation(TR.Y0, (TR.W, TR.H))
    # the wrong omega and what it does to the rows at the raw frames' focal length
    assert f"ω off by {TR.OMEGA_OFF_DEG}° moves its rows by " \
           f"{math.radians(TR.OMEGA_OFF_DEG) * o.K[0, 0]:.2f} px at f = {o.K[0, 0]:.0f} px" in FLAT
    # the distortion model and its largest displacement (at a corner)
    k1, k2, p1, p2, k3 = TR.DIST
    assert k3 == 0 and f"k1 {k1:g}, k2 {k2:g}, p1 {p1:g}, p2 {p2:g} (~12 px at the corners)" in FLAT
    x = (np.array([0.0, TR.W - 1]) - o.K[0, 2]) / o.K[0, 0]
    y = (np.array([0.0, TR.H - 1]) - o.K[1, 2]) / o.K[1, 1]
    x, y = (a.ravel() for a in np.meshgrid(x, y))
    r2 = x * x + y * y
    dx = x * (k1 * r2 + k2 * r2 * r2) + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    dy = y * (k1 * r2 + k2 * r2 * r2) + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    assert round(float(np.hypot(dx, dy).max() * o.K[0, 0])) == 12
    assert f"within {TR.ROWS_AGREE_PX} px and the mean within {TR.ROWS_MEAN_PX} px" in FLAT
    # the tie points: the warning thresholds, the range's margins and trim
    assert f"A median above {tie_points.WARN_PX:g} px, or fewer than {tie_points.MIN_POINTS} tie points" in FLAT
    assert f"{tie_points.FEATURES:,} ORB features per image" in FLAT
    assert f"{100 * tie_points.TRIM:g} % at each end left out), widened by {tie_points.RANGE_MARGIN} px and by half" \
           in FLAT and tie_points.RANGE_GROWTH == 0.5
    assert FLAT.count(f"± {frame_range.MARGIN_PX} px") == 2
    assert f"on a {frame_range.GRID} x {frame_range.GRID} grid" in FLAT
    # the round trips of the import: the tolerances the test holds each format to
    tol = {name: (c, r) for name, (_, _, _, c, r) in TO.EXPORTS.items()}
    assert {tol[n] for n in tol if not n.startswith("opensfm")} == {(1e-9, 1e-9)} and tol["opensfm"] == (1e-7, 1e-8)
    assert "come back to 1e-9 (OpenSfM, which goes through PROJ both ways: centres to 1e-7, rotation matrices to " \
           "1e-8)" in FLAT


#: Every figure with a unit, a percentage or a decimal in the text outside the generated blocks and code: each a rule
#: constant, an input of a case or a data fact (checked above, in tests/test_tie_points.py, or by the pages' format
#: tables), never a measurement. ``(number, unit): why``.
CONSTANTS = {
    ("0.001", "°"): "Orthority's CSV rounding", ("1", "mm"): "Orthority's CSV rounding",
    ("0.005", "°"): "OMEGA_OFF_DEG", ("0.26", "px"): "OMEGA_OFF_DEG at f = 3000 px",
    ("3000", "px"): "the raw frames' focal length",
    ("0.1", "px"): "ROWS_AGREE_PX", ("0.03", "px"): "ROWS_MEAN_PX",
    ("0.16", ""): "the sample's B/H", ("60", "%"): "the sample's overlap",
    ("0.3", ""): "DIST k1", ("0.2", ""): "DIST k2", ("0.0005", ""): "DIST p1, p2", ("12", "px"): "DIST at a corner",
    ("0.5", ""): "COLMAP's half pixel; RANGE_GROWTH; formulas of the format table",
    ("0.5", "%"): "tie_points.TRIM", ("0.5", "px"): "a half-pixel convention error",
    ("0.75", ""): "Lowe's ratio of row_agreement", ("15", "px"): "Lucas-Kanade's window",
    ("1", "px"): "tie_points.WARN_PX; RANSAC's threshold", ("4", "px"): "MARGIN_PX, RANGE_MARGIN",
    ("1", "m"): "orient's axis step", ("32", "px"): "OpenCV's INTER_BITS (1/32 px)",
    ("90", "°"): "turns; the ODM headings", ("180", "°"): "turns",
    ("1e-5", ""): "the rotation matrix tolerance", ("1e-7", ""): "round trip", ("1e-8", ""): "round trip",
    ("1e-9", ""): "round trip",
    ("24", "m"): "NGI DEM cell (test_tie_points)", ("5.8", "m"): "NGI ground pixel (test_tie_points)",
    ("1.1", "m"): "earth curvature (test_tie_points)", ("3.8", "km"): "earth curvature (test_tie_points)",
    ("4.8", "km"): "earth curvature (test_tie_points)", ("2", "cm"): "earth curvature (test_tie_points)",
    ("500", "m"): "earth curvature (test_tie_points)",
}
FIGURE = re.compile(r"(?<![\w.])(\d+(?:[.,]\d+)*(?:e-?\d+)?) ?(px|mm|cm|km|m|°|%|s|deg)?(?!\w)")


def test_no_hand_typed_measurement_outside_the_generated_blocks():
    text = re.sub(r"<!-- ([^>]*): begin -->.*?<!-- \1: end -->", "", DOC, flags=re.S)
    text = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    found = {(num, unit or "") for num, unit in FIGURE.findall(text) if unit or "." in num or "e" in num}
    assert found <= set(CONSTANTS), sorted(found - set(CONSTANTS))
