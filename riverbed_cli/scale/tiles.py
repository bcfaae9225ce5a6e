"""Tiled matching: overlapping tiles, each with the disparity range its LiDAR allows, stitched into one map.

Memory is bounded by the tile, not the image: a tile of ``T x T`` pixels with ``D`` disparities needs about
``6 T (T + D) D`` bytes (three uint16 volumes) plus the images.

How a tile is matched. The left crop covers the tile plus ``overlap`` on each side (SGM paths need room to settle)
and, on its left, ``d_max - d_min`` extra columns; the right crop has the same width, shifted left by ``off =
min(d_min, a)`` columns (``a`` the crop's first column), so every match ``x - d`` of the tile lies inside it and
:func:`~riverbed_cli.matching.pipeline.match_pair` runs unchanged on equal-size crops with the range ``[d_min - off,
d_max - off]``; ``off`` is added back. Only the tile's own pixels (not the overlap) are kept.
"""

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..errors import RiverbedError
from ..matching.pipeline import MatchParams, MatchResult, match_pair

log = logging.getLogger(__name__)


@dataclass
class Tile:
    y0: int
    y1: int
    x0: int
    x1: int
    d_min: int = 0
    d_max: int = 0
    source: str = "global"  # where the range came from: lidar, neighbours or global


def tile_grid(height, width, tile):
    """Tiles of at most ``tile x tile`` pixels covering the image, row by row."""
    if tile < 16:
        raise RiverbedError(f"--tile must be at least 16 px, got {tile}")
    ys = list(range(0, height, tile))
    xs = list(range(0, width, tile))
    return [Tile(y, min(y + tile, height), x, min(x + tile, width)) for y in ys for x in xs]


def lidar_ranges(tiles, sparse, d_min, d_max, reach=None, margin=4.0, thin_margin=16.0):
    """Give each tile the disparity range its LiDAR allows.

    A tile's range is the min/max of the sparse disparities in the tile grown by ``reach`` pixels (default: a
    quarter of the tile), widened by a margin that grows where LiDAR is thin: ``margin + thin_margin / sqrt(n)``
    px for ``n`` points (1 point: +20 px; 100 points: +5.6 px). Tiles without LiDAR take the union of their
    neighbours' ranges (8-neighbourhood, repeated until every tile has one), or the global ``[d_min, d_max]``.
    Every range is clipped to the global one.
    """
    H, W = sparse.shape
    valid = np.isfinite(sparse)
    for t in tiles:
        r = reach if reach is not None else max(t.y1 - t.y0, t.x1 - t.x0) // 4
        win = sparse[max(0, t.y0 - r):min(H, t.y1 + r), max(0, t.x0 - r):min(W, t.x1 + r)]
        vals = win[valid[max(0, t.y0 - r):min(H, t.y1 + r), max(0, t.x0 - r):min(W, t.x1 + r)]]
        vals = vals[(vals >= d_min) & (vals <= d_max)]
        if vals.size:
            m = margin + thin_margin / math.sqrt(vals.size)
            t.d_min = max(d_min, int(math.floor(vals.min() - m)))
            t.d_max = min(d_max, int(math.ceil(vals.max() + m)))
            t.source = "lidar"
        else:
            t.source = None
    # Tiles without LiDAR inherit from neighbours (breadth-first), else the global range.
    index = {(t.y0, t.x0): t for t in tiles}
    size_y = tiles[0].y1 - tiles[0].y0
    size_x = tiles[0].x1 - tiles[0].x0
    for _ in range(len(tiles)):
        pending = [t for t in tiles if t.source is None]
        if not pending:
            break
        found = []
        for t in pending:
            nb = [index.get((t.y0 + dy * size_y, t.x0 + dx * size_x)) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
            nb = [n for n in nb if n is not None and n.source in ("lidar", "neighbours")]
            if nb:
                found.append((t, min(n.d_min for n in nb), max(n.d_max for n in nb)))
        if not found:
            break
        for t, lo, hi in found:
            t.d_min, t.d_max, t.source = lo, hi, "neighbours"
    for t in tiles:
        if t.source is None:
            t.d_min, t.d_max, t.source = d_min, d_max, "global"
    return tiles


def match_tiled(left, right, sparse=None, d_min=None, d_max=None, params=None, tile=1024, overlap=128,
                lidar_range=True, progress=None, **overrides):
    """:func:`match_pair` tile by tile; same arguments plus ``tile`` (px), ``overlap`` (px) and ``lidar_range``.

    Returns a :class:`MatchResult` whose ``info`` adds ``tiles`` (count), ``tile``, ``overlap``,
    ``disparity_evaluations`` (sum over tiles of pixels x disparities, the work done) and per-stage sums.
    """
    import time

    from ..matching.pipeline import disparity_range_from_sparse

    p = MatchParams(**{**(params.__dict__ if params else {}), **overrides})
    H, W = left.shape[:2]
    if right.shape[:2] != (H, W):
        raise RiverbedError(f"left and right images differ in size: {W}x{H} vs {right.shape[1]}x{right.shape[0]}")
    if d_min is None or d_max is None:
        if sparse is None:
            raise RiverbedError("give the disparity range (--min-disp/--max-disp) or a sparse map to derive it from")
        lo, hi = disparity_range_from_sparse(sparse)
        d_min = lo if d_min is None else d_min
        d_max = hi if d_max is None else d_max
    d_min, d_max = int(d_min), int(d_max)
    if overlap < 0:
        raise RiverbedError(f"--overlap must be >= 0, got {overlap}")
    t_all = time.perf_counter()
    from ..matching.guidance import auto_window, lidar_share

    share = lidar_share(sparse) if sparse is not None else 0.0
    if p.guide != "none" and p.window == "auto":
        # One window for the whole image: a tile's own LiDAR share would change it from tile to tile.
        p = MatchParams(**{**p.__dict__, "window": auto_window(share, p.window_target)})
    tiles = tile_grid(H, W, tile)
    if sparse is not None and lidar_range:
        lidar_ranges(tiles, sparse, d_min, d_max, reach=overlap)
    else:
        for t in tiles:
            t.d_min, t.d_max = d_min, d_max
    out = np.full((H, W), np.nan, np.float32)
    stages = {}
    evaluations = 0
    for t in tiles:
        ya, yb = max(0, t.y0 - overlap), min(H, t.y1 + overlap)
        a = max(0, t.x0 - overlap - (t.d_max - t.d_min))
        b = min(W, t.x1 + overlap)
        off = min(t.d_min, a) if t.d_min >= 0 else max(t.d_min, b - W)
        lc = left[ya:yb, a:b]
        rc = right[ya:yb, a - off:b - off]
        sc = None
        if sparse is not None:
            sc = sparse[ya:yb, a:b] - np.float32(off)
            # LiDAR outside the tile's range cannot guide it (match_pair would warn about every tile)
            sc = np.where((sc >= t.d_min - off) & (sc <= t.d_max - off), sc, np.float32(np.nan))
            if p.guide != "none" and not np.isfinite(sc).any():
                sc = None
        kw = {} if sc is not None or p.guide == "none" else {"guide": "none"}
        res = match_pair(lc, rc, sc, t.d_min - off, t.d_max - off, p, **kw)
        out[t.y0:t.y1, t.x0:t.x1] = res.disparity[t.y0 - ya:t.y1 - ya, t.x0 - a:t.x1 - a] + np.float32(off)
        evaluations += lc.shape[0] * lc.shape[1] * (t.d_max - t.d_min + 1)
        for k, v in res.info["stages"].items():
            stages[k] = round(stages.get(k, 0.0) + v, 4)
        if progress:
            progress(1)
    info = {"seconds": round(time.perf_counter() - t_all, 4), "stages": stages, "guide": p.guide,
            "lidar_share": share, "window": p.window if p.guide != "none" else None, "d_min": d_min, "d_max": d_max,
            "size": [W, H], "tiles": len(tiles), "tile": tile, "overlap": overlap,
            "disparity_evaluations": int(evaluations),
            "tile_ranges": {s: sum(1 for t in tiles if t.source == s) for s in ("lidar", "neighbours", "global")}}
    return MatchResult(out, info)
