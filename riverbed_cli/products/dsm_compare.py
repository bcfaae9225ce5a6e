"""Compare two DSMs on a common grid: height-difference statistics and a difference map."""

import numpy as np
import rasterio
from rasterio.warp import Resampling, reproject

from ..errors import RiverbedError

#: Absolute thresholds (CRS height units, usually metres) for the shares of large differences.
DEFAULT_THRESHOLDS = (0.5, 1.0, 2.0)


def read_dsm_on_grid(path, ref_path):
    """Read DSM ``path`` resampled onto the grid of ``ref_path``; returns (dsm, ref, ref_resolution).

    Both are float64 with NaN for nodata; ``ref_resolution`` is None for a geographic CRS. When the grids differ
    (CRS, transform or size) the DSM is reprojected with
    rasterio (bilinear; nodata honoured, so no height is averaged with a nodata value).
    """
    def _open(p):
        try:
            return rasterio.open(p)
        except rasterio.errors.RasterioError as e:
            raise RiverbedError(f"cannot read DSM ({str(e).splitlines()[0]})", p) from None

    with _open(ref_path) as ref_ds, _open(path) as ds:
        ref = ref_ds.read(1, masked=True).astype(np.float64).filled(np.nan)
        if ref_ds.crs is None and ds.crs is not None or ds.crs is None and ref_ds.crs is not None:
            raise RiverbedError(f"one DSM has a CRS and the other has none ({ref_path})", path)
        same = (ds.crs == ref_ds.crs and ds.transform == ref_ds.transform and ds.shape == ref_ds.shape)
        if same:
            dsm = ds.read(1, masked=True).astype(np.float64).filled(np.nan)
        else:
            src = ds.read(1, masked=True).astype(np.float64).filled(np.nan)
            dsm = np.full(ref.shape, np.nan)
            reproject(src, dsm, src_transform=ds.transform, src_crs=ds.crs or ref_ds.crs, src_nodata=np.nan,
                      dst_transform=ref_ds.transform, dst_crs=ref_ds.crs or ds.crs, dst_nodata=np.nan,
                      resampling=Resampling.bilinear)
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
