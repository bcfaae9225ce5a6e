"""LiDAR tubes: the tube rule on hand-made cases, and every stage on a tube volume checked exactly against the dense
volume (tubes as wide as the range) and against a brute-force reference (narrow tubes)."""

import numpy as np
import pytest

from gates import inside_overlap
from riverbed_cli.matching import census, diffusion, disparity, guidance, riverbed_plus, sgm
from riverbed_cli.matching.guidance import lidar_share
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.matching.tubes import cell_tubes, lidar_tube_layout, lidar_tubes
from riverbed_cli.matching.volume import BAND_ROWS, TubeLayout, band_pair_rows, band_pairs
from tube_volumes import gather

SENT = 10 ** 9


def random_tubes(rng, H, W, D, narrow=True, most=5):
    lo = rng.integers(0, D, (H, W)) if narrow else np.zeros((H, W), int)
    hi = np.minimum(D - 1, lo + rng.integers(0, most, (H, W))) if narrow else np.full((H, W), D - 1)
    return lo, hi


def sgm_reference(cost, lo, hi, P1, P2, dirs):
    """Path costs summed over ``dirs`` with disparities outside a pixel's tube unreachable (brute force)."""
    H, W, D = cost.shape
    total = np.zeros((H, W, D), np.int64)
    for dx, dy in dirs:
        L = np.full((H, W, D), SENT, np.int64)
        forward = dy > 0 or (dy == 0 and dx > 0)
        ys = range(H) if forward else range(H - 1, -1, -1)
        xs = list(range(W)) if forward else list(range(W - 1, -1, -1))
        for y in ys:
            for x in xs:
                qx, qy = x - dx, y - dy
                for d in range(lo[y, x], hi[y, x] + 1):
                    if not (0 <= qx < W and 0 <= qy < H):
                        L[y, x, d] = cost[y, x, d]
                        continue
                    prev = L[qy, qx]
                    mp = prev[lo[qy, qx]:hi[qy, qx] + 1].min()
                    best = min(prev[d], (prev[d - 1] if d > 0 else SENT) + P1,
                               (prev[d + 1] if d < D - 1 else SENT) + P1, mp + P2)
                    L[y, x, d] = cost[y, x, d] + best - mp
        total += np.where(L < SENT, L, 0)
    return total


# (11, 5): tubes of 1-5 of 11 disparities. (80, 40): tubes of up to 40 (several vector chunks, sgm.LANES) whose
# offsets differ by up to 79, past the guard of the ring buffer (the scalar steps).
@pytest.mark.parametrize("paths", [4, 8, 16])
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("D, most", [(11, 5), (80, 40)])
def test_tube_sgm_equals_the_brute_force_reference(paths, seed, D, most):
    rng = np.random.default_rng(seed)
    H, W = 7, 9
    cost = rng.integers(0, 60, (H, W, D)).astype(np.uint16)
    lo, hi = random_tubes(rng, H, W, D, most=most)
    layout = TubeLayout.from_bounds(lo, hi, 0)
    fwd, bwd = sgm.sgm_aggregate_passes(gather(cost, layout), 7, 40, paths, tubes=layout)
    dirs = sgm.path_directions(paths)
    ref_f = sgm_reference(cost, lo, hi, 7, 40, dirs[: paths // 2])
    ref_b = sgm_reference(cost, lo, hi, 7, 40, dirs[paths // 2:])
    np.testing.assert_array_equal(fwd, gather(ref_f, layout).astype(np.uint16))
    np.testing.assert_array_equal(bwd, gather(ref_b, layout).astype(np.uint16))


# One pass's rows swept by 1-4 threads (sgm.sgm_forward_pass: rows taken from a counter, each swept in blocks once the
# rows before have done what it reads; 100 px wide rows are 1-4 blocks): the brute-force reference's bits, dense and
# in tubes. More threads than this process runs (2 on the CI machine) take the rows no other took.
@pytest.mark.parametrize("paths", [4, 8, 16])
@pytest.mark.parametrize("tubes", [False, True])
def test_a_pass_on_one_to_four_threads_equals_the_brute_force_reference(paths, tubes):
    rng = np.random.default_rng(paths)
    H, W, D = 14, 100, 11
    cost = rng.integers(0, 60, (H, W, D)).astype(np.uint16)
    lo, hi = random_tubes(rng, H, W, D, most=5) if tubes else (np.zeros((H, W), int), np.full((H, W), D - 1))
    layout = TubeLayout.from_bounds(lo, hi, 0)
    want = gather(sgm_reference(cost, lo, hi, 7, 40, sgm.path_directions(paths)[: paths // 2]), layout)
    for threads in (1, 2, 3, 4):
        got = sgm.sgm_forward_pass(gather(cost, layout) if tubes else cost, 7, 40, paths,
                                   tubes=layout if tubes else None, threads=threads)
        np.testing.assert_array_equal(got.reshape(-1), want.astype(np.uint16).reshape(-1), err_msg=f"{threads}")


def assert_passes_equal_the_reference(cost, lo, hi, paths):
    """Both SGM passes over the tubes ``[lo, hi]`` of ``cost`` (P1 7, P2 40) equal the brute-force reference."""
    layout = TubeLayout.from_bounds(lo, hi, 0)
    fwd, bwd = sgm.sgm_aggregate_passes(gather(cost, layout), 7, 40, paths, tubes=layout)
    dirs = sgm.path_directions(paths)
    for got, half in ((fwd, dirs[: paths // 2]), (bwd, dirs[paths // 2:])):
        np.testing.assert_array_equal(got, gather(sgm_reference(cost, lo, hi, 7, 40, half), layout).astype(np.uint16))


def hole_tubes(rng, H, W, D):
    """Tubes as the LiDAR makes them: narrow ones whose offsets drift slowly, a block of wide ones (20-40 disparities,
    offsets drifting alike) and a hole searching the whole range, side by side in rows and columns."""
    lo = np.clip(np.cumsum(rng.integers(-1, 2, (H, W)), axis=1) + D // 3, 0, D - 1)
    hi = np.minimum(D - 1, lo + rng.integers(0, 12, (H, W)))
    lo[2:9, 3:12] = np.clip(lo[2:9, 3:12] - 10, 0, D - 1)
    hi[2:9, 3:12] = np.minimum(D - 1, lo[2:9, 3:12] + rng.integers(19, 40, (7, 9)))
    lo[5:12, 9:17], hi[5:12, 9:17] = 0, D - 1
    return lo, hi


# runs of wide tubes beside each other, within reach of their neighbours in the row and the column (at 4 paths both
# directions of such a pixel go in one step, sgm_pass._wide_pair_steps, and the column's sweep must skip them)
# (D 150: holes of 10 chunks, the aerial pairs' range)
@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("seed, D", [(0, 80), (1, 80), (2, 150)])
def test_tube_sgm_with_holes_equals_the_brute_force_reference(paths, seed, D):
    rng = np.random.default_rng(seed)
    H, W = 13, 19
    cost = rng.integers(0, 60, (H, W, D)).astype(np.uint16)
    assert_passes_equal_the_reference(cost, *hole_tubes(rng, H, W, D), paths)


def cell_made_tubes(rng, H, W, D, cell=4):
    """Tubes as the rule makes them, constant over cells of ``cell`` x ``cell`` pixels: offsets from a few values (so
    that a row's neighbouring cells often start at the same disparity with other widths), widths of 1-16 with a
    few wider cells among them."""
    ch, cw = -(-H // cell), -(-W // cell)
    lo = rng.choice([D // 4, D // 4 + 1, D // 2], (ch, cw))
    width = rng.integers(1, 17, (ch, cw))
    width[rng.random((ch, cw)) < 0.1] = 30
    hi = np.minimum(D - 1, lo + width - 1)
    expand = lambda a: np.repeat(np.repeat(a, cell, axis=0), cell, axis=1)[:H, :W]  # noqa: E731
    return expand(lo), expand(hi)


# tubes made per cell: at 4 paths most steps go in runs along a row whose tubes start at the same disparity
# (lanes_runs.lanes_run_pair, the row's path costs carried in registers), ended by a wider tube, another offset, a
# column neighbour out of reach or the row's end
@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tube_sgm_on_cell_tubes_equals_the_brute_force_reference(paths, seed):
    rng = np.random.default_rng(seed)
    H, W, D = 14, 23, 48
    cost = rng.integers(0, 60, (H, W, D)).astype(np.uint16)
    assert_passes_equal_the_reference(cost, *cell_made_tubes(rng, H, W, D), paths)


# aggregation with the selection handed over row by row (sgm.sgm_aggregate_select) against the two stages one after
# the other: dense and tube volumes, with and without the left-right check, on both threads and on one (where the
# passes run one after the other and the second thread's hand-over does all the rows)
@pytest.mark.parametrize("threads", [2, 1])
@pytest.mark.parametrize("tube", [True, False])
@pytest.mark.parametrize("paths", [4, 8])
def test_aggregation_with_selection_equals_the_two_stages(threads, tube, paths):
    import numba

    rng = np.random.default_rng(paths + 2 * tube)
    H, W, D = 41, 37, 30
    cost = rng.integers(0, 60, (H, W, D)).astype(np.uint16)
    layout = None
    if tube:
        lo, hi = hole_tubes(rng, H, W, D)
        layout = TubeLayout.from_bounds(lo - 3, hi - 3, -3)
        cost = gather(cost, layout)
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        for lr_check, status in ((False, False), (True, False), (False, True), (True, True)):
            fwd, bwd = sgm.sgm_aggregate_passes(cost, 7, 40, paths, tubes=layout)
            want = disparity.select_disparity(fwd, -3, True, lr_check, 1, bwd, tubes=layout, return_status=status)
            got = sgm.sgm_aggregate_select(cost, 7, 40, -3, paths, tubes=layout, lr_check=lr_check,
                                           return_status=status)
            for a, b in zip(*((want, got) if status else ((want,), (got,)))):
                np.testing.assert_array_equal(a, b)
            assert np.isnan(got[0] if status else got).any() == lr_check  # the check rejects some pixels
    finally:
        numba.set_num_threads(before)


# (12, 5, 500): narrow tubes, few ties. (40, 30, 6): tubes of up to 30 disparities (two vector chunks of the votes)
# and costs of 6 values, ties everywhere (the right image's lowest disparity wins them); d_min 2 and -5 (right pixels
# on both sides of the image)
@pytest.mark.parametrize("D, most, levels", [(12, 5, 500), (40, 30, 6)])
@pytest.mark.parametrize("d_min", [2, -5])
def test_tube_selection_equals_the_brute_force_reference(D, most, levels, d_min):
    rng = np.random.default_rng(3)
    H, W = 6, 45
    agg = rng.integers(0, levels, (H, W, D)).astype(np.uint16)
    lo, hi = random_tubes(rng, H, W, D, most=most)
    layout = TubeLayout.from_bounds(lo + d_min, hi + d_min, d_min)
    d = disparity.select_disparity(gather(agg, layout), d_min, False, True, 1, gather(np.zeros_like(agg), layout),
                                   tubes=layout)
    d2, status = disparity.select_disparity(gather(agg, layout), d_min, False, False, 1,
                                            gather(np.zeros_like(agg), layout), tubes=layout, return_status=True)
    for y in range(H):
        best = {x: lo[y, x] + int(np.argmin(agg[y, x, lo[y, x]:hi[y, x] + 1])) for x in range(W)}
        right = {}
        for x in range(W):  # the right image's winner over the left pixels whose tube holds the disparity
            for k in range(lo[y, x], hi[y, x] + 1):
                xr = x - (d_min + k)
                if 0 <= xr < W and (xr not in right or agg[y, x, k] < right[xr][0]):
                    right[xr] = (agg[y, x, k], k)
        for x in range(W):
            xr = x - (d_min + best[x])
            ok = 0 <= xr < W and xr in right and abs(best[x] - right[xr][1]) <= 1
            assert (d[y, x] == d_min + best[x]) if ok else np.isnan(d[y, x])
            assert d2[y, x] == d_min + best[x] and status[y, x] == (0 if ok else 1)


def test_full_width_tubes_equal_the_dense_stages_bit_for_bit():
    """Every stage on tubes as wide as the range gives exactly the dense volume's numbers."""
    rng = np.random.default_rng(5)
    H, W, D, d_min = 20, 40, 16, 3
    left = rng.integers(0, 255, (H, W)).astype(np.float32)
    right = np.roll(left, -5, axis=1)
    cl, cr = census.census_transform(left, (5, 5)), census.census_transform(right, (5, 5))
    lo, hi = random_tubes(rng, H, W, D, narrow=False)
    layout = TubeLayout.from_bounds(lo + d_min, hi + d_min, d_min)
    dense = census.census_cost(cl, cr, d_min, d_min + D - 1, 6, 4)
    tube = census.census_cost(cl, cr, d_min, None, 6, 4, tubes=layout)
    np.testing.assert_array_equal(tube, dense.reshape(-1))
    sparse = np.full((H, W), np.nan, np.float32)
    sparse[::4, ::5] = rng.uniform(d_min, d_min + D - 1, sparse[::4, ::5].shape)
    guide_img = np.repeat(left[:, :, None], 3, axis=2)
    a = guidance.riverbed_modulate(dense.copy(), sparse, guide_img, d_min, 9, wall_scale=12.0, max_cost=4000,
                                   inplace=True)
    b = guidance.riverbed_modulate(tube.copy(), sparse, guide_img, d_min, 9, wall_scale=12.0, max_cost=4000,
                                   inplace=True, tubes=layout)
    np.testing.assert_array_equal(b, a.reshape(-1))
    f, bw = sgm.sgm_aggregate_passes(a, 40, 480, 8)
    tf, tb = sgm.sgm_aggregate_passes(b, 40, 480, 8, tubes=layout)
    np.testing.assert_array_equal(tf, f.reshape(-1))
    np.testing.assert_array_equal(tb, bw.reshape(-1))
    np.testing.assert_array_equal(disparity.select_disparity(tf, d_min, True, True, 1, tb, tubes=layout),
                                  disparity.select_disparity(f, d_min, True, True, 1, bw))


def test_tube_guidance_equals_dense_guidance_inside_the_tubes():
    rng = np.random.default_rng(7)
    H, W, D = 24, 30, 20
    cost = rng.integers(0, 200, (H, W, D)).astype(np.uint16)
    lo, hi = random_tubes(rng, H, W, D)
    layout = TubeLayout.from_bounds(lo, hi, 0)
    sparse = np.full((H, W), np.nan, np.float32)
    sparse[::3, ::4] = rng.uniform(0, D - 1, sparse[::3, ::4].shape)
    img = rng.uniform(0, 255, (H, W, 3)).astype(np.float32)
    cases = [
        lambda v, t: guidance.gauss_modulate(v, sparse, 0, max_cost=3000, inplace=True, wall_scale=10.0, tubes=t),
        lambda v, t: guidance.riverbed_modulate(v, sparse, img, 0, 7, max_cost=3000, inplace=True, wall_scale=10.0,
                                                tubes=t),
        lambda v, t: diffusion.diffusion_modulate(v, sparse, img, 0, inplace=True, tubes=t),
        lambda v, t: riverbed_plus.band_modulate(v, np.full((H, W), 5.0, np.float32), np.full((H, W), 8.0,
                                                 np.float32), np.ones((H, W), bool), 0, inplace=True, tubes=t),
    ]
    for run in cases:
        dense = run(cost.copy(), None)
        tube = run(gather(cost, layout), layout)
        np.testing.assert_array_equal(tube, gather(dense, layout))


@pytest.mark.parametrize("share,outside,shape", [(0.05, 0.0, (61, 47)), (0.02, 0.3, (40, 93)), (0.0003, 0.0, (64, 64)),
                                                 (0.0, 0.0, (23, 31))])
def test_tube_layout_from_cells_equals_the_layout_of_the_tubes(share, outside, shape):
    # lidar_tube_layout (the pipeline's) builds the layout from the rule's cells; from_bounds from the pixels' tubes
    rng = np.random.default_rng(len(shape) + int(share * 1e4))
    sparse = np.where(rng.random(shape) < share, rng.uniform(0, 40, shape), np.nan).astype(np.float32)
    sparse[(rng.random(shape) < outside) & np.isfinite(sparse)] += 30.0  # some beyond the range's end
    got = lidar_tube_layout(sparse, 0, 39, cell=3)
    want = TubeLayout.from_bounds(*lidar_tubes(sparse, 0, 39, cell=3), 0)
    for name in ("offset", "width", "start"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        assert getattr(got, name).dtype == getattr(want, name).dtype
    assert (got.size, got.max_width) == (want.size, want.max_width)


@pytest.mark.parametrize("seed", range(12))
def test_tube_rule_on_cells_equals_its_statement(seed):
    # cell_tubes against the rule as docs/tubes.md states it, cell by cell: at the first level whose window of
    # (2 r_k + 1)^2 cells holds LiDAR inside the range (else beyond it), [floor(min - m_k), ceil(max + m_k)] in
    # float32 (the extrema are float32, the margin rounded to float32), clipped to the range; else the range
    rng = np.random.default_rng(seed)
    ch, cw = rng.integers(3, 30, 2)
    d_min, d_max = int(rng.integers(-20, 5)), int(rng.integers(30, 60))
    spacing, reach, margin, level_margin, cell, levels = float(rng.uniform(2, 12)), 1.5, 2.0, 3.3, 4, 3

    def extrema(p, lo, hi):
        v = rng.uniform(lo, hi, (ch, cw)).astype(np.float32)
        near = rng.random((ch, cw)) < 0.5  # one float32 step off a whole pixel: where float32 and float64 part
        v[near] = np.nextafter(np.round(v[near]), np.where(rng.random(near.sum()) < 0.5, -np.inf, np.inf),
                               dtype=np.float32)
        hit = rng.random((ch, cw)) < p
        top = v + np.where(rng.random((ch, cw)) < 0.5, np.float32(0), np.float32(1.5))
        return np.where(hit, v, np.inf).astype(np.float32), np.where(hit, top, -np.inf).astype(np.float32)

    inside, beyond = extrema(0.05, d_min, d_max - 2), extrema(0.05, d_max + 1, d_max + 30)
    lo, hi = cell_tubes(*inside, d_min, d_max, spacing, reach=reach, margin=margin, levels=levels,
                        level_margin=level_margin, cell=cell, outside=beyond)
    for i in range(ch):
        for j in range(cw):
            want = (d_min, d_max)
            for k in range(levels):
                r = max(1, int(np.ceil(reach * spacing * 2 ** k / cell)))
                m = np.float32(margin + k * level_margin)
                win = np.s_[max(0, i - r):i + r + 1, max(0, j - r):j + r + 1]
                src = next((s for s in (inside, beyond) if np.isfinite(s[0][win]).any()), None)
                if src is not None:
                    want = (int(np.floor(src[0][win].min() - m)), int(np.ceil(src[1][win].max() + m)))
                    want = tuple(min(max(v, d_min), d_max) for v in want)
                    break
            assert (lo[i, j], hi[i, j]) == want, (i, j)


def test_tube_rule_hand_made_cases():
    H, W = 120, 160
    sparse = np.full((H, W), np.nan, np.float32)
    sparse[20:60:3, 20:60:3] = 30.0  # a surface at 30 px...
    sparse[20:60:3, 62:100:3] = 50.0  # ...meeting one at 50 px along a depth edge at x = 61
    lo, hi = lidar_tubes(sparse, 0, 127, reach=2.0, margin=2.0, levels=2)
    assert lo[40, 40] == 28 and hi[40, 40] == 32  # a pixel on the 30 px surface: a narrow tube around it
    assert lo[40, 61] <= 28 and hi[40, 61] >= 52  # on the edge: the tube spans both surfaces
    assert lo[110, 150] == 0 and hi[110, 150] == 127  # no LiDAR within reach: the full range
    lo1, hi1 = lidar_tubes(sparse, 0, 40)
    assert hi1.max() <= 40 and lo1.min() >= 0  # clipped to the nominal range


def test_lidar_beyond_the_range_bounds_only_the_pixels_it_alone_reaches():
    H, W = 120, 160
    sparse = np.full((H, W), np.nan, np.float32)
    sparse[20:60:3, 20:60:3] = 30.0  # a surface inside the range [0, 40]...
    sparse[20:60:3, 62:100:3] = 55.0  # ...beside one beyond it, as a --max-disp 40 that cuts off the near objects
    sparse[90:118:3, 110:150:3] = -6.0  # and one below d_min
    lo, hi = lidar_tubes(sparse, 0, 40, reach=2.0, margin=2.0, levels=2)
    assert (lo[40, 40], hi[40, 40]) == (28, 32)  # a pixel of the surface inside: its points alone
    assert (lo[40, 61], hi[40, 61]) == (28, 32)  # at the edge: the points inside set the tube, not those beyond
    assert (lo[40, 90], hi[40, 90]) == (40, 40)  # amid points beyond d_max only: the range's end, not all of it
    assert (lo[100, 130], hi[100, 130]) == (0, 0)  # amid points below d_min only: its other end
    assert (lo[5, 155], hi[5, 155]) == (0, 40)  # no LiDAR within reach: the whole range
    # the points inside set the same tubes as without those outside, wherever they are the nearest
    clo, chi = lidar_tubes(np.where(sparse >= 0, sparse, np.float32(np.nan)), 0, 40, reach=2.0, margin=2.0,
                           levels=2, share=float(lidar_share(sparse)))
    assert np.array_equal(lo[:, :61], clo[:, :61]) and np.array_equal(hi[:, :61], chi[:, :61])


def test_lidar_beyond_the_range_narrows_a_real_match_and_tiles_agree(cones):
    # Cones with --max-disp 39 cuts off its nearest parts (up to 55 px); the LiDAR there bounds their tubes at 39
    # instead of leaving them on the whole range. The pixels whose truth lies in the range are as accurate as with
    # that LiDAR removed, one tile on the global range searches the same tubes, and the planner counts them.
    from riverbed_cli.products.evaluate import evaluate_disparity
    from riverbed_cli.products.simulate import simulate_lidar
    from riverbed_cli.scale.tiles import match_tiled

    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    cut = np.where(sparse <= 39, sparse, np.float32(np.nan))
    assert np.isfinite(sparse).sum() > 1.2 * np.isfinite(cut).sum()  # a sixth of the points lie beyond
    with_beyond = match_pair(left, right, sparse, 0, 39, fusion="none")
    without = match_pair(left, right, cut, 0, 39, fusion="none")
    a, b = with_beyond.info["tubes"], without.info["tubes"]
    assert a["full_share"] < 0.2 * b["full_share"] and a["mean_width"] < 0.8 * b["mean_width"]
    truth = np.where(gt <= 39, gt, np.float32(np.nan))
    ea = evaluate_disparity(with_beyond.disparity, truth, exclude=sparse)
    eb = evaluate_disparity(without.disparity, truth, exclude=sparse)
    assert ea["bad3"] <= eb["bad3"] * 1.02 and ea["avg"] <= eb["avg"] * 1.02
    one = match_tiled(left, right, sparse, 0, 39, fusion="none", tile=0, lidar_range=False)
    assert one.info["tubes"] == a
    assert np.array_equal(one.disparity, with_beyond.disparity, equal_nan=True)


def test_lidar_sparser_than_max_spacing_bounds_no_pixel():
    # 9 points 180 px apart: share 9 / 361^2 (their hull), mean spacing 120 px > 40
    sparse = np.full((400, 400), np.nan, np.float32)
    sparse[20:400:180, 20:400:180] = 30.0
    lo, hi = lidar_tubes(sparse, 0, 63)
    assert (lo == 0).all() and (hi == 63).all()
    lo, hi = lidar_tubes(sparse, 0, 63, max_spacing=200.0)  # allowed: a narrow tube on the points
    assert lo[20, 20] == 28 and hi[20, 20] == 32


def test_range_tube_on_a_real_pair_is_as_accurate_and_searches_less(cones):
    from riverbed_cli.products.evaluate import evaluate_disparity
    from riverbed_cli.products.simulate import simulate_lidar

    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    full = match_pair(left, right, sparse, 0, 59, range="full")
    tube = match_pair(left, right, sparse, 0, 59, range="tube")
    assert full.info["range"] == "full" and tube.info["range"] == "tube"
    t = tube.info["tubes"]
    assert t["nominal"] == 60 and t["mean_width"] < 25 and 0 <= t["full_share"] < 0.2
    a = evaluate_disparity(full.disparity, gt, exclude=sparse)
    b = evaluate_disparity(tube.disparity, gt, exclude=sparse)
    assert b["bad3"] <= a["bad3"] * 1.02 and b["avg"] <= a["avg"] * 1.02
    assert match_pair(left, right, sparse, 0, 59).info["range"] == "tube"  # auto with LiDAR guidance
    assert match_pair(left, right, sparse, 0, 59, guide="none").info["range"] == "full"


def _write_range_map(path, bands):
    import rasterio

    bands = np.asarray(bands, np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=bands.shape[2], height=bands.shape[1], count=bands.shape[0],
                       dtype="float32") as ds:
        ds.write(bands)


def test_range_map_from_the_command_line_and_its_bad_inputs(cones, tmp_path):
    import warnings

    import rasterio
    from click.testing import CliRunner

    from riverbed_cli.cli.main import cli
    from riverbed_cli.io.disparity import read_disparity
    from riverbed_cli.products.evaluate import evaluate_disparity

    left, right, gt = cones
    H, W = gt.shape
    data = "tests/data/cones"
    good = tmp_path / "range.tif"
    lo = np.where(np.isfinite(gt), gt - 3, np.nan)
    warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
    _write_range_map(good, [lo, lo + 6])
    out = tmp_path / "d.tif"
    args = ["match", f"{data}/im2.png", f"{data}/im6.png", "--min-disp", "0", "--max-disp", "63"]
    r = CliRunner().invoke(cli, [*args, "--range-map", str(good), "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    import json

    s = json.loads(r.output)
    assert s["range"] == "tube" and s["tubes"]["mean_width"] < 20
    # unguided, but searched near the truth only: measured bad3 2.32 % inside the overlap, 9.32 % over every GT pixel
    # (7.2 % of them have their match outside the right image: invalid)
    assert evaluate_disparity(read_disparity(out), inside_overlap(gt))["bad3"] < 2.6
    assert 8.4 < evaluate_disparity(read_disparity(out), gt)["bad3"] < 10.3
    cases = {
        "size": ([lo[:-1], lo[:-1] + 6], f"range map is {W}x{H - 1} but the images are {W}x{H} (WxH)"),
        "bands": ([lo], "range map needs 2 bands (min and max disparity), has 1"),
        "order": ([lo + 6, lo], "range map has min > max at"),
        "nan": ([np.full_like(lo, np.nan), np.full_like(lo, np.nan)], "range map has no valid pixel (all NaN)"),
        "outside": ([lo + 30, lo + 36], "range map spans ["),
    }
    for name, (bands, message) in cases.items():
        path = tmp_path / f"{name}.tif"
        _write_range_map(path, bands)
        bad_out = tmp_path / f"{name}_d.tif"
        r = CliRunner().invoke(cli, [*args, "--range-map", str(path), "-o", str(bad_out)])
        assert r.exit_code == 1, (name, r.output)
        assert r.stderr.startswith(f"riverbed: error: {path}: {message}"), (name, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and not bad_out.exists()


def test_range_map_on_tiles(cones, tmp_path):
    """A tiled match searches the range map's intervals as the untiled one does: each tile the range the map spans
    there. Bad maps stop a tiled run before any work, as they stop an untiled one."""
    import json
    import warnings

    import rasterio
    from click.testing import CliRunner

    from riverbed_cli.cli.main import cli
    from riverbed_cli.io.disparity import read_disparity
    from riverbed_cli.products.evaluate import evaluate_disparity

    left, right, gt = cones
    lo = np.where(np.isfinite(gt), gt - 3, np.nan)
    lo[:, :40] = np.nan  # no interval here: the nominal range
    warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
    _write_range_map(tmp_path / "range.tif", [lo, lo + 6])
    args = ["match", "tests/data/cones/im2.png", "tests/data/cones/im6.png", "--min-disp", "0", "--max-disp", "63",
            "--range-map", str(tmp_path / "range.tif"), "--json"]
    runs = {}
    for name, extra in (("untiled", ["--tile", "0"]), ("tiled", ["--tile", "128", "--overlap", "64"])):
        r = CliRunner().invoke(cli, [*args, *extra, "-o", str(tmp_path / f"{name}.tif")])
        assert r.exit_code == 0, r.output
        runs[name] = json.loads(r.output), evaluate_disparity(read_disparity(tmp_path / f"{name}.tif"), gt)
    (untiled, e_untiled), (tiled, e_tiled) = runs["untiled"], runs["tiled"]
    assert tiled["tiles"] == 12 and tiled["range"] == "tube" and tiled["tile_ranges"]["range_map"] == 12
    # the map's intervals, 7 px wide, and the nominal range's 64 where it has none: the same tubes tiled or not
    assert tiled["tubes"] == untiled["tubes"] and 10 < tiled["tubes"]["mean_width"] < 20
    assert tiled["tubes"]["full_share"] > 0.1
    # unguided matching searched near the truth only: 9.32 % bad3, 7.2 points of it the GT pixels whose match lies
    # outside the right image (12.5 % on the full range)
    assert 8.4 < e_tiled["bad3"] < 10.3 and abs(e_tiled["bad3"] - e_untiled["bad3"]) < 0.1
    # the library on the map read by windows, the range taken from the map (as the command does without
    # --min-disp/--max-disp)
    from riverbed_cli.io.windowed import open_range_map
    from riverbed_cli.scale.tiles import match_tiled

    res = match_tiled(left, right, None, tile=128, overlap=64, guide="none",
                      range_map=open_range_map(tmp_path / "range.tif"))
    known = np.isfinite(lo)
    assert (res.info["d_min"], res.info["d_max"]) == (int(np.floor(np.nanmin(lo))), int(np.ceil(np.nanmax(lo + 6))))
    assert res.info["tiles"] == 12 and res.info["tubes"]["full_share"] == pytest.approx(1 - known.mean(), abs=1e-4)
    _write_range_map(tmp_path / "order.tif", [lo + 6, lo])
    r = CliRunner().invoke(cli, [*args[:-3], "--range-map", str(tmp_path / "order.tif"), "--tile", "128", "-o",
                                 str(tmp_path / "bad.tif")])
    assert r.exit_code == 1
    assert r.stderr.startswith(f"riverbed: error: {tmp_path / 'order.tif'}: range map has min > max")
    assert not (tmp_path / "bad.tif").exists()


def test_hole_bounds_hand_made_cases():
    from riverbed_cli.matching.tubes import hole_bounds

    coarse = np.full((10, 20), np.nan, np.float32)
    coarse[:, :5] = 10.0  # consistent coarse disparities on the left, none on the right
    coarse[0, 0] = 12.0
    lo, hi = hole_bounds(coarse, (21, 41), 0, 63, factor=2, window=1, margin=3.0)
    assert lo.shape == (21, 41)
    assert (lo[10, 2], hi[10, 2]) == (17, 23)  # 2 x 10 -+ 3
    assert (lo[0, 0], hi[0, 0]) == (17, 27)  # the window holds 10 and 12: 2 x 12 + 3
    assert (lo[10, 40], hi[10, 40]) == (0, 63)  # no coarse disparity in the window: the nominal range
    assert (lo[20, 9], hi[20, 9]) == (17, 23)  # the last full-resolution row takes the last coarse row
    # a pixel whose own coarse pixel has no disparity (its match outside the right image) keeps the nominal range,
    # even with disparities in its window
    assert (lo[10, 11], hi[10, 11]) == (0, 63)
    lo, hi = hole_bounds(coarse, (20, 40), 0, 20, factor=2, window=1, margin=3.0)
    assert hi[10, 2] == 20 and lo[10, 2] == 17  # clipped to the nominal range


def test_lidar_tubes_report_the_pixels_no_lidar_reaches():
    H, W = 120, 160
    sparse = np.full((H, W), np.nan, np.float32)
    sparse[20:60:3, 20:60:3] = 30.0
    lo, hi, hole = lidar_tubes(sparse, 0, 127, levels=2, return_holes=True)
    assert hole[110, 150] and (lo[110, 150], hi[110, 150]) == (0, 127)
    assert not hole[40, 40] and (lo[40, 40], hi[40, 40]) == (28, 32)
    assert ((hi - lo + 1)[hole] == 128).all()
    sparse = np.full((400, 400), np.nan, np.float32)
    sparse[20:400:180, 20:400:180] = 30.0  # sparser than max_spacing: no pixel is bounded, none is a hole
    assert not lidar_tubes(sparse, 0, 63, return_holes=True)[2].any()


def test_coarse_holes_bound_the_pixels_without_lidar_on_a_real_pair(cones):
    from riverbed_cli.matching.config import MatchConfig
    from riverbed_cli.matching.range_maps import fill_tube_holes
    from riverbed_cli.products.simulate import simulate_lidar

    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    sparse[100:300, 150:330] = np.nan  # a LiDAR hole (water, a shadow, a sensor gap) over the cones
    lo, hi, hole = lidar_tubes(sparse, 0, 59, return_holes=True)
    assert 0.05 < hole.mean() < 0.07
    config = MatchConfig().replace(tube={"holes": "coarse"})
    clo, chi = fill_tube_holes(left, right, lo, hi, hole, 0, 59, config, match_pair)
    assert (clo[~hole] == lo[~hole]).all() and (chi[~hole] == hi[~hole]).all()  # the LiDAR's tubes are kept
    ev = hole & np.isfinite(gt)
    inside = (gt[ev] >= clo[ev]) & (gt[ev] <= chi[ev])
    assert inside.mean() > 0.995  # the coarse ranges hold the truth
    assert (chi - clo + 1)[hole].mean() < 30  # against 60 on the nominal range
    full = match_pair(left, right, sparse, 0, 59, fusion="none")
    coarse = match_pair(left, right, sparse, 0, 59, params=config, fusion="none")
    assert full.info["tubes"]["full_share"] > 0.05 and coarse.info["tubes"]["full_share"] == 0.0
    e_full, e_coarse = (np.abs(r.disparity - gt)[ev] for r in (full, coarse))
    assert (e_coarse > 3).mean() <= (e_full > 3).mean() + 0.005
    assert np.nanmean(e_coarse) <= np.nanmean(e_full) * 1.02
    # the default is the nominal range in holes, as before
    assert np.array_equal(full.disparity, match_pair(left, right, sparse, 0, 59, fusion="none",
                                                     tube={"holes": "full"}).disparity, equal_nan=True)


def test_coarse_holes_from_the_command_line_untiled_and_tiled(cones, tmp_path):
    import json

    from click.testing import CliRunner

    from riverbed_cli.cli.main import cli
    from riverbed_cli.io.disparity import read_disparity, write_disparity
    from riverbed_cli.products.simulate import simulate_lidar
    from riverbed_cli.scale.tiles import match_tiled

    left, right, gt = cones
    sparse = simulate_lidar(gt, 0.05, seed=0)
    sparse[100:300, 150:330] = np.nan
    write_disparity(tmp_path / "s.tif", sparse)
    base = ["match", "tests/data/cones/im2.png", "tests/data/cones/im6.png", "--sparse", str(tmp_path / "s.tif"),
            "--min-disp", "0", "--max-disp", "59", "--tube-holes", "coarse"]
    ok = CliRunner().invoke(cli, base + ["--tile", "0", "-o", str(tmp_path / "d.tif"), "--json"])
    assert ok.exit_code == 0, ok.output
    assert '"full_share": 0.0' in ok.output and np.isfinite(read_disparity(tmp_path / "d.tif")).all()
    # tiled: each tile's holes take the coarse match of its own crop over its range
    tiled = CliRunner().invoke(cli, base + ["--tile", "128", "--overlap", "64", "-o", str(tmp_path / "t.tif"),
                                            "--json"])
    assert tiled.exit_code == 0, tiled.output
    info = json.loads(tiled.output[tiled.output.index("{"):])
    assert info["tiles"] > 4 and info["tubes"]["full_share"] == 0.0
    # the tiles' own LiDAR ranges already bound their holes; the coarse ranges narrow them further
    nominal = match_tiled(left, right, sparse, 0, 59, tile=128, overlap=64, tube={"holes": "full"}).info["tubes"]
    assert info["tubes"]["mean_width"] < nominal["mean_width"] - 1.0
    lo, hi, hole = lidar_tubes(sparse, 0, 59, return_holes=True)
    ev = hole & np.isfinite(gt)
    e_untiled, e_tiled = (np.abs(read_disparity(tmp_path / f) - gt)[ev] for f in ("d.tif", "t.tif"))
    assert (e_tiled > 3).mean() <= (e_untiled > 3).mean() + 0.005
    assert np.nanmean(e_tiled) <= np.nanmean(e_untiled) * 1.05
    # one tile over the whole image is the untiled match, bit for bit
    one = match_tiled(left, right, sparse, 0, 59, tile=512, tube={"holes": "coarse"})
    assert one.info["tiles"] == 1
    assert np.array_equal(one.disparity, read_disparity(tmp_path / "d.tif"), equal_nan=True)
    bad = CliRunner().invoke(cli, base[:-1] + ["nearest", "--tile", "0", "-o", str(tmp_path / "b.tif")])
    assert bad.exit_code != 0 and "expected one of full, coarse, got 'nearest'" in bad.output


@pytest.mark.parametrize("H", [1, 7, 15, 16, 17, 31, 32, 33, 500])
def test_band_pairs_share_every_row_once_and_alternate(H):
    """The row-parallel kernels' shares (volume.band_pair_rows): every row once; with two threads (the loop's two
    contiguous halves) the first takes the even pairs of bands, the second the odd ones, in every kernel alike."""
    m = band_pairs(H)
    shares = [[], []]
    for i in range(m):
        r0, r1 = band_pair_rows(i, m, H)
        shares[0 if i < (m + 1) // 2 else 1] += range(r0, r1)
    assert sorted(shares[0] + shares[1]) == list(range(H))
    for t in (0, 1):
        assert {y // (2 * BAND_ROWS) % 2 for y in shares[t]} <= {t}
    assert len(shares[1]) == 0 if H <= 2 * BAND_ROWS else len(shares[1]) > 0
