"""A DSM raster read as a point cloud: one point per valid cell, at the cell's centre, its height as ``z``.

What lets ``riverbed project`` take a DSM (a coarse one, a previous block's, SRTM) where it takes LiDAR: its
points project into the pair as sparse disparities, from which ``riverbed range-map`` makes the per-pixel ranges
``riverbed match --range-map`` searches (docs/tubes.md). Single-band GeoTIFF (``.tif``, ``.tiff``) or SRTM
``.hgt``, read by rasterio; cells equal to the nodata value or not finite are no points. Coordinates are the
raster's own (its CRS, no reprojection), the cell centre ``transform * (col + 0.5, row + 0.5)`` in float64
(rotated or sheared grids included); heights as stored, in the CRS's vertical reference (a geographic CRS without a
vertical part means ellipsoidal heights: give ``--crs`` with one otherwise, as for LiDAR). Read a block of rows at
a time, so memory is bounded by the chunk size.
"""

import functools
import os
import warnings

import numpy as np
import rasterio
from pyproj import CRS
from pyproj.exceptions import CRSError
from rasterio.errors import NotGeoreferencedWarning, RasterioIOError
from rasterio.windows import Window

from ..errors import RiverbedError

#: file name endings read as a DSM (case-insensitive)
DSM_SUFFIXES = (".tif", ".tiff", ".hgt")


def _open(path):
    try:
        with warnings.catch_warnings():  # no geotransform: refused below, in one line
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            ds = rasterio.open(str(path))
    except RasterioIOError as e:
        raise RiverbedError(f"cannot read the DSM: {' '.join(str(e).split())[:160]}", path) from None
    if ds.count != 1:
        ds.close()
        raise RiverbedError(f"a DSM must have one band (heights), this raster has {ds.count}", path)
    if ds.transform.is_identity:
        ds.close()
        raise RiverbedError("the raster has no geotransform: not a DSM", path)
    return ds


def _row_step(width, chunk_size):
    return max(1, int(chunk_size) // max(1, int(width)))


def _cells(ds, row0, rows):
    # the valid cells of rows row0.. row0 + rows: (N, 3) float64 centres and heights
    z = ds.read(1, window=Window(0, row0, ds.width, rows), masked=False).astype(np.float64)
    ok = np.isfinite(z)
    if ds.nodata is not None and np.isfinite(ds.nodata):
        ok &= z != float(ds.nodata)
    r, c = np.nonzero(ok)
    t = ds.transform
    cx, cy = c + 0.5, r + row0 + 0.5
    return np.stack([t.a * cx + t.b * cy + t.c, t.d * cx + t.e * cy + t.f, z[r, c]], axis=1)


def dsm_info_fields(path):
    """What :class:`~riverbed_cli.io.lidar.LidarInfo` holds for a DSM: ``point_count`` (valid cells), ``mins``,
    ``maxs`` (of the points), ``crs`` (pyproj, or None). The raster is read a block of rows at a time, once per
    version of the file in a process (``riverbed project`` asks for the count, then the projection again)."""
    st = os.stat(path)
    fields = _dsm_info(os.path.abspath(path), st.st_mtime_ns, st.st_size)
    return {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in fields.items()}  # the cache's stay as made


@functools.lru_cache(maxsize=8)
def _dsm_info(path, mtime_ns, size):
    # dsm_info_fields of one version of the file (mtime and size in the key)
    with _open(path) as ds:
        crs = None
        if ds.crs is not None:
            try:
                crs = CRS.from_user_input(ds.crs.to_wkt())
            except CRSError:
                crs = None
        n = 0
        mins, maxs = np.full(3, np.inf), np.full(3, -np.inf)
        step = _row_step(ds.width, 1_000_000)
        for row0 in range(0, ds.height, step):
            xyz = _cells(ds, row0, min(step, ds.height - row0))
            if len(xyz):
                n += len(xyz)
                mins, maxs = np.minimum(mins, xyz.min(axis=0)), np.maximum(maxs, xyz.max(axis=0))
    if n == 0:
        raise RiverbedError("the DSM has no valid cell (all nodata or NaN)", path)
    return {"point_count": n, "mins": mins, "maxs": maxs, "crs": crs}


def iter_dsm_points(path, chunk_size):
    """The DSM's valid cells as point chunks of about ``chunk_size`` (whole rows), in the dicts of
    :func:`~riverbed_cli.io.lidar.iter_lidar`: class 0 (never classified), intensity 0, no colour."""
    with _open(path) as ds:
        step = _row_step(ds.width, chunk_size)
        for row0 in range(0, ds.height, step):
            xyz = _cells(ds, row0, min(step, ds.height - row0))
            yield {"xyz": xyz, "classification": np.zeros(len(xyz), np.uint8),
                   "intensity": np.zeros(len(xyz), np.uint16), "rgb": None}
