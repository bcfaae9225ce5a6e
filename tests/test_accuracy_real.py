"""Accuracy beyond the development scenes: the KITTI 2015 frame (real outdoor scene, sparse LiDAR-derived GT).

KITTI may not be copied into the repository; it is read from RIVERBED_DATA (CI sets ../shared/data).
"""

import numpy as np
import pytest

from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar

KITTI = "kitti2015_stereo_sttr/sample_data/KITTI_2015/training"


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
    for share in (0.05, 0.0016):
        sparse = simulate_lidar(gt, share, seed=0)
        for guide in ("none", "gauss", "riverbed"):
            disp = match_pair(left, right, sparse, 0, d_max, guide=guide).disparity
            out[share, guide] = evaluate_disparity(disp, gt, exclude=sparse)
    return out


def test_kitti_riverbed_at_5_percent(results):
    none, gauss, rb = results[0.05, "none"], results[0.05, "gauss"], results[0.05, "riverbed"]
    assert rb["bad3"] <= 0.3 * none["bad3"] and rb["avg"] <= 0.5
    assert rb["bad3"] < gauss["bad3"] < none["bad3"] and rb["avg"] < gauss["avg"] < none["avg"]


def test_kitti_riverbed_beats_unguided_at_0_16_percent(results):
    none, rb = results[0.0016, "none"], results[0.0016, "riverbed"]
    assert rb["bad3"] < none["bad3"] and rb["avg"] < none["avg"]
