"""LiDAR tubes: each pixel's disparity search range from the projected LiDAR around it.

The rule (``docs/tubes.md`` measures it and its alternatives): with ``s = 1 / sqrt(p)`` the mean LiDAR spacing (px;
``p`` the LiDAR share), a pixel's tube at level ``k = 0, 1, ...`` is ``[min - m_k, max + m_k]`` of the LiDAR
disparities within ``R_k = reach * s * 2^k`` px of it (a square window of ``cell`` px cells), with the margin
``m_k = margin + k * level_margin`` growing with the distance the LiDAR had to be taken from. The first level that
holds LiDAR sets the tube; a pixel with none within the last level searches the full nominal range. Every tube is
clipped to the nominal range.

*LiDAR beyond the nominal range* (a user's ``--max-disp`` that cuts off the near objects, say) does not guide the
cost, but it still tells where the disparity lies: at a level whose window holds points inside the range, those
points alone set the tube (a pixel whose disparity lies in the range belongs to their surfaces, not to one beyond
it); where the window holds points beyond the range only, the pixel's disparity lies beyond it too and the tube is
theirs clipped to the range, the disparities at its end, instead of the whole range (on the speed pair with the
LiDAR of the whole scene, a sixth of the pixels: the mean tube width 21.7 -> 6.9 px).

LiDAR sparser than ``max_spacing`` px (mean spacing) bounds no pixel: objects smaller
than its spacing go unsampled and their disparity can lie outside every nearby point's (KITTI at 0.16 % of its GT:
the tubes held the truth at 91 % of the pixels), so every pixel searches the nominal range.
Across a depth edge the window holds both surfaces, so the tube spans both.

*Holes* (``holes="coarse"``, opt-in): where no LiDAR lies within the last level (water, shadows, a sensor gap; on
the speed pair with its LiDAR cut at the nominal range, the foreground beyond it) the pixel's range comes from a coarse
stereo match instead of the nominal range, as SURE's tSGM takes its ranges from a coarser pyramid level: the pair
at half resolution, unguided census SGM, the min and max of its disparities within ``HOLE_WINDOW`` coarse pixels,
widened by ``HOLE_MARGIN`` px (:func:`hole_bounds`; the pipeline runs the coarse match). A hole pixel whose window
holds no valid coarse disparity keeps the nominal range.

A tube volume holds each pixel's tube only, one after the other in a flat array
(:class:`~riverbed_cli.matching.volume.TubeLayout`): its size is the sum of the tube widths.
"""

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import prange

from ..errors import RiverbedError
from ..records import RecordMapping
from ..runtime.kernel import kernel
from .guidance import lidar_share
from .volume import TubeLayout, band_pair_rows, band_pairs


@dataclass
class TubeStats(RecordMapping):
    """``mean_width`` (px, of the tubes), ``max_width`` (the widest), ``nominal`` (the nominal range's
    disparities), ``full_share`` (share of pixels searching the nominal range)."""

    mean_width: float
    max_width: int
    nominal: int
    full_share: float


#: coarse matches for holes: the pair downsampled by this factor
HOLE_FACTOR = 2
#: half side (coarse px) of the window whose coarse disparities bound a hole pixel's range
HOLE_WINDOW = 4
#: disparity margin (px, full resolution) around those coarse extrema
HOLE_MARGIN = 8.0


def _window_extrema(cmin, cmax, r):
    # min / max over (2r + 1)^2 cells, the window cut at the image border (a replicated border changes no extremum)
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    lo = cv2.erode(np.ascontiguousarray(cmin, np.float32), kernel, borderType=cv2.BORDER_REPLICATE)
    hi = cv2.dilate(np.ascontiguousarray(cmax, np.float32), kernel, borderType=cv2.BORDER_REPLICATE)
    return lo, hi


def lidar_tubes(sparse, d_min, d_max, reach=2.0, margin=2.0, levels=3, level_margin=4.0, cell=4, share=None,
                max_spacing=40.0, holes="full", return_holes=False):
    """Per-pixel disparity tubes from sparse LiDAR disparities (module docstring).

    Parameters
    ----------
    sparse : (H, W) float
        LiDAR disparities of the left image (``d = x_left - x_right``), NaN elsewhere; points outside the nominal
        range bound the pixels that have no point inside it within reach (module docstring).
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
        LiDAR share (default: :func:`~riverbed_cli.matching.guidance.lidar_share` of ``sparse``, every point).
    max_spacing : float
        Mean LiDAR spacing (px) beyond which every pixel searches the nominal range.
    holes : {"full", "coarse"}
        The rule's setting of what pixels with no LiDAR within reach search (accepted with the other
        ``TubeConfig`` fields); this function gives them the nominal range either way: the coarse ranges need the
        images (:func:`hole_bounds`, applied by the pipeline to the pixels of ``return_holes``).
    return_holes : bool
        Also return the (H, W) bool mask of those pixels (none when the LiDAR is sparser than ``max_spacing``:
        then no pixel is bounded by it).

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
    if not np.isfinite(sparse).any():
        lo, hi = np.full((H, W), d_min, np.int32), np.full((H, W), d_max, np.int32)
        return (lo, hi, np.zeros((H, W), bool)) if return_holes else (lo, hi)
    lo, hi = np.empty((H, W), np.int32), np.empty((H, W), np.int32)  # every pixel takes its cell's tube below
    cell = max(1, int(cell))
    tlo, thi, reached, spacing = _rule_on_cells(sparse, d_min, d_max, reach, margin, levels, level_margin, cell, share,
                                                max_spacing)
    _expand_cells(tlo.astype(np.int32), thi.astype(np.int32), cell, lo, hi)
    if not return_holes:
        return lo, hi
    # LiDAR sparser than max_spacing reaches no cell, and no pixel is a hole: all search the nominal range anyway
    hole = ~np.repeat(np.repeat(reached, cell, axis=0), cell, axis=1)[:H, :W] if spacing <= max_spacing else \
        np.zeros((H, W), bool)
    return lo, hi, hole


def lidar_tube_layout(sparse, d_min, d_max, reach=2.0, margin=2.0, levels=3, level_margin=4.0, cell=4, share=None,
                      max_spacing=40.0, holes="full"):
    """The :class:`~riverbed_cli.matching.volume.TubeLayout` of :func:`lidar_tubes`'s tubes (the same arguments but
    ``return_holes``), made from the rule's cells in one pass: no image-sized tube ends in between."""
    sparse = np.asarray(sparse, dtype=np.float32)
    H, W = sparse.shape
    d_min, d_max = int(d_min), int(d_max)
    if d_max < d_min or not np.isfinite(sparse).any():
        return TubeLayout.from_bounds(*lidar_tubes(sparse, d_min, d_max), d_min)
    cell = max(1, int(cell))
    tlo, thi = _rule_on_cells(sparse, d_min, d_max, reach, margin, levels, level_margin, cell, share, max_spacing)[:2]
    offset, width, start, size, wmax = _cells_layout(tlo, thi, cell, H, W, d_min)
    return TubeLayout(offset, width, start, int(size), int(wmax))


def _rule_on_cells(sparse, d_min, d_max, reach, margin, levels, level_margin, cell, share, max_spacing):
    # the rule's tube ends per cell (int64), which cells had LiDAR within reach, and the mean spacing (px)
    share = lidar_share(sparse) if share is None else share
    spacing = 1.0 / math.sqrt(max(share, 1e-12))
    cmin, cmax, omin, omax = _cell_extrema(sparse, cell, np.float32(d_min), np.float32(d_max))
    outside = (omin, omax) if np.isfinite(omin).any() else None
    tlo, thi, reached = _cell_tubes(cmin, cmax, d_min, d_max, spacing, reach, margin, levels, level_margin, cell,
                                    max_spacing, outside)
    return tlo, thi, reached, spacing


@kernel(parallel=True)
def _cells_layout(tlo, thi, cell, H, W, d_min):
    # TubeLayout.from_bounds of the cells' tubes expanded to their pixels: offsets and widths by rows in parallel,
    # each row's total, then each row's start indices from the running total before it
    offset = np.empty((H, W), np.int32)
    width = np.empty((H, W), np.int32)
    start = np.empty((H, W), np.int64)
    rows = np.zeros(H + 1, np.int64)
    widest = np.zeros(H, np.int64)
    m = band_pairs(H)
    for i in prange(m):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            cy = y // cell
            total = 0
            most = 0
            for cx in range(tlo.shape[1]):
                o = tlo[cy, cx] - d_min
                w = thi[cy, cx] - tlo[cy, cx] + 1
                most = max(most, w)
                for x in range(cx * cell, min(W, (cx + 1) * cell)):
                    offset[y, x] = o
                    width[y, x] = w
                    total += w
            rows[y + 1] = total
            widest[y] = most
    for y in range(H):
        rows[y + 1] += rows[y]
    for i in prange(m):
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            s = rows[y]
            for x in range(W):
                start[y, x] = s
                s += width[y, x]
    return offset, width, start, rows[H], widest.max() if H else 0


#: largest window (half side, px) of ranges from sparse disparities: a DSM cell or a spacing of more than 256 px
#: is too coarse to bound the pixels between them
MAX_RANGE_WINDOW = 256


def spacing_window(disp):
    """The window (half side, px) ranges from the sparse disparities ``disp`` need: their mean spacing
    ``sqrt(pixels / values)`` rounded up, at least 1 (``riverbed range-map --window auto``; a DSM's cells projected
    by ``riverbed project``): where the values are spread evenly, a window of that half side holds one around every
    pixel. :class:`RiverbedError` when that is more than ``MAX_RANGE_WINDOW``."""
    n = int(np.count_nonzero(np.isfinite(disp)))
    window = max(1, math.ceil(math.sqrt(disp.size / n))) if n else 1
    if window > MAX_RANGE_WINDOW:
        raise RiverbedError(f"the values are {window} px apart on average, more than {MAX_RANGE_WINDOW}: too sparse "
                            "to bound the pixels between them")
    return window


def ranges_from_disparity(disp, shape=None, window=2, margin=3.0):
    """Per-pixel disparity ranges from a disparity map: a previous run, or a coarser one (``riverbed range-map``,
    ``--range-map``; the coarse match of :func:`hole_bounds`).

    Parameters
    ----------
    disp : (h, w) float
        Disparities of the left image (px at its own resolution, ``d = x_left - x_right``; NaN: none).
    shape : (H, W), optional
        The size of the image to match: ``disp``'s (default) or an integer multiple ``f`` of it, rounded down (a map
        of the image downsampled by ``f``: its pixel ``(i, j)`` covers ``(f i .. f i + f - 1, ...)``, pixels past
        its last row or column take the last, and its disparities count ``f`` times).
    window : int
        Half side (px of ``disp``) of the window whose disparities bound a pixel's range.
    margin : float
        Disparity (px at ``shape``'s resolution) added on both sides of their extrema.

    Returns
    -------
    lo, hi : (H, W) float32
        ``f * min - margin`` and ``f * max + margin`` over the window, NaN where it holds no disparity.
    """
    disp = np.asarray(disp, np.float32)
    h, w = disp.shape
    H, W = (h, w) if shape is None else (int(shape[0]), int(shape[1]))
    factor = W // w
    if factor < 1 or H // factor != h or W // factor != w:
        raise RiverbedError(f"a {w}x{h} disparity map is not the {W}x{H} image downsampled by an integer factor")
    if window < 0 or margin < 0:
        raise RiverbedError(f"range window and margin must be >= 0, got {window} and {margin}")
    cmin, cmax, known, _ = _window_bounds(disp, (H, W), factor, window)
    lo = np.where(known, np.where(known, cmin, 0) * factor - margin, np.nan)
    hi = np.where(known, np.where(known, cmax, 0) * factor + margin, np.nan)
    return lo.astype(np.float32), hi.astype(np.float32)


def _window_bounds(disp, shape, factor, window):
    # the min and max of the finite values of disp within window px, at each pixel of shape (disp downsampled by
    # factor); known: where the window holds one; own: where the pixel's own value of disp is finite
    H, W = shape
    ok = np.isfinite(disp)
    cmin, cmax = _window_extrema(np.where(ok, disp, np.inf), np.where(ok, disp, -np.inf), int(window))
    at = np.ix_(np.minimum(np.arange(H) // factor, disp.shape[0] - 1),
                np.minimum(np.arange(W) // factor, disp.shape[1] - 1))
    cmin, cmax = cmin[at], cmax[at]
    return cmin, cmax, np.isfinite(cmin), ok[at]


@kernel
def range_map_summary(lo, hi):
    """A range map's pixels with both ends finite, those of them with ``lo > hi``, and their smallest ``lo`` and
    largest ``hi`` (float64): one pass, no copy (a memory map is read once)."""
    known = 0
    crossed = 0
    low = np.inf
    high = -np.inf
    for y in range(lo.shape[0]):
        for x in range(lo.shape[1]):
            a = np.float64(lo[y, x])
            b = np.float64(hi[y, x])
            if math.isfinite(a) and math.isfinite(b):
                known += 1
                crossed += a > b
                low = min(low, a)
                high = max(high, b)
    return known, crossed, low, high


def hole_bounds(coarse, shape, d_min, d_max, factor=HOLE_FACTOR, window=HOLE_WINDOW, margin=HOLE_MARGIN):
    """Per-pixel ranges from a coarse disparity map, for the pixels the LiDAR leaves on the nominal range.

    Parameters
    ----------
    coarse : (h, w) float
        Disparities of the left image downsampled by ``factor`` (coarse px, ``d = x_left - x_right``; NaN: no
        disparity). Coarse pixel ``(i, j)`` covers full-resolution pixels
        ``(factor i .. factor i + factor - 1, ...)``; pixels past the last coarse row or column take the last.
    shape : (H, W)
        Full-resolution image size.
    d_min, d_max : int
        Nominal range (inclusive, full-resolution px); the ranges are clipped to it.
    factor, window, margin
        Downsampling factor, half side (coarse px) of the window of coarse disparities, and the margin (px) added
        on both sides of their extrema times ``factor``.

    Returns
    -------
    lo, hi : (H, W) int32
        Inclusive range ends; the nominal range where the pixel's own coarse pixel has no disparity (its match lies
        outside the right image: the neighbours' disparities would send it to a wrong match inside it) or the
        window holds none.
    """
    cmin, cmax, known, own = _window_bounds(np.asarray(coarse, np.float32), shape, factor, window)
    known &= own
    lo = np.where(known, np.floor(np.where(known, cmin, 0) * factor - margin), d_min)
    hi = np.where(known, np.ceil(np.where(known, cmax, 0) * factor + margin), d_max)
    lo = np.clip(lo, d_min, d_max).astype(np.int32)
    hi = np.clip(hi, d_min, d_max).astype(np.int32)
    return lo, np.maximum(hi, lo)


@kernel(parallel=True)
def _cell_extrema(sparse, cell, d_min, d_max):
    # min and max of the finite values of each cell x cell cell (+inf / -inf: none): of those inside [d_min, d_max],
    # and of those outside it; a row of cells per parallel iteration (it alone writes them)
    H, W = sparse.shape
    ch, cw = -(-H // cell), -(-W // cell)
    cmin = np.full((ch, cw), np.inf, np.float32)
    cmax = np.full((ch, cw), -np.inf, np.float32)
    omin = np.full((ch, cw), np.inf, np.float32)
    omax = np.full((ch, cw), -np.inf, np.float32)
    for cy in prange(ch):
        for y in range(cy * cell, min(H, (cy + 1) * cell)):
            for x in range(W):
                v = sparse[y, x]
                if not np.isfinite(v):
                    continue
                cx = x // cell
                if d_min <= v <= d_max:
                    cmin[cy, cx] = min(cmin[cy, cx], v)
                    cmax[cy, cx] = max(cmax[cy, cx], v)
                else:
                    omin[cy, cx] = min(omin[cy, cx], v)
                    omax[cy, cx] = max(omax[cy, cx], v)
    return cmin, cmax, omin, omax


@kernel(parallel=True)
def _expand_cells(tlo, thi, cell, lo, hi):
    # every pixel takes its cell's tube; a row walks its cells (a division per pixel took most of the time)
    H, W = lo.shape
    for y in prange(H):
        cy = y // cell
        for cx in range(tlo.shape[1]):
            a = tlo[cy, cx]
            b = thi[cy, cx]
            for x in range(cx * cell, min(W, (cx + 1) * cell)):
                lo[y, x] = a
                hi[y, x] = b


def cell_tubes(cmin, cmax, d_min, d_max, spacing, reach=2.0, margin=2.0, levels=3, level_margin=4.0, cell=4,
               max_spacing=40.0, holes="full", outside=None):
    """The tube rule on cells: ``cmin``/``cmax`` the extrema per ``cell`` x ``cell`` cell of the LiDAR inside
    ``[d_min, d_max]`` (+-inf: none), ``outside`` those of the LiDAR outside it (or None); returns the cells'
    inclusive tube ends (int64), clipped to ``[d_min, d_max]`` (cells with no LiDAR within reach: the whole range,
    whatever ``holes`` says; see :func:`lidar_tubes`)."""
    return _cell_tubes(cmin, cmax, d_min, d_max, spacing, reach, margin, levels, level_margin, cell, max_spacing,
                       outside)[:2]


def _cell_tubes(cmin, cmax, d_min, d_max, spacing, reach, margin, levels, level_margin, cell, max_spacing,
                outside=None):
    # cell_tubes, and which cells had LiDAR within reach
    ch, cw = cmin.shape
    done = np.zeros((ch, cw), bool)
    tlo = np.full((ch, cw), d_min, np.int64)
    thi = np.full((ch, cw), d_max, np.int64)
    if spacing > max_spacing:
        return tlo, thi, done
    # at each level the points inside the range first; those outside only where none inside is within reach
    sources = [(cmin, cmax)] + ([outside] if outside is not None else [])
    for k in range(int(levels)):
        r = max(1, int(math.ceil(reach * spacing * 2 ** k / cell)))
        m = margin + k * level_margin
        for emin, emax in sources:
            wlo, whi = _window_extrema(emin, emax, r)
            new = ~done & np.isfinite(wlo)
            tlo[new] = np.floor(wlo[new] - m)
            thi[new] = np.ceil(whi[new] + m)
            done |= new
        if done.all():
            break
    return np.clip(tlo, d_min, d_max), np.clip(thi, d_min, d_max), done


def cell_widths_from_points(rows, cols, values, shape, d_min, d_max, share, tube):
    """Tube widths per cell (int64 ``ceil(H / cell) x ceil(W / cell)``) from the LiDAR points (pixel rows, columns,
    disparities) of an image of ``shape``: the tube rule without an image-sized array, for planning tiles."""
    cell = max(1, int(tube["cell"]))
    ch, cw = -(-shape[0] // cell), -(-shape[1] // cell)
    v = np.asarray(values, np.float32)
    inside = (v >= d_min) & (v <= d_max)
    extrema = []
    for sel in (inside, ~inside):  # the points inside the range, and those outside it (lidar_tubes)
        emin = np.full((ch, cw), np.inf, np.float32)
        emax = np.full((ch, cw), -np.inf, np.float32)
        np.minimum.at(emin, (rows[sel] // cell, cols[sel] // cell), v[sel])
        np.maximum.at(emax, (rows[sel] // cell, cols[sel] // cell), v[sel])
        extrema.append((emin, emax))
    spacing = 1.0 / math.sqrt(max(share, 1e-12))
    tlo, thi = cell_tubes(*extrema[0], d_min, d_max, spacing, **tube, outside=extrema[1] if (~inside).any() else None)
    return thi - tlo + 1


def tube_reach_px(share, reach=2.0, levels=3, cell=4, **_):
    """How far (px) the tube rule looks for LiDAR: the last level's radius, rounded up to whole cells, plus a cell."""
    spacing = 1.0 / math.sqrt(max(share, 1e-12))
    r = max(1, int(math.ceil(reach * spacing * 2 ** (int(levels) - 1) / max(1, int(cell)))))
    return (r + 1) * max(1, int(cell))


def lidar_tubes_window(sparse, y0, y1, x0, x1, d_min, d_max, share, tube, return_holes=False):
    """:func:`lidar_tubes` of the window ``[y0:y1, x0:x1]`` of a whole-image sparse map (an array or anything
    sliced like one, e.g. a windowed raster), equal to the whole image's tubes there: the LiDAR is read with the
    rule's reach around the window, on cells aligned with the image's. ``tube`` holds the rule's settings; with
    ``return_holes`` also the window's mask of pixels with no LiDAR within reach."""
    H, W = sparse.shape[:2]
    cell = max(1, int(tube["cell"]))
    R = tube_reach_px(share, **tube)
    ya, xa = max(0, (y0 - R) // cell * cell), max(0, (x0 - R) // cell * cell)
    yb, xb = min(H, y1 + R), min(W, x1 + R)
    crop = np.asarray(sparse[ya:yb, xa:xb], np.float32)
    out = lidar_tubes(crop, d_min, d_max, share=share, return_holes=return_holes, **tube)
    return tuple(a[y0 - ya:y1 - ya, x0 - xa:x1 - xa] for a in out)


def tube_stats(layout, d_min, d_max):
    """:class:`TubeStats` of a :class:`~riverbed_cli.matching.volume.TubeLayout` over the nominal range."""
    D = int(d_max) - int(d_min) + 1
    w = layout.width
    if not w.size:
        return TubeStats(float(D), int(layout.max_width), D, 1.0)
    # the mean width from the volume's size (the exact sum of the widths), the full share by a count: a fifth of
    # NumPy's means' time
    return TubeStats(round(layout.size / w.size, 3), int(layout.max_width), D,
                     round(np.count_nonzero(w >= D) / w.size, 5))
