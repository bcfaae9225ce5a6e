"""The synthetic satellite sample (``riverbed sample --satellite``, docs/rpc_synthetic.md): deterministic, RPCs
fitted to the pushbroom cameras within the measured error and readable back, and the chain (rectify --rpc,
project, match, dsm, evaluate) on it within gates of the measured figures, guided ahead of unguided.

The chain runs on a 240 x 240 ROI of the small sample's left image with the sparse LiDAR only (a reduced
``benchmarks/bench_rpc_synthetic.py``), to stay within the test budget; docs/rpc_synthetic.md has the same
configuration's figures beside the whole table.
"""

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gates import assert_within, off_gate
from riverbed_cli.cli.main import cli
from riverbed_cli.geometry.rpc import read_rpc
from riverbed_cli.sample.pushbroom import local_to_lonlat
from riverbed_cli.sample.satellite import (SATELLITE_FILES, SATELLITE_SIZES, make_satellite, satellite_scene,
                                           write_satellite)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

ROI = "120,120,240,240"
#: RPC check-grid error bounds (px) over both views: measured rms 0.0595 / 0.0590, max 0.094 / 0.102
RPC_RMS_MAX, RPC_ERR_MAX = 0.07, 0.12
#: Measured with ROI, lidar_sparse: the committed benchmarks/results_rpc_synthetic_roi.json (docs/rpc_synthetic.md,
#: "the test's configuration", generated from it), rounded to the digits the doc prints
COMMITTED = json.loads((Path(__file__).resolve().parents[1] / "benchmarks" / "results_rpc_synthetic_roi.json")
                       .read_text())
DIGITS = {"rmse": 3, "nmad": 3, "over_3res": 2, "bad1": 2, "bad3": 2, "avg": 3, "predicted": 2}
MEASURED = {r["method"]: {m: round(r[m], n) for m, n in DIGITS.items()} for r in COMMITTED["rows"]}

TINY = replace(SATELLITE_SIZES["small"], name="tiny", size=(48, 40), supersample=2)


def test_generation_is_deterministic_and_seeded(tmp_path):
    a, b, c = make_satellite(TINY, 3), make_satellite(TINY, 3), make_satellite(TINY, 4)
    for x, y in zip(a.images, b.images):
        np.testing.assert_array_equal(x, y)
    assert a.rpcs == b.rpcs and a.rpc_report == b.rpc_report
    np.testing.assert_array_equal(a.dsm, b.dsm)
    np.testing.assert_array_equal(a.lidar["xyz"], b.lidar["xyz"])
    np.testing.assert_array_equal(a.sparse, b.sparse)
    assert not np.array_equal(a.images[0], c.images[0]) and a.rpcs != c.rpcs
    write_satellite(a, tmp_path / "a")
    write_satellite(b, tmp_path / "b")
    for name in SATELLITE_FILES:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    from bench_rpc_synthetic import run

    work = tmp_path_factory.mktemp("satellite")
    assert COMMITTED["roi"] == ROI and COMMITTED["size"] == "small" and COMMITTED["seed"] == 0
    summary = run(work, "small", 0, densities=("lidar_sparse",), methods=("unguided", "fused default"), roi=ROI)
    return work, summary


def test_rpcs_fit_the_cameras_and_read_back(chain):
    work, summary = chain
    sample = work / "sample"
    desc = json.loads((sample / "scene.json").read_text())
    for view in ("left", "right"):
        check = desc["rpc_fit"][view]["check"]
        assert check["n"] == 20 * 20 * 6
        assert check["rms_px"] < RPC_RMS_MAX and check["max_px"] < RPC_ERR_MAX
    assert max(summary["sample"]["rpc_check_rms_px"]) < RPC_RMS_MAX
    # deterministic (seeded): the committed figures the doc prints, to their last digit
    for key in ("rpc_check_rms_px", "rpc_check_max_px"):
        assert summary["sample"][key] == pytest.approx(COMMITTED["sample"][key], abs=1e-5), key
    # the RPC tags of the written images, read back, against the rigorous cameras at random points
    _, _, cameras, scene = satellite_scene("small", 0)
    to_ll = local_to_lonlat(scene.origin)
    rng = np.random.default_rng(1)
    lo, hi = desc["rpc_fit"]["left"]["heights_m"]
    for view, cam in zip(("left", "right"), cameras):
        rpc = read_rpc(sample / f"{view}.tif")
        assert rpc.format == "gdal-image"
        col, row = rng.uniform(0, cam.width - 1, 500), rng.uniform(0, cam.height - 1, 500)
        h = rng.uniform(lo, hi, 500)
        X = cam.localize(col, row, h - scene.origin[2])
        c, r = rpc.project(*to_ll(X[:, 0], X[:, 1]), h)
        err = np.hypot(c - col, r - row)
        assert err.max() < RPC_ERR_MAX and np.sqrt(np.mean(err ** 2)) < RPC_RMS_MAX
        # the pushbroom model is exact: projecting the localised points gives back the pixels
        c2, r2, _ = cam.project(X)
        assert np.abs(c2 - col).max() < 1e-6 and np.abs(r2 - row).max() < 1e-6


def test_chain_gates_and_guided_beats_unguided(chain):
    _, summary = chain
    rows = {r["method"]: r for r in summary["rows"]}
    assert set(rows) == {"unguided", "fused default"}
    assert_within({m: rows[m] for m in MEASURED}, MEASURED)
    g, u = rows["fused default"], rows["unguided"]
    assert g["rmse"] < u["rmse"] and g["nmad"] < u["nmad"] and g["over_3res"] < u["over_3res"]
    assert g["bad1"] < u["bad1"] and g["bad3"] < u["bad3"] and g["avg"] < u["avg"]
    gd = summary["gt_disparity"]
    assert gd["valid_share"] > 0.9 and gd["row_error_max_px"] < 0.5


def test_chain_gates_catch_a_real_regression(chain):
    # the fused match again with a 3 x 3 census window instead of 9 x 7: its bad1, bad3 and mean error leave their
    # gates
    from bench_rpc_synthetic import riverbed

    work, _ = chain
    sparse, out = work / "sparse_lidar_sparse.tif", work / "census3.tif"
    riverbed("match", work / "rect" / "left.tif", work / "rect" / "right.tif", "--sparse", sparse, "--census", "3x3",
             "-o", out, "--json")
    ev = riverbed("evaluate", out, work / "gt_disparity.tif", "--exclude", sparse, "--json")
    fused = {m: MEASURED["fused default"][m] for m in ("bad1", "bad3", "avg")}
    off = [line.split(":")[0] for line in off_gate({"fused default": ev}, {"fused default": fused})]
    assert off == ["fused default bad1", "fused default bad3", "fused default avg"], off


def test_cli_refuses_existing_sample_and_missing_parent(tmp_path):
    out = tmp_path / "sat"
    out.mkdir()
    (out / "left.tif").write_bytes(b"keep")
    runner = CliRunner()
    r = runner.invoke(cli, ["sample", str(out), "--satellite"])
    assert r.exit_code == 1
    assert r.output.strip().splitlines() == [f"riverbed: error: {out}: left.tif exists; pass --overwrite to replace "
                                             "the sample"]
    assert (out / "left.tif").read_bytes() == b"keep" and sorted(p.name for p in out.iterdir()) == ["left.tif"]
    r = runner.invoke(cli, ["sample", str(tmp_path / "missing" / "sat"), "--satellite"])
    assert r.exit_code == 1
    assert r.output.strip().splitlines() == [f"riverbed: error: {tmp_path / 'missing' / 'sat'}: folder "
                                             f"{tmp_path / 'missing'} does not exist"]
    assert not (tmp_path / "missing").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
