"""The real Pléiades Ventoux pair matched through the commands (docs/rpc.md, "The real pair matched").

A reduced ``benchmarks/bench_rpc_ventoux.py``: one LiDAR density (one SRTM point per 4 x 4 rectified pixels),
unguided and guided matching, both DSMs against the SRTM on the DSM's grid, compared with the committed
``benchmarks/results_rpc_ventoux.json`` (measured with the EGM96 grid; docs/rpc.md is generated from it). The chain
is deterministic (seeded LiDAR, deterministic matching and triangulation): the figures are gated to 0.1 % (or 1 mm),
the counts exactly.
"""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

COMMITTED = json.loads((Path(__file__).resolve().parents[1] / "benchmarks" / "results_rpc_ventoux.json").read_text())
ROWS = {r["method"]: r for r in COMMITTED["rows"] if r["spacing_px"] == 4 and r["method"] != "lidar linear"}
FIGURES = ("median", "nmad", "nmad_plane", "rmse", "completeness")


def gate(value):
    return pytest.approx(value, rel=1e-3, abs=1e-3)


def test_ventoux_matched_unguided_and_guided_against_srtm(shared_data, tmp_path, egm96):
    from bench_rpc_ventoux import run, table

    s = run(shared_data, tmp_path, spacings=(4,), picture=None, baseline=False)
    assert s["rectify"]["width"] == 613 and s["rectify"]["height"] == 614
    rows = {r["method"]: r for r in s["rows"]}
    assert set(rows) == set(ROWS) == {"unguided", "guided"}
    # the LiDAR: one point per 4 x 4 px of 0.505 m over the left crop's footprint, most of it kept by project
    assert (rows["guided"]["lidar_points"], rows["guided"]["kept"]) == (ROWS["guided"]["lidar_points"],
                                                                        ROWS["guided"]["kept"])
    assert rows["guided"]["kept"] > 0.9 * rows["guided"]["lidar_points"]
    # the reference: the SRTM on the DSM grid where both crops see the ground (they overlap over part of the left)
    assert s["reference_cells"] == COMMITTED["reference_cells"]
    assert s["grid"]["bounds"] == pytest.approx(COMMITTED["grid"]["bounds"]) and s["grid"]["resolution"] == 0.505
    assert s["vertical"] == COMMITTED["vertical"]
    for method, want in ROWS.items():
        for figure in FIGURES:
            assert (method, figure, rows[method][figure]) == (method, figure, gate(want[figure]))
    # the unguided matcher is far from the smooth reference, the guided one sits on it (by construction)
    assert rows["unguided"]["nmad"] > 20 * rows["guided"]["nmad"]
    assert rows["guided"]["completeness"] > 90 and rows["unguided"]["completeness"] > 90
    assert table(s).count("\n") == 3
