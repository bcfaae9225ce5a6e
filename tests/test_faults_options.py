"""Absurd parameters and corrupt inputs (issue 44): one line ``riverbed: error: ...``, exit code 1, no output; Ctrl-C
exits 130 with one line and leaves no file behind."""

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError, one_line
from riverbed_cli.geometry.rpc import read_rpc
from riverbed_cli.io.disparity import read_disparity, write_disparity, write_range_map
from riverbed_cli.io.images import read_image
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.scale.block.manifest import _clouds
from conftest import RIVERBED

REPO = Path(__file__).resolve().parents[1]
REINDEER = REPO / "sample_data" / "reindeer"
BLOCK = REPO / "sample_data" / "block"
LEFT, RIGHT, LIDAR = str(REINDEER / "left.png"), str(REINDEER / "right.png"), str(REINDEER / "lidar_5pct.tif")
CORRUPT = ("disparities beyond +-2684 px (e.g. {}; 4 times the image width of 671 px): a corrupt value, not a "
           "disparity of this pair")


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def error_line(r):
    # the one line the command printed on stderr (CliRunner mixes stdout and stderr into output)
    lines = r.output.strip().splitlines()
    assert len(lines) == 1, r.output
    return lines[0]


def refused(r, message):
    assert r.exit_code == 1, r.output
    assert error_line(r) == f"riverbed: error: {message}"


def lidar_with(tmp_path, value, n=5):
    # the bundled LiDAR with n of its points set to value
    sp = read_disparity(LIDAR)
    idx = np.argwhere(np.isfinite(sp))[:n]
    sp[tuple(idx.T)] = value
    path = tmp_path / f"lidar_{value:g}.tif"
    write_disparity(path, sp)
    return path


def crop_pair(tmp_path, width=200, height=150):
    paths = []
    for name, src in (("left", LEFT), ("right", RIGHT)):
        p = tmp_path / f"{name}.png"
        cv2.imwrite(str(p), cv2.imread(src)[:height, :width])
        paths.append(p)
    return paths


def program(*args, **kw):
    # the riverbed program itself (CliRunner bypasses main(): usage errors, Ctrl-C)
    return subprocess.run([*RIVERBED, *map(str, args)], capture_output=True, text=True,
                          **kw)


@pytest.mark.parametrize("value", [1e30, -1e30])
def test_match_refuses_corrupt_lidar_values(tmp_path, value):
    sparse = lidar_with(tmp_path, value)
    r = run("match", LEFT, RIGHT, "--sparse", sparse, "-o", tmp_path / "d.tif")
    refused(r, f"{sparse}: sparse map holds 5 " + CORRUPT.format(f"{value:g}"))
    assert not (tmp_path / "d.tif").exists()


def test_match_refuses_corrupt_lidar_values_with_a_given_range(tmp_path):
    sparse = lidar_with(tmp_path, 1e30)
    r = run("match", LEFT, RIGHT, "--sparse", sparse, "--min-disp", 0, "--max-disp", 100, "-o", tmp_path / "d.tif")
    refused(r, f"{sparse}: sparse map holds 5 " + CORRUPT.format("1e+30"))


def test_match_pair_refuses_corrupt_lidar_values():
    sp = read_disparity(LIDAR)
    sp[np.argwhere(np.isfinite(sp))[0][0], np.argwhere(np.isfinite(sp))[0][1]] = -1e30
    with pytest.raises(RiverbedError, match="sparse map holds 1 disparity beyond"):
        match_pair(read_image(LEFT), read_image(RIGHT), sp)


def test_densify_refuses_corrupt_lidar_values(tmp_path):
    sparse = lidar_with(tmp_path, 1e30)
    r = run("densify", sparse, "-o", tmp_path / "d.tif")
    refused(r, f"{sparse}: sparse map holds 5 " + CORRUPT.format("1e+30"))
    assert not (tmp_path / "d.tif").exists()


def test_range_map_refuses_corrupt_values(tmp_path):
    disp = lidar_with(tmp_path, -1e30)
    r = run("range-map", disp, "-o", tmp_path / "r.tif")
    refused(r, f"{disp}: disparity map holds 5 " + CORRUPT.format("-1e+30"))
    assert not (tmp_path / "r.tif").exists()


def test_match_names_an_out_of_range_range_map(tmp_path):
    rmap = tmp_path / "rm.tif"
    write_range_map(rmap, np.full((555, 671), -1e9, np.float32), np.full((555, 671), 1e9, np.float32))
    r = run("match", LEFT, RIGHT, "--range-map", rmap, "-o", tmp_path / "d.tif")
    refused(r, f"{rmap}: range map values span [-1e+09, 1e+09] px, out of range for images 671 px wide (at most "
               "+-2684 px, 4 times the width)")
    assert not (tmp_path / "d.tif").exists()


def test_match_refuses_a_single_lidar_point(tmp_path):
    sp = np.full((555, 671), np.nan, np.float32)
    sp[100, 100] = 50
    sparse = tmp_path / "one.tif"
    write_disparity(sparse, sp)
    r = run("match", LEFT, RIGHT, "--sparse", sparse, "-o", tmp_path / "d.tif")
    refused(r, f"{sparse}: sparse map has 1 LiDAR point; a LiDAR-guided match needs at least 7 (or match without "
               "--sparse)")
    assert not (tmp_path / "d.tif").exists()
    with pytest.raises(RiverbedError, match="has 1 LiDAR point"):
        match_pair(read_image(LEFT), read_image(RIGHT), sp)


def test_max_disp_beyond_the_width_is_clamped(tmp_path):
    left, right = crop_pair(tmp_path)
    r = run("match", left, right, "--max-disp", 100000, "-o", tmp_path / "d.tif", "--json")
    assert r.exit_code == 0, r.output
    warning = "riverbed: WARNING: disparity range [0, 100000] clamped to [0, 199]: the images are 200 px wide"
    assert r.output.splitlines().count(warning) == 1  # once, not once per tile
    assert json.loads(r.output[r.output.index("{"):])["d_max"] == 199
    res = match_pair(read_image(left), read_image(right), None, 0, 100000, guide="none")
    assert res.info["d_max"] == 199


def test_a_range_beyond_the_width_is_refused(tmp_path):
    left, right = crop_pair(tmp_path)
    r = run("match", left, right, "--min-disp", 500, "--max-disp", 600, "-o", tmp_path / "d.tif")
    refused(r, "disparity range [500, 600] lies beyond what images 200 px wide can match (|d| <= 199)")
    assert not (tmp_path / "d.tif").exists()


def test_window_is_bounded(tmp_path):
    r = run("match", LEFT, RIGHT, "--sparse", LIDAR, "--window", 100001, "-o", tmp_path / "d.tif")
    refused(r, "--window: expected 'auto' or an odd integer from 1 to 101, got 100001")
    left, right = crop_pair(tmp_path, 80, 60)
    sp = np.full((60, 80), np.nan, np.float32)
    sp[::5, ::5] = 20
    write_disparity(tmp_path / "sp.tif", sp)
    r = run("match", left, right, "--sparse", tmp_path / "sp.tif", "--window", 99, "-o", tmp_path / "d.tif")
    refused(r, "--window 99 is larger than the image (80x60 px)")
    assert not (tmp_path / "d.tif").exists()


def test_broken_left_image_is_reported_before_the_range(tmp_path):
    broken = tmp_path / "left.png"
    broken.write_bytes(b"\x89PNG\r\n\x1a\n not a png")
    r = run("match", broken, RIGHT, "-o", tmp_path / "d.tif")
    assert r.exit_code == 1
    line = error_line(r)
    assert line.startswith(f"riverbed: error: {broken}: ") and "--max-disp" not in line


def test_bogus_tiff_header_is_named(tmp_path):
    # a TIFF whose header claims 10^9 x 10^9 pixels
    import struct

    w = h = 10**9
    entries = [(256, 4, w), (257, 4, h), (258, 3, 8), (259, 3, 1), (262, 3, 1), (273, 4, 200), (277, 3, 1),
               (278, 4, h), (279, 4, 16)]
    ifd = struct.pack("<H", len(entries)) + b"".join(
        struct.pack("<HHII", t, ty, 1, v) if ty == 4 else struct.pack("<HHIHH", t, ty, 1, v, 0)
        for t, ty, v in entries) + struct.pack("<I", 0)
    data = b"II*\x00" + struct.pack("<I", 8) + ifd
    bogus = tmp_path / "bogus.tif"
    bogus.write_bytes(data + b"\x00" * (216 - len(data)))
    r = run("densify", bogus, "-o", tmp_path / "d.tif")
    assert r.exit_code == 1
    assert r.output.strip().splitlines()[-1] == (f"riverbed: error: {bogus}: sparse map is 1000000000x1000000000 px, "
                                                 "more than 400000000 pixels (a damaged header?)")
    r = run("range-map", bogus, "-o", tmp_path / "r.tif")
    assert r.output.strip().splitlines()[-1] == (f"riverbed: error: {bogus}: disparity map is 1000000000x1000000000 "
                                                 "px, more than 400000000 pixels (a damaged header?)")


def test_range_map_margin_must_be_finite(tmp_path):
    r = run("range-map", LIDAR, "-o", tmp_path / "r.tif", "--margin", "nan")
    refused(r, "--margin: expected a finite number >= 0, got 'nan'")
    assert not (tmp_path / "r.tif").exists()


def test_densify_names_its_own_scale_option(tmp_path):
    gt = REINDEER / "gt.png"
    r = run("densify", gt, "-o", tmp_path / "d.tif")
    refused(r, f"{gt}: 8-bit PNG disparity: give its scale (e.g. --sparse-scale 4 for Middlebury quarter size)")
    r = run("match", LEFT, RIGHT, "--sparse", gt, "-o", tmp_path / "d.tif")
    refused(r, f"{gt}: 8-bit PNG disparity: give its scale (e.g. --sparse-scale 4 for Middlebury quarter size)")


def test_evaluate_thresholds_must_be_positive(tmp_path):
    dsm = BLOCK / "gt_dsm.tif"
    for bad in ("nan,-1", "0", "inf"):
        r = run("evaluate", "--dsm", dsm, dsm, "--thresholds", bad)
        refused(r, f"--thresholds '{bad}': each threshold must be a finite number > 0")


def test_dsm_fill_holes_is_bounded(tmp_path):
    r = run("dsm", BLOCK / "gt_disparity.tif", BLOCK / "pair.yaml", "-o", tmp_path / "dsm.tif", "--fill-holes",
            1000000)
    refused(r, "--fill-holes must be from 0 to 256 cells, got 1000000")
    assert not (tmp_path / "dsm.tif").exists()


def test_rpc_heights_are_bounded(tmp_path):
    rpc = REPO / "tests" / "data" / "rpc"
    r = run("rectify", "--rpc", rpc / "left.tif", rpc / "left_image.geom", rpc / "right.tif",
            rpc / "right_image.geom", "-o", tmp_path / "out", "--heights", "-1e9,1e9")
    refused(r, "--heights: heights must lie from -1000 to 10000 m (the terrestrial range), got '-1e9,1e9'")
    assert not (tmp_path / "out").exists()


def test_rpc_counts_non_finite_coefficients(tmp_path):
    text = (REPO / "tests" / "data" / "rpc" / "left_image.geom").read_text()
    bad = tmp_path / "bad.geom"
    bad.write_text(text.replace("line_num_coeff_01:  0.0204059031462319", "line_num_coeff_01:  nan"))
    with pytest.raises(RiverbedError, match="LINE_NUM_COEFF: 1 of the 20 coefficients is not finite"):
        read_rpc(bad)


@pytest.mark.parametrize("glob", ["/**/*.laz", "../*.laz", "a/../../*.laz"])
def test_manifest_cloud_globs_stay_in_its_folder(tmp_path, glob):
    manifest = tmp_path / "block.yaml"
    with pytest.raises(RiverbedError) as e:
        _clouds(glob, "pairs[0]", manifest, tmp_path)
    assert str(e.value) == (f"{manifest}: pairs[0].cloud: the glob '{glob}' must stay inside the manifest's folder "
                            "(no absolute path, no '..'); name files outside it one by one")


def test_manifest_cloud_glob_inside_its_folder(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.laz").write_bytes(b"")
    assert _clouds("**/*.laz", "pairs[0]", tmp_path / "block.yaml", tmp_path) == [tmp_path / "a" / "x.laz"]


def test_error_lines_are_one_bounded_line(tmp_path):
    hostile = "\x1b[2J\x1b[31mEPSG:4326\r\nriverbed: ok" + "x" * 2000
    line = one_line(hostile)
    assert len(line) <= 500 and "\x1b" not in line and "\n" not in line and "\r" not in line
    assert line.startswith("\\x1b[2J\\x1b[31mEPSG:4326\\r\\nriverbed: ok") and " ... " in line
    name = tmp_path / "a\x1b[31mb\nc.tif"
    r = run("densify", name, "-o", tmp_path / "d.tif")
    assert r.exit_code == 1
    line = error_line(r)
    assert "\\x1b[31m" in line and "\\n" in line and "\x1b" not in line


@pytest.mark.parametrize("args, message", [
    (("match", "--bogus"), "No such option '--bogus'. (see riverbed match --help)"),
    (("match", "a.png"), "Missing argument 'RIGHT'. (see riverbed match --help)"),
    (("densify", "x.tif", "-o", "y.tif", "--method", "foo"),
     "Invalid value for '--method': 'foo' is not one of 'nearest', 'linear', 'planes', 'guided'. "
     "(see riverbed densify --help)"),
    (("nocmd",), "No such command 'nocmd'. (see riverbed --help)"),
])
def test_usage_errors_are_one_line(tmp_path, args, message):
    r = program(*args, cwd=tmp_path)
    assert r.returncode == 1
    assert r.stderr == f"riverbed: error: {message}\n"
    assert os.listdir(tmp_path) == []


def test_ctrl_c_exits_130_and_leaves_no_file(tmp_path):
    # a pair large enough to match for a few seconds: the sample tiled 3 x 3
    for name, src in (("left", LEFT), ("right", RIGHT)):
        cv2.imwrite(str(tmp_path / f"{name}.png"), np.tile(cv2.imread(src), (3, 3, 1)))
    before = set(os.listdir(tmp_path))
    # SIGINT at its default (a shell's background job would ignore it, and so would the child)
    p = subprocess.Popen([*RIVERBED, "match", "left.png", "right.png", "--max-disp", "200",
                          "-o", "out.tif"], cwd=tmp_path, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60
        # the match streams its tiles into a hidden temporary beside the output: it is matching
        while not any(f.startswith(".out") for f in os.listdir(tmp_path)) and p.poll() is None:
            assert time.monotonic() < deadline
            time.sleep(0.02)
        p.send_signal(signal.SIGINT)
        err = p.communicate(timeout=60)[1]
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, err
    assert err == "riverbed: interrupted\n"
    assert set(os.listdir(tmp_path)) == before


# -- a stereo pair of one view twice ------------------------------------------------------------------------------------

NO_BASELINE = ("the two views have no stereo baseline: the disparity changes by {} px per km of height (the same "
               "image, or one viewing direction, twice?)")


def test_rpc_rectify_of_one_image_twice_and_dsm_of_such_a_pair_are_refused(tmp_path):
    """`rectify --rpc L L L L` exited 0 with a zero baseline, and `dsm` on the pair it wrote raised numpy's
    LinAlgError: both are one line naming the file, and rectify writes nothing."""
    import yaml

    from test_rpc_cli import synthetic_pair  # tests/: a synthetic RPC pair

    left, right, rpc = synthetic_pair(tmp_path / "in")
    r = run("rectify", "--rpc", left, left, left, left, "-o", tmp_path / "same", "--heights", "470,530")
    assert r.exit_code == 1
    line = error_line(r)
    assert line.startswith(f"riverbed: error: {left}: the two views have no stereo baseline: the disparity changes "
                           "by ") and line.endswith(" px per km of height (the same image, or one viewing direction, "
                                                    "twice?)")
    assert not (tmp_path / "same").exists()
    # a real pair's file, its right model replaced by the left one: what the old rectify wrote
    r = run("rectify", "--rpc", left, left, right, rpc, "-o", tmp_path / "ok", "--heights", "470,530", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["disparity_per_metre"] > 1.0
    data = yaml.safe_load((tmp_path / "ok" / "pair.yaml").read_text())
    data["rpc"]["right"] = data["rpc"]["left"]
    data["rectification"]["H_right"] = data["rectification"]["H_left"]
    (tmp_path / "ok" / "same.yaml").write_text(yaml.safe_dump(data))
    write_disparity(tmp_path / "d.tif", np.full((data["rectification"]["height"], data["rectification"]["width"]),
                                                 2.0, np.float32))
    r = run("dsm", tmp_path / "d.tif", tmp_path / "ok" / "same.yaml", "-o", tmp_path / "dsm.tif")
    assert r.exit_code == 1
    assert error_line(r) == f"riverbed: error: {tmp_path / 'ok' / 'same.yaml'}: " + NO_BASELINE.format("0.00")
    assert not (tmp_path / "dsm.tif").exists()
