"""docs/dsm.md's "Fusion pays" table is what benchmarks/bench_fusion.py makes of the committed
benchmarks/results_fusion.json, the claims its text states hold on those rows, and one scene is measured again (data
test)."""

import json
import sys

import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_fusion  # noqa: E402

ROWS = json.loads((REPO / "benchmarks" / "results_fusion.json").read_text())
DOC = (REPO / "docs" / "dsm.md").read_text()
BY = {(r["scene"], r["method"]): r for r in ROWS}
SCENES = sorted({r["scene"] for r in ROWS})


def test_the_doc_table_is_the_committed_results():
    block = DOC.split(bench_fusion.BEGIN)[1].split(bench_fusion.END)[0]
    assert block.strip() == bench_fusion.tables(ROWS).strip()


def test_every_scene_has_the_three_methods():
    assert len(SCENES) == 5 and "sample block" in SCENES
    assert all((s, m) in BY for s in SCENES for m in bench_fusion.METHODS) and len(ROWS) == 15


@pytest.mark.parametrize("scene", SCENES)
def test_the_claims_hold(scene):
    unguided, lidar, riverbed = (BY[(scene, m)] for m in bench_fusion.METHODS)
    # "riverbed has the lowest RMSE on every scene, and the lowest NMAD on every Middlebury scene"
    assert riverbed["rmse"] < min(unguided["rmse"], lidar["rmse"])
    assert riverbed["nmad"] < unguided["nmad"]
    if scene.startswith("Middlebury"):
        assert riverbed["nmad"] < lidar["nmad"]
    else:  # the sample block: the LiDAR alone has the lower NMAD and covers more, twice riverbed's cells > 3 GSD
        assert lidar["nmad"] < riverbed["nmad"] and lidar["completeness"] > riverbed["completeness"]
        assert lidar["over_3res"] > 2 * riverbed["over_3res"]
    # "on Wood2 it has fewer such cells than riverbed" (and only there)
    assert (lidar["over_3res"] < riverbed["over_3res"]) == (scene == "Middlebury Wood2")


def test_a_scene_measured_again_is_the_committed_one(shared_data):
    rows, _ = bench_fusion.middlebury_scene(shared_data, "Cones")
    assert rows == [BY[("Middlebury Cones", m)] for m in bench_fusion.METHODS]


import bench_dsm  # noqa: E402

SPEED = json.loads((REPO / "benchmarks" / "results_dsm_speed.json").read_text())


def test_the_speed_table_is_the_committed_results():
    block = DOC.split(bench_dsm.BEGIN)[1].split(bench_dsm.END)[0]
    assert block.strip() == bench_dsm.tables(SPEED).strip()


def test_riverbed_rasterises_faster_than_every_numpy_way():
    # "riverbed is faster than every numpy way on every aggregation" (seconds of one run, side by side)
    ours = {r["aggregation"]: r["seconds"] for r in SPEED if r["method"] == "riverbed"}
    assert set(ours) == {"max", "mean", "median", "idw"}
    others = [r for r in SPEED if r["method"] != "riverbed"]
    assert len(others) == 4 and all(r["seconds"] > ours[r["aggregation"]] for r in others)
