"""GeoTIFF output: cloud-optimised GeoTIFFs (tiled, compressed, with overviews) through rasterio's COG driver."""

import warnings

import numpy as np
import rasterio
import rasterio.shutil
from rasterio._err import CPLE_BaseError
from rasterio.io import MemoryFile

from ..errors import RiverbedError
from .atomic import atomic_output, c_stderr_silenced

#: Default creation options: a cloud-optimised GeoTIFF (tiled, compressed, internal overviews).
DEFAULT_CREATION_OPTIONS = {"COMPRESS": "DEFLATE", "BLOCKSIZE": "256", "OVERVIEWS": "AUTO", "BIGTIFF": "IF_SAFER"}


def parse_creation_options(items):
    """``["KEY=VALUE", ...]`` (the ``--co`` option) into a dict with upper-case keys."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise RiverbedError(f"creation option '{item}' is not KEY=VALUE")
        k, v = item.split("=", 1)
        out[k.strip().upper()] = v.strip()
    return out


def write_geotiff(path, bands, transform, crs=None, nodata=None, creation_options=None, overwrite=False,
                  band_descriptions=None, tags=None):
    """Write a (cloud-optimised) GeoTIFF atomically.

    Parameters
    ----------
    path : str or path-like
        Output ``.tif``.
    bands : (H, W) or (B, H, W) array
        Raster data; all bands share one dtype.
    transform : affine.Affine
        Pixel-to-world transform (north-up: ``transform.e < 0``); pixel corners, as in GDAL.
    crs : str, rasterio.crs.CRS or None
        Coordinate reference system (``"EPSG:32632"``, WKT, ...).
    nodata : float, optional
        Nodata value of every band (NaN allowed for float rasters).
    creation_options : dict, optional
        GDAL COG creation options, overriding :data:`DEFAULT_CREATION_OPTIONS` (``PREDICTOR=FLOATING_POINT`` is added
        for float rasters unless given).
    """
    data = np.asarray(bands)
    if data.ndim == 2:
        data = data[None]
    if data.ndim != 3:
        raise RiverbedError(f"raster must be (H, W) or (B, H, W), got shape {data.shape}", path)
    count, height, width = data.shape
    co = dict(DEFAULT_CREATION_OPTIONS)
    if data.dtype.kind == "f":
        co["PREDICTOR"] = "FLOATING_POINT"
    co.update({k.upper(): str(v) for k, v in (creation_options or {}).items()})
    try:
        crs_obj = rasterio.crs.CRS.from_user_input(crs) if crs is not None else None
    except rasterio.errors.CRSError:
        raise RiverbedError(f"unknown CRS '{crs}'", path) from None
    profile = {"driver": "GTiff", "width": width, "height": height, "count": count, "dtype": data.dtype.name,
               "transform": transform, "crs": crs_obj, "nodata": nodata}
    # the COG's bytes are written by Python below (its writes raise on a full disk): no read-back needed
    with atomic_output(path, overwrite, verify=False) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        try:
            # Build the raster in memory, then let GDAL's COG driver lay out tiles and overviews.
            with MemoryFile() as mem:
                with mem.open(**profile) as ds:
                    ds.write(data)
                    if band_descriptions:
                        for i, desc in enumerate(band_descriptions, start=1):
                            ds.set_band_description(i, desc)
                    if tags:
                        ds.update_tags(**{str(k): str(v) for k, v in tags.items()})
                # the COG laid out in memory too, and written by Python, whose writes raise on a full disk
                with mem.open() as src, MemoryFile() as cog, c_stderr_silenced():
                    rasterio.shutil.copy(src, cog.name, driver="COG", **co)
                    with open(tmp, "wb") as f:
                        f.write(cog.getbuffer())
        except (rasterio.errors.RasterioError, CPLE_BaseError, ValueError) as e:
            raise RiverbedError(f"cannot write GeoTIFF ({e})", path) from None
