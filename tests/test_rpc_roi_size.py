"""Affine (s2p) rectification vs shareloc's epipolar grids by ROI size, on the Ventoux RPCs (docs/rpc_roi_size.md).

Exact correspondences from the two Pléiades RPC models of the full products (``tests/data/rpc``, no image): the
residual vertical parallax of the affine rectification grows as the ROI's size squared; shareloc's grids stay at
1e-5 px. The figures are ``benchmarks/bench_rpc_roi_size.py``'s at the SRTM height ranges it measured (fixed here:
the SRTM tile is too large for tests/data).
"""

import json
import sys
from argparse import Namespace
from pathlib import Path

import pytest

from riverbed_cli.geometry.rpc import read_rpc


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_rpc_roi_size import evaluate_roi  # noqa: E402

RPC_DIR = Path(__file__).parent / "data" / "rpc"
#: benchmarks/bench_rpc_roi_size.py's committed results (docs/rpc_roi_size.md is generated from them)
COMMITTED = json.loads((Path(__file__).resolve().parents[1] / "benchmarks" / "results_rpc_roi_size.json").read_text())
ROWS = {r["size"]: r for r in COMMITTED["pleiades"]["rows"]}
#: ROI size (px, centred in the 38415 x 42219 left product) -> the SRTM ellipsoidal height range under it (m, +- 20 m)
HEIGHTS = {size: tuple(ROWS[size]["heights"]) for size in (1000, 10000)}
#: |residual row| (px) of the affine rectification on a 41 x 41 lattice x 9 heights: median, p95, max
EXPECTED = {size: {k: ROWS[size]["affine_box_rpc"][k] for k in ("median", "p95", "max")} for size in HEIGHTS}
#: pure geometry (no image, no matcher): deterministic up to floating point, so gated to 0.1 %
RELATIVE = 1e-3


def roi_of(size, rpc):
    W, H = int(round(2 * rpc.samp_off)), int(round(2 * rpc.line_off))
    return ((W - size) // 2, (H - size) // 2, size, size)


@pytest.fixture(scope="module")
def models():
    return read_rpc(RPC_DIR / "left_image.geom"), read_rpc(RPC_DIR / "right_image.geom")


def test_affine_residual_grows_with_roi_size(models):
    rpc_l, rpc_r = models
    assert (COMMITTED["grid"], COMMITTED["heights"]) == (41, 9)
    args = Namespace(grid=41, heights=9, step=30.0)
    for size, heights in HEIGHTS.items():
        r = evaluate_roi(rpc_l, rpc_r, roi_of(size, rpc_l), heights, args)
        for k, v in EXPECTED[size].items():
            assert r["affine_box_rpc"][k] == pytest.approx(v, rel=RELATIVE), (size, k)
    # it grows as the ROI's size squared: 10 x the size, about 100 x the residual
    assert 80 < EXPECTED[10000]["max"] / EXPECTED[1000]["max"] < 120


def test_shareloc_grids_exact_where_affine_is_not(models, tmp_path):
    rpc_l, rpc_r = models
    args = Namespace(grid=21, heights=5, step=30.0)
    geoms = (RPC_DIR / "left_image.geom", RPC_DIR / "right_image.geom")
    r = evaluate_roi(rpc_l, rpc_r, roi_of(2000, rpc_l), (1052.0, 1300.0), args, geoms=geoms, tmp=tmp_path)
    # shareloc's nodes, through riverbed's RPCs, are correspondences at the grid's elevation (conventions agree)
    assert r["grid_node_check_px"] < 1e-6
    assert r["grid_box_rpc"]["max"] < 1e-3
    assert r["affine_box_rpc"]["max"] > 0.05
