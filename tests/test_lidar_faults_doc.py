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


import bench_changes  # noqa: E402

CHANGES = json.loads((REPO / "benchmarks" / "results_changes.json").read_text())


def test_the_check_tables_are_the_committed_results():
    block = DOC.split(bench_changes.BEGIN)[1].split(bench_changes.END)[0]
    assert block.strip() == bench_changes.tables(CHANGES).strip()


def test_the_doc_states_the_check_rule_the_code_has():
    from riverbed_cli.matching import lidar_check as c
    from riverbed_cli.matching import lidar_regions as r

    doc = " ".join(DOC.split())
    assert c.FACTOR == 2 and "at half resolution over the whole range" in doc
    assert c.SMOOTH == 3.0 and "spans at most 3 px" in doc and c.NEAR == 1.5 and "within 1.5 spacings" in doc
    assert c.TAU == 3.0 and "more than 3 px from the alternative" in doc
    assert c.MARGIN == 0.1 and "at least 0.1 below the cost" in doc and "at most 0.9" in doc
    assert c.EDGE == 8 and "plus 8 px" in doc and "within 8 px at the alternative" in doc
    assert c.CELL == 3.0 and r.REGION_SHARE == 0.6 and r.MIN_POINTS == 3 and r.GROW_SHARE == 0.3
    assert "Cells of 3 spacings where at least 60 % " in doc and "(at least 3 points)" in doc and "where 30 % do" in doc
    assert c.MIN_COMPARED == 16 and "at least 16 points with a reference" in doc
    assert c.SURFACE_STEP == 9.0 and "each within 9 px of the point before" in doc
    assert "joins when most of its neighbours on its own surface (within 1.5 spacings and 3 px of it)" in doc
    assert c.REGION_MARGIN == 0.2 and "by at least 0.2 on average" in doc
    assert c.UNKNOWN_HOPS == 2 and "at most 2 in a row" in doc
    assert c.SEEN_SHARE == 0.3 and "at least 30 % of the points it took" in doc
    assert c.MAX_SPACING == 16 and "Below one point per 16 x 16 px" in doc
    assert "more than 6 px off both the median of those points and their least-squares plane" in doc
    assert c.VOUCH == 0.5 and "(`1 - ZNCC` at most 0.5), costs at least 0.1 less than the best near" in doc
    assert "costs no more than at every other whole disparity of the range more than 2 px from it" in doc
    assert c.MASK_LABELS == {0: "no LiDAR", 1: "used", 2: "outlier", 3: "changed region", 4: "changed area"}
    from riverbed_cli.matching import tubes
    assert c.FINE_CELLS == 16_000_000 and "Over 16 M cells (pixels x disparities at half resolution)" in doc
    assert tubes.HOLE_WINDOW == 4 and tubes.HOLE_MARGIN == 8 and "within 4 of its pixels, 8 px beyond" in doc
    from riverbed_cli.scale import match_plan, tiles
    assert tiles.REFERENCE_BUDGET == 512 * 2**20 and tiles.REFERENCE_OVERLAP == 64
    assert match_plan.TILE_BUDGET == 1536 * 2**20
    assert ("at most 512 MiB of volumes, with a 64 px overlap at their resolution (the match's own tiles may take "
            "1.5 GiB") in doc


def test_every_scene_share_and_fault_of_the_check_is_in_the_results():
    faults = {r["fault"] for r in CHANGES}
    want = {"clean"} | {f[0] for f in bench_changes.REGIONS} | {f[0] for f in bench_changes.OUTLIERS}
    want |= {f[0] for f in bench_changes.SHIFTS} | {f[0] for f in bench_changes.NOISE}
    assert faults == want
    assert len(CHANGES) == 6 * len(bench_faults.SHARES) * len(want)


@pytest.mark.parametrize("row", CHANGES, ids=lambda r: f"{r['scene']}-{r['share']}-{r['fault']}")
def test_the_checks_claims_hold_on_every_row(row):
    if row["fault"] == "clean":  # clean LiDAR: at most 0.5 % of it dropped, bad3 within 0.1 points of unchecked
        assert row["dropped"][1] <= 0.005 and abs(row["default"][0] - row["off"][0]) <= 0.1
    elif "clean_outside" in row:  # a changed region: never worse than keeping it, and outside it close to clean
        assert row["default"][0] <= row["off"][0] and row["default"][1] <= row["off"][1]
        assert row["dropped"][1] <= 0.03
        assert row["default_outside"][0] <= 2 * row["clean_outside"][0] + 0.2
    elif row.get("kind") == "whole":  # every point off: the check drops few of them and costs little
        assert row["dropped"][0] <= 0.02
        assert row["default"][0] <= row["off"][0] + 0.1 and row["default"][1] <= row["off"][1] + 0.02
        if "sigma" in row:  # the fusion's estimate of the LiDAR's error grows with its noise
            assert row["sigma_estimate"] >= 0.5 * row["sigma"]
    else:  # gross outliers: most of them dropped, the result better than with them
        assert row["dropped"][0] >= 0.7 and row["dropped"][1] <= 0.004
        assert row["default"][0] < row["off"][0] and row["default"][1] < row["off"][1]


def test_a_row_of_the_check_measured_again_is_the_committed_one(shared_data):
    from datasets import middlebury

    from riverbed_cli.matching.pipeline import match_pair
    from riverbed_cli.products.simulate import simulate_lidar

    row = next(r for r in CHANGES if (r["scene"], r["share"], r["fault"]) == ("Cones", 0.05, "A: 25 %, +20 %"))
    scene = middlebury(shared_data, "Cones")
    sparse = simulate_lidar(scene.gt, 0.05, seed=0)
    have = np.isfinite(sparse)
    block = bench_changes.region_block(have, 0.30, 0.30, 0.25)
    vals = sparse[have]
    stale = np.where(block, sparse + np.float32(0.20 * float(vals.max() - vals.min())), sparse)
    res = match_pair(scene.left, scene.right, stale)
    assert bench_changes._score(res.disparity, scene.gt, sparse, block) == row["default"]
    assert bench_changes._score(res.disparity, scene.gt, sparse, ~block) == row["default_outside"]


import bench_check_scale  # noqa: E402

SCALE = json.loads((REPO / "benchmarks" / "results_check_scale.json").read_text())


def test_the_check_at_scale_table_is_the_committed_results():
    block = DOC.split(bench_check_scale.BEGIN)[1].split(bench_check_scale.END)[0]
    assert block.strip() == bench_check_scale.tables(SCALE).strip()


def test_at_scale_the_check_costs_two_fifths_of_the_match_and_little_memory():
    # the committed 10 MP run (medians of 5): the check takes 39 % more time than the match without it, beyond the
    # issue's 25 % (not met); the whole-range reference, measured beside it, takes 152 %; the peak RSS moves by 2 %
    row = SCALE[0]
    assert row["size"][0] * row["size"][1] >= 9.9e6 and row["range"] == [0, 520] and row["repeat"] == 5
    off = row["off"]["seconds"]
    assert 1.25 * off < row["default"]["seconds"] <= 1.5 * off < 2 * off < row["whole range"]["seconds"]
    assert row["default"]["dropped"] == pytest.approx(row["whole range"]["dropped"], abs=5)
    assert row["off"]["peak_rss_mib"] <= row["default"]["peak_rss_mib"] <= 1.05 * row["off"]["peak_rss_mib"]
    assert row["default"]["peak_rss_mib"] <= 1.4 * 1024


import bench_change_placement  # noqa: E402

PLACED = json.loads((REPO / "benchmarks" / "results_change_placement.json").read_text())


def test_the_held_out_placements_table_is_the_committed_results():
    block = DOC.split(bench_change_placement.BEGIN)[1].split(bench_change_placement.END)[0]
    assert block.strip() == bench_change_placement.tables(PLACED).strip()
    assert len(PLACED) == 6 * len(bench_faults.SHARES) * len(bench_change_placement.VARIANTS) * 3


def test_held_out_placements_are_met_less_often_as_the_doc_says():
    # reflected: fewer regions within the bound inside than at the dev placements; three hardly found (under 5 %
    # of their points dropped); sign turned: found (as often inside) but more clean points taken (fewer outside)
    dev = [r for r in CHANGES if "clean_outside" in r]
    dev_inside = sum(r["default"][0] <= bench_changes.region_target(r) for r in dev)
    dev_outside = sum(bench_changes._near_clean(r) for r in dev)
    for variant in bench_change_placement.VARIANTS:
        rows = [r for r in PLACED if r["variant"] == variant]
        inside = sum(r["default"][0] <= bench_changes.region_target(r) for r in rows)
        outside = sum(bench_changes._near_clean(r) for r in rows)
        if variant == "reflected":
            assert inside < dev_inside
            lost = {(r["scene"], r["share"], r["region"]) for r in rows if r["dropped"][0] < 0.05}
            assert lost == {("Dublin aerial", 0.05, "C"), ("Dublin aerial", 0.0123, "C"), ("Wood2", 0.0123, "C")}
        else:
            assert inside >= dev_inside and outside < dev_outside
