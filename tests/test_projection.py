"""Projection geometry, the streaming two-layer z-buffer against a pure-numpy reference, visibility, SOR."""

import laspy
import numpy as np
import pytest

from riverbed_cli.geometry import projection as pj
from riverbed_cli.geometry.cameras import PairGeometry
from riverbed_cli.geometry.outliers import sor_inliers
from riverbed_cli.geometry.visibility import footprint_radii, hpr_visible, zbuffer_visible

K = np.array([[935.0, 0, 224.5], [0, 935.0, 187.0], [0, 0, 1]])


def rigid(rng, scale=1.0):
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = rng.normal(size=3) * scale
    return T


def pair_in_world(rng, doffs=25.0, b=0.16, off_baseline=(0.0, 0.0)):
    """A rectified pair (optionally off the baseline as KITTI's) seen from a random rigid world frame."""
    K1 = K.copy()
    K1[0, 2] += doffs
    PL = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    PR = K1 @ np.hstack([np.eye(3), np.array([[-b], [off_baseline[0]], [off_baseline[1]]])])
    T = rigid(rng, 5.0)  # world -> camera
    return PairGeometry(PL @ T, PR @ T), T


def test_project_triangulate_round_trip_and_disparity_formula():
    rng = np.random.default_rng(0)
    pair, T = pair_in_world(rng)
    cam = np.column_stack([rng.uniform(-1, 1, 1000), rng.uniform(-1, 1, 1000), rng.uniform(1.5, 20, 1000)])
    world = (cam - T[:3, 3]) @ T[:3, :3]  # camera -> world
    xl, yl, xr, z = pair.project(world)
    assert np.allclose(z, cam[:, 2], rtol=1e-12)
    assert np.allclose(xl - xr, 935 * 0.16 / cam[:, 2] - 25.0, rtol=1e-12)  # d = f B / Z - doffs
    back = pair.triangulate(xl, yl, xl - xr)
    assert np.abs(back - world).max() < 1e-9
    assert pair.baseline == pytest.approx(0.16, rel=1e-12) and pair.focal == pytest.approx(935, rel=1e-12)
    cl, cr = pair.centres
    assert np.allclose(cr - cl, T[:3, :3].T @ np.array([0.16, 0, 0]))
    # Off the baseline (KITTI-like): triangulate uses the left row only and stays exact.
    kitti, _ = pair_in_world(rng, off_baseline=(-0.0027, 2e-5))
    assert not kitti.exactly_rectified
    xl, yl, xr, _, yr, _ = kitti.project(world, full=True)
    assert np.abs(yr - yl).max() > 0.1
    assert np.abs(kitti.triangulate(xl, yl, xl - xr) - world).max() < 1e-9


def test_lidar_to_local_keeps_utm_precision():
    rng = np.random.default_rng(1)
    pair, _ = pair_in_world(rng)
    reg = rigid(rng, 1.0)
    reg[:3, 3] += [500000.0, 5000000.0, 300.0]
    pair = pair.replace(origin=[500000.0, 5000000.0, 300.0], registration=reg)
    lidar = rng.normal(size=(100, 3))
    local = pair.lidar_to_local(lidar)
    expect = lidar @ reg[:3, :3].T + (reg[:3, 3] - pair.origin)
    assert np.abs(local - expect).max() < 1e-9


def write_cloud(path, xyz, cls=None):
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([1e-4] * 3)
    header.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = np.ones(len(xyz), np.uint8) if cls is None else cls
    las.write(str(path))
    return laspy.read(str(path)).xyz  # the quantised coordinates


def reference_nearest(pair, xyz, shape):
    """Pure numpy: per left pixel the nearest point in front of both cameras and inside both images."""
    H, W = shape
    xl, yl, xr, z, yr, zr = pair.project(xyz, full=True)
    ok = (z > 0) & (zr > 0)
    for x, lim in ((xl, W), (yl, H), (xr, W), (yr, H)):
        ok &= (x >= -0.5) & (x < lim - 0.5)
    rows, cols = np.floor(yl[ok] + 0.5).astype(int), np.floor(xl[ok] + 0.5).astype(int)
    d, zz = (xl - xr)[ok], z[ok]
    out = np.full(shape, np.nan)
    best = np.full(shape, np.inf)
    for r, c, dd, z1 in zip(rows, cols, d, zz):
        if z1 < best[r, c]:
            best[r, c], out[r, c] = z1, dd
    return out


@pytest.mark.parametrize("chunk,slots", [(1_000_000, 1 << 20), (1000, 16)])
def test_streaming_zbuffer_matches_numpy_reference(tmp_path, monkeypatch, chunk, slots):
    monkeypatch.setattr(pj, "_INITIAL_SLOTS", slots)  # also exercise the growth of the slot store
    rng = np.random.default_rng(2)
    pair, T = pair_in_world(rng, doffs=0.0)
    n = 20000
    cam = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-2.5, 2.5, n), rng.uniform(-1, 12, n)])
    xyz = write_cloud(tmp_path / "c.las", (cam - T[:3, 3]) @ T[:3, :3])
    shape = (60, 80)
    sparse, stats = pj.project_cloud(tmp_path / "c.las", pair, outliers="none", visibility="none",
                                     shape=shape, chunk_size=chunk)
    ref = reference_nearest(pair, xyz, shape)
    assert np.array_equal(np.isfinite(sparse), np.isfinite(ref))
    assert np.nanmax(np.abs(sparse - ref)) < 1e-4  # float32 storage
    assert stats["kept"] == np.isfinite(ref).sum()
    total = (stats["filtered"]["class"] + stats["filtered"]["outliers"] + stats["behind_camera"]
             + stats["outside"] + stats["row_offset"] + sum(stats["occluded"].values()) + stats["kept"])
    assert total == stats["points_read"] == n


def test_point_outside_right_image_still_hides_what_is_behind_it(tmp_path):
    pair = PairGeometry([[100, 0, 5, 0], [0, 100, 5, 0], [0, 0, 1, 0]],
                        [[100, 0, 5, -100], [0, 100, 5, 0], [0, 0, 1, 0]], width=10, height=10)
    # Pixel (5, 0): a near point whose right match is off the image (d = 50), and a far one behind it (d = 2).
    pts = np.array([[-0.05 * 2, 0.0, 2.0], [-0.05 * 50, 0.0, 50.0]])
    write_cloud(tmp_path / "c.las", pts)
    with pytest.raises(Exception, match="no point lands in both images"):
        pj.project_cloud(tmp_path / "c.las", pair, outliers="none", visibility="none")


def test_zbuffer_footprint_hides_points_behind_a_sparse_surface():
    rng = np.random.default_rng(3)
    H = W = 100
    front = rng.random((H, W)) < 0.1  # a surface sampled at 10 % of the pixels, disparity 20
    behind = ~front & (rng.random((H, W)) < 0.3)  # points behind it, disparity 12
    rows = np.concatenate([np.nonzero(front)[0], np.nonzero(behind)[0]])
    cols = np.concatenate([np.nonzero(front)[1], np.nonzero(behind)[1]])
    disp = np.concatenate([np.full(front.sum(), 20.0), np.full(behind.sum(), 12.0)])
    nf = front.sum()
    for radius in (0, 1, "auto"):
        vis = zbuffer_visible(rows, cols, disp, (H, W), radius)
        assert vis[:nf].all()  # the surface itself is never hidden
        removed = 1 - vis[nf:].mean()
        if radius == 0:
            assert removed == 0
        if radius == "auto":
            assert removed > 0.93  # 0.95 (misses are near the image border, where fewer splats reach)
    r = footprint_radii(rows, cols, disp, (H, W))
    assert 2 <= np.median(r[:nf]) <= 5  # k = 4 neighbours at 10 %: sqrt(4 / (pi 0.1)) = 3.6 px
    # A slanted surface (disparity falling 0.4 px per px, less than the 0.5 px/px slope) is not hidden by
    # itself; one falling 2 px per px is (its nearer samples cover the farther ones).
    rr, cc = np.nonzero(front)
    assert zbuffer_visible(rr, cc, 60 - 0.4 * cc, (H, W), 3).all()
    assert not zbuffer_visible(rr, cc, 250 - 2.0 * cc, (H, W), 3).all()


def test_hpr_sphere_front_half():
    rng = np.random.default_rng(4)
    p = rng.normal(size=(4000, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    vis = hpr_visible(p, np.array([0, 0, -10.0]), gamma=3.5)
    front = p[:, 2] < -0.2
    back = p[:, 2] > 0.2
    assert vis[front].mean() > 0.95 and vis[back].mean() < 0.05


def test_sor_removes_isolated_points_only():
    rng = np.random.default_rng(5)
    g = np.stack(np.meshgrid(np.arange(100.0), np.arange(100.0)), -1).reshape(-1, 2) * 0.01
    surface = np.column_stack([g, 5 + 0.001 * rng.normal(size=len(g))])
    noise = np.column_stack([rng.uniform(0, 1, (20, 2)), rng.uniform(2, 4, 20)])
    xyz = np.vstack([surface, noise])
    keep = sor_inliers(xyz, xyz[:, 2])
    assert keep[: len(surface)].mean() > 0.999 and not keep[len(surface):].any()


def reference_radii(rows, cols, disp, k=4, tolerance=1.0, largest=8):
    """k-d tree reference of footprint_radii (one point per pixel)."""
    from scipy.spatial import cKDTree

    pts = np.column_stack([rows, cols]).astype(float)
    n = len(pts)
    m = min(n - 1, 200)
    dist, idx = cKDTree(pts).query(pts, k=m + 1)
    out = np.empty(n, int)
    for i in range(n):
        d, j = dist[i, 1:], idx[i, 1:]
        inside = d <= largest
        d, j = d[inside], j[inside]
        same = disp[j] >= disp[i] - tolerance
        r = None
        for t in range(len(d)):
            if same[: t + 1].sum() == k:
                r = d[t]
                break
            if t + 1 >= 4 * k and t + 1 >= k:
                r = d[k - 1]
                break
        if r is None:
            r = d[k - 1] if len(d) >= k else largest
        out[i] = min(max(int(np.ceil(r)), 1), largest)
    return out


def test_radii_and_splat_kernels_match_references():
    rng = np.random.default_rng(6)
    H, W = 60, 70
    lin = rng.choice(H * W, 600, replace=False)
    rows, cols = lin // W, lin % W
    disp = rng.uniform(20, 22, lin.size) - np.where(rng.random(lin.size) < 0.3, 8.0, 0.0)
    r = footprint_radii(rows, cols, disp, (H, W))
    ref = reference_radii(rows, cols, disp)
    # Equal up to ties in distance (the scan order among equidistant pixels differs from the tree's).
    assert (r == ref).mean() > 0.97
    radius = rng.integers(0, 5, lin.size)
    vis = zbuffer_visible(rows, cols, disp, (H, W), radius, 1.0, 0.5)
    yy, xx = np.mgrid[:H, :W]
    cover = np.full((H, W), -np.inf)
    for y, x, d, rr in zip(rows, cols, disp, radius, strict=True):
        e = np.sqrt((yy - y) ** 2 + (xx - x) ** 2)
        disc = e <= rr
        cover[disc] = np.maximum(cover[disc], (d - 0.5 * e[disc]).astype(np.float32))
    assert np.array_equal(vis, cover[rows, cols] - disp <= 1.0)


def test_image_space_sor_matches_kd_tree_sor():
    from riverbed_cli.geometry.outliers import sor_inliers_image

    rng = np.random.default_rng(7)
    H = W = 80
    f = 100.0
    lin = np.flatnonzero(rng.random(H * W) < 0.3)
    z = 10 + 0.02 * (lin % W) + 0.001 * rng.normal(size=lin.size)  # a slanted surface
    n_out = 20
    out_lin = rng.choice(lin, n_out, replace=False)  # floating points in front of some surface points
    zo = rng.uniform(3, 7, n_out)
    idx0 = np.full(H * W, -1, np.int32)
    idx1 = np.full(H * W, -1, np.int32)
    idx0[lin] = np.arange(lin.size)
    pos = {p: i for i, p in enumerate(lin)}
    for j, p in enumerate(out_lin):  # the outlier is nearer: layer 0, the surface point goes to layer 1
        idx1[p] = pos[p]
        idx0[p] = lin.size + j
    pix = np.concatenate([lin, out_lin])
    depth = np.concatenate([z, zo])
    r, c = pix // W, pix % W
    xyz = np.column_stack([(c - W / 2) / f * depth, (r - H / 2) / f * depth, depth])
    slots = np.arange(pix.size)
    fast = sor_inliers_image(slots, pix, idx0, idx1, (H, W), xyz, depth, f)
    ref = sor_inliers(xyz, depth)
    assert not fast[lin.size:].any() and not ref[lin.size:].any()  # every outlier, by both
    assert (fast == ref).mean() > 0.995 and fast[: lin.size].mean() > 0.99
