"""End-to-end accuracy on a real pair (Middlebury Cones, quarter size) with simulated LiDAR."""

import pytest

from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar


@pytest.fixture(scope="module")
def results(cones):
    left, right, gt = cones
    out = {}
    for share in (0.05, 0.0016):
        sparse = simulate_lidar(gt, share, seed=0)
        for guide in ("none", "gauss", "riverbed"):
            disp = match_pair(left, right, sparse, 0, 59, guide=guide).disparity
            out[share, guide] = evaluate_disparity(disp, gt, exclude=sparse)
    return out


def test_unguided_sgm_is_a_real_matcher(results):
    m = results[0.05, "none"]
    assert m["density"] == 100.0
    assert m["bad3"] < 12.0 and m["avg"] < 1.5  # census-SGM on Cones: ~8.8 % and ~0.95 px


def test_riverbed_at_5_percent(results):
    none, gauss, rb = results[0.05, "none"], results[0.05, "gauss"], results[0.05, "riverbed"]
    assert rb["bad3"] <= 0.3 * none["bad3"]  # at least a 70 % cut
    assert rb["avg"] <= 0.5
    assert rb["bad3"] < gauss["bad3"] < none["bad3"]
    assert rb["avg"] < gauss["avg"] < none["avg"]


def test_riverbed_still_helps_at_0_16_percent(results):
    none, rb = results[0.0016, "none"], results[0.0016, "riverbed"]
    assert rb["bad3"] < none["bad3"] and rb["avg"] < none["avg"]
