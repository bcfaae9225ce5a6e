"""Accuracy beyond the development scenes: the KITTI 2015 frame (real outdoor scene, sparse LiDAR-derived GT).

KITTI may not be copied into the repository; it is read from RIVERBED_DATA (CI sets ../shared/data). Every figure is
gated within 2 % (small absolute floors: tests/gates.py) of the value measured with the current code and committed
below, for the three LiDAR shares, none / Gauss / riverbed, the default output (confidence fusion) and the matcher
alone (``fusion="none"``); one LiDAR sampling (seed 0; tests/test_accuracy.py gates three on Cones).
"""

import numpy as np
import pytest

from gates import assert_catches, assert_within, off_gate
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar

KITTI = "kitti2015_stereo_sttr/sample_data/KITTI_2015/training"
SHARES = (0.05, 0.0123, 0.0016)
CASES = (("none", "none"), ("gauss", "confidence"), ("gauss", "none"), ("riverbed", "confidence"),
         ("riverbed", "none"))

#: Measured with the current code (seed 0, 2 cores): bad1 %, bad3 %, avg px over the GT pixels not used as LiDAR (an
#: invalid pixel counts as an error; the unguided match leaves the 1 % of them whose match may lie outside the right
#: image invalid). The fusion's LiDAR side is local planes at 5 % and 1.23 %, the Delaunay fill at 0.16 % (25 px
#: between points; ``fusion_lidar: auto``, docs/fusion.md). Over seeds 1 and 2 the figures move by up to 0.15 points
#: of bad3 at 5 % and 0.55 at 0.16 % (riverbed): this test runs seed 0 only.
EXPECTED = {
    (0.05, "none", "none"): {"bad1": 20.396, "bad3": 5.009, "avg": 1.0259},
    (0.05, "gauss", "confidence"): {"bad1": 3.071, "bad3": 0.724, "avg": 0.2671},
    (0.05, "gauss", "none"): {"bad1": 7.860, "bad3": 0.821, "avg": 0.4505},
    (0.05, "riverbed", "confidence"): {"bad1": 1.580, "bad3": 0.239, "avg": 0.1567},
    (0.05, "riverbed", "none"): {"bad1": 2.222, "bad3": 0.242, "avg": 0.1771},
    (0.0123, "none", "none"): {"bad1": 20.418, "bad3": 5.024, "avg": 1.0291},
    (0.0123, "gauss", "confidence"): {"bad1": 6.589, "bad3": 1.745, "avg": 0.4345},
    (0.0123, "gauss", "none"): {"bad1": 14.145, "bad3": 2.256, "avg": 0.6927},
    (0.0123, "riverbed", "confidence"): {"bad1": 4.027, "bad3": 0.685, "avg": 0.2998},
    (0.0123, "riverbed", "none"): {"bad1": 7.163, "bad3": 0.705, "avg": 0.3972},
    (0.0016, "none", "none"): {"bad1": 20.525, "bad3": 5.064, "avg": 1.0268},
    (0.0016, "gauss", "confidence"): {"bad1": 11.102, "bad3": 3.455, "avg": 0.6592},
    (0.0016, "gauss", "none"): {"bad1": 19.110, "bad3": 4.140, "avg": 0.9669},
    (0.0016, "riverbed", "confidence"): {"bad1": 9.567, "bad3": 2.399, "avg": 0.5180},
    (0.0016, "riverbed", "none"): {"bad1": 15.439, "bad3": 2.446, "avg": 0.6866},
}



@pytest.fixture(scope="module")
def kitti(shared_data):
    base = shared_data / KITTI
    return (read_image(base / "image_2/000046_10.png"), read_image(base / "image_3/000046_10.png"),
            read_disparity(base / "disp_occ_0/000046_10.png"))


@pytest.fixture(scope="module")
def results(kitti):
    left, right, gt = kitti
    d_max = int(np.ceil(np.nanmax(gt))) + 4
    out = {}
    for share in SHARES:
        sparse = simulate_lidar(gt, share, seed=0)
        for guide, fusion in CASES:
            kwargs = {} if fusion == "confidence" else {"fusion": fusion}  # confidence: the default
            r = match_pair(left, right, sparse, 0, d_max, guide=guide, **kwargs)
            assert r.info.fusion == fusion
            out[share, guide, fusion] = evaluate_disparity(r.disparity, gt, exclude=sparse)
    return out


def test_kitti_gates_catch_a_5_percent_regression():
    assert sorted(EXPECTED) == sorted((share, *case) for share in SHARES for case in CASES)
    assert_catches(EXPECTED)


def test_the_kitti_gates_catch_a_real_regression(kitti):
    """Not only arithmetic: riverbed run with worse settings falls outside the committed gates, the default inside.
    Measured at 5 %: a 25 px window instead of the auto one, bad3 0.321 against 0.239 %; the Delaunay fill as the
    fusion's LiDAR side instead of planes, bad3 0.343 %."""
    left, right, gt = kitti
    sparse = simulate_lidar(gt, 0.05, seed=0)
    d_max = int(np.ceil(np.nanmax(gt))) + 4
    case = (0.05, "riverbed", "confidence")
    for kwargs, passes in (({}, True), ({"window": 25}, False), ({"fusion_lidar": "linear"}, False)):
        r = match_pair(left, right, sparse, 0, d_max, guide="riverbed", **kwargs)
        lines = off_gate({case: evaluate_disparity(r.disparity, gt, exclude=sparse)}, {case: EXPECTED[case]})
        assert (lines == []) == passes, (kwargs, lines)


@pytest.mark.parametrize("guide, fusion", CASES)
def test_kitti_accuracy_holds_its_expectation(results, guide, fusion):
    assert_within(results, {k: v for k, v in EXPECTED.items() if k[1:] == (guide, fusion)})
    # unguided, the left edge whose match may lie outside the right image is invalid (1 % of the GT pixels); guided,
    # the LiDAR covers it
    low, high = (98.9, 99.1) if guide == "none" else (99.95, 100.0)
    assert all(low <= results[share, guide, fusion]["density"] <= high for share in SHARES)


def test_kitti_riverbed_ahead_of_gauss_ahead_of_none_at_5_percent(results):
    for fusion in ("confidence", "none"):
        none, gauss, rb = (results[0.05, g, f] for g, f in (("none", "none"), ("gauss", fusion), ("riverbed", fusion)))
        assert rb["bad3"] < gauss["bad3"] < none["bad3"] and rb["avg"] < gauss["avg"] < none["avg"], fusion


def test_kitti_riverbed_beats_unguided_at_every_share(results):
    for share in SHARES:
        for fusion in ("confidence", "none"):
            none, rb = results[share, "none", "none"], results[share, "riverbed", fusion]
            assert rb["bad3"] < none["bad3"] and rb["avg"] < none["avg"], (share, fusion)
