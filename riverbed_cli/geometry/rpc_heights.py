"""The terrain's height range under a ROI of an RPC image: from a DEM, from LiDAR, or given (docs/rpc.md).

``riverbed rectify --rpc`` (``--dem``, ``--lidar``, ``--heights``) and block ``rpc:`` entries take the range from
here: the affine rectification is fitted on virtual matches over it and the rectified disparity range spans it.
"""

import math
import os

import numpy as np

from ..errors import RiverbedError
from ..io.lidar import class_mask, iter_lidar, lidar_info, resolve_crs
from .outliers import sor_inliers
from .rpc_dem import geoid_to_ellipsoid_transformer, read_dem
from .rpc_geometry import cloud_to_wgs84
from .rpc_rectify import heights_over_roi, rectify_rpc_pair
from .tie_points import rectification_check

#: Margin (m) added below and above the terrain's height range from a DEM or a LiDAR cloud.
HEIGHT_MARGIN_M = 20.0
#: The LiDAR's points under the ROI must fall in at least this share of the cells of a LIDAR_GRID x LIDAR_GRID
#: grid over the ROI for ``heights_from_lidar``; below it the cloud "does not cover the ROI".
LIDAR_MIN_COVER = 0.5
LIDAR_GRID = 8
#: At most this many of the points under the ROI (a seeded sample) go through the outlier filter.
LIDAR_SOR_POINTS = 2_000_000


def footprint_bounds(rpc, roi, h):
    """(lon_min, lat_min, lon_max, lat_max) of the ROI's border localised at height ``h`` (degrees)."""
    x, y, w, hh = roi
    t = np.linspace(0, 1, 9)
    cols = np.concatenate([x + t * (w - 1), x + t * (w - 1), np.full(9, x), np.full(9, x + w - 1)])
    rows = np.concatenate([np.full(9, y), np.full(9, y + hh - 1), y + t * (hh - 1), y + t * (hh - 1)])
    lon, lat = rpc.localize(cols, rows, h)
    if not (np.isfinite(lon).all() and np.isfinite(lat).all()):
        raise RiverbedError("the RPC model cannot localise the ROI (outside the model's domain)", rpc.source)
    return float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())


def heights_from_dem(rpc_left, roi, dem_path, vertical=None, margin_m=20.0):
    """The terrain's ellipsoidal height range (m) under the left ROI from a DEM, widened by ``margin_m``.

    The DEM must cover the ROI's footprint at the model's mean height (checked before reading: a one-line error
    naming the DEM) and the footprint on the terrain (:func:`~riverbed_cli.geometry.rpc_rectify.heights_over_roi`).
    """
    bounds = footprint_bounds(rpc_left, roi, rpc_left.height_off)
    dem = read_dem(dem_path, bounds=bounds, vertical=vertical, margin_deg=0.01)
    try:
        lo, hi = heights_over_roi(rpc_left, roi, dem, margin_m=margin_m)
    except RiverbedError:
        raise RiverbedError("the DEM does not cover the ROI's footprint on the terrain", dem_path) from None
    return (lo, hi), dem.vertical


def heights_from_lidar(rpc_left, roi, clouds, crs=None, classes=None, drop_classes=(7, 18),
                       margin_m=HEIGHT_MARGIN_M, chunk_size=1_000_000):
    """The terrain's ellipsoidal height range (m) under the left ROI from LiDAR clouds, widened by ``margin_m``.

    Every point (of the kept classes: ``classes``, all when None, minus ``drop_classes``, ASPRS noise by default)
    is converted to WGS 84 and ellipsoidal heights (:func:`~riverbed_cli.geometry.rpc_geometry.cloud_to_wgs84`,
    the file's CRS or ``crs``) and projected through the left RPC with its own height; the points landing inside
    the ROI give the range. The cloud must cover the ROI: its points must fall in at least
    :data:`LIDAR_MIN_COVER` of the cells of a :data:`LIDAR_GRID` x :data:`LIDAR_GRID` grid over the ROI, else a
    one-line :class:`RiverbedError` naming the (first) cloud. Unclassified noise (birds, multipath) would stretch
    the range, and the affine rectification fitted over it: the points under the ROI go through the statistical
    outlier filter ``riverbed project`` uses (:func:`~riverbed_cli.geometry.outliers.sor_inliers`, on local metric
    coordinates; at most :data:`LIDAR_SOR_POINTS` of them, a seeded sample), and the range is the inliers'.

    Parameters
    ----------
    rpc_left : RPCModel
        The left image's model (pixels of the left input file).
    roi : (col, row, width, height)
        The region of the left image (px).
    clouds : path or sequence of paths
        LAS/LAZ files (read in chunks).
    crs : str, optional
        The clouds' CRS when their files do not state it (3D or compound: the heights' datum must be known).

    Returns
    -------
    (lo, hi) : tuple of float
        Ellipsoidal heights (m), margins included.
    info : dict
        ``points`` under the ROI, ``points_read``, ``cover`` (share of the grid's cells with points), ``range``
        (the points' own min and max, m).
    """
    clouds = [clouds] if isinstance(clouds, (str, os.PathLike)) else list(clouds)
    x0, y0, w, h = roi
    n_read = n_in = 0
    kept = []
    cells = np.zeros(LIDAR_GRID * LIDAR_GRID, bool)
    for path in clouds:
        info = lidar_info(path)
        to_wgs = cloud_to_wgs84(resolve_crs(info, crs), path)
        for chunk in iter_lidar(path, chunk_size=chunk_size):
            xyz = np.asarray(chunk["xyz"], np.float64)
            n_read += xyz.shape[0]
            xyz = xyz[class_mask(chunk["classification"], classes, drop_classes)]
            lon, lat, hh = to_wgs(xyz[:, 0], xyz[:, 1], xyz[:, 2])
            col, row = rpc_left.project(lon, lat, hh)
            inside = (col >= x0 - 0.5) & (col < x0 + w - 0.5) & (row >= y0 - 0.5) & (row < y0 + h - 0.5)
            if not inside.any():
                continue
            n_in += int(inside.sum())
            kept.append(np.stack([lon[inside], lat[inside], hh[inside]], axis=1))
            gi = np.clip(((col[inside] - x0 + 0.5) * LIDAR_GRID / w).astype(np.int64), 0, LIDAR_GRID - 1)
            gj = np.clip(((row[inside] - y0 + 0.5) * LIDAR_GRID / h).astype(np.int64), 0, LIDAR_GRID - 1)
            cells[gj * LIDAR_GRID + gi] = True
    name = clouds[0] if len(clouds) == 1 else f"{clouds[0]} (and {len(clouds) - 1} more)"
    where = f"the ROI {x0},{y0},{w},{h} of the left image"
    if n_in == 0:
        raise RiverbedError(f"does not cover {where}: no point of the kept classes lands in it ({n_read} read)",
                            name)
    lo, hi, n_out = robust_height_range(np.concatenate(kept))
    cover = float(cells.mean())
    if cover < LIDAR_MIN_COVER:
        raise RiverbedError(f"does not cover {where}: its {n_in} points there fall in {cover:.0%} of an "
                            f"{LIDAR_GRID}x{LIDAR_GRID} grid over it (at least {LIDAR_MIN_COVER:.0%} needed)", name)
    return (lo - margin_m, hi + margin_m), {"points": n_in, "points_read": n_read, "cover": cover,
                                            "range": [lo, hi], "outliers": n_out}


def robust_height_range(llh, max_points=None, seed=0):
    """``(lo, hi, outliers)``: the height range (m) of the points ``llh`` (N, 3: lon, lat in degrees, height in m)
    without their statistical outliers (:func:`~riverbed_cli.geometry.outliers.sor_inliers` on local east / north /
    up metres, as seen from above), from a seeded sample of at most ``max_points`` (:data:`LIDAR_SOR_POINTS`)."""
    max_points = LIDAR_SOR_POINTS if max_points is None else int(max_points)
    if llh.shape[0] > max_points:
        llh = llh[np.random.default_rng(seed).choice(llh.shape[0], max_points, replace=False)]
    lat0 = float(np.median(llh[:, 1]))
    east = (llh[:, 0] - float(np.median(llh[:, 0]))) * 111_320.0 * math.cos(math.radians(lat0))
    north = (llh[:, 1] - lat0) * 110_574.0
    xyz = np.stack([east, north, llh[:, 2] - float(np.median(llh[:, 2]))], axis=1)
    keep = sor_inliers(xyz, np.ones(xyz.shape[0]))
    h = llh[keep, 2] if keep.any() else llh[:, 2]
    return float(h.min()), float(h.max()), int((~keep).sum())


def heights_to_ellipsoid(heights, rpc_left, roi, vertical):
    """``--heights`` in a vertical datum -> ellipsoidal heights (m) at the ROI's centre; unchanged for ellipsoid."""
    if vertical is None or str(vertical).lower() in ("ellipsoid", "ellipsoidal", "epsg:4979"):
        return tuple(float(v) for v in heights)
    try:
        tr = geoid_to_ellipsoid_transformer(vertical)
    except RiverbedError as e:
        raise RiverbedError(f"--vertical: {e}") from None
    x, y, w, h = roi
    lon, lat = rpc_left.localize(x + (w - 1) / 2, y + (h - 1) / 2, float(np.mean(heights)))
    _, _, out = tr.transform([float(lon)] * 2, [float(lat)] * 2, list(heights))
    return float(out[0]), float(out[1])


#: the margin (px) rectify_rpc_pair puts below the lowest virtual match's disparity
FRAME_MARGIN_PX = 5.0
#: the frames of the tie-point search are widened by at most this many pixels
MAX_WIDENING_PX = 20_000


def heights_from_tie_points(rpc_left, rpc_right, roi, rectified, margin_m=20.0):
    """The ``(lo, hi)`` ellipsoidal height range (m) the images themselves show over the left ROI, without a DEM or
    LiDAR (as s2p's tie-point range): the pair rectified over the left model's height domain (``height_off +-
    height_scale``), the disparity range of its tie points
    (:func:`~riverbed_cli.geometry.tie_points.rectification_check`) turned into heights by the rectification's
    disparity per metre, widened by ``margin_m`` and kept inside the domain.

    ``rectified(H_left, H_right, size)`` returns the two images resampled by those affinities into frames of
    ``size`` (w, h) and their valid areas: both frames are widened by the domain's disparity span, the right one
    shifted by it, so that every height of the domain keeps its matches inside them. Returns the range and the
    number of tie points; too few tie points is a :class:`RiverbedError`.
    """
    domain = (rpc_left.height_off - rpc_left.height_scale, rpc_left.height_off + rpc_left.height_scale)
    rect = rectify_rpc_pair(rpc_left, rpc_right, roi, domain, margin_px=FRAME_MARGIN_PX)
    w, h = rect.size
    span = int(min(math.ceil(rect.disparity[1]), MAX_WIDENING_PX))
    shift = np.array([[1.0, 0.0, span], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    left, right, valid = rectified(rect.H_left, shift @ rect.H_right, (w + span, h))
    check = rectification_check(left, right, valid_areas=valid)
    if "disparity" not in check:
        raise RiverbedError(f"{check['tie_points']} tie points between the images: too few to find the terrain's "
                            "height range; give --dem, --heights or --lidar")
    k = rect.info["disparity_per_metre"]
    # the frame puts the lowest virtual match's disparity at its margin: height is linear in disparity from there
    hs = [domain[0] + (d + span - FRAME_MARGIN_PX) / k for d in check["disparity"]]
    return (max(min(hs) - margin_m, domain[0]), min(max(hs) + margin_m, domain[1])), check["tie_points"]
