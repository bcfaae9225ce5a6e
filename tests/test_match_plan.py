"""One plan of a match (scale/match_plan.py): made of the LiDAR as it guides, the same for a tiled match, a whole
one and a block's tiles."""

import json

import numpy as np

from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.matching.config import MatchConfig
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.simulate import simulate_lidar
from riverbed_cli.scale.match_plan import MatchPlan, plan_match
from riverbed_cli.scale.tiles import match_tiled, prepare_lidar_whole
from conftest import DATA

CONES = DATA / "cones"


def cones_with_outliers(share=0.05, every=40):
    left, right = read_image(f"{CONES}/im2.png"), read_image(f"{CONES}/im6.png")
    sparse = simulate_lidar(read_disparity(f"{CONES}/disp2.png", scale=4), share, seed=0)
    rng = np.random.default_rng(3)
    idx = np.flatnonzero(np.isfinite(sparse))
    pick = rng.choice(idx, idx.size // every, replace=False)
    sparse.flat[pick] = rng.uniform(np.nanmin(sparse), np.nanmax(sparse), pick.size).astype(np.float32)
    return left, right, sparse


def test_one_tile_is_the_whole_match_when_the_check_drops_points():
    # the plan counts the points the check kept, as match_pair does (the share before the check set another
    # window and other tubes)
    left, right, sparse = cones_with_outliers()
    whole = match_pair(left, right, sparse)
    assert whole.info["lidar_check"]["outliers"] > 20
    tiled = match_tiled(left, right, sparse, tile=4096)
    assert tiled.info["tiles"] == 1
    assert tiled.info["lidar_share"] == whole.info["lidar_share"]
    assert tiled.info["window"] == whole.info["window"]
    np.testing.assert_array_equal(tiled.disparity, whole.disparity)


def test_the_plan_counts_the_points_that_guide():
    left, right, sparse = cones_with_outliers()
    n = int(np.isfinite(sparse).sum())
    points = np.nonzero(np.isfinite(sparse)) + (sparse[np.isfinite(sparse)],)
    lidar = prepare_lidar_whole(left, right, sparse, points, None, None, MatchConfig())
    kept = lidar.points[0].size
    assert n - kept == lidar.check.report.outliers + lidar.check.report.changed
    plan = plan_match(left.shape[:2], lidar.points, lidar.d_min, lidar.d_max, MatchConfig(), sparse=lidar.sparse,
                      tile=128, overlap=32)
    H, W = left.shape[:2]
    assert abs(plan.share_all - kept / (H * W)) < 0.002 and plan.share_in_range == plan.share_all
    assert plan.tiled and plan.tile == 128 and len(plan.tiles) == 12  # 375 x 450 px in 128 px tiles: 3 x 4
    assert plan.tube_width is not None and 1 < plan.tube_width < lidar.d_max - lidar.d_min
    # plain values: a block's project task hands the plan to its tile tasks through dask as it is
    again = MatchPlan.from_dict(json.loads(json.dumps(plan.to_dict())))
    assert again == plan
    assert [t.x1 for t in again.tile_list()][:4] == [128, 256, 384, 450]
