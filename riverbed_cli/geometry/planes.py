"""Local-plane interpolation of sparse LiDAR disparities, without a triangulation.

Each pixel takes the least-squares plane of its nearest LiDAR point and that point's natural neighbours (the points
whose Voronoi cells touch its own), evaluated at the pixel: a piecewise-planar surface that follows the local slope and
averages the LiDAR's noise over about seven points. A LiDAR pixel keeps its own value.

Everything comes from one labelled distance transform (OpenCV's ``distanceTransformWithLabels``, 5 x 5 mask): each
pixel's nearest point (its Voronoi cell) and the distance to it, and, from the cells that touch, each point's natural
neighbours - the neighbours of the Delaunay triangulation, found without one. With the fusion's sigma it costs a
third to a half of the CPU time of the Delaunay route of :func:`~riverbed_cli.geometry.interpolation.linear_fill`
(17.5 against 47 ms on the 18 500 points of the 740 x 500 speed pair; OpenCV's single-threaded incremental
triangulation alone took 11-17 ms), which the fusion (:mod:`riverbed_cli.matching.fusion`) runs beside the matcher on
every match (docs/fusion.md). The transform's distances are those of its 5 x 5 mask (within 2 % of the Euclidean
distance), so where two points are almost equally near a pixel, the one it names may be the farther by up to 3 %.

Conventions: the left image is the reference, ``d = x_left - x_right`` (px); NaN marks no LiDAR.
"""

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import prange

from ..runtime.kernel import kernel
from .coverage import lidar_points
from .interpolation import checked_points

#: most natural neighbours kept per point (a point has about 6; more only where many points ring one at one distance)
NEIGHBOUR_CAP = 32


def nearest_labels(rows, cols, shape):
    """Each pixel's nearest LiDAR point and its distance: ``(anchor, distance)``, (H, W) int32 (index into the
    row-major ``rows``, ``cols``) and float32 (px), from OpenCV's labelled distance transform (``DIST_L2``, 5 x 5 mask:
    distances within 2 % of the Euclidean ones)."""
    H, W = shape
    src = np.full((H, W), 255, np.uint8)
    src[rows, cols] = 0
    dist, labels = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    n = len(rows)
    at = labels[rows, cols]
    if np.array_equal(at, np.arange(1, n + 1, dtype=at.dtype)):  # OpenCV numbers the zero pixels in row-major order
        return labels - 1, dist
    index = np.empty(int(at.max()) + 1, np.int32)  # any other numbering: through the labels of the points
    index[at] = np.arange(n, dtype=np.int32)
    return index[labels], dist


@kernel(inline=True)
def _touching_cells(anchor, n, cap):
    # Pairs of 4-adjacent pixels with different anchors: their points are natural neighbours. Scanned in order, each
    # pair offered once per run of equal pairs (a cell boundary along the row repeats its vertical pair); a point's
    # list is short, so it is searched for duplicates. A row first marks, without branches, where it meets another
    # cell (to the right, below) and lists those pixels; the scan then visits only them, in the same order (a branch
    # on every pixel pair missed at each cell boundary).
    H, W = anchor.shape
    nb = np.full((n, cap), -1, np.int32)
    cnt = np.zeros(n, np.int32)
    flags = np.zeros(W, np.int64)
    at = np.zeros(W, np.int64)
    for y in range(H):
        m = 0
        for x in range(W):
            a = anchor[y, x]
            right = x + 1 < W and anchor[y, min(x + 1, W - 1)] != a
            down = y + 1 < H and anchor[min(y + 1, H - 1), x] != a
            f = np.int64(right) | (np.int64(down) << 1)
            flags[x] = f
            at[m] = x
            m += f != 0
        last_a = np.full(2, -1, np.int64)  # the last pair offered, horizontal and vertical
        last_b = np.full(2, -1, np.int64)
        for t in range(m):
            x = at[t]
            a = anchor[y, x]
            for k in range(2):
                if not flags[x] & (1 << k):
                    continue
                b = anchor[y, x + 1] if k == 0 else anchor[y + 1, x]
                if a == last_a[k] and b == last_b[k]:
                    continue
                last_a[k] = a
                last_b[k] = b
                for side in range(2):
                    p, q = (a, b) if side == 0 else (b, a)
                    # the whole list compared at once (its empty slots hold -1, never a point), no branch per entry
                    seen = False
                    for j in range(cap):
                        seen |= nb[p, j] == q
                    if not seen and cnt[p] < cap:
                        nb[p, cnt[p]] = q
                        cnt[p] += 1
    return nb, cnt


@kernel(inline=True)
def _second_ring(rows, cols, nb, cnt, fewest):
    # a point with fewer than `fewest` neighbours (its cell cut by an image corner) also takes the nearest of its
    # neighbours' neighbours, up to `fewest`: a plane needs three
    n, cap = nb.shape
    for i in range(n):
        while cnt[i] < min(fewest, cap):
            best = -1
            bd = 0
            for j in range(cnt[i]):
                p = nb[i, j]
                for t in range(cnt[p]):
                    q = nb[p, t]
                    if q == i:
                        continue
                    known = False
                    for u in range(cnt[i]):
                        if nb[i, u] == q:
                            known = True
                            break
                    if known:
                        continue
                    d = (rows[q] - rows[i]) ** 2 + (cols[q] - cols[i]) ** 2
                    if best < 0 or d < bd or (d == bd and q < best):
                        best = q
                        bd = d
            if best < 0:
                break
            nb[i, cnt[i]] = best  # one way only: the others' lists stay their own cells' neighbours
            cnt[i] += 1


@kernel(parallel=True)
def _natural_neighbours(anchor, rows, cols, cap, fewest):
    # natural_neighbours in one kernel (a fresh process loads each cached kernel for 3-4 ms): the cells' scan and the
    # corners' second ring in order, then each point's list sorted in parallel
    nb, cnt = _touching_cells(anchor, rows.shape[0], cap)
    _second_ring(rows, cols, nb, cnt, fewest)
    return nb, cnt, _sort_by_distance(rows, cols, nb, cnt)


@kernel(parallel=True, inline=True)
def _sort_by_distance(rows, cols, nb, cnt):
    # each point's neighbours nearest first (ties: the lower index), in place; and the nearest one's distance (px)
    n = nb.shape[0]
    nearest = np.full(n, np.inf)
    for i in prange(n):
        m = cnt[i]
        for t in range(1, m):  # insertion sort: a handful of neighbours
            q = nb[i, t]
            dq = (rows[q] - rows[i]) ** 2 + (cols[q] - cols[i]) ** 2
            j = t - 1
            while j >= 0:
                p = nb[i, j]
                dp = (rows[p] - rows[i]) ** 2 + (cols[p] - cols[i]) ** 2
                if dp < dq or (dp == dq and p < q):
                    break
                nb[i, j + 1] = p
                j -= 1
            nb[i, j + 1] = q
        if m:
            q = nb[i, 0]
            nearest[i] = math.sqrt((rows[q] - rows[i]) ** 2 + (cols[q] - cols[i]) ** 2)
    return nearest


def natural_neighbours(anchor, rows, cols, cap=NEIGHBOUR_CAP):
    """Each LiDAR point's natural neighbours, nearest first: ``(nb, count, nearest)`` with ``nb`` (n, cap) int32
    (padded with -1), ``count`` (n,) int32 and ``nearest`` (n,) float64, the distance to the nearest point (px; inf
    for a lone point). ``anchor``: each pixel's nearest point (:func:`nearest_labels`). Two points are natural
    neighbours where their cells (the pixels nearest to each) touch along a pixel edge: the discrete Voronoi diagram's
    neighbours, the Delaunay triangulation's edges but for cells that meet at a corner only. A point with fewer than
    three (an image corner cuts its cell) also takes the nearest of its neighbours' neighbours, up to three."""
    rows = np.asarray(rows, np.int64)
    cols = np.asarray(cols, np.int64)
    return _natural_neighbours(np.ascontiguousarray(anchor, np.int32), rows, cols, int(cap), 3)


@kernel(parallel=True)
def plane_fit(rows, cols, values, nb, cnt, k, self_weight, weighted):
    """Per point ``i``, the least-squares plane ``d = c + a dx + b dy`` (``dx``, ``dy``: px from the point) through
    its first ``min(k, cnt[i])`` neighbours ``nb[i]`` and, with weight ``self_weight``, itself: ``(c, a, b)``,
    float64. ``weighted``: a neighbour at squared distance ``r2`` weighs ``r2_nearest / r2`` (the nearest 1), else
    every neighbour 1. A tiny ridge (1e-3) on the slopes keeps collinear neighbours solvable; the solve is Cramer's
    rule (no LAPACK: thousands of 3 x 3 solves through BLAS threads fought Numba's for the cores). Where the system is
    singular the plane is flat at the point's value."""
    n = rows.shape[0]
    c = np.empty(n, np.float64)
    ga = np.zeros(n, np.float64)
    gb = np.zeros(n, np.float64)
    for i in prange(n):
        m = min(k, cnt[i])
        r2min = 1.0
        if weighted and m:
            q = nb[i, 0]
            r2min = (cols[q] - cols[i]) ** 2 + (rows[q] - rows[i]) ** 2
        sxx = 1e-3
        sxy = 0.0
        sx = 0.0
        syy = 1e-3
        sy = 0.0
        s1 = self_weight
        bx = 0.0
        by = 0.0
        b1 = self_weight * values[i]
        for j in range(m):
            q = nb[i, j]
            dx = cols[q] - cols[i]
            dy = rows[q] - rows[i]
            v = values[q]
            w = r2min / (dx * dx + dy * dy) if weighted else 1.0
            sxx += w * dx * dx
            sxy += w * dx * dy
            sx += w * dx
            syy += w * dy * dy
            sy += w * dy
            s1 += w
            bx += w * dx * v
            by += w * dy * v
            b1 += w * v
        det = sxx * (syy * s1 - sy * sy) - sxy * (sxy * s1 - sy * sx) + sx * (sxy * sy - syy * sx)
        if det != 0.0:
            c[i] = (sxx * (syy * b1 - by * sy) - sxy * (sxy * b1 - by * sx) + bx * (sxy * sy - syy * sx)) / det
            ga[i] = (bx * (syy * s1 - sy * sy) - sxy * (by * s1 - sy * b1) + sx * (by * sy - syy * b1)) / det
            gb[i] = (sxx * (by * s1 - b1 * sy) - bx * (sxy * s1 - sy * sx) + sx * (sxy * b1 - by * sx)) / det
        else:
            c[i] = values[i]
    return c, ga, gb


@kernel(parallel=True)
def _on_planes(anchor, rows, cols, c, ga, gb):
    # each pixel on its nearest point's plane
    H, W = anchor.shape
    out = np.empty((H, W), np.float32)
    for y in prange(H):
        for x in range(W):
            a = anchor[y, x]
            out[y, x] = np.float32(c[a] + ga[a] * (x - cols[a]) + gb[a] * (y - rows[a]))
    return out


@dataclass
class PlaneFill:
    """:func:`plane_fill`: ``values`` (H, W) float32, the interpolation; ``anchor`` (H, W) int32, each pixel's nearest
    LiDAR point (index into ``points``); ``distance`` (H, W) float32, px to it; ``neighbours``, ``count``,
    ``nearest``: each point's natural neighbours (:func:`natural_neighbours`); ``points``: the LiDAR's
    ``(rows, cols, values)``."""

    values: np.ndarray
    anchor: np.ndarray
    distance: np.ndarray
    neighbours: np.ndarray
    count: np.ndarray
    nearest: np.ndarray
    points: tuple


def plane_fill(sparse, points=None, neighbours=6):
    """Local-plane interpolation of the LiDAR pixels (module docstring), and each pixel's nearest point
    (:class:`PlaneFill`). A pixel takes the plane fitted to its nearest point (weight 1) and that point's
    ``neighbours`` nearest natural neighbours, each weighing ``r_nearest^2 / r^2``; ``points``: the LiDAR's
    ``(rows, cols, values)`` (:func:`~riverbed_cli.geometry.coverage.lidar_points`) if already found."""
    sparse, _ = checked_points(sparse)
    rows, cols, values = lidar_points(sparse) if points is None else points
    anchor, dist = nearest_labels(rows, cols, sparse.shape)
    nb, cnt, nearest = natural_neighbours(anchor, rows, cols)
    r, c = np.asarray(rows, np.float64), np.asarray(cols, np.float64)
    v = np.asarray(values, np.float64)
    c0, ga, gb = plane_fit(r, c, v, nb, cnt, int(neighbours), 1.0, True)
    out = _on_planes(anchor, r, c, c0, ga, gb)
    out[rows, cols] = values
    return PlaneFill(out, anchor, dist, nb, cnt, nearest, (rows, cols, values))


def interpolate_planes(sparse):
    """Local-plane interpolation of the LiDAR pixels (:func:`plane_fill`). (H, W) float32, no NaN."""
    return plane_fill(sparse).values
