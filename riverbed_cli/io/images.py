"""Read rectified stereo images and turn them into the float arrays the matchers use.

Conventions
-----------
- Images are ``H x W`` (grey) or ``H x W x 3`` (RGB order, not OpenCV's BGR), indexed ``[row, col]``.
- :func:`read_image` returns the stored samples unchanged: ``uint8`` or ``uint16``.
- :func:`to_grey` and :func:`to_guide` return ``float32`` on a 0..255 scale. 16-bit data is divided by
  ``2 ** (bits - 8)`` where ``bits`` is the *effective* bit depth (see :func:`effective_bits`), so 12-bit
  data in a 16-bit container keeps its contrast instead of being squeezed into 0..16.
"""

import os
import struct
import warnings
from pathlib import Path

import cv2
import numpy as np
import rasterio
from llvmlite import ir
from numba import prange, types
from numba.extending import intrinsic
from rasterio.enums import ColorInterp

from ..errors import RiverbedError
from ..runtime.kernel import kernel
from ..settings import MAX_PIXELS  # noqa: F401  (the default pixel limit; --max-pixels raises it)
from .atomic import c_stderr_silenced
from .paths import require_file

_UNREADABLE = "cannot read image (not a format OpenCV or rasterio reads)"
_CORRUPT = "cannot read image data (corrupt or truncated file)"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SOI, JPEG_EOI = b"\xff\xd8\xff", b"\xff\xd9"
#: The first four bytes of a TIFF or BigTIFF file.
TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def read_image(path, max_pixels=MAX_PIXELS):
    """Read an 8- or 16-bit grey or RGB image, samples unchanged.

    OpenCV reads most formats (``IMREAD_UNCHANGED``: no EXIF rotation, no depth conversion); files it cannot
    decode are read with rasterio (e.g. JPEG 2000, ERDAS .img), bands becoming channels. TIFF is read with
    rasterio first (OpenCV would mix a multi-band GeoTIFF down to grey) and with OpenCV if rasterio cannot open
    it or it is a palette image. A truncated or corrupt file is an error, never an image with missing rows: PNG
    and JPEG are checked for their end (:func:`check_complete`) and are never handed to rasterio when OpenCV
    refuses them (GDAL fills what it cannot decode with zeros); a TIFF whose strips or tiles rasterio cannot
    read is refused.

    Parameters
    ----------
    path : str or path-like
        Image file.
    max_pixels : int, optional
        Refuse images with more than this many pixels (width x height), checked from the header before
        decoding for PNG and TIFF, and after decoding otherwise. None: no limit.

    Returns
    -------
    img : ndarray of uint8 or uint16
        ``H x W`` (grey) or ``H x W x 3`` (RGB order). An alpha channel is dropped; with four or more bands
        from rasterio the first three are taken as RGB.

    Raises
    ------
    RiverbedError
        Missing, non-regular, unreadable, truncated or corrupt file, unsupported sample type (float, signed), or
        too many pixels.
    """
    path = require_file(path)
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] == PNG_SIGNATURE and head[12:16] == b"IHDR":
        # Cheap size check before decoding.
        width, height = struct.unpack(">II", head[16:24])
        check_pixels(path, height, width, max_pixels)
    check_complete(path, head)

    img = None
    if head[:4] in TIFF_MAGIC:
        # TIFF goes to rasterio first: OpenCV silently mixes a 3-band MINISBLACK TIFF (the usual multi-band
        # GeoTIFF) down to one grey channel, and rasterio checks the size before reading the pixels.
        img = _read_rasterio(path, max_pixels, required=False)
    if img is None:
        img = imread_quiet(path)
        if img is not None:
            img = _from_opencv(img)
    if img is None:
        kind = _opencv_kind(head)
        if kind:
            raise RiverbedError(f"cannot decode {kind} (corrupt or truncated data)", path)
        img = _read_rasterio(path, max_pixels, required=True)
    check_pixels(path, img.shape[0], img.shape[1], max_pixels)
    if img.dtype not in (np.uint8, np.uint16):
        raise RiverbedError(f"unsupported image sample type {img.dtype} (need 8- or 16-bit unsigned)", path)
    return np.ascontiguousarray(img)


def imread_quiet(path):
    """``cv2.imread(path, IMREAD_UNCHANGED)``, None when OpenCV cannot decode the file; what libpng, libjpeg or
    libtiff print on stderr about a corrupt file is discarded (the caller reports it in one line)."""
    try:
        with c_stderr_silenced():
            return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        return None


def _opencv_kind(head):
    """``"PNG"`` or ``"JPEG"`` when the file's first bytes say so, else None."""
    if head[:8] == PNG_SIGNATURE:
        return "PNG"
    if head[:3] == JPEG_SOI:
        return "JPEG"
    return None


def check_complete(path, head=None):
    """Raise :class:`RiverbedError` if a PNG or JPEG file is cut short; other files pass unchecked.

    Decoders fill what a truncated file lacks (libjpeg with grey, GDAL's PNG driver with zeros) or fail with a
    message of their own on stderr; this looks at the file's structure only, without decoding. PNG: the chain
    of chunk headers (length, type) must reach an ``IEND`` chunk inside the file. JPEG: the file must end with
    the end-of-image marker ``FFD9`` (trailing NUL or whitespace padding allowed).

    Parameters
    ----------
    path : path-like
        The file (a regular file).
    head : bytes, optional
        Its first bytes, if already read (at least 8).
    """
    path = Path(path)
    with open(path, "rb") as f:
        if head is None:
            head = f.read(8)
        kind = _opencv_kind(head)
        if kind is None:
            return
        size = os.fstat(f.fileno()).st_size
        if kind == "PNG" and not _png_reaches_iend(f, size):
            raise RiverbedError("truncated PNG (its chunks end before an IEND chunk)", path)
        if kind == "JPEG":
            f.seek(max(0, size - 4096))
            if not f.read().rstrip(b"\x00\t\n\r ").endswith(JPEG_EOI):
                raise RiverbedError("truncated JPEG (no end-of-image marker FFD9 at its end)", path)


def _png_reaches_iend(f, size):
    # Chunks are 4-byte length, 4-byte type, data, 4-byte CRC; following the lengths costs one small read per
    # chunk (a few dozen for a megapixel image).
    pos = 8
    while pos + 12 <= size:
        f.seek(pos)
        length, ctype = struct.unpack(">I4s", f.read(8))
        pos += 12 + length
        if ctype == b"IEND":
            return pos <= size
    return False


def check_pixels(path, height, width, max_pixels):
    if max_pixels is not None and height * width > max_pixels:
        raise RiverbedError(
            f"image is {height}x{width} = {height * width} pixels, more than the limit {max_pixels}; "
            "raise --max-pixels to allow it",
            path,
        )


def _from_opencv(img):
    # OpenCV gives BGR(A); grey+alpha comes as 2 channels.
    if img.ndim == 3:
        channels = img.shape[2]
        if channels == 1 or channels == 2:
            img = img[:, :, 0]
        elif channels == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        else:
            img = cv2.cvtColor(img[:, :, :4], cv2.COLOR_BGRA2RGB)
    return img


def _read_rasterio(path, max_pixels, required):
    """Bands as channels; None (if not ``required``) when rasterio cannot open it or it is a palette image.

    A file rasterio opens but cannot read (a TIFF with truncated strips or tiles) is an error either way: OpenCV
    would fail on it too, with lines of its own on stderr.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            ds = rasterio.open(path)
    except MemoryError:
        raise
    except Exception:  # noqa: BLE001 - GDAL drivers raise many types; any of them means "cannot read"
        if not required:
            return None
        raise RiverbedError(_UNREADABLE, path) from None
    with ds:
        if not required and ds.colorinterp[0] == ColorInterp.palette:
            return None  # OpenCV applies the colour table; rasterio would give the indices
        check_pixels(path, ds.height, ds.width, max_pixels)
        # 1 band: grey; 2: grey + alpha; 3: RGB; 4+: RGB + alpha/NIR/...
        bands = [1] if ds.count < 3 else [1, 2, 3]
        try:
            data = ds.read(bands)
        except MemoryError:
            raise
        except Exception:  # noqa: BLE001 - as above
            raise RiverbedError(_CORRUPT, path) from None
    if data.shape[0] == 1:
        return data[0]
    return np.moveaxis(data, 0, -1)


def effective_bits(*images):
    """Effective bit depth of one or more images: ``max(8, ceil(log2(max + 1)))``.

    ``uint8`` images are 8 bits. For ``uint16`` the largest sample decides, so 12-bit camera data stored in
    16-bit containers (max <= 4095) is 12 bits. Pass *both* images of a stereo pair so they are scaled alike.

    Parameters
    ----------
    *images : ndarray of uint8 or uint16

    Returns
    -------
    bits : int
        8 to 16.
    """
    bits = 8
    for img in images:
        img = np.asarray(img)
        if img.dtype == np.uint16 and img.size:
            # int.bit_length() == ceil(log2(m + 1)) for integers m >= 0, without float rounding.
            bits = max(bits, int(img.max()).bit_length())
        elif img.dtype not in (np.uint8, np.uint16) and img.dtype.kind != "f":
            # float images are already on a 0..255 scale (e.g. tiles of a 16-bit pair): no bits to find
            raise RiverbedError(f"effective bit depth needs uint8, uint16 or float images, got {img.dtype}")
    return bits


def _to_float255(img, bits):
    """Samples as float32 on a 0..255 scale (float input is taken as already on that scale)."""
    img = np.asarray(img)
    if img.dtype == np.uint8 and img.size >= 4096 and img.flags.c_contiguous:
        # OpenCV's conversion (SIMD) in 0.4-0.5x NumPy's time, exact (every uint8 is a float32): one channel wide, so
        # that the scale is not a per-channel Scalar, and not for tiny arrays, which OpenCV's binding may take for one
        flat = img.reshape(img.shape[0], -1)
        return cv2.multiply(flat, 1.0, dtype=cv2.CV_32F).reshape(img.shape)
    if img.dtype == np.uint8:
        return img.astype(np.float32)
    if img.dtype == np.uint16:
        if bits is None:
            bits = effective_bits(img)
        # A power of two: exact in float32.
        return img.astype(np.float32) * np.float32(2.0 ** (8 - bits))
    if img.dtype.kind == "f":
        return img.astype(np.float32)
    raise RiverbedError(f"image must be uint8, uint16 or float, got {img.dtype}")


#: ITU-R BT.601 luma weights of R, G and B in float32 (OpenCV's ``COLOR_RGB2GRAY`` coefficients)
LUMA = (np.float32(0.299), np.float32(0.587), np.float32(0.114))


_GREY_LANES = 16  # pixels per vector step of _grey_kernel


def _fma(builder, a, b, c):
    # a * b + c rounded once, float32 or a vector of them (llvm.fma: the FMA instruction, or libm's correctly
    # rounded fmaf on a CPU without it)
    t = a.type
    name = f"llvm.fma.v{t.count}f32" if isinstance(t, ir.VectorType) else "llvm.fma.f32"
    fn = builder.module.globals.get(name) or ir.Function(builder.module, ir.FunctionType(t, [t, t, t]), name)
    return builder.call(fn, [a, b, c])


@intrinsic
def _fma32(typingctx, a, b, c):
    # _fma of three float32 scalars
    sig = types.float32(types.float32, types.float32, types.float32)
    return sig, lambda context, builder, signature, args: _fma(builder, *args)


@intrinsic
def _grey_lanes(typingctx, img, i, out, o, scale, cr, cg, cb):
    # _GREY_LANES pixels at once: the interleaved samples img[i:i + 3 * n] split into R, G and B by shuffles, then
    # fma(B, cb, fma(R, cr, G * cg)) of the samples times scale, to out[o:o + n] (float32), lane by lane the scalar
    # loop's operations
    sig = types.void(img, i, out, o, scale, cr, cg, cb)
    n = _GREY_LANES

    def codegen(context, builder, signature, args):
        img_, i_, out_, o_, scale_, cr_, cg_, cb_ = args
        elem = context.get_value_type(signature.args[0].dtype)
        f32 = ir.FloatType()
        vf = ir.VectorType(f32, n)
        src = builder.gep(context.make_array(signature.args[0])(context, builder, img_).data, [i_])
        v = builder.load(builder.bitcast(src, ir.VectorType(elem, 3 * n).as_pointer()),
                         align=context.get_abi_sizeof(elem))
        undef = ir.Constant(v.type, ir.Undefined)

        def channel(c):
            picks = ir.Constant(ir.VectorType(ir.IntType(32), n), [3 * k + c for k in range(n)])
            x = builder.shuffle_vector(v, undef, picks)
            x = x if isinstance(elem, ir.FloatType) else builder.uitofp(x, vf)
            return builder.fmul(x, _splat(builder, scale_, vf))

        r, g, b = (channel(c) for c in range(3))
        grey = _fma(builder, r, _splat(builder, cr_, vf), builder.fmul(g, _splat(builder, cg_, vf)))
        grey = _fma(builder, b, _splat(builder, cb_, vf), grey)
        dst = builder.gep(context.make_array(signature.args[2])(context, builder, out_).data, [o_])
        builder.store(grey, builder.bitcast(dst, vf.as_pointer()), align=4)
        return context.get_dummy_value()

    return sig, codegen


def _splat(builder, value, vty):
    # value in every lane of vty (io sits below matching.vector_ir, which has the same for the matchers)
    one = builder.insert_element(ir.Constant(vty, ir.Undefined), value, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(one, ir.Constant(vty, ir.Undefined),
                                  ir.Constant(ir.VectorType(ir.IntType(32), vty.count), [0] * vty.count))


@kernel(parallel=True)
def _grey_kernel(img, scale, cr, cg, cb):
    # rows in parallel: fma(B, cb, fma(R, cr, G * cg)) of the samples times scale (a power of two: exact); img is
    # H x W x 3 C-contiguous, a row's pixels _GREY_LANES at a time, its last ones one by one
    H, W = img.shape[0], img.shape[1]
    out = np.empty((H, W), np.float32)
    flat, grey = img.reshape(-1), out.reshape(-1)
    full = W // _GREY_LANES * _GREY_LANES
    for y in prange(H):
        for x in range(0, full, _GREY_LANES):
            _grey_lanes(flat, 3 * (y * W + x), grey, y * W + x, scale, cr, cg, cb)
        row = img[y]
        for x in range(full, W):
            r = np.float32(row[x, 0]) * scale
            g = np.float32(row[x, 1]) * scale
            b = np.float32(row[x, 2]) * scale
            out[y, x] = _fma32(b, cb, _fma32(r, cr, g * cg))
    return out


def to_grey(img, bits=None):
    """Grey level as float32 on a 0..255 scale, for cost computation.

    Parameters
    ----------
    img : ndarray
        ``H x W`` or ``H x W x 3`` (RGB; a 4th alpha channel is ignored), ``uint8``, ``uint16`` or float
        (float is assumed to be on a 0..255 scale already and is not rescaled).
    bits : int, optional
        Bit depth of 16-bit data. Default: :func:`effective_bits` of ``img`` alone, i.e.
        ``max(8, ceil(log2(max + 1)))``; values are divided by ``2 ** (bits - 8)``. For a stereo pair pass
        ``bits=effective_bits(left, right)`` so both images get the same scaling.

    Returns
    -------
    grey : ndarray of float32, ``H x W``
        RGB is combined with the ITU-R BT.601 luma weights (:data:`LUMA`) in float32 as ``fma(B, 0.114, fma(R,
        0.299, G * 0.587))``, each fused multiply-add rounded once (not rounded to integers): the values OpenCV's
        vector code gives for ``cv2.COLOR_RGB2GRAY``, at every pixel. OpenCV's scalar code for the last pixels of a
        row (how many depends on the CPU's vector width) and without SIMD rounds otherwise (a fifth of the pixels of
        a 740 px wide image differ by an ulp there), which made the census bits depend on the machine; this
        is the same on every machine, in one pass over the samples (the 8-bit speed pair's two greys 0.75 ms ->
        0.2 ms in a fresh process).
    """
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        if img.dtype == np.uint8:
            scale = 1.0
        elif img.dtype == np.uint16:
            scale = 2.0 ** (8 - (effective_bits(img) if bits is None else bits))
        elif img.dtype.kind == "f":
            img, scale = np.asarray(img, np.float32), 1.0
        else:
            raise RiverbedError(f"image must be uint8, uint16 or float, got {img.dtype}")
        return _grey_kernel(np.ascontiguousarray(img[:, :, :3]), np.float32(scale), *LUMA)
    f = _to_float255(img, bits)
    if f.ndim == 2:
        return np.ascontiguousarray(f)
    if f.ndim == 3 and f.shape[2] == 1:
        return np.ascontiguousarray(f[:, :, 0])
    raise RiverbedError(f"image must be HxW or HxWx3, got shape {f.shape}")


def to_guide(img, bits=None):
    """Colour (or grey) as float32 ``H x W x C`` on a 0..255 scale, for colour-similarity weights.

    Parameters
    ----------
    img : ndarray
        ``H x W`` or ``H x W x 3`` (RGB; a 4th alpha channel is dropped), ``uint8``, ``uint16`` or float.
    bits : int, optional
        As in :func:`to_grey` (same 16-bit scaling).

    Returns
    -------
    guide : ndarray of float32, ``H x W x C``
        ``C = 1`` for grey input, ``C = 3`` (RGB) for colour input.
    """
    f = _to_float255(img, bits)
    if f.ndim == 2:
        return np.ascontiguousarray(f[:, :, None])
    if f.ndim == 3 and f.shape[2] in (1, 3):
        return np.ascontiguousarray(f)
    if f.ndim == 3 and f.shape[2] == 4:
        return np.ascontiguousarray(f[:, :, :3])
    raise RiverbedError(f"image must be HxW or HxWx3, got shape {f.shape}")


def guide_source(img, bits=None):
    """The left image for the guides' colour similarities: a ``uint8`` grey or RGB image as it is (``H x W x C``, a
    view), which :func:`~riverbed_cli.matching.guidance.homogeneous_owners` reads without a float copy and the other
    guides convert as they did (:func:`~riverbed_cli.matching.guidance.guide_image`); any other image as
    :func:`to_guide` makes it."""
    img = np.asarray(img)
    layout = img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 3))
    if img.dtype == np.uint8 and img.flags.c_contiguous and layout:
        return img[:, :, None] if img.ndim == 2 else img
    return to_guide(img, bits)


def check_pair(left, right, left_path=None, right_path=None):
    """Raise :class:`RiverbedError` (naming ``right_path``) if the two images differ in height or width.

    Rectified pairs must have the same size; the number of channels may differ (grey and colour can be
    matched).
    """
    if left.shape[:2] != right.shape[:2]:
        (hl, wl), (hr, wr) = left.shape[:2], right.shape[:2]
        left_name = f"; left image {left_path}" if left_path is not None else ""
        raise RiverbedError(
            f"left and right images differ in size: {hl}x{wl} vs {hr}x{wr} (height x width{left_name})",
            right_path,
        )


def has_mask(ds):
    """True when a rasterio dataset has a valid area (alpha, mask band or nodata), not only valid pixels."""
    return not all(flags == [rasterio.enums.MaskFlags.all_valid] for flags in ds.mask_flag_enums)


def read_valid_area(path):
    """The valid area of an image file: (H, W) bool, True where the pixel shows the scene, from its alpha channel
    (PNG grey + alpha or RGBA; TIFF alpha band, mask band or nodata, as GDAL gives them); None when the file has
    none (every pixel valid). The area a rectified frame's source covers (``riverbed rectify`` writes it as alpha).
    """
    path = require_file(path)
    with open(path, "rb") as f:
        head = f.read(26)
    if head[:8] == PNG_SIGNATURE:
        if len(head) < 26 or head[25] not in (4, 6):  # IHDR colour type: 4 grey + alpha, 6 RGBA
            return None
        img = imread_quiet(path)
        if img is None or img.ndim != 3 or img.shape[2] not in (2, 4):
            return None
        valid = img[:, :, -1] > 0
        return None if valid.all() else valid
    if head[:4] in TIFF_MAGIC:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                with rasterio.open(path) as ds:
                    if not has_mask(ds):
                        return None
                    valid = ds.dataset_mask() > 0
        except MemoryError:
            raise
        except Exception:  # noqa: BLE001 - GDAL drivers raise many types; any of them means "cannot read"
            raise RiverbedError(_CORRUPT, path) from None
        return None if valid.all() else valid
    return None


def write_png_file(path, img, valid=None):
    """Write ``img`` (uint8/uint16, H x W, or H x W x 3 in RGB order) as PNG with OpenCV; one-line error on failure.
    ``valid`` ((H, W) bool, optional): the image's valid area, written as its alpha channel (full scale where
    True, 0 elsewhere; :func:`read_valid_area`).

    Writes ``path`` directly: callers wrap it in :func:`~riverbed_cli.io.atomic.atomic_output`.
    """
    img = np.asarray(img)
    out = cv2.cvtColor(img, cv2.COLOR_RGB2BGR) if img.ndim == 3 else img
    if valid is not None:
        alpha = np.where(valid, np.iinfo(img.dtype).max, 0).astype(img.dtype)
        # OpenCV encodes 1, 3 or 4 channels (and decodes grey + alpha as 4): a grey image goes as grey RGBA
        out = np.dstack([out if out.ndim == 3 else np.dstack([out] * 3), alpha])
    try:
        ok, data = cv2.imencode(".png", out)
    except cv2.error:
        ok = False
    if not ok:
        raise RiverbedError("cannot write PNG (the encoder refused the image)", path)
    # encoded in memory and written by Python, whose writes raise on a full disk (OpenCV's return no error)
    with open(path, "wb") as f:
        f.write(data.tobytes())


def header_size(path):
    """``(W, H)`` of a raster from its header (GDAL), without decoding the pixels; None when GDAL cannot open it
    (the caller then reads it the usual way, with its one-line errors)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                return ds.width, ds.height
    except rasterio.errors.RasterioError:
        return None
