"""docs/tubes.md's coverage tables are what benchmarks/bench_tube_coverage.py makes of the committed
benchmarks/results_tube_coverage.json, and the claims its text makes hold on those rows; one scene is measured again
(data test)."""

import json
import sys

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_tube_coverage as btc  # noqa: E402

ROWS = json.loads((REPO / "benchmarks" / "results_tube_coverage.json").read_text())
DOC = (REPO / "docs" / "tubes.md").read_text()


def _get(scene, share, rule=btc.DEFAULT):
    return btc._get(ROWS, scene, share, rule)


def test_the_doc_tables_are_the_committed_results():
    assert DOC.split(btc.BEGIN)[1].split(btc.END)[0].strip() == btc.tables(ROWS).strip()


def test_the_targets_the_doc_reports():
    dev = ("Cones", "Reindeer", "Cloth3", "Wood2")
    # the tube rule's targets: the truth inside at 99 % or more of the dev pixels at every share, tubes several
    # times narrower than the nominal range; the aerial pixels on the nominal range: some at 5 %, none at 0.16 %
    assert min(_get(n, s)["coverage"] for n in dev for s in btc.SHARES) >= 99.0
    assert min(_get(n, s)["nominal"] / _get(n, s)["mean_width"] for n in dev for s in btc.SHARES) >= 3
    assert _get("Dublin aerial", 0.05)["full_range"] > 0 and _get("Dublin aerial", 0.0016)["full_range"] == 0


def test_a_scene_measured_again_is_the_committed_one(shared_data):
    from datasets import middlebury

    rows = btc.scene_rows("Cones", middlebury(shared_data, "Cones").gt)
    assert rows == [r for r in ROWS if r["scene"] == "Cones"]
