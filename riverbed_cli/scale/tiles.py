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
import os
import time
from dataclasses import asdict, dataclass

import numpy as np
import psutil

from ..errors import RiverbedError
from ..io.images import to_guide
from ..io.windowed import bounded_raster_cache, image_bits, sparse_points_any
from ..matching.config import OVERLAP_DEFAULT, SETTINGS_BY_NAME, TILE_DEFAULT, tile_size
from ..matching.guidance import lidar_share, lidar_share_of_points
from ..matching.lidar_input import check_disparity_values, check_inside, resolve_disparity_range
from ..matching.pipeline import check_lidar_count, lidar_points_needed, make_config, match_pair, resolve_range
from ..matching.range_maps import check_range_map_shape, check_range_summary, fill_tube_holes, range_map_ends
from ..matching.lidar_check import check_pair
from ..matching.lidar_offset import correct_large
from ..matching.registry import get_guide, get_matcher
from ..matching.tubes import cell_widths_from_points, lidar_tubes_window, range_map_summary
from ..matching.results import MatchResult, TiledMatchInfo
from ..settings import SettingError, parse_text

log = logging.getLogger(__name__)


#: Memory a tile may use for its cost volumes (three uint16 volumes: cost, forward and reverse SGM sums).
TILE_BUDGET = 1536 * 2**20


#: Bytes per crop pixel besides the cost volumes that a tube match holds (census, grey and guide images, tube ends
#: and layout, ownership): small against a full-range volume, the larger part of a tube match's memory.
TUBE_PIXEL_BYTES = 160


def auto_tile(d_range, overlap=128, budget=TILE_BUDGET, smallest=128, largest=4096, depth=None):
    """The largest tile side (a multiple of 64) whose crop fits ``budget`` bytes for ``d_range`` disparities.

    A crop is ``(T + 2 overlap)`` rows by ``(T + 2 overlap + d_range)`` columns; its volumes take 6 bytes per cell,
    ``d_range + 1`` cells per pixel; with tubes (``depth``: their mean width) ``6 depth +``
    :data:`TUBE_PIXEL_BYTES` bytes per pixel.
    """
    D = int(d_range) + 1
    per_pixel = 6.0 * D if depth is None else 6.0 * max(1.0, float(depth)) + TUBE_PIXEL_BYTES
    best = smallest
    for T in range(smallest, largest + 1, 64):
        if (T + 2 * overlap) * (T + 2 * overlap + D) * per_pixel <= budget:
            best = T
    return best


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


@dataclass
class Tile:
    y0: int
    y1: int
    x0: int
    x1: int
    d_min: int = 0
    d_max: int = 0
    source: str = "global"  # where the range came from: lidar, neighbours or global


def check_tiling(tile, overlap):
    """``--tile`` (``"auto"``, 0: never tile, else a side >= 16 px; command-line text or a value) and ``--overlap``
    checked by the settings table's validators, the ones block manifests use (one rule, one message); returns the
    tile, or raises RiverbedError."""
    out = {}
    for name, value in (("tile", tile), ("overlap", overlap)):
        setting = SETTINGS_BY_NAME[name]
        try:
            out[name] = setting.validate(parse_text(setting, value))
        except SettingError as e:
            raise RiverbedError(f"{setting.option}: {e}") from None
    return out["tile"]


def tile_grid(height, width, tile):
    """Tiles of at most ``tile x tile`` pixels covering the image, row by row; ``tile`` a side in px, checked by
    the ``tile`` setting's validator (:func:`~riverbed_cli.matching.config.tile_size`: at least 16)."""
    try:
        tile = tile_size(int(tile) if isinstance(tile, np.integer) else tile)
    except SettingError as e:
        raise RiverbedError(f"--tile: {e}") from None
    if tile in ("auto", 0):  # plan_tiles' to resolve, not a side
        raise RiverbedError(f"--tile: a tile grid needs a side in px, not {tile!r}")
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
    H, W = sparse.shape[:2]
    for t in tiles:
        r = reach if reach is not None else max(t.y1 - t.y0, t.x1 - t.x0) // 4
        win = np.asarray(sparse[max(0, t.y0 - r):min(H, t.y1 + r), max(0, t.x0 - r):min(W, t.x1 + r)])
        vals = win[np.isfinite(win)]
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


_NO_END = np.iinfo(np.int32).max  # a cell's smallest end where it has no range (its largest: -_NO_END)


@dataclass
class RangeMapScan:
    """A range map read once (:func:`scan_range_map`), for checking it and planning tiles before the disparity range
    is known: its pixels with a range (``known``), those with min > max (``crossed``), their smallest and largest
    end (``low``, ``high``), and per ``cell`` x ``cell`` block the sum of its known pixels' widths (``wsum``), their
    count (``nknown``), its pixels' count (``npix``) and the smallest and largest end of its known pixels (``lo``,
    ``hi``, int32). The nominal range fills the rest once it is known (:meth:`widths`, :meth:`ends`)."""

    known: int
    crossed: int
    low: float
    high: float
    wsum: np.ndarray
    nknown: np.ndarray
    npix: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    cell: int
    shape: tuple

    def span(self):
        """``(floor(low), ceil(high))``, the disparity range the map spans, or None for a map with no range."""
        return (int(math.floor(self.low)), int(math.ceil(self.high))) if self.known else None

    def check(self, d_min, d_max):
        """:class:`RiverbedError` (the messages of :func:`~riverbed_cli.matching.range_maps.check_range_map`) for
        a map with no range, min > max, or a range outside ``[d_min, d_max]``."""
        check_range_summary(self.known, self.crossed, self.low, self.high, d_min, d_max)

    def widths(self, d_min, d_max):
        """Each cell's mean range width, the nominal range's where the map has none (for :func:`plan_tiles`)."""
        return ((self.wsum + (self.npix - self.nknown) * (d_max - d_min + 1.0)) / self.npix).astype(np.float32)

    def ends(self, d_min, d_max):
        """Each cell's smallest and largest range end, the nominal range's where a pixel of it has no range."""
        full = self.nknown < self.npix
        return np.where(full, d_min, self.lo), np.where(full, d_max, self.hi)


def scan_range_map(range_map, shape, cell=4, rows=512):
    """Read a range map for a match of ``shape`` once, ``rows`` rows at a time (arrays, memory maps or windowed
    rasters), and sum it up (:class:`RangeMapScan`): the disparity range can be taken from it, checked against it
    and the tiles planned without another read."""
    lo, hi = range_map
    check_range_map_shape(lo, hi, shape)
    H, W = shape
    rows = max(cell, rows // cell * cell)
    ch, cw = -(-H // cell), -(-W // cell)
    wsum, nknown, npix = (np.empty((ch, cw), np.float64) for _ in range(3))
    clo, chi = np.empty((ch, cw), np.int32), np.empty((ch, cw), np.int32)
    summary = [0, 0, math.inf, -math.inf]
    for y0 in range(0, H, rows):
        blo, bhi = np.asarray(lo[y0:y0 + rows, :]), np.asarray(hi[y0:y0 + rows, :])
        k, c, a, b = range_map_summary(blo, bhi)
        summary = [summary[0] + k, summary[1] + c, min(summary[2], a), max(summary[3], b)]
        ok = np.isfinite(blo) & np.isfinite(bhi)
        a = np.floor(np.where(ok, blo, 0)).astype(np.int32)
        b = np.ceil(np.where(ok, bhi, 0)).astype(np.int32)
        a[~ok], b[~ok] = _NO_END, -_NO_END
        r = slice(y0 // cell, y0 // cell - (-a.shape[0] // cell))
        wsum[r] = _per_cell(np.where(ok, b.astype(np.float64) - a + 1, 0.0), cell, np.sum)
        nknown[r] = _per_cell(ok.astype(np.float64), cell, np.sum)
        npix[r] = _per_cell(np.ones(a.shape), cell, np.sum)
        clo[r] = _per_cell(a, cell, np.min, _NO_END)
        chi[r] = _per_cell(b, cell, np.max, -_NO_END)
    return RangeMapScan(*summary, wsum, nknown, npix, clo, chi, cell, (H, W))


def _per_cell(x, cell, reduce, fill=0):
    # reduce (np.sum, np.min, np.max) each cell x cell block of x, padded with fill at the bottom and right
    h, w = x.shape
    x = np.pad(x, ((0, -(-h // cell) * cell - h), (0, -(-w // cell) * cell - w)), constant_values=fill)
    return reduce(x.reshape(x.shape[0] // cell, cell, x.shape[1] // cell, cell), axis=(1, 3))


def range_map_ranges(tiles, scan, reach, d_min, d_max):
    """Give each tile the range a range map spans over the tile grown by ``reach`` px, from its
    :class:`RangeMapScan` (whole cells: up to ``cell - 1`` px more; the nominal ``[d_min, d_max]`` where it has
    none)."""
    H, W = scan.shape
    c = scan.cell
    lo, hi = scan.ends(d_min, d_max)
    for t in tiles:
        ya, yb, xa, xb = max(0, t.y0 - reach), min(H, t.y1 + reach), max(0, t.x0 - reach), min(W, t.x1 + reach)
        cells = (slice(ya // c, -(-yb // c)), slice(xa // c, -(-xb // c)))
        t.d_min, t.d_max, t.source = int(lo[cells].min()), int(hi[cells].max()), "range_map"
    return tiles


@dataclass
class TilePlan:
    """The tiles of a tiled match: ``tiles`` (each with its disparity range), ``size`` (tile side, px) and
    ``tiled`` (False: the image fits one tile and is matched whole)."""

    tiles: list
    size: int
    tiled: bool

    def to_dict(self):
        return {"tiles": len(self.tiles), "tile": self.size, "tiled": self.tiled,
                "tile_ranges": {s: sum(1 for t in self.tiles if t.source == s) for s in ("lidar", "neighbours",
                                                                                          "global", "range_map")}}


def tile_budget():
    """Bytes a tile's volumes may take: :data:`TILE_BUDGET`, or a quarter of the free memory when that is less;
    ``RIVERBED_TILE_BUDGET_MIB`` in the environment sets it (a small machine, or a test of the tiling)."""
    env = os.environ.get("RIVERBED_TILE_BUDGET_MIB")
    if env:
        try:
            return int(float(env) * 2**20)
        except ValueError:
            raise RiverbedError(f"RIVERBED_TILE_BUDGET_MIB must be a number of MiB, not '{env}'") from None
    return int(min(TILE_BUDGET, psutil.virtual_memory().available // 4))


def tube_widths(config, points, shape, d_min, d_max, share):
    """``(cell widths, cell)`` of the tubes a match with ``config`` will search (for :func:`plan_tiles`), or None when
    it searches whole ranges or its matcher's tiles are sized for the nominal volume (``tube_sized_tiles``).
    ``points``: the LiDAR's ``(rows, cols, values)``."""
    guide, matcher = get_guide(config.guide), get_matcher(config.matcher)
    if points is None or not matcher.tube_sized_tiles or resolve_range(config, guide, matcher, True, False) != "tube":
        return None
    tube = asdict(config.tube)
    return cell_widths_from_points(*points, shape, d_min, d_max, share, tube), max(1, int(tube["cell"]))


def plan_tiles(height, width, sparse, d_min, d_max, tile=TILE_DEFAULT, overlap=OVERLAP_DEFAULT, lidar_range=True,
               budget=None, widths=None, range_map=None):
    """The tiling of a ``height x width`` match over ``[d_min, d_max]``: one rule for ``riverbed match`` and blocks.

    ``tile="auto"``: the image is matched whole when its volumes fit ``budget`` (:func:`tile_budget` by default)
    for the whole range; otherwise tiles take the largest side that fits ``budget`` for the widest range a 1024 px
    tile would search (its LiDAR range with ``lidar_range``, else the global one). ``tile=0``: never tile. An
    integer: tiles of that side when the image is larger. Each tile gets its LiDAR range (:func:`lidar_ranges`) or
    the global one. With tubes, ``widths`` (:func:`tube_widths`) makes the volume count their mean width instead of
    the range's disparities (the image's for the whole, the widest 1024 px tile's for tiles). With a ``range_map``
    (a :class:`RangeMapScan`, :func:`range_map_ranges`) each tile takes the range the map spans there instead of its
    LiDAR's.
    Returns a :class:`TilePlan`; an untiled plan holds the one tile covering the image.
    """
    def plan(size):
        ts = tile_grid(height, width, max(size, 16))
        if range_map is not None:
            range_map_ranges(ts, range_map, overlap, d_min, d_max)
        elif sparse is not None and lidar_range:
            lidar_ranges(ts, sparse, d_min, d_max, reach=overlap)
        else:
            for t in ts:
                t.d_min, t.d_max = d_min, d_max
        return ts

    whole = max(height, width)
    if tile == 0:
        return TilePlan(plan(whole), whole, False)
    if tile == "auto":
        budget = tile_budget() if budget is None else budget
        cells, cell = widths if widths is not None else (None, 1)
        depth = float(cells.mean()) if cells is not None else None
        if whole <= auto_tile(d_max - d_min, overlap, budget, depth=depth):
            return TilePlan(plan(whole), whole, False)
        probe = plan(1024)
        if cells is not None:
            depth = max(float(cells[t.y0 // cell:-(-t.y1 // cell), t.x0 // cell:-(-t.x1 // cell)].mean())
                        for t in probe)
        tile = auto_tile(max(t.d_max - t.d_min for t in probe), overlap, budget, depth=depth)
    tile = int(tile)
    if whole <= tile:
        return TilePlan(plan(whole), whole, False)
    return TilePlan(plan(tile), tile, True)


def check_whole(left, right, sparse, d_min, d_max, params):
    """The LiDAR check (:mod:`~riverbed_cli.matching.lidar_check`) once for a whole pair matched in tiles (a tile's
    own check could drop other points than its neighbour's), its reference matched in tiles too: ``(sparse,
    check)``, the checked sparse map (an array) and the :class:`~riverbed_cli.matching.lidar_check.LidarCheck`
    (its ``report``, the changed area ``changed``, the ``dropped`` points). ``left``, ``right`` and ``sparse`` may
    be windowed rasters (read whole here)."""
    arrays = [np.asarray(a[:, :]) for a in (left, right)]
    return check_pair(*arrays, np.asarray(sparse[:, :], np.float32), d_min, d_max, params, match_tiled)


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
                confidence_out=None, range_scan=None, valid_areas=None, points=None, **overrides):
    """:func:`match_pair` tile by tile; same arguments plus ``tile`` (px, ``"auto"`` or 0), ``overlap`` (px) and
    ``lidar_range``; ``range_map`` (per-pixel ``(lo, hi)``, NaN: the nominal range) as :func:`match_pair`'s: each
    tile searches the range the map spans there and its pixels their own intervals (``range_scan``: its
    :func:`scan_range_map`, when the caller has read it already; ``points`` likewise ``sparse``'s points, ``(rows,
    cols, values)``). ``confidence_out`` receives the
    fusion's confidence tile by tile as ``out`` the disparities (NaN in tiles that were not fused).

    ``valid_areas`` (the images' valid areas, :func:`match_tile`'s) as :func:`match_pair`'s.

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
        share_all = 0.0  # every point's share, as given: it sets the tubes' spacing
        if sparse is not None:
            pr, pc, pv = sparse_points_any(sparse) if points is None else points
            if pv.size == 0:
                raise RiverbedError("sparse map has no valid disparities")
            share_all = lidar_share_of_points(pr, pc, (H, W))
        rmap, scan = None, range_scan
        if range_map is not None:  # read once to check and plan, kept as it is (tiles read their windows)
            rmap = tuple(range_map)
            scan = scan if scan is not None else scan_range_map(rmap, (H, W))
            span = scan.span()
            if span is not None:
                d_min = span[0] if d_min is None else d_min
                d_max = span[1] if d_max is None else d_max
        offset = None
        if sparse is not None:
            check_disparity_values(pv, W)
            check_lidar_count(pv.size, p)
            # one offset for every tile (a tile's own estimate could differ from its neighbour's): estimated over
            # the central window here, then given to the tiles as a forced one
            t0 = time.perf_counter()
            # the plan, the tiles and their tubes see the corrected LiDAR, and the tiles leave it as it is
            given = sparse
            sparse, offset = correct_large(left, right, sparse, (pr, pc, pv), p.lidar_offset, image_bits(left, right))
            p = p.replace(lidar_offset="none")
            if sparse is not given:
                pr, pc, pv = sparse_points_any(sparse)
            offset_seconds = round(time.perf_counter() - t0, 4)
        d_min, d_max = resolve_disparity_range(d_min, d_max, pv if sparse is not None else None, width=W)
        check, changed, lidar_check = None, None, None
        if sparse is not None and p.lidar_check == "auto":  # once for every tile, as the offset
            t0 = time.perf_counter()
            sparse, lidar_check = check_whole(left, right, sparse, d_min, d_max, p)
            check, changed = lidar_check.report, lidar_check.changed
            p = p.replace(lidar_check="off")
            pr, pc, pv = sparse_points_any(sparse)
            check_seconds = round(time.perf_counter() - t0, 4)
        if scan is not None:
            scan.check(d_min, d_max)
        # the LiDAR inside the range guides the cost, as match_pair's; all of it bounds the tubes (share_all)
        share_in_range = share_all
        if sparse is not None:
            inside = (pv >= d_min) & (pv <= d_max)
            check_inside(int(inside.sum()), pv.size, d_min, d_max, lambda: pv)
            if not inside.all():
                share_in_range = lidar_share_of_points(pr[inside], pc[inside], (H, W))
        bits = image_bits(left, right)
        if guide.uses_window and p.guidance.window == "auto":
            # One window for the whole image: a tile's own LiDAR share would change it from tile to tile.
            p = p.replace(window=guide.window(share_in_range, p))
        if scan is not None:
            widths = (scan.widths(d_min, d_max), scan.cell)
        else:
            widths = tube_widths(p, (pr, pc, pv), (H, W), d_min, d_max, share_all) if sparse is not None else None
        plan = plan_tiles(H, W, sparse, d_min, d_max, tile, overlap, lidar_range, widths=widths, range_map=scan)
        if out is None:
            out = np.full((H, W), np.nan, np.float32)
        stages = {}
        evaluations = 0
        tube_parts = []
        for t in plan.tiles:
            block, n, st, tube, *conf = match_tile(left, right, sparse, t, overlap, p, bits, share_all, (d_min, d_max),
                                                   rmap, confidence_out is not None, valid_areas, changed)
            tube_parts.append(tube)
            out[t.y0:t.y1, t.x0:t.x1] = block
            if conf:
                confidence_out[t.y0:t.y1, t.x0:t.x1] = conf[0]
            evaluations += n
            for k, v in st.items():
                stages[k] = round(stages.get(k, 0.0) + v, 4)
            if progress:
                progress(1)
    tubes = tiled_tube_stats(tube_parts, d_min, d_max)
    mode = "tube" if tubes is not None else ("tile" if sparse is not None and lidar_range else "full")
    if offset is not None:
        stages["lidar_offset"] = offset_seconds  # the tiles' own (forced) ones are free
    if check is not None:
        stages["lidar_check"] = check_seconds
    info = TiledMatchInfo(round(time.perf_counter() - t_all, 4), stages, p.guide, share_in_range,
                          p.guidance.window if guide.uses_window else None, d_min, d_max, [W, H], len(plan.tiles),
                          plan.size, overlap, int(evaluations), plan.to_dict()["tile_ranges"], mode, tubes,
                          offset.to_dict() if offset is not None else None,
                          check.to_dict() if check is not None else None)
    return MatchResult(out, info, lidar_check=lidar_check)
