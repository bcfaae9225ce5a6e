"""Fusion: the matched disparity and the LiDAR's own interpolation combined per pixel, with a confidence.

Guided matching alone does not always beat interpolating the LiDAR (docs/benchmarks.md): on smooth surfaces a
linear interpolation of dense airborne LiDAR is more precise than census stereo, while at depth edges and on
structures the LiDAR missed the stereo is right and the interpolation wrong. The ``confidence`` fusion decides per
pixel from an error estimate of each source:

* **LiDAR**: ``l`` is an interpolation of the sparse disparities without the images, ``lidar``:
  ``planes`` puts each pixel on the least-squares plane of its nearest LiDAR point and that point's ``neighbours``
  nearest natural neighbours (:func:`~riverbed_cli.geometry.planes.plane_fill`: no triangulation, a third of the
  cost); ``linear`` interpolates linearly over the Delaunay triangulation
  (:func:`~riverbed_cli.geometry.interpolation.linear_fill`); ``auto``
  (the default) takes planes for LiDAR denser than one point per 12 x 12 px (:func:`lidar_kind`), linear else. Its error
  ``sigma_l`` is measured on the LiDAR itself: each point is predicted by a plane fitted to its ``neighbours``
  nearest other points (leave-one-out; with ``planes`` the nearest of its natural neighbours); a point's ``sigma``
  is the RMS of that residual over itself and its ``support - 1`` nearest points (natural neighbours), and every
  pixel takes the ``sigma`` of its nearest LiDAR point (at least ``floor`` px), grown in proportion to its distance
  ``r`` to that point beyond four typical spacings ``t`` (the median distance between nearest LiDAR points):
  ``sigma_l = sigma_point * max(1, r / 4t)``. Planar roofs and roads give small ``sigma_l``; depth edges,
  vegetation, thin structures and pixels far from any LiDAR (outside its hull) give large ones.
* **Stereo**: ``s`` is the matcher's disparity, with its left-right check. Its error ``sigma_s`` is one number per
  image, measured where the LiDAR is most reliable (the 30 % of the left-right consistent pixels with the smallest
  ``sigma_l``) as the normalised median absolute deviation of ``s - l`` (at least 0.2 px), or set
  (``fusion_stereo_sigma``).
* **Decision**: where the two agree within ``gate`` standard deviations (``|s - l| <= gate sqrt(sigma_s^2 +
  sigma_l^2)``) the output is their inverse-variance weighted mean (sub-pixel precision from both). Where they
  disagree one of them is grossly wrong: the stereo is kept where it passed its left-right check or is the more
  precise source (``sigma_s <= sigma_l``), else the interpolation. Where the stereo has no value, the interpolation.

The **confidence** of a pixel is the probability that its disparity lies within 1 px of the truth under a Gaussian
error of the estimated standard deviation ``sigma_f``: ``erf(1 / (sigma_f sqrt(2)))``, in [0, 1]. ``sigma_f`` is
``1 / sqrt(1 / sigma_s^2 + 1 / sigma_l^2)`` where the sources agree; where they do not, the chosen source's sigma,
at least half their disagreement ``|s - l| / 2`` when the other was credible (a consistent stereo, or the LiDAR),
and ``sigma_l`` alone where the interpolation replaced a stereo that failed its left-right check.

``fusion: none`` returns the matcher's output unchanged (the paper's method, ``--guide riverbed --range full
--fusion none``). Conventions: the left image is the reference, ``d = x_left - x_right`` (px), NaN invalid.
"""

import math
from dataclasses import dataclass

import numpy as np
from numba import prange

from ..errors import RiverbedError
from ..geometry.coverage import lidar_points, row_offsets
from ..geometry.interpolation import delaunay_graph, linear_fill, nearest_points
from ..geometry.planes import PlaneFill, plane_fill, plane_fit
from ..records import RecordMapping
from ..runtime.kernel import kernel
from .config import LIDAR_KINDS
from .volume import spread_rows

#: pixels farther than this many typical LiDAR spacings from their nearest point have a proportionally larger sigma
GROWTH = 4.0


@dataclass
class FusionStats(RecordMapping):
    """What a fusion did: ``stereo_sigma`` (px, the stereo's estimated error), ``agree`` (share of pixels where the
    sources agreed and were averaged), ``lidar`` (share taken from the interpolation), ``stereo`` (share kept from the
    stereo against the interpolation), ``mean_confidence``, ``invalid`` (share left invalid: outside the overlap or
    beyond the searched range, :mod:`.overlap`); shares of all pixels."""

    stereo_sigma: float
    agree: float
    lidar: float
    stereo: float
    mean_confidence: float
    invalid: float = 0.0


@dataclass
class FusionOutput:
    """``disparity`` (H, W) float32 (NaN invalid), ``confidence`` (H, W) float32 in [0, 1] or None, ``stats``."""

    disparity: np.ndarray
    confidence: np.ndarray = None
    stats: FusionStats = None


def leave_one_out_residuals(rows, cols, values, neighbours=6, graph=None):
    """|value - prediction| of each LiDAR point by a plane through its ``neighbours`` nearest other points (px),
    float64.

    The plane ``d = a x + b y + c`` is fitted by least squares centred on the point (a tiny ridge on the slopes keeps
    collinear neighbours solvable); the prediction is ``c``. The nearest points come from the points' Delaunay graph
    (:func:`~riverbed_cli.geometry.interpolation.nearest_points`), ``graph`` ``(ptr, nbr)`` if already made.
    """
    k = min(int(neighbours), len(values) - 1)
    if graph is None:
        graph = delaunay_graph(rows, cols, (int(np.max(rows)) + 1, int(np.max(cols)) + 1))
    _, idx = nearest_points(rows, cols, k + 1, *graph)
    return _residuals(rows, cols, values, idx[:, 1:])


def _residuals(rows, cols, values, nb, count=None, k=None):
    # leave_one_out_residuals given each point's neighbours nb (indices, itself excluded; the first count[i] of row i,
    # at most k): |value - the intercept of the plane through them|
    nb = np.ascontiguousarray(nb)
    if count is None:
        count = np.full(nb.shape[0], nb.shape[1], np.int32)
    c, _, _ = plane_fit(rows.astype(np.float64), cols.astype(np.float64), values.astype(np.float64), nb, count,
                        nb.shape[1] if k is None else int(k), 0.0, False)
    return np.abs(c - values)


def _nearest_rms(res, nb, count, k):
    # per point: the RMS of the residuals over itself and its first k - 1 neighbours (fewer if it has fewer); NumPy
    # over a few thousand points, where a kernel would cost a fresh process more to load than it saves
    m = np.minimum(count, max(k - 1, 0))
    s = res * res
    for j in range(max(k - 1, 0)):  # in order, as a loop per point would add them
        s = s + np.where(j < m, res[np.where(j < m, nb[:, j], 0)] ** 2, 0.0)
    return np.sqrt(s / (m + 1))


def lidar_sigma(sparse, neighbours=6, support=4, floor=0.25, fill=None):
    """Per-pixel error estimate (px) of the interpolation of ``sparse`` (module docstring).

    Returns ``(sigma, distance)``: (H, W) float32 sigma (px of disparity) and each pixel's distance (px) to its
    nearest LiDAR point. ``fill``: the interpolation, a :class:`~riverbed_cli.geometry.planes.PlaneFill` (the points'
    neighbours are then their nearest natural neighbours) or a
    :class:`~riverbed_cli.geometry.interpolation.LinearFill` (their nearest points); made by
    :func:`~riverbed_cli.geometry.interpolation.linear_fill` if not given. With fewer than ``neighbours + 1`` LiDAR
    pixels nothing can be measured: every pixel gets the span of the LiDAR disparities plus 1 px (the interpolation
    is taken to know little).
    """
    fill = linear_fill(sparse) if fill is None else fill
    rows, cols, values = fill.points
    if len(values) < int(neighbours) + 1:
        span = float(values.max() - values.min()) + 1.0 if len(values) else 1.0
        return np.full(sparse.shape, max(span, floor), np.float32), fill.distance
    kn, k = min(int(neighbours), len(values) - 1), min(int(support), len(values))
    if isinstance(fill, PlaneFill):  # each point's natural neighbours, nearest first, are already known
        res = _residuals(rows, cols, values, fill.neighbours, fill.count, kn)
        point_sigma = _nearest_rms(res, fill.neighbours, fill.count, k)
        nearest = fill.nearest
    else:  # one search on the Delaunay graph for the planes' neighbours and the support's nearest points
        nn, idx = nearest_points(rows, cols, max(kn + 1, k, 2), fill.ptr, fill.nbr)
        res = _residuals(rows, cols, values, idx[:, 1:kn + 1])
        point_sigma = np.sqrt(np.mean(res[idx[:, :k]] ** 2, axis=1)) if k > 1 else res
        nearest = nn[:, 1]
    typical = max(1.0, float(median_of(nearest)))
    return _pixel_sigma(fill.anchor, fill.distance, point_sigma, float(floor), GROWTH * typical), fill.distance


@kernel(parallel=True)
def _pixel_sigma(anchor, dist, point_sigma, floor, reach):
    # sigma of the pixel's nearest point (at least floor), grown in proportion to the distance beyond reach
    H, W = anchor.shape
    out = np.empty((H, W), np.float32)
    for y in prange(H):
        for x in range(W):
            s = max(point_sigma[anchor[y, x]], floor)
            out[y, x] = np.float32(s * max(1.0, np.float64(dist[y, x]) / reach))
    return out


def estimate_stereo_sigma(stereo, lidar, sigma_l, consistent=None, share=0.3, smallest=0.2):
    """The stereo's error (px, one number): NMAD of ``stereo - lidar`` over the ``share`` of the left-right
    ``consistent`` pixels (default: those with a stereo value) that have the smallest ``sigma_l``; at least
    ``smallest``. Infinite when no pixel qualifies."""
    stereo = np.ascontiguousarray(stereo, np.float32)
    fin = np.isfinite(stereo) if consistent is None else np.asarray(consistent, np.bool_)
    if not fin.any():
        return float("inf")
    # the values gathered by one pass each (NumPy's masks and copies took 8 of 12 ms on 1 MP); the percentile and
    # median are NumPy's, of the same values
    sigma_l = np.ascontiguousarray(sigma_l)
    limit = np.percentile(_where_values(sigma_l, fin), 100.0 * share)
    r = _where_abs_diff(stereo, np.ascontiguousarray(lidar, np.float32), sigma_l, fin, float(limit))
    return max(smallest, 1.4826 * float(median_of(r))) if r.size else float("inf")


def median_of(values):
    """``np.median`` of a 1-D array, the same bits, from a partition at its middle only: NumPy's median also
    partitions at the last element to find a NaN (1.4 of the 3.2 ms of :func:`estimate_stereo_sigma` on the speed
    pair's 168 000 values); one test for NaN is cheaper."""
    values = np.asarray(values)
    n = values.size
    if n == 0 or (values.dtype.kind == "f" and np.isnan(values).any()):
        return np.median(values)
    half = n // 2
    if n % 2:
        return np.partition(values, half)[half]
    part = np.partition(values, [half - 1, half])
    return np.mean(part[half - 1:half + 1])


@kernel(parallel=True)
def _where_values(x, mask):
    # x[mask] as float64, row-major
    at = row_offsets(mask)
    out = np.empty(at[-1], np.float64)
    H, W = mask.shape
    for y in prange(H):
        k = at[y]
        for i in range(W):
            if mask[y, i]:
                out[k] = np.float64(x[y, i])
                k += 1
    return out


@kernel(parallel=True)
def _where_abs_diff(a, b, sigma, mask, limit):
    # |a - b| (float32, as NumPy's) where mask and sigma <= limit (sigma compared as float64), row-major
    H, W = mask.shape
    kept = np.empty((H, W), np.bool_)
    for y in prange(H):
        for x in range(W):
            kept[y, x] = mask[y, x] and np.float64(sigma[y, x]) <= limit
    at = row_offsets(kept)
    out = np.empty(at[-1], np.float32)
    for y in prange(H):
        k = at[y]
        for x in range(W):
            if kept[y, x]:
                out[k] = abs(a[y, x] - b[y, x])
                k += 1
    return out


@dataclass
class LidarModel:
    """The LiDAR side of the fusion (:func:`lidar_model`): ``values`` (H, W) float32, the LiDAR's interpolation;
    ``sigma`` (H, W) float32, its error estimate (px)."""

    values: np.ndarray
    sigma: np.ndarray


#: ``auto`` takes local planes where the LiDAR's mean spacing (px, over the whole image) is at most this, else the
#: Delaunay fill: dense LiDAR makes the triangulation costly and planes as accurate; sparse LiDAR makes it cheap,
#: and planes carried far from their points err (docs/fusion.md, "The LiDAR side")
PLANES_MAX_SPACING = 12.0


def lidar_kind(kind, n_points, shape):
    """The interpolation ``kind`` a fusion uses (``planes`` or ``linear``) for ``n_points`` LiDAR pixels in an image
    of ``shape``: ``auto`` is planes where their mean spacing ``sqrt(H W / n)`` is at most
    :data:`PLANES_MAX_SPACING` px."""
    if kind not in LIDAR_KINDS:
        raise RiverbedError(f"unknown fusion LiDAR interpolation '{kind}' (use {', '.join(LIDAR_KINDS)})")
    if kind != "auto":
        return kind
    return "planes" if n_points and shape[0] * shape[1] <= PLANES_MAX_SPACING ** 2 * n_points else "linear"


def lidar_model(sparse, neighbours=6, support=4, floor=0.25, points=None, kind="auto"):
    """The interpolation of the ``sparse`` LiDAR and its per-pixel error (:class:`LidarModel`): all of the fusion
    that needs no stereo, so :func:`~riverbed_cli.matching.pipeline.match_pair` computes it beside the matcher.
    ``kind``: ``auto``, ``planes`` or ``linear`` (:func:`lidar_kind`, module docstring); ``points``:
    ``lidar_points(sparse)`` if already found."""
    sparse = np.asarray(sparse)
    points = lidar_points(sparse) if points is None else points
    # the interpolation and each pixel's nearest point, for its sigma
    if lidar_kind(kind, len(points[0]), sparse.shape) == "planes":
        fill = plane_fill(sparse, points, neighbours)
    else:
        fill = linear_fill(sparse, points)
    return LidarModel(fill.values, lidar_sigma(sparse, neighbours, support, floor, fill)[0])


def fuse_disparity(stereo, status, sparse, gate=4.0, neighbours=6, support=4, floor=0.25, stereo_sigma="auto",
                   lidar=None, lidar_kind="auto"):
    """The ``confidence`` fusion of a matched disparity with the LiDAR (module docstring).

    Parameters
    ----------
    stereo : (H, W) float32
        The matcher's disparity of the left image (px, NaN invalid).
    status : (H, W) int array or None
        The matcher's left-right check (0 consistent, > 0 failing); None: every valid pixel counts as consistent.
    sparse : (H, W) float
        LiDAR disparities of the left image, NaN elsewhere (at least one).
    gate : float
        Agreement gate in standard deviations.
    neighbours, support : int
        LiDAR points of the leave-one-out plane fit, and of the RMS that gives a point's sigma.
    floor : float
        Smallest LiDAR sigma (px).
    stereo_sigma : float or "auto"
        The stereo's error (px), or estimated from the image (:func:`estimate_stereo_sigma`).
    lidar : LidarModel, optional
        ``lidar_model(sparse, neighbours, support, floor, kind=lidar_kind)`` if already made (``neighbours``,
        ``support``, ``floor`` and ``lidar_kind`` are then its).
    lidar_kind : str
        The LiDAR's interpolation: ``auto``, ``planes`` or ``linear`` (:func:`lidar_kind`, module docstring).

    Returns
    -------
    FusionOutput
    """
    stereo = np.asarray(stereo, np.float32)
    model = lidar_model(sparse, neighbours, support, floor, kind=lidar_kind) if lidar is None else lidar
    lidar, sig_l = model.values, model.sigma
    fin = np.isfinite(stereo)
    consistent = fin if status is None else fin & (np.asarray(status) == 0)
    if stereo_sigma == "auto":
        sig_s = estimate_stereo_sigma(stereo, lidar, sig_l, consistent)
    else:
        sig_s = float(stereo_sigma)
    out, confidence, counts = _decide(stereo, lidar, sig_l, consistent, float(sig_s), float(gate))
    n = float(stereo.size)
    stats = FusionStats(round(sig_s, 4) if math.isfinite(sig_s) else None, round(int(counts[0]) / n, 4),
                        round(int(counts[2]) / n, 4), round(int(counts[1]) / n, 4), round(float(confidence.mean()), 4))
    return FusionOutput(out, confidence, stats)


@kernel(parallel=True)
def _decide(stereo, lidar, sig_l, consistent, sig_s, gate):
    # The per-pixel decision of fuse_disparity (module docstring) in one pass: output, confidence, and the counts of
    # pixels averaged / kept from the stereo / taken from the LiDAR.
    H, W = stereo.shape
    out = np.empty((H, W), np.float32)
    conf = np.empty((H, W), np.float32)
    per_row = np.zeros((H, 3), np.int64)  # counted per row in the parallel pass, summed after
    finite_s = math.isfinite(sig_s)
    ws = 1.0 / (sig_s * sig_s) if finite_s else 0.0
    root2 = math.sqrt(2.0)
    for yy in prange(H):
        # every other row in each thread's share (volume.spread_rows): a row's work (its erf calls) varies
        # with the image (the cut speed pair: 2.6 -> 2.3 ms)
        y = spread_rows(yy, H)
        # the confidence's erf once per run of equal sigmas: neighbours that agree share their nearest LiDAR point's
        # sigma, hence sigma_f (the same value in, the same value out)
        last_sf = -1.0
        last_conf = np.float32(0.0)
        last_sl = -1.0  # and the gate, weight and sigma_f of agreeing sources once per run of equal LiDAR sigmas
        limit = wl = sf_agree = 0.0
        for x in range(W):
            s = np.float64(stereo[y, x])
            li = np.float64(lidar[y, x])
            sl = np.float64(sig_l[y, x])
            if sl != last_sl:
                last_sl = sl
                limit = gate * math.sqrt(sig_s * sig_s + sl * sl)
                wl = 1.0 / (sl * sl)
                sf_agree = 1.0 / math.sqrt(ws + wl)
            fin = math.isfinite(s)
            diff = abs(s - li) if fin else 0.0
            if fin and finite_s and diff <= limit:
                v = (s * ws + li * wl) / (ws + wl)
                sf = sf_agree
                kind = 0
            elif fin and (consistent[y, x] or sig_s <= sl):
                # against a credible rival the choice is unsure by half the disagreement
                v = s
                sf = max(sig_s, diff / 2.0)
                kind = 1
            else:
                v = li
                # over a stereo that failed its left-right check the LiDAR is as sure as its own sigma
                sf = max(sl, diff / 2.0) if consistent[y, x] else sl
                kind = 2
            out[y, x] = np.float32(v)
            if sf != last_sf:
                last_sf = sf
                last_conf = np.float32(math.erf(1.0 / (max(sf, 1e-6) * root2)))
            conf[y, x] = last_conf
            per_row[y, kind] += 1
    counts = np.zeros(3, np.int64)
    for y in range(H):
        for k in range(3):
            counts[k] += per_row[y, k]
    return out, conf, counts
