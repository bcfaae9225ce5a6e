"""LiDAR tubes: each pixel's disparity search range from the projected LiDAR around it.

The rule (``docs/tubes.md`` measures it and its alternatives): with ``s = 1 / sqrt(p)`` the mean LiDAR spacing (px;
``p`` the LiDAR share), a pixel's tube at level ``k = 0, 1, ...`` is ``[min - m_k, max + m_k]`` of the LiDAR
disparities within ``R_k = reach * s * 2^k`` px of it (a square window of ``cell`` px cells), with the margin
``m_k = margin + k * level_margin`` growing with the distance the LiDAR had to be taken from. The first level that
holds LiDAR sets the tube; a pixel with none within the last level searches the full nominal range. Every tube is
clipped to the nominal range. LiDAR sparser than ``max_spacing`` px (mean spacing) bounds no pixel: objects smaller
than its spacing go unsampled and their disparity can lie outside every nearby point's (KITTI at 0.16 % of its GT:
the tubes held the truth at 91 % of the pixels), so every pixel searches the nominal range.
Across a depth edge the window holds both surfaces, so the tube spans both.

A tube volume holds each pixel's tube only, one after the other in a flat array
(:class:`~riverbed_cli.matching.volume.TubeLayout`): its size is the sum of the tube widths.
"""

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit, prange

from ..errors import RiverbedError
from ..records import RecordMapping
from .guidance import lidar_share


@dataclass
class TubeStats(RecordMapping):
    """``mean_width`` (px, of the tubes), ``max_width`` (the widest), ``nominal`` (the nominal range's
    disparities), ``full_share`` (share of pixels searching the nominal range)."""

    mean_width: float
    max_width: int
    nominal: int
    full_share: float


def _window_extrema(cmin, cmax, r):
    # min / max over (2r + 1)^2 cells, the window cut at the image border (a replicated border changes no extremum)
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    lo = cv2.erode(np.ascontiguousarray(cmin, np.float32), kernel, borderType=cv2.BORDER_REPLICATE)
    hi = cv2.dilate(np.ascontiguousarray(cmax, np.float32), kernel, borderType=cv2.BORDER_REPLICATE)
    return lo, hi


def lidar_tubes(sparse, d_min, d_max, reach=2.0, margin=2.0, levels=3, level_margin=4.0, cell=4, share=None,
                max_spacing=40.0):
    """Per-pixel disparity tubes from sparse LiDAR disparities (module docstring).

    Parameters
    ----------
    sparse : (H, W) float
        LiDAR disparities of the left image (``d = x_left - x_right``), NaN elsewhere.
    d_min, d_max : int
        Nominal range (inclusive); every tube lies inside it.
    reach : float
        Radius of the first level, in mean LiDAR spacings.
    margin, level_margin : float
        Margin (px of disparity) at level 0, and its growth per level.
    levels : int
        Levels tried before a pixel falls back to the nominal range.
    cell : int
        Side (px) of the cells the LiDAR extrema are gathered in.
    share : float, optional
        LiDAR share (default: :func:`~riverbed_cli.matching.guidance.lidar_share` of ``sparse``).
    max_spacing : float
        Mean LiDAR spacing (px) beyond which every pixel searches the nominal range.

    Returns
    -------
    lo, hi : (H, W) int32
        Inclusive tube ends (disparity px).
    """
    sparse = np.asarray(sparse, dtype=np.float32)
    H, W = sparse.shape
    d_min, d_max = int(d_min), int(d_max)
    if d_max < d_min:
        raise RiverbedError(f"empty disparity range [{d_min}, {d_max}]")
    valid = np.isfinite(sparse)
    lo = np.full((H, W), d_min, np.int32)
    hi = np.full((H, W), d_max, np.int32)
    if not valid.any():
        return lo, hi
    share = lidar_share(sparse) if share is None else share
    spacing = 1.0 / math.sqrt(max(share, 1e-12))
    cell = max(1, int(cell))
    cmin, cmax = _cell_extrema(sparse, cell)
    tlo, thi = cell_tubes(cmin, cmax, d_min, d_max, spacing, reach, margin, levels, level_margin, cell, max_spacing)
    _expand_cells(tlo.astype(np.int32), thi.astype(np.int32), cell, lo, hi)
    return lo, hi


@njit(cache=True)
def _cell_extrema(sparse, cell):
    # min and max of the finite values of each cell x cell cell (+inf / -inf: none)
    H, W = sparse.shape
    ch, cw = -(-H // cell), -(-W // cell)
    cmin = np.full((ch, cw), np.inf, np.float32)
    cmax = np.full((ch, cw), -np.inf, np.float32)
    for y in range(H):
        for x in range(W):
            v = sparse[y, x]
            if np.isfinite(v):
                cy, cx = y // cell, x // cell
                cmin[cy, cx] = min(cmin[cy, cx], v)
                cmax[cy, cx] = max(cmax[cy, cx], v)
    return cmin, cmax


@njit(cache=True, parallel=True)
def _expand_cells(tlo, thi, cell, lo, hi):
    # every pixel takes its cell's tube
    H, W = lo.shape
    for y in prange(H):
        for x in range(W):
            lo[y, x] = tlo[y // cell, x // cell]
            hi[y, x] = thi[y // cell, x // cell]


def cell_tubes(cmin, cmax, d_min, d_max, spacing, reach=2.0, margin=2.0, levels=3, level_margin=4.0, cell=4,
               max_spacing=40.0):
    """The tube rule on cells: ``cmin``/``cmax`` the LiDAR extrema per ``cell`` x ``cell`` cell (+-inf: none);
    returns the cells' inclusive tube ends (int64), clipped to ``[d_min, d_max]``."""
    ch, cw = cmin.shape
    done = np.zeros((ch, cw), bool)
    tlo = np.full((ch, cw), d_min, np.int64)
    thi = np.full((ch, cw), d_max, np.int64)
    if spacing > max_spacing:
        return tlo, thi
    for k in range(int(levels)):
        r = max(1, int(math.ceil(reach * spacing * 2 ** k / cell)))
        wlo, whi = _window_extrema(cmin, cmax, r)
        new = ~done & np.isfinite(wlo)
        m = margin + k * level_margin
        tlo[new] = np.floor(wlo[new] - m)
        thi[new] = np.ceil(whi[new] + m)
        done |= new
        if done.all():
            break
    return np.clip(tlo, d_min, d_max), np.clip(thi, d_min, d_max)


def cell_widths_from_points(rows, cols, values, shape, d_min, d_max, share, tube):
    """Tube widths per cell (int64 ``ceil(H / cell) x ceil(W / cell)``) from the LiDAR points (pixel rows, columns,
    disparities) of an image of ``shape``: the tube rule without an image-sized array, for planning tiles."""
    cell = max(1, int(tube["cell"]))
    ch, cw = -(-shape[0] // cell), -(-shape[1] // cell)
    cmin = np.full((ch, cw), np.inf, np.float32)
    cmax = np.full((ch, cw), -np.inf, np.float32)
    keep = (values >= d_min) & (values <= d_max)
    r, c, v = rows[keep] // cell, cols[keep] // cell, values[keep].astype(np.float32)
    np.minimum.at(cmin, (r, c), v)
    np.maximum.at(cmax, (r, c), v)
    spacing = 1.0 / math.sqrt(max(share, 1e-12))
    tlo, thi = cell_tubes(cmin, cmax, d_min, d_max, spacing, **tube)
    return thi - tlo + 1


def tube_reach_px(share, reach=2.0, levels=3, cell=4, **_):
    """How far (px) the tube rule looks for LiDAR: the last level's radius, rounded up to whole cells, plus a cell."""
    spacing = 1.0 / math.sqrt(max(share, 1e-12))
    r = max(1, int(math.ceil(reach * spacing * 2 ** (int(levels) - 1) / max(1, int(cell)))))
    return (r + 1) * max(1, int(cell))


def lidar_tubes_window(sparse, y0, y1, x0, x1, d_min, d_max, share, tube):
    """:func:`lidar_tubes` of the window ``[y0:y1, x0:x1]`` of a whole-image sparse map (an array or anything
    sliced like one, e.g. a windowed raster), equal to the whole image's tubes there: the LiDAR is read with the
    rule's reach around the window, on cells aligned with the image's. ``tube`` holds the rule's settings."""
    H, W = sparse.shape[:2]
    cell = max(1, int(tube["cell"]))
    R = tube_reach_px(share, **tube)
    ya, xa = max(0, (y0 - R) // cell * cell), max(0, (x0 - R) // cell * cell)
    yb, xb = min(H, y1 + R), min(W, x1 + R)
    crop = np.asarray(sparse[ya:yb, xa:xb], np.float32)
    lo, hi = lidar_tubes(crop, d_min, d_max, share=share, **tube)
    return lo[y0 - ya:y1 - ya, x0 - xa:x1 - xa], hi[y0 - ya:y1 - ya, x0 - xa:x1 - xa]


def tube_stats(layout, d_min, d_max):
    """:class:`TubeStats` of a :class:`~riverbed_cli.matching.volume.TubeLayout` over the nominal range."""
    D = int(d_max) - int(d_min) + 1
    w = layout.width
    return TubeStats(round(float(w.mean()), 3) if w.size else float(D), int(layout.max_width), D,
                     round(float((w >= D).mean()), 5) if w.size else 1.0)
