"""docs/tubes.md's AD-Census table is what benchmarks/bench_adcensus_tubes.py makes of the committed
benchmarks/results_adcensus_tubes.json, and the claims its text makes hold on those rows."""

import json
import sys

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_adcensus_tubes as bat  # noqa: E402

ROWS = json.loads((REPO / "benchmarks" / "results_adcensus_tubes.json").read_text())
DOC = (REPO / "docs" / "tubes.md").read_text()


def test_the_doc_table_is_the_committed_results():
    assert DOC.split(bat.BEGIN)[1].split(bat.END)[0].strip() == bat.tables(ROWS).strip()


def test_every_scene_and_share():
    assert [(r["scene"], r["share"]) for r in ROWS] == [
        (s, share) for s in ("Cones", "Reindeer", "Cloth3", "Wood2", "Dublin aerial") for share in bat.SHARES]


def test_the_claims_hold():
    # tubes as good or better than the full range, fused or not, on bad3 and the mean error (the tube issue's target)
    assert all(r[f"tube{k}"][i] <= r[f"full{k}"][i] for r in ROWS for k in ("", "_fused") for i in (0, 1))
    # "not faster": the matcher alone on tubes takes longer than on the full range on every scene and share
    assert all(r["seconds"][1] > r["seconds"][0] for r in ROWS)
    # the support layout holds more costs than the tubes, fewer than the full range
    assert all(r["mean_width"] < r["support"] < r["nominal"] for r in ROWS)
