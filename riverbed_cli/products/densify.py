"""LiDAR-only baselines: a dense disparity map from the sparse LiDAR alone (no matching).

The obvious alternative to fusing LiDAR with stereo is to interpolate the LiDAR and ignore the second image; every
accuracy table shows these beside the matchers (``riverbed benchmark``), so a fused result can be seen to beat them.

Methods:

* ``nearest``: the disparity of the nearest LiDAR pixel (Euclidean, ``scipy.ndimage.distance_transform_edt``);
* ``linear``: linear interpolation over the Delaunay triangulation of the LiDAR pixels, nearest outside their convex
  hull (:func:`~riverbed_cli.geometry.interpolation.interpolate_linear`);
* ``planes``: each pixel on the least-squares plane of its nearest LiDAR pixel and that pixel's natural neighbours
  (:func:`~riverbed_cli.geometry.planes.interpolate_planes`; the fusion's LiDAR side, docs/fusion.md);
* ``guided``: an image-guided weighted average (the paper's §2.2 family, a joint-bilateral normalised convolution):
  ``d(p) = sum_q w(p, q) d_q / sum_q w(p, q)`` over the LiDAR pixels ``q`` within ``radius`` px (default: twice the
  mean LiDAR spacing), ``w = exp(-|p - q|^2 / 2 sigma_s^2 - |I(p) - I(q)|^2 / 2 sigma_i^2)`` with the left image
  ``I``; nearest where no LiDAR pixel is within ``radius``. ``sigma_s`` defaults to the spacing.

Conventions: the left image is the reference, ``d = x_left - x_right`` (px); NaN in ``sparse`` marks no LiDAR.
"""

import math

import numpy as np
from numba import prange
from scipy import ndimage

from ..errors import RiverbedError
from ..geometry.coverage import lidar_rows, lidar_share
from ..geometry.interpolation import checked_points, interpolate_linear
from ..geometry.planes import interpolate_planes
from ..matching.diffusion import bilateral_weight
from ..runtime.kernel import kernel

METHODS = ("nearest", "linear", "planes", "guided")


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


@kernel(parallel=True)
def _guided_kernel(sparse, ptr, cols, guide, radius, a, b, out, wsum):
    H, W = sparse.shape
    for y in prange(H):
        for x in range(W):
            num = 0.0
            den = 0.0
            for yy in range(max(0, y - radius), min(H, y + radius + 1)):
                row = cols[ptr[yy]:ptr[yy + 1]]
                j = np.searchsorted(row, x - radius)
                while j < row.shape[0] and row[j] <= x + radius:
                    xx = row[j]
                    j += 1
                    w = bilateral_weight(guide, y, x, yy, xx, a, b)
                    num += w * sparse[yy, xx]
                    den += w
            wsum[y, x] = den
            out[y, x] = num / den if den > 0.0 else np.nan


def densify_guided(sparse, image, radius=None, sigma_s=None, sigma_i=8.0, min_weight=1e-6):
    """Image-guided interpolation (module docstring): a joint-bilateral weighted average of the nearby LiDAR.

    Parameters
    ----------
    sparse : (H, W) float
        LiDAR disparities of the left image, NaN elsewhere.
    image : (H, W) or (H, W, C) array
        The left image, 0..255 scale (8-bit) or any scale of the same range as ``sigma_i``.
    radius : int, optional
        Window half side (px); default twice the mean LiDAR spacing ``1 / sqrt(p)``.
    sigma_s, sigma_i : float, optional
        Spatial (px; default the spacing) and colour (grey levels) widths of the weight.
    min_weight : float
        Pixels whose summed weight is below this take the nearest LiDAR disparity.
    """
    sparse, valid = checked_points(sparse)
    guide = np.asarray(image, dtype=np.float32)
    if guide.ndim == 2:
        guide = guide[:, :, None]
    if guide.shape[:2] != sparse.shape:
        raise RiverbedError(f"guide image is {guide.shape[1]}x{guide.shape[0]} but the sparse map is "
                            f"{sparse.shape[1]}x{sparse.shape[0]} (WxH)")
    spacing = 1.0 / math.sqrt(max(lidar_share(sparse), 1e-12))
    radius = int(math.ceil(2.0 * spacing)) if radius is None else int(radius)
    sigma_s = spacing if sigma_s is None else float(sigma_s)
    if radius < 0 or sigma_s <= 0 or sigma_i <= 0:
        raise RiverbedError(f"guided densify needs radius >= 0 and positive sigmas (got {radius}, {sigma_s}, "
                            f"{sigma_i})")
    ptr, cols = lidar_rows(np.where(valid, sparse, np.nan))
    out = np.empty(sparse.shape, np.float32)
    wsum = np.empty(sparse.shape, np.float64)
    _guided_kernel(np.where(valid, sparse, 0).astype(np.float32), ptr, cols,
                   np.ascontiguousarray(guide), radius, 1.0 / (2.0 * sigma_s * sigma_s),
                   1.0 / (2.0 * sigma_i * sigma_i * guide.shape[2]), out, wsum)
    weak = ~(wsum >= min_weight)
    if weak.any():
        out[weak] = interpolate_nearest(sparse)[weak]
    return out


def densify(sparse, method="linear", image=None, **kwargs):
    """A dense disparity map from sparse LiDAR alone: ``method`` is ``nearest``, ``linear``, ``planes`` or ``guided``
    (which needs the left ``image``). (H, W) float32, no NaN."""
    if method not in METHODS:
        raise RiverbedError(f"unknown densify method '{method}' (use one of {', '.join(METHODS)})")
    if method == "guided":
        if image is None:
            raise RiverbedError("densify method guided needs the left image (--image)")
        return densify_guided(sparse, image, **kwargs)
    if kwargs:
        raise RiverbedError(f"densify method {method} takes no settings ({', '.join(kwargs)})")
    if method == "planes":
        return interpolate_planes(sparse)
    return interpolate_nearest(sparse) if method == "nearest" else interpolate_linear(sparse)
