"""LiDAR reader (riverbed_cli.io.lidar): real LAS/LAZ/COPC files against laspy, and malformed input.

The files in tests/data/lidar are byte-for-byte copies from the laspy and PDAL test suites (see its MANIFEST.md
and README.md). Malformed files must end in a one-line RiverbedError within 5 s: some of them make plain
laspy/lazrs hang or panic.
"""

import json
import logging
import struct
import subprocess
from pathlib import Path

import laspy
import numpy as np
import pytest
from pyproj import CRS

from riverbed_cli.errors import RiverbedError
from riverbed_cli.io.lidar import iter_lidar, lidar_info, read_lidar, resolve_crs
from conftest import PYTHON

DATA = Path(__file__).parent / "data" / "lidar"
BOUND_S = 5.0  # robustness bound: a malformed file must be refused within this many seconds

# Readable copies: (LAS version, point format, CRS as EPSG code or name, None for none).
READABLE = {
    "1.0_0.las": ("1.0", 0, 26915),
    "1.1_1.las": ("1.1", 1, 26915),
    "1.2_3.las": ("1.2", 3, 26915),
    "1.2-empty-geotiff-vlrs.las": ("1.2", 1, None),
    "1_4_w_evlr.las": ("1.4", 6, "NAD83(HARN) / New Mexico Central (ftUS)"),
    "1_4_w_evlr.laz": ("1.4", 6, "NAD83(HARN) / New Mexico Central (ftUS)"),
    "append-bug.laz": ("1.4", 8, 2154),
    "autzen.las": ("1.2", 1, 2994),
    "autzen_trim.laz": ("1.2", 3, "NAD_1983_HARN_Lambert_Conformal_Conic"),
    "bad-geotiff-keys.las": ("1.0", 1, 32617),
    "fullwave.laz": ("1.4", 10, 32723),
    "gps-time-nan.las": ("1.2", 1, None),
    "lots_of_vlr.las": ("1.1", 1, None),
    "no-points.las": ("1.2", 3, 4269),
    "simple.copc.laz": ("1.4", 7, "NAD83 / Oregon LCC (m) + NAVD88 height (ftUS)"),
    "simple.las": ("1.2", 3, None),
    "simple.laz": ("1.2", 3, None),
    "simple1_3.las": ("1.3", 4, None),
    "synthetic_test.las": ("1.2", 3, None),
    "test1_4.las": ("1.4", 6, "NAD83(HARN) / New Mexico Central (ftUS)"),
    "unregistered_extra_bytes.las": ("1.4", 6, None),
    "warsaw_small.las": ("1.2", 3, None),  # its WKT VLR is empty: a warning, no CRS
}

# Malformed (or, for the LASzip 1.2r0 file, unsupported) copies and the exact message after "path: ".
MALFORMED = {
    # VLR count 1,069,128,089 with no room for any: plain laspy loops for ever.
    "garbage_nVariableLength.las":
        "malformed LAS header: 1069128089 VLRs declared, but only 0 bytes lie between the header and the "
        "point data",
    # Header says 1065 points, the file ends after the header (laspy silently returns 0 points).
    "1.2-no-points.las":
        "truncated LAS: the header declares 1065 points of 34 bytes from byte 229 (36439 bytes), the file "
        "has 229",
    # LASzip 1.2r0 pointwise compression: lazrs panics ("Variable-size chunks, but no chunk table").
    "simple-laszip-compressor-version-1.2r0.laz":
        "unsupported LAZ compressor 1 (pointwise, LASzip 1.x); re-compress it with LASzip 2 or later",
}


# Refusals run in a child process with a timeout: if a regression lets a malformed file through to laspy or
# lazrs, the test fails (hang, abort, huge allocation) instead of hanging or killing the whole test run.
_CHILD = r"""
import json, sys, time
from riverbed_cli.errors import RiverbedError
from riverbed_cli.io import lidar
out = []
for fn, path in json.loads(sys.argv[1]):
    t0 = time.monotonic()
    try:
        result = getattr(lidar, fn)(path)
        if fn == "iter_lidar":
            list(result)
        out.append({"error": "no error raised"})
    except RiverbedError as e:
        out.append({"msg": str(e), "path": e.path, "elapsed": time.monotonic() - t0})
    except BaseException as e:
        out.append({"error": f"{type(e).__name__}: {e}"})
print(json.dumps(out))
"""


def _refuse_all(calls):
    """Run (function name, path) calls in a child; each must raise a one-line RiverbedError naming the path
    within BOUND_S seconds (timed with time.monotonic in the child). Returns the messages."""
    calls = [(fn, str(path)) for fn, path in calls]
    try:
        proc = subprocess.run([*PYTHON, "-c", _CHILD, json.dumps(calls)], check=False,
                              capture_output=True, text=True, timeout=30 + 2 * BOUND_S * len(calls))
    except subprocess.TimeoutExpired:
        pytest.fail(f"reader hung on {calls}")
    assert proc.returncode == 0, f"child died (rc {proc.returncode}): {proc.stderr[-2000:]}"
    results = json.loads(proc.stdout.strip().splitlines()[-1])
    messages = []
    for (fn, path), r in zip(calls, results):
        assert "error" not in r, f"{fn}({path}): {r['error']}"
        assert r["elapsed"] < BOUND_S, f"{fn}({path}) took {r['elapsed']:.1f} s"
        assert "\n" not in r["msg"] and r["path"] == path
        messages.append(r["msg"])
    return messages


def _refused(fn, path):
    return _refuse_all([(fn, path)])[0]


def _laspy_crs(path):
    try:
        return laspy.read(path).header.parse_crs()
    except Exception:  # noqa: BLE001 - e.g. warsaw_small.las: empty WKT -> CRSError
        return None


# ---------------------------------------------------------------------------------------------------------
# The copied set


def test_copied_set_is_what_the_tests_expect():
    on_disk = {p.name for p in DATA.iterdir() if p.suffix in (".las", ".laz")}
    assert on_disk == set(READABLE) | set(MALFORMED) | {"bad_vlr_count.las"}
    assert sum(p.stat().st_size for p in DATA.iterdir()) < 3 * 2**20
    versions = {v for v, _, _ in READABLE.values()}
    formats = {f for _, f, _ in READABLE.values()}
    assert versions == {"1.0", "1.1", "1.2", "1.3", "1.4"}
    assert formats >= {0, 1, 3, 4, 6, 7, 8, 10}


@pytest.mark.parametrize("name", sorted(READABLE))
def test_readable_file_matches_laspy(name):
    path = DATA / name
    version, point_format, _ = READABLE[name]
    las = laspy.read(path)
    info = lidar_info(path)
    pts = read_lidar(path)

    assert (info.version, info.point_format) == (version, point_format)
    assert info.point_count == len(las.points) == las.header.point_count
    np.testing.assert_array_equal(info.mins, las.header.mins)
    np.testing.assert_array_equal(info.maxs, las.header.maxs)
    np.testing.assert_array_equal(info.scales, las.header.scales)
    np.testing.assert_array_equal(info.offsets, las.header.offsets)
    assert info.has_classification

    xyz = pts["xyz"]
    assert xyz.dtype == np.float64 and xyz.shape == (len(las.points), 3)
    ref = np.column_stack([las.x, las.y, las.z]).reshape(-1, 3)
    np.testing.assert_array_equal(xyz, ref)  # exact: same arithmetic as laspy, never via float32
    if len(ref):
        np.testing.assert_array_equal(xyz.min(axis=0), ref.min(axis=0))
        np.testing.assert_array_equal(xyz.max(axis=0), ref.max(axis=0))
    assert pts["classification"].dtype == np.uint8
    np.testing.assert_array_equal(pts["classification"], np.asarray(las.classification))
    assert pts["intensity"].dtype == np.uint16
    np.testing.assert_array_equal(pts["intensity"], np.asarray(las.intensity))

    has_rgb = "red" in las.point_format.dimension_names
    assert info.has_rgb == has_rgb
    if has_rgb:
        assert pts["rgb"].dtype == np.uint16 and pts["rgb"].shape == (len(las.points), 3)
        np.testing.assert_array_equal(pts["rgb"], np.column_stack([las.red, las.green, las.blue]).reshape(-1, 3))
    else:
        assert pts["rgb"] is None


@pytest.mark.parametrize("name", sorted(READABLE))
def test_chunked_reading_equals_one_chunk(name):
    path = DATA / name
    whole = list(iter_lidar(path, chunk_size=10**7))
    chunks = list(iter_lidar(path, chunk_size=1000))
    n = lidar_info(path).point_count
    assert len(whole) == (1 if n else 0)
    assert [len(c["xyz"]) for c in chunks] == [min(1000, n - i) for i in range(0, n, 1000)]
    if n:
        for key in ("xyz", "classification", "intensity"):
            np.testing.assert_array_equal(np.concatenate([c[key] for c in chunks]), whole[0][key])
        if whole[0]["rgb"] is None:
            assert all(c["rgb"] is None for c in chunks)
        else:
            np.testing.assert_array_equal(np.concatenate([c["rgb"] for c in chunks]), whole[0]["rgb"])


def test_multi_chunk_laz_read_across_laz_chunk_boundaries():
    # autzen_trim.laz holds 3 LASzip chunks of 50,000 points: read in pieces that straddle them.
    path = DATA / "autzen_trim.laz"
    ref = laspy.read(path)
    chunks = list(iter_lidar(path, chunk_size=33_333))
    assert [len(c["xyz"]) for c in chunks] == [33_333, 33_333, 33_333, 10_001]
    np.testing.assert_array_equal(np.concatenate([c["xyz"] for c in chunks]),
                                  np.column_stack([ref.x, ref.y, ref.z]))


@pytest.mark.parametrize("name", sorted(READABLE))
def test_crs_matches_laspy_and_pyproj(name):
    info = lidar_info(DATA / name)
    expected = READABLE[name][2]
    ref = _laspy_crs(DATA / name)
    if expected is None:
        assert info.crs is None and ref is None
        assert resolve_crs(info) is None
    else:
        assert isinstance(info.crs, CRS) and info.crs == ref
        assert (info.crs.to_epsg() if isinstance(expected, int) else info.crs.name) == expected
        assert resolve_crs(info) == info.crs


def test_crs_from_wkt_and_from_geotiff_keys():
    # test1_4.las has only a WKT VLR; autzen.las only GeoTIFF keys; simple.las nothing.
    wkt_only = laspy.read(DATA / "test1_4.las").vlrs
    assert [type(v).__name__ for v in wkt_only][:1] == ["WktCoordinateSystemVlr"]
    assert lidar_info(DATA / "test1_4.las").crs.name == "NAD83(HARN) / New Mexico Central (ftUS)"
    assert "GeoKeyDirectoryVlr" in [type(v).__name__ for v in laspy.read(DATA / "autzen.las").vlrs]
    assert lidar_info(DATA / "autzen.las").crs.to_epsg() == 2994
    assert lidar_info(DATA / "simple.las").crs is None


def test_unparseable_crs_is_no_crs_with_a_warning(caplog):
    with caplog.at_level(logging.WARNING, logger="riverbed_cli.io.lidar"):
        info = lidar_info(DATA / "warsaw_small.las")
    assert info.crs is None
    assert "cannot parse the CRS stated in the file" in caplog.text


def test_resolve_crs_override():
    info = lidar_info(DATA / "simple.las")
    assert resolve_crs(info, "EPSG:2154").to_epsg() == 2154
    assert resolve_crs(lidar_info(DATA / "autzen.las"), CRS.from_epsg(26910)).to_epsg() == 26910
    with pytest.raises(RiverbedError) as exc:
        resolve_crs(info, "EPSG:99999999")
    assert str(exc.value) == "unknown CRS 'EPSG:99999999'"
    with pytest.raises(RiverbedError) as exc:
        resolve_crs(info, "not a crs")
    assert str(exc.value) == "unknown CRS 'not a crs'"
    # iter_lidar checks its crs argument before reading anything.
    with pytest.raises(RiverbedError, match="unknown CRS 'EPSG:0'"):
        iter_lidar(DATA / "simple.las", crs="EPSG:0")


def test_empty_las_keeps_dtypes():
    pts = read_lidar(DATA / "no-points.las")
    assert pts["xyz"].shape == (0, 3) and pts["xyz"].dtype == np.float64
    assert pts["rgb"].shape == (0, 3) and pts["classification"].dtype == np.uint8


def test_coordinates_are_float64_world_values():
    # UTM-size coordinates at 0.01 m: float32 would lose them, so they must arrive as exact float64.
    pts = read_lidar(DATA / "autzen.las")
    las = laspy.read(DATA / "autzen.las")
    expected = las.X * las.header.scales[0] + las.header.offsets[0]
    np.testing.assert_array_equal(pts["xyz"][:, 0], expected)
    assert not np.array_equal(pts["xyz"][:, 0].astype(np.float32).astype(np.float64), expected)


# ---------------------------------------------------------------------------------------------------------
# Malformed copies


@pytest.mark.parametrize("name", sorted(MALFORMED))
def test_malformed_file_is_refused_quickly(name):
    path = DATA / name
    messages = _refuse_all([(fn, path) for fn in ("lidar_info", "read_lidar", "iter_lidar")])
    assert messages == [f"{path}: {MALFORMED[name]}"] * 3


def test_overstated_vlr_count_is_read_with_a_warning(caplog):
    """bad_vlr_count.las (PDAL): the header declares 3 VLRs, 2 fit before the point data, the 10 points are intact.
    laspy reads it; so do we, with a one-line warning naming the file and what is wrong."""
    path = DATA / "bad_vlr_count.las"
    with caplog.at_level(logging.WARNING, logger="riverbed_cli.io.lidar"):
        pts = read_lidar(path)
    las = laspy.read(path)
    np.testing.assert_array_equal(pts["xyz"], np.column_stack([las.x, las.y, las.z]))
    assert len(pts["xyz"]) == 10
    assert [r.getMessage() for r in caplog.records] == [
        f"{path}: the LAS header declares 3 VLRs but only 2 fit before the point data (byte 429); the points are read"]


# ---------------------------------------------------------------------------------------------------------
# Hand-made bad input


def _patched(tmp_path, name, patches, new_name=None):
    data = bytearray((DATA / name).read_bytes())
    for offset, fmt, value in patches:
        struct.pack_into(fmt, data, offset, value)
    out = tmp_path / (new_name or name)
    out.write_bytes(bytes(data))
    return out


def test_truncated_las(tmp_path):
    data = (DATA / "simple.las").read_bytes()
    path = tmp_path / "half.las"
    path.write_bytes(data[: len(data) // 2])
    assert _refused("read_lidar", path) == (
        f"{path}: truncated LAS: the header declares 1065 points of 34 bytes from byte 227 (36437 bytes), "
        "the file has 18218"
    )


def test_truncated_laz(tmp_path):
    data = (DATA / "simple.laz").read_bytes()
    path = tmp_path / "half.laz"
    path.write_bytes(data[: len(data) // 2])
    assert _refused("read_lidar", path) == (
        f"{path}: truncated LAZ: chunk table at byte 18203, past the end of the file (9108 bytes)"
    )


def test_truncated_header(tmp_path):
    path = tmp_path / "short.las"
    path.write_bytes((DATA / "simple.las").read_bytes()[:100])
    assert _refused("lidar_info", path) == f"{path}: truncated LAS header (100 bytes; a LAS header has at least 227)"


def test_forged_point_count_las(tmp_path):
    # LAS 1.4: 64-bit count at byte 247.
    path = _patched(tmp_path, "test1_4.las", [(247, "<Q", 10**12)])
    assert _refused("iter_lidar", path) == (
        f"{path}: truncated LAS: the header declares 1000000000000 points of 30 bytes from byte 2305 "
        "(30000000002305 bytes), the file has 32305"
    )
    # LAS 1.2: the 32-bit count at byte 107.
    path = _patched(tmp_path, "simple.las", [(107, "<I", 2**32 - 1)])
    assert _refused("iter_lidar", path) == (
        f"{path}: truncated LAS: the header declares 4294967295 points of 34 bytes from byte 227 "
        "(146028888257 bytes), the file has 36437"
    )


def test_forged_point_count_laz(tmp_path):
    path = _patched(tmp_path, "1_4_w_evlr.laz", [(247, "<Q", 10**12)])
    assert _refused("read_lidar", path) == (
        f"{path}: malformed LAZ: the header declares 1000000000000 points, but the chunk table lists "
        "1 chunk(s) of 50000"
    )
    # COPC uses variable-size chunks: the count must equal the chunk table's total.
    path = _patched(tmp_path, "simple.copc.laz", [(247, "<Q", 1066)])
    assert _refused("read_lidar", path) == (
        f"{path}: malformed LAZ: the header declares 1066 points, the chunk table holds 1065"
    )


def test_forged_laz_chunk_table(tmp_path):
    # Chunk count at chunk table + 4 (simple.laz: table at byte 18203). lazrs would reserve 16 bytes per
    # declared chunk up front (64 GiB here) and abort the process when that fails.
    path = _patched(tmp_path, "simple.laz", [(18207, "<I", 2**32 - 1)])
    assert _refused("read_lidar", path) == (
        f"{path}: malformed LAZ: chunk table lists 4294967295 chunks for 17862 compressed bytes"
    )
    # Chunk size in the LASzip VLR (simple.laz: VLR data at 227 + 54, chunk size at +12).
    path = _patched(tmp_path, "simple.laz", [(227 + 54 + 12, "<I", 2**32 - 2)])
    assert _refused("read_lidar", path) == f"{path}: malformed LAZ: chunk size 4294967294 points"


def test_forged_laz_layer_size(tmp_path):
    # simple.copc.laz: point data at 1709, chunk 1 at 1709 + 8; its first layer size follows the raw first
    # point (36 bytes) and the point count (4). lazrs would zero-fill a 4 GiB buffer before failing.
    path = _patched(tmp_path, "simple.copc.laz", [(1709 + 8 + 36 + 4, "<I", 2**32 - 1)])
    assert _refused("read_lidar", path) == (
        f"{path}: malformed LAZ: the layers of chunk 1 of 65 overrun its 458 bytes"
    )


def test_garbage_vlr_count(tmp_path):
    path = _patched(tmp_path, "simple.las", [(100, "<I", 1000)])
    assert _refused("lidar_info", path) == (
        f"{path}: malformed LAS header: 1000 VLRs declared, but only 0 bytes lie between the header and the "
        "point data"
    )
    path = _patched(tmp_path, "simple.las", [(100, "<I", 2**32 - 1)], "max.las")
    assert "4294967295 VLRs declared" in _refused("lidar_info", path)
    # One VLR too many, where the VLRs end exactly at the point data: an overstated count, read with a warning
    # (as bad_vlr_count.las; the points are intact).
    path = _patched(tmp_path, "autzen.las", [(100, "<I", 5)])
    assert read_lidar(path)["xyz"].shape == read_lidar(DATA / "autzen.las")["xyz"].shape
    # A VLR whose length runs past the point data: found by walking them, refused.
    path = _patched(tmp_path, "autzen.las", [(227 + 20, "<H", 60000)], "long_vlr.las")
    assert _refused("lidar_info", path) == (
        f"{path}: malformed LAS header: VLR 1 of 4 (at byte 227) does not fit before the point data (byte 1994)"
    )


def test_garbage_evlr_count(tmp_path):
    path = _patched(tmp_path, "1_4_w_evlr.las", [(243, "<I", 2**32 - 1)])
    assert _refused("lidar_info", path) == (
        f"{path}: malformed LAS header: 4294967295 EVLRs declared, but only 76 bytes follow byte 32305"
    )


def test_offset_past_end(tmp_path):
    path = _patched(tmp_path, "simple.las", [(96, "<I", 2**32 - 1)])
    assert _refused("lidar_info", path) == (
        f"{path}: truncated LAS: point data starts at byte 4294967295, past the end of the file (36437 bytes)"
    )


def test_kitti_bin_wrong_size(tmp_path):
    path = tmp_path / "scan.bin"
    path.write_bytes(b"\0" * 17)
    assert _refused("read_lidar", path) == (
        f"{path}: not a KITTI Velodyne scan: 17 bytes is not a multiple of 16 (float32 x, y, z, reflectance)"
    )


def test_text_file_named_las(tmp_path):
    path = tmp_path / "notes.las"
    path.write_text("x,y,z\n1,2,3\n")
    assert _refused("read_lidar", path) == f"{path}: not a LAS/LAZ file (it must start with 'LASF')"


def test_empty_file(tmp_path):
    for name in ("empty.las", "empty.laz", "empty.bin"):
        path = tmp_path / name
        path.write_bytes(b"")
        assert _refused("lidar_info", path) == f"{path}: empty file"


def test_missing_file_directory_and_extension(tmp_path):
    path = tmp_path / "missing.las"
    assert _refused("lidar_info", path) == f"{path}: file not found"
    folder = tmp_path / "folder.laz"
    folder.mkdir()
    assert _refused("iter_lidar", folder) == f"{folder}: not a file"
    xyz = tmp_path / "cloud.xyz"
    xyz.write_text("1 2 3\n")
    assert _refused("read_lidar", xyz) == (
        f"{xyz}: unsupported point cloud format '.xyz' (use .las, .laz, KITTI .bin, or a DSM .tif/.hgt)"
    )


def test_bad_chunk_size():
    with pytest.raises(ValueError, match="chunk_size"):
        iter_lidar(DATA / "simple.las", chunk_size=0)


# ---------------------------------------------------------------------------------------------------------
# KITTI .bin


def test_kitti_bin_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    raw = rng.normal(0, 20, (2500, 4)).astype("<f4")
    path = tmp_path / "000000.bin"
    raw.tofile(path)
    info = lidar_info(path)
    assert (info.point_count, info.version, info.point_format, info.crs) == (2500, "kitti-bin", -1, None)
    assert (info.has_rgb, info.has_classification, info.scales, info.offsets) == (False, False, None, None)
    np.testing.assert_array_equal(info.mins, raw[:, :3].min(axis=0).astype(np.float64))
    np.testing.assert_array_equal(info.maxs, raw[:, :3].max(axis=0).astype(np.float64))
    pts = read_lidar(path)
    assert pts["xyz"].dtype == np.float64 and pts["intensity"].dtype == np.float32
    np.testing.assert_array_equal(pts["xyz"], raw[:, :3].astype(np.float64))
    np.testing.assert_array_equal(pts["intensity"], raw[:, 3])
    assert pts["rgb"] is None and not pts["classification"].any() and pts["classification"].dtype == np.uint8
    chunks = list(iter_lidar(path, chunk_size=1000))
    assert [len(c["xyz"]) for c in chunks] == [1000, 1000, 500]
    np.testing.assert_array_equal(np.concatenate([c["xyz"] for c in chunks]), pts["xyz"])


def test_kitti_bin_non_finite(tmp_path):
    raw = np.zeros((40, 4), "<f4")
    raw[17, 1] = np.nan
    path = tmp_path / "nan.bin"
    raw.tofile(path)
    assert _refused("read_lidar", path) == f"{path}: non-finite coordinates at point 17"


# ---------------------------------------------------------------------------------------------------------
# The whole shared data folder (RIVERBED_DATA)

SHARED_SETS = ("lidar_laspy_testdata", "lidar_pdal_testdata", "lidar_ign_lidarhd_nimes")
SHARED_MALFORMED = {
    "lidar_pdal_testdata/test/data/las/garbage_nVariableLength.las": MALFORMED["garbage_nVariableLength.las"],
    "lidar_pdal_testdata/test/data/las/permutations/1.2-no-points.las": MALFORMED["1.2-no-points.las"],
    "lidar_pdal_testdata/test/data/laz/simple-laszip-compressor-version-1.2r0.laz":
        MALFORMED["simple-laszip-compressor-version-1.2r0.laz"],
}
IGN = "lidar_ign_lidarhd_nimes/data/subsampled_nimes.laz"
KITTI_BIN = "kitti_object_stereo_lidar_stereorcnn/demo/lidar.bin"


@pytest.mark.data
def test_every_shared_las_file(shared_data):
    files = sorted(p for s in SHARED_SETS for p in (shared_data / s).rglob("*") if p.suffix in (".las", ".laz"))
    assert len(files) == 54
    malformed = [p for p in files if p.relative_to(shared_data).as_posix() in SHARED_MALFORMED]
    assert len(malformed) == len(SHARED_MALFORMED)
    messages = _refuse_all([("read_lidar", p) for p in malformed])
    assert messages == [f"{p}: {SHARED_MALFORMED[p.relative_to(shared_data).as_posix()]}" for p in malformed]
    failures, coloured = [], 0
    for path in files:
        if path in malformed:
            continue
        las = laspy.read(path)
        pts = read_lidar(path)
        # every point, in the file's order, as laspy reads the whole file: coordinates (scaled and offset),
        # classes, and colours where the point format has them
        ref = np.column_stack([las.x, las.y, las.z]).reshape(-1, 3)
        same = pts["xyz"].shape == ref.shape and np.array_equal(pts["xyz"], ref)
        same = same and np.array_equal(pts["classification"], np.asarray(las.classification))
        if "red" in las.point_format.dimension_names:
            coloured += 1
            same = same and pts.get("rgb") is not None and np.array_equal(
                pts["rgb"], np.column_stack([las.red, las.green, las.blue]))
        if not same:
            failures.append(f"{path}: {pts['xyz'].shape} differs from laspy's {ref.shape}")
    assert not failures, "\n".join(failures)
    assert coloured > 5, coloured


@pytest.mark.data
def test_ign_lidar_hd_laz(shared_data, caplog):
    path = shared_data / IGN
    with caplog.at_level(logging.WARNING, logger="riverbed_cli.io.lidar"):
        info = lidar_info(path)
    las = laspy.read(path)
    assert info.point_count == len(las.points) == 404_500
    assert (info.version, info.point_format, info.has_rgb) == ("1.2", 3, True)
    # laspy finds no CRS: the GeoTIFF keys hold a user-defined CRS, named only in the citation text.
    assert info.crs is None and las.header.parse_crs() is None
    assert "citation 'RGF93 / Lambert-93'" in caplog.text
    assert resolve_crs(info, "EPSG:2154").to_epsg() == 2154
    pts = read_lidar(path)
    ref = np.column_stack([las.x, las.y, las.z])
    np.testing.assert_array_equal(pts["xyz"].min(axis=0), ref.min(axis=0))
    np.testing.assert_array_equal(pts["xyz"].max(axis=0), ref.max(axis=0))
    np.testing.assert_array_equal(pts["xyz"], ref)
    assert set(np.unique(pts["classification"]).tolist()) == {1, 28}
    np.testing.assert_array_equal(pts["rgb"], np.column_stack([las.red, las.green, las.blue]))


@pytest.mark.data
def test_kitti_velodyne_bin(shared_data):
    path = shared_data / KITTI_BIN
    raw = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    info = lidar_info(path)
    assert info.point_count == 103_344 == len(raw)
    pts = read_lidar(path)
    np.testing.assert_array_equal(pts["xyz"], raw[:, :3].astype(np.float64))
    np.testing.assert_array_equal(pts["intensity"], raw[:, 3])
    np.testing.assert_array_equal(info.mins, pts["xyz"].min(axis=0))
    np.testing.assert_array_equal(info.maxs, pts["xyz"].max(axis=0))
