"""Image reading and the grey / guide conversions."""

import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio

from riverbed_cli.errors import RiverbedError
from riverbed_cli.io.images import check_pair, effective_bits, read_image, to_grey, to_guide

DATA = Path(__file__).parent / "data"


def _rgb(h=5, w=7, dtype=np.uint8, top=255):
    rng = np.random.default_rng(0)
    return rng.integers(0, top + 1, size=(h, w, 3)).astype(dtype)


def test_read_rgb8_is_rgb_order(tmp_path):
    rgb = _rgb()
    rgb[0, 0] = (255, 0, 0)  # pure red in RGB
    p = tmp_path / "c.png"
    assert cv2.imwrite(str(p), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    img = read_image(p)
    assert img.dtype == np.uint8 and img.shape == (5, 7, 3)
    np.testing.assert_array_equal(img, rgb)
    assert tuple(img[0, 0]) == (255, 0, 0)


def test_read_grey8(tmp_path):
    grey = _rgb()[:, :, 0]
    p = tmp_path / "g.png"
    cv2.imwrite(str(p), grey)
    img = read_image(p)
    assert img.dtype == np.uint8 and img.shape == (5, 7)
    np.testing.assert_array_equal(img, grey)


def test_read_grey16(tmp_path):
    grey = _rgb(dtype=np.uint16, top=4095)[:, :, 0]
    grey[0, 0] = 65535
    p = tmp_path / "g16.png"
    cv2.imwrite(str(p), grey)
    img = read_image(p)
    assert img.dtype == np.uint16 and img.shape == (5, 7)
    np.testing.assert_array_equal(img, grey)


def test_read_rgb16_tiff_and_alpha_dropped(tmp_path):
    rgb = _rgb(dtype=np.uint16, top=65535)
    p = tmp_path / "c16.tif"
    cv2.imwrite(str(p), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    np.testing.assert_array_equal(read_image(p), rgb)

    rgba = np.dstack([_rgb(), np.full((5, 7), 128, np.uint8)])
    p = tmp_path / "a.png"
    cv2.imwrite(str(p), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
    np.testing.assert_array_equal(read_image(p), rgba[:, :, :3])


def _write_raster(path, bands, driver="GTiff"):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path, "w", driver=driver, width=bands.shape[2], height=bands.shape[1],
                           count=bands.shape[0], dtype=bands.dtype) as ds:
            ds.write(bands)


def test_multiband_geotiff_keeps_bands(tmp_path):
    # OpenCV would mix these three MINISBLACK bands down to grey.
    bands = np.arange(3 * 4 * 5, dtype=np.uint16).reshape(3, 4, 5) * 100
    p = tmp_path / "m.tif"
    _write_raster(p, bands)
    img = read_image(p)
    assert img.dtype == np.uint16 and img.shape == (4, 5, 3)
    np.testing.assert_array_equal(img, np.moveaxis(bands, 0, -1))


def test_rasterio_fallback_for_format_opencv_cannot_read(tmp_path):
    bands = np.arange(4 * 4 * 5, dtype=np.uint8).reshape(4, 4, 5)
    p = tmp_path / "m.img"  # ERDAS Imagine: OpenCV has no decoder for it
    _write_raster(p, bands, driver="HFA")
    assert cv2.imread(str(p), cv2.IMREAD_UNCHANGED) is None
    img = read_image(p)
    np.testing.assert_array_equal(img, np.moveaxis(bands[:3], 0, -1))


def test_read_real_middlebury_pair():
    left = read_image(DATA / "cones" / "im2.png")
    right = read_image(DATA / "cones" / "im6.png")
    assert left.shape == right.shape == (375, 450, 3)
    assert left.dtype == np.uint8
    check_pair(left, right, "im2.png", "im6.png")  # same size: no error


def test_missing_file(tmp_path):
    p = tmp_path / "nope.png"
    with pytest.raises(RiverbedError) as e:
        read_image(p)
    assert str(e.value) == f"{p}: file not found"


def test_unreadable_file(tmp_path):
    p = tmp_path / "junk.png"
    p.write_bytes(b"this is not an image" * 10)
    with pytest.raises(RiverbedError) as e:
        read_image(p)
    assert str(e.value) == f"{p}: cannot read image (not a format OpenCV or rasterio reads)"


def test_float_image_refused(tmp_path):
    p = tmp_path / "f.tif"
    _write_raster(p, np.zeros((1, 3, 4), np.float32))
    with pytest.raises(RiverbedError, match=r"unsupported image sample type float32"):
        read_image(p)


def test_max_pixels(tmp_path):
    p = tmp_path / "big.png"
    cv2.imwrite(str(p), np.zeros((30, 40), np.uint8))
    assert read_image(p, max_pixels=1200).shape == (30, 40)
    with pytest.raises(RiverbedError) as e:
        read_image(p, max_pixels=1199)
    assert str(e.value) == (
        f"{p}: image is 30x40 = 1200 pixels, more than the limit 1199; raise --max-pixels to allow it"
    )
    t = tmp_path / "big.tif"
    _write_raster(t, np.zeros((3, 30, 40), np.uint8))
    with pytest.raises(RiverbedError, match="--max-pixels"):
        read_image(t, max_pixels=1000)


def test_size_mismatch_message():
    left, right = np.zeros((500, 740), np.uint8), np.zeros((500, 741, 3), np.uint8)
    with pytest.raises(RiverbedError) as e:
        check_pair(left, right, "l.png", "r.png")
    assert str(e.value) == (
        "r.png: left and right images differ in size: 500x740 vs 500x741 (height x width; left image l.png)"
    )
    assert e.value.path == "r.png"


def test_to_grey_8bit_unchanged_and_luma():
    grey = np.array([[0, 17, 255]], np.uint8)
    out = to_grey(grey)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, [[0, 17, 255]])
    rgb = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255], [10, 20, 30]]], np.uint8)
    np.testing.assert_allclose(to_grey(rgb), [[0.299 * 255, 0.587 * 255, 0.114 * 255,
                                               0.299 * 10 + 0.587 * 20 + 0.114 * 30]], atol=1e-3)


def _luma_reference(rgb):
    """fma(B, 0.114, fma(R, 0.299, G * 0.587)) in float32, each fused multiply-add rounded once: computed in float64
    (a float32 sample times a float32 weight is exact there) and rounded to float32 (for 8-bit samples the values of
    OpenCV's vector code, every triple)."""
    r, g, b = (rgb[..., c].astype(np.float32).astype(np.float64) for c in range(3))
    cr, cg, cb = (np.float64(np.float32(w)) for w in (0.299, 0.587, 0.114))
    inner = (r * cr + (g * cg).astype(np.float32).astype(np.float64)).astype(np.float32).astype(np.float64)
    return (b * cb + inner).astype(np.float32)


def test_to_grey_is_the_fused_luma_at_every_pixel():
    # every 8-bit RGB triple, in rows of 4096 (the vector steps) and as single columns (the row's last pixels, one by
    # one): the same values
    v = np.arange(256, dtype=np.uint8)
    rgb = np.stack(np.meshgrid(v, v, v, indexing="ij"), -1).reshape(4096, 4096, 3)
    expect = _luma_reference(rgb)
    np.testing.assert_array_equal(to_grey(rgb), expect)
    cols = rgb[:64, :37]
    np.testing.assert_array_equal(np.hstack([to_grey(cols[:, x:x + 1]) for x in range(37)]), expect[:64, :37])
    np.testing.assert_array_equal(to_grey(cols), expect[:64, :37])  # two vector steps and 5 pixels one by one
    # 16-bit and float samples on the same scale, and an alpha channel, give the same values
    np.testing.assert_array_equal(to_grey(cols.astype(np.uint16) * 16), expect[:64, :37])
    np.testing.assert_array_equal(to_grey(cols.astype(np.float64)), expect[:64, :37])
    rgba = np.dstack([cols, np.full(cols.shape[:2], 9, np.uint8)])
    np.testing.assert_array_equal(to_grey(rgba), expect[:64, :37])


def test_to_grey_equals_opencv_vector_code_where_it_runs():
    # OpenCV's COLOR_RGB2GRAY on float32 gives the same values in its vector steps (AVX2, AVX-512: fused
    # multiply-adds); its scalar code for a row's last pixels rounds otherwise. Rows of 64 px: no scalar tail at
    # any vector width.
    if not (cv2.useOptimized() and cv2.checkHardwareSupport(11) and cv2.checkHardwareSupport(12)):  # AVX2, FMA3
        pytest.skip("capability: OpenCV's vector code here is not the AVX2 / AVX-512 one")
    rgb = np.random.default_rng(3).integers(0, 256, (300, 64, 3)).astype(np.uint8)
    np.testing.assert_array_equal(to_grey(rgb), cv2.cvtColor(rgb.astype(np.float32), cv2.COLOR_RGB2GRAY))


def test_to_grey_12bit_in_16bit_container():
    img = np.array([[0, 16, 4095]], np.uint16)  # 12-bit data
    assert effective_bits(img) == 12
    np.testing.assert_array_equal(to_grey(img), [[0, 1, 4095 / 16]])
    # One more level needs 13 bits: divided by 32.
    img13 = np.array([[0, 32, 4096]], np.uint16)
    assert effective_bits(img13) == 13
    np.testing.assert_array_equal(to_grey(img13), [[0, 1, 128]])
    # Full 16-bit range ends near 255; dark 16-bit data (max <= 255) is not scaled at all.
    np.testing.assert_array_equal(to_grey(np.array([[65535]], np.uint16)), [[65535 / 256]])
    np.testing.assert_array_equal(to_grey(np.array([[200]], np.uint16)), [[200]])
    # A pair scaled alike: the joint depth, passed explicitly.
    bits = effective_bits(img, img13)
    assert bits == 13
    np.testing.assert_array_equal(to_grey(img, bits=bits), [[0, 0.5, 4095 / 32]])


def test_to_guide_shapes_and_scaling():
    g = to_guide(np.array([[0, 4095]], np.uint16))
    assert g.shape == (1, 2, 1) and g.dtype == np.float32
    np.testing.assert_array_equal(g[:, :, 0], [[0, 4095 / 16]])
    rgb = _rgb()
    c = to_guide(rgb)
    assert c.shape == (5, 7, 3) and c.dtype == np.float32
    np.testing.assert_array_equal(c, rgb.astype(np.float32))


@pytest.mark.parametrize("shape", [(500, 740, 3), (64, 64, 4), (1, 5000, 3), (4096, 1), (70, 70), (63, 65, 1)])
def test_large_8bit_images_convert_exactly(shape):
    # 8-bit images of 4096 samples and more go through OpenCV's conversion (io.images._to_float255): the same
    # values as NumPy's, every channel, as guide; the grey from the samples, in the input's shape
    img = np.random.default_rng(sum(shape)).integers(0, 256, shape, dtype=np.uint8)
    f = img.astype(np.float32)
    guide = to_guide(img)
    assert guide.dtype == np.float32
    np.testing.assert_array_equal(guide.reshape(f.shape[:2] + (-1,)), f.reshape(f.shape[:2] + (-1,))[:, :, :3])
    grey = to_grey(img)
    assert grey.shape == img.shape[:2] and grey.dtype == np.float32
    if img.ndim == 3 and img.shape[2] >= 3:
        np.testing.assert_array_equal(grey, _luma_reference(img))
    else:
        np.testing.assert_array_equal(grey, f.reshape(f.shape[:2]))
