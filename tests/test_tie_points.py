"""The tie-point check of a rectified pair (riverbed_cli.geometry.tie_points) on the sample block's raw frames."""

import json
import logging
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.geometry.orientation import opk_to_matrix
from riverbed_cli.geometry.tie_points import MIN_POINTS, agreeing, rectification_check, warn_on_parallax

RAW = Path(__file__).resolve().parents[1] / "sample_data" / "block" / "raw"
LIDAR_RANGE = (491.5, 514.0)  # the sample LiDAR's disparities in this rectified pair (riverbed project)


def rectify(tmp_path, right_yaml=RAW / "frame1.yaml", name="r"):
    """``riverbed rectify --json`` of the sample's raw frames 0 and 1: its summary and its warning lines."""
    r = CliRunner().invoke(cli, ["rectify", str(RAW / "frame0.png"), str(RAW / "frame0.yaml"),
                                 str(RAW / "frame1.png"), str(right_yaml), "-o", str(tmp_path / name), "--json"])
    assert r.exit_code == 0, r.output
    warnings = [line for line in r.output.splitlines() if line.startswith("riverbed: WARNING")]
    return json.loads(r.output[r.output.index("{"):]), warnings


def test_a_right_rectification_has_rows_within_a_tenth_of_a_pixel_and_shows_its_range(tmp_path):
    summary, warnings = rectify(tmp_path)
    check = summary["tie_points"]
    assert warnings == []
    # measured: 658 tie points, median |dy| 0.084 px, p90 0.33 px; disparities 477..527 px around the LiDAR's
    assert 600 < check["tie_points"] < 720
    assert check["dy_median_px"] < 0.12 and check["dy_p90_px"] < 0.45 and abs(check["dy_mean_px"]) < 0.05
    lo, hi = check["disparity"]
    assert lo <= LIDAR_RANGE[0] and hi >= LIDAR_RANGE[1] and hi - lo < 2 * (LIDAR_RANGE[1] - LIDAR_RANGE[0]) + 20


def test_a_transposed_rotation_is_seen_and_named(tmp_path):
    """The right frame's rotation pasted transposed (another program's camera-to-world matrix): rectify still runs,
    but its tie points' rows differ by pixels, and one warning line says what is likely wrong."""
    doc = yaml.safe_load((RAW / "frame1.yaml").read_text())
    M = opk_to_matrix(*doc["exterior"].pop("omega_phi_kappa_deg"))
    doc["exterior"]["rotation"] = M.T.tolist()
    path = tmp_path / "frame1_transposed.yaml"
    path.write_text(yaml.safe_dump(doc))
    summary, warnings = rectify(tmp_path, path, "t")
    # measured: the rectified images share no scene on their rows, no tie point matches
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
    """The NGI DMC frames (Orthority's orientations): rows within a tenth of a pixel; the right frame's rotation
    transposed: 6.6 px, warned (docs/rectify.md)."""
    ngi = shared_data / "aerial_ngi_orthority" / "ngi"
    frames = ("3324c_2015_1004_05_0184_RGB", "3324c_2015_1004_05_0182_RGB")
    run = CliRunner().invoke
    r = run(cli, ["orient", str(ngi / "ngi_int_param.yaml"), str(ngi / "ngi_xyz_opk.csv"), "-o", str(tmp_path / "o"),
                  "--images", ",".join(frames)])
    assert r.exit_code == 0, r.output
    doc = yaml.safe_load((tmp_path / "o" / f"{frames[1]}.yaml").read_text())
    M = opk_to_matrix(*doc["exterior"].pop("omega_phi_kappa_deg"))
    doc["exterior"]["rotation"] = M.T.tolist()
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(doc))
    got = {}
    for name, right in (("right", tmp_path / "o" / f"{frames[1]}.yaml"), ("transposed", tmp_path / "t.yaml")):
        r = run(cli, ["rectify", str(ngi / f"{frames[0]}.tif"), str(tmp_path / "o" / f"{frames[0]}.yaml"),
                      str(ngi / f"{frames[1]}.tif"), str(right), "-o", str(tmp_path / name), "--json"])
        assert r.exit_code == 0, r.output
        got[name] = json.loads(r.output[r.output.index("{"):])["tie_points"], r.output
    # measured: 146 tie points, median |dy| 0.075 px; transposed: 6.65 px
    right, transposed = got["right"][0], got["transposed"][0]
    assert 130 < right["tie_points"] < 165 and right["dy_median_px"] < 0.1 and "WARNING" not in got["right"][1]
    assert transposed["dy_median_px"] == pytest.approx(6.65, abs=0.3)
    assert "the tie points' rows differ by 6." in got["transposed"][1]
    # the DEM's disparities there span 440.9..477.3 px (99.9 % below 476.5): the tie points' range, 426..477,
    # holds them (`riverbed match --pair` searches it: tests/test_rectify.py)
    assert right["disparity"][0] <= 440 and 476.5 <= right["disparity"][1] <= 480
    # and matched over it with no DEM nor LiDAR, the DSM is the one an unguided match over the DEM's range gives
    # (docs/rectify.md; measured: median -0.31 m, NMAD 2.96 m, RMSE 5.00 m against the DEM, as bench_overlap's
    # "unguided" row)
    rect = tmp_path / "right"
    for args in (["match", rect / "left.png", rect / "right.png", "--pair", rect / "pair.yaml",
                  "-o", tmp_path / "d.tif"],
                 ["dsm", tmp_path / "d.tif", rect / "pair.yaml", "-o", tmp_path / "dsm.tif"]):
        r = run(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output
    r = run(cli, ["evaluate", "--dsm", str(tmp_path / "dsm.tif"), str(ngi / "dem.tif"), "--json"])
    e = json.loads(r.stdout)
    assert e["median"] == pytest.approx(-0.307, abs=0.05) and e["nmad"] == pytest.approx(2.955, abs=0.05)
    assert e["rmse"] == pytest.approx(5.005, abs=0.1)


def test_the_earth_curvature_bound_the_docs_state(shared_data, tmp_path):
    """docs/rectify.md, Limits: D^2 / 2R at the NGI frames' corners, from the orientation and the DEM's heights."""
    import rasterio

    from riverbed_cli.geometry.orientation import load_orientation

    ngi = shared_data / "aerial_ngi_orthority" / "ngi"
    r = CliRunner().invoke(cli, ["orient", str(ngi / "ngi_int_param.yaml"), str(ngi / "ngi_xyz_opk.csv"), "-o",
                                 str(tmp_path), "--images", "3324c_2015_1004_05_0184_RGB"])
    assert r.exit_code == 0, r.output
    o = load_orientation(tmp_path / "3324c_2015_1004_05_0184_RGB.yaml", (640, 1152))
    with rasterio.open(ngi / "dem.tif") as ds:
        dem = ds.read(1, masked=True)
    above = o.centre[2] - float(np.ma.median(dem))
    corners = np.array([[0, 0], [639, 0], [0, 1151], [639, 1151]], float)
    tan = np.hypot(corners[:, 0] - o.K[0, 2], corners[:, 1] - o.K[1, 2]).max() / o.K[0, 0]
    D = above * tan
    doc = (Path(__file__).resolve().parents[1] / "docs" / "rectify.md").read_text()
    assert f"{D * D / (2 * 6371000.0):.1f} m at the NGI frames' corners (D = {D / 1000:.1f} km, " \
           f"{above / 1000:.1f} km above the ground" in doc
    assert f"{500.0 ** 2 / (2 * 6371000.0) * 100:.0f} cm at 500 m" in doc
