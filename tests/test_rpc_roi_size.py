"""Affine (s2p) rectification vs shareloc's epipolar grids by ROI size, on the Ventoux RPCs (docs/rpc_roi_size.md).

Exact correspondences from the two Pléiades RPC models of the full products (``tests/data/rpc``, no image): the
residual vertical parallax of the affine rectification grows as the ROI's size squared; shareloc's grids stay at
1e-5 px. The figures are ``benchmarks/bench_rpc_roi_size.py``'s at the SRTM height ranges it measured (fixed here:
the SRTM tile is too large for tests/data).
"""

import sys
from argparse import Namespace
from pathlib import Path

import pytest

from riverbed_cli.geometry.rpc import read_rpc

from gates import assert_catches, assert_within

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_rpc_roi_size import evaluate_roi  # noqa: E402

RPC_DIR = Path(__file__).parent / "data" / "rpc"
#: ROI size (px, centred in the 38415 x 42219 left product) -> SRTM ellipsoidal height range under it (m, +- 20 m)
HEIGHTS = {1000: (1097.0, 1251.0), 10000: (691.0, 1692.0)}
#: |residual row| (px) of the affine rectification on a 41 x 41 lattice x 9 heights: median, p95, max
EXPECTED = {"affine_1000": {"median": 0.0050, "p95": 0.0147, "max": 0.0194},
            "affine_10000": {"median": 0.5009, "p95": 1.4568, "max": 1.8280}}


def roi_of(size, rpc):
    W, H = int(round(2 * rpc.samp_off)), int(round(2 * rpc.line_off))
    return ((W - size) // 2, (H - size) // 2, size, size)


@pytest.fixture(scope="module")
def models():
    return read_rpc(RPC_DIR / "left_image.geom"), read_rpc(RPC_DIR / "right_image.geom")


def test_affine_residual_grows_with_roi_size(models):
    rpc_l, rpc_r = models
    args = Namespace(grid=41, heights=9, step=30.0)
    got = {}
    for size, heights in HEIGHTS.items():
        r = evaluate_roi(rpc_l, rpc_r, roi_of(size, rpc_l), heights, args)
        got[f"affine_{size}"] = {k: r["affine_box_rpc"][k] for k in ("median", "p95", "max")}
    assert_within(got, EXPECTED)
    # a 20 % regression is caught wherever 20 % exceeds the gates' 0.005 px floor
    assert_catches({c: {m: v for m, v in f.items() if v > 0.025} for c, f in EXPECTED.items()})


def test_shareloc_grids_exact_where_affine_is_not(models, tmp_path):
    rpc_l, rpc_r = models
    args = Namespace(grid=21, heights=5, step=30.0)
    geoms = (RPC_DIR / "left_image.geom", RPC_DIR / "right_image.geom")
    r = evaluate_roi(rpc_l, rpc_r, roi_of(2000, rpc_l), (1052.0, 1300.0), args, geoms=geoms, tmp=tmp_path)
    # shareloc's nodes, through riverbed's RPCs, are correspondences at the grid's elevation (conventions agree)
    assert r["grid_node_check_px"] < 1e-6
    assert r["grid_box_rpc"]["max"] < 1e-3
    assert r["affine_box_rpc"]["max"] > 0.05
