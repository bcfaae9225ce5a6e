"""Disparity map reading and writing: PFM, KITTI / Middlebury PNG, float32 TIFF."""

import struct
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio

from riverbed_cli.errors import RiverbedError
from riverbed_cli.io.disparity import read_disparity, read_disparity_tags, sparse_points, write_disparity

DATA = Path(__file__).parent / "data"
NAN = np.nan


def _asym():
    """3 x 4, every value different, so a flipped or transposed read is caught."""
    d = np.arange(12, dtype=np.float32).reshape(3, 4) + 0.25
    d[0, 1] = NAN
    return d


# --- PFM ------------------------------------------------------------------------------------------

def test_pfm_round_trip_with_nan(tmp_path):
    d = _asym()
    p = tmp_path / "d.pfm"
    write_disparity(p, d)
    out = read_disparity(p)
    assert out.dtype == np.float32 and out.shape == (3, 4)
    np.testing.assert_array_equal(out, d)  # NaN == NaN here
    raw = p.read_bytes()
    header = b"Pf\n4 3\n-1.0\n"
    assert raw[: len(header)] == header
    data = np.frombuffer(raw[len(header):], "<f4").reshape(3, 4)
    np.testing.assert_array_equal(data[0], d[2])  # bottom row first
    assert np.isinf(data[2, 1])  # NaN stored as inf


def test_pfm_little_endian_scale_multiplies(tmp_path):
    rows = np.array([[1, 2, 3], [4, 5, np.inf]], "<f4")  # as stored: bottom row first
    p = tmp_path / "s.pfm"
    p.write_bytes(b"Pf\n3 2\n-2.0\n" + rows.tobytes())
    out = read_disparity(p)
    np.testing.assert_array_equal(out, [[8, 10, NAN], [2, 4, 6]])


def test_pfm_big_endian_bottom_to_top(tmp_path):
    top_to_bottom = np.array([[10, 11, 12, 13], [20, 21, 22, 23], [30, 31, 32, 33]], np.float32)
    stored = top_to_bottom[::-1]
    payload = b"".join(struct.pack(">f", v) for v in stored.ravel())
    p = tmp_path / "be.pfm"
    p.write_bytes(b"Pf\n4 3\n1.0\n" + payload)
    np.testing.assert_array_equal(read_disparity(p), top_to_bottom)
    # Same bytes read as little endian would be garbage: the sign of the scale line matters.
    assert not np.array_equal(np.frombuffer(payload, "<f4").reshape(3, 4)[::-1], top_to_bottom)


def test_pfm_header_on_one_line_and_whitespace_like_data(tmp_path):
    # 32.0 in little endian is 00 00 00 42; 0x0a0a0a0a is whitespace-like bytes: only one byte may be skipped.
    values = np.array([[np.frombuffer(b"\n\n\n\n", "<f4")[0], 32.0]], "<f4")
    p = tmp_path / "w.pfm"
    p.write_bytes(b"Pf 2 1 -1.0\n" + values.tobytes())
    np.testing.assert_array_equal(read_disparity(p), values.astype(np.float32))


def test_pfm_truncated(tmp_path):
    p = tmp_path / "t.pfm"
    p.write_bytes(b"Pf\n3 2\n-1.0\n" + b"\x00" * 10)
    with pytest.raises(RiverbedError) as e:
        read_disparity(p)
    assert str(e.value) == f"{p}: truncated PFM: 3x2 needs 24 data bytes, the file has 10"


def test_pfm_forged_size_refused_before_allocating(tmp_path):
    p = tmp_path / "f.pfm"
    p.write_bytes(b"Pf\n100000 100000\n-1.0\n" + b"\x00" * 16)
    with pytest.raises(RiverbedError, match="truncated PFM: 100000x100000 needs 40000000000 data bytes"):
        read_disparity(p)


def test_pfm_colour_and_garbage(tmp_path):
    p = tmp_path / "c.pfm"
    p.write_bytes(b"PF\n1 1\n-1.0\n" + b"\x00" * 12)
    with pytest.raises(RiverbedError) as e:
        read_disparity(p)
    assert str(e.value) == f"{p}: colour PFM is not a disparity map (expected 'Pf', one channel)"
    g = tmp_path / "g.pfm"
    g.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)
    with pytest.raises(RiverbedError) as e:
        read_disparity(g)
    assert str(e.value) == f"{g}: not a PFM file (it must start with 'Pf')"
    h = tmp_path / "h.pfm"
    h.write_bytes(b"Pf\nabc 2\n-1.0\n" + b"\x00" * 40)
    with pytest.raises(RiverbedError, match="malformed PFM header"):
        read_disparity(h)
    z = tmp_path / "z.pfm"
    z.write_bytes(b"Pf\n1 1\n0\n" + b"\x00" * 4)
    with pytest.raises(RiverbedError, match="scale 0.0"):
        read_disparity(z)


# --- PNG ------------------------------------------------------------------------------------------

def test_png_round_trip(tmp_path):
    d = np.array([[0.0, 0.001, 1.5, 100.123], [NAN, 255.99, 3.14159, 7.0]], np.float32)
    p = tmp_path / "d.png"
    write_disparity(p, d)
    raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    # 0.0 and 0.001 are valid but round to 0: stored as 1 so they stay valid.
    np.testing.assert_array_equal(raw, [[1, 1, 384, 25631], [0, 65533, 804, 1792]])
    out = read_disparity(p)
    assert np.isnan(out[1, 0]) and np.isfinite(out).sum() == 7
    valid = np.isfinite(d)
    assert np.all(np.abs(out[valid] - d[valid]) <= 1 / 256)


def test_png_refuses_negative_and_too_large(tmp_path):
    p = tmp_path / "n.png"
    with pytest.raises(RiverbedError) as e:
        write_disparity(p, np.array([[1.0, -0.5]]))
    assert str(e.value) == f"{p}: negative disparity -0.500 cannot be stored in a KITTI PNG; use .pfm or .tif"
    with pytest.raises(RiverbedError, match="exceeds the KITTI PNG maximum 255.996"):
        write_disparity(p, np.array([[1.0, 256.0]]))
    assert list(tmp_path.iterdir()) == []  # nothing written, no temporary left
    write_disparity(p, np.array([[-np.inf, 3.0]]))  # -inf is invalid, not negative: stored as 0
    np.testing.assert_array_equal(cv2.imread(str(p), cv2.IMREAD_UNCHANGED), [[0, 768]])


def test_png_16bit_custom_scale_and_8bit(tmp_path):
    p16 = tmp_path / "k.png"
    cv2.imwrite(str(p16), np.array([[0, 64, 640]], np.uint16))
    np.testing.assert_array_equal(read_disparity(p16), [[NAN, 0.25, 2.5]])
    np.testing.assert_array_equal(read_disparity(p16, scale=64), [[NAN, 1, 10]])

    p8 = tmp_path / "m.png"
    cv2.imwrite(str(p8), np.array([[0, 4, 221]], np.uint8))
    with pytest.raises(RiverbedError) as e:
        read_disparity(p8)
    assert str(e.value) == (
        f"{p8}: 8-bit PNG disparity: give its scale (e.g. --gt-scale 4 for Middlebury quarter size)"
    )
    np.testing.assert_array_equal(read_disparity(p8, scale=4), [[NAN, 1, 55.25]])
    with pytest.raises(RiverbedError, match="scale must be a positive number"):
        read_disparity(p8, scale=0)


def test_colour_png_refused(tmp_path):
    p = tmp_path / "c.png"
    cv2.imwrite(str(p), np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(RiverbedError, match="colour PNG .3 channels. is not a disparity map"):
        read_disparity(p, scale=1)


def test_real_middlebury_cones_gt():
    p = DATA / "cones" / "disp2.png"
    d = read_disparity(p, scale=4)
    assert d.shape == (375, 450) and d.dtype == np.float32
    assert int(np.isnan(d).sum()) == 5429  # value 0 = unknown
    assert d[100, 200] == 86 / 4
    assert d[0, 0] == 68 / 4
    assert np.nanmax(d) == 55.0
    assert np.nansum(d.astype(np.float64)) == 21908588 / 4


# --- TIFF -----------------------------------------------------------------------------------------

def test_tif_exact_round_trip_and_tags(tmp_path):
    rng = np.random.default_rng(1)
    d = (rng.random((300, 260)) * 200 - 20).astype(np.float32)  # negative disparities are fine in TIFF
    d[5, 7] = NAN
    d[6, 7] = np.inf  # non-finite: invalid
    p = tmp_path / "d.TIFF"
    write_disparity(p, d, tags={"matcher": "census-sgm", "d_min": -20})
    out = read_disparity(p)
    expected = d.copy()
    expected[6, 7] = NAN
    np.testing.assert_array_equal(out, expected)
    tags = read_disparity_tags(p)
    assert tags["matcher"] == "census-sgm" and tags["d_min"] == "-20"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(p) as ds:
            assert ds.dtypes == ("float32",)
            assert np.isnan(ds.nodata)
            assert ds.compression.name.lower() == "deflate"
            assert ds.profile["tiled"] and ds.block_shapes == [(256, 256)]
            assert ds.crs is None


def test_tif_write_emits_no_warning(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_disparity(tmp_path / "w.tif", np.ones((3, 3), np.float32))
        read_disparity(tmp_path / "w.tif")


def test_tif_nodata_value_becomes_nan(tmp_path):
    p = tmp_path / "n.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(p, "w", driver="GTiff", width=3, height=1, count=1, dtype="int16",
                           nodata=-9999) as ds:
            ds.write(np.array([[5, -9999, -3]], np.int16), 1)
    np.testing.assert_array_equal(read_disparity(p), [[5, NAN, -3]])


def test_tif_corrupt_and_not_a_tiff(tmp_path):
    good = tmp_path / "good.tif"
    write_disparity(good, np.random.default_rng(2).random((600, 600)).astype(np.float32))
    cut = tmp_path / "cut.tif"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(RiverbedError) as e:
        read_disparity(cut)
    assert str(e.value) == f"{cut}: cannot read TIFF disparity (corrupt or truncated data)"
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"junk" * 100)
    with pytest.raises(RiverbedError) as e:
        read_disparity(junk)
    assert str(e.value) == f"{junk}: cannot read TIFF disparity (not a TIFF rasterio reads)"


def test_tags_of_other_formats_are_empty(tmp_path):
    p = tmp_path / "d.pfm"
    write_disparity(p, np.ones((2, 2)))
    assert read_disparity_tags(p) == {}


# --- common ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["d.pfm", "d.png", "d.tif"])
def test_refuses_to_overwrite(tmp_path, name):
    p = tmp_path / name
    write_disparity(p, np.full((2, 3), 2.0))
    before = p.read_bytes()
    with pytest.raises(RiverbedError) as e:
        write_disparity(p, np.full((2, 3), 9.0))
    assert str(e.value) == f"{p}: output exists; pass --overwrite to replace it"
    assert p.read_bytes() == before
    write_disparity(p, np.full((2, 3), 9.0), overwrite=True)
    np.testing.assert_array_equal(read_disparity(p), np.full((2, 3), 9.0))
    assert sorted(x.name for x in tmp_path.iterdir()) == [name]  # no temporary left behind


def test_unsupported_extension(tmp_path):
    p = tmp_path / "d.xyz"
    p.write_bytes(b"x")
    with pytest.raises(RiverbedError) as e:
        read_disparity(p)
    assert str(e.value) == f"{p}: unsupported disparity format '.xyz' (use .pfm, .png or .tif)"
    with pytest.raises(RiverbedError) as e:
        write_disparity(tmp_path / "o.JPG", np.ones((2, 2)))
    assert str(e.value) == (
        f"{tmp_path / 'o.JPG'}: unsupported disparity format '.jpg' (use .pfm, .png or .tif)"
    )


def test_missing_file_and_bad_shape(tmp_path):
    p = tmp_path / "none.pfm"
    with pytest.raises(RiverbedError) as e:
        read_disparity(p)
    assert str(e.value) == f"{p}: file not found"
    with pytest.raises(RiverbedError, match=r"2-D array \(H x W\), got shape \(2, 2, 3\)"):
        write_disparity(tmp_path / "x.pfm", np.ones((2, 2, 3)))


def test_sparse_points():
    d = np.full((3, 4), NAN, np.float32)
    d[0, 3], d[2, 1] = 5.5, -1.0
    rows, cols, values = sparse_points(d)
    np.testing.assert_array_equal(rows, [0, 2])
    np.testing.assert_array_equal(cols, [3, 1])
    np.testing.assert_array_equal(values, [5.5, -1.0])
    assert values.dtype == np.float32
