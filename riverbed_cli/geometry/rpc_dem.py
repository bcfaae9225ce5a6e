"""DEMs for RPC localisation: ellipsoidal heights on a lon/lat grid, vertical datums through pyproj (docs/rpc.md)."""

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj
import rasterio
import rasterio.windows
from pyproj import CRS
from pyproj.exceptions import CRSError, ProjError
from pyproj.transformer import TransformerGroup
from rasterio.errors import RasterioIOError

from ..errors import RiverbedError
from ..io.paths import require_file

#: Debian's proj-data puts PROJ's grids here (EGM96: ``egm96_15.gtx``); pyproj's wheel ships none of them.
SYSTEM_PROJ_DATA = Path("/usr/share/proj")
ELLIPSOID = "ellipsoid"
EGM96 = "EPSG:5773"


def geoid_to_ellipsoid_transformer(vertical, path=None):
    """A pyproj transformer (lon, lat, orthometric height) -> (lon, lat, WGS 84 ellipsoidal height).

    ``vertical`` is a vertical CRS (e.g. ``"EPSG:5773"``, EGM96 height, SRTM's datum); the grid rule of
    :func:`height_transformer`.
    """
    try:
        src = CRS.from_user_input(f"EPSG:4326+{CRS.from_user_input(vertical).to_epsg()}")
    except (CRSError, TypeError):
        raise RiverbedError(f"unknown vertical datum '{vertical}'", path) from None
    return height_transformer(src, CRS.from_epsg(4979), path, what=CRS.from_user_input(vertical).name)


def height_transformer(src, dst, path=None, what=None):
    """A pyproj transformer from ``src`` to ``dst`` (3-D or compound CRSs, ``always_xy``) that converts heights
    between their vertical datums with PROJ's geoid grid. PROJ's grids are not in pyproj's wheel and cannot be
    downloaded here: when the grid is not on PROJ's search path, Debian's ``/usr/share/proj`` (package proj-data)
    is added; if the grid is still missing, a :class:`RiverbedError` names it (never PROJ's silent "ballpark"
    transformation, which leaves the heights unchanged). ``what``: how the heights are named in that error."""
    for attempt in range(2):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)    # "best transformation is not available": handled here
            group = TransformerGroup(src, dst, always_xy=True)
        if group.best_available and group.transformers and "ballpark" not in group.transformers[0].description:
            return group.transformers[0]
        dirs = pyproj.datadir.get_data_dir().split(":")
        if attempt == 0 and SYSTEM_PROJ_DATA.is_dir() and str(SYSTEM_PROJ_DATA) not in dirs:
            pyproj.datadir.append_data_dir(str(SYSTEM_PROJ_DATA))
            continue
    grids = [g.short_name for op in group.unavailable_operations for g in op.grids if not g.available]
    name = grids[0] if grids else "its geoid grid"
    raise RiverbedError(f"heights are {what or src.name} and PROJ's grid {name} is not available offline (install "
                        "Debian's proj-data, or point PROJ_DATA at a folder with it)", path)


@dataclass
class DEM:
    """Ellipsoidal heights (m, float64, NaN where unknown) on a geographic (lon, lat) grid, bilinear lookup.

    ``transform`` is the rasterio affine of the grid (pixel *corners*, GDAL's convention; :meth:`height`
    interpolates between pixel centres).
    """

    heights: np.ndarray
    transform: object
    source: str
    vertical: str

    @property
    def mean_height(self):
        return float(np.nanmean(self.heights))

    @property
    def min_height(self):
        return float(np.nanmin(self.heights))

    @property
    def max_height(self):
        return float(np.nanmax(self.heights))

    def height(self, lon, lat):
        """Bilinear ellipsoidal height (m) at WGS 84 ``lon, lat`` (degrees); NaN outside the grid or next to a hole."""
        lon, lat = np.broadcast_arrays(np.asarray(lon, np.float64), np.asarray(lat, np.float64))
        inv = ~self.transform
        c, r = inv * (lon, lat)
        c = np.asarray(c) - 0.5
        r = np.asarray(r) - 0.5
        hgt = self.heights
        ok = np.isfinite(c) & np.isfinite(r) & (c >= 0) & (r >= 0) & (c <= hgt.shape[1] - 1) & \
            (r <= hgt.shape[0] - 1)
        c0 = np.clip(np.floor(np.where(ok, c, 0)).astype(np.int64), 0, max(hgt.shape[1] - 2, 0))
        r0 = np.clip(np.floor(np.where(ok, r, 0)).astype(np.int64), 0, max(hgt.shape[0] - 2, 0))
        fc = np.where(ok, c, 0) - c0
        fr = np.where(ok, r, 0) - r0
        c1 = np.minimum(c0 + 1, hgt.shape[1] - 1)
        r1 = np.minimum(r0 + 1, hgt.shape[0] - 1)
        out = (hgt[r0, c0] * (1 - fc) * (1 - fr) + hgt[r0, c1] * fc * (1 - fr) + hgt[r1, c0] * (1 - fc) * fr
               + hgt[r1, c1] * fc * fr)
        return np.where(ok, out, np.nan)


def dem_vertical(path, ds, vertical=None):
    """The vertical datum of a DEM's heights: ``"ellipsoid"`` or a vertical CRS (``"EPSG:5773"``).

    ``vertical`` (the user's word) wins; else SRTM ``.hgt`` (GDAL's SRTMHGT driver) is EGM96 by its
    specification; else a compound CRS gives its vertical part and a 3D geographic CRS means ellipsoidal; a 2D CRS
    says nothing of the heights: a :class:`RiverbedError` asks for ``vertical``.
    """
    if vertical is not None:
        if str(vertical).lower() in ("ellipsoid", "ellipsoidal", "epsg:4979"):
            return ELLIPSOID
        try:
            crs = CRS.from_user_input(vertical)
        except CRSError:
            raise RiverbedError(f"unknown vertical datum '{vertical}'", path) from None
        if not crs.is_vertical:
            raise RiverbedError(f"'{vertical}' is not a vertical CRS", path)
        return crs.to_string()
    if ds.driver == "SRTMHGT":
        return EGM96
    if ds.crs is None:
        raise RiverbedError("DEM without a CRS", path)
    crs = CRS.from_user_input(ds.crs.to_wkt())
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if sub.is_vertical:
                return sub.to_string() if sub.to_epsg() is None else f"EPSG:{sub.to_epsg()}"
    if crs.is_geographic and len(crs.axis_info) == 3:
        return ELLIPSOID
    raise RiverbedError(f"heights in an unknown vertical datum (the CRS {crs.name} is 2D): say whether they are "
                        "ellipsoidal or e.g. EGM96 (EPSG:5773)", path)


def read_dem(path, bounds=None, vertical=None, margin_deg=0.002):
    """Read a DEM (any raster GDAL reads, SRTM ``.hgt`` included) as ellipsoidal heights on a lon/lat grid.

    Parameters
    ----------
    path : str or Path
        The DEM file, in a geographic CRS (a projected DEM is refused: reproject it first).
    bounds : (lon_min, lat_min, lon_max, lat_max), optional
        Read only the window covering these bounds plus ``margin_deg``; a DEM that does not cover them all is a
        :class:`RiverbedError`.
    vertical : str, optional
        The vertical datum of the heights when the file does not say (:func:`dem_vertical`).
    margin_deg : float
        Margin added around ``bounds`` (degrees).
    """
    path = require_file(path)
    try:
        with rasterio.open(path) as ds:
            datum = dem_vertical(path, ds, vertical)
            if ds.crs is None or not CRS.from_user_input(ds.crs.to_wkt()).is_geographic:
                raise RiverbedError("DEM not in a geographic (lon, lat) CRS: reproject it to EPSG:4326", path)
            window = None
            if bounds is not None:
                lo_lon, lo_lat, hi_lon, hi_lat = bounds
                b = ds.bounds
                if lo_lon < b.left or hi_lon > b.right or lo_lat < b.bottom or hi_lat > b.top:
                    raise RiverbedError(f"the DEM (lon {b.left:.4f}..{b.right:.4f}, lat {b.bottom:.4f}..{b.top:.4f}) "
                                        f"does not cover the region (lon {lo_lon:.4f}..{hi_lon:.4f}, lat "
                                        f"{lo_lat:.4f}..{hi_lat:.4f})", path)
                window = rasterio.windows.from_bounds(lo_lon - margin_deg, lo_lat - margin_deg, hi_lon + margin_deg,
                                                      hi_lat + margin_deg, ds.transform)
                c0, r0 = int(np.floor(window.col_off)), int(np.floor(window.row_off))
                c1 = int(np.ceil(window.col_off + window.width))
                r1 = int(np.ceil(window.row_off + window.height))
                c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, ds.width), min(r1, ds.height)
                window = rasterio.windows.Window(c0, r0, c1 - c0, r1 - r0)
            heights = ds.read(1, window=window, masked=True).astype(np.float64).filled(np.nan)
            transform = ds.window_transform(window) if window is not None else ds.transform
    except RasterioIOError as e:
        raise RiverbedError(f"cannot read the DEM ({str(e).splitlines()[0]})", path) from None
    if not np.isfinite(heights).any():
        raise RiverbedError("the DEM has no valid height over the region", path)
    if datum != ELLIPSOID:
        tr = geoid_to_ellipsoid_transformer(datum, path)
        rows, cols = np.mgrid[0:heights.shape[0], 0:heights.shape[1]]
        lon, lat = transform * (cols + 0.5, rows + 0.5)
        try:
            _, _, h = tr.transform(lon, lat, np.where(np.isfinite(heights), heights, 0.0), errcheck=True)
        except ProjError as e:
            raise RiverbedError(f"cannot convert {datum} heights to ellipsoidal ({e})", path) from None
        heights = np.where(np.isfinite(heights), h, np.nan)
    return DEM(heights=heights, transform=transform, source=str(path), vertical=datum)
