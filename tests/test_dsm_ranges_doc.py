"""docs/tubes.md's coarse-DSM ranges block is what benchmarks/bench_dsm_ranges.py makes of the committed
benchmarks/results_dsm_ranges.json, and the claims of its text hold on those rows."""

import json
import sys

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_dsm_ranges as bdr  # noqa: E402

RESULTS = json.loads((REPO / "benchmarks" / "results_dsm_ranges.json").read_text())
DOC = (REPO / "docs" / "tubes.md").read_text()
ROWS = {(r["k"], r["margin"]): r for r in RESULTS["rows"] if r["source"] == "dsm"}
LIDAR = next(r for r in RESULTS["rows"] if r["source"] == "lidar")


def test_the_doc_block_is_the_committed_results():
    assert DOC.split(bdr.BEGIN)[1].split(bdr.END)[0].strip() == bdr.tables(RESULTS).strip()


def test_the_claims_hold():
    assert set(ROWS) == set(bdr.CASES)
    # at 3.2 m cells the ranges beat both inputs (mean error and bad3); at 9.6 m the 2 px margin loses the truth
    # on more than a tenth of the pixels and a 6 px margin gets it back
    mid = ROWS[16, 2.0]
    for i in (0, 1):
        assert mid["ranges"][i] < min(mid["full"][i], mid["alone"][i])
    assert ROWS[48, 2.0]["inside"] < 90 < 98 < ROWS[48, 6.0]["inside"]
    assert ROWS[48, 6.0]["ranges"][1] < ROWS[48, 2.0]["ranges"][1]
    # a fine DSM is better used as LiDAR: better than the DSM alone and than its ranges
    fine = ROWS[4, 2.0]
    assert fine["as_lidar"][1] < min(fine["alone"][1], fine["ranges"][1])
    # the block's own LiDAR: the defaults beat its interpolation and unguided matching
    assert LIDAR["as_lidar"][1] < min(LIDAR["alone"][1], LIDAR["full"][1])
