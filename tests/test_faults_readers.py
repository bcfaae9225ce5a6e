"""Readers that fail loudly (issue 44): a truncated, corrupt, hostile or endless input file is one line
``riverbed: error: <path>: <problem>``, exit code 1 and no output, never a traceback, zeros or exhausted memory."""

import json
import os
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.io.disparity import write_disparity, write_range_map
from riverbed_cli.io.textfiles import MAX_DEPTH, MAX_YAML_NODES, parse_yaml
from riverbed_cli.io.windowed import read_range_map
from conftest import PYTHON, RIVERBED

REPO = Path(__file__).resolve().parents[1]
CONES = REPO / "tests" / "data" / "cones"
REINDEER = REPO / "sample_data" / "reindeer"
BLOCK = REPO / "sample_data" / "block"
DEEP = 10_000


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def assert_one_line(r, path, problem):
    assert r.exit_code == 1, r.output
    assert r.output == f"riverbed: error: {path}: {problem}\n"


def truncated(src, dst, keep=0.5):
    data = Path(src).read_bytes()
    Path(dst).write_bytes(data[:int(len(data) * keep)])
    return Path(dst)


def billion_laughs(path, levels=10):
    """A YAML alias bomb: 9 ** levels strings behind a file of a few hundred bytes."""
    lines = ['a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    names = "abcdefghijklmnop"
    for i in range(1, levels):
        lines.append(f"{names[i]}: &{names[i]} [" + ", ".join([f"*{names[i - 1]}"] * 9) + "]")
    lines.append(f"pairs: [*{names[levels - 1]}]")
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


# --- images: truncated or corrupt files are errors, not black rows ---------------------------------------------


def _bad_images(tmp_path):
    """name -> (bad file, its one-line problem)."""
    left = CONES / "im2.png"
    img = cv2.imread(str(left), cv2.IMREAD_UNCHANGED)
    jpg = tmp_path / "full.jpg"
    cv2.imwrite(str(jpg), img)
    tif = tmp_path / "full.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(tif, "w", driver="GTiff", width=img.shape[1], height=img.shape[0], count=3,
                           dtype="uint8") as ds:  # strips, uncompressed: the directory comes first
            ds.write(np.moveaxis(img[:, :, ::-1], -1, 0))
    corrupt = bytearray(left.read_bytes())
    corrupt[len(corrupt) // 2:len(corrupt) // 2 + 64] = bytes(64)  # inside the image data; IEND intact
    (tmp_path / "corrupt.png").write_bytes(bytes(corrupt))
    return {
        "png": (truncated(left, tmp_path / "cut.png"), "truncated PNG (its chunks end before an IEND chunk)"),
        "jpeg": (truncated(jpg, tmp_path / "cut.jpg"), "truncated JPEG (no end-of-image marker FFD9 at its end)"),
        "tiff": (truncated(tif, tmp_path / "cut.tif"), "cannot read image data (corrupt or truncated file)"),
        "corrupt png": (tmp_path / "corrupt.png", "cannot decode PNG (corrupt or truncated data)"),
    }


@pytest.mark.parametrize("kind", ["png", "jpeg", "tiff", "corrupt png"])
def test_match_refuses_a_truncated_left_image(tmp_path, kind):
    bad, problem = _bad_images(tmp_path)[kind]
    out = tmp_path / "out.tif"
    r = run("match", bad, CONES / "im6.png", "-o", out, "--max-disp", 64)
    assert_one_line(r, bad, problem)
    assert not out.exists()


@pytest.mark.parametrize("kind", ["png", "jpeg"])
def test_densify_guided_refuses_a_truncated_image(tmp_path, kind):
    bad, problem = _bad_images(tmp_path)[kind]
    sparse = tmp_path / "sparse.tif"
    write_disparity(sparse, np.where(np.arange(375 * 450).reshape(375, 450) % 97 == 0, 20.0, np.nan))
    out = tmp_path / "dense.tif"
    r = run("densify", sparse, "--method", "guided", "--image", bad, "-o", out)
    assert_one_line(r, bad, problem)
    assert not out.exists()


def test_truncated_png_prints_one_line_in_a_real_process(tmp_path):
    # libpng prints its own "Read Error" on the process's stderr when it meets a truncated file
    bad, problem = _bad_images(tmp_path)["corrupt png"]
    out = tmp_path / "out.tif"
    p = subprocess.run([*RIVERBED, "match", str(bad), str(CONES / "im6.png"), "-o",
                        str(out), "--max-disp", "64"], capture_output=True, text=True, timeout=120)
    assert (p.returncode, p.stdout, p.stderr) == (1, "", f"riverbed: error: {bad}: {problem}\n")
    assert not out.exists()


# --- disparity maps and range maps -----------------------------------------------------------------------------


def _tiled_tif(path, bands=1):
    a = np.random.default_rng(0).uniform(0, 60, (bands, 600, 600)).astype(np.float32)
    if bands == 2:
        write_range_map(path, a[0], a[0] + 5)
    else:
        write_disparity(path, a[0])
    return path


def _cut_tif(src, dst):
    # keep the directory (GDAL writes it first) and lose the last tiles
    dst = truncated(src, dst, keep=0.6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(dst):
            pass  # the precondition: the header still opens, the data does not read
    return dst


def test_evaluate_refuses_truncated_disparity_maps(tmp_path):
    gt = CONES / "disp2.png"
    png = truncated(gt, tmp_path / "d.png")
    for args in ((png, gt), (gt, png)):
        r = run("evaluate", *args, "--disp-scale", 4, "--gt-scale", 4)
        assert_one_line(r, png, "truncated PNG (its chunks end before an IEND chunk)")
    png16 = truncated(REINDEER / "gt.png", tmp_path / "d16.png")
    r = run("evaluate", png16, REINDEER / "gt.png", "--gt-scale", 1)
    assert_one_line(r, png16, "truncated PNG (its chunks end before an IEND chunk)")

    tif = _cut_tif(_tiled_tif(tmp_path / "full.tif"), tmp_path / "d.tif")
    r = run("evaluate", tif, gt)
    assert_one_line(r, tif, "cannot read TIFF disparity (corrupt or truncated data)")

    pfm = tmp_path / "full.pfm"
    write_disparity(pfm, np.ones((10, 12), np.float32))
    cut = truncated(pfm, tmp_path / "d.pfm", keep=0.8)
    r = run("evaluate", cut, gt)
    header = len(b"Pf\n12 10\n-1.0\n")
    assert_one_line(r, cut, f"truncated PFM: 12x10 needs 480 data bytes, the file has {cut.stat().st_size - header}")


def test_match_refuses_a_range_map_with_truncated_tiles(tmp_path):
    img = np.random.default_rng(1).integers(0, 256, (600, 600), dtype=np.uint8)
    left, right = tmp_path / "l.png", tmp_path / "r.png"
    cv2.imwrite(str(left), img)
    cv2.imwrite(str(right), img)
    bad = _cut_tif(_tiled_tif(tmp_path / "full.tif", bands=2), tmp_path / "range.tif")
    problem = "cannot read raster data (corrupt or truncated file)"
    with pytest.raises(RiverbedError) as e:
        read_range_map(bad)
    assert str(e.value) == f"{bad}: {problem}"
    out = tmp_path / "out.tif"
    r = run("match", left, right, "-o", out, "--max-disp", 64, "--range-map", bad)
    # one line naming the file (riverbed_cli/scale/match_files.py names it a second time: not a reader's doing)
    assert r.exit_code == 1 and r.output.startswith(f"riverbed: error: {bad}: ") and r.output.count("\n") == 1
    assert r.output.endswith(f"{bad}: {problem}\n")
    assert not out.exists()


def test_match_refuses_a_sparse_tiff_with_truncated_tiles(tmp_path):
    bad = _cut_tif(_tiled_tif(tmp_path / "full.tif"), tmp_path / "sparse.tif")
    img = np.random.default_rng(1).integers(0, 256, (600, 600), dtype=np.uint8)
    left, right = tmp_path / "l.png", tmp_path / "r.png"
    cv2.imwrite(str(left), img)
    cv2.imwrite(str(right), img)
    out = tmp_path / "out.tif"
    r = run("match", left, right, "-o", out, "--sparse", bad)
    assert_one_line(r, bad, "cannot read raster data (corrupt or truncated file)")  # rasterio's names no file
    assert not out.exists()


# --- structured text files: nesting and alias bombs --------------------------------------------------------------


def _deep_json(path):
    Path(path).write_text("[" * DEEP + "]" * DEEP)
    return Path(path)


def _deep_yaml(path, key="P_left"):
    Path(path).write_text(f"{key}: " + "[" * DEEP + "]" * DEEP + "\n")
    return Path(path)


DEEP_JSON = f"invalid JSON at line 1: nested more than {MAX_DEPTH} levels deep"


def deep_yaml(key):
    """The problem reported for :func:`_deep_yaml` under ``key``: the first bracket past the limit."""
    # the file's mapping is the first level, so the 64th bracket opens the 65th
    return f"invalid YAML at line 1, column {len(key) + 2 + MAX_DEPTH}: nested more than {MAX_DEPTH} levels deep"


BOMB = f"invalid YAML at line 7, column 8: aliases expand to more than {MAX_YAML_NODES} nodes"


@pytest.mark.parametrize("kind", ["deep json", "deep yaml", "bomb"])
def test_pair_file_bounds(tmp_path, kind):
    bad, problem = {"deep json": lambda: (_deep_json(tmp_path / "pair.json"), DEEP_JSON),
                    "deep yaml": lambda: (_deep_yaml(tmp_path / "pair.yaml"), deep_yaml("P_left")),
                    "bomb": lambda: (billion_laughs(tmp_path / "pair.yaml"), BOMB)}[kind]()
    out = tmp_path / "sparse.tif"
    r = run("project", BLOCK / "lidar.laz", bad, "-o", out)
    assert_one_line(r, bad, problem)
    assert not out.exists()


def test_registration_file_bounds(tmp_path):
    bad = _deep_json(tmp_path / "reg.json")
    out = tmp_path / "sparse.tif"
    r = run("project", BLOCK / "lidar.laz", BLOCK / "pair.yaml", "--registration", bad, "-o", out)
    assert_one_line(r, bad, DEEP_JSON)
    assert not out.exists()


@pytest.mark.parametrize("kind", ["deep yaml", "deep json text", "bomb"])
def test_block_manifest_bounds(tmp_path, kind):
    bad, problem = {"deep yaml": lambda: (_deep_yaml(tmp_path / "m.yaml", "pairs"), deep_yaml("pairs")),
                    "deep json text": lambda: (_deep_json(tmp_path / "m.yaml"),
                                               f"invalid YAML at line 1, column {MAX_DEPTH + 1}: nested more than "
                                               f"{MAX_DEPTH} levels deep"),
                    "bomb": lambda: (billion_laughs(tmp_path / "m.yaml"), BOMB)}[kind]()
    out = tmp_path / "out"
    r = run("block", bad, "-o", out)
    assert_one_line(r, bad, problem)
    assert not out.exists()


def test_orientation_file_bounds(tmp_path):
    bad = billion_laughs(tmp_path / "frame0.yaml")
    out = tmp_path / "rect"
    r = run("rectify", BLOCK / "raw" / "frame0.png", bad, BLOCK / "raw" / "frame1.png", BLOCK / "raw" / "frame1.yaml",
            "-o", out)
    assert_one_line(r, bad, BOMB)
    assert not out.exists()


def test_rpc_json_bounds(tmp_path):
    bad = tmp_path / "left_rpc.json"
    bad.write_text('{"rpc": ' + "[" * DEEP + "]" * DEEP + "}")
    img = tmp_path / "left.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(img, "w", driver="GTiff", width=8, height=8, count=1, dtype="uint8") as ds:
            ds.write(np.zeros((1, 8, 8), np.uint8))
    out = tmp_path / "rect"
    r = run("rectify", "--rpc", img, bad, img, bad, "-o", out, "--heights", "0,100")
    assert_one_line(r, bad, DEEP_JSON)
    assert not out.exists()


def test_shared_anchors_stay_allowed(tmp_path):
    # split-rpc manifests share one ROI mapping per pair through an anchor: aliases within the bound are read
    text = "roi: &r {col: 0, row: 0, w: 100, h: 100}\n" + "".join(f"p{i}: *r\n" for i in range(1000))
    data = parse_yaml(text, tmp_path / "m.yaml")
    assert data["p999"] == {"col": 0, "row": 0, "w": 100, "h": 100}


def test_huge_integers_are_one_line(tmp_path):
    bad = tmp_path / "pair.json"
    bad.write_text('{"width": ' + "9" * 5000 + "}")
    r = run("project", BLOCK / "lidar.laz", bad, "-o", tmp_path / "s.tif")
    assert r.exit_code == 1 and r.output.startswith(f"riverbed: error: {bad}: invalid JSON: ")
    assert r.output.count("\n") == 1


# --- endless files ------------------------------------------------------------------------------------------------


def _zero(tmp_path, name):
    link = tmp_path / name
    link.symlink_to("/dev/zero")  # the extension some readers need, the endless stream behind it
    return link


@pytest.mark.parametrize("reader", ["image", "disparity", "pair", "registration", "manifest", "orientation",
                                    "rpc", "benchmark"])
def test_dev_zero_is_not_a_file(tmp_path, reader):
    z = _zero(tmp_path, {"image": "zero.png", "disparity": "zero.png", "rpc": "zero.json"}.get(reader, "zero.yaml"))
    out = tmp_path / "out"
    out_tif = tmp_path / "out.tif"
    args = {
        "image": ("match", z, CONES / "im6.png", "-o", out_tif, "--max-disp", 64),
        "disparity": ("evaluate", z, CONES / "disp2.png"),
        "pair": ("project", BLOCK / "lidar.laz", z, "-o", out_tif),
        "registration": ("project", BLOCK / "lidar.laz", BLOCK / "pair.yaml", "--registration", z, "-o", out_tif),
        "manifest": ("block", z, "-o", out),
        "orientation": ("rectify", BLOCK / "raw" / "frame0.png", z, BLOCK / "raw" / "frame1.png",
                        BLOCK / "raw" / "frame1.yaml", "-o", out),
        "rpc": ("rectify", "--rpc", CONES / "im2.png", z, CONES / "im6.png", z, "-o", out, "--heights", "0,100"),
        "benchmark": ("benchmark", tmp_path, "--layout", "middlebury", "-o", out, "--check", z),
    }[reader]
    r = run(*args)
    assert_one_line(r, z, "not a file")
    assert not out.exists() and not out_tif.exists()


def _measured(args):
    """Exit code, stderr, seconds and peak memory (MiB) of ``python -m riverbed_cli ARGS`` in a process of its own
    (a fresh parent, so RUSAGE_CHILDREN holds that one child)."""
    probe = ("import json, resource, subprocess, sys, time\n"
             "t = time.perf_counter()\n"
             f"p = subprocess.run([sys.executable, *{list(PYTHON[1:])!r}, '-m', 'riverbed_cli', *sys.argv[1:]], "
             "capture_output=True, text=True, timeout=300)\n"
             "s = time.perf_counter() - t\n"
             "kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
             "print(json.dumps([p.returncode, p.stderr, s, kib / 1024]))\n")
    p = subprocess.run([*PYTHON, "-c", probe, *map(str, args)], capture_output=True, text=True, timeout=360)
    rc, err, seconds, mib = json.loads(p.stdout)
    print(f"riverbed {' '.join(map(str, args[:1]))}: exit {rc}, {seconds:.2f} s, peak {mib:.0f} MiB")
    return rc, err, seconds, mib


def test_alias_bomb_is_refused_in_bounded_memory(tmp_path):
    bad = billion_laughs(tmp_path / "m.yaml")
    out = tmp_path / "out"
    rc, err, seconds, mib = _measured(["block", bad, "-o", out])
    assert (rc, err) == (1, f"riverbed: error: {bad}: {BOMB}\n")
    assert mib < 300  # a process's imports alone are ~190 MiB; the expanded bomb would be gigabytes
    assert not out.exists()


def test_dev_zero_check_file_is_refused_in_bounded_memory(tmp_path):
    shutil.copytree(CONES, tmp_path / "ds" / "cones")
    out = tmp_path / "out"
    rc, err, seconds, mib = _measured(["benchmark", tmp_path / "ds", "--layout", "middlebury", "-o", out,
                                       "--check", "/dev/zero"])
    assert (rc, err) == (1, "riverbed: error: /dev/zero: not a file\n")
    assert mib < 300
    assert not out.exists()


# --- benchmark: --check files and the cache ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("mb")
    shutil.copytree(CONES, root / "cones")
    return root


def _bench(dataset, out, *extra):
    return run("benchmark", dataset, "--layout", "middlebury", "-o", out, "--baselines", "", "--guides", "none",
               "--shares", "0.05", "--json", "--overwrite", *extra)


@pytest.mark.parametrize("content, problem", [
    ("[" * DEEP + "]" * DEEP, DEEP_JSON),
    (b"\xff\xfe{\x00}\x00", "not a benchmark expectations file (not UTF-8 text)"),
    ("[1, 2]", "not a benchmark expectations file (a JSON list, expected an object with tolerance and cases)"),
    ('{"cases": {"a": 1}, "tolerance": {"relative": 0.1, "floor": {}}}',
     "not a benchmark expectations file (cases: expected a list)"),
    ('{"cases": [{"key": "x", "bad1": "a lot"}], "tolerance": {"relative": 0.1, "floor": {"bad1": 1}}}',
     "not a benchmark expectations file (cases[0].bad1: expected a number)"),
    ('{"cases": [], "tolerance": {"bad1": 1}}', "not a benchmark expectations file (tolerance.relative: expected a "
                                                 "number)"),
    ('{"cases": [], "tolerance": {"relative": 0.1}}',
     "not a benchmark expectations file (tolerance.floor: expected an object of metric: number)"),
    ('{"cases": [1], "tolerance": {"relative": 0.1, "floor": {}}}',
     "not a benchmark expectations file (cases[0]: expected an object with a key string)"),
    ('{"cases": [], "tolerance": {"relative": 0.1, "floor": {"wrong": 1}}}',
     "not a benchmark expectations file (tolerance: 'wrong' is not a metric with a number (metrics: bad1, bad2, "
     "bad3, avg, rmse, density, d1, n))"),
    ('{"cases": [', "invalid JSON at line 1, column 12: Expecting value"),
])
def test_benchmark_check_file_is_one_line(dataset, tmp_path, content, problem):
    bad = tmp_path / "expected.json"
    bad.write_bytes(content.encode() if isinstance(content, str) else content)
    out = tmp_path / "out"
    r = _bench(dataset, out, "--check", bad)
    assert_one_line(r, bad, problem)
    assert not out.exists()


def test_benchmark_ignores_a_truncated_cache_file(dataset, tmp_path):
    out = tmp_path / "out"
    r = _bench(dataset, out)
    assert r.exit_code == 0, r.output
    (cached,) = (out / "cache").glob("*.json")
    first = json.loads(cached.read_text())
    truncated(cached, cached, keep=0.5)
    r = _bench(dataset, out)
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["cached"] == 0  # run again, not read
    (warning,) = r.stderr.splitlines()
    assert warning.startswith(f"riverbed: WARNING: ignoring a cached case: {cached}: invalid JSON at line 1, column ")
    assert warning.endswith("; running it again")
    assert json.loads(cached.read_text())["bad1"] == first["bad1"]  # rewritten whole
    r = _bench(dataset, out)
    assert r.exit_code == 0 and json.loads(r.stdout)["cached"] == 1


@pytest.mark.parametrize("content", ["[1, 2]", '{"key": "another case"}', "[" * DEEP, b"\xff\xfe"])
def test_benchmark_ignores_a_foreign_cache_file(dataset, tmp_path, content):
    out = tmp_path / "out"
    assert _bench(dataset, out).exit_code == 0
    (cached,) = (out / "cache").glob("*.json")
    cached.write_bytes(content.encode() if isinstance(content, str) else content)
    r = _bench(dataset, out)
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["cached"] == 0
    (warning,) = r.stderr.splitlines()
    assert warning.startswith(f"riverbed: WARNING: ignoring a cached case: {cached}: ")
    assert warning.endswith("; running it again")


def test_yaml_bounds_take_little_time(tmp_path):
    # the refusal works on the parser's events: no object is built for the 9**10 nodes
    text = billion_laughs(tmp_path / "m.yaml").read_text()
    t = time.perf_counter()
    with pytest.raises(Exception, match="aliases expand"):
        parse_yaml(text, tmp_path / "m.yaml")
    print(f"alias bomb refused by parse_yaml in {time.perf_counter() - t:.4f} s")
    deep = "[" * DEEP + "]" * DEEP
    t = time.perf_counter()
    with pytest.raises(Exception, match="nested more than"):
        parse_yaml(deep, tmp_path / "d.yaml")
    print(f"10,000-deep YAML refused by parse_yaml in {time.perf_counter() - t:.4f} s")
    assert os.path.getsize(tmp_path / "m.yaml") < 1000
