"""docs/tubes.md's "LiDAR beyond the nominal range" table is what benchmarks/bench_tube_beyond.py makes of the
committed benchmarks/results_tube_beyond.json, and the claims under it hold on those rows; one pair is measured again
(data test)."""

import json
import sys

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_tube_beyond as btb  # noqa: E402

ROWS = json.loads((REPO / "benchmarks" / "results_tube_beyond.json").read_text())
DOC = (REPO / "docs" / "tubes.md").read_text()


def test_the_doc_table_is_the_committed_results():
    assert DOC.split(btb.BEGIN)[1].split(btb.END)[0].strip() == btb.tables(ROWS).strip()


def test_the_claims_hold():
    tubes = [r for r in ROWS if r.get("range") == "tube"]
    for pair in {r["pair"] for r in ROWS}:
        cut = [r for r in tubes if r["pair"] == pair and r["lidar"] == "cut at the range"]
        whole = [r for r in tubes if r["pair"] == pair and r["lidar"] == "whole scene"]
        # the points beyond narrow the tubes and leave no pixel on the whole range; the matchers' output beats the
        # LiDAR alone inside the range (bad3), tubes beat the full range
        assert all(w["mean_width"] < c["mean_width"] / 2 and w["full_range"] == 0 for c, w in zip(cut, whole))
        alone = min(r["scores"][1] for r in ROWS if r["pair"] == pair and "range" not in r)
        assert all(r["scores"][1] < alone for r in tubes if r["pair"] == pair)
        full = [r for r in ROWS if r["pair"] == pair and r.get("range") == "full"]
        assert max(r["scores"][1] for r in tubes if r["pair"] == pair) < min(r["scores"][1] for r in full)
    # beyond the range: the tubes' output sits at its end, the whole range's does not
    speed = {r["range"]: r["beyond"] for r in ROWS if r.get("beyond") and r["lidar"] == "whole scene"
             and r["fusion"] == "auto"}
    assert speed["tube"]["at_end"] > 70 and speed["tube"]["error"] < speed["full"]["error"]


def test_a_pair_measured_again_is_the_committed_one(shared_data):
    cones = btb.pairs(shared_data)[1]
    assert btb.pair_rows(*cones) == [r for r in ROWS if r["pair"] == cones[0]]
