"""docs/lidar_faults.md is what benchmarks/bench_faults.py makes of the committed benchmarks/results_faults.json, the
claims it states hold on every row, and one row is measured again (data test)."""

import json
import sys

import numpy as np
import pytest

from conftest import REPO
from riverbed_cli.matching import lidar_offset

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_faults  # noqa: E402

ROWS = json.loads((REPO / "benchmarks" / "results_faults.json").read_text())
DOC = (REPO / "docs" / "lidar_faults.md").read_text()


def test_the_doc_tables_are_the_committed_results():
    block = DOC.split(bench_faults.BEGIN)[1].split(bench_faults.END)[0]
    assert block.strip() == bench_faults.tables(ROWS).strip()


def test_the_doc_states_the_rule_the_code_has():
    assert lidar_offset.MIN_OFFSET == 1.5 and "at least 1.5 px" in DOC
    assert lidar_offset.MIN_GAIN == 0.02 and "at least 2 % below" in DOC
    assert lidar_offset.SEARCH_SHARE == 0.15 and lidar_offset.MIN_SEARCH == 4 and "±15 %" in DOC and "±4 px" in DOC
    assert lidar_offset.RADIUS == 2 and "5 x 5" in DOC and f"At most {lidar_offset.MAX_POINTS:,} points" in DOC
    assert lidar_offset.MAX_SPREAD == 1.5 and "within 1.5 px" in DOC and lidar_offset.MIN_BLOCKS == 4


def test_every_scene_share_and_offset_is_in_the_results():
    scenes = {r["scene"] for r in ROWS}
    assert {"Cones", "Reindeer", "Cloth3", "Wood2", "Dublin aerial"} <= scenes and len(scenes) == 6
    assert len(ROWS) == len(scenes) * len(bench_faults.SHARES) * len(bench_faults.OFFSETS)


@pytest.mark.parametrize("row", ROWS, ids=lambda r: f"{r['scene']}-{r['share']}-{r['offset']}")
def test_the_claims_hold_on_every_row(row):
    # the added offset estimated within 0.25 px (beside what the images see in the clean LiDAR), and removed
    assert abs(row["estimated"] - row["clean_estimate"] - row["offset_px"]) <= 0.25
    assert row["applied"] == row["estimated"] and abs(row["applied"]) >= 1.5
    # removed, the LiDAR guides as the clean one does: bad3 within 10 % (or 0.2 points) of the oracle's; the mean
    # error against a ground truth the images place elsewhere grows by at most that offset
    assert row["default"][0] <= max(1.1 * row["oracle"][0], row["oracle"][0] + 0.2)
    assert row["default"][1] <= row["oracle"][1] + abs(row["gt_minus_stereo"]) + 0.1
    # kept, its mean error is the offset's; past 3 px (bad3's threshold) it is worse than unguided matching
    assert row["default"][1] < row["kept"][1] and abs(row["kept"][1] - abs(row["offset_px"])) < 0.5
    if abs(row["offset_px"]) > 3:
        assert row["kept"][0] > row["unguided"][0] and row["kept"][0] > 3 * row["default"][0]
    assert row["default"][0] < row["unguided"][0] and row["default"][0] < row["lidar_only"][0]


def test_the_clean_lidar_is_left_as_it_is():
    assert all(abs(r["clean_estimate"]) < lidar_offset.MIN_OFFSET for r in ROWS)
    # and the images see the ground truth where unguided stereo does, within 0.2 px
    assert all(abs(r["clean_estimate"] - r["gt_minus_stereo"]) < 0.2 for r in ROWS)


def test_a_row_measured_again_is_the_committed_one(shared_data):
    from datasets import middlebury

    from riverbed_cli.matching.pipeline import match_pair
    from riverbed_cli.products.simulate import simulate_lidar

    row = next(r for r in ROWS if (r["scene"], r["share"], r["offset"]) == ("Cones", 0.05, "+10 %"))
    scene = middlebury(shared_data, "Cones")
    sparse = simulate_lidar(scene.gt, 0.05, seed=0)
    biased = sparse + np.float32(row["offset_px"])
    auto = match_pair(scene.left, scene.right, biased)
    kept = match_pair(scene.left, scene.right, biased, lidar_offset="none", lidar_check="off")
    assert auto.info["lidar_offset"]["estimated"] == row["estimated"]
    assert bench_faults._score(auto.disparity, scene.gt, sparse) == row["default"]
    assert bench_faults._score(kept.disparity, scene.gt, sparse) == row["kept"]
