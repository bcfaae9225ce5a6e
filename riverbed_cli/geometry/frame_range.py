"""The disparity range of a rectified frame pair from what is known of its terrain: a height range, a DEM or LiDAR
(``riverbed rectify --heights / --dem / --lidar``), written into its pair file for ``riverbed match --pair``.

Without any of them ``rectify`` takes the range its tie points show (:mod:`.tie_points`). With a height range
``[lo, hi]`` (m, on the pair's vertical axis), the left image's rays on a 21 x 21 grid are cut with the planes at
``lo`` and ``hi`` and the points projected into both cameras; with a DEM or LiDAR, the points are projected as
``riverbed project`` does (:func:`~riverbed_cli.geometry.projection.project_cloud`: only points both images see,
heights converted to the pair's vertical datum). Either range is widened by :data:`MARGIN_PX` at each end.
"""

import math

import numpy as np

from ..errors import RiverbedError
from .projection import project_cloud

#: px added at each end of the range
MARGIN_PX = 4
#: rays per image side for a height range
GRID = 21


def range_from_heights(pair, heights, shape):
    """``(d_min, d_max)`` (whole px) of ``pair`` (a :class:`~riverbed_cli.geometry.cameras.PairGeometry`, images of
    ``shape`` (H, W)) for terrain between ``heights`` ``(lo, hi)`` (m, world z: the cameras look down on it)."""
    lo, hi = (float(v) for v in heights)
    H, W = shape
    u, v = np.meshgrid(np.linspace(0, W - 1, GRID), np.linspace(0, H - 1, GRID))
    rays = np.linalg.solve(pair.P_left[:, :3], np.stack([u.ravel(), v.ravel(), np.ones(u.size)]))
    centre = pair.centres[0]
    d = []
    for h in (lo, hi):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (h - pair.origin[2] - centre[2]) / rays[2]
        xl, _, xr, depth = pair.project((centre[:, None] + t * rays).T)
        if not (np.isfinite(depth).all() and (depth > 0).all()):
            raise RiverbedError(f"--heights: the cameras do not look down on the terrain at {h:g} m (the plane is "
                                "not in front of the left camera everywhere in its view)")
        d.append(xl - xr)
    d = np.concatenate(d)
    return int(math.floor(d.min())) - MARGIN_PX, int(math.ceil(d.max())) + MARGIN_PX


def range_from_clouds(pair, clouds, shape, crs=None):
    """``(d_min, d_max)`` (whole px) of the points of ``clouds`` (LAS/LAZ files or DEM rasters) seen by both images
    of ``pair``, and how many there are."""
    lo, hi, n = math.inf, -math.inf, 0
    for cloud in clouds:
        _, st = project_cloud(cloud, pair, shape=shape, crs=crs)
        lo, hi, n = min(lo, st.d_range[0]), max(hi, st.d_range[1]), n + st.kept
    return int(math.floor(lo)) - MARGIN_PX, int(math.ceil(hi)) + MARGIN_PX, n
