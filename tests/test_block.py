"""riverbed block: manifest validation, the same merged DSM sequentially and on a 2-worker LocalCluster, re-runs
that skip verified pairs, tampered outputs and changed settings that re-run only their pair, failing pairs."""

import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rasterio
import yaml
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.cameras import PairGeometry
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.io.lidar import read_lidar
from riverbed_cli.geometry.pairfile import load_pairfile, write_pairfile
from riverbed_cli.io.pointcloud import write_points
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.dsm import Grid, rasterize
from riverbed_cli.products.visualize import write_png
from riverbed_cli.scale.block import load_manifest, plan_block, project_stage, run_block
from riverbed_cli.scale.tiles import match_tiled

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_dsm_ranges import coarse_dsm  # noqa: E402  (the sample block's GT DSM averaged over k x k cells)

DATA = Path(__file__).parent / "data" / "cones"
SAMPLE = Path(__file__).parent.parent / "sample_data" / "block"

# A nadir-like frame for the Middlebury Cones pair (450 x 375): f = 1000 px, baseline 115 m, a Middlebury-style
# principal point shift (doffs) of 200 px, so GT disparities 5.5..55 px are depths of 442..561 m below a camera at
# 600 m: an aerial block's geometry (GSD ~0.5 m) on real images.
F, BASE, DOFFS, FLY = 1000.0, 115.0, 200.0, 600.0
ORIGIN = np.array([501000.0, 5002300.0, 0.0])  # just south-west of the synthetic sample block
CROP = (200, 240)  # H, W of each test pair
CROPS = {"a": (0, 0), "b": (210, 0), "c": (0, 175), "d": (210, 175)}  # x0, y0: four overlapping views
CRS = "EPSG:32632"


def cones_pair(x0=0, y0=0, width=450, height=375, left=None, right=None):
    """The rectified cameras of a crop at (x0, y0) of Cones: every crop sees the same world."""
    R = np.diag([1.0, -1.0, -1.0])  # looking down, image x east, image y south
    C = np.array([0.0, 0.0, FLY])
    K = np.array([[F, 0, 225.0 - x0], [0, F, 187.0 - y0], [0, 0, 1]])
    K1 = K.copy()
    K1[0, 2] += DOFFS
    return PairGeometry(K @ np.c_[R, -R @ C], K1 @ np.c_[R, -R @ (C + [BASE, 0, 0])], origin=ORIGIN, crs=CRS,
                        left=left, right=right, width=width, height=height)


def gt_points(share=1.0, seed=0):
    """World points (float64) of the Cones ground truth, all or a random share of them."""
    gt = read_disparity(DATA / "disp2.png", scale=4)
    r, c = np.nonzero(np.isfinite(gt))
    if share < 1:
        keep = np.random.default_rng(seed).random(r.size) < share
        r, c = r[keep], c[keep]
    return cones_pair().triangulate(c, r, gt[r, c]) + ORIGIN


def write_cones_block(base):
    """Four crops of Cones as pair files, LiDAR (5 % of the GT) in two LAZ tiles, and block manifests."""
    left, right = read_image(DATA / "im2.png"), read_image(DATA / "im6.png")
    H, W = CROP
    for name, (x0, y0) in CROPS.items():
        folder = base / name
        folder.mkdir(parents=True)
        write_png(folder / "left.png", left[y0:y0 + H, x0:x0 + W])
        write_png(folder / "right.png", right[y0:y0 + H, x0:x0 + W])
        write_pairfile(folder / "pair.yaml", cones_pair(x0, y0, W, H, folder / "left.png", folder / "right.png"))
    xyz = gt_points(0.05)
    west = xyz[:, 0] < np.median(xyz[:, 0])
    (base / "lidar").mkdir()
    write_points(base / "lidar" / "west.laz", xyz[west], None, CRS)
    write_points(base / "lidar" / "east.laz", xyz[~west], None, CRS)
    (base / "lidar" / "corrupt.laz").write_bytes(b"LASF" + bytes(range(256)) * 4)
    pairs = [{"pair": "a/pair.yaml", "cloud": "lidar/*st.laz"},
             {"pair": "b/pair.yaml", "cloud": ["lidar/west.laz", "lidar/east.laz"]},
             {"pair": "c/pair.yaml", "cloud": "lidar/*st.laz", "name": "c"},
             {"pair": "d/pair.yaml", "cloud": "lidar/*st.laz", "tile": 256}]  # not tiled: one match_pair task
    if (SAMPLE / "pair.yaml").is_file():  # the synthetic aerial sample block, when it has been generated
        pairs.append({"pair": str(SAMPLE / "pair.yaml"), "cloud": str(SAMPLE / "lidar.laz"), "name": "sample",
                      "tile": 4096})
    defaults = {"resolution": 1.0, "agg": "max", "tile": 128, "overlap": 32}
    (base / "block.yaml").write_text(yaml.safe_dump({"defaults": defaults, "pairs": pairs}, sort_keys=False))
    bad = [{"pair": "d/pair.yaml", "cloud": "lidar/*st.laz", "name": "good"},
           {"pair": "a/pair.yaml", "cloud": "lidar/corrupt.laz", "name": "bad"}]
    (base / "bad.yaml").write_text(yaml.safe_dump({"defaults": defaults, "pairs": bad}, sort_keys=False))
    return base


def run(args):
    result = CliRunner().invoke(cli, args, catch_exceptions=False)
    return result


def summary(result):
    return json.loads(result.stdout)


def read_dsm(path):
    with rasterio.open(path) as ds:
        return ds.read(1), ds.transform, ds.crs


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    base = write_cones_block(tmp_path_factory.mktemp("block"))
    t0 = time.perf_counter()
    res = run(["block", str(base / "block.yaml"), "-o", str(base / "seq"), "--workers", "0", "--json"])
    seconds = time.perf_counter() - t0
    assert res.exit_code == 0, res.stderr
    return base, summary(res), seconds


# -- manifest validation --------------------------------------------------------------------------------------------

GOOD = {"pair": "a/pair.yaml", "cloud": "lidar/*st.laz"}


ERRORS = [
    ({"pairs": [GOOD], "extra": 1}, "unknown key 'extra' (manifest keys: defaults, pairs)"),
    ({"defaults": {"windw": 5}, "pairs": [GOOD]}, "defaults: unknown key 'windw' (settings: resolution, crs, agg, "),
    ({"pairs": [{**GOOD, "colour": 1}]},
     "pairs[0]: unknown key 'colour' (pair keys: pair, raw, rpc, cloud, name, range_map, and the settings of "
     "defaults)"),
    ({"pairs": [{**GOOD, "range_map": "a/ranges.tif"}]}, "pairs[0].range_map: file not found: a/ranges.tif"),
    ({"pairs": [{"raw": {"left": "a/left.png", "left_orientation": "a/pair.yaml", "right": "a/right.png",
                         "right_orientation": "a/pair.yaml"}, "cloud": "lidar/west.laz", "range_map": "a/left.png"}]},
     "pairs[0].range_map: only for a pair: entry (its ranges are of the rectified images"),
    ({"defaults": {"range_dsm": "dsm.tif"}, "pairs": [GOOD]}, "defaults.range_dsm: file not found: dsm.tif"),
    ({"pairs": [{**GOOD, "range_dsm": "a/left.png", "range_dsm_margin": -1}]},
     "pairs[0].range_dsm_margin: expected a number of pixels >= 0, got -1"),
    ({"defaults": {"range_dsm": "a/left.png"}, "pairs": [{**GOOD, "range_map": "a/left.png"}]},
     "pairs[0]: give range_map or range_dsm (the ranges from a DSM), not both"),
    ({"pairs": []}, "pairs: expected a non-empty list of {pair: PAIR_FILE, cloud: CLOUDS}"),
    ({"pairs": [GOOD, {"pair": "x/pair.yaml", "cloud": "lidar/west.laz"}]},
     "pairs[1].pair: file not found: x/pair.yaml"),
    ({"pairs": [{**GOOD, "cloud": "lidar/*.las"}]}, "pairs[0].cloud: 'lidar/*.las' matches no file"),
    ({"pairs": [{**GOOD, "cloud": ["lidar/west.laz", "lidar/north.laz"]}]},
     "pairs[0].cloud: file not found: lidar/north.laz"),
    ({"defaults": {"tile": 8}, "pairs": [GOOD]}, "defaults.tile: expected 'auto' or an integer >= 16 (px), got 8"),
    ({"defaults": {"agg": "mode"}, "pairs": [GOOD]},
     "defaults.agg: expected one of max, mean, median, idw, got 'mode'"),
    ({"defaults": {"crs": "EPSG:99999999"}, "pairs": [GOOD]}, "defaults.crs: unknown CRS 'EPSG:99999999'"),
    ({"defaults": {"resolution": -1}, "pairs": [GOOD]},
     "defaults.resolution: expected a positive number (CRS units) or null, got -1"),
    ({"pairs": [{**GOOD, "window": 4}]}, "pairs[0].window: expected 'auto' or an odd integer from 1 to 101, got 4"),
    ({"pairs": [{**GOOD, "lr_check": "yes"}]}, "pairs[0].lr_check: expected true or false, got 'yes'"),
    ({"pairs": [{**GOOD, "census": "8x7"}]}, "pairs[0].census: census window 8x7: width and height must be odd"),
    ({"pairs": [{**GOOD, "resolution": 0.5}]}, "pairs[0].resolution: a block-wide setting; give it under defaults"),
    ({"pairs": [{**GOOD, "min_disp": 9, "max_disp": 3}]}, "pairs[0]: min_disp 9 > max_disp 3"),
    ({"pairs": [GOOD, {**GOOD, "cloud": "lidar/west.laz"}]},
     "pairs[1].name: 'a_pair' is already the name of pairs[0]; give each pair a unique name"),
    ({"pairs": [{**GOOD, "name": "../up"}]}, "pairs[0].name: expected letters, digits"),
]


@pytest.mark.parametrize("manifest, message", ERRORS)
def test_manifest_errors_name_the_manifest_and_the_key(block, manifest, message):
    base = block[0]
    path = base / "wrong.yaml"
    path.write_text(yaml.safe_dump(manifest))
    with pytest.raises(RiverbedError) as e:
        load_manifest(path)
    assert str(e.value).startswith(f"{path}: {message}"), str(e.value)
    res = CliRunner().invoke(cli, ["block", str(path), "-o", str(base / "never")])
    assert res.exit_code == 1 and res.stderr.startswith(f"riverbed: error: {path}: {message}")
    assert len(res.stderr.strip().splitlines()) == 1 and not (base / "never").exists()


def test_manifest_yaml_errors_and_defaults(block, tmp_path):
    base = block[0]
    bad = tmp_path / "m.yaml"
    bad.write_text("pairs: [unclosed\n")
    with pytest.raises(RiverbedError, match=r"m.yaml: invalid YAML at line 2, column 1"):
        load_manifest(bad)
    bad.write_text("!!python/object/apply:os.system ['true']\n")
    with pytest.raises(RiverbedError, match="invalid YAML"):  # safe_load only
        load_manifest(bad)
    m = load_manifest(base / "block.yaml")
    names = [p.name for p in m.pairs]
    assert names[:4] == ["a_pair", "b_pair", "c", "d_pair"]
    assert [len(p.clouds) for p in m.pairs[:4]] == [2, 2, 2, 2]
    assert m.pairs[0].settings["tile"] == 128 and m.pairs[3].settings["tile"] == 256
    assert m.pairs[0].settings["census"] == "9x7" and m.pairs[0].settings["drop_classes"] == [7, 18]


def test_output_folder_rule(block, tmp_path):
    base = block[0]
    other = tmp_path / "other"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    res = CliRunner().invoke(cli, ["block", str(base / "bad.yaml"), "-o", str(other)])
    assert res.exit_code == 1 and "output folder is not empty and holds no block; pass --overwrite" in res.stderr
    res = CliRunner().invoke(cli, ["block", str(base / "bad.yaml"), "-o", str(base / "seq")])
    assert res.exit_code == 1 and "holds the block of another manifest" in res.stderr
    res = CliRunner().invoke(cli, ["block", str(base / "bad.yaml"), "-o", str(tmp_path / "no" / "out")])
    assert res.exit_code == 1 and "does not exist" in res.stderr


# -- running blocks -------------------------------------------------------------------------------------------------

def test_sequential_block_products(block):
    base, info, _ = block
    assert [p["status"] for p in info["pairs"]] == ["done"] * len(info["pairs"])
    assert [p["tiles"] for p in info["pairs"][:4]] == [4, 4, 4, 0]
    assert info["merged"]["status"] == "done" and info["merged"]["pairs"] == len(info["pairs"])
    out = base / "seq"
    for name in ("a_pair", "b_pair", "c", "d_pair"):
        folder = out / "pairs" / name
        assert sorted(p.name for p in folder.iterdir()) == ["disparity.tif", "done.json", "dsm.tif",
                                                            "points.laz", "sparse.tif"]
    dsm, transform, crs = read_dsm(out / "dsm.tif")
    assert crs.to_epsg() == 32632 and transform.a == 1.0 and transform.c % 1.0 == 0 and transform.f % 1.0 == 0
    # The merged DSM holds the Cones surface: against the ground-truth points on the same grid.
    xyz = gt_points()
    grid = Grid(transform.c, transform.f, 1.0, dsm.shape[1], dsm.shape[0])
    ref = rasterize(xyz[:, 0], xyz[:, 1], xyz[:, 2], grid, "max")
    both = np.isfinite(dsm) & np.isfinite(ref)
    assert both.sum() > 0.8 * np.isfinite(ref).sum()
    assert np.median(np.abs(dsm[both] - ref[both])) < 0.6  # ~0.25 px of disparity at 2.2 m per px


def test_tile_tasks_are_match_tiled(block):
    """The per-tile tasks stitched give exactly what match_tiled gives on the same pair, sparse map and settings."""
    base = block[0]
    folder = base / "seq" / "pairs" / "a_pair"
    pair = load_pairfile(base / "a" / "pair.yaml")
    sparse = read_disparity(folder / "sparse.tif")
    ref = match_tiled(read_image(pair.left), read_image(pair.right), sparse, tile=128, overlap=32)
    np.testing.assert_array_equal(read_disparity(folder / "disparity.tif"), ref.disparity)


def test_dask_block_equals_sequential(block):
    base, seq, t_seq = block
    t0 = time.perf_counter()
    res = run(["block", str(base / "block.yaml"), "-o", str(base / "dask"), "--workers", "2", "--json"])
    t_dask = time.perf_counter() - t0
    assert res.exit_code == 0, res.stderr
    info = summary(res)
    assert info["mode"] == "local"
    assert [p["status"] for p in info["pairs"]] == ["done"] * len(info["pairs"])
    a, ta, _ = read_dsm(base / "seq" / "dsm.tif")
    b, tb, _ = read_dsm(base / "dask" / "dsm.tif")
    assert ta == tb
    np.testing.assert_array_equal(a, b)
    for p in seq["pairs"]:
        done_seq = json.loads((base / "seq" / "pairs" / p["name"] / "done.json").read_text())
        done_dask = json.loads((base / "dask" / "pairs" / p["name"] / "done.json").read_text())
        assert done_seq["outputs"]["points.laz"] == done_dask["outputs"]["points.laz"]
    print(f"\nsequential {t_seq:.1f} s, 2 workers {t_dask:.1f} s (cluster start included)")


def test_rerun_skips_every_finished_pair(block):
    base = block[0]
    before = (base / "seq" / "dsm.tif").stat().st_mtime_ns
    t0 = time.perf_counter()
    res = run(["block", str(base / "block.yaml"), "-o", str(base / "seq"), "--json"])  # default: local cluster
    seconds = time.perf_counter() - t0
    assert res.exit_code == 0, res.stderr
    info = summary(res)
    assert [p["status"] for p in info["pairs"]] == ["skipped"] * len(info["pairs"])
    assert info["merged"]["status"] == "skipped" and (base / "seq" / "dsm.tif").stat().st_mtime_ns == before
    assert all(p["points"] > 10000 for p in info["pairs"])
    # no cluster is started when nothing is left to do (what it reports, not a wall-clock limit)
    assert info["cluster"] is None and info["cluster_seconds"] is None
    print(f"\nre-run {seconds:.2f} s")


def test_tampered_output_and_changed_setting_rerun_only_their_pair(block, tmp_path):
    base = block[0]
    copy = tmp_path / "copy"
    shutil.copytree(base, copy)  # copy2: mtimes kept, so the inputs hash the same
    marker = copy / "seq" / "block.json"
    record = json.loads(marker.read_text())
    record["manifest"] = str(copy / "block.yaml")  # the copied block belongs to the copied manifest
    marker.write_text(json.dumps(record))
    laz = copy / "seq" / "pairs" / "b_pair" / "points.laz"
    original = laz.read_bytes()
    data = bytearray(original)
    data[len(data) // 2] ^= 0xFF  # one byte changed, same size
    laz.write_bytes(bytes(data))
    manifest = yaml.safe_load((copy / "block.yaml").read_text())
    manifest["pairs"][2]["median"] = 5  # pair c: a changed setting
    (copy / "block.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    res = run(["block", str(copy / "block.yaml"), "-o", str(copy / "seq"), "--workers", "0", "--json"])
    assert res.exit_code == 0, res.stderr
    status = {p["name"]: p["status"] for p in summary(res)["pairs"]}
    assert status.pop("b_pair") == "done" and status.pop("c") == "done"
    assert set(status.values()) == {"skipped"}
    assert laz.read_bytes() == original  # recomputed identically
    assert summary(res)["merged"]["status"] == "done"


@pytest.mark.parametrize("where", ["sequential", "scheduler"])
def test_failing_pair_is_reported_and_the_rest_finish(block, tmp_path, where):
    base = block[0]
    out = tmp_path / "out"
    args = ["block", str(base / "bad.yaml"), "-o", str(out), "--json"]
    if where == "sequential":
        res = run([*args, "--workers", "0"])
    else:  # an existing cluster (--scheduler ADDRESS), here a threaded one in this process
        from distributed import LocalCluster

        with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
            res = run([*args, "--scheduler", cluster.scheduler_address])
    assert res.exit_code == 1
    info = summary(res)
    assert info["mode"] == where
    by = {p["name"]: p for p in info["pairs"]}
    assert by["good"]["status"] == "done" and by["bad"]["status"] == "failed"
    assert by["bad"]["stage"] == "project" and "corrupt.laz" in by["bad"]["error"]
    lines = res.stderr.strip().splitlines()
    assert lines == [f"riverbed: error: pair bad failed in project: {by['bad']['error']}"]
    assert info["merged"]["status"] == "done" and (out / "dsm.tif").is_file()
    assert not (out / "pairs" / "bad" / "done.json").exists()


def test_several_clouds_keep_the_nearer_point_and_skip_clouds_elsewhere(block, tmp_path):
    base = block[0]
    west = read_lidar(base / "lidar" / "west.laz")["xyz"]
    write_points(tmp_path / "lower.laz", west - [0, 0, 20.0], None, CRS)  # 20 m farther from the camera
    write_points(tmp_path / "far.laz", west + [20000.0, 0, 0], None, CRS)  # 20 km east: not in the image
    m = tmp_path / "m.yaml"
    clouds = [str(base / "lidar" / "west.laz"), str(tmp_path / "lower.laz"), str(tmp_path / "far.laz")]
    # the LiDAR check off: sparse.tif holds the merged clouds as projected (the check would drop the region where
    # the lowered copy fills the west cloud's gaps)
    m.write_text(yaml.safe_dump({"defaults": {"lidar_check": "off"},
                                 "pairs": [{"pair": str(base / "a" / "pair.yaml"), "cloud": clouds, "name": "a"},
                                           {"pair": str(base / "a" / "pair.yaml"), "cloud": clouds[:1],
                                            "name": "w"}]}))
    plan = plan_block(m, tmp_path / "out")
    pair_plan = project_stage(plan.jobs[0])
    assert pair_plan.stats["clouds"] == 2 and pair_plan.stats["clouds_without_points"] == 1
    merged = read_disparity(tmp_path / "out" / "pairs" / "a" / "sparse.tif")
    project_stage(plan.jobs[1])
    near = read_disparity(tmp_path / "out" / "pairs" / "w" / "sparse.tif")
    has = np.isfinite(near)
    np.testing.assert_array_equal(merged[has], near[has])  # where the true surface has a point, it wins
    assert np.isfinite(merged).sum() > has.sum()  # the lowered copy fills pixels the west cloud does not reach
    with pytest.raises(RiverbedError, match="give --workers .* or --scheduler .*, not both"):
        run_block(plan, workers=2, scheduler="tcp://127.0.0.1:1")


def test_plan_marks_unreadable_pair_file_failed(block, tmp_path):
    base = block[0]
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "pair.yaml").write_text("P_left: [1, 2]\n")
    m = tmp_path / "m.yaml"
    m.write_text(yaml.safe_dump({"pairs": [{"pair": "p/pair.yaml", "cloud": str(base / "lidar" / "west.laz")}]}))
    plan = plan_block(m, tmp_path / "out")
    assert plan.jobs[0].status == "failed" and plan.jobs[0].error.endswith("P_right: missing (a 3x4 projection matrix)")


def test_raw_frames_in_the_manifest_are_rectified_then_matched(tmp_path):
    """A manifest entry may list raw frames with their orientations: the block rectifies them first."""
    sample = Path(__file__).resolve().parent.parent / "sample_data" / "block"
    for f in ("raw/frame0.png", "raw/frame0.yaml", "raw/frame1.png", "raw/frame1.yaml", "lidar.laz"):
        (tmp_path / f).parent.mkdir(exist_ok=True)
        shutil.copy(sample / f, tmp_path / f)
    (tmp_path / "block.yaml").write_text(yaml.safe_dump({
        "defaults": {"resolution": 0.5},
        "pairs": [{"name": "strip", "cloud": "lidar.laz",
                   "raw": {"left": "raw/frame0.png", "left_orientation": "raw/frame0.yaml",
                           "right": "raw/frame1.png", "right_orientation": "raw/frame1.yaml"}}]}))
    res = run(["block", str(tmp_path / "block.yaml"), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert res.exit_code == 0, res.stderr
    assert [p["status"] for p in summary(res)["pairs"]] == ["done"]
    rect = tmp_path / "out" / "pairs" / "strip" / "rectified"
    assert all((rect / f).is_file() for f in ("left.png", "right.png", "pair.yaml"))
    with rasterio.open(tmp_path / "out" / "dsm.tif") as ds:
        assert ds.crs.to_epsg() == 32632 and np.isfinite(ds.read(1, masked=True).filled(np.nan)).mean() > 0.2
    res = run(["block", str(tmp_path / "block.yaml"), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert [p["status"] for p in summary(res)["pairs"]] == ["skipped"]
    # rectification settings in the manifest: a new alpha re-rectifies (every source pixel kept: a new camera
    # matrix) and re-runs the pair; so does a new size
    m = yaml.safe_load((tmp_path / "block.yaml").read_text())
    size0 = tuple(read_image(rect / "left.png").shape[1::-1])
    pair0 = (rect / "pair.yaml").read_text()
    m["pairs"][0]["raw"]["alpha"] = 1
    (tmp_path / "block.yaml").write_text(yaml.safe_dump(m))
    res = run(["block", str(tmp_path / "block.yaml"), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert [p["status"] for p in summary(res)["pairs"]] == ["done"]
    assert json.loads((rect / "inputs.json").read_text())[-1] == {"alpha": 1.0, "size": None}
    assert (rect / "pair.yaml").read_text() != pair0
    m["pairs"][0]["raw"]["size"] = "600x400"
    (tmp_path / "block.yaml").write_text(yaml.safe_dump(m))
    res = run(["block", str(tmp_path / "block.yaml"), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert [p["status"] for p in summary(res)["pairs"]] == ["done"]
    assert tuple(read_image(rect / "left.png").shape[1::-1]) == (600, 400) != size0
    for key, value, msg in (("alpha", 2, "expected a number from 0 to 1 (or -1), got 2"),
                            ("size", "600 by 400", "expected WIDTHxHEIGHT in pixels, e.g. 1200x800, got '600 by 400'")):
        bad = yaml.safe_load((tmp_path / "block.yaml").read_text())
        bad["pairs"][0]["raw"][key] = value
        (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
        res = run(["block", str(tmp_path / "bad.yaml"), "-o", str(tmp_path / "out3")])
        assert res.exit_code == 1
        assert res.stderr == f"riverbed: error: {tmp_path / 'bad.yaml'}: pairs[0].raw.{key}: {msg}\n"
    bad = yaml.safe_load((tmp_path / "block.yaml").read_text())
    bad["pairs"][0]["pair"] = "x.yaml"
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
    res = run(["block", str(tmp_path / "bad.yaml"), "-o", str(tmp_path / "out2")])
    assert res.exit_code == 1
    assert res.stderr == (f"riverbed: error: {tmp_path / 'bad.yaml'}: pairs[0]: give one of pair (a rectified pair "
                          "file), raw (frames and orientations) or rpc (satellite images and their RPCs)\n")


def test_manifest_reaches_adcensus_diffusion_and_riverbed_plus_settings(block, tmp_path):
    """Every riverbed match setting is a manifest key: a pair's AD-Census / riverbed+ / diffusion settings reach the
    matcher (its disparity is match_pair's with that configuration, and differs from the defaults')."""
    base = block[0]
    pairs = [{"pair": str(base / "d/pair.yaml"), "cloud": str(base / "lidar/east.laz"), "name": "plus",
              "matcher": "adcensus", "guide": "riverbed+", "adcensus_pi2": 4.5, "plus_hops": 2, "plus_margin": 1.0},
             {"pair": str(base / "d/pair.yaml"), "cloud": str(base / "lidar/east.laz"), "name": "diff",
              "guide": "diffusion", "diffusion_radius": 2, "diffusion_sigma_s": 4.0}]
    manifest = tmp_path / "settings.yaml"
    manifest.write_text(yaml.safe_dump({"defaults": {"resolution": 1.0, "tile": 0, "min_disp": 0, "max_disp": 63},
                                        "pairs": pairs}))
    r = run(["block", str(manifest), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert r.exit_code == 0, r.output
    pair = load_pairfile(base / "d/pair.yaml")
    left, right = read_image(pair.left), read_image(pair.right)
    for entry in pairs:
        folder = tmp_path / "out" / "pairs" / entry["name"]
        sparse = read_disparity(folder / "sparse.tif")
        settings = {k: v for k, v in entry.items() if k not in ("pair", "cloud", "name")}
        want = match_pair(left, right, sparse, 0, 63, **settings).disparity
        got = read_disparity(folder / "disparity.tif")
        np.testing.assert_array_equal(got, want)
        plain = match_pair(left, right, sparse, 0, 63, guide=entry["guide"],
                           matcher=entry.get("matcher", "sgm")).disparity
        assert not np.array_equal(got, plain, equal_nan=True)  # the settings changed the result


@pytest.mark.parametrize("key, value, message", [
    ("plus_hops", -1, "expected 'auto' or an integer >= 0, got -1"),
    ("adcensus_guide_stage", "later", "expected one of aggregated, initial, got 'later'"),
    ("diffusion_sigma_s", 0, "expected a positive number, got 0"),
    ("paths", 5, "expected one of 4, 8, 16, got 5"),
])
def test_bad_setting_same_message_in_manifest_and_on_the_command_line(block, tmp_path, key, value, message):
    base = block[0]
    manifest = tmp_path / "bad.yaml"
    manifest.write_text(yaml.safe_dump({"defaults": {key: value},
                                        "pairs": [{"pair": str(base / "d/pair.yaml"),
                                                   "cloud": str(base / "lidar/west.laz")}]}))
    r = CliRunner().invoke(cli, ["block", str(manifest), "-o", str(tmp_path / "never")])
    assert r.exit_code == 1 and r.stderr == f"riverbed: error: {manifest}: defaults.{key}: {message}\n"
    option = "--" + key.replace("_", "-")
    r = CliRunner().invoke(cli, ["match", str(DATA / "im2.png"), str(DATA / "im6.png"), "--max-disp", "59",
                                 option, str(value), "-o", str(tmp_path / "never.tif")])
    assert r.exit_code == 1 and r.stderr == f"riverbed: error: {option}: {message}\n"
    assert not (tmp_path / "never").exists() and not (tmp_path / "never.tif").exists()


def test_block_tiles_fill_lidar_holes_with_coarse_ranges(tmp_path):
    """``tube_holes: coarse`` in a manifest reaches the block's tiles: each tile's LiDAR holes take the coarse
    match's ranges, exactly as match_tiled's (and not the tile's range, as by default; on this crop the narrower
    ranges find the same disparities)."""
    base = write_cones_block(tmp_path)
    xyz = gt_points(0.05)
    lo, hi = np.quantile(xyz[:, 0], [0.1, 0.45])  # a band about 150 px wide across pair a's crop: no LiDAR
    write_points(base / "lidar" / "holed.laz", xyz[(xyz[:, 0] < lo) | (xyz[:, 0] > hi)], None, CRS)
    manifest = {"defaults": {"resolution": 1.0, "agg": "max", "tile": 128, "overlap": 32, "tube_holes": "coarse"},
                "pairs": [{"pair": "a/pair.yaml", "cloud": "lidar/holed.laz", "name": "a"}]}
    (base / "holes.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    res = run(["block", str(base / "holes.yaml"), "-o", str(base / "out"), "--workers", "0", "--json"])
    assert res.exit_code == 0, res.stderr
    assert [(p["status"], p["tiles"]) for p in summary(res)["pairs"]] == [("done", 4)]
    folder = base / "out" / "pairs" / "a"
    pair = load_pairfile(base / "a" / "pair.yaml")
    left, right = read_image(pair.left), read_image(pair.right)
    sparse = read_disparity(folder / "sparse.tif")
    coarse = match_tiled(left, right, sparse, tile=128, overlap=32, tube={"holes": "coarse"})
    nominal = match_tiled(left, right, sparse, tile=128, overlap=32)
    disp = read_disparity(folder / "disparity.tif")
    np.testing.assert_array_equal(disp, coarse.disparity)
    # the holes narrowed (from each tile's range, which its neighbouring LiDAR already bounds)
    assert coarse.info["tubes"]["mean_width"] < nominal.info["tubes"]["mean_width"]


def test_block_pairs_search_the_ranges_of_a_dsm(tmp_path):
    """``range_dsm`` (a setting, here under defaults): each pair projects the DSM as a cloud and searches the ranges
    `riverbed project DSM` + `riverbed range-map --window auto --margin M` give (the same bits, tiled or not); a
    changed DSM re-runs the pair."""
    from riverbed_cli.io.windowed import read_range_map
    from riverbed_cli.matching.lidar_input import resolve_disparity_range

    coarse_dsm(tmp_path / "coarse.tif", 16)  # the sample block's ground-truth DSM averaged to 3.2 m cells
    pairs = [{"pair": str(SAMPLE / "pair.yaml"), "cloud": str(SAMPLE / "lidar.laz"), "name": "whole"},
             {"pair": str(SAMPLE / "pair.yaml"), "cloud": str(SAMPLE / "lidar.laz"), "name": "tiled", "tile": 256,
              "overlap": 32}]
    manifest = {"defaults": {"range_dsm": "coarse.tif", "range_dsm_margin": 3, "tile": 0}, "pairs": pairs}
    (tmp_path / "block.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    res = run(["block", str(tmp_path / "block.yaml"), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert res.exit_code == 0, res.stderr
    by = {p["name"]: p for p in summary(res)["pairs"]}
    assert by["whole"]["status"] == by["tiled"]["status"] == "done"
    assert by["whole"]["tiles"] == 0 and by["tiled"]["tiles"] > 1
    # the same ranges through the commands
    for args in (["project", tmp_path / "coarse.tif", SAMPLE / "pair.yaml", "-o", tmp_path / "dsm_sparse.tif"],
                 ["range-map", tmp_path / "dsm_sparse.tif", "--window", "auto", "--margin", "3", "-o",
                  tmp_path / "ranges.tif"]):
        r = CliRunner().invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output
    lo, hi = read_range_map(tmp_path / "ranges.tif")
    pair = load_pairfile(SAMPLE / "pair.yaml")
    left, right = read_image(pair.left), read_image(pair.right)
    for name in ("whole", "tiled"):
        folder = tmp_path / "out" / "pairs" / name
        sparse = read_disparity(folder / "sparse.tif")
        d_min, d_max = resolve_disparity_range(None, None, sparse[np.isfinite(sparse)])
        known = np.isfinite(lo)
        d_min, d_max = min(d_min, int(np.floor(lo[known].min()))), max(d_max, int(np.ceil(hi[known].max())))
        if name == "tiled":
            ref = match_tiled(left, right, sparse, d_min, d_max, tile=256, overlap=32, range_map=(lo, hi))
        else:
            ref = match_pair(left, right, sparse, d_min, d_max, range_map=(lo, hi))
        np.testing.assert_array_equal(read_disparity(folder / "disparity.tif"), ref.disparity)
    # the DSM is an input of each pair: a changed DSM re-runs both, an unchanged one none
    res = run(["block", str(tmp_path / "block.yaml"), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert {p["status"] for p in summary(res)["pairs"]} == {"skipped"}
    with rasterio.open(tmp_path / "coarse.tif", "r+") as ds:
        ds.write(ds.read(1) + np.float32(0.5), 1)
    res = run(["block", str(tmp_path / "block.yaml"), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert {p["status"] for p in summary(res)["pairs"]} == {"done"}


def test_block_pairs_search_their_range_maps(tmp_path):
    """``range_map`` on a pair entry: the pair searches the map's intervals (riverbed match --range-map), tiled as
    match_tiled with the map, untiled as match_pair; the pair's range widens to hold the map; a map of the wrong
    size fails its pair with one line naming the file."""
    from riverbed_cli.io.disparity import write_range_map
    from riverbed_cli.matching.lidar_input import resolve_disparity_range

    base = write_cones_block(tmp_path)
    gt = read_disparity(DATA / "disp2.png", scale=4)
    H, W = CROP
    maps = {}
    for name in ("a", "d"):
        x0, y0 = CROPS[name]
        crop = gt[y0:y0 + H, x0:x0 + W]
        maps[name] = (crop - 4.0, crop + 4.0)  # the truth +- 4 px (NaN where the GT has none: the pair's range)
        write_range_map(base / name / "ranges.tif", *maps[name])
    write_range_map(base / "b" / "ranges.tif", np.zeros((H - 1, W)), np.ones((H - 1, W)))
    pairs = [{"pair": "a/pair.yaml", "cloud": "lidar/*st.laz", "name": "a", "range_map": "a/ranges.tif"},
             {"pair": "d/pair.yaml", "cloud": "lidar/*st.laz", "name": "d", "range_map": "d/ranges.tif",
              "tile": 256},  # not tiled
             {"pair": "b/pair.yaml", "cloud": "lidar/*st.laz", "name": "b", "range_map": "b/ranges.tif"}]
    manifest = {"defaults": {"resolution": 1.0, "agg": "max", "tile": 128, "overlap": 32}, "pairs": pairs}
    (base / "ranges.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    res = run(["block", str(base / "ranges.yaml"), "-o", str(base / "out"), "--workers", "0", "--json"])
    by = {p["name"]: p for p in summary(res)["pairs"]}
    assert (by["a"]["status"], by["a"]["tiles"]) == ("done", 4) and (by["d"]["status"], by["d"]["tiles"]) == ("done", 0)
    assert by["b"]["status"] == "failed"
    assert by["b"]["error"] == f"{base / 'b' / 'ranges.tif'}: range map is {W}x{H - 1} but the images are {W}x{H} (WxH)"
    for name in ("a", "d"):
        folder = base / "out" / "pairs" / name
        pair = load_pairfile(base / name / "pair.yaml")
        left, right = read_image(pair.left), read_image(pair.right)
        sparse = read_disparity(folder / "sparse.tif")
        lo, hi = maps[name]
        d_min, d_max = resolve_disparity_range(None, None, sparse[np.isfinite(sparse)])
        known = np.isfinite(lo)
        d_min, d_max = min(d_min, int(np.floor(lo[known].min()))), max(d_max, int(np.ceil(hi[known].max())))
        if name == "a":
            ref = match_tiled(left, right, sparse, d_min, d_max, tile=128, overlap=32, range_map=(lo, hi))
            assert ref.info["tiles"] == 4 and ref.info["tile_ranges"]["range_map"] == 4
        else:
            ref = match_pair(left, right, sparse, d_min, d_max, range_map=(lo, hi))
        np.testing.assert_array_equal(read_disparity(folder / "disparity.tif"), ref.disparity)
        assert ref.info["tubes"]["mean_width"] < 12  # 9 px where the GT is known, against the LiDAR's tubes


def test_a_pair_without_a_cloud_is_matched_from_its_images(tmp_path):
    """An entry without ``cloud``: raw frames are rectified (pair.yaml holds the tie points' range) and matched
    unguided over that range, bit for bit as ``riverbed match --pair`` matches the rectified pair; a re-run skips
    it. A pair file without a range and no min_disp/max_disp is one line naming it."""
    sample = Path(__file__).resolve().parent.parent / "sample_data" / "block"
    for f in ("raw/frame0.png", "raw/frame0.yaml", "raw/frame1.png", "raw/frame1.yaml", "pair.yaml", "left.png",
              "right.png"):
        (tmp_path / f).parent.mkdir(exist_ok=True)
        shutil.copy(sample / f, tmp_path / f)
    raw = {"left": "raw/frame0.png", "left_orientation": "raw/frame0.yaml", "right": "raw/frame1.png",
           "right_orientation": "raw/frame1.yaml"}
    (tmp_path / "block.yaml").write_text(yaml.safe_dump({"pairs": [{"name": "strip", "raw": raw}]}))
    res = run(["block", str(tmp_path / "block.yaml"), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert res.exit_code == 0, res.stderr
    folder = tmp_path / "out" / "pairs" / "strip"
    done = json.loads((folder / "done.json").read_text())
    assert done["stats"]["clouds"] == 0 and [done["stats"]["d_min"], done["stats"]["d_max"]] == [477, 527]
    assert not (folder / "sparse.tif").exists() and "sparse.tif" not in done["outputs"]
    rect = folder / "rectified"
    r = run([str(a) for a in ("match", rect / "left.png", rect / "right.png", "--pair", rect / "pair.yaml", "-o",
                              tmp_path / "d.tif")])
    assert r.exit_code == 0, r.stderr
    assert np.array_equal(read_disparity(folder / "disparity.tif"), read_disparity(tmp_path / "d.tif"),
                          equal_nan=True)
    res = run(["block", str(tmp_path / "block.yaml"), "-o", str(tmp_path / "out"), "--workers", "0", "--json"])
    assert [p["status"] for p in summary(res)["pairs"]] == ["skipped"]
    # the sample's own pair file states no range
    (tmp_path / "bare.yaml").write_text(yaml.safe_dump({"pairs": [{"name": "bare", "pair": "pair.yaml"}]}))
    res = run(["block", str(tmp_path / "bare.yaml"), "-o", str(tmp_path / "out2"), "--workers", "0"])
    assert res.exit_code == 1
    assert (f"pair bare failed in project: {tmp_path / 'pair.yaml'}: no cloud and no disparity range: give the pair "
            "a cloud, min_disp and max_disp, or a pair file with its range (riverbed rectify writes one)") in res.stderr
