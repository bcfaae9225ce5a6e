"""``match_pair``: a rectified pair (and sparse LiDAR) through a registered matcher and guide, timed.

The driver checks the inputs, resolves the disparity range, runs the guide's preparation (riverbed+'s first pass)
and hands over to the matcher, which runs the stages (cost, guidance, aggregation, selection, refinement).
Matchers live in ``matching/matchers/``, guides in ``matching/guides/``, their settings in :mod:`.config`.
"""

import logging
import math
import time
from dataclasses import asdict

import cv2
import numpy as np
from numba import njit, prange

from ..errors import RiverbedError
from ..runtime.beside import After, Beside
from . import fusion, guides, matchers  # noqa: F401  (importing them fills the registries)
from ..geometry.coverage import lidar_share_of_row_ends
from .config import MatchConfig
from .overlap import keep_fusion_to_lidar, keep_to_overlap, lidar_coverage
from .lidar_check import check_pair, prefer_stereo
from .lidar_check import warm_up as warm_check
from .lidar_offset import correct_lidar
from .registry import get_fusion, get_guide, get_matcher
from .results import MatchInfo, MatchResult
from .tubes import HOLE_FACTOR, hole_bounds, lidar_tube_layout, lidar_tubes, range_map_summary, tube_stats
from .volume import TubeLayout, band_pair_rows, band_pairs

log = logging.getLogger(__name__)

#: largest image (pixels) whose fusion's LiDAR side runs beside the matcher (``beside="auto"``): its arrays (about
#: 30 bytes a pixel) would add to the matcher's peak memory; a 40 MP pair's 4 MP tiles peaked at 1526 MiB beside,
#: 1297 MiB after
BESIDE_MAX_PIXELS = 2_000_000


#: disparities (LiDAR, range maps) beyond this many image widths are no disparity of the pair but a corrupt value
#: (a stray +-1e30): refused, naming the file, rather than searched or copied
ABSURD_WIDTHS = 4


def check_disparity_values(values, width, what="sparse map"):
    """:class:`RiverbedError` when a finite value of ``values`` (any array, NaN ignored) lies beyond
    ``+-ABSURD_WIDTHS * width`` px: ``what`` (a map of an image ``width`` px wide) is corrupt."""
    limit = ABSURD_WIDTHS * max(int(width), 1)
    values = np.asarray(values)
    with np.errstate(invalid="ignore"):
        bad = np.abs(values) > limit  # False for NaN
    n = int(np.count_nonzero(bad))
    if n:
        example = float(values[bad].flat[0])
        raise RiverbedError(f"{what} holds {n} disparit{'y' if n == 1 else 'ies'} beyond +-{limit} px (e.g. "
                            f"{example:g}; {ABSURD_WIDTHS} times the image width of {width} px): a corrupt value, "
                            "not a disparity of this pair")


#: fewest LiDAR points a LiDAR-guided match takes: fewer cannot give the scene a slope, and a single point made a
#: flat map (the fusion's interpolation of one point is a constant, and it outweighed the stereo everywhere)
MIN_LIDAR_POINTS = 3


def lidar_points_needed(config):
    """The fewest LiDAR points a match with ``config`` takes: 0 when the LiDAR neither guides nor is fused (it
    only gives the range), :data:`MIN_LIDAR_POINTS`, and with the confidence fusion its leave-one-out plane fit's
    ``fusion_neighbours + 1``."""
    guide = get_guide(config.guide)
    fusion = resolve_fusion(config, guide, True)
    if not guide.needs_sparse and fusion == "none":
        return 0
    return max(MIN_LIDAR_POINTS, config.fuse.neighbours + 1 if fusion != "none" else 0)


def check_lidar_count(n, config):
    """:class:`RiverbedError` when ``n`` LiDAR points are too few for a match with ``config``
    (:func:`lidar_points_needed`)."""
    if n == 0:
        raise RiverbedError("sparse map has no valid disparities")
    needed = lidar_points_needed(config)
    if n < needed:
        raise RiverbedError(f"sparse map has {n} LiDAR point{'' if n == 1 else 's'}; a LiDAR-guided match needs at "
                            f"least {needed} (or match without --sparse)")


def clamp_to_width(d_min, d_max, width):
    """``(d_min, d_max)`` cut to what a pair ``width`` px wide can match, ``|d| <= width - 1`` (a pixel's match at a
    larger disparity lies outside the other image, and the volume would grow for nothing), with a warning when it
    cuts; :class:`RiverbedError` when no disparity of the range is left. An end that is None (not given: derived
    later) stays None; an empty range (``d_min > d_max``) is left for the caller to report."""
    top = max(int(width) - 1, 0)
    if d_min is not None and d_max is not None and d_min > d_max:
        return d_min, d_max
    if (d_min is not None and d_min > top) or (d_max is not None and d_max < -top):
        raise RiverbedError(f"disparity range [{d_min}, {d_max}] lies beyond what images {width} px wide can match "
                            f"(|d| <= {top})")
    lo = None if d_min is None else max(d_min, -top)
    hi = None if d_max is None else min(d_max, top)
    if (lo, hi) != (d_min, d_max):
        show = lambda v: "auto" if v is None else str(v)  # noqa: E731
        log.warning("disparity range [%s, %s] clamped to [%s, %s]: the images are %d px wide", show(d_min),
                    show(d_max), show(lo), show(hi), width)
    return lo, hi


def disparity_range_from_sparse(sparse, margin=None):
    """Inclusive integer range ``(d_min, d_max)`` covering the sparse disparities plus a margin.

    The margin (px) defaults to ``max(8, 15 % of the LiDAR span)``: LiDAR misses parts of the scene (occlusions,
    dark surfaces) whose disparities may lie a little beyond what it saw. Corrupt values are refused where the LiDAR
    enters (:func:`check_disparity_values`: ``match_pair``, ``match_tiled``, ``match_files``, a block's project stage).
    """
    vals = sparse[np.isfinite(sparse)]
    if vals.size == 0:
        raise RiverbedError("sparse map has no valid disparities")
    lo, hi = float(vals.min()), float(vals.max())
    if margin is None:
        margin = max(8.0, 0.15 * (hi - lo))
    return int(math.floor(lo - margin)), int(math.ceil(hi + margin))


def resolve_disparity_range(d_min, d_max, sparse_values, width=None):
    """``(d_min, d_max)`` as ints, the missing ends derived from the sparse disparities (any array, NaN ignored);
    with ``width`` (the images', px) clamped to what they can match (:func:`clamp_to_width`)."""
    if d_min is None or d_max is None:
        if sparse_values is None:
            raise RiverbedError("give the disparity range (--min-disp/--max-disp, or --pair with the pair file "
                                "riverbed rectify wrote), or --sparse or --range-map to derive it from")
        lo, hi = disparity_range_from_sparse(sparse_values)
        d_min = lo if d_min is None else d_min
        d_max = hi if d_max is None else d_max
    d_min, d_max = int(d_min), int(d_max)
    if d_max < d_min:
        raise RiverbedError(f"empty disparity range: --min-disp {d_min} > --max-disp {d_max}")
    if width is not None:
        d_min, d_max = clamp_to_width(d_min, d_max, width)
    return d_min, d_max


def prepare_sparse(sparse, shape, d_min, d_max):
    """The sparse map as float32, checked against the image ``shape``; disparities outside ``[d_min, d_max]``
    become NaN (with a warning)."""
    return prepare_lidar(sparse, shape, d_min, d_max)[0]


def prepare_lidar(sparse, shape, d_min, d_max):
    """:func:`prepare_sparse` and what a match needs of its LiDAR, from one pass over the map: ``(sparse, points,
    share, share_all)`` with ``points`` the :func:`~riverbed_cli.geometry.coverage.lidar_points` of the prepared
    map (the points inside the range), ``share`` their :func:`lidar_share` and ``share_all`` that of every finite
    point (the tube rule's spacing counts them all)."""
    sparse = np.asarray(sparse, dtype=np.float32)
    if sparse.shape != shape:
        raise RiverbedError(
            f"sparse map is {sparse.shape[1] if sparse.ndim > 1 else '?'}x{sparse.shape[0]} (WxH) but the images are "
            f"{shape[1]}x{shape[0]}"
        )
    per_row, cut = _cut_to_range(sparse, float(d_min), float(d_max))
    n, n_in = int(per_row[:, 0].sum()), int(per_row[:, 1].sum())
    if n == 0:
        raise RiverbedError("sparse map has no valid disparities")
    if n_in < n:  # the values outside the range: dropped below, unless corrupt
        check_disparity_values(sparse[np.isfinite(sparse)], shape[1])
    check_inside(n_in, n, d_min, d_max, lambda: sparse[np.isfinite(sparse)])
    out = cut if n_in < n else sparse
    points = _points_of_rows(out, per_row)
    share = lidar_share_of_row_ends(n_in, per_row[:, 4], per_row[:, 5], shape)
    share_all = share if n_in == n else lidar_share_of_row_ends(n, per_row[:, 2], per_row[:, 3], shape)
    return out, points, share, share_all


@njit(cache=True, parallel=True)
def _cut_to_range(sparse, d_min, d_max):
    # In one pass: a copy with NaN outside [d_min, d_max] and per row the finite values and those inside, with the
    # first and last column of each (-1: none). NumPy's masks, sums and np.where took 1 ms on 740 x 500 px, and the
    # points and the shares another pass each; one kernel, as each cached kernel costs a fresh process 3-4 ms to load.
    # The row's pass is branch-free (it vectorises: 0.5x the time of the loop that tracked the ends as it went);
    # the ends come after, from scans that stop at the first and last hit.
    H, W = sparse.shape
    per_row = np.empty((H, 6), np.int64)
    out = np.empty((H, W), np.float32)
    nan = np.float32(np.nan)
    m = band_pairs(H)
    for i in prange(m):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            row = sparse[y]
            cut = out[y]
            finite = inside_n = 0
            for x in range(W):
                v = np.float64(row[x])
                inside = (v >= d_min) & (v <= d_max)  # False for NaN and +-inf
                cut[x] = row[x] if inside else nan
                finite += np.int64(abs(v) < np.inf)
                inside_n += np.int64(inside)
            f0 = f1 = i0 = i1 = -1
            if finite:
                f0, f1 = _row_ends(row, -np.inf, np.inf)
            if inside_n:
                i0, i1 = _row_ends(row, d_min, d_max)
            per_row[y, 0], per_row[y, 1], per_row[y, 2], per_row[y, 3], per_row[y, 4], per_row[y, 5] = (
                finite, inside_n, f0, f1, i0, i1)
    return per_row, out


@njit(cache=True, inline="always")
def _row_ends(row, lo, hi):
    # the first and last column of a row whose value is finite and within [lo, hi] (-1, -1: none)
    W = row.shape[0]
    first = last = -1
    for x in range(W):
        v = np.float64(row[x])
        if v >= lo and v <= hi and abs(v) < np.inf:
            first = x
            break
    if first >= 0:
        for x in range(W - 1, first - 1, -1):
            v = np.float64(row[x])
            if v >= lo and v <= hi and abs(v) < np.inf:
                last = x
                break
    return first, last


@njit(cache=True, parallel=True)
def _points_of_rows(sparse, per_row):
    # lidar_points of a map whose finite values are those counted inside by _cut_to_range: rows, columns (int64)
    # and values (float64) in row-major order, each row filled from its running total
    H = sparse.shape[0]
    at = np.zeros(H + 1, np.int64)
    for y in range(H):
        at[y + 1] = at[y] + per_row[y, 1]
    rows = np.empty(at[H], np.int64)
    cols = np.empty(at[H], np.int64)
    values = np.empty(at[H], np.float64)
    m = band_pairs(H)
    for i in prange(m):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            k = at[y]
            for x in range(max(per_row[y, 4], 0), per_row[y, 5] + 1):
                v = sparse[y, x]
                if np.isfinite(v):
                    rows[k] = y
                    cols[k] = x
                    values[k] = np.float64(v)
                    k += 1
    return rows, cols, values


def check_inside(n_in, n, d_min, d_max, values):
    """Raise when none of the ``n`` LiDAR disparities lies in ``[d_min, d_max]``, warn when only ``n_in`` do
    (``values()``: the disparities, for the message)."""
    if n_in == 0:
        vals = values()
        raise RiverbedError(
            f"disparity range [{d_min}, {d_max}] excludes all sparse disparities (they span "
            f"[{vals.min():.2f}, {vals.max():.2f}])"
        )
    if n_in < n:
        log.warning("%d of %d sparse disparities lie outside [%d, %d]: they guide no cost (tubes keep the pixels "
                    "only they reach at the range's end)", n - n_in, n, d_min, d_max)


def make_config(params=None, **overrides):
    """A :class:`MatchConfig` from ``params`` (a MatchConfig or None) with flat ``overrides``
    (:meth:`MatchConfig.replace`)."""
    config = params if params is not None else MatchConfig()
    if not isinstance(config, MatchConfig):
        raise RiverbedError(f"params: expected a MatchConfig, got {type(config).__name__}")
    return config.replace(**overrides) if overrides else config


def resolve_range(config, guide, matcher, have_lidar, have_map):
    """The search-range mode a match uses: ``tube`` or ``full`` (``tile`` is :func:`match_tiled`'s; a single
    match searches its whole range)."""
    mode = config.range
    if mode == "auto":
        return "tube" if (have_map or (guide.needs_sparse and have_lidar)) and matcher.supports_tubes else "full"
    if mode == "tube":
        if not matcher.supports_tubes:
            raise RiverbedError(f"--range tube is not available with --matcher {matcher.name} (use tile or full)")
        if not (have_lidar or have_map):
            raise RiverbedError("--range tube needs --sparse or --range-map")
        return "tube"
    return "full"


def resolve_fusion(config, guide, have_lidar):
    """The fusion a match applies: ``auto`` is ``confidence`` for a LiDAR-guided match, else ``none``."""
    name = config.fusion
    if name == "auto":
        return "confidence" if guide.needs_sparse and have_lidar else "none"
    if name != "none" and not have_lidar:
        raise RiverbedError(f"--fusion {name} needs --sparse (it combines the stereo with the LiDAR)")
    return name


def check_range_map_shape(lo, hi, shape):
    """:class:`RiverbedError` unless both bands of a range map are of ``shape``."""
    if tuple(lo.shape) != tuple(shape) or tuple(hi.shape) != tuple(shape):
        raise RiverbedError(f"range map is {lo.shape[1] if len(lo.shape) > 1 else '?'}x{lo.shape[0]} but the images "
                            f"are {shape[1]}x{shape[0]} (WxH)")


def check_range_summary(known, crossed, low, high, d_min, d_max):
    """:class:`RiverbedError` for a range map with no valid pixel, min > max, or a range outside ``[d_min, d_max]``
    (from its :func:`~riverbed_cli.matching.tubes.range_map_summary`)."""
    if not known:
        raise RiverbedError("range map has no valid pixel (all NaN)")
    if crossed:
        raise RiverbedError(f"range map has min > max at {crossed} pixels")
    if low < d_min or high > d_max:
        raise RiverbedError(f"range map spans [{low:.2f}, {high:.2f}], outside the nominal range [{d_min}, {d_max}]")


def check_range_map(range_map, shape, d_min, d_max):
    """A per-pixel range ``(lo, hi)`` (float arrays, NaN: the nominal range) checked for a match of ``shape`` over
    ``[d_min, d_max]`` (:class:`RiverbedError` for another size, no valid pixel, min > max, or a range outside the
    nominal one), as inclusive int32 tube ends."""
    lo, hi = (np.asarray(a) for a in range_map)
    check_range_map_shape(lo, hi, shape)
    check_range_summary(*range_map_summary(lo, hi), d_min, d_max)
    return range_map_ends(lo, hi, d_min, d_max)


def range_map_ends(lo, hi, d_min, d_max):
    """Inclusive int32 ends of a checked range map (a crop of one, say): ``floor(lo)``, ``ceil(hi)``, and
    ``[d_min, d_max]`` where the map has no range."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    known = np.isfinite(lo) & np.isfinite(hi)
    return (np.where(known, np.floor(lo), d_min).astype(np.int32),
            np.where(known, np.ceil(hi), d_max).astype(np.int32))


#: the coarse match of the tube rule's holes: unguided census SGM on the whole range. Without the left-right check:
#: with it, the windows lost the disparities of textureless and occluded parts and the ranges got worse (Wood2 holes:
#: bad3 5.14 % against 1.16 %, docs/tubes.md)
_COARSE = {"matcher": "sgm", "guide": "none", "range": "full", "fusion": "none", "lr_check": False}


def coarse_hole_ranges(left, right, d_min, d_max, config):
    """Per-pixel ranges ``(lo, hi)`` (inclusive int32, full resolution) from an unguided match of the pair at
    ``1 / HOLE_FACTOR`` resolution, for the tube rule's holes (:func:`~riverbed_cli.matching.tubes.hole_bounds`).

    The coarse match is census SGM over the nominal range divided by the factor, with no left-right check,
    guidance, tubes or fusion; the other settings are ``config``'s. A pair smaller than 16 px at that scale gets
    the nominal range.
    """
    f = HOLE_FACTOR
    H, W = left.shape[:2]
    h, w = H // f, W // f
    if min(h, w) < 16:
        return np.full((H, W), d_min, np.int32), np.full((H, W), d_max, np.int32)
    small = [cv2.resize(np.ascontiguousarray(im), (w, h), interpolation=cv2.INTER_AREA) for im in (left, right)]
    res = match_pair(small[0], small[1], None, int(math.floor(d_min / f)), int(math.ceil(d_max / f)),
                     params=config, **_COARSE)
    return hole_bounds(res.disparity, (H, W), d_min, d_max, f)


def fill_tube_holes(left, right, lo, hi, hole, d_min, d_max, config):
    """The tubes ``(lo, hi)`` with the ``hole`` pixels (no LiDAR within reach) given the coarse match's ranges
    (:func:`coarse_hole_ranges`, with ``config``'s settings), for ``tube.holes`` ``coarse``."""
    if not hole.any():
        return lo, hi
    clo, chi = coarse_hole_ranges(left, right, d_min, d_max, config)
    return np.where(hole, clo, lo), np.where(hole, chi, hi)


def match_pair(left, right, sparse=None, d_min=None, d_max=None, *, params=None, range_map=None, beside="auto",
               valid_areas=None, changed_area=None, **overrides):
    """Dense disparity of a rectified pair, optionally guided by sparse LiDAR disparities.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) uint8 / uint16 arrays
        Rectified images; the left one is the reference.
    sparse : (H, W) float, optional
        LiDAR disparities of the left image, NaN where there is none.
    d_min, d_max : int, optional
        Inclusive disparity search range, ``d = x_left - x_right``. Without them the range comes from ``sparse``
        with a margin (:func:`disparity_range_from_sparse`).
    params : MatchConfig, optional
        Settings; keyword ``overrides`` replace single settings by their flat names (``guide="gauss"``,
        ``p2=150``, ``plus_hops=3``) or whole groups (``plus=PlusConfig(hops=3)``), :meth:`MatchConfig.replace`.
        ``range`` chooses the search range per pixel: ``tube`` (from the LiDAR around each pixel,
        :mod:`.tubes`), ``full``, or ``auto`` (tube for a LiDAR-guided matcher that supports it).
    range_map : (lo, hi) of (H, W) float, optional
        Per-pixel disparity ranges from elsewhere (a coarse DSM, a previous run; NaN: the nominal range), used as
        the tubes instead of the LiDAR's.
    beside : "auto" or bool
        Run the fusion's LiDAR side (``Fusion.prepare``) in a thread beside the matcher; ``auto``: for images up to
        ``BESIDE_MAX_PIXELS``. The output is the same either way. Tiled matches pass False: a second thread's
        allocator arena keeps its freed memory beside the main one's, from tile to tile.
    valid_areas : (left_valid, right_valid), optional
        The images' valid areas ((H, W) bool or None each; e.g. a rectified frame's alpha): left pixels outside the
        left one, and those whose every candidate falls outside the right one, are not matched (:mod:`.overlap`).
    changed_area : (H, W) bool, optional
        The changed area of a LiDAR check made already (a tiled match checks the whole image once,
        :mod:`.lidar_check`): ``sparse`` is taken as checked, and the area is searched and fused as the check's.

    Returns
    -------
    MatchResult
        ``disparity``: (H, W) float32, NaN invalid; ``info`` (:class:`MatchInfo`): ``seconds`` (whole matching
        time), ``stages`` (seconds per stage; ``first_pass`` for riverbed+), ``lidar_share``, ``window``,
        ``d_min``, ``d_max``, ``guide``, ``matcher``, ``outside_overlap`` (share of pixels with no candidate
        inside the right image: NaN, confidence 0; :mod:`.overlap`), and for AD-Census ``refinement`` (outlier
        counts and step timings).

    The SGM settings (``config.sgm``) apply to the ``sgm`` matcher; AD-Census takes ``config.adcensus`` and always
    checks left-right consistency in its refinement.
    """
    config = make_config(params, **overrides)
    guide = get_guide(config.guide)
    matcher = get_matcher(config.matcher)
    if left.shape[:2] != right.shape[:2]:
        raise RiverbedError(f"left and right images differ in size: {left.shape[1]}x{left.shape[0]} vs "
                            f"{right.shape[1]}x{right.shape[0]}")
    if guide.needs_sparse and sparse is None:
        raise RiverbedError(f"guide '{guide.name}' needs a sparse LiDAR map (--sparse)")
    t_all = time.perf_counter()
    stages = {}
    offset = None
    if sparse is not None:  # the LiDAR's offset against the images, removed before it sets the range or guides
        sparse = np.asarray(sparse, np.float32)
        check_disparity_values(sparse, left.shape[1])
        sparse, offset = correct_lidar(left, right, sparse, config.lidar_offset)
        stages["lidar_offset"] = round(time.perf_counter() - t_all, 4)
    d_min, d_max = resolve_disparity_range(d_min, d_max, sparse, width=left.shape[1])
    check, changed = None, changed_area
    if sparse is not None and config.lidar_check == "auto" and changed_area is None:
        t0 = time.perf_counter()  # the points the images contradict guide nothing
        sparse, check = check_pair(left, right, sparse, d_min, d_max, config, match_pair)
        stages["lidar_check"] = round(time.perf_counter() - t0, 4)
        changed = check.changed
    if changed is not None and not changed.any():
        changed = None

    shape = left.shape[:2]
    lidar = None
    points, share, share_all = None, 0.0, 0.0
    if sparse is not None:
        lidar = np.asarray(sparse, dtype=np.float32)
        # the LiDAR's pixels found once: for its share, the guide and the fusion's LiDAR side
        sparse, points, share, share_all = prepare_lidar(lidar, shape, d_min, d_max)
        check_lidar_count(len(points[0]), config)
    fuser = get_fusion(resolve_fusion(config, guide, sparse is not None))
    # The fusion's LiDAR side (its Delaunay triangulation is single-threaded OpenCV) needs no stereo: it runs beside
    # the matcher, on the core the matcher's serial parts leave idle; on large images (the tiles of a large pair)
    # after it, as before, so that its arrays do not add to the matcher's peak memory
    lidar_side = None
    if fuser.name != "none":
        if beside == "auto":
            beside = shape[0] * shape[1] <= BESIDE_MAX_PIXELS
        lidar_side = (Beside if beside else After)(fuser.prepare, sparse, config, points)
    try:
        out, mode, stats, tubes = _match_stages(left, right, sparse, lidar, d_min, d_max, config, guide, matcher,
                                                share, range_map, stages, fuser.needs_status, points, share_all,
                                                changed)
        # where the LiDAR reaches: a guided value outside the overlap is kept there, the fusion fills only there
        needs = points is not None and (guide.needs_sparse or fuser.name != "none")
        coverage = lidar_coverage(points, shape) if needs else None
        outside, no_stereo = keep_to_overlap(out, d_min, d_max, valid_areas, tubes,
                                             coverage if guide.needs_sparse else None)
        t0 = time.perf_counter()  # the fusion's stage is the time it adds after the matcher
        fused = fuser.fuse(out.disparity, out.status, sparse, config,
                           lidar_side.result() if lidar_side is not None else None)
    finally:
        if lidar_side is not None:  # not left running behind an error
            lidar_side.join()
    if fuser.name != "none":
        fused = keep_fusion_to_lidar(prefer_stereo(fused, out.disparity, out.status, changed), no_stereo, points,
                                     d_min, d_max, valid_areas, coverage)
        stages["fusion"] = round(time.perf_counter() - t0, 4)
    info = MatchInfo(round(time.perf_counter() - t_all, 4), stages, config.guide, config.matcher, share,
                     len(points[0]) if points is not None else 0, out.window, d_min, d_max,
                     [int(shape[1]), int(shape[0])], out.refinement, mode,
                     stats.to_dict() if stats is not None else None, fuser.name,
                     fused.stats.to_dict() if fused.stats is not None else None,
                     offset.to_dict() if offset is not None else None, round(float(outside.mean()), 6),
                     check.report.to_dict() if check is not None else None)
    return MatchResult(fused.disparity, info, fused.confidence, check)


def _nominal_where(mask, lo, hi, d_min, d_max):
    # the tubes (lo, hi) with the pixels of mask (None: none) searching the nominal range
    if mask is None:
        return lo, hi
    return np.where(mask, np.int32(d_min), lo), np.where(mask, np.int32(d_max), hi)


def _match_stages(left, right, sparse, lidar, d_min, d_max, config, guide, matcher, share, range_map, stages,
                  return_status, points=None, share_all=0.0, changed=None):
    # match_pair's range (tubes), guide preparation and matcher: the matcher's output, the range mode, tube stats,
    # the tubes (None: the whole range)
    shape = left.shape[:2]
    mode = resolve_range(config, guide, matcher, sparse is not None, range_map is not None)
    tubes, stats = None, None
    if mode == "tube":
        t0 = time.perf_counter()
        # The LiDAR outside the nominal range bounds the pixels it alone reaches at the range's end (lidar_tubes):
        # their disparity lies beyond the range, where no search finds it. Only the points inside guide the cost.
        # The spacing counts every point (share_all), as match_tiled's tubes do.
        if range_map is not None:
            lo, hi = check_range_map(range_map, shape, d_min, d_max)
            layout = TubeLayout.from_bounds(*_nominal_where(changed, lo, hi, d_min, d_max), d_min)
        elif config.tube.holes == "coarse" or changed is not None:  # a changed area searches as a hole
            lo, hi, hole = lidar_tubes(lidar, d_min, d_max, share=share_all, return_holes=True, **asdict(config.tube))
            if changed is not None:
                hole |= changed
            if config.tube.holes == "coarse":
                lo, hi = fill_tube_holes(left, right, lo, hi, hole, d_min, d_max, config)
            else:
                lo, hi = _nominal_where(hole, lo, hi, d_min, d_max)
            layout = TubeLayout.from_bounds(lo, hi, d_min)
        else:  # the layout straight from the rule's cells
            layout = lidar_tube_layout(lidar, d_min, d_max, share=share_all, **asdict(config.tube))
        stats = tube_stats(layout, d_min, d_max)
        if stats.full_share < 1.0:  # tubes as wide as the range everywhere: the full-range volume, exactly
            tubes = layout
        stages["range"] = round(time.perf_counter() - t0, 4)
    t0 = time.perf_counter()
    first_pass = guide.prepare(left, right, sparse, d_min, d_max, config, matcher, tubes)
    if guide.has_first_pass:
        stages["first_pass"] = round(time.perf_counter() - t0, 4)
    out = matcher.match(left, right, sparse, d_min, d_max, config, guide, share, first_pass, stages, tubes,
                        return_status=return_status, points=points)
    return out, mode, stats, tubes


def warm_up(matcher="sgm", guide_names=("none", "gauss", "riverbed"), config=None, fusion_lidar=None):
    """Compile (or load from Numba's cache) the kernels ``match_pair`` uses with ``matcher`` and ``guide_names``, on a
    tiny pair; with ``config`` only those of that one configuration (what a ``riverbed match`` run needs), and with
    ``fusion_lidar`` the fusion's LiDAR side the run will take (``planes`` or ``linear``: ``auto`` decides by the
    LiDAR's density, which the tiny pair's is not).

    Loading compiled code is start-up cost; calling this first keeps it out of ``info["seconds"]``.
    """
    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
    right = np.roll(left, -2, axis=1)
    sparse = np.full((24, 32), np.nan, dtype=np.float32)
    sparse[::5, ::5] = 2.0
    if config is not None:
        if fusion_lidar is not None:
            config = config.replace(fusion_lidar=fusion_lidar)
        if config.lidar_check == "auto":  # the tiny pair is too small for the check's reference
            warm_check()
        match_pair(left, right, sparse if get_guide(config.guide).needs_sparse or config.range != "full" else None,
                   0, 7, params=config)
        if config.tube.holes == "coarse" and config.range != "full":  # the coarse match of the tube rule's holes
            match_pair(left, right, None, 0, 7, params=config, **_COARSE)
        return
    for guide in guide_names:
        match_pair(left, right, sparse, 0, 7, guide=guide, matcher=matcher)
    if matcher == "sgm":
        match_pair(left, right, sparse, 0, 7, guide="none", lr_check=True)
