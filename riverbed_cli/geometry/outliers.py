"""Statistical outlier removal (SOR) for LiDAR points that land in the image.

For each point, the mean distance to its ``k`` nearest neighbours, divided by the point's depth from the
camera (an angular spacing: a terrestrial scanner's spacing grows with range, which plain SOR would read as
outliers; for an aerial view the depth is nearly constant and this is the classic SOR). A point is an
outlier when that value exceeds ``median + n_sigma * sigma`` with ``sigma = max(1.4826 * MAD, 0.1 *
median)`` over all points (a robust mean + n sigma: the outliers themselves do not inflate the threshold; the
floor keeps the border of a regular grid, whose MAD is nearly 0). With ``k + 1`` points or fewer nothing is
removed. Defaults ``k = 8``, ``n_sigma = 5``: a point is an outlier when its
neighbours are more than 1.5 times (usually several times) as far as typical.

The points are the candidates kept per pixel (at most two per pixel, see
:func:`riverbed_cli.geometry.projection.project_cloud`), so memory is bounded by the image size whatever the
size of the cloud, and neighbours come from every chunk of the file. Points outside the image are not
neighbours: near the image border a point has fewer close neighbours, which the robust threshold tolerates.
"""

import math

import numpy as np
from numba import prange
from scipy.spatial import cKDTree

from ..runtime.kernel import kernel
from .visibility import disc_offsets

SOR_K = 8
SOR_SIGMA = 5.0
#: Floor of the robust sigma, relative to the median (a regular grid has MAD ~ 0: its border would go).
SOR_MIN_SIGMA = 0.1


def sor_inliers(xyz, depth, k=SOR_K, n_sigma=SOR_SIGMA):
    """Boolean mask of the points of ``xyz`` (N, 3) that are not statistical outliers.

    Parameters
    ----------
    xyz : (N, 3) float64
        Points in a metric frame (world minus origin).
    depth : (N,) float64
        Depth of each point from the camera (> 0), to turn distances into angular spacing.
    k : int
        Neighbours per point.
    n_sigma : float
        Threshold in robust standard deviations above the median.
    """
    xyz = np.asarray(xyz, np.float64)
    n = xyz.shape[0]
    if n <= k + 1:
        return np.ones(n, bool)
    tree = cKDTree(xyz)
    dist, _ = tree.query(xyz, k=k + 1, workers=-1)
    spacing = dist[:, 1:].mean(axis=1) / np.maximum(np.asarray(depth, np.float64), 1e-12)
    return _threshold(spacing, n_sigma)


#: Image-space search radius of :func:`sor_inliers_image` (px).
SOR_SEARCH_RADIUS = 24


@kernel(parallel=True)
def _sor_spacing_kernel(slots, pix, idx0, idx1, width, height, xyz, depth, ody, odx, odist, focal, k):
    """Mean distance to the k nearest (3D) candidates over depth, by an image scan (see sor_inliers_image)."""
    n = slots.shape[0]
    out = np.empty(n, np.float64)
    for i in prange(n):
        best = np.empty(k, np.float64)
        s = slots[i]
        r0 = pix[i] // width
        c0 = pix[i] % width
        for t in range(k):
            best[t] = np.inf
        seen = 0
        zs = max(depth[s], 1e-12)
        for o in range(ody.shape[0]):
            # Points farther in the image than the k-th best are (about) farther in 3D too: stop.
            if seen >= k and odist[o] / focal > best[k - 1] / zs:
                break
            y = r0 + ody[o]
            x = c0 + odx[o]
            if y < 0 or y >= height or x < 0 or x >= width:
                continue
            q = y * width + x
            for layer in range(2):
                t = idx0[q] if layer == 0 else idx1[q]
                if t < 0 or t == s:
                    continue
                seen += 1
                d = math.sqrt((xyz[t, 0] - xyz[s, 0]) ** 2 + (xyz[t, 1] - xyz[s, 1]) ** 2
                              + (xyz[t, 2] - xyz[s, 2]) ** 2)
                if d < best[k - 1]:
                    j = k - 1
                    while j > 0 and best[j - 1] > d:
                        best[j] = best[j - 1]
                        j -= 1
                    best[j] = d
        if seen == 0:
            out[i] = np.inf  # alone within the search radius
            continue
        m = min(seen, k)
        total = 0.0
        for t in range(m):
            total += best[t]
        out[i] = total / m / zs
    return out


def sor_inliers_image(slots, pix, idx0, idx1, shape, xyz, depth, focal, k=SOR_K, n_sigma=SOR_SIGMA):
    """:func:`sor_inliers` for the candidates of a per-pixel z-buffer, with neighbours searched in the image.

    The ``k`` nearest neighbours (in 3D) of a candidate are searched among the candidates of the pixels around
    it (both layers), scanned in order of pixel distance up to ``SOR_SEARCH_RADIUS`` px, and the scan stops
    once ``k`` are found and the next pixels are farther (as an angle, ``rho / focal``) than the ``k``-th best
    (``distance / depth``): a point at ``rho`` px from a point at depth ``z`` is at least about ``rho z / f``
    away unless it is much nearer the camera. So a point on a surface finds its surface neighbours (even among
    denser points behind it), and a point floating above the surface finds only far points. Linear in the
    number of candidates (a parallel Numba kernel), where a k-d tree over millions of candidates takes seconds
    (the tests compare both). A candidate with no other candidate within the search radius is an outlier,
    unless that is true of most candidates (LiDAR too sparse for the search radius): then the k-d tree version
    runs.

    Parameters
    ----------
    slots : (N,) int
        Candidate ids (rows of ``xyz`` and ``depth``).
    pix : (N,) int
        Their pixels, ``row * W + col``.
    idx0, idx1 : (H * W,) int
        The candidate ids of each pixel's two layers (-1: none).
    shape : (H, W)
    xyz, depth : (M, 3) and (M,) float64
        Coordinates and depths of all candidate ids.
    """
    n = len(slots)
    if n <= k + 1:
        return np.ones(n, bool)
    ody, odx, odist = disc_offsets(SOR_SEARCH_RADIUS)
    spacing = _sor_spacing_kernel(np.ascontiguousarray(slots, np.int64), np.ascontiguousarray(pix, np.int64),
                                  idx0, idx1, int(shape[1]), int(shape[0]), xyz, depth, ody, odx, odist,
                                  float(focal), int(k))
    if np.isinf(spacing).mean() > 0.5:
        return sor_inliers(xyz[slots], depth[slots], k, n_sigma)
    return _threshold(spacing, n_sigma)


def _threshold(spacing, n_sigma):
    finite = spacing[np.isfinite(spacing)]
    if finite.size == 0:
        return np.zeros(spacing.size, bool)
    med = float(np.median(finite))
    sigma = max(float(np.median(np.abs(finite - med))) * 1.4826, SOR_MIN_SIGMA * med)
    return spacing <= med + n_sigma * sigma


def layer_winners(first, inlier, idx1, first_pix):
    """Each pixel's projected point after outlier removal: its first-layer candidate (slots ``first``, at pixels
    ``first_pix``) when that is an inlier, else its second-layer candidate (``idx1[pixel]``, -1 for none) when that
    one is. Returns ``(winners, taken_back)``: the winning slots, and how many pixels their second layer took
    back from an outlier."""
    win = first.copy()
    lost = ~inlier[first]
    second = idx1[first_pix[lost]]
    second_ok = second >= 0
    second_ok[second_ok] = inlier[second[second_ok]]
    win[lost] = np.where(second_ok, second, -1)
    return win[win >= 0], int(second_ok.sum())
