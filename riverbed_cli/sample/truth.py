"""Ground truth: the disparity of the rectified pair (NaN where the right camera does not see the point) and the
DSM (surface height on a north-up grid over the left image's footprint)."""

import math

import numpy as np

from ..products.dsm import Grid
from .raycast import cast_rays, surface_height
from .spec import NODATA


def ground_truth_disparity(scene, hits, left, right, P_right, tolerance=1e-3):
    """Disparity ``d = x_left - x_right`` of each left pixel's surface point; NaN where the right camera cannot see it.

    A point is hidden when the ray from the right camera towards it meets the surface more than ``tolerance`` m
    before it; points outside the right image are NaN too.

    Returns
    -------
    disp : (H, W) float64
    occluded : (H, W) bool
        Hidden from the right camera (inside the right image's field of view).
    """
    H, W = hits.shape[:2]
    X = hits.reshape(-1, 3)
    ok = np.isfinite(X[:, 0])
    Xh = np.hstack([X, np.ones((len(X), 1))])
    with np.errstate(invalid="ignore", divide="ignore"):
        uvw = Xh @ P_right.T
        xr = uvw[:, 0] / uvw[:, 2]
        yr = uvw[:, 1] / uvw[:, 2]
    inside = ok & (xr >= -0.5) & (xr < W - 0.5) & (yr >= -0.5) & (yr < H - 0.5)
    vec = X[inside] - right.C
    dist = np.linalg.norm(vec, axis=1)
    t = cast_rays(scene, np.broadcast_to(right.C, vec.shape), vec / dist[:, None], 0.0, dist + 1.0)
    visible = (t < 0) | (t >= dist - tolerance)
    cols = np.tile(np.arange(W, dtype=np.float64), H)
    disp = np.full(H * W, np.nan)
    idx = np.flatnonzero(inside)
    disp[idx[visible]] = cols[idx[visible]] - xr[idx[visible]]
    occluded = np.zeros(H * W, bool)
    occluded[idx[~visible]] = True
    return disp.reshape(H, W), occluded.reshape(H, W)


def ground_truth_dsm(scene, left, hits, resolution):
    """The surface height on a north-up grid covering the left image's footprint.

    Returns
    -------
    dsm : (rows, cols) float32
        World heights at cell centres; :data:`NODATA` where the cell centre's surface point is outside the left
        image (or the scene).
    grid : riverbed_cli.products.dsm.Grid
        Cells of ``resolution`` m (which should divide 1 m), bounds snapped outwards to whole metres (world
        coordinates).
    """
    ox, oy, oz = scene.origin
    X = hits.reshape(-1, 3)
    X = X[np.isfinite(X[:, 0])]
    # Whole-metre bounds (exact in binary, on the lattice of any resolution dividing 1 m).
    xmin, xmax = math.floor(X[:, 0].min() + ox), math.ceil(X[:, 0].max() + ox)
    ymin, ymax = math.floor(X[:, 1].min() + oy), math.ceil(X[:, 1].max() + oy)
    grid = Grid(float(xmin), float(ymax), resolution, round((xmax - xmin) / resolution),
                round((ymax - ymin) / resolution))
    cols = grid.xmin + (np.arange(grid.width) + 0.5) * grid.resolution - ox
    rows = grid.ymax - (np.arange(grid.height) + 0.5) * grid.resolution - oy
    gx, gy = np.meshgrid(cols, rows)
    z = surface_height(scene, gx, gy)
    pts = np.stack([gx.ravel(), gy.ravel(), z.ravel()], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        x, y, depth = left.project(pts)
    inside = (x >= -0.5) & (x < left.width - 0.5) & (y >= -0.5) & (y < left.height - 0.5) & (depth > 0)
    dsm = np.where(inside.reshape(z.shape) & np.isfinite(z), z + oz, NODATA).astype(np.float32)
    return dsm, grid
