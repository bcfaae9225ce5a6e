"""The LiDAR checked against the images before it guides: gross outliers and changed regions dropped.

Real LiDAR was flown months or years before the images: buildings were raised or torn down, trees grew or were
cut, and some points are plain wrong (birds, multipath, low points). Guided by such a point riverbed would follow
it: its tube never visits the true disparity and the fusion averages the error in. The images know better.

Stage: ``(left, right, LiDAR disparities, a coarse unguided match of the pair) -> (LiDAR kept, LidarCheck)``.

* **The images' alternative.** Each LiDAR point is compared with what the images say at its pixel: the coarse
  reference (an unguided census SGM of the pair at 1 / :data:`FACTOR` resolution over the whole range, with its
  left-right check), where it is valid and smooth around the point (its 3 x 3 coarse neighbourhood spans at most
  :data:`SMOOTH` px: no depth edge, where a coarse match fattens the foreground); else the median of the other
  LiDAR points within :data:`NEAR` spacings (the mean spacing: ``sqrt(pixels / points)``).
* **Disagreement.** A point disagrees when its disparity lies more than :data:`TAU` px from the alternative and the
  images prefer the alternative clearly: the best ``1 - ZNCC`` of a 5 x 5 patch within ``FACTOR`` px of it is at
  least :data:`MARGIN` below the cost at the LiDAR's disparity
  (:func:`~riverbed_cli.matching.lidar_offset.patch_costs`), or the LiDAR's patch leaves the right image where
  the alternative's correlates (``1 - ZNCC`` at most ``1 - MARGIN``). A flat patch prefers nothing: its LiDAR
  stays.
* **Occlusions and depth edges.** A disagreement the LiDAR around the point explains is not a change: a point
  behind the images' alternative with a LiDAR point to its right (within the disparity difference plus
  :data:`EDGE` px, one spacing up or down) at least as near as the alternative is hidden from the right image by
  that foreground; a point in front of it with a LiDAR point within ``EDGE`` px at the alternative sits beside a
  depth edge the coarse reference moved.
* **Changed regions.** Change comes in regions (a building, a stand of trees), and one disagreeing point may be the
  reference's mistake (:mod:`.lidar_regions`). The image is cut into square cells of :data:`CELL` spacings; a
  cell is a seed when at least ``REGION_SHARE`` of its points with a reference disagree with the same sign (at
  least ``MIN_POINTS``); seed cells are closed and grown into neighbouring cells where ``GROW_SHARE`` disagree that
  way. A group of cells is a change when it holds at least :data:`MIN_COMPARED` points with a reference, their median
  ``LiDAR - images`` lies beyond ``TAU`` and the images prefer the alternative by at least :data:`REGION_MARGIN`
  on average (a patch of the reference's own mistakes on repeated texture costs about the same either way). From
  its disagreeing points the change spreads to the points within ``NEAR`` spacings: through points the images
  contradict the same way (unless an occlusion or a moved depth edge explains it), through points where the
  reference lies off the LiDAR by the region's change (within ``TAU``) and the patch cannot tell (SGM carries the
  surface across a flat patch) or the disagreement is explained, through at most :data:`UNKNOWN_HOPS` in a row
  they cannot judge (each within :data:`SURFACE_STEP` px of the point before, and half the change: along the
  LiDAR's surface, not across the stale block's edge into the clean LiDAR around it), never through a point the
  reference confirms (within ``TAU``). A change is kept when the images contradict at least :data:`SEEN_SHARE` of
  the points it took other than those the reference alone contradicts. It then takes its fringe
  (:func:`~.lidar_regions.fringe`): a point the reference does not confirm joins when most of its neighbours on
  its own surface (within ``NEAR`` spacings and ``TAU`` px) are in the change. Every point it took is dropped.
* **Gross outliers.** A point outside the changes that no other LiDAR point within ``NEAR`` spacings supports
  (none lies within ``TAU`` px of it) is dropped when the images contradict it, or when it lies more than
  ``2 TAU`` px off both the median of those points and their least-squares plane (:func:`plane_at`: a point on
  a steep slope lies off the median, not off the plane; with no plane the neighbours are too few to outvote it)
  and the images do not vouch for it: the reference does not confirm it, and its patch does not vouch. A patch
  vouches when it correlates (cost at most :data:`VOUCH`), costs at least :data:`MARGIN` less than the best near
  the neighbours' median (a flat patch vouches for nothing) and costs no more than at every other whole disparity
  of the range more than ``FACTOR`` px from it (a low-contrast patch correlates by chance somewhere).
* **Downstream** (:func:`~riverbed_cli.matching.pipeline.match_pair`). The points dropped guide nothing, bound no
  tube and are not interpolated by the fusion. The changed area (a disc of one spacing round each changed point,
  closed over two) searches the whole range instead of the tubes of the LiDAR around it, and there the fusion keeps
  the stereo where it passed its left-right check (with the stereo's confidence); elsewhere in the area its value
  is the LiDAR's interpolation across the change, with confidence 0.

``--lidar-check off`` keeps every point (the paper's method). Conventions: the left image is the reference,
``d = x_left - x_right`` (px), NaN where there is no LiDAR; a change is ``LiDAR - images`` (px).
"""

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import prange

from ..io.images import effective_bits, to_grey
from ..records import RecordMapping
from ..runtime.kernel import kernel
from .lidar_offset import RADIUS, patch_costs
from .lidar_regions import cell_regions, changed_area, flood, fringe
from .range_maps import coarse_match, coarse_to_fine_match

#: the coarse reference's scale: 1 / FACTOR of the image's resolution
FACTOR = 2
#: LiDAR sparser than one point per MAX_SPACING x MAX_SPACING px is not checked: its neighbours lie too far apart to
#: support a point or make a region (dropping one of its points costs more than it can save)
MAX_SPACING = 16
#: the patch cost of a flat patch or one leaving the right image: it says nothing (an informative one is at most 2)
NO_INFO = 3.0
#: a point disagrees with the images when it lies more than this (px) from their alternative ...
TAU = 3.0
#: ... and the images' best patch cost near the alternative is at least this below its own (1 - ZNCC)
MARGIN = 0.1
#: a reference whose 3 x 3 coarse neighbourhood spans more than this (px, full resolution) is at a depth edge
SMOOTH = 3.0
#: how far (px) the half-resolution reference may move a depth edge: its census window's half width, doubled
EDGE = 8
#: the square (half side, in mean LiDAR spacings) whose other points give a point's neighbours' alternative and
#: its support
NEAR = 1.5
#: side of the cells regions are made of, in mean LiDAR spacings
CELL = 3.0
#: a changed region's points as a whole: the images' alternative costs at least this less than the LiDAR (mean
#: 1 - ZNCC); a patch of the reference's mistakes on repeated texture costs about the same either way
REGION_MARGIN = 0.2
#: a region is judged only on at least this many points with the reference's alternative (fewer: a patch of the
#: reference's own mistakes next to noisy or outlying LiDAR passed the other tests)
MIN_COMPARED = 16
#: a change is kept when the images contradict at least this share of its points (the rest it passed through;
#: the points the reference alone contradicts by the change do not count)
SEEN_SHARE = 0.3
#: a change spreads through at most this many LiDAR points in a row the images cannot judge ...
UNKNOWN_HOPS = 2
#: ... each within this many px of the point before (along the LiDAR's surface: a stale block's edge is a jump to
#: the clean LiDAR around it)
SURFACE_STEP = 3 * TAU
#: a point's own patch vouches for it only when it correlates: 1 - ZNCC at most this
VOUCH = 0.5


@dataclass
class CheckReport(RecordMapping):
    """What the check did: ``mode``; ``skipped`` (why it did not run, or None); ``points`` (LiDAR points checked),
    ``compared`` (those with an alternative from the images), ``disagree`` (of those, the ones the images
    contradict), ``outliers`` (single points dropped),
    ``changed`` (points dropped in changed regions), ``regions`` (changed areas), ``changed_share`` (share of the
    image's pixels in them), ``change`` (median ``LiDAR - images`` of the changed points with a reference, px)."""

    mode: str
    skipped: str = None
    points: int = 0
    compared: int = 0
    disagree: int = 0
    outliers: int = 0
    changed: int = 0
    regions: int = 0
    changed_share: float = 0.0
    change: float = None


@dataclass
class LidarCheck:
    """The check's outcome: ``report`` (:class:`CheckReport`), ``changed`` ((H, W) bool: the changed area; None
    when nothing changed), ``dropped`` ((H, W) uint8 per LiDAR pixel: 0 kept or no
    LiDAR, 1 outlier, 2 in a changed region)."""

    report: CheckReport
    changed: np.ndarray = None
    dropped: np.ndarray = None


def reference_at(reference, rows, cols, factor=FACTOR):
    """The coarse ``reference`` (float, NaN invalid, coarse px) at full-resolution pixels ``(rows, cols)``, in full
    px, NaN where it is invalid or not smooth (its 3 x 3 neighbourhood spans more than :data:`SMOOTH` px)."""
    h, w = reference.shape
    r = np.clip(np.asarray(rows) // factor, 0, h - 1)
    c = np.clip(np.asarray(cols) // factor, 0, w - 1)
    pad = np.pad(reference, 1, constant_values=np.nan)
    win = np.stack([pad[r + 1 + dy, c + 1 + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    with np.errstate(invalid="ignore"):
        span = (np.max(win, axis=0) - np.min(win, axis=0)) * factor
    out = reference[r, c].astype(np.float64) * factor
    out[~np.isfinite(span) | (span > SMOOTH)] = np.nan
    return out


def _costs(gl, gr, rows, cols, values, alt, factor):
    # 1 - ZNCC at each point's own disparity, and the best within factor px of its alternative; NO_INFO where the
    # patch is flat or leaves the right image (uncapped otherwise: at most 2)
    own = patch_costs(gl, gr, rows, cols, values.astype(np.float32), np.zeros(1), cap=NO_INFO)[:, 0]
    steps = np.arange(-factor, factor + 0.25, 0.5)
    # the alternative's costs: the patch at alt + s, written as offsets of the alternative's value
    best = patch_costs(gl, gr, rows, cols, alt.astype(np.float32), -steps, cap=NO_INFO).min(axis=1)
    return own, best


def _prefers(own, best, margin):
    # the images prefer the alternative clearly: both patches informative, the alternative's at least margin lower
    return (own < NO_INFO) & (best < NO_INFO) & (best + margin <= own)


def _unique(gl, gr, rows, cols, values, own, lo, hi, factor):
    # each point's patch cost own (at its disparity) no higher than the best at every whole disparity of
    # [lo, hi] more than factor px from it
    d = np.arange(math.floor(lo), math.ceil(hi) + 1, dtype=np.float64)
    costs = patch_costs(gl, gr, rows, cols, np.zeros(rows.size, np.float32), -d, cap=NO_INFO)
    costs[np.abs(d[None, :] - values[:, None]) <= factor] = np.inf
    return own <= costs.min(axis=1)


def _verdicts(gl, gr, rows, cols, values, alt, factor):
    # +1 / -1: the images contradict the point (LiDAR above / below them), 0: they agree or prefer nothing
    far = np.isfinite(alt) & (np.abs(values - alt) > TAU)
    out = np.zeros(values.size, np.int8)
    if not far.any():
        return out
    i = np.flatnonzero(far)
    own, best = _costs(gl, gr, rows[i], cols[i], values[i], alt[i], factor)
    # a disparity whose patch leaves the right image, where the alternative's correlates, is contradicted too
    xr = cols[i] - values[i]
    leaves = (xr < RADIUS) | (xr >= gl.shape[1] - RADIUS - 1)
    contradicted = _prefers(own, best, MARGIN) | (leaves & (best + MARGIN <= 1.0))
    out[i[contradicted]] = np.sign(values[i[contradicted]] - alt[i[contradicted]]).astype(np.int8)
    return out


@kernel(parallel=True)
def _explained_kernel(sparse, rows, cols, values, alt, band, edge, tau, out):
    # out[j]: the LiDAR around point j holds the images' alternative alt[j] (module docstring, "occlusions")
    H, W = sparse.shape
    for j in prange(rows.size):
        r, c, v, a = rows[j], cols[j], values[j], alt[j]
        if v < a:  # behind: a foreground point x' = x + (a - v) to the right hides it from the right image
            y0, y1, x0, x1 = r - band, r + band + 1, c + 1, c + int(math.ceil(a - v)) + edge + 1
        else:  # in front: the background beside a depth edge the coarse reference moved
            y0, y1, x0, x1 = r - edge, r + edge + 1, c - edge, c + edge + 1
        found = False
        for y in range(max(0, y0), min(H, y1)):
            for x in range(max(0, x0), min(W, x1)):
                s = sparse[y, x]
                if s == s and (s >= a - tau if v < a else abs(s - a) <= tau):
                    found = True
                    break
            if found:
                break
        out[j] = found


@kernel(parallel=True)
def _neighbour_kernel(sparse, rows, cols, radius, tau, around, supported):
    H, W = sparse.shape
    side = 2 * radius + 1
    for j in prange(rows.size):
        r, c = rows[j], cols[j]
        v = sparse[r, c]
        vals = np.empty(side * side, np.float32)
        k = 0
        ok = False
        for y in range(max(0, r - radius), min(H, r + radius + 1)):
            for x in range(max(0, c - radius), min(W, c + radius + 1)):
                s = sparse[y, x]
                if s == s and (y != r or x != c):
                    i = k  # kept sorted (a few points): insertion
                    while i > 0 and vals[i - 1] > s:
                        vals[i] = vals[i - 1]
                        i -= 1
                    vals[i] = s
                    k += 1
                    if abs(s - v) <= tau:
                        ok = True
        if k == 0:
            around[j] = np.nan
        elif k % 2:
            around[j] = vals[k // 2]
        else:
            around[j] = 0.5 * (np.float64(vals[k // 2 - 1]) + np.float64(vals[k // 2]))
        supported[j] = ok


def neighbour_stats(sparse, rows, cols, radius):
    """Per LiDAR point ``(rows, cols)`` of ``sparse``: the median of the other points within a square of ``radius``
    px (float64, NaN with none) and whether one of them lies within :data:`TAU` px of it (bool: a point no
    neighbour supports may be an outlier)."""
    around = np.empty(rows.size, np.float64)
    supported = np.empty(rows.size, np.bool_)
    _neighbour_kernel(np.ascontiguousarray(sparse, np.float32), np.asarray(rows, np.int64),
                      np.asarray(cols, np.int64), int(radius), np.float32(TAU), around, supported)
    return around, supported


@kernel(parallel=True)
def _plane_kernel(sparse, rows, cols, radius, out):
    # out[j]: the least-squares plane through the other points within the square of the radius round point j, at
    # its pixel (NaN with fewer than 3 points or all on a line); coordinates relative to the point, so the value
    # sought is the plane's constant term, by Cramer's rule on the 3 x 3 normal equations
    H, W = sparse.shape
    for j in prange(rows.size):
        r, c = rows[j], cols[j]
        n = sx = sy = sxx = syy = sxy = sv = sxv = syv = 0.0
        for y in range(max(0, r - radius), min(H, r + radius + 1)):
            for x in range(max(0, c - radius), min(W, c + radius + 1)):
                s = sparse[y, x]
                if s == s and (y != r or x != c):
                    dx, dy, v = np.float64(x - c), np.float64(y - r), np.float64(s)
                    n += 1.0
                    sx += dx
                    sy += dy
                    sxx += dx * dx
                    syy += dy * dy
                    sxy += dx * dy
                    sv += v
                    sxv += dx * v
                    syv += dy * v
        det = n * (sxx * syy - sxy * sxy) - sx * (sx * syy - sxy * sy) + sy * (sx * sxy - sxx * sy)
        if n < 3.0 or abs(det) <= 1e-9 * n * (sxx + syy + 1.0) ** 2:
            out[j] = np.nan
        else:
            out[j] = (sv * (sxx * syy - sxy * sxy) - sx * (sxv * syy - sxy * syv) + sy * (sxv * sxy - sxx * syv)) / det


def plane_at(sparse, rows, cols, radius):
    """Per LiDAR point ``(rows, cols)`` of ``sparse``: the least-squares plane through the other points within a
    square of ``radius`` px, evaluated at the point (float64 px, NaN with fewer than 3 of them or all on a line).
    A point on a steep slope lies off its neighbours' median but on their plane."""
    out = np.empty(len(rows), np.float64)
    _plane_kernel(np.ascontiguousarray(sparse, np.float32), np.asarray(rows, np.int64), np.asarray(cols, np.int64),
                  int(radius), out)
    return out


def _skip(n, shape):
    # why n points over an image of shape are not checked, or None
    if n < 9:
        return "fewer than 9 points"
    if shape[0] * shape[1] / n > MAX_SPACING ** 2:  # too far apart for a region or a neighbour to mean anything
        return f"sparser than one point per {MAX_SPACING} x {MAX_SPACING} px"
    return None


def check_lidar(left, right, sparse, reference, *, factor=FACTOR, bits=None, searched=None):
    """The LiDAR points the images do not contradict, and the :class:`LidarCheck` (module docstring).

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) arrays
        The rectified pair; the left image is the reference.
    sparse : (H, W) float
        LiDAR disparities of the left image (px, ``d = x_left - x_right``), NaN elsewhere.
    reference : (h, w) float
        An unguided match of the pair at ``1 / factor`` resolution (coarse px), NaN where it failed its
        left-right check.
    searched : (d_min, d_max), optional
        The range the reference searched (px): points outside it are not judged (the reference cannot see them).

    Returns
    -------
    (H, W) float32, LidarCheck
        The sparse map without the dropped points, and what was dropped.
    """
    sparse = np.asarray(sparse, np.float32)
    shape = sparse.shape
    rows, cols = np.nonzero(np.isfinite(sparse))
    values = sparse[rows, cols].astype(np.float64)
    n = values.size
    why = _skip(n, shape)
    if why is not None:
        return sparse, LidarCheck(CheckReport("auto", why, points=int(n)))
    bits = effective_bits(left) if bits is None else bits
    gl, gr = to_grey(left, bits), to_grey(right, bits)
    spacing = math.sqrt(shape[0] * shape[1] / n)
    near = max(1, int(math.ceil(NEAR * spacing)))
    around, supported = neighbour_stats(sparse, rows, cols, near)
    alt = reference_at(reference, rows, cols, factor)
    if searched is not None:  # the reference cannot see a point outside its range: nothing judges it
        outside = (values < searched[0]) | (values > searched[1])
        alt[outside], around[outside] = np.nan, np.nan
    from_ref = np.isfinite(alt)
    alt = np.where(from_ref, alt, around)
    raw = _verdicts(gl, gr, rows, cols, values, alt, factor)
    # the images' alternative explained by the LiDAR around the point: an occluded background point, or one beside a
    # depth edge the coarse reference fattened, not a change
    explained = np.zeros(n, np.bool_)
    i = np.flatnonzero(raw != 0)
    if i.size:
        out = np.zeros(i.size, np.bool_)
        _explained_kernel(sparse, rows[i].astype(np.int64), cols[i].astype(np.int64), values[i], alt[i],
                          max(1, int(round(spacing))), EDGE, np.float64(TAU), out)
        explained[i] = out
    verdict = np.where(explained, 0, raw).astype(np.int8)

    side = max(2, int(round(CELL * spacing)))
    regions, cell = cell_regions(rows, cols, np.where(from_ref, verdict, 0), from_ref, shape, side)
    # a region is a change only when its points as a whole lie off the images: the median of LiDAR - images
    # over its compared points beyond TAU, and the images' alternative clearly better on average (a patch of the
    # reference's own mistakes on repeated texture costs about the same either way)
    n_regions, labels = cv2.connectedComponents(regions.astype(np.uint8), connectivity=8)
    label = labels.ravel()[cell]
    seeds = np.zeros(n, np.int8)
    level = np.zeros(n)  # a seed's change: its region's median LiDAR - images
    # what the spread sees of each point: confirmed (2), contradicted (the sign), or not judged (0: an occlusion or
    # a moved depth edge explains its disagreement: the background beside a foreground the reference fattened)
    state = np.where(from_ref & (np.abs(values - alt) <= TAU), 2, verdict).astype(np.int8)
    for k in range(1, n_regions):
        i = np.flatnonzero((label == k) & from_ref)
        if i.size < MIN_COMPARED:
            continue
        change = float(np.median(values[i] - alt[i]))
        own, best = _costs(gl, gr, rows[i], cols[i], values[i], alt[i], factor)
        informative = (own < NO_INFO) & (best < NO_INFO)
        if abs(change) > TAU and informative.any() and np.mean((own - best)[informative]) >= REGION_MARGIN:
            sign = 1 if change > 0 else -1
            seeds[(label == k) & (raw == sign)] = sign
            level[(label == k) & (raw == sign)] = change
    # from its seeds a change spreads to the points within NEAR spacings: through the points the images contradict
    # the same way or the reference alone contradicts by the change, and up to UNKNOWN_HOPS points in a row they
    # cannot judge along the LiDAR's surface; it stops at points the images confirm
    in_region = seeds != 0
    lean = np.where(from_ref & (state == 0), values - alt, np.nan)  # unjudged with a reference: beyond TAU
    if seeds.any():
        index = np.full(shape, -1, np.int32)
        index[rows, cols] = np.arange(n, dtype=np.int32)
        in_region = flood(index, rows.astype(np.int64), cols.astype(np.int64), values, near, state, seeds,
                           UNKNOWN_HOPS, np.float64(SURFACE_STEP), lean, level, np.float64(TAU))
    changed, n_regions = None, 0
    if in_region.any():  # a change the images mostly saw: most of its points contradicted, not passed through
        changed = changed_area(rows[in_region], cols[in_region], shape, spacing)
        n_area, labels = cv2.connectedComponents(changed.astype(np.uint8), connectivity=8)
        label = labels[rows, cols]
        seen = np.bincount(label[in_region & (state != 2) & (raw != 0)], minlength=n_area)
        alone = np.isfinite(lean) & (raw == 0)  # the reference contradicts it, its patch cannot tell
        weak = seen < SEEN_SHARE * np.bincount(label[in_region & ~alone], minlength=n_area)
        in_region &= ~weak[label]
        if in_region.any():  # with the fringe the flood left (most of a point's own surface in the change)
            widened = fringe(index, rows.astype(np.int64), cols.astype(np.int64), values, near, state, in_region,
                             np.float64(TAU))
            if weak[1:].any() or (widened != in_region).any():  # the area of the changes kept, drawn again
                in_region = widened
                changed = changed_area(rows[in_region], cols[in_region], shape, spacing)
        else:
            changed = None
        if changed is not None:
            n_regions = cv2.connectedComponents(changed.astype(np.uint8), connectivity=8)[0] - 1
    # a point no neighbour supports is dropped when the images contradict it, or when it lies off its neighbours and
    # the images do not confirm it (its patch not clearly better than theirs) where the reference does not either
    lonely = ~supported & ~in_region
    outlier = lonely & (raw != 0)
    off = lonely & (raw == 0) & (state != 2) & np.isfinite(around) & (np.abs(values - around) > 2 * TAU)
    i = np.flatnonzero(off)
    if i.size:  # ... and off their plane too: a point on a steep slope lies off the median, not off the plane;
        # with no plane (fewer than 3 neighbours, or all on a line) they are too few to outvote it
        plane = plane_at(sparse, rows[i], cols[i], near)
        i = i[np.abs(values[i] - plane) > 2 * TAU]
    if i.size:  # the images do not vouch for it: its patch is not clearly better than the neighbours', nor best
        own, best = _costs(gl, gr, rows[i], cols[i], values[i], around[i], factor)
        vouched = (own <= VOUCH) & (own + MARGIN <= best)
        j = np.flatnonzero(vouched)
        if j.size:  # ... and no other disparity of the range does better (a low-contrast patch correlates somewhere)
            lo, hi = searched if searched is not None else (values.min(), values.max())
            vouched[j] = _unique(gl, gr, rows[i[j]], cols[i[j]], values[i[j]], own[j], lo, hi, factor)
        outlier[i] = ~vouched
    dropped = np.zeros(shape, np.uint8)
    dropped[rows[outlier], cols[outlier]] = 1
    dropped[rows[in_region], cols[in_region]] = 2
    kept = sparse.copy()
    kept[dropped > 0] = np.nan
    diff = values[in_region & from_ref] - alt[in_region & from_ref]
    report = CheckReport("auto", None, int(n), int(from_ref.sum()), int((verdict != 0).sum()),
                         int(outlier.sum()), int(in_region.sum()), int(n_regions),
                         round(float(changed.mean()), 6) if changed is not None else 0.0,
                         round(float(np.median(diff)), 3) if diff.size else None)
    return kept, LidarCheck(report, changed, dropped)


#: the reference's settings (the others are the run's): unguided census SGM over the whole range, left-right checked
REFERENCE_MATCH = {"matcher": "sgm", "guide": "none", "range": "full", "fusion": "none", "lr_check": True,
                   "lidar_check": "off", "lidar_offset": "none"}


#: a reference of more cells than this (pixels x disparities at its resolution) is searched coarse to fine; below
#: it the first pass saves a small share of the match at best (the 1 MP aerial tile holds 10 M), and its tubes move
#: a few of the check's verdicts
FINE_CELLS = 16_000_000


def coarse_reference(left, right, d_min, d_max, config, match, factor=FACTOR):
    """The check's reference: ``match`` (:func:`~riverbed_cli.matching.pipeline.match_pair`) of the pair at
    ``1 / factor`` resolution, unguided census SGM over ``[d_min, d_max] / factor`` with its left-right check and
    ``config``'s other settings; (h, w) float32 in coarse px, NaN where it failed. None for a pair smaller than
    16 px at that scale (:func:`~riverbed_cli.matching.range_maps.coarse_match`). Over :data:`FINE_CELLS` cells
    it searches tubes round a match at half its resolution
    (:func:`~riverbed_cli.matching.range_maps.coarse_to_fine_match`)."""
    H, W = left.shape[:2]
    cells = (H // factor) * (W // factor) * (math.ceil(d_max / factor) - math.floor(d_min / factor) + 1)
    search = coarse_to_fine_match if cells > FINE_CELLS else coarse_match
    return search(left, right, d_min, d_max, factor, config, match, REFERENCE_MATCH)


def check_pair(left, right, sparse, d_min, d_max, config, match):
    """:func:`check_lidar` of ``sparse`` against its :func:`coarse_reference` (``config.lidar_check`` ``auto``):
    the sparse map kept and the :class:`LidarCheck`. A pair too small for the reference keeps every point."""
    n = int(np.count_nonzero(np.isfinite(sparse)))
    why = _skip(n, sparse.shape)
    reference = coarse_reference(left, right, d_min, d_max, config, match, FACTOR) if why is None else None
    if reference is None:
        return sparse, LidarCheck(CheckReport("auto", why or "the pair is too small for the reference", points=n))
    return check_lidar(left, right, sparse, reference, factor=FACTOR, searched=(d_min, d_max))


def prefer_stereo(fused, stereo, status, changed):
    """In the changed area (``changed``, (H, W) bool) the images win: a fusion's output (changed in place) takes the
    matcher's disparity ``stereo`` wherever it passed its left-right check (``status`` 0; every finite value
    without a status), with the stereo's confidence (``erf(1 / (sigma_s sqrt 2))``, :mod:`.fusion`); elsewhere in
    the area its value is the LiDAR's interpolation across the change, kept with confidence 0."""
    if changed is None:
        return fused
    take = changed & np.isfinite(stereo)
    if status is not None:
        take &= status == 0
    fused.disparity[take] = stereo[take]
    if fused.confidence is not None:
        sigma = fused.stats.stereo_sigma if fused.stats is not None else None
        fused.confidence[changed] = 0.0
        if sigma:
            fused.confidence[take] = math.erf(1.0 / (float(sigma) * math.sqrt(2.0)))
    return fused


def warm_up():
    """Compile (or load from Numba's cache) the check's kernels on a tiny pair, so that a run's ``seconds`` hold
    none of it."""
    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (64, 96), dtype=np.uint8)
    right = np.roll(left, -3, axis=1)
    sparse = np.full(left.shape, np.nan, np.float32)
    sparse[::3, ::3] = 3.0
    sparse[12:54:3, 24:84:3] = 13.0  # a raised block: the region and flood kernels run too
    check_lidar(left, right, sparse, np.full((32, 48), 1.5, np.float32))
    plane_at(sparse, np.array([3]), np.array([3]), 3)  # the lone points' plane, which this pair does not reach


def lidar_mask(sparse, check):
    """Per pixel what the LiDAR did, uint8: 0 no LiDAR, 1 a point used, 2 a point dropped as an outlier, 3 a point
    dropped in a changed region, 4 a pixel of a changed area without a point (:data:`MASK_LABELS`). ``sparse``: the
    LiDAR's disparities (NaN: none), or where it has points (bool)."""
    sparse = np.asarray(sparse)
    have = sparse if sparse.dtype == bool else np.isfinite(sparse)
    out = have.astype(np.uint8)
    if check is not None and check.dropped is not None:
        out[check.dropped == 1] = 2
        out[check.dropped == 2] = 3
    if check is not None and check.changed is not None:
        out[check.changed & ~have] = 4
    return out


#: the values of :func:`lidar_mask`
MASK_LABELS = {0: "no LiDAR", 1: "used", 2: "outlier", 3: "changed region", 4: "changed area"}
