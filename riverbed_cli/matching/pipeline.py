"""``match_pair``: the matching stages in order (cost, guidance, aggregation, selection, refinement), timed.

Two matchers: ``sgm`` (census cost, guidance, Semi-Global Matching, winner-takes-all) and ``adcensus`` (Mei et al.
2011, :mod:`adcensus`: AD-Census cost, cross-based aggregation, guidance, scanline optimisation, multi-step
refinement). Guides: ``none``, ``gauss``, ``riverbed`` (the paper, default with LiDAR), ``diffusion``
(:mod:`diffusion`) and ``riverbed+`` (:mod:`riverbed_plus`), applied to the cost volume right before the
SGM-style optimisation in both matchers.
"""

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import RiverbedError
from ..io.images import effective_bits, to_grey, to_guide
from . import adcensus, census, disparity, guidance, sgm

log = logging.getLogger(__name__)

GUIDES = ("none", "gauss", "riverbed", "diffusion", "riverbed+")
MATCHERS = ("sgm", "adcensus")


@dataclass
class MatchParams:
    """Matcher settings; defaults are the paper's where it gives them (k = 10, c = 1, sigma = 8, gamma = 0.3)."""

    guide: str = "riverbed"
    window: object = "auto"  # riverbed window side s (odd) or "auto"
    census: tuple = (9, 7)
    paths: int = 8
    p1: int = 10  # census (Hamming) units
    p2: int = 120
    subpixel: bool = True
    median: int = 3
    lr_check: bool = False
    lr_threshold: int = 1
    outside_cost: object = "auto"  # cost where the match leaves the right image; auto = a quarter of the bits
    k: float = 10.0
    c: float = 1.0
    sigma_xy: float = 8.0
    sigma_i: float = 8.0
    gamma: float = 0.3
    band: float = 3.0
    form: str = "additive"
    wall_scale: object = "auto"  # F_bar of the additive walls; auto = half the largest cost (a random mismatch):
    #                              half the census bits (sgm), 1.0 of AD-Census's [0, 2] (adcensus)
    cost_scale: int = 4  # guided costs are kept in uint16 at this resolution (1/4 of a Hamming unit)
    window_target: float = 4.0  # auto window: smallest odd s with s*s*p >= window_target (measured, docs/method.md)
    literal_eq3: bool = False  # homogeneous pixels by eq. 3 as printed (W > gamma); only to reproduce that reading
    matcher: str = "sgm"  # "sgm" (census + SGM) or "adcensus" (Mei et al. 2011, adcensus.py)
    adcensus: object = None  # adcensus.ADCensusParams; None = its defaults (the paper's)
    diffusion: object = None  # dict of diffusion_modulate keywords (radius, sigma_s, sigma_i); None = defaults
    plus: object = None  # riverbed_plus.PlusParams; None = defaults (guide "riverbed+")
    _status: bool = False  # internal: AD-Census returns its left-right outlier map in info["status"]


@dataclass
class MatchResult:
    disparity: np.ndarray
    info: dict = field(default_factory=dict)


def disparity_range_from_sparse(sparse, margin=None):
    """Inclusive integer range ``(d_min, d_max)`` covering the sparse disparities plus a margin.

    The margin (px) defaults to ``max(8, 15 % of the LiDAR span)``: LiDAR misses parts of the scene (occlusions,
    dark surfaces) whose disparities may lie a little beyond what it saw.
    """
    vals = sparse[np.isfinite(sparse)]
    if vals.size == 0:
        raise RiverbedError("sparse map has no valid disparities")
    lo, hi = float(vals.min()), float(vals.max())
    if margin is None:
        margin = max(8.0, 0.15 * (hi - lo))
    return int(math.floor(lo - margin)), int(math.ceil(hi + margin))


def resolve_disparity_range(d_min, d_max, sparse_values):
    """``(d_min, d_max)`` as ints, the missing ends derived from the sparse disparities (any array, NaN ignored)."""
    if d_min is None or d_max is None:
        if sparse_values is None:
            raise RiverbedError("give the disparity range (--min-disp/--max-disp) or a sparse map to derive it from")
        lo, hi = disparity_range_from_sparse(sparse_values)
        d_min = lo if d_min is None else d_min
        d_max = hi if d_max is None else d_max
    d_min, d_max = int(d_min), int(d_max)
    if d_max < d_min:
        raise RiverbedError(f"empty disparity range: --min-disp {d_min} > --max-disp {d_max}")
    return d_min, d_max


def _match_info(p, t_all, stages, share, sparse, window, d_min, d_max, shape, **extra):
    """The ``info`` of a :class:`MatchResult`."""
    return {
        "seconds": round(time.perf_counter() - t_all, 4),
        "stages": stages,
        "guide": p.guide,
        "matcher": p.matcher,
        "lidar_share": share,
        "lidar_points": int(np.isfinite(sparse).sum()) if sparse is not None else 0,
        "window": window,
        "d_min": d_min,
        "d_max": d_max,
        "size": [int(shape[1]), int(shape[0])],
        **extra,
    }


def _prepare_sparse(sparse, shape, d_min, d_max):
    sparse = np.asarray(sparse, dtype=np.float32)
    if sparse.shape != shape:
        raise RiverbedError(
            f"sparse map is {sparse.shape[1] if sparse.ndim > 1 else '?'}x{sparse.shape[0]} (WxH) but the images are "
            f"{shape[1]}x{shape[0]}"
        )
    valid = np.isfinite(sparse)
    n = int(valid.sum())
    if n == 0:
        raise RiverbedError("sparse map has no valid disparities")
    inside = valid & (sparse >= d_min) & (sparse <= d_max)
    n_in = int(inside.sum())
    if n_in == 0:
        vals = sparse[valid]
        raise RiverbedError(
            f"disparity range [{d_min}, {d_max}] excludes all sparse disparities (they span "
            f"[{vals.min():.2f}, {vals.max():.2f}])"
        )
    if n_in < n:
        log.warning("%d of %d sparse disparities lie outside [%d, %d] and are ignored", n - n_in, n, d_min, d_max)
        sparse = np.where(inside, sparse, np.float32(np.nan))
    return sparse


def match_pair(left, right, sparse=None, d_min=None, d_max=None, params=None, **overrides):
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
    params : MatchParams, optional
        Settings; keyword ``overrides`` replace single fields (``match_pair(l, r, s, guide="gauss")``).

    Returns
    -------
    MatchResult
        ``disparity``: (H, W) float32, NaN invalid; ``info``: ``seconds`` (whole matching time), ``stages``
        (seconds per stage; ``first_pass`` for riverbed+), ``lidar_share``, ``window``, ``d_min``, ``d_max``,
        ``guide``, ``matcher``, and for AD-Census ``refinement`` (outlier counts and step timings).

    ``p1``, ``p2``, ``paths``, ``lr_check`` and ``cost_scale`` apply to the SGM matcher; AD-Census takes its
    settings from ``params.adcensus`` (:class:`adcensus.ADCensusParams`) and always checks left-right consistency in
    its refinement.
    """
    p = MatchParams(**{**(params.__dict__ if params else {}), **overrides})
    if p.guide not in GUIDES:
        raise RiverbedError(f"unknown guide '{p.guide}' (use one of {', '.join(GUIDES)})")
    if p.matcher not in MATCHERS:
        raise RiverbedError(f"unknown matcher '{p.matcher}' (use one of {', '.join(MATCHERS)})")
    if left.shape[:2] != right.shape[:2]:
        raise RiverbedError(f"left and right images differ in size: {left.shape[1]}x{left.shape[0]} vs "
                            f"{right.shape[1]}x{right.shape[0]}")
    if p.guide != "none" and sparse is None:
        raise RiverbedError(f"guide '{p.guide}' needs a sparse LiDAR map (--sparse)")
    d_min, d_max = resolve_disparity_range(d_min, d_max, sparse)

    t_all = time.perf_counter()
    stages = {}

    def lap(name, t0):
        stages[name] = round(time.perf_counter() - t0, 4)

    shape = left.shape[:2]
    if sparse is not None:
        sparse = _prepare_sparse(sparse, shape, d_min, d_max)
    unreliable = None
    if p.guide == "riverbed+":
        t0 = time.perf_counter()
        unreliable = _unreliable_pixels(left, right, sparse, d_min, d_max, p)
        lap("first_pass", t0)
    if p.matcher == "adcensus":
        return _match_adcensus(left, right, sparse, d_min, d_max, p, t_all, stages, unreliable)

    t0 = time.perf_counter()
    win = census.parse_census_window(p.census)
    nbits = win[0] * win[1] - 1
    outside = nbits // 4 if p.outside_cost == "auto" else int(p.outside_cost)
    scale = 1 if p.guide == "none" else int(p.cost_scale)
    bits = effective_bits(left, right)  # one scale for both images of a 16-bit pair
    cl = census.census_transform(to_grey(left, bits), win)
    cr = census.census_transform(to_grey(right, bits), win)
    cost = census.census_cost(cl, cr, d_min, d_max, outside, scale)
    del cl, cr
    lap("cost", t0)

    share = guidance.lidar_share(sparse) if sparse is not None else 0.0
    window = None
    max_cost = max(nbits, outside) * scale
    t0 = time.perf_counter()
    if p.guide != "none":
        cap = 65535 // p.paths - p.p2 * scale
        # A fixed wall scale (not the mean cost at this image's LiDAR pixels) keeps tiles consistent with the whole
        # image; the walls' height barely matters (docs/method.md).
        fbar = nbits / 2.0 if p.wall_scale == "auto" else float(p.wall_scale)
        if cap <= nbits * scale:
            raise RiverbedError(f"P2 {p.p2} is too large for {p.paths} paths with guided uint16 costs")
        if p.guide == "gauss":
            cost = guidance.gauss_modulate(cost, sparse, d_min, p.k, p.c, p.form, scale, cap, inplace=True,
                                           fbar=fbar)
            max_cost = cap
        elif p.guide in ("diffusion", "riverbed+"):
            cost, window = _modulate(cost, sparse, to_guide(left, bits), d_min, p, share, scale, cap, fbar,
                                     unreliable)
        else:
            window = guidance.auto_window(share, p.window_target) if p.window == "auto" else int(p.window)
            cost = guidance.riverbed_modulate(cost, sparse, to_guide(left, bits), d_min, window, p.k, p.c, p.sigma_xy,
                                              p.sigma_i, p.gamma, p.band, p.form, scale, cap, inplace=True,
                                              literal_eq3=p.literal_eq3, fbar=fbar)
        max_cost = cap
    lap("guidance", t0)

    t0 = time.perf_counter()
    fwd, bwd = sgm.sgm_aggregate_passes(cost, p.p1 * scale, p.p2 * scale, p.paths, max_cost=max_cost)
    del cost
    lap("aggregation", t0)

    t0 = time.perf_counter()
    disp = disparity.select_disparity(fwd, d_min, p.subpixel, p.lr_check, p.lr_threshold, aggregated2=bwd)
    del fwd, bwd
    lap("selection", t0)

    t0 = time.perf_counter()
    disp = disparity.median_filter(disp, p.median)
    lap("refinement", t0)

    return MatchResult(disp, _match_info(p, t_all, stages, share, sparse, window, d_min, d_max, shape))


def _plus_params(p):
    from .riverbed_plus import PlusParams

    return p.plus or PlusParams()


def _unreliable_pixels(left, right, sparse, d_min, d_max, p):
    """riverbed+ confidence: pixels whose riverbed-guided match fails the left-right check (None: extend to all)."""
    q = _plus_params(p)
    if q.confidence == "none":
        return None
    if q.confidence != "lr":
        raise RiverbedError(f"unknown riverbed+ confidence '{q.confidence}' (use lr or none)")
    if p.matcher == "adcensus":
        first = match_pair(left, right, sparse, d_min, d_max, p, guide="riverbed", _status=True)
        return first.info.pop("status") > 0
    first = match_pair(left, right, sparse, d_min, d_max, p, guide="riverbed", lr_check=True,
                       lr_threshold=q.lr_threshold, median=1)
    return ~np.isfinite(first.disparity)


def _modulate(cost, sparse, guide_img, d_min, p, share, scale, cap, fbar, unreliable=None, want_support=False):
    """Guide a cost volume (uint16 in units of ``1 / scale``, modulated in place) with ``p.guide``; ``fbar`` is
    the wall scale ``F_bar`` in plain cost units, ``unreliable`` the riverbed+ first-pass mask.

    Returns ``(volume, window)`` (the riverbed window, None for guides without one), and with ``want_support`` also
    the ``(lo, hi)`` disparity interval the guide vouches for per pixel (NaN elsewhere; AD-Census's refinement keeps
    those winners): the LiDAR disparity at LiDAR pixels (Gauss), riverbed's band at its homogeneous pixels
    (similarity >= gamma), the disparity a pixel received from the diffusion with a weight >= gamma, riverbed+'s
    extended band.
    """
    window = None
    support = None
    if p.guide == "gauss":
        cost = guidance.gauss_modulate(cost, sparse, d_min, p.k, p.c, p.form, scale, cap, inplace=True, fbar=fbar)
        if want_support:
            support = (sparse, sparse)
    elif p.guide == "riverbed":
        window = guidance.auto_window(share, p.window_target) if p.window == "auto" else int(p.window)
        owners = guidance.homogeneous_owners(sparse, guide_img, window, p.sigma_xy, p.sigma_i, p.gamma,
                                             p.literal_eq3)
        cost = guidance.riverbed_modulate(cost, sparse, guide_img, d_min, window, p.k, p.c, p.sigma_xy, p.sigma_i,
                                          p.gamma, p.band, p.form, scale, cap, owners=owners, inplace=True,
                                          literal_eq3=p.literal_eq3, fbar=fbar)
        if want_support:
            from .riverbed_plus import riverbed_support

            support = riverbed_support(sparse, owners, p.band)
    elif p.guide == "diffusion":
        from .diffusion import diffusion_modulate

        if want_support:
            cost, dref = diffusion_modulate(cost, sparse, guide_img, d_min, cost_scale=scale, inplace=True,
                                            support_weight=p.gamma, **(p.diffusion or {}))
            support = (dref, dref)
        else:
            cost = diffusion_modulate(cost, sparse, guide_img, d_min, cost_scale=scale, inplace=True,
                                      **(p.diffusion or {}))
    elif p.guide == "riverbed+":
        from .riverbed_plus import riverbed_plus_modulate

        window = guidance.auto_window(share, p.window_target) if p.window == "auto" else int(p.window)
        cost, extra = riverbed_plus_modulate(cost, sparse, guide_img, d_min, window, p.k, p.c, p.sigma_xy,
                                             p.sigma_i, p.gamma, p.band, p.form, scale, cap, fbar, _plus_params(p),
                                             unreliable, share, inplace=True, return_support=want_support)
        support = extra.get("support")
    if want_support:
        return cost, window, support
    return cost, window


def _match_adcensus(left, right, sparse, d_min, d_max, p, t_all, stages, unreliable=None):
    """``match_pair`` with the AD-Census matcher: guidance between cross aggregation and scanline optimisation."""
    ap = p.adcensus or adcensus.ADCensusParams()
    bits = effective_bits(left, right)
    guide_img = to_guide(left, bits)
    il, ir = adcensus.to_u8(guide_img), adcensus.to_u8(to_guide(right, bits))
    grey = (to_grey(left, bits), to_grey(right, bits))
    share = guidance.lidar_share(sparse) if sparse is not None else 0.0
    used = {"window": None}
    modulate = None
    if p.guide != "none":
        # int16 scanline paths: a guided cost plus the largest penalty must stay below 16384 (and each half-sum of
        # two paths within int16)
        cap = 16383 - int(adcensus.so_penalties(ap.pi1, ap.pi2, ap.scale)[1][0])
        # wall scale: half the largest AD-Census cost (1.0 of the paper's [0, 2]), as half the census bits for SGM
        fbar = 1.0 if p.wall_scale == "auto" else float(p.wall_scale)

        def modulate(vol, max_cost):
            vol, used["window"], support = _modulate(vol, sparse, guide_img, d_min, p, share, ap.scale, cap, fbar,
                                                     unreliable, want_support=True)
            return vol, cap, support

    timings = {}
    disp, ref = adcensus.adcensus_disparity(il, ir, d_min, d_max, ap, census.parse_census_window(p.census), grey,
                                            modulate, p.subpixel, p.median, timings, return_status=p._status)
    stages.update({k: round(v, 4) for k, v in timings.items()})
    info = _match_info(p, t_all, stages, share, sparse, used["window"], d_min, d_max, left.shape, refinement=ref)
    if p._status:
        info["status"] = ref.pop("status")
    return MatchResult(disp, info)


def warm_up(matcher="sgm", guides=("none", "gauss", "riverbed")):
    """Compile (or load from Numba's cache) the kernels ``match_pair`` uses with ``matcher`` and ``guides``, on a
    tiny pair.

    Loading compiled code is start-up cost; calling this first keeps it out of ``info["seconds"]``.
    """
    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
    right = np.roll(left, -2, axis=1)
    sparse = np.full((24, 32), np.nan, dtype=np.float32)
    sparse[::5, ::5] = 2.0
    for guide in guides:
        match_pair(left, right, sparse, 0, 7, guide=guide, matcher=matcher)
    if matcher == "sgm":
        match_pair(left, right, sparse, 0, 7, guide="none", lr_check=True)
