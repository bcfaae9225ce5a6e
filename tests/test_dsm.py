import json

import math
import laspy
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from plyfile import PlyData

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.cameras import PairGeometry
from riverbed_cli.io.pointcloud import write_points
from riverbed_cli.io.raster import write_geotiff
from riverbed_cli.products.dsm import Grid, build_dsm, disparity_points, fill_holes, rasterize
from riverbed_cli.products.dsm_compare import compare_dsm


def numpy_reference(x, y, z, grid, agg):
    col = np.floor((x - grid.xmin) / grid.resolution).astype(int)
    row = np.floor((grid.ymax - y) / grid.resolution).astype(int)
    out = np.full((grid.height, grid.width), np.nan)
    cells = {}
    for r, c, h, px, py in zip(row, col, z, x, y):
        if 0 <= r < grid.height and 0 <= c < grid.width:
            cells.setdefault((r, c), []).append((h, px, py))
    for (r, c), v in cells.items():
        h = np.array([t[0] for t in v])
        if agg == "max":
            out[r, c] = h.max()
        elif agg == "mean":
            out[r, c] = h.mean()
        elif agg == "median":
            out[r, c] = np.median(h)
        else:
            cx = grid.xmin + (c + 0.5) * grid.resolution
            cy = grid.ymax - (r + 0.5) * grid.resolution
            w = 1 / ((np.array([t[1] for t in v]) - cx) ** 2 + (np.array([t[2] for t in v]) - cy) ** 2
                     + (grid.resolution / 4) ** 2)
            out[r, c] = (w * h).sum() / w.sum()
    return out


@pytest.mark.parametrize("agg", ["max", "mean", "median", "idw"])
def test_rasterize_matches_reference(agg):
    rng = np.random.default_rng(0)
    x = 500000 + rng.uniform(0, 20, 3000)
    y = 5000000 + rng.uniform(0, 10, 3000)
    z = rng.normal(300, 2, 3000)
    grid = Grid.from_bounds(x.min(), y.min(), x.max(), y.max(), 0.7)
    got = rasterize(x, y, z, grid, agg)
    ref = numpy_reference(x, y, z, grid, agg)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    np.testing.assert_allclose(got[~np.isnan(got)], ref[~np.isnan(ref)], rtol=1e-6)


def test_grid_covers_its_bounds():
    g = Grid.from_bounds(10.2, 20.1, 13.0, 21.9, 0.5)
    xmin, ymin, xmax, ymax = g.bounds
    assert xmin <= 10.2 and ymin <= 20.1 and xmax > 13.0 and ymax >= 21.9
    with pytest.raises(RiverbedError, match="resolution must be a positive number, got -1"):
        Grid.from_bounds(0, 0, 1, 1, -1)


def test_fill_holes_only_small_enclosed_gaps():
    dsm = np.full((30, 30), 5.0, np.float32)
    dsm[5:7, 5:7] = np.nan  # 2x2 enclosed: filled with 3
    dsm[15:25, 15:25] = np.nan  # 10x10 enclosed: too big for 3
    dsm[0:2, 10:12] = np.nan  # touches the border: never filled
    out, mask = fill_holes(dsm, 3)
    assert np.allclose(out[5:7, 5:7], 5.0) and mask[5:7, 5:7].all()
    assert np.isnan(out[15:25, 15:25]).all() and np.isnan(out[0:2, 10:12]).all()
    assert mask.sum() == 4
    out, mask = fill_holes(dsm, 12)
    assert mask.sum() == 104 and np.isnan(out[0:2, 10:12]).all()


def test_geotiff_is_a_cog_with_crs_nodata_and_overviews(tmp_path):
    dsm = np.random.default_rng(1).random((600, 700)).astype(np.float32)
    dsm[:5] = np.nan
    g = Grid(500000.0, 5000300.0, 0.25, 700, 600)
    write_geotiff(tmp_path / "d.tif", dsm, g.transform, "EPSG:32632", float("nan"))
    with rasterio.open(tmp_path / "d.tif") as ds:
        assert ds.crs.to_epsg() == 32632 and ds.transform == g.transform and np.isnan(ds.nodata)
        assert ds.overviews(1) == [2, 4] and ds.block_shapes == [(256, 256)]
        assert ds.profile["compress"] == "deflate"
        np.testing.assert_array_equal(ds.read(1), dsm)


def test_points_round_trip_las_laz_ply(tmp_path):
    rng = np.random.default_rng(2)
    xyz = np.c_[rng.uniform(500000, 500500, 500), rng.uniform(5e6, 5e6 + 500, 500), rng.uniform(200, 260, 500)]
    rgb = rng.integers(0, 256, (500, 3)).astype(np.uint8)
    for ext in ("las", "laz"):
        write_points(tmp_path / f"p.{ext}", xyz, rgb, "EPSG:32632")
        las = laspy.read(tmp_path / f"p.{ext}")
        back = np.c_[las.x, las.y, las.z]
        assert np.abs(back - xyz).max() <= 0.5 * las.header.scales.max() + 1e-9
        assert las.header.parse_crs().to_epsg() == 32632
        np.testing.assert_array_equal(las.red, rgb[:, 0].astype(np.uint16) * 257)
    write_points(tmp_path / "p.ply", xyz, rgb, "EPSG:32632")
    v = PlyData.read(tmp_path / "p.ply")["vertex"]
    np.testing.assert_array_equal(np.c_[v["x"], v["y"], v["z"]], xyz)
    np.testing.assert_array_equal(v["green"], rgb[:, 1])
    with pytest.raises(RiverbedError, match=r"unsupported point cloud format '.xyz' \(use .las, .laz or .ply\)"):
        write_points(tmp_path / "p.xyz", xyz)


@pytest.mark.parametrize("ext", ["las", "laz"])
def test_points_written_in_chunks_equal_one_write(tmp_path, monkeypatch, ext):
    import riverbed_cli.io.pointcloud as pointcloud

    rng = np.random.default_rng(3)
    xyz = np.c_[rng.uniform(500000, 500500, 1003), rng.uniform(5e6, 5e6 + 500, 1003), rng.uniform(200, 260, 1003)]
    rgb = rng.integers(0, 256, (1003, 3)).astype(np.uint8)
    cls = rng.integers(0, 19, 1003).astype(np.uint8)
    write_points(tmp_path / f"one.{ext}", xyz, rgb, "EPSG:32632", cls)
    monkeypatch.setattr(pointcloud, "CHUNK", 100)  # 11 chunks, the last one of 3 points
    write_points(tmp_path / f"chunks.{ext}", xyz, rgb, "EPSG:32632", cls)
    one, chunks = (laspy.read(tmp_path / f"{n}.{ext}") for n in ("one", "chunks"))
    assert chunks.header.point_count == 1003
    np.testing.assert_array_equal(chunks.points.array, one.points.array)
    np.testing.assert_array_equal(chunks.header.mins, one.header.mins)
    np.testing.assert_array_equal(chunks.header.maxs, one.header.maxs)
    np.testing.assert_array_equal(chunks.classification, cls)
    write_points(tmp_path / f"empty.{ext}", np.zeros((0, 3)), crs="EPSG:32632")
    assert laspy.read(tmp_path / f"empty.{ext}").header.point_count == 0


def nadir_pair(f=1000.0, B=50.0, H=400.0, W=120, Hh=100, origin=(500000.0, 5000000.0, 0.0)):
    """A rectified nadir pair 400 m above ground: x right = east, image rows = south; world = UTM minus origin."""
    K = np.array([[f, 0, W / 2], [0, f, Hh / 2], [0, 0, 1.0]])
    R = np.diag([1.0, -1.0, -1.0])  # camera looks down, image y to the south
    C = np.array([0.0, 0.0, H])
    P_left = K @ np.c_[R, -R @ C]
    P_right = K @ np.c_[R, -R @ (C + [B, 0, 0])]
    return PairGeometry(P_left, P_right, origin=np.array(origin), crs="EPSG:32632", width=W, height=Hh)


def test_triangulated_points_and_dsm_are_exact():
    pair = nadir_pair()
    # A flat roof at 30 m and ground at 0: disparity f B / (H - z).
    disp = np.full((100, 120), 1000 * 50 / 400.0, np.float32)
    disp[30:60, 40:80] = 1000 * 50 / 370.0
    xyz, depth, _ = disparity_points(disp, pair)
    roof = np.isclose(xyz[:, 2], 30.0, atol=1e-6)
    assert roof.sum() == 30 * 40 and np.allclose(xyz[~roof, 2], 0.0, atol=1e-6)
    assert np.allclose(depth[roof], 370.0) and xyz[:, 0].min() > 499900
    res = build_dsm([(disp, pair, None)])
    assert res.stats["resolution"] == pytest.approx(0.4, rel=1e-6)  # GSD at the median depth 400 m
    vals = res.dsm[np.isfinite(res.dsm)]
    assert set(np.round(vals, 4)) == {0.0, 30.0}


def test_kept_points_are_the_sinks_and_the_dsm_the_same():
    # keep_points triangulates once: the same DSM as the two passes, and the points (with colours) the sink gets
    pair = nadir_pair()
    rng = np.random.default_rng(5)
    disp = (1000 * 50 / (400.0 - rng.uniform(0, 40, (100, 120)))).astype(np.float32)
    disp[rng.random(disp.shape) < 0.1] = np.nan
    image = rng.integers(0, 255, (100, 120, 3), dtype=np.uint8)
    sunk = []
    two = build_dsm([(disp, pair, image), (disp[::-1], pair, image)], block_rows=32, agg="mean",
                    point_sink=lambda xyz, rgb: sunk.append((xyz, rgb)))
    one = build_dsm([(disp, pair, image), (disp[::-1], pair, image)], block_rows=32, agg="mean", keep_points=True)
    assert two.points is None and np.array_equal(one.dsm, two.dsm, equal_nan=True) and one.stats == two.stats
    xyz, rgb = one.points
    assert np.array_equal(xyz, np.concatenate([b[0] for b in sunk]))
    assert np.array_equal(rgb, np.concatenate([b[1] for b in sunk])) and len(xyz) == 2 * np.isfinite(disp).sum()
    assert build_dsm([(disp, pair, None)], keep_points=True).points[1] is None  # no image, no colours


def test_dsm_cli_with_lidar_merge(tmp_path, monkeypatch):
    pair = nadir_pair()
    from riverbed_cli.io.disparity import write_disparity
    from riverbed_cli.geometry.pairfile import write_pairfile

    write_pairfile(tmp_path / "pair.yaml", pair)
    disp = np.full((100, 120), 125.0, np.float32)
    write_disparity(tmp_path / "d.tif", disp)
    # LiDAR 1 m above the image surface on a small patch: it must win there.
    xyz = np.c_[np.full(50, 500000.0) + np.linspace(-2, 2, 50), np.full(50, 5000000.0), np.full(50, 1.0)]
    write_points(tmp_path / "l.las", xyz, crs="EPSG:32632")
    r = CliRunner().invoke(cli, ["dsm", str(tmp_path / "d.tif"), str(tmp_path / "pair.yaml"), "-o",
                                 str(tmp_path / "dsm.tif"), "--lidar", str(tmp_path / "l.las"), "--json",
                                 "--points", str(tmp_path / "p.laz"), "--hillshade", str(tmp_path / "hs.png")])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["image_points"] == 12000 and s["lidar_points"] == 50 and s["crs"] == "EPSG:32632"
    with rasterio.open(tmp_path / "dsm.tif") as ds:
        z = ds.read(1)
        assert ds.crs.to_epsg() == 32632
        rc = ds.index(500000.0, 5000000.0)
    assert z[rc] == pytest.approx(1.0) and np.nanmin(z) == pytest.approx(0.0, abs=1e-6)
    assert len(laspy.read(tmp_path / "p.laz").points) == 12000
    r = CliRunner().invoke(cli, ["dsm", str(tmp_path / "d.tif"), "-o", str(tmp_path / "x.tif")])
    assert r.exit_code == 1
    assert r.output == "riverbed: error: give DISP PAIR couples: a disparity map and its pair file each\n"


def test_compare_dsm_statistics():
    ref = np.zeros((10, 10))
    dsm = np.full((10, 10), 0.2)
    dsm[0, :5] = 3.0
    dsm[9, :] = np.nan
    m = compare_dsm(dsm, ref, (0.5, 1.0), resolution=0.5)
    assert m["n"] == 90 and m["completeness"] == pytest.approx(90.0)
    assert m["median"] == pytest.approx(0.2) and m["nmad"] == pytest.approx(0.0)
    assert m["over_0.5"] == pytest.approx(100 * 5 / 90) and m["over_3res"] == pytest.approx(100 * 5 / 90)
    assert m["mean"] == pytest.approx((85 * 0.2 + 5 * 3.0) / 90)


def test_hillshade_is_lit_from_the_sun_side():
    # default sun in the north-west (azimuth 315, altitude 45): a slope facing west (rising eastwards) and one facing
    # north (rising southwards, down the rows) are lit, their opposites shaded; a flat cell gives sin(45 deg)
    from riverbed_cli.products.dsm import hillshade

    x = np.tile(np.arange(16, dtype=np.float64), (16, 1))
    facing_west, facing_east = hillshade(x, 1.0)[8, 8], hillshade(-x, 1.0)[8, 8]
    facing_north, facing_south = hillshade(x.T, 1.0)[8, 8], hillshade(-x.T, 1.0)[8, 8]
    # 45 deg slopes: the lit side cos(45) cos(45) + sin(45) sin(45) cos(45), the shaded one the same minus
    lit, shaded = int(255 * (0.5 + 0.5 * math.cos(math.pi / 4))), int(255 * (0.5 - 0.5 * math.cos(math.pi / 4)))
    assert (facing_west, facing_north) == (lit, lit) and (facing_east, facing_south) == (shaded, shaded)
    assert hillshade(np.zeros((4, 4)), 1.0)[1, 1] == int(255 * math.sin(math.pi / 4))


def test_close_lattice_is_the_plain_loop_and_closes_only_sampling_holes():
    from riverbed_cli.products.dsm_holes import close_lattice, close_lattice_reference

    rng = np.random.default_rng(4)
    dsm = rng.normal(100.0, 5.0, (40, 50)).astype(np.float32)
    dsm[rng.random(dsm.shape) < 0.15] = np.nan  # a sampling lattice's empty cells
    dsm[10:16, 10:16] = np.nan  # a real gap: its inner cells have fewer than 6 neighbours with data
    got, n = close_lattice(dsm)
    want, n_ref = close_lattice_reference(dsm)
    np.testing.assert_allclose(got, want, rtol=1e-6, equal_nan=True)
    assert n == n_ref and 0 < n < np.isnan(dsm).sum()
    assert np.isnan(got[11:15, 11:15]).all()
    # a lone empty cell in a plane takes its neighbours' median: the plane's height there
    plane = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    plane[4, 4] = np.nan
    closed, n = close_lattice(plane)
    assert n == 1 and closed[4, 4] == 8.0
    assert close_lattice(plane, min_neighbours=9)[1] == 0
