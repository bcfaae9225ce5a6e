"""Interpolation of sparse LiDAR disparities without the images: nearest and linear (Delaunay) fills.

Used by the LiDAR-only baselines (:mod:`riverbed_cli.products.densify`) and by the fusion
(:mod:`riverbed_cli.matching.fusion`). The left image is the reference, ``d = x_left - x_right`` (px); NaN marks no
LiDAR.
"""

import numpy as np
from scipy import ndimage
from scipy.interpolate import LinearNDInterpolator

from ..errors import RiverbedError


def checked_points(sparse):
    """``(sparse as float32, valid mask)`` of a 2-D sparse disparity map with at least one finite value."""
    sparse = np.asarray(sparse, dtype=np.float32)
    if sparse.ndim != 2:
        raise RiverbedError(f"sparse map must be 2-D (H, W), got shape {sparse.shape}")
    valid = np.isfinite(sparse)
    if not valid.any():
        raise RiverbedError("sparse map has no valid disparities")
    return sparse, valid


def interpolate_nearest(sparse):
    """Every pixel takes the disparity of its nearest LiDAR pixel. (H, W) float32."""
    sparse, valid = checked_points(sparse)
    _, (iy, ix) = ndimage.distance_transform_edt(~valid, return_indices=True)
    return sparse[iy, ix].astype(np.float32)


def interpolate_linear(sparse):
    """Linear interpolation over the Delaunay triangulation of the LiDAR pixels; nearest outside their hull."""
    sparse, valid = checked_points(sparse)
    rows, cols = np.nonzero(valid)
    if rows.size < 3:
        return interpolate_nearest(sparse)
    out = interpolate_nearest(sparse)
    try:
        interp = LinearNDInterpolator(np.stack([cols, rows], axis=1).astype(np.float64),
                                      sparse[rows, cols].astype(np.float64))
    except Exception:  # noqa: BLE001 - Qhull refuses degenerate (collinear) point sets: nearest is all there is
        return out
    H, W = sparse.shape
    ys, xs = np.mgrid[0:H, 0:W]
    lin = interp(xs.ravel().astype(np.float64), ys.ravel().astype(np.float64)).reshape(H, W)
    inside = np.isfinite(lin)
    out[inside] = lin[inside].astype(np.float32)
    return out
