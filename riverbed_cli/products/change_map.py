"""The change map: where the surface the images show differs from the LiDAR's, in map coordinates.

Stage: ``(disparity, the LiDAR disparities given to the match, its LiDAR mask, pair) -> height changes on a grid``.
The LiDAR check of ``riverbed match`` (:mod:`~riverbed_cli.matching.lidar_check`) drops the points of regions the
images contradict and marks them in ``--lidar-mask`` (3: a point dropped in a changed region). At each such pixel
the LiDAR's disparity (less its offset against the match where the match used it, :func:`lidar_offset`: the
offset ``riverbed match`` removed) and the match's are triangulated along the same ray; the change is the height of the match's
point minus the LiDAR's (m: positive where something was built or grew since the LiDAR flight, negative where it
was torn down or cut), placed where the match puts the surface. The map holds the median change per cell of the
DSM's grid, NaN elsewhere.
"""

import numpy as np

from ..errors import RiverbedError
from ..io.images import read_image
from ..matching.lidar_check import MASK_LABELS
from .dsm import Accumulator, disparity_points

#: the mask values of a LiDAR point the match used, and of one dropped in a changed region
USED_POINT = next(k for k, v in MASK_LABELS.items() if v == "used")
CHANGED_POINT = next(k for k, v in MASK_LABELS.items() if v == "changed region")


def read_lidar_mask(path, shape):
    """A ``riverbed match --lidar-mask`` PNG, checked against the disparity map's ``shape``: (H, W) uint8."""
    mask = read_image(path)
    if mask.ndim != 2 or mask.dtype != np.uint8:
        raise RiverbedError("not a LiDAR mask (a single-band 8-bit PNG from riverbed match --lidar-mask)", path)
    if mask.shape != tuple(shape):
        raise RiverbedError(f"LiDAR mask is {mask.shape[1]}x{mask.shape[0]} but the disparity map is "
                            f"{shape[1]}x{shape[0]} (W x H)", path)
    if int(mask.max(initial=0)) > max(MASK_LABELS):
        raise RiverbedError(f"not a LiDAR mask: values up to {int(mask.max())} (riverbed match --lidar-mask writes "
                            f"0 to {max(MASK_LABELS)})", path)
    return mask


def lidar_offset(disp, sparse, mask):
    """The LiDAR's disparity offset against the match where the check used it (``mask`` 1): the median of LiDAR
    minus match (px; 0 without such points). ``riverbed match`` removes the LiDAR's offset before it guides
    (:mod:`~riverbed_cli.matching.lidar_offset`); the change is measured against the LiDAR so registered."""
    used = (mask == USED_POINT) & np.isfinite(sparse) & np.isfinite(disp)
    return float(np.median(sparse[used] - disp[used])) if used.any() else 0.0


def change_points(disp, sparse, mask, pair, offset=0.0):
    """At the LiDAR points dropped in a changed region (``mask`` 3) where the match has a disparity: the match's
    points ``x, y`` (world, the pair's CRS) and the height change ``dz`` (m, match minus the LiDAR less its
    disparity ``offset``), float64 each."""
    sel = (mask == CHANGED_POINT) & np.isfinite(sparse) & np.isfinite(disp)
    now = np.where(sel, np.asarray(disp, np.float64), np.nan)
    then = np.where(sel, np.asarray(sparse, np.float64) - offset, np.nan)
    xyz_now, _, _ = disparity_points(now, pair)
    xyz_then, _, _ = disparity_points(then, pair)
    if len(xyz_now) != len(xyz_then):  # an RPC pair drops what it cannot intersect
        raise RiverbedError("the changed LiDAR points could not all be triangulated twice")
    ok = np.isfinite(xyz_now).all(axis=1) & np.isfinite(xyz_then).all(axis=1)
    return xyz_now[ok, 0], xyz_now[ok, 1], xyz_now[ok, 2] - xyz_then[ok, 2]


def change_map(couples, grid):
    """The median height change per cell of ``grid`` (float32, NaN where no changed point falls) over the
    ``couples`` ``(disparity, sparse, mask, pair)``, and its summary (``cells``, ``points``, ``median`` m)."""
    acc = Accumulator(grid, "median")
    dz_all, offsets = [], []
    for disp, sparse, mask, pair in couples:
        offsets.append(lidar_offset(disp, sparse, mask))
        x, y, dz = change_points(disp, sparse, mask, pair, offsets[-1])
        acc.add(x, y, dz)
        dz_all.append(dz)
    out = acc.result()
    dz = np.concatenate(dz_all) if dz_all else np.zeros(0)
    return out, {"cells": int(np.isfinite(out).sum()), "points": int(dz.size),
                 "median": round(float(np.median(dz)), 3) if dz.size else None,
                 "lidar_offset_px": [round(o, 3) for o in offsets]}
