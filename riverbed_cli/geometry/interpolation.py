"""Interpolation of sparse LiDAR disparities without the images: nearest and linear (Delaunay) fills.

Used by the LiDAR-only baselines (:mod:`riverbed_cli.products.densify`) and by the fusion
(:mod:`riverbed_cli.matching.fusion`). The left image is the reference, ``d = x_left - x_right`` (px); NaN marks no
LiDAR.
"""

import numpy as np
from numba import njit, prange
from scipy import ndimage
from scipy.spatial import Delaunay

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


@njit(cache=True, parallel=True)
def _raster_triangles(simplices, xs, ys, values, out):
    # Each Delaunay triangle fills the pixel centres inside it (or on its edges) with the barycentric interpolation of
    # its corners' values; triangles are independent, and a pixel on a shared edge gets the same value from both.
    H, W = out.shape
    for t in prange(simplices.shape[0]):
        a, b, c = simplices[t, 0], simplices[t, 1], simplices[t, 2]
        x0, y0, x1, y1, x2, y2 = xs[a], ys[a], xs[b], ys[b], xs[c], ys[c]
        det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
        if det == 0.0:
            continue
        xa = max(0, int(np.ceil(min(x0, min(x1, x2)))))
        xb = min(W - 1, int(np.floor(max(x0, max(x1, x2)))))
        ya = max(0, int(np.ceil(min(y0, min(y1, y2)))))
        yb = min(H - 1, int(np.floor(max(y0, max(y1, y2)))))
        eps = 1e-9
        for y in range(ya, yb + 1):
            for x in range(xa, xb + 1):
                l0 = ((y1 - y2) * (x - x2) + (x2 - x1) * (y - y2)) / det
                l1 = ((y2 - y0) * (x - x2) + (x0 - x2) * (y - y2)) / det
                l2 = 1.0 - l0 - l1
                if l0 >= -eps and l1 >= -eps and l2 >= -eps:
                    out[y, x] = np.float32(l0 * values[a] + l1 * values[b] + l2 * values[c])


def interpolate_linear(sparse):
    """Linear interpolation over the Delaunay triangulation of the LiDAR pixels; nearest outside their hull.

    The triangulation is scipy's (Qhull, as ``LinearNDInterpolator``); the triangles are rasterised in one Numba
    kernel (barycentric weights at the pixel centres): 0.1 s for a megapixel where evaluating the interpolator pixel
    by pixel took 20 s.
    """
    sparse, valid = checked_points(sparse)
    rows, cols = np.nonzero(valid)
    out = interpolate_nearest(sparse)
    if rows.size < 3:
        return out
    pts = np.stack([cols, rows], axis=1).astype(np.float64)
    try:
        tri = Delaunay(pts)
    except Exception:  # noqa: BLE001 - Qhull refuses degenerate (collinear) point sets: nearest is all there is
        return out
    lin = np.full(sparse.shape, np.nan, np.float32)
    _raster_triangles(tri.simplices.astype(np.int64), pts[:, 0].copy(), pts[:, 1].copy(),
                      sparse[rows, cols].astype(np.float64), lin)
    inside = np.isfinite(lin)
    out[inside] = lin[inside]
    return out
