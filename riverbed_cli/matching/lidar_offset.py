"""The LiDAR's disparity offset against the images, estimated from the images and removed before guidance.

A LiDAR on another vertical datum, with a height offset, or a pair whose orientation drifted since the LiDAR was
registered, gives every LiDAR disparity the same error: guided by it, the tubes never visit the true disparity and
the fusion averages the error in (+4 px made 95 % of the pixels bad). The images know better: at the right
disparity, a small patch around each LiDAR pixel looks the same in both images.

Stage: ``(left, right, LiDAR pixels and disparities) -> OffsetEstimate``. For each candidate offset ``o`` the cost
is the mean over the LiDAR points of ``1 - ZNCC`` (capped) of the left image's 5 x 5 patch at the point and the right
image's at ``x - (d - o)`` (linear in x: sub-pixel disparities), :func:`patch_costs`. The
offset is the cost's minimum over whole pixels within the search, refined on a 1/4 px grid around it and by a
parabola through the three lowest samples. Textureless points add the same cost to every candidate and do not move
the minimum; a minority of wrong points (outliers, a changed building) neither. It is applied (subtracted from
every LiDAR disparity) when it is at least :data:`MIN_OFFSET` px, the images prefer it clearly over no offset (the
cost at the offset at least :data:`MIN_GAIN` below the cost at 0), it lies inside the search, and it is one offset
of the whole LiDAR: the minima over the blocks of a 3 x 3 grid of the image lie within :data:`MAX_SPREAD` px of it.

Sign: ``offset = LiDAR - images`` (px), so a LiDAR whose disparities are 4 px too large has offset +4.
"""

import logging
import math
from dataclasses import dataclass

import numpy as np
from numba import prange

from ..errors import RiverbedError
from ..io.images import effective_bits, to_grey
from ..records import RecordMapping
from ..runtime.kernel import kernel

log = logging.getLogger(__name__)

#: half side of the patch compared (px)
RADIUS = 2
#: largest cost (``1 - ZNCC``) a point adds: a point no offset explains weighs no more than this
CAP = 1.0
#: a patch whose grey levels vary less than this (variance, grey levels squared) is flat: it compares as CAP
MIN_VARIANCE = 1.0
#: offsets of at least this size (px) are removed. Ground truths sampled as LiDAR sit up to 0.7 px off their own
#: images (unguided stereo sees the same, docs/lidar_faults.md), and the estimate of one scatters by about 0.2 px
#: from one sampling of its points to another (the aerial pair's reached -1.00 px at 0.16 % of its GT): below 1.5 px
#: the LiDAR is left as it is
MIN_OFFSET = 1.5
#: and only when the cost at the offset is at least this share below the cost at no offset
MIN_GAIN = 0.02
#: at most this many LiDAR points are compared (every k-th of a denser map: the estimate needs no more, and the
#: comparisons are its cost)
MAX_POINTS = 8_000
#: the offset is one of the whole LiDAR when the estimates over the blocks of a BLOCKS x BLOCKS grid of the image
#: (those with MIN_BLOCK_POINTS and MIN_BLOCK_SHARE of the points) lie within MAX_SPREAD px of it: on the dev scenes,
#: offset or not, they lie within 0.71 px; an SRTM DEM used as the LiDAR of a Pleiades pair scattered them by 7-10 px
BLOCKS = 3
MIN_BLOCK_POINTS = 20
MIN_BLOCK_SHARE = 0.03
MAX_SPREAD = 1.5
#: and at least this many blocks hold enough points to say so (sparser LiDAR: no offset is removed)
MIN_BLOCKS = 4
#: the search reaches this share of the LiDAR's disparity span beyond no offset (and at least MIN_SEARCH px)
SEARCH_SHARE = 0.15
MIN_SEARCH = 4
#: and never beyond this (px): a few stray points far off the rest must not make the search, and its cost, huge
MAX_SEARCH = 128


@dataclass
class OffsetEstimate(RecordMapping):
    """The LiDAR's disparity offset against the images (px, ``LiDAR - images``): ``estimated`` (None: not
    estimated), ``applied`` (what was subtracted: the estimate when significant, a forced value, or 0), ``mode``
    (``auto``, ``none`` or ``forced``), ``points`` compared, ``gain`` (relative cost drop from no offset to the
    estimate), ``search`` (the largest offset looked for, px) and ``spread`` (px: how far the estimates over blocks
    of the image lie from it, :func:`estimate_offset`)."""

    mode: str
    applied: float = 0.0
    estimated: float = None
    points: int = 0
    gain: float = None
    search: float = None
    spread: float = None


@kernel(parallel=True)
def _patch_cost_kernel(gl, gr, rows, cols, vals, offsets, radius, cap, out):
    H, W = gl.shape
    n, m = rows.size, offsets.size
    side = 2 * radius + 1
    count = np.float32(side * side)
    for i in prange(n):
        y, x = rows[i], cols[i]
        a = np.empty(side * side, np.float32)
        b = np.empty(side * side, np.float32)
        inside = radius <= y < H - radius and radius <= x < W - radius
        ma = np.float32(0.0)
        if inside:
            j = 0
            for dy in range(-radius, radius + 1):
                for dx in range(-radius, radius + 1):
                    a[j] = gl[y + dy, x + dx]
                    ma += a[j]
                    j += 1
            ma /= count
        for k in range(m):
            xr = np.float64(x) - (np.float64(vals[i]) - offsets[k])
            x0 = np.int64(math.floor(xr))
            if not inside or x0 < radius or x0 + 1 >= W - radius:
                out[i, k] = cap
                continue
            f = np.float32(xr - x0)
            mb = np.float32(0.0)
            j = 0
            for dy in range(-radius, radius + 1):
                for dx in range(-radius, radius + 1):
                    b[j] = (np.float32(1.0) - f) * gr[y + dy, x0 + dx] + f * gr[y + dy, x0 + dx + 1]
                    mb += b[j]
                    j += 1
            mb /= count
            sab = np.float32(0.0)
            saa = np.float32(0.0)
            sbb = np.float32(0.0)
            for j in range(side * side):
                sab += (a[j] - ma) * (b[j] - mb)
                saa += (a[j] - ma) * (a[j] - ma)
                sbb += (b[j] - mb) * (b[j] - mb)
            if saa < MIN_VARIANCE * count or sbb < MIN_VARIANCE * count:
                out[i, k] = cap  # a flat patch says nothing
            else:
                out[i, k] = min(np.float32(1.0) - sab / math.sqrt(saa * sbb), np.float32(cap))


def patch_costs(grey_left, grey_right, rows, cols, values, offsets, radius=RADIUS, cap=CAP):
    """Per point and candidate offset, ``1 - ZNCC`` of the left image's patch at ``(row, col)`` and the right
    image's at ``col - (value - offset)`` (linear in x), capped at ``cap``: zero-mean and normalised, so a pair whose
    images differ in brightness and contrast (aerial frames, satellite views) compares as well as a studio one.

    Parameters
    ----------
    grey_left, grey_right : (H, W) float32
        The rectified pair (left: the reference), grey.
    rows, cols : (N,) int
        LiDAR pixels of the left image; ``values`` (N,) their disparities (px, ``d = x_left - x_right``).
    offsets : (M,) float64
        Candidate offsets (px, ``LiDAR - images``).

    Returns
    -------
    (N, M) float32
        In ``[0, cap]``; ``cap`` where a patch leaves either image or is flat (variance below
        :data:`MIN_VARIANCE` grey levels squared).
    """
    out = np.empty((len(rows), len(offsets)), np.float32)
    _patch_cost_kernel(np.ascontiguousarray(grey_left, np.float32), np.ascontiguousarray(grey_right, np.float32),
                       np.asarray(rows, np.int64), np.asarray(cols, np.int64), np.asarray(values, np.float32),
                       np.asarray(offsets, np.float64), int(radius), np.float32(cap), out)
    return out


def patch_costs_reference(grey_left, grey_right, rows, cols, values, offsets, radius=RADIUS, cap=CAP):
    """:func:`patch_costs` as a plain loop (the kernel's statement, for tests)."""
    H, W = grey_left.shape
    out = np.empty((len(rows), len(offsets)), np.float32)
    n = (2 * radius + 1) ** 2
    for i, (y, x, v) in enumerate(zip(rows, cols, values)):
        for k, o in enumerate(offsets):
            xr = x - (float(np.float32(v)) - o)
            x0 = math.floor(xr)
            if not (radius <= y < H - radius and radius <= x < W - radius and radius <= x0 and x0 + 1 < W - radius):
                out[i, k] = cap
                continue
            f = np.float32(xr - x0)
            ys = slice(y - radius, y + radius + 1)
            a = grey_left[ys, x - radius:x + radius + 1].astype(np.float64)
            b = ((1 - f) * grey_right[ys, x0 - radius:x0 + radius + 1]
                 + f * grey_right[ys, x0 - radius + 1:x0 + radius + 2]).astype(np.float64)
            a, b = a - a.mean(), b - b.mean()
            saa, sbb = (a * a).sum(), (b * b).sum()
            if saa < MIN_VARIANCE * n or sbb < MIN_VARIANCE * n:
                out[i, k] = cap
            else:
                out[i, k] = min(1.0 - (a * b).sum() / math.sqrt(saa * sbb), cap)
    return out


def _vertex(offsets, cost):
    """The offset at the cost's minimum, refined by a parabola through it and its neighbours."""
    i = int(np.argmin(cost))
    if 0 < i < len(cost) - 1:
        a, b, c = (float(v) for v in cost[i - 1:i + 2])
        den = a - 2 * b + c
        if den > 0:
            return float(offsets[i] + 0.5 * (a - c) / den * (offsets[1] - offsets[0]))
    return float(offsets[i])


def estimate_offset(left, right, rows, cols, values, bits=None):
    """The LiDAR's disparity offset against the images (px, ``LiDAR - images``; module docstring).

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) arrays
        The rectified pair, left the reference (``bits``: their effective bit depth).
    rows, cols, values : (N,) arrays
        LiDAR pixels of the left image and their disparities (px, ``d = x_left - x_right``).

    Returns
    -------
    offset : float
    gain : float
        The relative cost drop from no offset to ``offset`` (0: the images prefer no offset).
    points : int
        Points compared.
    search : float
        The largest offset looked for (px).
    spread : float
        The largest distance (px) from ``offset`` of the minimum over a block of a 3 x 3 grid of the image (blocks
        with at least 3 % of the points and 20): small for one offset of the whole LiDAR; infinite when fewer than
        :data:`MIN_BLOCKS` blocks hold that many.
    """
    values = np.asarray(values, np.float32)
    if len(values) == 0:
        raise RiverbedError("sparse map has no valid disparities")
    step = max(1, -(-len(values) // MAX_POINTS))
    rows, cols, values = rows[::step], cols[::step], values[::step]
    if bits is None:
        bits = effective_bits(left, right)
    gl, gr = (to_grey(im, bits) for im in (left, right))
    span = float(values.max() - values.min())
    search = float(min(max(MIN_SEARCH, math.ceil(SEARCH_SHARE * span)), MAX_SEARCH))
    coarse = np.arange(-search, search + 1.0)
    per_point = patch_costs(gl, gr, rows, cols, values, coarse)
    cost = per_point.mean(axis=0)
    at = coarse[int(np.argmin(cost))]
    fine = at + np.arange(-1.0, 1.0 + 1e-9, 0.25)
    cost_fine = patch_costs(gl, gr, rows, cols, values, np.append(fine, 0.0)).mean(axis=0)
    offset = _vertex(fine, cost_fine[:-1])
    at_zero, at_offset = float(cost_fine[-1]), float(cost_fine[:-1].min())
    gain = (at_zero - at_offset) / at_zero if at_zero > 0 else 0.0
    # the same minimum over each block of a 3 x 3 grid of the image (blocks with enough points): one offset of
    # the whole LiDAR puts every block's there; a LiDAR whose error varies over the image (an old coarse DEM as the
    # "LiDAR", a changed scene) scatters them
    H, W = gl.shape
    block = np.minimum(rows * BLOCKS // H, BLOCKS - 1) * BLOCKS + np.minimum(cols * BLOCKS // W, BLOCKS - 1)
    least = max(MIN_BLOCK_POINTS, MIN_BLOCK_SHARE * len(values))
    local = [_vertex(coarse, per_point[block == b].mean(axis=0)) for b in range(BLOCKS * BLOCKS)
             if np.count_nonzero(block == b) >= least]
    spread = max(abs(v - offset) for v in local) if len(local) >= MIN_BLOCKS else math.inf
    return offset, max(gain, 0.0), len(values), search, spread


def parse_offset(value):
    """The ``lidar_offset`` setting as ``("auto"|"none"|"forced", (dx, dy, dd))``: ``auto``, ``none``, a number DD
    (px) or ``DX,DY,DD`` (px: the LiDAR's pixels shifted by ``-DX, -DY`` and its disparities by ``-DD``)."""
    if value in ("auto", "none"):
        return value, (0.0, 0.0, 0.0)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return "forced", (0.0, 0.0, float(value))
    parts = [float(p) for p in str(value).split(",")]
    return "forced", tuple(parts) if len(parts) == 3 else (0.0, 0.0, parts[0])


def shift_points(sparse, dx, dy):
    """The sparse map with its points moved by ``(-dx, -dy)`` px (rounded to whole pixels): a LiDAR registered
    ``(dx, dy)`` px off the image, put back. Points moved off the image are dropped."""
    dx, dy = int(round(dx)), int(round(dy))
    if dx == 0 and dy == 0:
        return sparse
    out = np.full(sparse.shape, np.nan, np.float32)
    H, W = sparse.shape
    ys, yd = (slice(dy, H), slice(0, H - dy)) if dy >= 0 else (slice(0, H + dy), slice(-dy, H))
    xs, xd = (slice(dx, W), slice(0, W - dx)) if dx >= 0 else (slice(0, W + dx), slice(-dx, W))
    out[yd, xd] = sparse[ys, xs]
    return out


def correct_lidar(left, right, sparse, setting="auto", bits=None):
    """The sparse map with the LiDAR's offset removed, and the :class:`OffsetEstimate` (module docstring).

    ``setting``: ``auto`` (estimate; remove it when significant), ``none`` (leave the LiDAR as it is), or a forced
    offset (:func:`parse_offset`). The input is not modified.
    """
    mode, (dx, dy, dd) = parse_offset(setting)
    if mode == "none":
        return sparse, OffsetEstimate("none")
    if mode == "forced":
        out = shift_points(np.asarray(sparse, np.float32), dx, dy)
        return (out - np.float32(dd)).astype(np.float32), OffsetEstimate("forced", applied=dd)
    rows, cols = np.nonzero(np.isfinite(sparse))
    est = offset_estimate(left, right, rows, cols, sparse[rows, cols], bits)
    if not est.applied:
        return sparse, est
    return (np.asarray(sparse, np.float32) - np.float32(est.applied)).astype(np.float32), est


def correct_large(left, right, sparse, points, setting="auto", bits=None):
    """:func:`correct_lidar` for a large pair matched in tiles (arrays or windowed rasters): the offset estimated
    once over the central window (:func:`offset_estimate_windowed`; ``points``: the map's rows, columns and
    values), the sparse map returned corrected (:func:`corrected_sparse`: a windowed one stays windowed), with the
    :class:`OffsetEstimate`."""
    mode, (dx, dy, dd) = parse_offset(setting)
    if mode == "auto":
        est = offset_estimate_windowed(left, right, *points, bits)
        dd = est.applied
    else:
        est = OffsetEstimate(mode, applied=dd)
    return corrected_sparse(sparse, dx, dy, dd), est


def offset_estimate(left, right, rows, cols, values, bits=None, warn=True):
    """:func:`estimate_offset` and the rule (module docstring): the :class:`OffsetEstimate` of ``auto``, whose
    ``applied`` is the offset to remove (0: none); a warning says so when ``warn``."""
    offset, gain, n, search, spread = estimate_offset(left, right, rows, cols, values, bits)
    offset = round(offset, 3)  # what is reported is what is removed
    apply = abs(offset) >= MIN_OFFSET and gain >= MIN_GAIN and spread <= MAX_SPREAD and abs(offset) < search
    if apply and warn:
        log.warning("the LiDAR's disparities are %+.2f px off the images: removed (a height offset or another "
                    "vertical datum?); --lidar-offset none keeps them", offset)
    elif abs(offset) >= MIN_OFFSET:
        log.info("the LiDAR disagrees with the images by %+.2f px overall, but not by one offset over the image "
                 "(blocks %.2f px apart, gain %.3f): not removed", offset, spread, gain)
    return OffsetEstimate("auto", offset if apply else 0.0, offset, n, round(gain, 4), search,
                          round(spread, 3) if math.isfinite(spread) else None)


class CorrectedSparse:
    """A sparse map read window by window (a :class:`~riverbed_cli.io.windowed.WindowedRaster`, sliced
    ``[y0:y1, x0:x1]``) seen with the LiDAR's offset removed: each point moved by ``(-dx, -dy)`` px and its disparity
    less ``dd``, as :func:`shift_points` and :func:`correct_lidar` do to a whole map."""

    def __init__(self, src, dx, dy, dd):
        self.src, self.dx, self.dy, self.dd = src, int(round(dx)), int(round(dy)), np.float32(dd)
        self.shape, self.ndim, self.dtype = src.shape, 2, np.dtype(np.float32)

    def __getitem__(self, key):
        rows, cols = key[:2] if isinstance(key, tuple) else (key, slice(None))
        H, W = self.shape[:2]
        y0, y1, _ = rows.indices(H)
        x0, x1, _ = cols.indices(W)
        out = np.full((max(0, y1 - y0), max(0, x1 - x0)), np.nan, np.float32)
        sy0, sy1 = max(0, y0 + self.dy), min(H, y1 + self.dy)  # the source window the points come from
        sx0, sx1 = max(0, x0 + self.dx), min(W, x1 + self.dx)
        if sy0 < sy1 and sx0 < sx1:
            out[sy0 - self.dy - y0:sy1 - self.dy - y0, sx0 - self.dx - x0:sx1 - self.dx - x0] = \
                np.asarray(self.src[sy0:sy1, sx0:sx1], np.float32)
        return out - self.dd


def corrected_sparse(sparse, dx, dy, dd):
    """The sparse map (array or windowed) with the LiDAR's offset ``(dx, dy, dd)`` removed (:class:`CorrectedSparse`:
    a windowed map stays windowed)."""
    if not (round(dx) or round(dy) or dd):
        return sparse
    if isinstance(sparse, np.ndarray):
        return (shift_points(np.asarray(sparse, np.float32), dx, dy) - np.float32(dd)).astype(np.float32)
    return CorrectedSparse(sparse, dx, dy, dd)


#: the window (px, square) of a large image in which :func:`offset_estimate_windowed` estimates the offset
WINDOW = 2048


def offset_estimate_windowed(left, right, rows, cols, values, bits=None, warn=True):
    """:func:`offset_estimate` over the central ``WINDOW`` x ``WINDOW`` px of a large pair (numpy arrays or windowed
    rasters, sliced ``[y0:y1, x0:x1]``), read with the right image's columns its matches need: one estimate for
    every tile of a tiled match. ``rows``, ``cols``, ``values``: all the LiDAR points."""
    H, W = left.shape[:2]
    y0, x0 = max(0, (H - WINDOW) // 2), max(0, (W - WINDOW) // 2)
    y1, x1 = min(H, y0 + WINDOW), min(W, x0 + WINDOW)
    inside = (rows >= y0) & (rows < y1) & (cols >= x0) & (cols < x1)
    if not inside.any():
        inside = np.ones(len(rows), bool)
        y0, y1, x0, x1 = 0, H, 0, W
    vals = np.asarray(values, np.float32)[inside]
    reach = int(math.ceil(max(float(vals.max()), 0.0) + MAX_SEARCH)) + 4
    xs = max(0, x0 - reach)  # both crops from here: one column frame, the right one holding the matches
    crop = [np.asarray(im[y0:y1, xs:x1]) for im in (left, right)]
    return offset_estimate(*crop, rows[inside] - y0, cols[inside] - xs, vals, bits, warn)

