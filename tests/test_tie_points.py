"""The tie-point check of a rectified pair (riverbed_cli.geometry.tie_points) on the sample block's raw frames and
on the NGI frames (RIVERBED_DATA), each also with the right frame's rotation pasted transposed.

The measuring functions here (:func:`sample_checks`, :func:`ngi_checks`) are what ``benchmarks/bench_rectify.py``
runs for docs/rectify.md's tie-point table; the tests hold their figures to the committed ones.
"""

import json
import logging
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.geometry.orientation import opk_to_matrix
from riverbed_cli.geometry.pairfile import load_pairfile
from riverbed_cli.geometry.projection import project_cloud
from riverbed_cli.geometry.tie_points import MIN_POINTS, agreeing, rectification_check, warn_on_parallax
from test_rectify import assert_figures, committed

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data" / "block"
RAW = SAMPLE / "raw"
NGI = "aerial_ngi_orthority/ngi"
NGI_FRAMES = ("3324c_2015_1004_05_0184_RGB", "3324c_2015_1004_05_0182_RGB")  # left (west), right


def rectify(tmp_path, right_yaml=RAW / "frame1.yaml", name="r", left=(RAW / "frame0.png", RAW / "frame0.yaml"),
            right_image=RAW / "frame1.png"):
    """``riverbed rectify --json`` of two frames (by default the sample's raw frames 0 and 1) into ``tmp_path /
    name``: its summary and its warning lines."""
    r = CliRunner().invoke(cli, ["rectify", *map(str, left), str(right_image), str(right_yaml),
                                 "-o", str(tmp_path / name), "--json"])
    assert r.exit_code == 0, r.output
    warnings = [line for line in r.output.splitlines() if line.startswith("riverbed: WARNING")]
    return json.loads(r.output[r.output.index("{"):]), warnings


def transposed(orientation, path):
    """The orientation file ``orientation`` with its rotation pasted transposed (``rotation: Mᵀ``: another program's
    camera-to-world matrix), written to ``path``."""
    doc = yaml.safe_load(Path(orientation).read_text())
    M = opk_to_matrix(*doc["exterior"].pop("omega_phi_kappa_deg"))
    doc["exterior"]["rotation"] = M.T.tolist()
    path.write_text(yaml.safe_dump(doc))
    return path


def warning_kind(warnings):
    """What ``rectify`` warned about: ``None``, ``"too few tie points"`` or ``"rows differ"``."""
    if not warnings:
        return None
    assert len(warnings) == 1, warnings
    return "too few tie points" if "tie points matched" in warnings[0] else "rows differ"


def reference_disparities(rect, cloud):
    """The disparities of the points of ``cloud`` (a LAS/LAZ file or a DEM raster) that both images of the rectified
    pair in folder ``rect`` see, as ``riverbed project`` (and ``rectify --lidar/--dem``) finds them."""
    pair = load_pairfile(rect / "pair.yaml")
    sparse, _ = project_cloud(cloud, pair, shape=(pair.height, pair.width))
    return sparse[np.isfinite(sparse)]


def check_row(summary, warnings, reference=None):
    """A row of the tie-point table: ``rectify``'s check (its ``tie_points`` summary), what it warned about, and with
    ``reference`` disparities their span (``reference``) and the % of them inside the check's range."""
    row = {**summary["tie_points"], "warning": warning_kind(warnings)}
    if reference is not None:
        lo, hi = row["disparity"]
        row["reference"] = [round(float(reference.min()), 1), round(float(reference.max()), 1)]
        row["reference_inside"] = float(100 * ((reference >= lo) & (reference <= hi)).mean())
    return row


def sample_checks(tmp_path):
    """The check of the sample's raw frames 0 + 1 (the LiDAR as the reference) and with frame 1's rotation
    transposed: ``{"sample": row, "sample_transposed": row}`` (:func:`check_row`)."""
    right = rectify(tmp_path)
    bad = rectify(tmp_path, transposed(RAW / "frame1.yaml", tmp_path / "frame1_transposed.yaml"), "t")
    return {"sample": check_row(*right, reference_disparities(tmp_path / "r", SAMPLE / "lidar.laz")),
            "sample_transposed": check_row(*bad)}


def ngi_checks(data, tmp_path):
    """The check of the NGI DMC frames 0184 + 0182 with Orthority's orientations (``riverbed orient``; the reference
    DEM as the reference) and with 0182's rotation transposed: ``{"ngi": row, "ngi_transposed": row}``; the rectified
    pair is ``tmp_path / "right"``."""
    ngi = Path(data) / NGI
    r = CliRunner().invoke(cli, ["orient", str(ngi / "ngi_int_param.yaml"), str(ngi / "ngi_xyz_opk.csv"),
                                 "-o", str(tmp_path / "o"), "--images", ",".join(NGI_FRAMES)])
    assert r.exit_code == 0, r.output
    left = (ngi / f"{NGI_FRAMES[0]}.tif", tmp_path / "o" / f"{NGI_FRAMES[0]}.yaml")
    right_yaml = tmp_path / "o" / f"{NGI_FRAMES[1]}.yaml"
    rows = {}
    for name, orientation in (("right", right_yaml), ("transposed", transposed(right_yaml, tmp_path / "t.yaml"))):
        summary, warnings = rectify(tmp_path, orientation, name, left, ngi / f"{NGI_FRAMES[1]}.tif")
        reference = reference_disparities(tmp_path / name, ngi / "dem.tif") if name == "right" else None
        rows["ngi" if name == "right" else "ngi_transposed"] = check_row(summary, warnings, reference)
    return rows


#: the figures of a check row held to the committed ones by :func:`~test_rectify.assert_figures`
CHECKED = ("tie_points", "dy_median_px", "dy_p90_px", "dy_mean_px", "warning")


def _assert_row(row, want, what):
    """A check row is the committed one: its range, the reference's span (0.1 px) and the share inside the range
    (the projection is deterministic arithmetic) equal, the tie points' figures by :func:`assert_figures`."""
    assert set(row) == set(want), what
    assert row.get("disparity") == want.get("disparity") and row.get("reference") == want.get("reference"), what
    if "reference_inside" in want:
        assert row["reference_inside"] == pytest.approx(want["reference_inside"], abs=1e-3), what
    assert_figures(row, {k: v for k, v in want.items() if k in CHECKED}, what=what)


def test_a_right_rectification_has_rows_within_a_tenth_of_a_pixel_and_shows_its_range(tmp_path):
    rows = sample_checks(tmp_path)
    check = rows["sample"]
    assert check["warning"] is None
    assert check["dy_median_px"] < 0.1
    # the range holds the LiDAR's disparities, and is no wider than twice their span and a margin
    lo, hi = check["disparity"]
    ref_lo, ref_hi = check["reference"]
    assert check["reference_inside"] == 100.0 and hi - lo < 2 * (ref_hi - ref_lo) + 20
    _assert_row(check, committed("tie_points", "sample"), "sample")
    # the right frame's rotation pasted transposed: the rectified images share no scene on their rows, no tie point
    # matches, and one warning line says what is likely wrong
    assert rows["sample_transposed"] == committed("tie_points", "sample_transposed") == {
        "tie_points": 0, "warning": "too few tie points"}


def test_a_transposed_rotation_is_seen_and_named(tmp_path):
    """The right frame's rotation pasted transposed (another program's camera-to-world matrix): rectify still runs,
    but its tie points do not match, and one warning line says what is likely wrong."""
    path = transposed(RAW / "frame1.yaml", tmp_path / "frame1_transposed.yaml")
    summary, warnings = rectify(tmp_path, path, "t")
    assert summary["tie_points"] == {"tie_points": 0}
    assert warnings == [f"riverbed: WARNING: {tmp_path / 't'}: only 0 tie points matched: the rectified images show "
                        "too little texture, or not the same scene on their rows (the orientations or their "
                        "convention likely wrong)"]


def test_repeated_texture_matches_are_left_out_of_the_range():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 500, (200, 2))
    d = 100 + 0.02 * pts[:, 0]
    d[:5] = [-300, 900, 20, 400, 170]  # isolated wrong columns
    keep = agreeing(pts, d)
    assert not keep[:5].any() and keep[5:].all()


def test_too_few_tie_points_warn(caplog):
    flat = np.full((60, 80), 128, np.uint8)
    check = rectification_check(flat, flat)
    assert check == {"tie_points": 0}
    with caplog.at_level(logging.WARNING):
        assert warn_on_parallax(check, "x")
    assert "x: only 0 tie points matched: the rectified images show too little texture" in caplog.text


def test_the_real_ngi_pair_and_its_transposed_twin(shared_data, tmp_path):
    """The NGI DMC frames (Orthority's orientations): rows within a tenth of a pixel and a range that holds nearly
    all of the DEM's disparities; the right frame's rotation transposed: rows pixels apart, warned (docs/rectify.md)."""
    rows = ngi_checks(shared_data, tmp_path)
    right, bad = rows["ngi"], rows["ngi_transposed"]
    assert right["warning"] is None and right["dy_median_px"] < 0.1 and right["reference_inside"] > 99.5
    assert bad["warning"] == "rows differ" and bad["dy_median_px"] > 1.0
    _assert_row(right, committed("tie_points", "ngi"), "NGI")
    _assert_row(bad, committed("tie_points", "ngi_transposed"), "NGI transposed")
    # matched over the tie points' range with no DEM nor LiDAR (`riverbed match --pair`), the DSM is the one an
    # unguided match over the DEM's range gives: bench_overlap's "unguided" NGI row (docs/rectify.md), to 5 cm in
    # median and NMAD and 10 cm in RMSE (the two ranges differ by a few px at each end)
    run = CliRunner().invoke
    rect = tmp_path / "right"
    for args in (["match", rect / "left.png", rect / "right.png", "--pair", rect / "pair.yaml",
                  "-o", tmp_path / "d.tif"],
                 ["dsm", tmp_path / "d.tif", rect / "pair.yaml", "-o", tmp_path / "dsm.tif"]):
        r = run(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output
    r = run(cli, ["evaluate", "--dsm", str(tmp_path / "dsm.tif"), str(shared_data / NGI / "dem.tif"), "--json"])
    e = json.loads(r.stdout)
    overlap = json.loads((REPO / "benchmarks" / "results_overlap.json").read_text())
    unguided = next(o for o in overlap if o["route"].startswith("NGI") and o["method"] == "unguided")
    assert e["median"] == pytest.approx(unguided["median"], abs=0.05)
    assert e["nmad"] == pytest.approx(unguided["nmad"], abs=0.05)
    assert e["rmse"] == pytest.approx(unguided["rmse"], abs=0.1)


def test_the_ngi_data_facts_the_docs_state(shared_data, tmp_path):
    """docs/rectify.md's facts of the NGI data, from the orientation and the DEM: the DEM's cell and the frames'
    ground pixel at nadir (the overlap table's caption), and, in Limits, the earth's curvature D^2 / 2R at the
    frames' corners."""
    import rasterio

    from riverbed_cli.geometry.orientation import load_orientation

    ngi = shared_data / NGI
    r = CliRunner().invoke(cli, ["orient", str(ngi / "ngi_int_param.yaml"), str(ngi / "ngi_xyz_opk.csv"), "-o",
                                 str(tmp_path), "--images", NGI_FRAMES[0]])
    assert r.exit_code == 0, r.output
    o = load_orientation(tmp_path / f"{NGI_FRAMES[0]}.yaml", (640, 1152))
    with rasterio.open(ngi / "dem.tif") as ds:
        dem = ds.read(1, masked=True)
        cell = ds.res
    above = o.centre[2] - float(np.ma.median(dem))
    corners = np.array([[0, 0], [639, 0], [0, 1151], [639, 1151]], float)
    tan = np.hypot(corners[:, 0] - o.K[0, 2], corners[:, 1] - o.K[1, 2]).max() / o.K[0, 0]
    D = above * tan
    doc = (REPO / "docs" / "rectify.md").read_text()
    assert cell[0] == cell[1]
    assert f"reference DEM ({cell[0]:.0f} m terrain model; its raw frames {above / o.K[0, 0]:.1f} m per pixel at " \
           "nadir)" in " ".join(doc.split())
    assert f"{D * D / (2 * 6371000.0):.1f} m at the NGI frames' corners (D = {D / 1000:.1f} km, " \
           f"{above / 1000:.1f} km above the ground" in doc
    assert f"{500.0 ** 2 / (2 * 6371000.0) * 100:.0f} cm at 500 m" in doc
