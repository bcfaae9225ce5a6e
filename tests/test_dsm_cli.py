"""``riverbed dsm`` and ``riverbed evaluate --dsm`` through the CLI, on inputs whose DSM is known exactly.

The pair is a nadir pair 400 m above flat ground (f = 800 px, B = 50 m: one pixel is 0.5 m on the ground) whose origin
puts every ground point at a cell centre of a 0.5 m grid, and three pixels by three inside each cell of a 1.5 m grid
(heights of up to 2 m move a point by at most 0.15 m, never across a cell edge). So every cell count, grid, transform
and height below is exact: the outputs are a COG (GDAL's layout, checked as GDAL's validator does, also for the DSMs
``riverbed block`` writes), each option does what it says, every bad input is one exact line, exit code 1, no output.
"""

import json
import math
import struct
from pathlib import Path
from types import SimpleNamespace

import cv2
import laspy
import numpy as np
import pytest
import rasterio
import yaml
from affine import Affine
from click.testing import CliRunner
from test_block import write_cones_block
from test_dsm import nadir_pair, numpy_reference

from riverbed_cli.cli.main import cli
from riverbed_cli.geometry.pairfile import load_pairfile, write_pairfile
from riverbed_cli.io.disparity import read_disparity, write_disparity
from riverbed_cli.io.raster import write_geotiff
from riverbed_cli.products.dsm import Grid, build_dsm, disparity_points, grid_indices, hillshade
from riverbed_cli.products.visualize import hillshade_picture

F, BASE, FLY = 800.0, 50.0, 400.0
ORIGIN = (499999.75, 5000001.25, 0.0)  # ground x = ORIGIN + 0.5 (col - 60): cell centres of 0.5 m and 1.5 m grids
W, H = 120, 100
GROUND = F * BASE / FLY  # 100 px: ground at 0 m
# The 1.5 m grid of the ground points: 40 x 34 cells, cell (i, j) holds pixels rows 3i..3i+2, cols 3j..3j+2.
GRID15 = Affine(1.5, 0.0, 499969.5, 0.0, -1.5, 5000026.5)


def disparity_of(z):
    return (F * BASE / (FLY - np.asarray(z, np.float64))).astype(np.float32)


def cog_problems(path):
    """What keeps ``path`` from being a cloud-optimised GeoTIFF, checked as GDAL's
    ``validate_cloud_optimized_geotiff.py --full-check`` does: the ghost area with GDAL's structural metadata right
    after the TIFF header, the main IFD right after it and the overview IFDs after it, all IFDs before any image
    data, tiles, overviews when the image is larger than a tile, image data from the smallest overview to the full
    resolution, the blocks of each level in row-major order with their size before them and their last 4 bytes
    repeated after them. ``[]`` for a COG."""
    raw = Path(path).read_bytes()
    if raw[:4] not in (b"II*\0", b"II+\0"):
        return ["not a little-endian TIFF"]
    problems = []
    pos = 16 if raw[2] == ord("+") else 8
    key = b"GDAL_STRUCTURAL_METADATA_SIZE="
    expected_ifd = None
    if raw[pos:pos + len(key)] != key:
        problems.append("no GDAL structural metadata after the TIFF header")
    else:
        size = int(raw[pos + len(key):pos + len(key) + 6])
        start = pos + len(key) + 6 + len(b" bytes\n")
        meta = raw[start:start + size].decode()
        for item in ("LAYOUT=IFDS_BEFORE_DATA", "BLOCK_ORDER=ROW_MAJOR", "BLOCK_LEADER=SIZE_AS_UINT4",
                     "BLOCK_TRAILER=LAST_4_BYTES_REPEATED"):
            if item not in meta.split():
                problems.append(f"structural metadata without {item}")
        expected_ifd = start + size + (start + size) % 2  # IFDs start on a word boundary
    with rasterio.open(path) as ds:
        if ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") != "COG":
            problems.append("GDAL does not report LAYOUT=COG")
        if not ds.profile.get("tiled"):
            problems.append("not tiled")
        bh, bw = ds.block_shapes[0]
        factors = ds.overviews(1)
        if max(ds.width, ds.height) > max(bw, bh) and not factors:
            problems.append("larger than a tile but no overviews")
        count = ds.count
    if Path(f"{path}.ovr").exists():
        problems.append("external overviews")
    ifds, first_blocks = [], []
    for level in [None, *range(len(factors))]:  # full resolution, then the overviews from the largest
        name = "full resolution" if level is None else f"overview {level}"
        with rasterio.open(path, overview_level=level) as ds:
            ifds.append(int(ds.get_tag_item("IFD_OFFSET", "TIFF", bidx=1)))
            for band in range(1, count + 1):
                last = 0
                for y in range(math.ceil(ds.height / bh)):
                    for x in range(math.ceil(ds.width / bw)):
                        offset = int(ds.get_tag_item(f"BLOCK_OFFSET_{x}_{y}", "TIFF", bidx=band) or 0)
                        nbytes = int(ds.get_tag_item(f"BLOCK_SIZE_{x}_{y}", "TIFF", bidx=band) or 0)
                        if band == 1 and x == y == 0:
                            first_blocks.append(offset)
                        if offset == 0:
                            continue  # a sparse (empty) block
                        if offset < last:
                            problems.append(f"{name} band {band}: block ({x}, {y}) before the previous one")
                        last = offset
                        if struct.unpack("<I", raw[offset - 4:offset])[0] != nbytes:
                            problems.append(f"{name} band {band}: block ({x}, {y}) without its size before it")
                        if nbytes >= 4 and raw[offset + nbytes - 4:offset + nbytes] != raw[
                                offset + nbytes:offset + nbytes + 4]:
                            problems.append(f"{name} band {band}: block ({x}, {y}) without its trailer")
    if expected_ifd is not None and ifds[0] != expected_ifd:
        problems.append(f"main IFD at byte {ifds[0]}, not right after the structural metadata ({expected_ifd})")
    if ifds != sorted(ifds):
        problems.append(f"IFDs not in the order full resolution, overviews: {ifds}")
    if min(first_blocks) < max(ifds):
        problems.append("an IFD after image data")
    if first_blocks[::-1] != sorted(first_blocks):
        problems.append(f"image data not from the smallest overview to the full resolution: {first_blocks}")
    return problems


def test_cog_problems_tell_a_plain_geotiff_from_a_cog(tmp_path):
    """The check itself: a tiled GeoTIFF with internal overviews, written by the GTiff driver, is no COG."""
    data = np.random.default_rng(0).random((600, 700)).astype(np.float32)
    profile = {"driver": "GTiff", "width": 700, "height": 600, "count": 1, "dtype": "float32", "tiled": True,
               "blockxsize": 256, "blockysize": 256, "crs": "EPSG:32632", "transform": GRID15}
    with rasterio.open(tmp_path / "plain.tif", "w", **profile) as ds:
        ds.write(data, 1)
        ds.build_overviews([2, 4])
    problems = cog_problems(tmp_path / "plain.tif")
    assert "no GDAL structural metadata after the TIFF header" in problems
    assert "GDAL does not report LAYOUT=COG" in problems
    assert any(p.startswith("image data not from the smallest overview") for p in problems)
    write_geotiff(tmp_path / "cog.tif", data, GRID15, "EPSG:32632", float("nan"))
    assert cog_problems(tmp_path / "cog.tif") == []


# -- inputs -----------------------------------------------------------------------------------------------------------


def write_pair(folder, disp, name="d.tif"):
    """The pair file and a disparity map in ``folder``; returns their paths as strings."""
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / "pair.yaml").exists():
        write_pairfile(folder / "pair.yaml", nadir_pair(f=F, B=BASE, H=FLY, W=W, Hh=H, origin=ORIGIN))
    write_disparity(folder / name, disp)
    return str(folder / name), str(folder / "pair.yaml")


def rough_heights(seed=0):
    return np.random.default_rng(seed).uniform(0.0, 2.0, (H, W))


def with_holes():
    """Flat ground with a 2 x 2-cell hole (1.5 m cells 10..11, 10..11) and a 10 x 10-cell gap (cells 20..29)."""
    disp = np.full((H, W), GROUND, np.float32)
    disp[30:36, 30:36] = np.nan
    disp[60:90, 60:90] = np.nan
    return disp


def dsm(*args):
    return CliRunner().invoke(cli, ["dsm", *map(str, args)])


def read_bands(path):
    """The bands of a GeoTIFF and what the tests read of its profile."""
    with rasterio.open(path) as ds:
        return ds.read(), SimpleNamespace(transform=ds.transform, shape=ds.shape, nodata=ds.nodata,
                                          nodatavals=ds.nodatavals, descriptions=ds.descriptions, tags=ds.tags())


def points_of(disp_path, pair_path):
    xyz, _, _ = disparity_points(read_disparity(disp_path), load_pairfile(pair_path))
    return xyz


# -- the outputs are cloud-optimised GeoTIFFs --------------------------------------------------------------------------


@pytest.mark.parametrize("extra, bands, block, overviews", [
    ((), 1, 256, [2, 4]),
    (("--fill-holes", "3"), 2, 256, [2, 4]),
    (("--co", "BLOCKSIZE=128", "--co", "COMPRESS=LZW"), 1, 128, [2, 4, 8]),
])
def test_dsm_output_is_a_cog(tmp_path, extra, bands, block, overviews):
    d, p = write_pair(tmp_path, disparity_of(rough_heights()))
    r = dsm(d, p, "-o", tmp_path / "dsm.tif", "--resolution", "0.0625", *extra)
    assert r.exit_code == 0, r.output
    assert cog_problems(tmp_path / "dsm.tif") == []
    with rasterio.open(tmp_path / "dsm.tif") as ds:
        assert (ds.count, ds.width, ds.height) == (bands, 952, 792)  # the points span 59.5 m x 49.5 m
        assert ds.block_shapes == [(block, block)] * bands and ds.overviews(1) == overviews


def test_block_dsms_are_cogs(tmp_path):
    """``riverbed block`` on one pair (Cones crop 'd' of tests/test_block.py, 0.25 m cells): the merged DSM and the
    pair's DSM are COGs with an overview."""
    base = write_cones_block(tmp_path / "block")
    manifest = {"defaults": {"resolution": 0.25, "tile": 256}, "pairs": [{"pair": "d/pair.yaml",
                                                                         "cloud": "lidar/*st.laz"}]}
    (base / "one.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    r = CliRunner().invoke(cli, ["block", str(base / "one.yaml"), "-o", str(base / "out"), "--workers", "0",
                                 "--json"])
    assert r.exit_code == 0, r.output
    merged = json.loads(r.stdout)["merged"]
    assert merged["status"] == "done" and merged["pairs"] == 1
    for path in (base / "out" / "dsm.tif", base / "out" / "pairs" / "d_pair" / "dsm.tif"):
        assert cog_problems(path) == [], path
        with rasterio.open(path) as ds:
            assert (ds.width, ds.height) == (merged["width"], merged["height"]) and ds.overviews(1) == [2]


# -- options ----------------------------------------------------------------------------------------------------------


def test_agg_each_value_equals_numpy_on_the_points(tmp_path):
    d, p = write_pair(tmp_path, disparity_of(rough_heights()))
    xyz = points_of(d, p)
    grid = Grid(GRID15.c, GRID15.f, 1.5, 40, 34)
    counts = np.zeros((34, 40), int)
    np.add.at(counts, grid_indices(grid, xyz[:, 0], xyz[:, 1]), 1)
    assert (counts[:33] == 9).all() and (counts[33] == 3).all()  # 3 x 3 pixels a cell, 3 x 1 in the last row
    got = {}
    for agg in ("max", "mean", "median", "idw"):
        out = tmp_path / f"{agg}.tif"
        r = dsm(d, p, "-o", out, "--resolution", "1.5", "--agg", agg, "--json")
        assert r.exit_code == 0, r.output
        s = json.loads(r.stdout)
        assert s["aggregation"] == agg and s["image_points"] == W * H and s["confidence_dropped"] is None
        (z,), ds = read_bands(out)
        assert ds.transform == GRID15 and ds.shape == (34, 40) and ds.tags["riverbed_aggregation"] == agg
        ref = numpy_reference(xyz[:, 0], xyz[:, 1], xyz[:, 2], grid, agg).astype(np.float32)
        assert np.isfinite(ref).all()
        np.testing.assert_array_equal(z, ref)
        got[agg] = z
    for a in got:  # four different answers: the option reaches the rasteriser
        for b in got:
            assert a == b or not np.array_equal(got[a], got[b])


@pytest.mark.parametrize("bounds", [("499980", "4999989", "500010", "5000010"),
                                    ("499980.7", "4999989.2", "500009.9", "5000009.8")])
def test_bounds_give_the_grid_exactly(tmp_path, bounds):
    """--bounds on the 1.5 m multiples, or inside them (snapped outwards): 20 x 14 cells from (499980, 5000010),
    each cell the one of the full DSM."""
    d, p = write_pair(tmp_path, disparity_of(rough_heights()))
    assert dsm(d, p, "-o", tmp_path / "full.tif", "--resolution", "1.5").exit_code == 0
    r = dsm(d, p, "-o", tmp_path / "part.tif", "--resolution", "1.5", "--bounds", *bounds, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["bounds"] == [499980.0, 4999989.0, 500010.0, 5000010.0] and (s["width"], s["height"]) == (20, 14)
    (full,), _ = read_bands(tmp_path / "full.tif")
    (part,), ds = read_bands(tmp_path / "part.tif")
    assert ds.transform == Affine(1.5, 0.0, 499980.0, 0.0, -1.5, 5000010.0) and ds.shape == (14, 20)
    # (5000026.5 - 5000010) / 1.5 = 11 rows and (499980 - 499969.5) / 1.5 = 7 columns into the full DSM
    np.testing.assert_array_equal(part, full[11:25, 7:27])


def test_fill_holes_fills_the_hole_and_leaves_the_gap(tmp_path):
    d, p = write_pair(tmp_path, with_holes())
    r = dsm(d, p, "-o", tmp_path / "dsm.tif", "--resolution", "1.5", "--fill-holes", "3", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["cells_filled"] == 4 and s["image_points"] == W * H - 36 - 900
    (z, filled), ds = read_bands(tmp_path / "dsm.tif")
    assert ds.transform == GRID15 and ds.descriptions == ("height", "filled")
    hole = np.zeros((34, 40), bool)
    hole[10:12, 10:12] = True
    gap = np.zeros((34, 40), bool)
    gap[20:30, 20:30] = True
    np.testing.assert_array_equal(filled, hole.astype(np.float32))  # 1 = filled, exactly the 2 x 2 hole
    assert (z[hole] == 0.0).all()  # filled from the flat ground around it
    assert np.isnan(z[gap]).all() and (z[~gap] == 0.0).all()  # 10 cells across: too wide for 3
    r = dsm(d, p, "-o", tmp_path / "plain.tif", "--resolution", "1.5")
    (plain,), _ = read_bands(tmp_path / "plain.tif")
    assert np.isnan(plain[hole | gap]).all() and (plain[~(hole | gap)] == 0.0).all()


def test_nodata_in_the_holes_and_the_tag(tmp_path):
    d, p = write_pair(tmp_path, with_holes())
    r = dsm(d, p, "-o", tmp_path / "dsm.tif", "--resolution", "1.5", "--nodata", "-9999", "--fill-holes", "3")
    assert r.exit_code == 0, r.output
    (z, filled), ds = read_bands(tmp_path / "dsm.tif")
    assert ds.nodata == -9999.0 and ds.nodatavals == (-9999.0, -9999.0)
    assert (z[20:30, 20:30] == -9999.0).all() and int((z == -9999.0).sum()) == 100  # the gap, nothing else
    assert (z[10:12, 10:12] == 0.0).all() and int(filled.sum()) == 4 and not (filled == -9999.0).any()
    assert dsm(d, p, "-o", tmp_path / "nan.tif", "--resolution", "1.5", "--fill-holes", "3").exit_code == 0
    with rasterio.open(tmp_path / "dsm.tif") as a, rasterio.open(tmp_path / "nan.tif") as b:
        np.testing.assert_array_equal(a.read(1, masked=True).filled(np.nan), b.read(1))
    r = CliRunner().invoke(cli, ["evaluate", "--dsm", str(tmp_path / "dsm.tif"), str(tmp_path / "nan.tif"),
                                 "--json"])
    assert r.exit_code == 0, r.output
    m = json.loads(r.stdout)
    assert m["n"] == 34 * 40 - 100 and m["rmse"] == 0.0 and m["completeness"] == 100.0


def test_hillshade_png_of_the_dsm(tmp_path):
    """--hillshade writes a PNG holding the DSM's hillshade at the DSM's size, drawn from the heights (never
    from the --nodata value)."""
    d, p = write_pair(tmp_path, disparity_of(rough_heights()))
    r = dsm(d, p, "-o", tmp_path / "dsm.tif", "--resolution", "1.5", "--nodata", "-9999", "--hillshade",
            tmp_path / "hs.png")
    assert r.exit_code == 0, r.output
    with rasterio.open(tmp_path / "dsm.tif") as ds:
        z = ds.read(1, masked=True).filled(np.nan)
    picture = hillshade_picture(hillshade(z, 1.5), z, 1.5)
    assert picture.box[2:] == z.shape == (34, 40)
    png = cv2.cvtColor(cv2.imread(str(tmp_path / "hs.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(png, picture.rgb)


def test_co_reaches_the_file(tmp_path):
    d, p = write_pair(tmp_path, disparity_of(rough_heights()))
    r = dsm(d, p, "-o", tmp_path / "dsm.tif", "--resolution", "0.25", "--co", "COMPRESS=LZW", "--co",
            "blocksize=128")
    assert r.exit_code == 0, r.output
    with rasterio.open(tmp_path / "dsm.tif") as ds:
        assert ds.profile["compress"] == "lzw" and ds.block_shapes == [(128, 128)]
        assert ds.tags(ns="IMAGE_STRUCTURE")["PREDICTOR"] == "3"  # the float predictor is still riverbed's default
    assert cog_problems(tmp_path / "dsm.tif") == []


# -- confidence -------------------------------------------------------------------------------------------------------


def test_min_confidence_drops_points_and_cells(tmp_path):
    """Pixels below X or with NaN confidence are dropped; X itself is kept; invalid disparities are no drop."""
    disp = np.full((H, W), GROUND, np.float32)
    disp[60:63, 60:63] = np.nan  # no points here, whatever their confidence (1.5 m cell (20, 20))
    conf = np.full((H, W), 0.9, np.float32)
    conf[30:33, 30:33] = 0.2  # all 9 points of cell (10, 10): the cell loses its height
    conf[33:36, 30:32] = np.nan  # 6 of the 9 points of cell (11, 10): it keeps 3
    conf[36:39, 30:33] = 0.5  # == X: kept
    conf[39:42, 33:36] = 0.4999  # all 9 of cell (13, 11): lost
    conf[60:63, 60:63] = 0.1
    d, p = write_pair(tmp_path, disp)
    write_disparity(tmp_path / "conf.tif", conf)  # a float32 TIFF, NaN nodata
    # the lattice left open: the cells as their points give them
    r = dsm(d, p, "-o", tmp_path / "dsm.tif", "--resolution", "1.5", "--points", tmp_path / "p.las",
            "--confidence", tmp_path / "conf.tif", "--min-confidence", "0.5", "--json", "--keep-lattice")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["confidence_dropped"] == 9 + 6 + 9 and s["cells_closed"] == 0
    assert s["image_points"] == W * H - 9 - 24 == len(laspy.read(tmp_path / "p.las").points)
    assert dsm(d, p, "-o", tmp_path / "all.tif", "--resolution", "1.5", "--keep-lattice").exit_code == 0
    (kept,), ds = read_bands(tmp_path / "dsm.tif")
    (every,), _ = read_bands(tmp_path / "all.tif")
    assert ds.transform == GRID15
    lost = np.isfinite(every) & np.isnan(kept)
    assert sorted(zip(*np.nonzero(lost))) == [(10, 10), (13, 11)]
    assert np.isnan(every[20, 20]) and np.array_equal(kept[~lost], every[~lost], equal_nan=True)
    # by default a lone empty cell among 8 with heights is closed by their median (docs/dsm.md): the two lost cells
    # and the cell without disparities take the flat ground's height again
    r = dsm(d, p, "-o", tmp_path / "closed.tif", "--resolution", "1.5", "--confidence", tmp_path / "conf.tif",
            "--min-confidence", "0.5", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["cells_closed"] == 3
    (closed,), _ = read_bands(tmp_path / "closed.tif")
    for cell in ((10, 10), (13, 11), (20, 20)):
        assert closed[cell] == every[10, 12], cell


def test_min_confidence_in_the_library_equals_masked_disparities(tmp_path):
    pair = load_pairfile(Path(write_pair(tmp_path, with_holes())[1]))
    disp = disparity_of(rough_heights(1))
    conf = np.random.default_rng(2).random((H, W)).astype(np.float32)
    conf[::7, ::5] = np.nan
    res = build_dsm([(disp, pair, None)], resolution=1.5, agg="mean", confidence=[conf], min_confidence=0.3)
    masked = np.where(conf >= 0.3, disp, np.nan).astype(np.float32)
    ref = build_dsm([(masked, pair, None)], resolution=1.5, agg="mean", bounds=res.grid.bounds)
    assert res.stats["confidence_dropped"] == int((~(conf >= 0.3)).sum())
    np.testing.assert_array_equal(res.dsm, ref.dsm)


def confidence_case(tmp_path, name):
    """Extra arguments of ``riverbed dsm`` and the expected message (after ``riverbed: error: ``) of each bad
    confidence input."""
    c = tmp_path / "conf.tif"
    write_disparity(c, np.full((H, W), 0.9, np.float32))  # a good one, unless the case replaces it
    use = ["--confidence", c, "--min-confidence", "0.5"]
    if name == "no confidence":
        return ["--min-confidence", "0.5"], "--min-confidence needs --confidence CONF.tif (the disparity's " \
                                             "per-pixel confidence)"
    if name == "no minimum":
        return ["--confidence", c], "--confidence needs --min-confidence X (the lowest confidence kept, 0 to 1)"
    if name in ("above 1", "below 0", "nan"):
        x = {"above 1": "1.5", "below 0": "-0.1", "nan": "nan"}[name]
        return ["--confidence", c, "--min-confidence", x], f"--min-confidence must be a number from 0 to 1, got {x}"
    if name == "text":
        return ["--confidence", c, "--min-confidence", "high"], "--min-confidence: 'high' is not a number"
    if name == "missing":
        return ["--confidence", tmp_path / "none.tif", "--min-confidence", "0.5"], \
            f"{tmp_path / 'none.tif'}: file not found"
    if name == "one for two":
        return [*use, tmp_path / "d.tif", tmp_path / "pair.yaml"], \
            "give one --confidence per DISP PAIR couple (2 couples, 1 --confidence)"
    if name == "other size":
        write_disparity(c, np.full((50, 60), 0.9, np.float32), overwrite=True)
        return use, f"{c}: confidence map is 60x50 but the disparity map is 120x100 (W x H)"
    if name == "two bands":
        write_geotiff(c, np.full((2, H, W), 0.9, np.float32), GRID15, None, None, overwrite=True)
        return use, f"{c}: confidence map must have one band, has 2"
    if name == "integers":
        write_geotiff(c, np.full((H, W), 200, np.uint8), GRID15, None, None, overwrite=True)
        return use, f"{c}: confidence map must be float32 (values 0 to 1), got uint8"
    if name == "values above 1":
        bad = np.full((H, W), 0.9, np.float32)
        bad[5, 7:9] = 1.5
        write_disparity(c, bad, overwrite=True)
        return use, f"{c}: confidence values must lie in [0, 1] (NaN: none), found 1.5 (2 pixels outside)"
    if name == "unreadable":
        c.write_bytes(b"II*\0" + b"\xff" * 60)
        return use, f"{c}: cannot read confidence map (not a TIFF rasterio reads)"
    raise KeyError(name)


CONFIDENCE_CASES = ["no confidence", "no minimum", "above 1", "below 0", "nan", "text", "missing", "one for two",
                    "other size", "two bands", "integers", "values above 1", "unreadable"]


@pytest.mark.parametrize("name", CONFIDENCE_CASES)
def test_bad_confidence_is_one_line(tmp_path, name):
    d, p = write_pair(tmp_path, np.full((H, W), GROUND, np.float32))
    args, message = confidence_case(tmp_path, name)
    out = tmp_path / "out"
    out.mkdir()
    r = dsm(d, p, "-o", out / "dsm.tif", "--points", out / "p.laz", *args)
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {message}\n")
    assert list(out.iterdir()) == []


# -- bad inputs -------------------------------------------------------------------------------------------------------


def bad_dsm_case(tmp_path, name):
    """Arguments of ``riverbed dsm`` (outputs in tmp_path/out) and the expected message of each bad input."""
    t, out = tmp_path, tmp_path / "out"
    d, p = write_pair(t, with_holes())
    o = ["-o", out / "dsm.tif", "--resolution", "1.5"]
    if name == "missing disparity":
        return [t / "none.tif", p, *o], f"{t / 'none.tif'}: file not found"
    if name == "unreadable disparity":
        (t / "junk.tif").write_bytes(b"II*\0" + b"\x00" * 100)
        return [t / "junk.tif", p, *o], f"{t / 'junk.tif'}: cannot read TIFF disparity (not a TIFF rasterio reads)"
    if name == "disparity of another size":
        write_disparity(t / "small.tif", np.full((50, 60), GROUND, np.float32))
        return [t / "small.tif", p, *o], (f"{t / 'small.tif'}: disparity map is 60x50 but the images of {p} are "
                                          "120x100 (W x H)")
    if name == "pair file without P_right":
        (t / "bad.yaml").write_text(yaml.safe_dump({"P_left": np.eye(3, 4).tolist()}))
        return [d, t / "bad.yaml", *o], f"{t / 'bad.yaml'}: P_right: missing (a 3x4 projection matrix)"
    if name == "pair file not YAML":
        (t / "bad.yaml").write_text("P_left: [1, 2\n")
        return [d, t / "bad.yaml", *o], (f"{t / 'bad.yaml'}: invalid YAML at line 2, column 1: expected ',' or ']', "
                                         "but got '<stream end>'")
    if name == "missing pair file":
        return [d, t / "none.yaml", *o], f"{t / 'none.yaml'}: file not found"
    if name == "bounds text":
        return [d, p, *o, "--bounds", "499980", "south", "500010", "5000010"], \
            "--bounds: 'south' is not a number (give XMIN YMIN XMAX YMAX)"
    if name == "bounds reversed":
        return [d, p, *o, "--bounds", "500010", "4999989", "499980", "5000010"], \
            "bounds 500010 4999989 499980 5000010 are empty (XMIN YMIN XMAX YMAX with XMIN < XMAX and YMIN < YMAX)"
    if name == "bounds not finite":
        return [d, p, *o, "--bounds", "499980", "4999989", "inf", "5000010"], \
            "bounds 499980 4999989 inf 5000010 are not all finite numbers"
    if name == "bounds off the points":
        return [d, p, *o, "--bounds", "0", "0", "100", "100"], \
            "bounds 0 0 100 100 hold none of the points (they span 499969.75 4999976.75 to 500029.25 5000026.25)"
    if name == "bounds in the gap":  # inside the extent of the points, but only over the 10 x 10-cell gap
        return [d, p, *o, "--bounds", "500001", "4999986", "500010", "4999995"], \
            ("bounds 500001 4999986 500010 4999995 hold none of the points (they span 499969.75 4999976.75 to "
             "500029.25 5000026.25)")
    if name == "output exists":
        (out / "dsm.tif").write_bytes(b"mine")
        return [d, p, *o], f"{out / 'dsm.tif'}: output exists; pass --overwrite to replace it"
    if name == "points output exists":
        (out / "p.laz").write_bytes(b"mine")
        return [d, p, *o, "--points", out / "p.laz"], f"{out / 'p.laz'}: output exists; pass --overwrite to replace it"
    if name == "hillshade not png":
        return [d, p, *o, "--hillshade", out / "hs.jpg"], f"{out / 'hs.jpg'}: hillshade must be a .png file"
    if name == "negative fill":
        return [d, p, *o, "--fill-holes", "-1"], "--fill-holes must be from 0 to 256 cells, got -1"
    if name == "nodata 0 with fill":
        return [d, p, *o, "--fill-holes", "3", "--nodata", "0"], \
            "--nodata 0 is a value of the 'filled' band (0 or 1) that --fill-holes writes; choose another (e.g. -9999)"
    if name == "nodata beyond float32":
        return [d, p, *o, "--nodata", "1e39"], "--nodata 1e+39 does not fit in the DSM's float32"
    if name == "unknown crs":
        return [d, p, *o, "--crs", "EPSG:99999"], "--crs: unknown CRS 'EPSG:99999'"
    if name == "co without =":
        return [d, p, *o, "--co", "COMPRESS"], "creation option 'COMPRESS' is not KEY=VALUE"
    if name == "co block size":  # 100 would crash GDAL's COG driver, 'abc' or 0 hang it
        return [d, p, *o, "--co", "BLOCKSIZE=100"], \
            "--co BLOCKSIZE=100: the tile size must be a multiple of 16 from 128 to 4096"
    # the rest are GDAL's own words (GDAL 3.10), which GDAL would only warn about and then ignore the option
    if name == "co unknown value":
        return [d, p, *o, "--co", "COMPRESS=ZIP"], \
            "--co: 'ZIP' is an unexpected value for COMPRESS creation option of type string-select"
    if name == "co unknown option":
        return [d, p, *o, "--co", "COMPRESSION=LZW"], "--co: driver COG does not support creation option COMPRESSION"
    if name == "co unknown resampling":  # would fail only when the overviews are built, after all the work
        return [d, p, *o, "--co", "RESAMPLING=SMOOTH"], \
            '--co: GDALGetResampleFunction: Unsupported resampling method "SMOOTH"'
    raise KeyError(name)


BAD_DSM_CASES = ["missing disparity", "unreadable disparity", "disparity of another size", "pair file without P_right",
                 "pair file not YAML", "missing pair file", "bounds text", "bounds reversed", "bounds not finite",
                 "bounds off the points", "bounds in the gap", "output exists", "points output exists",
                 "hillshade not png", "negative fill", "nodata 0 with fill", "nodata beyond float32", "unknown crs",
                 "co without =", "co block size", "co unknown value", "co unknown option", "co unknown resampling"]


@pytest.mark.parametrize("name", BAD_DSM_CASES)
def test_bad_dsm_input_is_one_line_and_leaves_nothing(tmp_path, name):
    (tmp_path / "out").mkdir()
    args, message = bad_dsm_case(tmp_path, name)
    before = {f.name: f.read_bytes() for f in (tmp_path / "out").iterdir()}
    r = dsm(*args, "--points", tmp_path / "out" / "points.laz", "--hillshade", tmp_path / "out" / "hs.png") \
        if name not in ("points output exists", "hillshade not png") else dsm(*args)
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {message}\n")
    assert {f.name: f.read_bytes() for f in (tmp_path / "out").iterdir()} == before


# -- evaluate --dsm ---------------------------------------------------------------------------------------------------


def flat(tmp_path, name, crs="EPSG:32632", transform=GRID15, shape=(34, 40), value=0.0):
    write_geotiff(tmp_path / name, np.full(shape, value, np.float32), transform, crs, float("nan"))
    return tmp_path / name


def bad_evaluate_case(tmp_path, name):
    t = tmp_path
    dsm_path = flat(t, "dsm.tif")
    if name == "reference elsewhere":
        ref = flat(t, "ref.tif", transform=Affine(1.5, 0.0, 600000.0, 0.0, -1.5, 5100000.0))
        return dsm_path, ref, (f"{dsm_path}: does not overlap the reference DSM {ref} (DSM 499969.5 4999975.5 "
                               "500029.5 5000026.5, reference 600000 5099949 600060 5100000: XMIN YMIN XMAX YMAX in "
                               "EPSG:32632)")
    if name == "reference in another crs elsewhere":  # Lambert-93 around Paris; the DSM is in Italy
        ref = flat(t, "ref.tif", crs="EPSG:2154", transform=Affine(1.0, 0.0, 652000.0, 0.0, -1.0, 6862000.0))
        with rasterio.open(dsm_path) as ds:
            b = rasterio.warp.transform_bounds(ds.crs, "EPSG:2154", *ds.bounds, densify_pts=21)
        shown = " ".join(f"{v:.10g}" for v in b)
        return dsm_path, ref, (f"{dsm_path}: does not overlap the reference DSM {ref} (DSM {shown}, reference 652000 "
                               "6861966 652040 6862000: XMIN YMIN XMAX YMAX in EPSG:2154)")
    if name == "reference without crs":
        ref = flat(t, "ref.tif", crs=None)
        return dsm_path, ref, f"{dsm_path}: one DSM has a CRS and the other has none ({ref})"
    if name == "unreadable reference":
        (t / "ref.tif").write_bytes(b"II*\0" + b"\x00" * 100)
        return dsm_path, t / "ref.tif", f"{t / 'ref.tif'}: cannot read DSM (not a raster GDAL reads)"
    if name == "truncated reference":
        big = flat(t, "big.tif", shape=(600, 700))
        with rasterio.open(big) as ds:
            first = int(ds.get_tag_item("BLOCK_OFFSET_0_0", "TIFF", bidx=1))
        (t / "ref.tif").write_bytes(big.read_bytes()[:first + 10])  # the IFDs whole, the tiles cut off
        return dsm_path, t / "ref.tif", f"{t / 'ref.tif'}: cannot read DSM (corrupt or truncated data)"
    if name == "missing reference":
        return dsm_path, t / "none.tif", f"{t / 'none.tif'}: file not found"
    if name == "unreadable dsm":
        (t / "junk.tif").write_bytes(b"\x89PNG" + b"\x00" * 100)
        return t / "junk.tif", flat(t, "ref.tif"), f"{t / 'junk.tif'}: cannot read DSM (not a raster GDAL reads)"
    if name == "missing dsm":
        return t / "none.tif", flat(t, "ref.tif"), f"{t / 'none.tif'}: file not found"
    if name == "reference all nodata":
        return dsm_path, flat(t, "ref.tif", value=np.nan), "the reference DSM has no data in the compared area"
    if name == "bad thresholds":
        return dsm_path, flat(t, "ref.tif"), "--thresholds '0.5,one' is not a comma-separated list of numbers"
    raise KeyError(name)


BAD_EVALUATE_CASES = ["reference elsewhere", "reference in another crs elsewhere", "reference without crs",
                      "unreadable reference", "truncated reference", "missing reference", "unreadable dsm",
                      "missing dsm", "reference all nodata", "bad thresholds"]


@pytest.mark.parametrize("name", BAD_EVALUATE_CASES)
def test_bad_evaluate_dsm_input_is_one_line_and_leaves_nothing(tmp_path, name):
    dsm_path, ref, message = bad_evaluate_case(tmp_path, name)
    out = tmp_path / "out"
    out.mkdir()
    args = ["evaluate", "--dsm", str(dsm_path), str(ref), "--error-map", str(out / "dz.png"), "--json"]
    if name == "bad thresholds":
        args += ["--thresholds", "0.5,one"]
    r = CliRunner().invoke(cli, args)
    assert (r.exit_code, r.output) == (1, f"riverbed: error: {message}\n")
    assert list(out.iterdir()) == []


def test_evaluate_dsm_reference_in_another_crs_is_reprojected(tmp_path):
    """Another CRS is no error: the DSM (UTM 32N, 2 m everywhere) is resampled onto a Web Mercator reference over
    its middle (0 m): every reference cell is compared, all 2 m below."""
    dsm_path = flat(tmp_path, "dsm.tif", value=2.0)
    with rasterio.open(dsm_path) as ds:
        x0, y0, x1, y1 = rasterio.warp.transform_bounds(ds.crs, "EPSG:3857", *ds.bounds)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    ref = flat(tmp_path, "ref.tif", crs="EPSG:3857", transform=Affine(2.0, 0.0, cx - 10, 0.0, -2.0, cy + 10),
               shape=(10, 10))
    r = CliRunner().invoke(cli, ["evaluate", "--dsm", str(dsm_path), str(ref), "--json"])
    assert r.exit_code == 0, r.output
    m = json.loads(r.stdout)
    assert m["n"] == 100 and m["completeness"] == 100.0
    assert m["median"] == pytest.approx(2.0, abs=1e-9) and m["nmad"] == pytest.approx(0.0, abs=1e-9)

