"""Planning a match: its range, the LiDAR's shares, the guide's window, the tubes' widths and the tiles, one rule for
``riverbed match`` (whole or tiled) and blocks.

Stage: ``(image size, the LiDAR as it will guide, range, settings) -> MatchPlan`` (:func:`plan_match`). The LiDAR
is taken after its offset and check (:func:`~riverbed_cli.scale.tiles.prepare_lidar_whole`), so the plan's shares
count the points that will guide. A :class:`MatchPlan` is plain values (:meth:`MatchPlan.to_dict`,
:meth:`MatchPlan.from_dict`): a block's project task hands it to its tile tasks.

The tiling (:func:`plan_tiles`): memory is bounded by the tile, not the image: a tile of ``T x T`` pixels with ``D``
disparities needs about ``6 T (T + D) D`` bytes (three uint16 volumes) plus the images; each tile takes the range its
LiDAR (or a range map) allows there.
"""

import math
import os
from dataclasses import asdict, dataclass

import numpy as np
import psutil

from ..errors import RiverbedError
from ..geometry.coverage import lidar_share_of_points
from ..matching.config import OVERLAP_DEFAULT, SETTINGS_BY_NAME, TILE_DEFAULT, tile_size
from ..matching.pipeline import resolve_range
from ..matching.range_maps import check_range_map_shape, check_range_summary
from ..matching.registry import get_guide, get_matcher
from ..matching.tubes import cell_widths_from_points, range_map_summary
from ..records import RecordMapping
from ..settings import SettingError, parse_text


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


@dataclass
class MatchPlan(RecordMapping):
    """How a pair is matched (:func:`plan_match`): its range ``d_min``, ``d_max`` (px, inclusive); ``share_all``, the
    LiDAR share of the image of every point that guides (the tubes' spacing, :func:`~riverbed_cli.matching.tubes
    .lidar_tubes`) and ``share_in_range``, of the points inside the range (they guide the costs; the guide's window);
    ``window``, the guide's window for every tile (``"auto"`` only for a guide without one); ``tile`` (px) and
    ``tiled`` (False: matched whole); ``tiles``, ``[y0, y1, x0, x1, d_min, d_max, source]`` per tile (one covering
    the image when not tiled); ``tile_ranges``, how many tiles took their range from their LiDAR, their neighbours,
    the global range or a range map; ``tube_width``, the tubes' mean width over the image (disparities; None when
    the match searches whole ranges)."""

    d_min: int
    d_max: int
    share_all: float
    share_in_range: float
    window: object
    tile: int
    tiled: bool
    tiles: list
    tile_ranges: dict
    tube_width: float = None

    @classmethod
    def from_dict(cls, values):
        return cls(**values)

    def tile_list(self):
        """The tiles as :class:`Tile`."""
        return [Tile(*t) for t in self.tiles]


def plan_match(shape, points, d_min, d_max, params, *, sparse=None, tile=TILE_DEFAULT, overlap=OVERLAP_DEFAULT,
               lidar_range=True, scan=None, budget=None):
    """The :class:`MatchPlan` of a ``shape`` (H, W) match over ``[d_min, d_max]`` with ``params`` (a
    :class:`~riverbed_cli.matching.config.MatchConfig`).

    ``points``: the LiDAR's ``(rows, cols, values)`` as it will guide (its offset removed, checked), or None;
    ``sparse``: its map (array or windowed raster; the tiles' LiDAR ranges), ``scan``: a range map's
    :class:`RangeMapScan` (its widths and ranges instead of the LiDAR's). ``tile``, ``overlap``, ``lidar_range`` and
    ``budget`` as :func:`plan_tiles`'s. The window is the guide's for the points inside the range (one for every tile: a
    tile's own share would change it from tile to tile), as :func:`~riverbed_cli.matching.pipeline.match_pair`
    chooses it for a whole image.
    """
    H, W = shape
    share_all = share_in_range = 0.0
    if points is not None:
        pr, pc, pv = points
        share_all = lidar_share_of_points(pr, pc, (H, W))
        inside = (pv >= d_min) & (pv <= d_max)
        share_in_range = share_all if inside.all() else lidar_share_of_points(pr[inside], pc[inside], (H, W))
    guide = get_guide(params.guide)
    window = params.guidance.window
    if guide.uses_window and window == "auto":
        window = guide.window(share_in_range, params)
    if scan is not None:
        widths = (scan.widths(d_min, d_max), scan.cell)
    else:
        widths = tube_widths(params, points, (H, W), d_min, d_max, share_all) if points is not None else None
    tiles = plan_tiles(H, W, sparse, d_min, d_max, tile, overlap, lidar_range, budget=budget, widths=widths,
                       range_map=scan)
    return MatchPlan(int(d_min), int(d_max), share_all, share_in_range, window, int(tiles.size), tiles.tiled,
                     [[t.y0, t.y1, t.x0, t.x1, t.d_min, t.d_max, t.source] for t in tiles.tiles],
                     tiles.to_dict()["tile_ranges"], float(np.mean(widths[0])) if widths is not None else None)
