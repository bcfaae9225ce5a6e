"""The real Pléiades Ventoux pair matched through the commands (docs/rpc.md, "The real pair matched").

A reduced ``benchmarks/bench_rpc_ventoux.py``: one LiDAR density (one SRTM point per 4 x 4 rectified pixels),
unguided and guided matching, both DSMs against the SRTM on the DSM's grid. The gates are the figures measured
with the EGM96 grid (docs/rpc.md), within 10 % relative or 0.1 m.
"""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

# docs/rpc.md, "The real pair matched" (EGM96 -> ellipsoid through PROJ's grid), 4 x 4 px LiDAR
MEASURED = {"unguided": {"median": 3.95, "nmad": 10.18}, "guided": {"median": 0.00, "nmad": 0.14}}


def gate(value):
    return pytest.approx(value, rel=0.10, abs=0.1)


def test_ventoux_matched_unguided_and_guided_against_srtm(shared_data, tmp_path, egm96):
    from bench_rpc_ventoux import run, table

    s = run(shared_data, tmp_path, spacings=(4,), picture=None, baseline=False)
    assert s["rectify"]["width"] == 613 and s["rectify"]["height"] == 614
    rows = {r["method"]: r for r in s["rows"]}
    assert set(rows) == {"unguided", "guided"}
    # the LiDAR: one point per 4 x 4 px of 0.505 m over the left crop's footprint, most of it kept by project
    assert rows["guided"]["lidar_points"] == 17039 and rows["guided"]["kept"] > 0.9 * 17039
    # the reference: the SRTM on the DSM grid where both crops see the ground (they overlap over ~30 % of the left)
    assert s["reference_cells"] == pytest.approx(70991, rel=0.01)
    assert s["vertical"].startswith("EGM96")
    for method, want in MEASURED.items():
        assert (method, rows[method]["median"]) == (method, gate(want["median"]))
        assert (method, rows[method]["nmad"]) == (method, gate(want["nmad"]))
    # the unguided matcher is far from the smooth reference, the guided one sits on it (by construction)
    assert rows["unguided"]["nmad"] > 20 * rows["guided"]["nmad"]
    assert rows["guided"]["completeness"] > 90 and rows["unguided"]["completeness"] > 90
    assert table(s).count("\n") == 3
