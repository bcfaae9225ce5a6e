"""Tiled matching: overlapping tiles, each with the disparity range its LiDAR allows, stitched into one map.

Stage: ``(pair, LiDAR, MatchPlan) -> disparity map``. The plan (:mod:`.plan`: range, shares, window, tiles) is made
once for the whole pair, after the LiDAR's offset and check made once for it too (:func:`prepare_lidar_whole`).

How a tile is matched. The left crop covers the tile plus ``overlap`` on each side (SGM paths need room to settle)
and, on its left, ``d_max - d_min`` extra columns; the right crop has the same width, shifted left by ``off =
min(d_min, a)`` columns (``a`` the crop's first column), so every match ``x - d`` of the tile lies inside it and
:func:`~riverbed_cli.matching.pipeline.match_pair` runs unchanged on equal-size crops with the range ``[d_min - off,
d_max - off]``; ``off`` is added back. Only the tile's own pixels (not the overlap) are kept.
"""

import logging
import time
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import RiverbedError
from ..io.images import to_guide
from ..io.windowed import bounded_raster_cache, image_bits, sparse_points_any
from ..matching.config import OVERLAP_DEFAULT, TILE_DEFAULT
from ..matching.guidance import lidar_share
from ..matching.lidar_check import check_pair
from ..matching.lidar_input import check_disparity_values, check_inside, resolve_disparity_range
from ..matching.lidar_offset import correct_large
from ..matching.pipeline import check_lidar_count, lidar_points_needed, make_config, match_pair, resolve_range
from ..matching.range_maps import fill_tube_holes, range_map_ends
from ..matching.registry import get_guide, get_matcher
from ..matching.results import MatchResult, TiledMatchInfo
from ..matching.tubes import lidar_tubes_window
from .match_plan import check_tiling, plan_match, scan_range_map, tile_budget

log = logging.getLogger(__name__)


@dataclass
class TileTubes:
    """The tubes of a tile's own pixels (not its overlap): ``width_sum`` (disparities searched), ``pixels``,
    ``max_width`` and ``full`` (pixels on the whole image's nominal range)."""

    width_sum: int
    pixels: int
    max_width: int
    full: int


def tiled_tube_stats(parts, d_min, d_max):
    """The whole image's tube statistics (``riverbed match --json``'s ``tubes``) from its tiles'
    :class:`TileTubes`; None when no tile searched tubes."""
    parts = [q for q in parts if q is not None]
    if not parts:
        return None
    n = sum(q.pixels for q in parts)
    return {"mean_width": round(sum(q.width_sum for q in parts) / n, 3), "max_width": max(q.max_width for q in parts),
            "nominal": int(d_max) - int(d_min) + 1, "full_share": round(sum(q.full for q in parts) / n, 5)}


#: bytes a tile's volumes may take in the check's reference: at the match's own budget the tiles of its first pass
#: (over the whole range) and of its second would raise a tiled match's peak memory well above what its tubes take
REFERENCE_BUDGET = 512 * 2**20
#: the overlap (coarse px) of those tiles: the match's 128 px would be 256 px of the image at half resolution and
#: double the tiles' work at that budget (at 64 the reference differs on few pixels by more than half a coarse px)
REFERENCE_OVERLAP = 64


def reference_match(left, right, sparse=None, d_min=None, d_max=None, **settings):
    """:func:`match_tiled` for the check's reference (:func:`~riverbed_cli.matching.lidar_check.coarse_reference`),
    in tiles of at most :data:`REFERENCE_BUDGET` bytes of volumes and :data:`REFERENCE_OVERLAP` px of overlap."""
    budget = min(REFERENCE_BUDGET, tile_budget())
    return match_tiled(left, right, sparse, d_min, d_max, budget=budget, overlap=REFERENCE_OVERLAP, **settings)


def check_whole(left, right, sparse, d_min, d_max, params):
    """The LiDAR check (:mod:`~riverbed_cli.matching.lidar_check`) once for a whole pair matched in tiles (a tile's
    own check could drop other points than its neighbour's), its reference matched in tiles too: ``(sparse,
    check)``, the checked sparse map (an array) and the :class:`~riverbed_cli.matching.lidar_check.LidarCheck`
    (its ``report``, the changed area ``changed``, the ``dropped`` points). ``left``, ``right`` and ``sparse`` may
    be windowed rasters (read whole here)."""
    arrays = [np.asarray(a[:, :]) for a in (left, right)]
    return check_pair(*arrays, np.asarray(sparse[:, :], np.float32), d_min, d_max, params, reference_match)


class CheckedSparse:
    """A sparse map (an array or windowed, sliced ``[y0:y1, x0:x1]``) without the points its LiDAR check dropped
    (``dropped``: the check's (H, W) uint8, > 0 where a point was dropped): a tiled match keeps that byte per pixel
    instead of a float copy of the whole map."""

    def __init__(self, src, dropped):
        self.src, self.dropped = src, dropped
        self.shape, self.ndim, self.dtype = tuple(src.shape[:2]), 2, np.dtype(np.float32)

    def __getitem__(self, key):
        rows, cols = key[:2] if isinstance(key, tuple) else (key, slice(None))
        out = np.array(self.src[rows, cols], np.float32)
        out[self.dropped[rows, cols] > 0] = np.nan
        return out

    def __array__(self, dtype=None, copy=None):  # the whole map, for a caller that needs it (a block's sparse.tif)
        out = self[0:self.shape[0], 0:self.shape[1]]
        return out if dtype is None else out.astype(dtype)


@dataclass
class WholeLidar:
    """A pair's LiDAR as it will guide its tiles (:func:`prepare_lidar_whole`): ``sparse`` (the given map, the map
    with its offset removed, or a :class:`CheckedSparse` of it when the check dropped points), its ``points``
    ``(rows, cols, values)``, ``corrected`` (the map with its offset removed, before the check), the range
    ``d_min``, ``d_max`` resolved with it, the :class:`~riverbed_cli.matching.lidar_offset.OffsetEstimate`
    ``offset``, the :class:`~riverbed_cli.matching.lidar_check.LidarCheck` ``check`` (None with ``lidar_check``
    off) and the two stages' ``seconds``."""

    sparse: object
    points: tuple
    corrected: object
    d_min: int
    d_max: int
    offset: object
    check: object
    seconds: dict


def prepare_lidar_whole(left, right, sparse, points, d_min, d_max, params):
    """The LiDAR's offset against the images removed and its check made, once for a whole pair (a tile's own could
    differ from its neighbour's; the tiles take the result as it is): a tiled match's and a block pair's.

    ``points``: ``sparse``'s ``(rows, cols, values)``; ``d_min``, ``d_max``: the range given (None: from the
    corrected LiDAR, :func:`~riverbed_cli.matching.lidar_input.resolve_disparity_range`). The offset is estimated
    over the pair's central window (:func:`~riverbed_cli.matching.lidar_offset.correct_large`), the check's
    reference matched in tiles (:func:`check_whole`). Returns a :class:`WholeLidar`.
    """
    W = left.shape[1]
    check_disparity_values(points[2], W)  # a point next to a camera is no disparity of the pair
    t0 = time.perf_counter()
    given = sparse
    sparse, offset = correct_large(left, right, sparse, points, params.lidar_offset, image_bits(left, right))
    if sparse is not given:
        points = sparse_points_any(sparse)
    seconds = {"lidar_offset": round(time.perf_counter() - t0, 4)}
    d_min, d_max = resolve_disparity_range(d_min, d_max, points[2], width=W)
    check, corrected = None, sparse
    if params.lidar_check == "auto":
        t0 = time.perf_counter()
        _, check = check_whole(left, right, sparse, d_min, d_max, params)
        if check.dropped is not None and check.dropped.any():  # the points kept: those it did not drop
            keep = check.dropped[points[0], points[1]] == 0
            points = tuple(a[keep] for a in points)
            sparse = CheckedSparse(sparse, check.dropped)
        seconds["lidar_check"] = round(time.perf_counter() - t0, 4)
    return WholeLidar(sparse, points, corrected, d_min, d_max, offset, check, seconds)


def match_tile(left, right, sparse, t, overlap, params, bits=8, share_all=None, global_range=None, range_map=None,
               confidence=False, valid_areas=None, changed=None):
    """Match one :class:`Tile` (sources sliced like numpy arrays: arrays, memory maps, :class:`WindowedRaster`).

    Returns ``(block, evaluations, stages, tubes)``: the tile's own disparities (float32, ``t.y1 - t.y0`` x ``t.x1 -
    t.x0``), the disparity evaluations done on its crop, the stage timings, and with tubes a
    :class:`TileTubes` of the tile's own pixels (None on whole ranges). ``params.window`` should be fixed
    (not "auto") so every tile uses the same riverbed window; ``bits`` is the whole pair's effective bit depth.
    With tubes (``params.range``), ``share_all`` (the whole image's LiDAR share, every point) and ``global_range``
    (the whole image's ``(d_min, d_max)``) make the crop's tubes the whole image's (:func:`lidar_tubes_window`),
    clipped to the tile's range. A ``range_map`` (the whole image's checked ``(lo, hi)``, NaN: no range) gives the tubes
    instead.
    With ``confidence`` a fifth value: the fusion's confidence of the tile's own pixels (NaN where the tile was not
    fused: no LiDAR in its range). ``valid_areas``: the images' valid areas ``(left, right)``, each None or sliced
    like the images (:func:`~riverbed_cli.io.windowed.valid_area_source`). ``changed``: the whole pair's changed
    area from its LiDAR check (:func:`check_whole`; sliced like the images), searched on the tile's whole range.
    """
    H, W = left.shape[:2]
    ya, yb = max(0, t.y0 - overlap), min(H, t.y1 + overlap)
    a = max(0, t.x0 - overlap - (t.d_max - t.d_min))
    b = min(W, t.x1 + overlap)
    off = min(t.d_min, a) if t.d_min >= 0 else max(t.d_min, b - W)
    # the tile's range in the crop, cut to what the crop can match (|d| < its width: beyond, every pixel's match
    # lies outside the right crop)
    cw = b - a
    lo_c, hi_c = max(t.d_min - off, 1 - cw), min(t.d_max - off, cw - 1)
    if lo_c > hi_c:  # no pixel of the tile can match a disparity of its range
        block = np.full((t.y1 - t.y0, t.x1 - t.x0), np.nan, np.float32)
        return (block, 0, {}, None) + ((block.copy(),) if confidence else ())
    lc = np.asarray(left[ya:yb, a:b])
    rc = np.asarray(right[ya:yb, a - off:b - off])
    if bits > 8:
        # one 0..255 scale for every tile of a 16-bit pair (a tile's own maximum would change it)
        lc, rc = (np.squeeze(to_guide(c, bits), axis=-1) if c.ndim == 2 else to_guide(c, bits) for c in (lc, rc))
    sc = None
    if sparse is not None:
        sc = np.asarray(sparse[ya:yb, a:b], np.float32) - np.float32(off)
        # LiDAR outside the tile's range cannot guide it (match_pair would warn about every tile)
        sc = np.where((sc >= lo_c) & (sc <= hi_c), sc, np.float32(np.nan))
        # a tile with too few LiDAR points to guide it is matched as one with none
        if get_guide(params.guide).needs_sparse and np.count_nonzero(np.isfinite(sc)) < lidar_points_needed(params):
            sc = None
    kw = {} if sc is not None or not get_guide(params.guide).needs_sparse else {"guide": "none"}
    p = params.replace(**kw) if kw else params
    mode = resolve_range(p, get_guide(p.guide), get_matcher(p.matcher), sc is not None, range_map is not None)
    full_map, range_map = range_map, None
    if mode == "tube" and full_map is not None:
        ends = range_map_ends(full_map[0][ya:yb, a:b], full_map[1][ya:yb, a:b], t.d_min, t.d_max)
        range_map = tuple(np.clip(e - off, lo_c, hi_c) for e in ends)
    elif mode == "tube" and sparse is not None:
        g_lo, g_hi = global_range if global_range is not None else (t.d_min, t.d_max)
        share = share_all if share_all is not None else lidar_share(sc)
        coarse = p.tube.holes == "coarse"
        lo, hi, *hole = lidar_tubes_window(sparse, ya, yb, a, b, g_lo, g_hi, share, asdict(p.tube), coarse)
        lo = np.clip(lo - off, lo_c, hi_c)
        hi = np.clip(hi - off, lo_c, hi_c)
        if coarse:
            # the holes take the coarse match of the tile's own crop over the tile's range (a tile that is the
            # whole image: the untiled match's)
            lo, hi = fill_tube_holes(lc, rc, lo, hi, hole[0], lo_c, hi_c, p, match_pair)
        range_map = (lo, hi)
    ch = None if changed is None else np.asarray(changed[ya:yb, a:b], np.bool_)
    # the fusion's LiDAR side in this thread: a thread's malloc arena would keep its freed memory from tile to tile
    # (10 MP: 1233-1267 MiB peak against 1193-1201)
    lv, rv = valid_areas if valid_areas is not None else (None, None)
    crops = (None if lv is None else np.asarray(lv[ya:yb, a:b]),
             None if rv is None else np.asarray(rv[ya:yb, a - off:b - off]))
    res = match_pair(lc, rc, sc, lo_c, hi_c, params=p, range_map=range_map, lidar_thread=False, valid_areas=crops,
                     changed_area=ch)
    block = res.disparity[t.y0 - ya:t.y1 - ya, t.x0 - a:t.x1 - a] + np.float32(off)
    tubes = res.info.get("tubes")
    n = int(lc.shape[0] * lc.shape[1] * (tubes["mean_width"] if tubes else (t.d_max - t.d_min + 1)))
    own = None
    if range_map is not None and res.info["range"] == "tube":
        w = (range_map[1] - range_map[0] + 1)[t.y0 - ya:t.y1 - ya, t.x0 - a:t.x1 - a]
        g_lo, g_hi = global_range if global_range is not None else (t.d_min, t.d_max)
        own = TileTubes(int(w.sum()), int(w.size), int(w.max()), int((w >= g_hi - g_lo + 1).sum()))
    out = np.ascontiguousarray(block), n, res.info["stages"], own
    if not confidence:
        return out
    conf = res.confidence
    conf = (np.full(block.shape, np.nan, np.float32) if conf is None else
            np.ascontiguousarray(conf[t.y0 - ya:t.y1 - ya, t.x0 - a:t.x1 - a]))
    return (*out, conf)


def match_tiled(left, right, sparse=None, d_min=None, d_max=None, *, params=None, tile=TILE_DEFAULT,
                overlap=OVERLAP_DEFAULT, lidar_range=True, progress=None, out=None, range_map=None,
                confidence_out=None, range_scan=None, valid_areas=None, points=None, budget=None, **overrides):
    """:func:`match_pair` tile by tile; same arguments plus ``tile`` (px, ``"auto"`` or 0), ``overlap`` (px) and
    ``lidar_range``; ``range_map`` (per-pixel ``(lo, hi)``, NaN: the nominal range) as :func:`match_pair`'s: each
    tile searches the range the map spans there and its pixels their own intervals (``range_scan``: its
    :func:`scan_range_map`, when the caller has read it already; ``points`` likewise ``sparse``'s points, ``(rows,
    cols, values)``). ``confidence_out`` receives the
    fusion's confidence tile by tile as ``out`` the disparities (NaN in tiles that were not fused).

    ``valid_areas`` (the images' valid areas, :func:`match_tile`'s) as :func:`match_pair`'s. ``budget``: the bytes
    an automatic tile's volumes may take (default :func:`~.match_plan.tile_budget`).

    ``left``, ``right`` and ``sparse`` may be numpy arrays or :class:`WindowedRaster` (read tile by tile); ``out``
    receives each tile by ``out[y0:y1, x0:x1] = block`` (default: a new float32 array, returned in the result).
    The tiling is :func:`plan_tiles`'s (an image that fits one tile is one tile).

    Returns a :class:`MatchResult` whose ``info`` (:class:`TiledMatchInfo`) adds ``tiles`` (count), ``tile``,
    ``overlap``, ``disparity_evaluations`` (sum over tiles of pixels x disparities, the work done) and per-stage
    sums.
    """
    p = make_config(params, **overrides)
    tile = check_tiling(tile, overlap)
    guide = get_guide(p.guide)
    H, W = left.shape[:2]
    if right.shape[:2] != (H, W):
        raise RiverbedError(f"left and right images differ in size: {W}x{H} vs {right.shape[1]}x{right.shape[0]}")
    if sparse is not None and sparse.shape[:2] != (H, W):
        raise RiverbedError(f"sparse map is {sparse.shape[1]}x{sparse.shape[0]} but the images are {W}x{H} (WxH)")
    with bounded_raster_cache():  # GDAL's cache would otherwise hold blocks of the whole image
        t_all = time.perf_counter()
        rmap, scan = None, range_scan
        if range_map is not None:  # read once to check and plan, kept as it is (tiles read their windows)
            rmap = tuple(range_map)
            scan = scan if scan is not None else scan_range_map(rmap, (H, W))
            span = scan.span()
            if span is not None:
                d_min = span[0] if d_min is None else d_min
                d_max = span[1] if d_max is None else d_max
        lidar = None
        if sparse is not None:
            points = sparse_points_any(sparse) if points is None else points
            if points[2].size == 0:
                raise RiverbedError("sparse map has no valid disparities")
            check_lidar_count(points[2].size, p)
            # the plan and the tiles see the LiDAR as it guides; the tiles leave it as it is
            lidar = prepare_lidar_whole(left, right, sparse, points, d_min, d_max, p)
            sparse, points, d_min, d_max = lidar.sparse, lidar.points, lidar.d_min, lidar.d_max
            p = p.replace(lidar_offset="none", lidar_check="off")
            pv = points[2]
            inside = (pv >= d_min) & (pv <= d_max)
            check_inside(int(inside.sum()), pv.size, d_min, d_max, lambda: pv)
        else:
            points = None
            d_min, d_max = resolve_disparity_range(d_min, d_max, None, width=W)
        if scan is not None:
            scan.check(d_min, d_max)
        plan = plan_match((H, W), points, d_min, d_max, p, sparse=sparse, tile=tile, overlap=overlap,
                          lidar_range=lidar_range, scan=scan, budget=budget)
        p = p.replace(window=plan.window)
        bits = image_bits(left, right)
        changed = lidar.check.changed if lidar is not None and lidar.check is not None else None
        if out is None:
            out = np.full((H, W), np.nan, np.float32)
        stages = dict(lidar.seconds) if lidar is not None else {}  # the tiles' own (forced, off) ones are free
        evaluations = 0
        tube_parts = []
        for t in plan.tile_list():
            block, n, st, tube, *conf = match_tile(left, right, sparse, t, overlap, p, bits, plan.share_all,
                                                   (d_min, d_max), rmap, confidence_out is not None, valid_areas,
                                                   changed)
            tube_parts.append(tube)
            out[t.y0:t.y1, t.x0:t.x1] = block
            if conf:
                confidence_out[t.y0:t.y1, t.x0:t.x1] = conf[0]
            evaluations += n
            for k, v in st.items():
                if k not in ("lidar_offset", "lidar_check"):
                    stages[k] = round(stages.get(k, 0.0) + v, 4)
            if progress:
                progress(1)
    tubes = tiled_tube_stats(tube_parts, d_min, d_max)
    mode = "tube" if tubes is not None else ("tile" if sparse is not None and lidar_range else "full")
    offset = lidar.offset if lidar is not None else None
    check = lidar.check.report if lidar is not None and lidar.check is not None else None
    info = TiledMatchInfo(round(time.perf_counter() - t_all, 4), stages, p.guide, plan.share_in_range,
                          p.guidance.window if guide.uses_window else None, d_min, d_max, [W, H], len(plan.tiles),
                          plan.tile, overlap, int(evaluations), plan.tile_ranges, mode, tubes,
                          offset.to_dict() if offset is not None else None,
                          check.to_dict() if check is not None else None)
    return MatchResult(out, info, lidar_check=lidar.check if lidar is not None else None)
