"""Hidden point removal against known visibility (benchmarks/bench_visibility.py): Cones and hand-made cases."""

import sys
from pathlib import Path

import numpy as np
import pytest

from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry import projection as pj
from riverbed_cli.geometry.visibility import zbuffer_visible

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_visibility as bv  # noqa: E402

#: Measured with benchmarks/bench_visibility.py (docs/projection.md): (visible kept, hidden removed) on the Cones
#: round-trip scene at 10 % LiDAR, per edge_reach.
CONES_10 = {1.0: (0.9559, 0.9993), 0.25: (0.9915, 0.9975)}


def miss_close(measured, expected):
    """Miss rates (1 - share) agree within 10 % relative."""
    return abs((1 - measured) - (1 - expected)) <= 0.1 * (1 - expected)


@pytest.fixture(scope="module")
def cones_scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("vis")
    return folder, bv.cones_scene(0.1, folder)


@pytest.mark.parametrize("reach", [1.0, 0.25])
def test_cones_visible_kept_and_hidden_removed(cones_scene, reach):
    folder, (sc, gt) = cones_scene
    sparse, _ = pj.project_cloud(folder / "scene.las", sc["pair"], edge_reach=reach)
    m = bv.score_cones(sparse, gt, sc)
    kept, removed = CONES_10[reach]
    assert miss_close(m["visible_kept"], kept), m
    assert miss_close(m["hidden_removed"], removed), m
    if reach < 1:  # the target: >= 98.5 % visible kept with >= 99.5 % hidden removed
        assert m["visible_kept"] >= 0.985 and m["hidden_removed"] >= 0.995


def test_edge_reach_out_of_range_is_refused(cones_scene):
    folder, (sc, _) = cones_scene
    with pytest.raises(RiverbedError, match=r"^edge_reach must be between 0 and 1, got 1.5$"):
        pj.project_cloud(folder / "scene.las", sc["pair"], edge_reach=1.5)


def test_point_behind_a_surface_is_removed():
    # A surface of disparity 20 sampled every 3 px; one point at disparity 10 in the middle of a gap.
    yy, xx = np.mgrid[2:40:3, 2:40:3]
    rows = np.append(yy.ravel(), 20)
    cols = np.append(xx.ravel(), 21)
    disp = np.append(np.full(yy.size, 20.0), 10.0)
    for reach in (1.0, 0.25, 0.0):
        vis = zbuffer_visible(rows, cols, disp, (42, 42), edge_reach=reach)
        assert vis[:-1].all() and not vis[-1], reach


def test_background_beside_an_edge_is_kept_with_a_short_reach():
    # A foreground (d 20) sampled every 3 px on the left half; background points (d 10) from 2 px right of its
    # last column on. The whole disc hides the first background columns; edge_reach 0.25 keeps them (covered
    # from one side only), and still hides a background point inside the foreground.
    fy, fx = np.mgrid[1:40:3, 1:20:3]  # last column 19
    by, bx = np.mgrid[1:40:2, 21:40:2]
    rows = np.concatenate([fy.ravel(), by.ravel(), [20]])
    cols = np.concatenate([fx.ravel(), bx.ravel(), [11]])
    disp = np.concatenate([np.full(fy.size, 20.0), np.full(by.size, 10.0), [10.0]])
    nf, nb = fy.size, by.size
    full = zbuffer_visible(rows, cols, disp, (41, 41))
    short = zbuffer_visible(rows, cols, disp, (41, 41), edge_reach=0.25)
    assert full[:nf].all() and short[:nf].all()
    assert not full[nf:nf + nb].all()  # the disc reaches past the edge
    assert short[nf:nf + nb].all()
    assert not full[-1] and not short[-1]


def test_slanted_surface_next_to_denser_points_is_kept():
    # A slanted plane (disparity falling 0.4 px per px) sampled every 4 px, beside a denser patch of points
    # on the same plane: none is hidden, whatever the reach.
    yy, xx = np.mgrid[0:40:4, 0:60:4]
    dy, dx = np.mgrid[0:40:1, 60:70:1]
    rows = np.concatenate([yy.ravel(), dy.ravel()])
    cols = np.concatenate([xx.ravel(), dx.ravel()])
    disp = 40.0 - 0.4 * cols
    for reach in (1.0, 0.25, 0.0):
        assert zbuffer_visible(rows, cols, disp, (40, 70), edge_reach=reach).all(), reach


#: Sample block (ray-cast truth, bench_visibility.block_truth): (visible kept, hidden removed, wrong pixels).
BLOCK = {1.0: (0.9383, 0.8749, 146), 0.25: (0.9960, 0.6677, 350)}


def test_sample_block_visible_kept_and_hidden_removed():
    truth = bv.block_truth()
    assert (int(truth["visible"].sum()), int(truth["hidden"].sum())) == (9782, 951)
    for reach, (kept, removed, wrong) in BLOCK.items():
        sparse, _ = pj.project_cloud(bv.BLOCK / "lidar.laz", truth["pair"], edge_reach=reach)
        m = bv.score_points(sparse, truth["gt"], truth["rows"], truth["cols"], truth["disp"], truth["visible"],
                            truth["hidden"])
        assert miss_close(m["visible_kept"], kept) and miss_close(m["hidden_removed"], removed), (reach, m)
        assert abs(m["wrong"] - wrong) <= 0.1 * wrong, (reach, m)
