"""``match_pair``: a rectified pair (and sparse LiDAR) through a registered matcher and guide, timed.

The driver checks the inputs, resolves the disparity range, runs the guide's preparation (riverbed+'s first pass)
and hands over to the matcher, which runs the stages (cost, guidance, aggregation, selection, refinement).
Matchers live in ``matching/matchers/``, guides in ``matching/guides/``, their settings in :mod:`.config`.
"""

import time
from dataclasses import asdict

import numpy as np

from ..errors import RiverbedError
from ..runtime.helper_thread import InThread, OnDemand
from . import fusions, guides, matchers  # noqa: F401  (importing them fills the registries)
from .config import MatchConfig
from .overlap import keep_fusion_to_lidar, keep_to_overlap, lidar_coverage
from .lidar_check import REFERENCE_MATCH, check_pair, prefer_stereo
from .lidar_check import warm_up as warm_check
from .lidar_input import check_disparity_values, prepare_lidar, resolve_disparity_range
from .lidar_offset import correct_lidar
from .range_maps import COARSE_MATCH, check_range_map, fill_tube_holes
from .registry import get_fusion, get_guide, get_matcher
from .results import MatchInfo, MatchResult
from .tubes import lidar_tube_layout, lidar_tubes, tube_stats
from .volume import TubeLayout

#: largest image (pixels) whose fusion's LiDAR side runs beside the matcher (``lidar_thread="auto"``): its arrays (about
#: 30 bytes a pixel) would add to the matcher's peak memory; a 40 MP pair's 4 MP tiles peaked at 1526 MiB beside,
#: 1297 MiB after
LIDAR_THREAD_MAX_PIXELS = 2_000_000


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


def match_pair(left, right, sparse=None, d_min=None, d_max=None, *, params=None, range_map=None, lidar_thread="auto",
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
        with a margin (:func:`~.lidar_input.disparity_range_from_sparse`).
    params : MatchConfig, optional
        Settings; keyword ``overrides`` replace single settings by their flat names (``guide="gauss"``,
        ``p2=150``, ``plus_hops=3``) or whole groups (``plus=PlusConfig(hops=3)``), :meth:`MatchConfig.replace`.
        ``range`` chooses the search range per pixel: ``tube`` (from the LiDAR around each pixel,
        :mod:`.tubes`), ``full``, or ``auto`` (tube for a LiDAR-guided matcher that supports it).
    range_map : (lo, hi) of (H, W) float, optional
        Per-pixel disparity ranges from elsewhere (a coarse DSM, a previous run; NaN: the nominal range), used as
        the tubes instead of the LiDAR's.
    lidar_thread : "auto" or bool
        Run the fusion's LiDAR side (``Fusion.prepare``) in a thread beside the matcher; ``auto``: for images up to
        ``LIDAR_THREAD_MAX_PIXELS``. The output is the same either way. Tiled matches pass False: a second thread's
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
        if lidar_thread == "auto":
            lidar_thread = shape[0] * shape[1] <= LIDAR_THREAD_MAX_PIXELS
        lidar_side = (InThread if lidar_thread else OnDemand)(fuser.prepare, sparse, config, points)
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
                lo, hi = fill_tube_holes(left, right, lo, hi, hole, d_min, d_max, config, match_pair)
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
        if config.lidar_check == "auto":  # the check's kernels, and its reference's match (too small a pair for the
            warm_check()  # reference itself)
            match_pair(left, right, None, 0, 7, params=config, **REFERENCE_MATCH)
        match_pair(left, right, sparse if get_guide(config.guide).needs_sparse or config.range != "full" else None,
                   0, 7, params=config)
        if config.tube.holes == "coarse" and config.range != "full":  # the coarse match of the tube rule's holes
            match_pair(left, right, None, 0, 7, params=config, **COARSE_MATCH)
        return
    for guide in guide_names:
        match_pair(left, right, sparse, 0, 7, guide=guide, matcher=matcher)
    if matcher == "sgm":
        match_pair(left, right, sparse, 0, 7, guide="none", lr_check=True)
