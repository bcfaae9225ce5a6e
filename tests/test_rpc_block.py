"""Blocks of satellite pairs (issue 14 step 5): ``rpc:`` entries in a block manifest, ``riverbed block split-rpc``,
``riverbed rectify --rpc --lidar``; the real Ventoux crops split into ROIs on dask (data).

The synthetic pair is ``tests/test_rpc_cli.py``'s (two cubic RPCs, a flat textured terrain at 500 m ellipsoidal
height, the left RPC in its GeoTIFF tags, the right image a crop of a larger image), here with the right image's
true RPC (a pointing error along the epipolar lines is a height error no tie point can tell apart); its LiDAR is a
grid of points on that terrain over the left image's footprint (one per 3 x 3 px), in UTM 31N with ellipsoidal
heights. So every DSM must be 500 m, and the LiDAR's height range is exactly 500 m.
"""

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
import yaml
from click.testing import CliRunner
from pyproj import CRS, Transformer

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.pairfile import load_pairfile
from riverbed_cli.io.pointcloud import write_points
from riverbed_cli.scale.block.split import split_axis, split_rois
from rpc_synthetic import H0  # noqa: E402  (tests/: synthetic RPC models)
from test_rpc_cli import LEFT, RIGHT_FULL, SIZE, synthetic_pair  # noqa: E402  (the synthetic RPC pair)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")

UTM3D = CRS("EPSG:32631").to_3d()
VENTOUX = "satellite_pleiades_ventoux_shareloc/tests/data"


def run(args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    return r


def flat_lidar(path, step=3.0, margin=10, h=H0, extra=None):
    """Points on the flat terrain over the left image's footprint (plus ``margin`` px), one per ``step`` px of
    the left image, in UTM 31N with ellipsoidal heights (``extra``: more (lon, lat, h) points)."""
    g = np.arange(-margin, SIZE[0] + margin, step, dtype=np.float64)
    cols, rows = np.meshgrid(g, g)
    lon, lat = LEFT.localize(cols.ravel(), rows.ravel(), np.full(cols.size, h))
    hh = np.full(lon.size, h)
    if extra is not None:
        lon, lat, hh = (np.r_[a, b] for a, b in zip((lon, lat, hh), extra))
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True).transform(lon, lat)
    write_points(path, np.stack([e, n, hh], axis=1), crs=UTM3D, overwrite=True)
    return path


def corner_only(path, px):
    """The cloud at ``path`` cut, in place, to its points over the left image's first ``px`` x ``px`` pixels; returns
    how many it keeps."""
    import laspy

    las = laspy.read(path)
    lon, lat = Transformer.from_crs("EPSG:32631", "EPSG:4326", always_xy=True).transform(las.x, las.y)
    c, rw = LEFT.project(lon, lat, np.asarray(las.z))
    las.points = las.points[(c < px) & (rw < px)]
    las.write(str(path))
    return len(las.points)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The synthetic pair, its LiDAR and the split manifest of 4 ROIs (140 x 140, overlap >= 40 px)."""
    base = tmp_path_factory.mktemp("rpc_block")
    left, right, rpc = synthetic_pair(base / "in", right_rpc=RIGHT_FULL)
    cloud = flat_lidar(base / "lidar.laz")
    r = run(["block", "split-rpc", left, left, right, rpc, "--cloud", cloud, "--size", "140", "--overlap", "40",
             "--heights", "470,530", "--resolution", "1", "-o", base / "split.yaml", "--json"])
    assert r.exit_code == 0, r.output
    return base, (left, right, rpc, cloud), json.loads(r.output)


def merged(path):
    with rasterio.open(path) as ds:
        return ds.read(1), ds.transform, ds.crs, ds.tags()


# -- the splitter ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("length, size, overlap", [(240, 140, 40), (500, 280, 60), (1000, 300, 0), (40000, 2000, 200),
                                                    (999, 100, 99), (100, 100, 10), (60, 100, 10), (250, 150, 50)])
def test_split_axis_covers_exactly_with_the_overlap(length, size, overlap):
    starts = split_axis(length, size, overlap)
    if length <= size:
        assert starts == [0]
        return
    ends = [s + size for s in starts]
    assert starts[0] == 0 and ends[-1] == length and starts == sorted(starts)
    assert all(e <= length for e in ends)
    shared = [a - b for a, b in zip(ends[:-1], starts[1:])]
    assert min(shared) >= overlap
    # as few windows as the overlap allows: one fewer could not cover the axis
    n = len(starts)
    assert (n - 1) * (size - overlap) + overlap < length <= n * (size - overlap) + overlap


def test_split_rois_tile_the_region_and_refuse_bad_sizes():
    region = (30, 20, 500, 333)
    rois = split_rois(region, (150, 120), 30)
    count = np.zeros((333, 500), np.int32)
    for x, y, w, h in rois:
        assert (w, h) == (150, 120) and x >= 30 and y >= 20 and x + w <= 530 and y + h <= 353
        count[y - 20:y - 20 + h, x - 30:x - 30 + w] += 1
    assert count.min() >= 1                       # every pixel of the region in a ROI, none outside it
    assert len(rois) == len(split_axis(500, 150, 30)) * len(split_axis(333, 120, 30)) == 4 * 4
    assert rois == sorted(rois, key=lambda r: (r[1], r[0]))
    assert split_rois((0, 0, 60, 500), 100, 10)[0] == (0, 0, 60, 100)
    for size, overlap, message in [(7, 0, "ROI size must be at least 8 px, got 7x7"),
                                   (100, 100, "overlap must be at least 0 and below the ROI size (100x100), got 100")]:
        with pytest.raises(RiverbedError) as e:
            split_rois(region, size, overlap)
        assert str(e.value) == message


def test_split_manifest_lists_the_rois(scene):
    base, (left, right, rpc, cloud), s = scene
    data = yaml.safe_load((base / "split.yaml").read_text())
    assert data["defaults"] == {"crs": "EPSG:32631", "resolution": 1.0}
    assert [p["rpc"]["roi"] for p in data["pairs"]] == [[0, 0, 140, 140], [100, 0, 140, 140], [0, 100, 140, 140],
                                                        [100, 100, 140, 140]]
    assert [p["name"] for p in data["pairs"]] == ["roi_000_000", "roi_000_100", "roi_100_000", "roi_100_100"]
    first = data["pairs"][0]
    assert first["cloud"] == "lidar.laz" and first["rpc"]["left"] == "in/left.tif"
    assert first["rpc"]["left_rpc"] == "in/left.tif" and first["rpc"]["right_rpc"] == "in/right_rpc.json"
    assert first["rpc"]["heights"] == [470.0, 530.0]
    assert "&id" not in (base / "split.yaml").read_text()  # every ROI's settings written out, no shared anchors
    assert s["left_out"] == [] and all(r["right_share"] > 0.5 for r in s["rois"])
    # the file is not replaced without --overwrite
    r = run(["block", "split-rpc", left, left, right, rpc, "--cloud", cloud, "--size", "140", "-o",
             base / "split.yaml"])
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {base / 'split.yaml'}: exists; pass --overwrite to "
                                          "replace it\n")


# -- the block ------------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def ran(scene):
    base = scene[0]
    r = run(["block", base / "split.yaml", "-o", base / "seq", "--workers", "0", "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


def test_rpc_block_rectifies_matches_and_merges_the_rois(scene, ran):
    base = scene[0]
    assert [p["status"] for p in ran["pairs"]] == ["done"] * 4
    dsm, t, crs, tags = merged(base / "seq" / "dsm.tif")
    assert crs.to_epsg() == 32631 and t.a == 1.0 and tags["riverbed_heights"] == "ellipsoidal (WGS 84, m)"
    z = dsm[np.isfinite(dsm)]
    # the left image's footprint (~190 m x 265 m at ~1 m per px) turned against the north-up grid: ~2/3 of the box
    assert z.size > 0.5 * ran["merged"]["width"] * ran["merged"]["height"]
    # the terrain is flat at 500 m: every ROI's points, rectified and triangulated on their own, lie on it (to the
    # matcher's subpixel error: 2.0 px of disparity per metre, 0.3 px at worst)
    assert abs(np.median(z) - H0) < 0.02 and np.percentile(np.abs(z - H0), 99) < 0.2
    # the merged DSM (agg max over the union of the points) is the cell-wise max of the ROIs' DSMs (1 mm: LAZ steps,
    # which move the points within 0.5 mm of a cell border to the next cell: < 0.2 % of the cells)
    stack = np.full(dsm.shape, np.nan, np.float32)
    for p in ran["pairs"]:
        d, tp, _, _ = merged(base / "seq" / "pairs" / p["name"] / "dsm.tif")
        c0, r0 = int(round((tp.c - t.c) / t.a)), int(round((t.f - tp.f) / t.a))
        window = stack[r0:r0 + d.shape[0], c0:c0 + d.shape[1]]
        window[...] = np.fmax(window, d)
    assert np.mean(np.isfinite(stack) != np.isfinite(dsm)) < 0.002
    assert np.nanpercentile(np.abs(stack - dsm), 99) < 1.5e-3
    for p in ran["pairs"]:
        folder = base / "seq" / "pairs" / p["name"]
        pair = load_pairfile(folder / "rectified" / "pair.yaml", accept_rpc=True)
        roi = yaml.safe_load((base / "split.yaml").read_text())["pairs"][ran["pairs"].index(p)]["rpc"]["roi"]
        assert list(pair.roi) == roi and pair.heights == (470.0, 530.0)
        assert abs(pair.rectification.info["pointing_row_offset_px"]) < 0.1  # the true RPCs: no pointing error
        done = json.loads((folder / "done.json").read_text())
        assert done["stats"]["roi"] == roi and done["stats"]["crs"] == "EPSG:32631"
        assert done["stats"]["lidar_points_kept"] > 1000 and "rectify" in done["stats"]["seconds"]
        with rasterio.open(folder / "dsm.tif") as ds:
            assert ds.tags()["riverbed_heights"] == "ellipsoidal (WGS 84, m)"


def test_rerun_skips_and_a_changed_roi_reruns_only_its_pair(scene, ran, tmp_path):
    base = scene[0]
    r = run(["block", base / "split.yaml", "-o", base / "seq", "--workers", "0", "--json"])
    assert r.exit_code == 0
    again = json.loads(r.output)
    assert [p["status"] for p in again["pairs"]] == ["skipped"] * 4 and again["merged"]["status"] == "skipped"
    # a copy of the block with one ROI's heights changed: that pair is re-rectified and re-run, the rest skipped
    shutil.copytree(base / "seq", tmp_path / "seq")
    data = yaml.safe_load((base / "split.yaml").read_text())
    data["pairs"][2]["rpc"]["heights"] = [480, 520]
    manifest = base / "split_changed.yaml"
    manifest.write_text(yaml.safe_dump(data))
    r = run(["block", manifest, "-o", tmp_path / "seq", "--workers", "0", "--overwrite", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert [p["status"] for p in s["pairs"]] == ["skipped", "skipped", "done", "skipped"]
    pair = load_pairfile(tmp_path / "seq" / "pairs" / "roi_100_000" / "rectified" / "pair.yaml", accept_rpc=True)
    assert pair.heights == (480.0, 520.0) and s["merged"]["status"] == "done"


def test_rpc_block_on_dask_equals_sequential(scene, ran):
    base = scene[0]
    r = run(["block", base / "split.yaml", "-o", base / "dask", "--workers", "2", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["mode"] == "local" and s["cluster"]["workers"] == 2
    assert [p["status"] for p in s["pairs"]] == ["done"] * 4
    a, ta, _, _ = merged(base / "seq" / "dsm.tif")
    b, tb, _, _ = merged(base / "dask" / "dsm.tif")
    assert ta == tb
    np.testing.assert_array_equal(a, b)


def test_heights_from_the_pairs_lidar_and_rpc_pair_files_in_a_block(scene, tmp_path):
    """An rpc: entry without dem or heights takes its range from its clouds; a pair: entry may be an RPC pair file
    (riverbed rectify --rpc --lidar); a ROI the cloud does not cover fails in the rectify stage, the rest finish."""
    base, (left, right, rpc, cloud), _ = scene
    rect = tmp_path / "rect"
    r = run(["rectify", "--rpc", left, left, right, rpc, "-o", rect, "--lidar", cloud, "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["heights"] == pytest.approx([H0 - 20, H0 + 20], abs=2e-3)   # the LiDAR's 500 m (1 mm steps) +- 20 m
    assert s["heights_from"].startswith("LiDAR lidar.laz (") and "points under the ROI, 500.0..500.0 m) +- 20 m" \
        in s["heights_from"]
    part = flat_lidar(tmp_path / "corner.laz", margin=0)
    kept = corner_only(part, 60)  # the corner cloud: only the points over the left image's first 60 x 60 px
    rel = lambda p: Path(p).relative_to(base).as_posix() if Path(p).is_relative_to(base) else str(p)  # noqa: E731
    rpc_entry = {"left": rel(left), "left_rpc": rel(left), "right": rel(right), "right_rpc": rel(rpc)}
    manifest = {"defaults": {"resolution": 0.5}, "pairs": [
        {"name": "lidar_heights", "rpc": {**rpc_entry, "roi": [60, 60, 120, 120]}, "cloud": "lidar.laz"},
        {"name": "from_file", "pair": str(rect / "pair.yaml"), "cloud": "lidar.laz"},
        {"name": "uncovered", "rpc": {**rpc_entry, "roi": [120, 120, 120, 120]}, "cloud": str(part)}]}
    (base / "lidar_heights.yaml").write_text(yaml.safe_dump(manifest))
    r = run(["block", base / "lidar_heights.yaml", "-o", tmp_path / "out", "--workers", "0", "--json"])
    assert r.exit_code == 1
    s = json.loads(r.stdout)
    status = {p["name"]: (p["status"], p["stage"]) for p in s["pairs"]}
    assert status == {"lidar_heights": ("done", None), "from_file": ("done", None), "uncovered": ("failed", "rectify")}
    bad = next(p for p in s["pairs"] if p["name"] == "uncovered")
    assert bad["error"] == (f"{part}: does not cover the ROI 120,120,120,120 of the left image: no point of the kept "
                            f"classes lands in it ({kept} read)")
    assert r.stderr.endswith(f"riverbed: error: pair uncovered failed in rectify: {bad['error']}\n")
    pair = load_pairfile(tmp_path / "out" / "pairs" / "lidar_heights" / "rectified" / "pair.yaml", accept_rpc=True)
    assert pair.heights == pytest.approx((H0 - 20, H0 + 20), abs=2e-3)
    dsm, _, crs, tags = merged(tmp_path / "out" / "dsm.tif")
    z = dsm[np.isfinite(dsm)]
    assert crs.to_epsg() == 32631 and abs(np.median(z) - H0) < 0.01 and s["merged"]["pairs"] == 2


# -- bad input ------------------------------------------------------------------------------------------------------

def test_bad_rpc_entries_are_one_line_errors_and_nothing_is_written(scene, tmp_path):
    base, (left, right, rpc, cloud), _ = scene
    good = {"left": "in/left.tif", "left_rpc": "in/left.tif", "right": "in/right.tif", "right_rpc": "in/right_rpc.json",
            "roi": [0, 0, 100, 100], "pointing": False}

    def entry(**rpc_changes):
        e = {**good, **rpc_changes}
        return {"pairs": [{"rpc": {k: v for k, v in e.items() if v is not None}, "cloud": "lidar.laz"}]}

    cases = [
        (entry(left_rpc=None), "pairs[0].rpc.left_rpc: missing (an RPC file, or the image itself for GeoTIFF RPC "
                               "tags)"),
        (entry(right="in/nope.tif"), "pairs[0].rpc.right: file not found: in/nope.tif"),
        (entry(roi=[200, 0, 100, 100]), f"pairs[0].rpc.roi: {base / 'in' / 'left.tif'}: ROI 200,0,100,100 is outside "
                                        "the 240x240 image (it covers cols 200..299, rows 0..99)"),
        (entry(roi=[0, 0, 100]), "pairs[0].rpc.roi: expected [col, row, width, height] (four integers, px, width and "
                                 "height at least 8), got [0, 0, 100]"),
        (entry(roi="0,0,4,100"), "pairs[0].rpc.roi: width and height must be at least 8 px, got '0,0,4,100'"),
        (entry(heights=[530, 470]), "pairs[0].rpc.heights: LO must be below HI, got '530,470'"),
        (entry(heights=[470, 530], dem="lidar.laz"),
         "pairs[0].rpc: give dem or heights (or neither: the pair's clouds), not both"),
        (entry(dem="srtm.hgt"), "pairs[0].rpc.dem: file not found: srtm.hgt"),
        (entry(vertical="EPSG:5773"), "pairs[0].rpc.vertical: expected the datum (ellipsoid or a vertical CRS such "
                                      "as EPSG:5773) of dem or heights, got 'EPSG:5773'"),
        (entry(heights=[470, 530], vertical="EPSG:4326"), "pairs[0].rpc.vertical: 'EPSG:4326' is not a vertical CRS"),
        (entry(pointing="no"), "pairs[0].rpc.pointing: expected true or false, got 'no'"),
        (entry(colour=1), "pairs[0].rpc: unknown key 'colour' (rpc keys: left, left_rpc, right, right_rpc, roi, dem, "
                          "heights, vertical, pointing)"),
        ({"pairs": [{"rpc": "in/left.tif", "cloud": "lidar.laz"}]},
         "pairs[0].rpc: expected a mapping with left, left_rpc, right, right_rpc, got 'in/left.tif'"),
        ({"pairs": [{"rpc": good, "raw": good, "cloud": "lidar.laz"}]},
         "pairs[0]: give one of pair (a rectified pair file), raw (frames and orientations) or rpc (satellite images "
         "and their RPCs)"),
        ({"defaults": {"crs": "EPSG:4326"}, "pairs": entry()["pairs"]}, None),   # refused when the DSM is made
    ]
    for i, (manifest, message) in enumerate(cases):
        path = base / f"bad{i}.yaml"
        path.write_text(yaml.safe_dump(manifest))
        out = tmp_path / f"out{i}"
        r = run(["block", path, "-o", out, "--workers", "0"])
        assert r.exit_code == 1, (i, r.output)
        if message is None:       # a geographic crs: the pair fails in its dsm stage, in one line
            assert r.stderr == ("riverbed: error: pair in_left_roi_0_0 failed in dsm: crs: WGS 84 is not a projected "
                                "CRS (an RPC pair's DSM is gridded in metres)\n"
                                "riverbed: error: merged DSM: no pair finished: no merged DSM\n")
            assert not (out / "dsm.tif").exists() and not (out / "pairs" / "in_left_roi_0_0" / "done.json").exists()
            continue
        assert r.stderr == f"riverbed: error: {path}: {message}\n", i
        assert not out.exists()


def test_rectify_lidar_bad_inputs(scene, tmp_path):
    base, (left, right, rpc, cloud), _ = scene
    far = flat_lidar(tmp_path / "far.laz", margin=0)
    import laspy
    las = laspy.read(far)
    las.x = np.asarray(las.x) + 5000.0   # 5 km east: nowhere near the image
    las.write(str(far))
    junk = tmp_path / "junk.laz"
    junk.write_bytes(b"LASF" + bytes(200))
    out = tmp_path / "out"
    args = ["rectify", "--rpc", left, left, right, rpc, "-o", out]
    n = len(las.points)
    cases = [
        ([*args, "--lidar", far], f"{far}: does not cover the ROI 0,0,240,240 of the left image: no point of the kept "
                                  f"classes lands in it ({n} read)"),
        ([*args, "--lidar", cloud, "--heights", "470,530"],
         "give the terrain's height range by one of --dem DEM, --heights LO,HI or --lidar CLOUD (or none: from tie "
         "points)"),
        ([*args, "--lidar", cloud, "--vertical", "EPSG:5773"],
         "--vertical does not apply to --lidar (the cloud's CRS gives its heights' datum)"),
        ([*args, "--lidar", tmp_path / "none.laz"], f"{tmp_path / 'none.laz'}: file not found"),
        (["rectify", left, left, right, rpc, "-o", out, "--lidar", cloud, "--roi", "0,0,10,10"], "--roi needs --rpc"),
    ]
    for argv, message in cases:
        r = run(argv)
        assert (r.exit_code, r.output) == (1, f"riverbed: error: {message}\n")
        assert not out.exists()
    r = run([*args, "--lidar", junk])
    assert r.exit_code == 1 and r.output.startswith(f"riverbed: error: {junk}: ") and r.output.count("\n") == 1
    # a cloud that covers only a corner of the ROI
    corner = flat_lidar(tmp_path / "corner.laz", margin=0)
    corner_only(corner, 80)
    r = run([*args, "--lidar", corner])
    # 27 x 27 points on 80 x 80 px: 3 x 3 of the 8 x 8 cells of 30 x 30 px
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {corner}: does not cover the ROI 0,0,240,240 of the left "
                                          "image: its 729 points there fall in 14% of an 8x8 grid over it (at least "
                                          "50% needed)\n")
    assert not out.exists()


# -- the real Pléiades pair: 4 ROIs on dask against the whole crop ------------------------------------------------

def test_ventoux_split_into_rois_on_dask_merges_like_the_whole_crop(shared_data, tmp_path):
    from bench_rpc_block import REGION
    from bench_rpc_block import run as run_bench

    s = run_bench(shared_data, tmp_path, single=REGION)   # one ROI over the split region (docs: the whole crop)
    assert [p["status"] for p in s["split"]["pairs"]] == ["done"] * 4
    assert s["split"]["cluster"]["workers"] == 2
    d = s["figures"]
    # the merged DSM of the 4 ROIs and the one ROI's: the same surface (each ROI rectified and pointed alone), and
    # as close to the SRTM (measured: dz 0.013 / 0.048 m median / NMAD over 135 201 cells; against the SRTM
    # 0.019 / 0.151 m and -0.001 / 0.146 m)
    assert d["merged_vs_whole"]["cells"] == pytest.approx(135201, rel=0.01)
    assert d["merged_vs_whole"]["median"] == pytest.approx(0.013, abs=0.01)
    assert d["merged_vs_whole"]["nmad"] == pytest.approx(0.048, abs=0.01)
    assert d["merged_vs_srtm"]["median"] == pytest.approx(0.019, abs=0.01)
    assert d["whole_vs_srtm"]["median"] == pytest.approx(-0.001, abs=0.01)
    assert d["merged_vs_srtm"]["nmad"] == pytest.approx(0.151, rel=0.1)
    assert d["whole_vs_srtm"]["nmad"] == pytest.approx(0.146, rel=0.1)
    assert d["merged_vs_srtm"]["nmad"] < 1.1 * d["whole_vs_srtm"]["nmad"]


def test_lidar_height_range_ignores_unclassified_noise():
    # 40 x 40 ground points at 1 m on a 5 % slope (500..502 m), a bird 120 m above and a multipath echo 60 m below:
    # neither stretches the range (the affine rectification is fitted over it)
    from riverbed_cli.geometry.rpc_heights import robust_height_range

    e, n = np.meshgrid(np.arange(40.0), np.arange(40.0))
    lon = 5.2 + e.ravel() / (111_320.0 * np.cos(np.radians(44.2)))
    lat = 44.2 + n.ravel() / 110_574.0
    h = 500.0 + 0.05 * e.ravel()
    llh = np.stack([lon, lat, h], axis=1)
    noisy = np.concatenate([llh, [[lon[300], lat[300], 620.0], [lon[900], lat[900], 440.0]]])
    lo, hi, out = robust_height_range(noisy)
    # (the grid's 4 corners, whose neighbours are far, go too: SOR's floor of 1.5 times the typical spacing)
    assert out == 6 and lo == 500.0 and hi == pytest.approx(501.95)
    assert robust_height_range(llh)[:2] == (500.0, pytest.approx(501.95))


def test_a_failed_pointing_correction_in_a_block_names_the_manifest_key(scene, tmp_path):
    # a 100 x 100 ROI has too few tie points for the pointing correction: the block's message names the manifest's
    # way of turning it off, not the rectify command's flag
    base, (left, right, rpc, cloud), _ = scene
    entry = {"left": str(left), "left_rpc": str(left), "right": str(right), "right_rpc": str(rpc),
             "roi": [60, 60, 100, 100], "heights": [470, 530]}
    manifest = {"defaults": {"resolution": 1}, "pairs": [{"name": "tiny", "rpc": entry, "cloud": str(cloud)}]}
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(manifest))
    r = run(["block", tmp_path / "tiny.yaml", "-o", tmp_path / "out", "--workers", "0", "--json"])
    assert r.exit_code == 1
    (pair,) = json.loads(r.stdout)["pairs"]
    assert (pair["status"], pair["stage"]) == ("failed", "rectify")
    assert pair["error"].startswith(f"{left}: too few tie points (0) to estimate the RPC pointing error")
    assert pair["error"].endswith(f"(with {right}; pointing: false in its rpc: entry rectifies without it)")
    entry["pointing"] = False
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(manifest))
    r = run(["block", tmp_path / "tiny.yaml", "-o", tmp_path / "out2", "--workers", "0", "--json"])
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("heights", [["--heights", "470,530"], []], ids=["heights", "tie points"])
def test_a_satellite_block_without_lidar(scene, tmp_path, heights):
    """split-rpc without --cloud: each ROI matched from the images alone over its range (--heights, or without it
    the ROI's tie points); the merged DSM lies on the flat terrain as the LiDAR-guided block's does. The manifest
    writes each ROI's settings out in full (no YAML anchors shared between ROIs)."""
    left, right, rpc, _ = scene[1]
    manifest = tmp_path / "split.yaml"
    r = run(["block", "split-rpc", left, left, right, rpc, "--size", "140", "--overlap", "40", "--resolution", "1",
             "-o", manifest, *heights])
    assert r.exit_code == 0, r.output
    text = manifest.read_text()
    assert "&id" not in text and "*id" not in text and "cloud" not in text
    r = run(["block", manifest, "-o", tmp_path / "out", "--workers", "0", "--json"])
    assert r.exit_code == 0, r.output
    ran = json.loads(r.stdout)
    assert [p["status"] for p in ran["pairs"]] == ["done"] * 4
    for p in ran["pairs"]:
        done = json.loads((tmp_path / "out" / "pairs" / p["name"] / "done.json").read_text())
        assert done["stats"]["clouds"] == 0 and done["stats"]["lidar_share"] == 0.0
        assert not (tmp_path / "out" / "pairs" / p["name"] / "sparse.tif").exists()
        pair = load_pairfile(tmp_path / "out" / "pairs" / p["name"] / "rectified" / "pair.yaml", accept_rpc=True)
        assert pair.inputs["heights_from"].startswith("--heights" if heights else "tie points")
    z, *_ = merged(tmp_path / "out" / "dsm.tif")
    z = z[np.isfinite(z)]
    assert z.size > 0.5 * ran["merged"]["width"] * ran["merged"]["height"]
    # measured: median -0.093 m over 470..530 m, -0.020 m over the tie points' range (unguided SGM's sub-pixel
    # bias, which the guided block's LiDAR removes), 95 % within 0.135 / 0.061 m, 1.0 / 0.9 % of the cells more
    # than 1 m off (the lower ROIs' bottom edge)
    e = z - H0
    median, p95 = (-0.093, 0.135) if heights else (-0.020, 0.061)
    assert np.median(e) == pytest.approx(median, abs=0.02) and np.percentile(np.abs(e), 95) < p95 + 0.025
    assert np.mean(np.abs(e) > 1) < 0.015
