"""Rasters read and written window by window: :class:`WindowedRaster` (a TIFF sliced like a numpy array),
:class:`TiffSink` (a float32 GeoTIFF written tile by tile), and whole-raster scans that read block by block."""

import os
import warnings

import numpy as np
import rasterio
from rasterio.windows import Window

from ..errors import RiverbedError
from .atomic import c_stderr_silenced
from .disparity import TIFF_COMPRESSION, disparity_format, read_disparity
from .images import TIFF_MAGIC, effective_bits, has_mask, read_image, read_valid_area
from .paths import require_file


class WindowedRaster:
    """A raster file read window by window (rasterio), sliced like a numpy array: ``src[y0:y1, x0:x1]``.

    ``kind="image"``: bands become channels (H x W or H x W x 3, samples unchanged); ``kind="disparity"``: band
    ``band`` (default 1) as float32 with nodata, inf and NaN as NaN; ``kind="valid"``: the image's valid area as
    GDAL gives it (alpha, mask band or nodata), H x W bool. Only what a tile needs is ever in memory.
    """

    def __init__(self, path, kind="image", band=1):
        self.path, self.kind, self.band = str(path), kind, int(band)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                self._ds = rasterio.open(self.path)
        except rasterio.errors.RasterioError as e:
            raise RiverbedError(f"cannot read raster ({str(e).splitlines()[0]})", path) from None
        H, W = self._ds.height, self._ds.width
        self.bands = 1 if kind in ("disparity", "valid") else min(self._ds.count, 3)
        self.shape = (H, W) if self.bands == 1 else (H, W, self.bands)
        self.dtype = np.dtype({"disparity": np.float32, "valid": np.bool_}.get(kind, self._ds.dtypes[0]))
        self.ndim = len(self.shape)

    def __getitem__(self, key):
        rows, cols = key[:2]
        H, W = self.shape[:2]
        y0, y1, _ = rows.indices(H)
        x0, x1, _ = cols.indices(W)
        win = Window(x0, y0, max(0, x1 - x0), max(0, y1 - y0))
        if self.kind == "valid":
            try:
                return self._ds.dataset_mask(window=win) > 0
            except MemoryError:
                raise
            except Exception:  # noqa: BLE001 - as _read
                raise RiverbedError("cannot read image data (corrupt or truncated file)", self.path) from None
        if self.kind == "disparity":
            a = self._read(self.band, win, masked=True).astype(np.float32).filled(np.nan)
            a[~np.isfinite(a)] = np.nan
            return a
        a = self._read(list(range(1, self.bands + 1)), win)
        return a[0] if self.bands == 1 else np.moveaxis(a, 0, -1)

    def _read(self, bands, window, masked=False):
        # GDAL raises on a truncated or corrupt strip or tile with a message that names no file
        try:
            return self._ds.read(bands, window=window, masked=masked)
        except MemoryError:
            raise
        except Exception:  # noqa: BLE001 - GDAL drivers raise many types; any of them means "cannot read"
            what = "image" if self.kind == "image" else "raster"
            raise RiverbedError(f"cannot read {what} data (corrupt or truncated file)", self.path) from None

    def row_blocks(self, rows=512):
        for y in range(0, self.shape[0], rows):
            yield y, self[y:y + rows, 0:self.shape[1]]

    def __getstate__(self):  # dask ships sources to workers: reopen there
        return {"path": self.path, "kind": self.kind, "band": self.band}

    def __setstate__(self, state):
        self.__init__(state["path"], state["kind"], state.get("band", 1))


#: GDAL's block cache while rasters are read and written tile by tile. GDAL's default is 5 % of the machine's memory
#: (1.2 GiB here): a 100 MP tiled match filled it with the inputs' and the output's blocks and peaked at 2016 MiB
#: instead of 1339 MiB. Each tile reads its window once, so a small cache costs no speed.
TILED_CACHE_BYTES = 64 * 2**20


def bounded_raster_cache():
    """A context in which GDAL's block cache holds at most :data:`TILED_CACHE_BYTES` (``GDAL_CACHEMAX`` in the
    environment, in MiB, overrides it)."""
    env = os.environ.get("GDAL_CACHEMAX")
    return rasterio.Env() if env else rasterio.Env(GDAL_CACHEMAX=TILED_CACHE_BYTES)


def valid_area_source(path):
    """The valid area of an image file (:func:`~riverbed_cli.io.images.read_valid_area`) as a source sliced like
    the image: None when every pixel is valid, a :class:`WindowedRaster` of kind ``valid`` for a TIFF (read by
    windows), else an (H, W) bool array."""
    if is_tiff(path):
        src = WindowedRaster(path, "valid")
        return src if has_mask(src._ds) else None
    return read_valid_area(path)


def is_tiff(path):
    """True when the file starts with a TIFF or BigTIFF signature."""
    with open(path, "rb") as f:
        return f.read(4) in TIFF_MAGIC


def open_windowed(path, kind="image"):
    """A :class:`WindowedRaster` for TIFF files (read by windows); other formats are read whole into numpy."""
    if is_tiff(path):
        return WindowedRaster(path, kind)
    return read_disparity(path) if kind == "disparity" else read_image(path)


def open_range_map(path):
    """A range map (``riverbed match --range-map``: a 2-band TIFF of min and max disparity, px,
    ``d = x_left - x_right``; NaN or nodata: no range there) as two :class:`WindowedRaster` bands ``(lo, hi)``, read
    by windows; :class:`RiverbedError` naming the file for anything else."""
    path = require_file(path)
    if disparity_format(path) != "tif" or not is_tiff(path):
        raise RiverbedError("range map must be a 2-band GeoTIFF/TIFF (min and max disparity)", path)
    lo = WindowedRaster(path, "disparity", band=1)
    count = lo._ds.count
    if count != 2:
        raise RiverbedError(f"range map needs 2 bands (min and max disparity), has {count}", path)
    if lo._ds.dtypes[0].startswith("complex"):
        raise RiverbedError(f"range map must be real-valued, got {lo._ds.dtypes[0]}", path)
    return lo, WindowedRaster(path, "disparity", band=2)


def read_range_map(path):
    """A range map (:func:`open_range_map`) read whole: ``(lo, hi)`` float32 ``H x W``."""
    return tuple(band[:, :] for band in open_range_map(path))


def row_blocks(a, rows=512):
    """``(first row, block)`` of an in-memory or windowed raster, ``rows`` rows at a time."""
    if isinstance(a, WindowedRaster):
        yield from a.row_blocks(rows)
    else:
        for y in range(0, a.shape[0], rows):
            yield y, a[y:y + rows]


def sparse_points_any(sparse):
    """Rows, columns and values of the LiDAR pixels of an in-memory or windowed sparse map, block by block."""
    rows, cols, vals = [], [], []
    for y, blk in row_blocks(sparse):
        r, c = np.nonzero(np.isfinite(blk))
        rows.append(r + y)
        cols.append(c)
        vals.append(blk[r, c])
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals).astype(np.float32)


def image_bits(*images):
    """Effective bit depth over whole images (in memory or windowed), so every tile scales 16-bit data alike."""
    if all(np.dtype(getattr(a, "dtype", np.uint8)) == np.uint8 for a in images):
        return 8
    top = 0
    for a in images:
        for _, blk in row_blocks(a):
            top = max(top, int(blk.max()) if blk.size else 0)
    return effective_bits(np.array([top], np.uint16))


class TiffSink:
    """A float32 GeoTIFF written tile by tile (``sink[y0:y1, x0:x1] = block``); NaN nodata, DEFLATE, 256 x 256 tiles.

    Use as a context manager on a temporary path and rename it when the work succeeded (the CLI does).
    """

    def __init__(self, path, height, width, tags=None):
        self.path = str(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            self._ds = rasterio.open(self.path, "w", driver="GTiff", width=width, height=height, count=1,
                                     dtype="float32", nodata=float("nan"), tiled=True, blockxsize=256,
                                     blockysize=256, BIGTIFF="IF_SAFER", **TIFF_COMPRESSION)
        if tags:
            self.update_tags(**tags)
        self.shape = (height, width)

    def __setitem__(self, key, block):
        rows, cols = key
        y0, y1, _ = rows.indices(self.shape[0])
        x0, x1, _ = cols.indices(self.shape[1])
        with c_stderr_silenced():  # a failed write is found when the file is checked (io/atomic.py)
            self._ds.write(np.asarray(block, np.float32), 1, window=Window(x0, y0, x1 - x0, y1 - y0))

    def update_tags(self, **tags):
        self._ds.update_tags(**{str(k): str(v) for k, v in tags.items()})

    def close(self):
        with c_stderr_silenced():  # the last blocks are compressed and written here
            self._ds.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
