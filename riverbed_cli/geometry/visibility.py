"""Hidden point removal for projected LiDAR: a z-buffer with a small footprint, Katz et al. 2007 HPR, a 2.5-D test.

All three take the points that already won their pixel (the nearest point per pixel, see
:func:`riverbed_cli.geometry.projection.project_cloud`) and tell which of them are visible from a camera.

* :func:`zbuffer_visible`: every point is splatted as a disc of radius ``radius`` px; a point is hidden when
  a nearer point's splat covers its pixel with a disparity larger by more than ``tolerance`` px (the splat's
  disparity falls off by ``slope`` px per px from its centre). The disc closes the gaps between sparse LiDAR
  samples of a surface, through which points behind it would otherwise show; the tolerance and the slope keep
  points of the same, slanted surface. The default radius is per point (:func:`footprint_radii`), so it
  follows the LiDAR density. With ``edge_reach < 1`` a covered point stays hidden only when a splat covers it
  within ``edge_reach`` of that splat's radius, or when covering points surround it (no empty angle of 180 deg
  or more within ``SURROUND_RADIUS`` px): that keeps the background next to a depth edge, which nearer points
  cover from one side only (see :func:`zbuffer_visible`).
* :func:`hpr_visible`: Katz, Tal, Basri, "Direct visibility of point sets" (SIGGRAPH 2007): spherical flipping
  ``p' = p + 2 (R - |p|) p / |p|`` about the viewpoint with ``R = max|p| * 10**gamma``, then the convex hull
  of the flipped points and the viewpoint; the points on the hull are visible.

* :func:`surface_visible` (with :func:`surface_grid`): a 2.5-D test for aerial / nadir frames (world z up): a
  point is hidden when its segment to the camera passes more than a margin below a height grid built from the
  LiDAR itself.

docs/projection.md gives the measured comparison; the z-buffer is the default.
"""

import logging
import math

import numpy as np
from numba import prange
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError

from ..runtime.kernel import kernel

log = logging.getLogger(__name__)

#: Defaults chosen by measurement (docs/projection.md).
ZBUFFER_RADIUS = "auto"
ZBUFFER_TOLERANCE = 1.0  # px of disparity
ZBUFFER_SLOPE = 0.5  # px of disparity per px of image distance
ZBUFFER_K = 4
ZBUFFER_MAX_RADIUS = 8
#: One-sided reach of a splat, as a fraction of its radius (1: the whole disc hides, the default).
ZBUFFER_EDGE_REACH = 1.0
#: Radius (px) and angular sectors of the surround test used when ``edge_reach < 1``.
SURROUND_RADIUS = 12
SURROUND_SECTORS = 16
HPR_GAMMA = 3.5


def disc_offsets(radius):
    """Pixel offsets ``(dy, dx)`` with ``dy^2 + dx^2 <= radius^2``, sorted by distance; and the distances."""
    r = int(radius)
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    d2 = (dy * dy + dx * dx).ravel()
    keep = d2 <= r * r
    order = np.argsort(d2[keep], kind="stable")
    return (dy.ravel()[keep][order].astype(np.int64), dx.ravel()[keep][order].astype(np.int64),
            np.sqrt(d2[keep][order]).astype(np.float64))


@kernel
def _index_image(rows, cols, disp, H, W):
    """Index of the nearest point (largest disparity) per pixel (-1: none)."""
    img = np.full((H, W), -1, np.int32)
    for i in range(rows.shape[0]):
        j = img[rows[i], cols[i]]
        if j < 0 or disp[i] > disp[j]:
            img[rows[i], cols[i]] = i
    return img


@kernel
def _radii_kernel(img, rows, cols, disp, ody, odx, odist, k, tolerance, largest):
    """Distance to the k-th nearest same-or-nearer point, scanning pixels in order of distance (see below)."""
    H, W = img.shape
    n = rows.shape[0]
    out = np.empty(n, np.int64)
    for i in range(n):
        limit = disp[i] - tolerance
        same = 0
        seen = 0
        kth_any = -1.0
        r = -1.0
        for o in range(1, ody.shape[0]):  # offset 0 is the point's own pixel
            y = rows[i] + ody[o]
            x = cols[i] + odx[o]
            if y < 0 or y >= H or x < 0 or x >= W:
                continue
            j = img[y, x]
            if j < 0:
                continue
            seen += 1
            if seen == k:
                kth_any = odist[o]
            if disp[j] >= limit:
                same += 1
                if same == k:
                    r = odist[o]
                    break
            if seen >= 4 * k and kth_any >= 0:
                r = kth_any  # few neighbours of its own surface: the k-th of any depth
                break
        if r < 0:  # the scan ended first: the k-th of any depth, if any
            r = kth_any if kth_any >= 0 else float(largest)
        out[i] = min(max(math.ceil(r), 1), largest)
    return out


@kernel
def _splat_kernel(rows, cols, disp, radius, slope, H, W):
    """Largest ``d - slope * distance`` over the discs (radius per point) covering each pixel (-inf: none)."""
    cover = np.full((H, W), -np.inf, np.float32)
    for i in range(rows.shape[0]):
        r = radius[i]
        r2 = r * r
        for dy in range(-r, r + 1):
            y = rows[i] + dy
            if y < 0 or y >= H:
                continue
            for dx in range(-r, r + 1):
                x = cols[i] + dx
                e2 = dy * dy + dx * dx
                if x < 0 or x >= W or e2 > r2:
                    continue
                v = np.float32(disp[i] - slope * math.sqrt(e2))
                cover[y, x] = max(cover[y, x], v)
    return cover


@kernel
def _surround_kernel(cand, img, rows, cols, disp, radius, ody, odx, odist, slope, tolerance, reach, nsec):
    """For each candidate (a point some splat covers): still hidden under the edge-reach rule?

    Scans the nearest point of each pixel within the offsets (in order of distance) for covering points ``j``
    (``disp[j] - slope * e - disp[i] > tolerance``, ``e`` the image distance). Hidden when one of them is within
    ``reach * radius[j]``, or when their directions leave no empty run of ``nsec // 2`` sectors or more (no
    empty half-plane: ``i`` lies inside the nearer surface, not beside its edge).
    """
    H, W = img.shape
    out = np.zeros(cand.shape[0], np.bool_)
    bits = np.zeros(nsec, np.bool_)
    for a in range(cand.shape[0]):
        i = cand[a]
        bits[:] = False
        hidden = False
        for o in range(1, ody.shape[0]):
            y = rows[i] + ody[o]
            x = cols[i] + odx[o]
            if y < 0 or y >= H or x < 0 or x >= W:
                continue
            j = img[y, x]
            if j < 0:
                continue
            e = odist[o]
            if disp[j] - slope * e - disp[i] <= tolerance:
                continue
            if e <= reach * radius[j]:
                hidden = True
                break
            ang = math.atan2(float(ody[o]), float(odx[o]))
            bits[int((ang + math.pi) / (2.0 * math.pi) * nsec) % nsec] = True
        if not hidden:
            longest = 0
            run = 0
            for t in range(2 * nsec):  # the longest circular run of empty sectors
                if bits[t % nsec]:
                    run = 0
                else:
                    run += 1
                    longest = max(longest, run)
            hidden = longest < nsec // 2
        out[a] = hidden
    return out


def footprint_radii(rows, cols, disp, shape, k=ZBUFFER_K, tolerance=ZBUFFER_TOLERANCE,
                    largest=ZBUFFER_MAX_RADIUS):
    """Per-point splat radius (px): image distance to the ``k``-th nearest point of its surface or nearer.

    Neighbours whose disparity is more than ``tolerance`` px below the point's (farther) are ignored,
    so points behind a surface (which may be denser than the surface's own samples) do not shrink its
    splats. With samples at a share ``p`` of the pixels the ``k``-th neighbour lies about
    ``sqrt(k / (pi p))`` px away; ``k = 4`` closes the gaps of a randomly sampled surface at 99 %. Radii
    are rounded up and clipped to ``[1, largest]``; a point that meets ``4 k`` neighbours (or the end of
    the scan) before ``k`` of its own surface takes the ``k``-th nearest of any depth (``largest`` if
    there are fewer than ``k``). Neighbours are the nearest point of each pixel, scanned in order of
    distance up to ``largest`` px (a Numba kernel; the tests hold a k-d tree reference).
    """
    rows = np.ascontiguousarray(rows, np.int64)
    cols = np.ascontiguousarray(cols, np.int64)
    disp = np.ascontiguousarray(disp, np.float64)
    img = _index_image(rows, cols, disp, int(shape[0]), int(shape[1]))
    ody, odx, odist = disc_offsets(largest)
    return _radii_kernel(img, rows, cols, disp, ody, odx, odist, int(k), float(tolerance), int(largest))


def zbuffer_visible(rows, cols, disp, shape, radius="auto", tolerance=ZBUFFER_TOLERANCE, slope=ZBUFFER_SLOPE,
                    edge_reach=ZBUFFER_EDGE_REACH):
    """Visibility by a z-buffer whose points are discs (``dy^2 + dx^2 <= r^2``), compared in disparity.

    Each point covers the pixels of its disc with ``d - slope * e`` (``e``: distance to its centre, px): a
    point is hidden when that value exceeds its own disparity by more than ``tolerance`` px. Disparity, not
    depth: it is what the matcher uses (a point less than a pixel behind the surface misguides nobody), and
    its scale does not depend on the flying height (a 10 m building seen from 1000 m changes the depth by 1 %
    but the disparity by tens of pixels). ``slope`` spares slanted surfaces, whose disparity changes along
    the image (a road seen from a car: about 0.3 px per px).

    ``edge_reach < 1`` narrows what a splat hides on its own: a covered point stays hidden when a covering
    point (``d - slope * e`` above its own disparity by more than ``tolerance``) lies within ``edge_reach``
    times that point's radius, or when covering points within ``SURROUND_RADIUS`` px surround it (their
    directions, in ``SURROUND_SECTORS`` sectors, leave no empty half-plane). A point in a gap of a sparsely
    sampled surface is surrounded; the background beside a depth edge is covered from one side only and is
    kept. Right for LiDAR seen from (about) the camera's viewpoint; LiDAR from elsewhere (an aerial flight
    strip) also sees ground beside walls that the camera does not, and that is covered from one side only too
    (docs/projection.md: measured on Cones and the sample block).

    Parameters
    ----------
    rows, cols : (N,) int
        Pixel of each point in the view tested, inside ``shape``.
    disp : (N,) float
        Disparity ``x_left - x_right`` of each point (larger = nearer; the same value for either view).
    shape : (H, W)
    radius : int, (N,) int array or "auto"
        Splat radius in pixels (0: plain per-pixel z-buffer); ``"auto"``: :func:`footprint_radii`.
    tolerance : float
        Disparity margin (px).
    slope : float
        Disparity decrease of a splat per pixel from its centre.
    edge_reach : float
        One-sided reach of a splat as a fraction of its radius, in [0, 1]; 1 (default): the whole disc hides.

    Returns
    -------
    visible : (N,) bool
    """
    rows = np.ascontiguousarray(rows, np.int64)
    cols = np.ascontiguousarray(cols, np.int64)
    disp = np.ascontiguousarray(disp, np.float64)
    if isinstance(radius, str):
        radius = footprint_radii(rows, cols, disp, shape, tolerance=tolerance)
    radius = np.ascontiguousarray(np.broadcast_to(np.asarray(radius, np.int64), disp.shape))
    cover = _splat_kernel(rows, cols, disp, radius, float(slope), int(shape[0]), int(shape[1]))
    visible = cover[rows, cols] - disp <= tolerance
    if edge_reach >= 1.0:
        return visible
    cand = np.flatnonzero(~visible)
    img = _index_image(rows, cols, disp, int(shape[0]), int(shape[1]))
    ody, odx, odist = disc_offsets(SURROUND_RADIUS)
    hidden = _surround_kernel(cand, img, rows, cols, disp, radius, ody, odx, odist, float(slope), float(tolerance),
                              float(edge_reach), SURROUND_SECTORS)
    visible[cand[~hidden]] = True
    return visible


def hpr_visible(xyz, viewpoint, gamma=HPR_GAMMA):
    """Katz et al. 2007 hidden point removal: which points of ``xyz`` (N, 3) are visible from ``viewpoint``.

    ``gamma`` sets the flipping radius ``R = max|p - viewpoint| * 10**gamma`` (larger: more points visible).
    """
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


#: 2.5-D surface test (aerial / nadir frames), defaults chosen by measurement (docs/projection.md).
SURFACE_CELL = "auto"  # m, or "auto": SURFACE_CELL_SHARE of the LiDAR point spacing (surface_cell)
SURFACE_CELL_SHARE = 0.5
SURFACE_FILL = 2.0  # point spacings: empty cells this close to a point take the nearest cell's height
SURFACE_CLOSING = 1  # cells: radius of the grey closing that fills pits and gaps of the height grid
SURFACE_MARGIN = 0.5  # m the ray must pass below the surface to hide the point
#: Most cells of a surface grid (the cell grows beyond the point spacing to stay under it: bounded memory).
SURFACE_MAX_CELLS = 1 << 25


def surface_cell(xyz):
    """LiDAR point spacing in the horizontal plane (m): ``1 / sqrt(density)`` over the occupied area.

    The occupied area is the number of cells of side ``2 c0`` holding a point, ``c0`` the spacing over the
    bounding box; so empty parts of the box (outside a flight strip, water) do not inflate the spacing.
    """
    xy = np.asarray(xyz, np.float64)[:, :2]
    n = xy.shape[0]
    if n < 2:
        return 1.0
    lo = xy.min(axis=0)
    ext = np.maximum(xy.max(axis=0) - lo, 1e-9)
    c0 = 2.0 * max(math.sqrt(ext[0] * ext[1] / n), 1e-6)
    ij = np.floor((xy - lo) / c0).astype(np.int64)
    occupied = np.unique(ij[:, 0] * (int(ext[1] / c0) + 2) + ij[:, 1]).size
    return max(math.sqrt(occupied * c0 * c0 / n), 1e-6)


@kernel
def _grid_max(xyz, x0, y0, cell, nx, ny):
    grid = np.full((ny, nx), -np.inf, np.float64)
    for i in range(xyz.shape[0]):
        ix = int(math.floor((xyz[i, 0] - x0) / cell))
        iy = int(math.floor((xyz[i, 1] - y0) / cell))
        if 0 <= ix < nx and 0 <= iy < ny and xyz[i, 2] > grid[iy, ix]:
            grid[iy, ix] = xyz[i, 2]
    return grid


@kernel
def _filter(grid, r, take_max):
    """Max (``take_max``) or min filter over the (2r+1)^2 window, ignoring empty (-inf) cells."""
    ny, nx = grid.shape
    out = np.full((ny, nx), -np.inf, np.float64)
    for y in range(ny):
        for x in range(nx):
            best = -np.inf if take_max else np.inf
            for yy in range(max(y - r, 0), min(y + r + 1, ny)):
                for xx in range(max(x - r, 0), min(x + r + 1, nx)):
                    v = grid[yy, xx]
                    if v == -np.inf:
                        continue
                    if take_max:
                        best = max(best, v)
                    else:
                        best = min(best, v)
            if best != np.inf:
                out[y, x] = best
    return out


def surface_grid(xyz, cell=SURFACE_CELL, closing=SURFACE_CLOSING, fill=SURFACE_FILL):
    """Height grid of a point cloud: per-cell maximum height, gaps filled by the nearest cell, a grey closing.

    Parameters
    ----------
    xyz : (N, 3) float
        Points (m) in a frame whose third axis is vertical (up).
    cell : float or "auto"
        Cell side (m); auto: ``SURFACE_CELL_SHARE`` of :func:`surface_cell` (the point spacing). Grown if the
        grid would exceed ``SURFACE_MAX_CELLS`` cells.
    closing : int
        Radius (cells) of the grey closing (max filter, then min filter over the window ``2 closing + 1``):
        fills pits narrower than the window (last returns under a crown) and leaves step edges in place.
    fill : float
        Empty cells within ``fill`` point spacings of a point take the height of the nearest non-empty cell
        (a Voronoi surface: a wall lies halfway between the last roof and the first ground sample); farther
        ones stay -inf (no surface).

    Returns
    -------
    grid : (ny, nx) float64
        Surface height (m), -inf: none.
    origin : (2,) float64
        ``(x0, y0)`` of the grid's corner (m).
    cell : float
        Cell side (m).
    """
    xyz = np.ascontiguousarray(xyz, np.float64)
    spacing = surface_cell(xyz)
    cell = SURFACE_CELL_SHARE * spacing if isinstance(cell, str) else float(cell)
    lo = xyz[:, :2].min(axis=0) - cell
    ext = xyz[:, :2].max(axis=0) + cell - lo
    while (ext[0] / cell + 1) * (ext[1] / cell + 1) > SURFACE_MAX_CELLS:
        cell *= 2.0
    nx, ny = int(ext[0] / cell) + 1, int(ext[1] / cell) + 1
    grid = _grid_max(xyz, float(lo[0]), float(lo[1]), cell, nx, ny)
    empty = ~np.isfinite(grid)
    if fill > 0 and empty.any() and not empty.all():
        dist, (iy, ix) = ndimage.distance_transform_edt(empty, return_indices=True)
        near = dist * cell <= fill * spacing
        grid = np.where(near, grid[iy, ix], -np.inf)
        del dist, iy, ix
    if closing > 0:
        grid = _filter(_filter(grid, int(closing), True), int(closing), False)
    return grid, lo, cell


@kernel(parallel=True)
def _surface_kernel(xyz, centre, grid, x0, y0, cell, zmax, margin):
    """Per point: does the segment to ``centre`` pass more than ``margin`` below the grid (cell by cell)?

    An exact grid traversal (Amanatides & Woo 1987) of the segment's horizontal trace from the point's own
    cell; in each cell the ray is lowest where it enters (it rises towards the camera), and that height is
    compared with the cell's. The march ends where the ray is above ``zmax - margin`` (no surface can hide it
    higher up) or at the camera.
    """
    n = xyz.shape[0]
    ny, nx = grid.shape
    out = np.ones(n, np.bool_)
    for i in prange(n):
        px = xyz[i, 0]
        py = xyz[i, 1]
        pz = xyz[i, 2]
        dx = centre[0] - px
        dy = centre[1] - py
        dz = centre[2] - pz
        if not dz > 0.0:
            continue  # the camera is not above the point: the test does not apply
        t_end = min(1.0, (zmax - margin - pz) / dz)
        if not t_end > 0.0:
            continue
        fx = (px - x0) / cell
        fy = (py - y0) / cell
        ix = int(math.floor(fx))
        iy = int(math.floor(fy))
        gx = dx / cell
        gy = dy / cell
        sx = 1 if gx > 0 else -1
        sy = 1 if gy > 0 else -1
        if gx != 0.0:
            tx = ((ix + 1 - fx) / gx) if gx > 0 else ((fx - ix) / -gx)
            ddx = abs(1.0 / gx)
        else:
            tx = np.inf
            ddx = np.inf
        if gy != 0.0:
            ty = ((iy + 1 - fy) / gy) if gy > 0 else ((fy - iy) / -gy)
            ddy = abs(1.0 / gy)
        else:
            ty = np.inf
            ddy = np.inf
        t = 0.0
        while t < t_end:
            if 0 <= ix < nx and 0 <= iy < ny:
                if grid[iy, ix] - (pz + t * dz) > margin:
                    out[i] = False
                    break
            if tx < ty:
                t = tx
                tx += ddx
                ix += sx
            else:
                t = ty
                ty += ddy
                iy += sy
    return out


def surface_visible(xyz, centre, surface, margin=SURFACE_MARGIN):
    """2.5-D visibility: a point is hidden when its segment to the camera passes below the surface model.

    Valid where the world has a vertical axis (the third coordinate, up) and the surface is a height field
    seen from above: aerial / nadir frames. Points with the camera not above them are kept (not tested).

    Parameters
    ----------
    xyz : (N, 3) float
        Points (m), the frame of ``surface``.
    centre : (3,) float
        Camera centre (m).
    surface : tuple
        ``(grid, origin, cell)`` from :func:`surface_grid`.
    margin : float
        Height (m) by which the ray must pass below the surface to hide the point.

    Returns
    -------
    visible : (N,) bool
    """
    grid, origin, cell = surface
    xyz = np.ascontiguousarray(xyz, np.float64)
    finite = grid[np.isfinite(grid)]
    if xyz.shape[0] == 0 or finite.size == 0:
        return np.ones(xyz.shape[0], bool)
    return _surface_kernel(xyz, np.ascontiguousarray(centre, np.float64), grid, float(origin[0]),
                           float(origin[1]), float(cell), float(finite.max()), float(margin))


def visible_in_both(usable, rows, cols, xr, yr, code, side, visible_at):
    """Hidden point removal in the left view, the right one or both (``side``) for the projected points.

    ``usable``: points that land in both images; ``rows``, ``cols`` their left pixels, ``xr``, ``yr`` their right
    image positions and ``code`` their projection outcome (0 usable, 3 off the row: both still hide points in the
    right image); ``visible_at(rows, cols, mask, view)`` tests the points ``mask`` at those pixels of view 0
    (left) or 1 (right), or None for no test. Returns ``(visible, hidden_left, hidden_right)``.
    """
    visible = usable.copy()
    if visible_at is not None and side in ("left", "both"):
        visible &= visible_at(rows, cols, slice(None), 0)
    n_left = int(usable.sum() - visible.sum())
    if visible_at is not None and side in ("right", "both"):
        in_right = (code == 0) | (code == 3)  # points with a place in the right image hide others there
        vr = np.ones(usable.size, bool)
        vr[in_right] = visible_at(np.floor(yr[in_right] + 0.5).astype(np.int64),
                                  np.floor(xr[in_right] + 0.5).astype(np.int64), in_right, 1)
        visible &= vr
    return visible, n_left, int(usable.sum() - visible.sum()) - n_left
