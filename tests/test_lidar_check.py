"""The LiDAR check (matching/lidar_check.py): a changed region flagged and the output there following the images, an
outlier dropped, clean LiDAR left alone, the kernels against their plain statements, the setting and the mask."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.io.disparity import write_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.matching import lidar_check, lidar_regions
from riverbed_cli.matching.config import validate_setting
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar
from riverbed_cli.settings import SettingError
from test_lidar_offset import textured_pair


def constructed(H=160, W=240, d=10.0, step=4):
    """A textured pair at one disparity ``d`` and LiDAR on a grid every ``step`` px, with its truth."""
    left, right = textured_pair(d=d, H=H, W=W)
    sparse = np.full((H, W), np.nan, np.float32)
    sparse[2::step, 2::step] = d
    return left, right, sparse, np.full((H, W), d, np.float32)


def test_a_raised_region_is_flagged_and_the_output_there_follows_the_images():
    left, right, sparse, gt = constructed()
    region = np.zeros(sparse.shape, bool)
    region[40:110, 70:170] = True
    stale = np.where(region, sparse + 8, sparse)  # the LiDAR shows a surface 8 px above what the images see
    res = match_pair(left, right, stale)
    info, check = res.info["lidar_check"], res.lidar_check
    have = np.isfinite(sparse)
    assert (check.dropped[region & have] == 2).mean() >= 0.95  # the region's points dropped as a change
    assert (check.dropped[~region & have] > 0).mean() <= 0.01
    assert info["regions"] == 1 and info["change"] == pytest.approx(8.0, abs=0.5) and info["outliers"] == 0
    assert check.changed[region].mean() >= 0.9 and check.changed[~region].mean() < 0.1
    inside = evaluate_disparity(res.disparity, np.where(region, gt, np.nan), exclude=sparse)
    assert inside["bad3"] < 1.0  # the images, not the stale LiDAR
    off = match_pair(left, right, stale, lidar_check="off")
    assert evaluate_disparity(off.disparity, np.where(region, gt, np.nan), exclude=sparse)["bad3"] > 90
    assert off.info.lidar_check is None and "lidar_check" not in off.info.to_dict() and off.lidar_check is None


def test_a_lowered_region_is_flagged_too():
    left, right, sparse, gt = constructed(d=14.0)
    region = np.zeros(sparse.shape, bool)
    region[60:140, 40:130] = True
    res = match_pair(left, right, np.where(region, sparse - 7, sparse))
    have = np.isfinite(sparse)
    assert (res.lidar_check.dropped[region & have] == 2).mean() >= 0.95
    assert res.info["lidar_check"]["change"] == pytest.approx(-7.0, abs=0.5)
    assert evaluate_disparity(res.disparity, np.where(region, gt, np.nan), exclude=sparse)["bad3"] < 1.0


def test_single_gross_outliers_are_dropped_and_nothing_else():
    left, right, sparse, gt = constructed()
    rng = np.random.default_rng(4)
    rows, cols = np.nonzero(np.isfinite(sparse))
    pick = rng.choice(rows.size, 12, replace=False)
    bad = sparse.copy()
    bad[rows[pick], cols[pick]] = rng.choice([25.0, 31.0, 2.0], 12)  # birds and low points
    res = match_pair(left, right, bad)
    dropped = res.lidar_check.dropped
    assert (dropped[rows[pick], cols[pick]] == 1).mean() >= 11 / 12
    assert (dropped > 0).sum() <= 13 and res.info["lidar_check"]["changed"] == 0


def test_a_lone_point_the_images_cannot_judge_is_dropped_only_far_off_its_neighbours():
    # on a flat patch (the same grey in both views) no patch cost says anything: a point there with no neighbour
    # within TAU is dropped when it lies more than 2 TAU off their median, kept closer than that
    left, right, sparse, gt = constructed()
    left, right = left.copy(), right.copy()
    left[56:88, 96:128] = 128
    right[56:88, 86:118] = 128
    bad = sparse.copy()
    bad[66, 110] = 25.0  # 15 px off: a bird over a roof the images cannot see
    bad[74, 106] = 14.0  # 4 px off: within twice the tolerance, the benefit of the doubt
    bad[72:89, 112:129] = np.nan
    bad[82, 122], bad[78, 118], bad[86, 126] = 25.0, 10.0, 10.0  # 15 px off two neighbours only: no plane to
    res = match_pair(left, right, bad)  # outvote it
    dropped = res.lidar_check.dropped
    assert dropped[66, 110] == 1 and dropped[74, 106] == 0 and dropped[82, 122] == 0
    assert (dropped > 0).sum() == 1 and res.info["lidar_check"]["outliers"] == 1


def test_a_patch_vouches_only_when_no_other_disparity_of_the_range_matches_it_better():
    from riverbed_cli.io.images import to_grey
    from riverbed_cli.matching.lidar_offset import patch_costs

    left, right, _, _ = constructed()
    gl, gr = to_grey(left, 8), to_grey(right, 8)
    rows, cols = np.array([50, 60, 70]), np.array([100, 120, 140])
    values = np.array([10.0, 25.0, 11.0])  # the truth; a random disparity; the truth + 1 px
    own = patch_costs(gl, gr, rows, cols, values.astype(np.float32), np.zeros(1), cap=lidar_check.NO_INFO)[:, 0]
    # the truth is best; 25 px is beaten at 10 px; 11 px is beaten at 10 px, but that lies within 2 px of it
    assert lidar_check._unique(gl, gr, rows, cols, values, own, 0, 40, 2).tolist() == [True, False, True]
    assert lidar_check._unique(gl, gr, rows, cols, values, own, 0, 40, 0).tolist() == [True, False, False]

def test_the_coarse_to_fine_reference_is_the_whole_ranges(cones):
    # the reference searched in tubes round a match at half its resolution finds what the whole range finds
    from riverbed_cli.matching.config import MatchConfig
    from riverbed_cli.matching.range_maps import coarse_match, coarse_to_fine_match

    left, right, _ = cones
    whole, fine = (f(left, right, 0, 63, 2, MatchConfig(), match_pair, lidar_check.REFERENCE_MATCH)
                   for f in (coarse_match, coarse_to_fine_match))
    both = np.isfinite(whole) & np.isfinite(fine)
    assert both.mean() > 0.8 and np.isfinite(fine).mean() == pytest.approx(np.isfinite(whole).mean(), abs=0.02)
    assert np.mean(np.abs(whole[both] - fine[both]) <= 1) > 0.99


def test_clean_lidar_is_kept(cones):
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    res = match_pair(left, right, sparse)
    info = res.info["lidar_check"]
    assert info["changed"] == 0 and info["regions"] == 0 and info["outliers"] <= 0.001 * info["points"]
    off = match_pair(left, right, sparse, lidar_check="off")
    a, b = (evaluate_disparity(r.disparity, gt, exclude=sparse)["bad3"] for r in (res, off))
    assert abs(a - b) <= 0.05  # points of bad3 (measured 1.53 against 1.50 %: the 6 outliers it drops were right)


def test_a_stale_block_on_a_real_scene(cones):
    # Cones at 5 %: a quarter of the image whose LiDAR is 20 % of its span too high; inside, the output is about as
    # good as unguided matching and as the default without those points (committed figures, docs/lidar_faults.md)
    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    H, W = gt.shape
    block = np.zeros((H, W), bool)
    block[int(0.3 * H):int(0.3 * H) + int(0.25 * H), int(0.3 * W):int(0.3 * W) + int(0.25 * W)] = True
    vals = sparse[np.isfinite(sparse)]
    stale = np.where(block, sparse + np.float32(0.2 * (vals.max() - vals.min())), sparse)
    res = match_pair(left, right, stale)
    have = np.isfinite(sparse)
    assert 0.93 <= (res.lidar_check.dropped[block & have] > 0).mean() <= 1.0
    inside = evaluate_disparity(res.disparity, np.where(block, gt, np.nan), exclude=sparse)
    assert 8.0 <= inside["bad3"] <= 12.0


def scattered(seed, n):
    """A 40 x 50 sparse map of ``n`` points at random pixels, random disparities in [0, 20), and the points."""
    rng = np.random.default_rng(seed)
    sparse = np.full((40, 50), np.nan, np.float32)
    sparse.flat[rng.choice(2000, n, replace=False)] = rng.uniform(0, 20, n).astype(np.float32)
    return sparse, *np.nonzero(np.isfinite(sparse))


def test_the_neighbour_kernel_is_its_plain_statement():
    sparse, rows, cols = scattered(2, 300)
    around, supported = lidar_check.neighbour_stats(sparse, rows, cols, 3)
    for i in range(rows.size):
        win = sparse[max(0, rows[i] - 3):rows[i] + 4, max(0, cols[i] - 3):cols[i] + 4].copy()
        win[min(rows[i], 3), min(cols[i], 3)] = np.nan  # itself
        others = win[np.isfinite(win)]
        assert around[i] == pytest.approx(np.median(others) if others.size else np.nan, nan_ok=True)
        assert supported[i] == bool((np.abs(others - sparse[rows[i], cols[i]]) <= lidar_check.TAU).any())


def test_the_plane_kernel_is_its_plain_statement():
    sparse, rows, cols = scattered(3, 150)
    plane = lidar_check.plane_at(sparse, rows, cols, 4)
    for i in range(rows.size):
        y, x = np.mgrid[max(0, rows[i] - 4):min(40, rows[i] + 5), max(0, cols[i] - 4):min(50, cols[i] + 5)]
        v = sparse[y, x]
        keep = np.isfinite(v) & ((y != rows[i]) | (x != cols[i]))
        A = np.column_stack([np.ones(keep.sum()), x[keep] - cols[i], y[keep] - rows[i]])
        if keep.sum() < 3 or np.linalg.matrix_rank(A) < 3:
            assert np.isnan(plane[i])
        else:
            want = np.linalg.lstsq(A, v[keep].astype(np.float64), rcond=None)[0][0]
            assert plane[i] == pytest.approx(want, abs=1e-6)
    line = np.full((20, 30), np.nan, np.float32)
    line[10, 2:28:3] = 5.0  # points all on one row: no plane
    assert np.isnan(lidar_check.plane_at(line, [10], [14], 6)[0])
    ramp = np.where(np.isfinite(sparse), 0, np.nan) + np.arange(50, dtype=np.float32) * 1.5  # a steep slope
    assert lidar_check.plane_at(ramp, [20], [20], 4)[0] == pytest.approx(30.0)


def _index(sparse):
    rows, cols = np.nonzero(np.isfinite(sparse))
    index = np.full(sparse.shape, -1, np.int32)
    index[rows, cols] = np.arange(rows.size, dtype=np.int32)
    return index, rows.astype(np.int64), cols.astype(np.int64), sparse[rows, cols].astype(np.float64)


def test_a_change_spreads_along_the_lidar_surface_not_across_a_stale_blocks_edge():
    # one row of points 2 px apart: a seed (contradicted, LiDAR below the images), two the images cannot judge on
    # its surface, then the clean LiDAR 28 px higher (unjudged), then one point contradicted the same way
    sparse = np.full((5, 40), np.nan, np.float32)
    sparse[2, 2:40:2] = [10, 10.5, 11, 39, 39.5, 40, 40.5, 41, 41.5, 42, 42.5, 43, 43.5, 44, 44.5, 45, 45.5, 46, 46.5]
    index, rows, cols, values = _index(sparse)
    state = np.zeros(values.size, np.int8)
    seeds = np.zeros(values.size, np.int8)
    seeds[0] = state[0] = -1
    no_lean = np.full(values.size, np.nan), np.full(values.size, -29.0), lidar_check.TAU
    taken = lidar_regions.flood(index, rows, cols, values, 2, state, seeds, 2, lidar_check.SURFACE_STEP, *no_lean)
    assert taken.tolist() == [True, True, True] + [False] * 16  # not across the 28 px jump
    state[3] = -1  # the first point beyond the jump contradicted the same way: the change takes it, then 2 more
    taken = lidar_regions.flood(index, rows, cols, values, 2, state, seeds, 2, lidar_check.SURFACE_STEP, *no_lean)
    assert taken.tolist() == [True] * 6 + [False] * 13
    state[4] = 2  # a point the reference confirms stops it
    taken = lidar_regions.flood(index, rows, cols, values, 2, state, seeds, 2, lidar_check.SURFACE_STEP, *no_lean)
    assert taken.tolist() == [True] * 4 + [False] * 15


def test_a_change_passes_where_only_the_reference_contradicts_the_lidar_by_its_change():
    # a lowered block on a flat wall: a seed the images contradict, then a row of flat patches (unjudged) where the
    # reference lies 29 px above the LiDAR, as the region's change says, then one 12 px above it, then no reference
    sparse = np.full((5, 40), np.nan, np.float32)
    sparse[2, 2:40:2] = 10.0
    index, rows, cols, values = _index(sparse)
    state = np.zeros(values.size, np.int8)
    seeds = np.zeros(values.size, np.int8)
    seeds[0] = state[0] = -1
    level = np.zeros(values.size)
    level[0] = -29.0
    lean = np.full(values.size, -29.0)
    lean[12], lean[13:] = -12.0, np.nan
    taken = lidar_regions.flood(index, rows, cols, values, 2, state, seeds, 2, lidar_check.SURFACE_STEP,
                                lean, level, lidar_check.TAU)
    # through the leaning points freely, then 2 unjudged in a row past the one that leans by another change
    assert taken.tolist() == [True] * 14 + [False] * 5
    taken = lidar_regions.flood(index, rows, cols, values, 2, state, seeds, 2, lidar_check.SURFACE_STEP,
                                np.full(values.size, np.nan), level, lidar_check.TAU)
    assert taken.tolist() == [True] * 3 + [False] * 16  # without the reference's lean: 2 unjudged in a row


def test_an_unjudged_point_continues_a_change_only_nearer_the_lidar_surface_than_the_images():
    # a seed, then unjudged points 2.5 px apart: along a change of -29 px they continue the stale surface (within
    # 9 px), along a change of -4 px they lie nearer the images' surface (more than half the change away)
    sparse = np.full((5, 12), np.nan, np.float32)
    sparse[2, 2:12:2] = [10.0, 12.5, 15.0, 17.5, 20.0]
    index, rows, cols, values = _index(sparse)
    state = np.zeros(values.size, np.int8)
    seeds = np.zeros(values.size, np.int8)
    seeds[0] = state[0] = -1
    no_lean = np.full(values.size, np.nan)
    for change, want in ((-29.0, [True] * 3 + [False] * 2), (-4.0, [True] + [False] * 4)):
        level = np.full(values.size, change)
        taken = lidar_regions.flood(index, rows, cols, values, 2, state, seeds, 2, lidar_check.SURFACE_STEP,
                                    no_lean, level, lidar_check.TAU)
        assert taken.tolist() == want


def fringe_plain(sparse, rows, cols, values, radius, state, taken, tau):
    """The fringe rule as a plain loop: rounds of every point joining at once."""
    out = taken.copy()
    while True:
        add = np.zeros_like(out)
        for j in range(values.size):
            if out[j] or state[j] == 2:
                continue
            same = inside = 0
            near_change = False
            for k in range(values.size):
                if k == j or abs(rows[k] - rows[j]) > radius or abs(cols[k] - cols[j]) > radius:
                    continue
                near_change |= bool(out[k])
                if abs(values[k] - values[j]) <= tau:
                    same += 1
                    inside += int(out[k])
            add[j] = near_change and 2 * inside > same
        if not add.any():
            return out
        out |= add


def test_the_fringe_kernel_is_its_plain_statement():
    for seed in range(4):
        sparse, _, _ = scattered(seed, 400)
        index, rows, cols, values = _index(sparse)
        rng = np.random.default_rng(seed)
        state = rng.choice(np.array([-1, 0, 1, 2], np.int8), values.size, p=[0.2, 0.5, 0.1, 0.2])
        taken = rng.random(values.size) < 0.1
        got = lidar_regions.fringe(index, rows, cols, values, 3, state, taken, lidar_check.TAU)
        want = fringe_plain(sparse, rows, cols, values, 3, state, taken, lidar_check.TAU)
        assert (got == want).all() and got.sum() > taken.sum()


def test_a_changes_fringe_joins_it_and_the_clean_lidar_round_it_does_not():
    # a stale block (value 10) with a taken core and an untaken rim, set in clean LiDAR 28 px higher
    sparse = np.full((30, 30), 38.0, np.float32)
    sparse[8:22, 8:22] = 10.0
    index, rows, cols, values = _index(sparse)
    taken = (rows >= 10) & (rows < 20) & (cols >= 10) & (cols < 20)
    state = np.zeros(values.size, np.int8)
    got = lidar_regions.fringe(index, rows, cols, values, 2, state, taken, lidar_check.TAU)
    block = (rows >= 8) & (rows < 22) & (cols >= 8) & (cols < 22)
    assert (got == block).all()
    state[(rows == 8) & (cols == 15)] = 2  # a rim point the reference confirms stays
    got = lidar_regions.fringe(index, rows, cols, values, 2, state, taken, lidar_check.TAU)
    assert not got[(rows == 8) & (cols == 15)].any() and got.sum() == block.sum() - 1

def test_the_changed_area_drawn_in_its_box_is_the_whole_images():
    # changed_area closes the changed points' discs inside their bounding box with a margin: the same area as the
    # plain statement, the closing over the whole image (points near the edges and far apart included)
    import cv2

    rng = np.random.default_rng(7)
    for _ in range(60):
        H, W = (int(v) for v in rng.integers(40, 300, 2))
        n = int(rng.integers(1, 40))
        cy, cx = int(rng.integers(0, H)), int(rng.integers(0, W))
        rows = np.clip(cy + rng.integers(-60, 60, n), 0, H - 1)
        cols = np.clip(cx + rng.integers(-60, 60, n), 0, W - 1)
        spacing = float(rng.uniform(1, 12))
        r = max(1, int(round(spacing)))
        whole = np.zeros((H, W), np.uint8)
        whole[rows, cols] = 1
        whole = cv2.dilate(whole, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
        whole = cv2.morphologyEx(whole, cv2.MORPH_CLOSE,
                                 cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (4 * r + 1, 4 * r + 1))).astype(bool)
        assert np.array_equal(lidar_regions.changed_area(rows, cols, (H, W), spacing), whole)


def test_the_setting_and_its_message():
    assert validate_setting("lidar_check", "off") == "off"
    with pytest.raises(SettingError, match="'maybe'"):
        validate_setting("lidar_check", "maybe")


def test_the_cli_writes_the_mask_and_refuses_bad_values(tmp_path):
    left, right, sparse, gt = constructed()
    region = np.zeros(sparse.shape, bool)
    region[40:110, 70:170] = True
    for name, im in (("l.png", left), ("r.png", right)):
        import cv2
        cv2.imwrite(str(tmp_path / name), im)
    write_disparity(tmp_path / "s.tif", np.where(region, sparse + 8, sparse))
    args = ["match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(tmp_path / "d.tif"),
            "--sparse", str(tmp_path / "s.tif")]
    r = CliRunner().invoke(cli, [*args, "--lidar-mask", str(tmp_path / "m.png"), "--json"])
    assert r.exit_code == 0, r.output
    summary = json.loads(r.output)
    assert summary["lidar_check"]["regions"] == 1
    mask = read_image(tmp_path / "m.png")
    assert set(np.unique(mask)) <= {0, 1, 3, 4}
    have = np.isfinite(sparse)
    assert (mask[region & have] == 3).mean() >= 0.95 and (mask[~region & have] == 1).mean() > 0.99
    assert (mask == 4).sum() > 0 and not (mask[~np.isfinite(sparse)] == 1).any()
    # a pair matched in tiles: the check ran once for the whole pair, its mask is written as a whole match's
    r = CliRunner().invoke(cli, [*args, "--tile", "96", "--overlap", "24", "--lidar-mask", str(tmp_path / "t.png"),
                                 "--json", "--overwrite"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["tiles"] == 6 and json.loads(r.output)["lidar_check"]["regions"] == 1
    tiled = read_image(tmp_path / "t.png")
    assert (tiled[region & have] == 3).mean() >= 0.95 and (tiled[~region & have] == 1).mean() > 0.99
    assert (tiled == 4).sum() > 0 and not (tiled[~have] == 1).any()
    r = CliRunner().invoke(cli, [*args, "--lidar-check", "maybe", "--overwrite"])
    assert r.exit_code == 1 and "--lidar-check" in r.output and "'maybe'" in r.output
    r = CliRunner().invoke(cli, [*args, "--lidar-mask", str(tmp_path / "m.tif"), "--overwrite"])
    assert r.exit_code == 1 and "the LiDAR mask must be written to a .png file" in r.output
    r = CliRunner().invoke(cli, [*args[:5], "--max-disp", "20", "--lidar-mask", str(tmp_path / "n.png"),
                                 "--overwrite"])
    assert r.exit_code == 1 and "--lidar-mask needs --sparse" in r.output
