"""docs/rpc_roi_size.md's generated blocks are what benchmarks/bench_rpc_roi_size.py makes of the committed
benchmarks/results_rpc_roi_size.json, and the claims of its text hold on those figures."""

import json
import sys

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_rpc_roi_size as brs  # noqa: E402

RESULTS = json.loads((REPO / "benchmarks" / "results_rpc_roi_size.json").read_text())
DOC = (REPO / "docs" / "rpc_roi_size.md").read_text()


def block(kind):
    return DOC.split(brs.BEGIN[kind])[1].split(brs.END[kind])[0].strip()


def test_the_doc_blocks_are_the_committed_results():
    assert block("pleiades") == brs.pleiades_text(RESULTS).strip()
    assert block("synthetic") == brs.synthetic_text(RESULTS).strip()


def test_the_claims_hold():
    rows = {r["size"]: r for r in RESULTS["pleiades"]["rows"]}
    # the default ROI of split-rpc stays under rectify's 0.1 px warning, and under the 0.1 px crossing
    assert rows[brs.SPLIT_DEFAULT]["affine_box_rpc"]["max"] < 0.1 < rows[3000]["affine_box_rpc"]["max"]
    assert brs.crossing(RESULTS["pleiades"]["rows"], "max", 0.1) > brs.SPLIT_DEFAULT
    # shareloc's grids stay exact (far below a thousandth of a pixel) at every size; the affine model does not
    assert all(r["grid_box_rpc"]["max"] < 1e-3 for r in rows.values())
    assert rows[38000]["affine_box_rpc"]["max"] > 10
    # through the true cameras both methods err alike (within 10 %) on the synthetic sample
    for r in RESULTS["synthetic"]["rows"]:
        a, g = r["affine_box_true"], r["grid_box_true"]
        assert abs(a["median"] / g["median"] - 1) < 0.1 and abs(a["max"] / g["max"] - 1) < 0.1
