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
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import RiverbedError
from ..matching.pipeline import MatchParams, MatchResult, match_pair

log = logging.getLogger(__name__)


class WindowedRaster:
    """A raster file read window by window (rasterio), sliced like a numpy array: ``src[y0:y1, x0:x1]``.

    ``kind="image"``: bands become channels (H x W or H x W x 3, samples unchanged); ``kind="disparity"``: band 1
    as float32 with nodata, inf and NaN as NaN. Only what a tile needs is ever in memory.
    """

    def __init__(self, path, kind="image"):
        import rasterio

        self.path, self.kind = str(path), kind
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                self._ds = rasterio.open(self.path)
        except rasterio.errors.RasterioError as e:
            raise RiverbedError(f"cannot read raster ({str(e).splitlines()[0]})", path) from None
        H, W = self._ds.height, self._ds.width
        self.bands = 1 if kind == "disparity" else min(self._ds.count, 3)
        self.shape = (H, W) if self.bands == 1 else (H, W, self.bands)
        self.dtype = np.dtype(np.float32 if kind == "disparity" else self._ds.dtypes[0])
        self.ndim = len(self.shape)

    def __getitem__(self, key):
        from rasterio.windows import Window

        rows, cols = key[:2]
        H, W = self.shape[:2]
        y0, y1, _ = rows.indices(H)
        x0, x1, _ = cols.indices(W)
        win = Window(x0, y0, max(0, x1 - x0), max(0, y1 - y0))
        if self.kind == "disparity":
            a = self._ds.read(1, window=win, masked=True).astype(np.float32).filled(np.nan)
            a[~np.isfinite(a)] = np.nan
            return a
        a = self._ds.read(list(range(1, self.bands + 1)), window=win)
        return a[0] if self.bands == 1 else np.moveaxis(a, 0, -1)

    def row_blocks(self, rows=512):
        for y in range(0, self.shape[0], rows):
            yield y, self[y:y + rows, 0:self.shape[1]]

    def __getstate__(self):  # dask ships sources to workers: reopen there
        return {"path": self.path, "kind": self.kind}

    def __setstate__(self, state):
        self.__init__(state["path"], state["kind"])


def open_windowed(path, kind="image"):
    """A :class:`WindowedRaster` for TIFF files (read by windows); other formats are read whole into numpy."""
    from ..io.disparity import read_disparity
    from ..io.images import read_image

    with open(path, "rb") as f:
        head = f.read(4)
    if head in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        return WindowedRaster(path, kind)
    return read_disparity(path) if kind == "disparity" else read_image(path)


def _blocks(a, rows=512):
    if isinstance(a, WindowedRaster):
        yield from a.row_blocks(rows)
    else:
        for y in range(0, a.shape[0], rows):
            yield y, a[y:y + rows]


def sparse_points_any(sparse):
    """Rows, columns and values of the LiDAR pixels of an in-memory or windowed sparse map, block by block."""
    rows, cols, vals = [], [], []
    for y, blk in _blocks(sparse):
        r, c = np.nonzero(np.isfinite(blk))
        rows.append(r + y)
        cols.append(c)
        vals.append(blk[r, c])
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals).astype(np.float32)


def image_bits(*images):
    """Effective bit depth over whole images (in memory or windowed), so every tile scales 16-bit data alike."""
    from ..io.images import effective_bits

    if all(np.dtype(getattr(a, "dtype", np.uint8)) == np.uint8 for a in images):
        return 8
    top = 0
    for a in images:
        for _, blk in _blocks(a):
            top = max(top, int(blk.max()) if blk.size else 0)
    return effective_bits(np.array([top], np.uint16))


class TiffSink:
    """A float32 GeoTIFF written tile by tile (``sink[y0:y1, x0:x1] = block``); NaN nodata, DEFLATE, 256 x 256 tiles.

    Use as a context manager on a temporary path and rename it when the work succeeded (the CLI does).
    """

    def __init__(self, path, height, width, tags=None):
        import rasterio

        self.path = str(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            self._ds = rasterio.open(self.path, "w", driver="GTiff", width=width, height=height, count=1,
                                     dtype="float32", nodata=float("nan"), compress="deflate", predictor=3,
                                     tiled=True, blockxsize=256, blockysize=256, BIGTIFF="IF_SAFER")
        if tags:
            self.update_tags(**tags)
        self.shape = (height, width)

    def __setitem__(self, key, block):
        from rasterio.windows import Window

        rows, cols = key
        y0, y1, _ = rows.indices(self.shape[0])
        x0, x1, _ = cols.indices(self.shape[1])
        self._ds.write(np.asarray(block, np.float32), 1, window=Window(x0, y0, x1 - x0, y1 - y0))

    def update_tags(self, **tags):
        self._ds.update_tags(**{str(k): str(v) for k, v in tags.items()})

    def close(self):
        self._ds.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


#: Memory a tile may use for its cost volumes (three uint16 volumes: cost, forward and reverse SGM sums).
TILE_BUDGET = 1536 * 2**20


def auto_tile(d_range, overlap=128, budget=TILE_BUDGET, smallest=128, largest=4096):
    """The largest tile side (a multiple of 64) whose crop's volumes fit ``budget`` bytes for ``d_range`` disparities.

    A crop is ``(T + 2 overlap)`` rows by ``(T + 2 overlap + d_range)`` columns; its volumes take 6 bytes per cell.
    """
    D = int(d_range) + 1
    best = smallest
    for T in range(smallest, largest + 1, 64):
        if 6 * (T + 2 * overlap) * (T + 2 * overlap + D) * D <= budget:
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


def plan_tiles(height, width, sparse, d_min, d_max, tile="auto", overlap=128, lidar_range=True):
    """The tiles of a tiled match and the tile size: ``tile="auto"`` sizes tiles for :data:`TILE_BUDGET` from the
    widest range a 1024 px tile would search; each tile gets its LiDAR range (or the global one)."""

    def plan(size):
        ts = tile_grid(height, width, size)
        if sparse is not None and lidar_range:
            lidar_ranges(ts, sparse, d_min, d_max, reach=overlap)
        else:
            for t in ts:
                t.d_min, t.d_max = d_min, d_max
        return ts

    if tile == "auto":
        tile = auto_tile(max(t.d_max - t.d_min for t in plan(1024)), overlap)
        if max(height, width) <= tile:
            tile = max(height, width)
    return plan(int(tile)), int(tile)


def match_tile(left, right, sparse, t, overlap, params, bits=8):
    """Match one :class:`Tile` (sources sliced like numpy arrays: arrays, memory maps, :class:`WindowedRaster`).

    Returns ``(block, evaluations, stages)``: the tile's own disparities (float32, ``t.y1 - t.y0`` x ``t.x1 -
    t.x0``), the disparity evaluations done on its crop, and the stage timings. ``params.window`` should be fixed
    (not "auto") so every tile uses the same riverbed window; ``bits`` is the whole pair's effective bit depth.
    """
    from ..io.images import to_guide

    H, W = left.shape[:2]
    ya, yb = max(0, t.y0 - overlap), min(H, t.y1 + overlap)
    a = max(0, t.x0 - overlap - (t.d_max - t.d_min))
    b = min(W, t.x1 + overlap)
    off = min(t.d_min, a) if t.d_min >= 0 else max(t.d_min, b - W)
    lc = np.asarray(left[ya:yb, a:b])
    rc = np.asarray(right[ya:yb, a - off:b - off])
    if bits > 8:
        # one 0..255 scale for every tile of a 16-bit pair (a tile's own maximum would change it)
        lc, rc = (np.squeeze(to_guide(c, bits), axis=-1) if c.ndim == 2 else to_guide(c, bits) for c in (lc, rc))
    sc = None
    if sparse is not None:
        sc = np.asarray(sparse[ya:yb, a:b], np.float32) - np.float32(off)
        # LiDAR outside the tile's range cannot guide it (match_pair would warn about every tile)
        sc = np.where((sc >= t.d_min - off) & (sc <= t.d_max - off), sc, np.float32(np.nan))
        if params.guide != "none" and not np.isfinite(sc).any():
            sc = None
    kw = {} if sc is not None or params.guide == "none" else {"guide": "none"}
    res = match_pair(lc, rc, sc, t.d_min - off, t.d_max - off, params, **kw)
    block = res.disparity[t.y0 - ya:t.y1 - ya, t.x0 - a:t.x1 - a] + np.float32(off)
    return np.ascontiguousarray(block), lc.shape[0] * lc.shape[1] * (t.d_max - t.d_min + 1), res.info["stages"]


def match_tiled(left, right, sparse=None, d_min=None, d_max=None, params=None, tile="auto", overlap=128,
                lidar_range=True, progress=None, out=None, **overrides):
    """:func:`match_pair` tile by tile; same arguments plus ``tile`` (px), ``overlap`` (px) and ``lidar_range``.

    ``left``, ``right`` and ``sparse`` may be numpy arrays or :class:`WindowedRaster` (read tile by tile); ``out``
    receives each tile by ``out[y0:y1, x0:x1] = block`` (default: a new float32 array, returned in the result).
    ``tile="auto"`` picks the largest tile whose volumes fit :data:`TILE_BUDGET` for the widest disparity range a
    tile will search (its LiDAR range, or the global one).

    Returns a :class:`MatchResult` whose ``info`` adds ``tiles`` (count), ``tile``, ``overlap``,
    ``disparity_evaluations`` (sum over tiles of pixels x disparities, the work done) and per-stage sums.
    """
    import time

    from ..matching.guidance import auto_window, lidar_share_of_points
    from ..matching.pipeline import resolve_disparity_range

    p = MatchParams(**{**(params.__dict__ if params else {}), **overrides})
    H, W = left.shape[:2]
    if right.shape[:2] != (H, W):
        raise RiverbedError(f"left and right images differ in size: {W}x{H} vs {right.shape[1]}x{right.shape[0]}")
    if sparse is not None and sparse.shape[:2] != (H, W):
        raise RiverbedError(f"sparse map is {sparse.shape[1]}x{sparse.shape[0]} but the images are {W}x{H} (WxH)")
    t_all = time.perf_counter()
    share = 0.0
    if sparse is not None:
        pr, pc, pv = sparse_points_any(sparse)
        if pv.size == 0:
            raise RiverbedError("sparse map has no valid disparities")
        share = lidar_share_of_points(pr, pc, (H, W))
    d_min, d_max = resolve_disparity_range(d_min, d_max, pv if sparse is not None else None)
    if overlap < 0:
        raise RiverbedError(f"--overlap must be >= 0, got {overlap}")
    bits = image_bits(left, right)
    if p.guide != "none" and p.window == "auto":
        # One window for the whole image: a tile's own LiDAR share would change it from tile to tile.
        p = MatchParams(**{**p.__dict__, "window": auto_window(share, p.window_target)})
    tiles, tile = plan_tiles(H, W, sparse, d_min, d_max, tile, overlap, lidar_range)
    if out is None:
        out = np.full((H, W), np.nan, np.float32)
    stages = {}
    evaluations = 0
    for t in tiles:
        block, n, st = match_tile(left, right, sparse, t, overlap, p, bits)
        out[t.y0:t.y1, t.x0:t.x1] = block
        evaluations += n
        for k, v in st.items():
            stages[k] = round(stages.get(k, 0.0) + v, 4)
        if progress:
            progress(1)
    info = {"seconds": round(time.perf_counter() - t_all, 4), "stages": stages, "guide": p.guide,
            "lidar_share": share, "window": p.window if p.guide != "none" else None, "d_min": d_min, "d_max": d_max,
            "size": [W, H], "tiles": len(tiles), "tile": tile, "overlap": overlap,
            "disparity_evaluations": int(evaluations),
            "tile_ranges": {s: sum(1 for t in tiles if t.source == s) for s in ("lidar", "neighbours", "global")}}
    return MatchResult(out, info)
