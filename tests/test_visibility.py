"""Hidden point removal against known visibility (benchmarks/bench_visibility.py): Cones and hand-made cases."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry import projection as pj
from riverbed_cli.geometry.visibility import surface_cell, surface_grid, surface_visible, zbuffer_visible
from riverbed_cli.io.disparity import read_disparity

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_visibility as bv  # noqa: E402

#: The committed rows of benchmarks/bench_visibility.py (docs/projection.md). The projection is deterministic: its
#: shares are gated to 1e-6 and its pixel counts exactly.
ROWS = json.loads((Path(__file__).resolve().parents[1] / "benchmarks" / "results_visibility.json").read_text())


def assert_row(m, r):
    """A scored projection ``m`` is the committed row ``r``."""
    got = (m["visible_kept"], m["hidden_removed"], m["wrong"], m["n_visible"], m["n_hidden"])
    want = (r["visible_kept"], r["hidden_removed"], r["wrong"], r["n_visible"], r["n_hidden"])
    assert got == pytest.approx(want, abs=1e-6), (r["rule"], got, want)


@pytest.fixture(scope="module")
def cones_scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("vis")
    return folder, bv.cones_scene(0.1, folder)


@pytest.mark.parametrize("rule", [name for name, _ in bv.RULES])
def test_cones_visible_kept_and_hidden_removed(cones_scene, rule):
    folder, (sc, gt) = cones_scene
    sparse, _ = pj.project_cloud(folder / "scene.las", sc["pair"], **dict(bv.RULES)[rule])
    assert_row(bv.score_cones(sparse, gt, sc), bv.row(ROWS, "Cones", rule, 0.1))


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


@pytest.fixture(scope="module")
def block_truth():
    return bv.block_truth()


@pytest.mark.parametrize("rule", [name for name, _ in bv.RULES + [bv.AGGRESSIVE]])
def test_sample_block_visible_kept_and_hidden_removed(block_truth, rule):
    truth = block_truth
    sparse, st = pj.project_cloud(bv.BLOCK / "lidar.laz", truth["pair"], **dict(bv.RULES + [bv.AGGRESSIVE])[rule])
    m = bv.score_points(sparse, truth["gt"], truth["rows"], truth["cols"], truth["disp"], truth["visible"],
                        truth["hidden"])
    assert_row(m, bv.row(ROWS, "sample block", rule))
    occ = st["occluded"]
    assert st["kept"] + occ["left"] + occ["right"] + occ["same_pixel"] < st["points_read"]


def building_scene():
    """Ground (z 0) sampled every 1 m on 40 x 30 m, a flat roof at 10 m on x 10..20, y 10..20 (walls unsampled)."""
    gy, gx = np.mgrid[0:31, 0:41].astype(np.float64)
    on_roof = (gx >= 10) & (gx <= 20) & (gy >= 10) & (gy <= 20)
    xyz = np.column_stack([gx.ravel(), gy.ravel(), np.where(on_roof, 10.0, 0.0).ravel()])
    return xyz


def test_surface_grid_of_a_building():
    xyz = building_scene()
    assert surface_cell(xyz) == pytest.approx(1.0, abs=0.03)
    grid, origin, cell = surface_grid(xyz)
    assert cell == pytest.approx(0.5 * surface_cell(xyz))
    # The wall lies halfway between the last roof sample (x 10) and the first ground sample (x 9), to a cell.
    x = origin[0] + (np.arange(grid.shape[1]) + 0.5) * cell
    row = grid[int((15 - origin[1]) / cell)]
    assert (row[(x > 10.0) & (x < 20.0)] == 10.0).all() and (row[(x < 9.0) | (x > 21.0)] == 0.0).all()


def test_surface_test_hides_ground_behind_a_wall_and_keeps_open_ground_and_roofs():
    xyz = building_scene()
    surface = surface_grid(xyz)
    camera = np.array([300.0, 15.0, 600.0])  # east, 2 m up per m towards it: a wall of 10 m hides 5 m of ground
    tests = np.array([[7.0, 15.0, 0.0],  # ground west of the wall, seen by the LiDAR: behind the wall
                      [4.0, 15.0, 0.0],  # ground 6 m west of the wall: the ray clears it (12 m up at x 10)
                      [30.0, 15.0, 0.0],  # ground east of the building, in the open
                      [5.0, 28.0, 0.0],  # ground far from the building
                      [15.0, 15.0, 10.0],  # roof
                      [10.0, 12.0, 10.0],  # roof edge, on the hidden side
                      [15.0, 15.0, 2.0]])  # inside the building (a last return under a roof)
    vis = surface_visible(tests, camera, surface)
    assert vis.tolist() == [False, True, True, True, True, True, False]
    # From a camera straight above, nothing on the ground beside the walls is hidden.
    assert surface_visible(tests, np.array([15.0, 15.0, 600.0]), surface).tolist() == [True] * 6 + [False]
    # A camera below the points (not an aerial frame): the test does not apply, everything is kept.
    assert surface_visible(tests, np.array([300.0, 15.0, -600.0]), surface).all()


def test_surface_margin_keeps_points_just_below_the_surface():
    xyz = building_scene()
    surface = surface_grid(xyz)
    p = np.array([[15.0, 15.0, 9.6], [15.0, 15.0, 9.4]])  # 0.4 m and 0.6 m under the roof
    assert surface_visible(p, np.array([15.0, 15.0, 600.0]), surface, margin=0.5).tolist() == [True, False]


def test_visibility_mode_is_checked(cones_scene):
    folder, (sc, _) = cones_scene
    with pytest.raises(RiverbedError, match=r"^visibility must be one of zbuffer, surface, surface\+zbuffer, "
                                            r"hpr, none, got 'ground'$"):
        pj.project_cloud(folder / "scene.las", sc["pair"], visibility="ground")
    with pytest.raises(RiverbedError, match=r"^surface_margin must be at least 0 m, got -0.5$"):
        pj.project_cloud(folder / "scene.las", sc["pair"], visibility="surface", surface_margin=-0.5)


def test_cli_surface_visibility_writes_the_library_map(tmp_path):
    out = tmp_path / "sparse.tif"
    r = CliRunner().invoke(cli, ["project", str(bv.BLOCK / "lidar.laz"), str(bv.BLOCK / "pair.yaml"), "-o",
                                 str(out), "--visibility", "surface+zbuffer", "--edge-reach", "0.75"])
    assert r.exit_code == 0, r.output
    pair = bv.load_pairfile(bv.BLOCK / "pair.yaml")
    ref, _ = pj.project_cloud(bv.BLOCK / "lidar.laz", pair, visibility="surface+zbuffer", edge_reach=0.75)
    got = read_disparity(out)
    assert np.array_equal(np.isfinite(got), np.isfinite(ref)) and np.array_equal(got[np.isfinite(got)],
                                                                                 ref[np.isfinite(ref)])
    base, _ = pj.project_cloud(bv.BLOCK / "lidar.laz", pair)
    assert np.isfinite(base).sum() != np.isfinite(got).sum()  # the option reached the library
