"""docs/rpc.md's generated blocks are what the RPC benchmarks make of their committed results
(benchmarks/results_rpc_rectify.json, results_rpc_ventoux.json, results_rpc_block.json)."""

import json
import sys

import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_rpc_block  # noqa: E402
import bench_rpc_rectify  # noqa: E402
import bench_rpc_ventoux  # noqa: E402

DOC = (REPO / "docs" / "rpc.md").read_text()


@pytest.mark.parametrize("bench, results", [(bench_rpc_rectify, "results_rpc_rectify.json"),
                                            (bench_rpc_ventoux, "results_rpc_ventoux.json"),
                                            (bench_rpc_block, "results_rpc_block.json")])
def test_the_doc_block_is_the_committed_results(bench, results):
    summary = json.loads((REPO / "benchmarks" / results).read_text())
    assert DOC.split(bench.BEGIN)[1].split(bench.END)[0].strip() == bench.doc_text(summary).strip()


def test_the_claims_hold():
    rect = json.loads((REPO / "benchmarks" / "results_rpc_rectify.json").read_text())
    # the affine model and shareloc's grids agree to a few hundredths of a pixel; the pointing error is pixels
    assert rect["shareloc_before_pointing_correction"]["row_difference_of_shareloc_matches_max_abs"] < 0.05
    assert abs(rect["pointing_row_offset_px"]) > 1 and rect["check_row_residual_max_px"] < 0.01
    # the rows after correction meet the targets the table names
    assert rect["sift_lk"]["dy_median_abs"] < 0.2 and rect["sift_lk"]["dy_p95_abs"] < 0.5
    block = json.loads((REPO / "benchmarks" / "results_rpc_block.json").read_text())["figures"]
    # the merged 4-ROI DSM is the whole crop's to a few centimetres, with a centimetre offset
    assert block["merged_vs_whole"]["nmad"] < 0.1 and abs(block["merged_vs_whole"]["median"]) < 0.03
