"""End-to-end accuracy on a real pair (Middlebury Cones, quarter size) with simulated LiDAR.

Every figure is gated within 2 % (small absolute floors: tests/gates.py) of the value measured with the current
code and committed below, for the three LiDAR shares of docs/benchmarks.md, each guide the docs make a claim for
(none, Gauss, riverbed), the default output (confidence fusion, ``fusion=auto``) and the matcher alone
(``fusion="none"``, the paper's method), and three LiDAR samplings (seeds 0, 1, 2): each seed is gated, so the worst
one is too.
"""

import pytest

from gates import assert_catches, assert_within, off_gate
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar

SHARES = (0.05, 0.0123, 0.0016)
SEEDS = (0, 1, 2)
#: (guide, fusion): the default output of each guide (``confidence`` with LiDAR) and the matcher alone
CASES = (("none", "none"), ("gauss", "confidence"), ("gauss", "none"), ("riverbed", "confidence"),
         ("riverbed", "none"))

#: Measured with the current code (2 cores): bad1 %, bad3 % and avg px over the GT pixels not used as LiDAR, per
#: seed (0, 1, 2). Worst seed: riverbed at 0.16 % (confidence) seed 1, 6.564 % / 0.7593 px (seed 2: 0.7787 px).
MEASURED = {
    (0.05, "none", "none"): {"bad1": (15.612, 15.665, 15.672), "bad3": (12.511, 12.536, 12.542),
                             "avg": (0.6958, 0.6982, 0.6985)},
    (0.05, "gauss", "confidence"): {"bad1": (7.347, 7.528, 7.562), "bad3": (4.073, 4.088, 4.307),
                                    "avg": (0.5443, 0.5506, 0.5641)},
    (0.05, "gauss", "none"): {"bad1": (7.526, 7.694, 7.754), "bad3": (4.113, 4.133, 4.337),
                              "avg": (0.5748, 0.5803, 0.5949)},
    (0.05, "riverbed", "confidence"): {"bad1": (3.219, 3.267, 3.352), "bad3": (1.533, 1.543, 1.595),
                                       "avg": (0.2733, 0.2718, 0.2787)},
    (0.05, "riverbed", "none"): {"bad1": (3.237, 3.294, 3.386), "bad3": (1.545, 1.558, 1.605),
                                 "avg": (0.2824, 0.2811, 0.2885)},
    (0.0123, "none", "none"): {"bad1": (15.610, 15.622, 15.626), "bad3": (12.487, 12.511, 12.503),
                               "avg": (0.6947, 0.6956, 0.6964)},
    (0.0123, "gauss", "confidence"): {"bad1": (10.627, 10.623, 10.699), "bad3": (6.109, 6.258, 6.105),
                                      "avg": (0.7380, 0.7489, 0.7344)},
    (0.0123, "gauss", "none"): {"bad1": (10.762, 10.790, 10.798), "bad3": (6.132, 6.266, 6.138),
                                "avg": (0.7568, 0.7683, 0.7539)},
    (0.0123, "riverbed", "confidence"): {"bad1": (5.165, 5.472, 5.379), "bad3": (2.373, 2.520, 2.537),
                                         "avg": (0.3899, 0.4115, 0.4027)},
    (0.0123, "riverbed", "none"): {"bad1": (5.185, 5.463, 5.396), "bad3": (2.371, 2.524, 2.543),
                                   "avg": (0.3985, 0.4199, 0.4129)},
    (0.0016, "none", "none"): {"bad1": (15.626, 15.630, 15.629), "bad3": (12.502, 12.507, 12.505),
                               "avg": (0.6958, 0.6962, 0.6960)},
    (0.0016, "gauss", "confidence"): {"bad1": (12.686, 13.113, 12.857), "bad3": (8.501, 9.019, 8.801),
                                      "avg": (0.9275, 0.9495, 0.9459)},
    (0.0016, "gauss", "none"): {"bad1": (12.687, 12.886, 12.735), "bad3": (8.515, 9.022, 8.789),
                                "avg": (0.9283, 0.9433, 0.9423)},
    (0.0016, "riverbed", "confidence"): {"bad1": (9.982, 10.516, 10.673), "bad3": (5.536, 6.564, 6.478),
                                         "avg": (0.7045, 0.7593, 0.7787)},
    (0.0016, "riverbed", "none"): {"bad1": (9.950, 10.296, 10.530), "bad3": (5.523, 6.551, 6.450),
                                   "avg": (0.7032, 0.7507, 0.7731)},
}
#: the same figures as gates: {(share, guide, fusion, seed): {metric: value}}
EXPECTED = {(*case, seed): {metric: values[i] for metric, values in metrics.items()}
            for case, metrics in MEASURED.items() for i, seed in enumerate(SEEDS)}


@pytest.fixture(scope="module")
def results(cones):
    left, right, gt = cones
    out = {}
    for seed in SEEDS:
        for share in SHARES:
            sparse = simulate_lidar(gt, share, seed=seed)
            for guide, fusion in CASES:
                kwargs = {} if fusion == "confidence" else {"fusion": fusion}  # confidence: the default
                r = match_pair(left, right, sparse, 0, 59, guide=guide, **kwargs)
                assert r.info.fusion == fusion
                out[share, guide, fusion, seed] = evaluate_disparity(r.disparity, gt, exclude=sparse)
    return out


def test_gates_catch_a_5_percent_regression():
    assert sorted(MEASURED) == sorted((share, *case) for share in SHARES for case in CASES)
    assert_catches(EXPECTED)


@pytest.mark.parametrize("guide, fusion", CASES)
def test_cones_accuracy_holds_its_expectation(results, guide, fusion):
    assert_within(results, {k: v for k, v in EXPECTED.items() if k[1:3] == (guide, fusion)})
    # unguided, the left edge whose match may lie outside the right image is invalid (7.3 % of the GT pixels); guided,
    # the LiDAR covers it but for the corners beyond its reach at 0.16 %
    low = 92.6 if guide == "none" else 99.8
    assert all(low < results[k]["density"] <= 100.0 for k in EXPECTED if k[1:3] == (guide, fusion))
    if guide == "none":
        assert all(results[k]["density"] < 92.8 for k in EXPECTED if k[1:3] == (guide, fusion))


def test_riverbed_ahead_of_gauss_ahead_of_none_at_5_percent(results):
    for fusion in ("confidence", "none"):
        for seed in SEEDS:
            none, gauss, rb = (results[0.05, g, f, seed] for g, f in (("none", "none"), ("gauss", fusion),
                                                                       ("riverbed", fusion)))
            assert rb["bad3"] < gauss["bad3"] < none["bad3"] and rb["avg"] < gauss["avg"] < none["avg"]


def test_riverbed_beats_unguided_at_every_share(results):
    for share in SHARES:
        for fusion in ("confidence", "none"):
            for seed in SEEDS:
                none, rb = results[share, "none", "none", seed], results[share, "riverbed", fusion, seed]
                # (mean errors are over the predicted pixels: the unguided match predicts 7 % fewer)
                assert rb["bad3"] < none["bad3"] and rb["bad1"] < none["bad1"], (share, fusion, seed)


def test_the_gates_catch_a_real_regression(cones):
    """Not only arithmetic: riverbed run with a worse setting (a 5 px window instead of the auto 9 at 5 %: measured
    bad3 1.92 against 1.53 %) falls outside the committed gates, and the default run inside them."""
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    case = (0.05, "riverbed", "confidence", 0)
    for kwargs, passes in (({}, True), ({"window": 5}, False)):
        r = match_pair(left, right, sparse, 0, 59, guide="riverbed", **kwargs)
        lines = off_gate({case: evaluate_disparity(r.disparity, gt, exclude=sparse)}, {case: EXPECTED[case]})
        assert (lines == []) == passes, lines
