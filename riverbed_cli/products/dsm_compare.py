"""Compare two DSMs on a common grid: height-difference statistics and a difference map."""

import warnings

import numpy as np
import rasterio
from rasterio.warp import Resampling, reproject, transform_bounds

from ..errors import RiverbedError
from ..io.paths import require_file

#: Absolute thresholds (CRS height units, usually metres) for the shares of large differences.
DEFAULT_THRESHOLDS = (0.5, 1.0, 2.0)


def _crs_name(crs):
    if crs is None:
        return "no CRS"
    epsg = crs.to_epsg()
    return f"EPSG:{epsg}" if epsg else "a CRS without an EPSG code"


def _bounds_text(b):
    return " ".join(f"{float(v):.10g}" for v in b)


def _open_dsm(path):
    path = require_file(path)
    try:
        return rasterio.open(path)
    except MemoryError:
        raise
    except Exception:  # noqa: BLE001 - GDAL drivers raise many types; any of them means "cannot read"
        raise RiverbedError("cannot read DSM (not a raster GDAL reads)", path) from None


def _read_heights(ds, path):
    try:
        return ds.read(1, masked=True).astype(np.float64).filled(np.nan)
    except MemoryError:
        raise
    except Exception:  # noqa: BLE001 - as in _open_dsm
        raise RiverbedError("cannot read DSM (corrupt or truncated data)", path) from None


def read_dsm_on_grid(path, ref_path):
    """Read DSM ``path`` resampled onto the grid of ``ref_path``; returns (dsm, ref, ref_resolution).

    Both are float64 with NaN for nodata; ``ref_resolution`` is None for a geographic CRS. When the grids differ
    (CRS, transform or size) the DSM is reprojected with
    rasterio (bilinear; nodata honoured, so no height is averaged with a nodata value).

    Raises :class:`RiverbedError` (one line, naming the file) for a missing or unreadable file, a CRS on one side
    only, and a DSM whose extent (in the reference's CRS) does not overlap the reference's.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with _open_dsm(ref_path) as ref_ds, _open_dsm(path) as ds:
            if (ref_ds.crs is None) != (ds.crs is None):
                raise RiverbedError(f"one DSM has a CRS and the other has none ({ref_path})", path)
            b = ds.bounds
            if ds.crs != ref_ds.crs:
                try:
                    b = transform_bounds(ds.crs, ref_ds.crs, *b, densify_pts=21)
                except Exception:  # noqa: BLE001 - PROJ errors come as several types
                    raise RiverbedError(f"cannot transform the DSM's extent from {_crs_name(ds.crs)} to the "
                                        f"reference's {_crs_name(ref_ds.crs)} ({ref_path})", path) from None
            rb = ref_ds.bounds
            if not (b[0] < rb.right and b[2] > rb.left and b[1] < rb.top and b[3] > rb.bottom):
                raise RiverbedError(f"does not overlap the reference DSM {ref_path} (DSM {_bounds_text(b)}, reference "
                                    f"{_bounds_text(rb)}: XMIN YMIN XMAX YMAX in {_crs_name(ref_ds.crs)})", path)
            ref = _read_heights(ref_ds, ref_path)
            src = _read_heights(ds, path)
            same = (ds.crs == ref_ds.crs and ds.transform == ref_ds.transform and ds.shape == ref_ds.shape)
            if same:
                dsm = src
            else:
                dsm = np.full(ref.shape, np.nan)
                try:
                    reproject(src, dsm, src_transform=ds.transform, src_crs=ds.crs or ref_ds.crs, src_nodata=np.nan,
                              dst_transform=ref_ds.transform, dst_crs=ref_ds.crs or ds.crs, dst_nodata=np.nan,
                              resampling=Resampling.bilinear)
                except Exception as e:  # noqa: BLE001 - GDAL's warper raises its own error types
                    raise RiverbedError(f"cannot resample the DSM onto the grid of {ref_path} "
                                        f"({str(e).splitlines()[0] if str(e) else type(e).__name__})", path) from None
            # A cell size in degrees is no height threshold: only projected grids get the 3-cell share.
            res = abs(ref_ds.transform.a) if ref_ds.crs is None or ref_ds.crs.is_projected else None
    return dsm, ref, res


def compare_dsm(dsm, ref, thresholds=DEFAULT_THRESHOLDS, resolution=None, mask=None):
    """Statistics of ``dz = dsm - ref`` over the cells where both have data.

    Returns a dict: ``mean``, ``median``, ``rmse``, ``nmad`` (1.4826 median |dz - median dz|), ``std``, ``over_T`` (%
    of compared cells with |dz| > T for each threshold T), ``over_3res`` (% with |dz| > 3 x the reference cell size,
    if ``resolution`` is given), ``completeness`` (% of the reference cells that the DSM covers) and ``n``.
    ``mask`` (bool, same shape) restricts the cells compared (e.g. to exclude walls).
    """
    dsm = np.asarray(dsm, np.float64)
    ref = np.asarray(ref, np.float64)
    if dsm.shape != ref.shape:
        raise RiverbedError(f"DSM grids differ: {dsm.shape} vs {ref.shape}")
    ref_ok = np.isfinite(ref) if mask is None else np.isfinite(ref) & mask
    both = ref_ok & np.isfinite(dsm)
    n_ref = int(ref_ok.sum())
    if n_ref == 0:
        raise RiverbedError("the reference DSM has no data in the compared area")
    dz = (dsm - ref)[both]
    out = {"n": int(both.sum()), "completeness": 100.0 * both.sum() / n_ref}
    if dz.size == 0:
        out.update(mean=float("nan"), median=float("nan"), rmse=float("nan"), nmad=float("nan"), std=float("nan"))
        return out
    med = float(np.median(dz))
    out.update(mean=float(dz.mean()), median=med, rmse=float(np.sqrt(np.mean(dz**2))),
               nmad=float(1.4826 * np.median(np.abs(dz - med))), std=float(dz.std()))
    for t in thresholds:
        out[f"over_{t:g}"] = float(100.0 * np.mean(np.abs(dz) > t))
    if resolution:
        out["over_3res"] = float(100.0 * np.mean(np.abs(dz) > 3 * resolution))
    order = ["mean", "median", "rmse", "nmad", "std"] + [k for k in out if k.startswith("over_")] + [
        "completeness", "n"]
    return {k: out[k] for k in order}


def difference_limit(dsm, ref):
    """Default saturation of :func:`difference_map`: 3 NMAD of ``dsm - ref`` over the cells both have, at least 0.1
    (height units); 0.1 when they share no cell."""
    dz = np.asarray(dsm, np.float64) - np.asarray(ref, np.float64)
    v = dz[np.isfinite(dz)]
    if v.size == 0:
        return 0.1
    return max(0.1, 3 * 1.4826 * float(np.median(np.abs(v - np.median(v)))))


def difference_map(dsm, ref, limit=None):
    """RGB (uint8) of ``dsm - ref``: blue below, white equal, red above, saturating at +-``limit``; black no data.

    ``limit`` defaults to :func:`difference_limit` (3 NMAD of the differences, at least 0.1).
    """
    dz = np.asarray(dsm, np.float64) - np.asarray(ref, np.float64)
    ok = np.isfinite(dz)
    rgb = np.zeros(dz.shape + (3,), np.uint8)
    if not ok.any():
        return rgb
    if limit is None:
        limit = difference_limit(dsm, ref)
    t = np.clip(dz[ok] / limit, -1, 1)
    r = np.where(t > 0, 1.0, 1.0 + t)
    b = np.where(t < 0, 1.0, 1.0 - t)
    g = 1.0 - np.abs(t)
    rgb[ok] = (np.stack([r, g, b], axis=1) * 255).astype(np.uint8)
    return rgb
