"""Hidden point removal for projected LiDAR: a z-buffer with a small footprint, and Katz et al. 2007 HPR.

Both take the points that already won their pixel (the nearest point per pixel, see
:func:`riverbed_cli.geometry.projection.project_cloud`) and tell which of them are visible from a camera.

* :func:`zbuffer_visible`: every point is splatted as a disc of radius ``radius`` px at its depth; a point is hidden
  when a nearer point's splat covers its pixel and is nearer by more than ``tolerance`` times the point's depth.
  The disc closes the gaps between sparse LiDAR samples of a surface, through which points behind it would
  otherwise show; the relative tolerance keeps points of the same, slanted surface.
* :func:`hpr_visible`: Katz, Tal, Basri, "Direct visibility of point sets" (SIGGRAPH 2007): spherical flipping
  ``p' = p + 2 (R - |p|) p / |p|`` about the viewpoint with ``R = max|p| * 10**gamma``, then the convex hull of the
  flipped points and the viewpoint; the points on the hull are visible.

docs/projection.md gives the measured comparison; the z-buffer is the default.
"""

import logging

import cv2
import numpy as np

log = logging.getLogger(__name__)

#: Defaults chosen by measurement (docs/projection.md).
ZBUFFER_RADIUS = 2
ZBUFFER_TOLERANCE = 0.03
HPR_GAMMA = 2.0


def nearest_depth_image(rows, cols, depth, shape):
    """``H x W`` float32 image of the smallest depth per pixel (inf where no point lands)."""
    H, W = shape
    img = np.full(H * W, np.inf, np.float32)
    if rows.size:
        lin = rows.astype(np.int64) * W + cols.astype(np.int64)
        order = np.lexsort((depth, lin))
        lin_sorted = lin[order]
        first = np.ones(lin_sorted.size, bool)
        first[1:] = lin_sorted[1:] != lin_sorted[:-1]
        img[lin_sorted[first]] = depth[order][first]
    return img.reshape(H, W)


def zbuffer_visible(rows, cols, depth, shape, radius=ZBUFFER_RADIUS, tolerance=ZBUFFER_TOLERANCE):
    """Visibility by a z-buffer whose points are discs of ``radius`` px.

    Parameters
    ----------
    rows, cols : (N,) int
        Pixel of each point (in the camera the depths refer to).
    depth : (N,) float
        Depth along that camera's optical axis (> 0).
    shape : (H, W)
    radius : int
        Splat radius in pixels (0: plain per-pixel z-buffer).
    tolerance : float
        A covering point must be nearer by more than ``tolerance * depth`` to hide a point.

    Returns
    -------
    visible : (N,) bool
    """
    depth = np.asarray(depth, np.float64)
    zimg = nearest_depth_image(rows, cols, depth.astype(np.float32), shape)
    if radius > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        zimg = cv2.erode(zimg, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=float("inf"))
    return depth - zimg[rows, cols] <= tolerance * depth


def hpr_visible(xyz, viewpoint, gamma=HPR_GAMMA):
    """Katz et al. 2007 hidden point removal: which points of ``xyz`` (N, 3) are visible from ``viewpoint``.

    ``gamma`` sets the flipping radius ``R = max|p - viewpoint| * 10**gamma`` (larger: more points visible).
    """
    from scipy.spatial import ConvexHull
    from scipy.spatial import QhullError

    p = np.asarray(xyz, np.float64) - np.asarray(viewpoint, np.float64)
    n = p.shape[0]
    visible = np.ones(n, bool)
    if n < 4:
        return visible
    norm = np.linalg.norm(p, axis=1)
    norm = np.maximum(norm, 1e-12)
    R = norm.max() * 10.0 ** gamma
    flipped = p + (2.0 * (R - norm) / norm)[:, None] * p
    try:
        hull = ConvexHull(np.vstack([flipped, np.zeros((1, 3))]))
    except QhullError as e:
        log.warning("HPR: convex hull failed (%s); all %d points kept", str(e).splitlines()[0], n)
        return visible
    visible[:] = False
    v = hull.vertices
    visible[v[v < n]] = True
    return visible
