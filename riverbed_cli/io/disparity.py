"""Read and write disparity maps: Middlebury PFM, KITTI 16-bit PNG (and Middlebury 8-bit PNG), float32 TIFF.

Conventions
-----------
- In memory a disparity map is ``float32``, ``H x W``, indexed ``[row, col]``, on the left (reference) image,
  with ``d = x_left - x_right`` in pixels and ``NaN`` for invalid / unknown.
- On disk the invalid marker is the format's own: ``inf`` in PFM, ``0`` in PNG, ``NaN`` (the nodata value) in
  TIFF.
- The format is chosen by the file extension, case-insensitively: ``.pfm``, ``.png``, ``.tif`` / ``.tiff``.
"""

import warnings
from pathlib import Path

import numpy as np
import rasterio

from ..errors import RiverbedError
from .atomic import atomic_output, c_stderr_silenced
from .images import check_complete, imread_quiet, write_png_file
from .paths import require_file

_PNG_MAX = 65535 / 256  # largest disparity a KITTI 16-bit PNG holds
_WHITESPACE = b" \t\r\n\v\f"


def disparity_format(path):
    """``pfm``, ``png`` or ``tif`` by the file's extension; :class:`RiverbedError` for any other."""
    ext = Path(path).suffix.lower()
    if ext == ".pfm":
        return "pfm"
    if ext == ".png":
        return "png"
    if ext in (".tif", ".tiff"):
        return "tif"
    shown = ext if ext else "(no extension)"
    raise RiverbedError(f"unsupported disparity format '{shown}' (use .pfm, .png or .tif)", path)


def _check_input(path):
    kind = disparity_format(Path(path))
    path = require_file(path)
    return path, kind


def read_disparity(path, scale=None):
    """Read a disparity map as float32 ``H x W`` with NaN for invalid pixels.

    Parameters
    ----------
    path : str or path-like
        ``.pfm``, ``.png``, ``.tif`` or ``.tiff`` (case-insensitive).
    scale : float, optional
        Stored value per pixel of disparity: ``d = stored / scale``.

        - PNG, 16-bit: default 256 (KITTI). 8-bit: required, e.g. 4 for Middlebury 2003 quarter-size GT
          (Cones, Teddy), 2 for the half-size 2005/2006 scenes. In both, 0 means unknown.
        - PFM and TIFF: default 1 (values are disparities already).

    Returns
    -------
    disp : ndarray of float32, ``H x W``
        Disparity in pixels, ``d = x_left - x_right``; NaN where unknown.

    Notes
    -----
    PFM: the header is ``Pf`` (one channel; ``PF``, three channels, is refused), ``width height``, then a
    scale line whose sign gives the byte order (negative: little endian, positive: big endian). Rows are
    stored bottom to top. The magnitude of the scale line is honoured as a multiplier:
    ``d = stored * |scale|`` (Middlebury and SceneFlow files use 1.0, so this only matters for files that set
    another factor). Non-finite values (Middlebury writes ``inf``) become NaN. The ``scale`` argument then
    divides as for the other formats.

    TIFF: band 1 as float32; the nodata value, if set, and non-finite values become NaN.
    """
    path, kind = _check_input(path)
    if scale is not None and not (np.isfinite(scale) and scale > 0):
        raise RiverbedError(f"disparity scale must be a positive number, got {scale}", path)
    if kind == "pfm":
        disp = _read_pfm(path)
    elif kind == "png":
        disp = _read_png(path, scale)
        scale = None  # already applied
    else:
        disp = _read_tif(path)
    if scale is not None and scale != 1:
        disp /= np.float32(scale)
    return disp


def _read_pfm(path):
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(256)

    # Header: four whitespace-separated tokens, then exactly one whitespace byte before the binary data (the
    # data may itself begin with bytes that look like whitespace, so no more may be skipped).
    tokens, pos = [], 0
    while len(tokens) < 4:
        while pos < len(head) and head[pos] in _WHITESPACE:
            pos += 1
        start = pos
        while pos < len(head) and head[pos] not in _WHITESPACE and pos - start <= 32:
            pos += 1
        complete = start < pos < len(head) and head[pos] in _WHITESPACE
        if not tokens and (not complete or head[start:pos] not in (b"Pf", b"PF")):
            raise RiverbedError("not a PFM file (it must start with 'Pf')", path)
        if not complete:
            raise RiverbedError("truncated or malformed PFM header (expected 'Pf', width, height, scale)",
                                path)
        tokens.append(head[start:pos])
    offset = pos + 1

    if tokens[0] == b"PF":
        raise RiverbedError("colour PFM is not a disparity map (expected 'Pf', one channel)", path)
    try:
        width, height = int(tokens[1]), int(tokens[2])
        pfm_scale = float(tokens[3])
    except ValueError:
        raise RiverbedError("malformed PFM header (width, height and scale must be numbers)", path) from None
    if width <= 0 or height <= 0:
        raise RiverbedError(f"malformed PFM header: size {width}x{height}", path)
    if not np.isfinite(pfm_scale) or pfm_scale == 0:
        raise RiverbedError(
            f"malformed PFM header: scale {pfm_scale} (must be non-zero; its sign is the byte order)", path
        )

    # Check the size before allocating, so a forged header cannot ask for gigabytes.
    needed = width * height * 4
    available = size - offset
    if available < needed:
        raise RiverbedError(
            f"truncated PFM: {width}x{height} needs {needed} data bytes, the file has {max(available, 0)}",
            path,
        )
    dtype = "<f4" if pfm_scale < 0 else ">f4"
    data = np.fromfile(path, dtype=dtype, count=width * height, offset=offset)
    # Stored bottom row first.
    disp = data.reshape(height, width)[::-1].astype(np.float32)
    if abs(pfm_scale) != 1:
        disp *= np.float32(abs(pfm_scale))
    disp[~np.isfinite(disp)] = np.nan
    return disp


def _read_png(path, scale):
    check_complete(path)  # a truncated PNG is refused before libpng reads it
    raw = imread_quiet(path)
    if raw is None:
        raise RiverbedError("cannot read PNG disparity (not a PNG OpenCV reads)", path)
    if raw.ndim != 2:
        raise RiverbedError(
            f"colour PNG ({raw.shape[2]} channels) is not a disparity map "
            "(expected one 8- or 16-bit channel)",
            path,
        )
    if raw.dtype == np.uint8:
        if scale is None:
            raise RiverbedError(
                "8-bit PNG disparity: give its scale (e.g. --gt-scale 4 for Middlebury quarter size)", path
            )
    elif raw.dtype == np.uint16:
        scale = 256.0 if scale is None else scale
    else:
        raise RiverbedError(f"PNG disparity must be 8- or 16-bit, got {raw.dtype}", path)
    disp = raw.astype(np.float32) / np.float32(scale)
    disp[raw == 0] = np.nan
    return disp


def _open_tif(path):
    try:
        return rasterio.open(path)
    except MemoryError:
        raise
    except Exception:  # noqa: BLE001 - GDAL drivers raise many types; any of them means "cannot read"
        raise RiverbedError("cannot read TIFF disparity (not a TIFF rasterio reads)", path) from None


def _read_tif(path):
    """Band 1 of a real-valued TIFF as float32 ``(H, W)``, with nodata, inf and NaN as NaN."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with _open_tif(path) as ds:
            if ds.dtypes[0].startswith("complex"):
                raise RiverbedError(f"TIFF disparity must be real-valued, got {ds.dtypes[0]}", path)
            try:
                raw = ds.read(1)
            except MemoryError:
                raise
            except Exception:  # noqa: BLE001 - as in _open_tif
                raise RiverbedError("cannot read TIFF disparity (corrupt or truncated data)", path) from None
            nodata = ds.nodata
    out = raw.astype(np.float32)
    invalid = ~np.isfinite(out)
    if nodata is not None and not np.isnan(nodata):
        invalid |= raw == nodata  # compare in the stored type: exact
    out[invalid] = np.nan
    return out


def read_disparity_tags(path):
    """Dataset tags of a TIFF disparity map (``{}`` for PFM and PNG, which have none).

    Returns
    -------
    tags : dict of str to str
    """
    path, kind = _check_input(path)
    if kind != "tif":
        return {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with _open_tif(path) as ds:
            return dict(ds.tags())


def write_disparity(path, disp, overwrite=False, tags=None):
    """Write a disparity map, format by extension, atomically (no half-written file on failure).

    Parameters
    ----------
    path : str or path-like
        ``.pfm``, ``.png``, ``.tif`` or ``.tiff``.
    disp : array_like, ``H x W``
        Disparity in pixels (``d = x_left - x_right``); NaN (or any non-finite value) is invalid.
    overwrite : bool
        Replace an existing file; otherwise an existing ``path`` raises :class:`RiverbedError`.
    tags : dict, optional
        TIFF only: written as dataset tags, keys and values as strings. Ignored for PFM and PNG.

    Notes
    -----
    - PFM: ``Pf``, little endian (scale line ``-1.0``), rows bottom to top, invalid as ``inf``. Exact.
    - PNG: KITTI 16-bit, ``round(d * 256)``, invalid as 0; a valid disparity that would round to 0 is stored
      as 1 (1/256 px) so it stays valid. Negative disparities and disparities above 65535/256 (~256 px) cannot
      be stored and raise :class:`RiverbedError`. Precision 1/512 px.
    - TIFF: float32, nodata NaN, DEFLATE with the floating-point predictor, 256 x 256 tiles when both sides
      are at least 256 px, no georeference. Exact.
    """
    path = Path(path)
    kind = disparity_format(path)
    disp = np.asarray(disp)
    if disp.ndim != 2:
        raise RiverbedError(f"disparity must be a 2-D array (H x W), got shape {disp.shape}", path)
    if disp.dtype.kind not in "fiub":
        raise RiverbedError(f"disparity must be numeric, got {disp.dtype}", path)
    disp = disp.astype(np.float32)
    valid = np.isfinite(disp)

    if kind == "png":
        out = _encode_png(path, disp, valid)
        with atomic_output(path, overwrite) as tmp:
            write_png_file(tmp, out)
    elif kind == "pfm":
        data = np.where(valid, disp, np.float32(np.inf)).astype("<f4")[::-1]
        header = f"Pf\n{disp.shape[1]} {disp.shape[0]}\n-1.0\n".encode("ascii")
        with atomic_output(path, overwrite) as tmp, open(tmp, "wb") as f:
            f.write(header)
            f.write(np.ascontiguousarray(data).tobytes())
    else:
        _write_tif(path, np.where(valid, disp, np.float32(np.nan)), overwrite, tags)


def _encode_png(path, disp, valid):
    d = disp[valid].astype(np.float64)
    if d.size and d.min() < 0:
        raise RiverbedError(
            f"negative disparity {d.min():.3f} cannot be stored in a KITTI PNG; use .pfm or .tif", path
        )
    if d.size and d.max() > _PNG_MAX:
        raise RiverbedError(
            f"disparity {d.max():.3f} exceeds the KITTI PNG maximum {_PNG_MAX:.3f} (65535/256); "
            "use .pfm or .tif",
            path,
        )
    out = np.zeros(disp.shape, np.uint16)
    # Valid values that round to 0 would read back as invalid: keep them valid at 1/256 px.
    out[valid] = np.maximum(np.round(d * 256), 1).astype(np.uint16)
    return out


#: How disparity TIFFs are compressed: DEFLATE on the floats' bytes (predictor 3), at level 1 and on every core -
#: 10 ms for the 740 x 500 speed pair's map against 31 ms at GDAL's level 6 on one core, for a file 1.3 % larger.
TIFF_COMPRESSION = {"compress": "deflate", "predictor": 3, "zlevel": 1, "num_threads": "ALL_CPUS"}


def write_range_map(path, lo, hi, overwrite=False, tags=None):
    """Write a per-pixel disparity range (the ``--range-map`` :func:`~riverbed_cli.io.windowed.open_range_map`
    reads): a 2-band float32 TIFF of min and max disparity (px, ``d = x_left - x_right``; NaN: no range, the match's
    nominal range there), atomically, compressed as disparity TIFFs."""
    path = Path(path)
    if disparity_format(path) != "tif":
        raise RiverbedError("range map must be written to a .tif file", path)
    lo, hi = (np.asarray(a, np.float32) for a in (lo, hi))
    if lo.ndim != 2 or lo.shape != hi.shape:
        raise RiverbedError(f"range map bands must be two H x W arrays, got {lo.shape} and {hi.shape}", path)
    bands = np.stack([lo, hi])
    _write_tif(path, np.where(np.isfinite(bands), bands, np.float32(np.nan)), overwrite, tags)


def _write_tif(path, disp, overwrite, tags):
    # disp: (H, W), or (bands, H, W)
    bands = disp[None] if disp.ndim == 2 else disp
    height, width = bands.shape[1:]
    profile = {
        "driver": "GTiff",
        "width": width,
        "height": height,
        "count": bands.shape[0],
        "dtype": "float32",
        "nodata": float("nan"),
        "BIGTIFF": "IF_SAFER",
        **TIFF_COMPRESSION,
    }
    if height >= 256 and width >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    with atomic_output(path, overwrite) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        try:
            with c_stderr_silenced(), rasterio.open(tmp, "w", **profile) as ds:
                ds.write(bands)
                if tags:
                    ds.update_tags(**{str(k): str(v) for k, v in tags.items()})
        except rasterio.errors.RasterioError as e:
            raise RiverbedError(f"cannot write TIFF ({e})", path) from None


def sparse_points(disp):
    """Row, column and value of every finite pixel of a (sparse) disparity map.

    Returns
    -------
    rows, cols : ndarray of intp
        Pixel indices in row-major order.
    values : ndarray of float32
        Disparities at those pixels.
    """
    disp = np.asarray(disp)
    rows, cols = np.nonzero(np.isfinite(disp))
    return rows, cols, disp[rows, cols].astype(np.float32)
