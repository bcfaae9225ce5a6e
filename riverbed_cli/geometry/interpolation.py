"""Interpolation of sparse LiDAR disparities without the images: nearest and linear (Delaunay) fills.

Used by the LiDAR-only baselines (:mod:`riverbed_cli.products.densify`) and by the fusion
(:mod:`riverbed_cli.matching.fusion`). The left image is the reference, ``d = x_left - x_right`` (px); NaN marks no
LiDAR.
"""

import cv2
import numpy as np
from numba import njit, prange
from scipy import ndimage

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


def nearest_lidar(sparse):
    """Each pixel's distance (px, float64) to its nearest LiDAR pixel and that pixel's row and column:
    ``(distance, rows, cols)``, (H, W) each (Euclidean distance transform)."""
    sparse, valid = checked_points(sparse)
    dist, (iy, ix) = ndimage.distance_transform_edt(~valid, return_indices=True)
    return dist, iy, ix


def interpolate_nearest(sparse, nearest=None):
    """Every pixel takes the disparity of its nearest LiDAR pixel. (H, W) float32. ``nearest``: the
    :func:`nearest_lidar` of ``sparse`` if already known."""
    sparse, _ = checked_points(sparse)
    _, iy, ix = nearest_lidar(sparse) if nearest is None else nearest
    return sparse[iy, ix].astype(np.float32)


@njit(cache=True, parallel=True)
def _raster_triangles(tx, ty, tv, out):
    # Each triangle (corners tx, ty, values tv: (T, 3)) fills the pixel centres inside it (or on its edges) with the
    # barycentric interpolation of its corners' values; triangles are independent, and a pixel on a shared edge gets
    # the same value from both.
    H, W = out.shape
    for t in prange(tx.shape[0]):
        x0, y0, x1, y1, x2, y2 = tx[t, 0], ty[t, 0], tx[t, 1], ty[t, 1], tx[t, 2], ty[t, 2]
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
                    out[y, x] = np.float32(l0 * tv[t, 0] + l1 * tv[t, 1] + l2 * tv[t, 2])


def delaunay_triangles(rows, cols, shape):
    """Delaunay triangles of integer pixel positions: ``(T, 3)`` corner columns and rows (float64).

    OpenCV's incremental ``Subdiv2D`` (10x faster than Qhull here: 21 ms for 18 500 points); the triangles that touch
    its virtual outer vertices are dropped, so the union is the points' convex hull. Where four points are
    co-circular (common on the pixel grid) either diagonal is a Delaunay triangulation; the two libraries may pick
    differently.
    """
    H, W = shape
    # a wide rectangle puts its virtual outer vertices far away: long sliver triangles along the hull stay Delaunay
    sub = cv2.Subdiv2D((-20 * W, -20 * H, 41 * W, 41 * H))
    sub.insert(np.stack([cols, rows], axis=1).astype(np.float32))
    tri = sub.getTriangleList().reshape(-1, 3, 2).astype(np.float64)
    inside = ((tri[..., 0] >= 0) & (tri[..., 0] < W) & (tri[..., 1] >= 0) & (tri[..., 1] < H)).all(axis=(1,))
    tri = tri[inside]
    return tri[..., 0], tri[..., 1]


def interpolate_linear(sparse, nearest=None):
    """Linear interpolation over the Delaunay triangulation of the LiDAR pixels; nearest outside their hull.

    The triangles (:func:`delaunay_triangles`) are rasterised in one Numba kernel (barycentric weights at the pixel
    centres): 0.03 s for 18 500 points on 740 x 500 px, where ``scipy.interpolate.LinearNDInterpolator`` took 12 s
    on 0.5 MP. ``nearest``: the :func:`nearest_lidar` of ``sparse`` if already known.
    """
    sparse, valid = checked_points(sparse)
    rows, cols = np.nonzero(valid)
    out = interpolate_nearest(sparse, nearest)
    if rows.size < 3:
        return out
    tx, ty = delaunay_triangles(rows, cols, sparse.shape)
    if tx.shape[0] == 0:  # collinear points: no triangle, nearest is all there is
        return out
    tv = sparse[np.rint(ty).astype(np.int64), np.rint(tx).astype(np.int64)].astype(np.float64)
    lin = np.full(sparse.shape, np.nan, np.float32)
    _raster_triangles(np.ascontiguousarray(tx), np.ascontiguousarray(ty), np.ascontiguousarray(tv), lin)
    inside = np.isfinite(lin)
    out[inside] = lin[inside]
    return out
