"""Holes in a DSM: the sampling lattice of image points closed by default, and enclosed gaps filled on request.

**The lattice.** An image DSM at its default cell (the left image's ground sample distance at the median depth) gets
about one point per cell, unevenly: perspective, relief and the rectification stretch the pixel grid against the map
grid, so about a tenth of the cells get none, in a regular pattern plainly visible in a hillshade.
:func:`close_lattice` gives an empty cell with at least :data:`LATTICE_NEIGHBOURS` of its 8 neighbours holding
heights their median: those holes are the sampling's, not the surface's (a wider gap has fewer neighbours with data).
Measured by ``benchmarks/bench_overlap.py`` (its ``holes`` columns, docs/rectify.md): about a tenth of the footprint
open, a few % closed, the NMAD against the references within a few %. A larger cell closes them too but biases the ``max`` aggregation upwards; the neighbours'
maximum instead of their median costs a few % of RMSE (docs/dsm.md).

**Gaps.** ``--fill-holes N`` fills enclosed gaps up to N cells across by GDAL's inverse-distance interpolation,
flagged in a second band (:func:`fill_holes`).
"""

import cv2
import numpy as np
from numba import prange
from rasterio.fill import fillnodata

from ..errors import RiverbedError
from ..runtime.kernel import kernel

#: An empty cell is closed when at least this many of its 8 neighbours hold heights.
LATTICE_NEIGHBOURS = 6


def close_lattice(dsm, min_neighbours=LATTICE_NEIGHBOURS):
    """The DSM ``dsm`` ((H, W) float, NaN empty) with each empty cell that has at least ``min_neighbours`` of its 8
    neighbours holding heights given their median (module docstring). Returns ``(closed float32, count closed)``;
    neighbours are those of the input (one pass: closing does not spread)."""
    dsm = np.ascontiguousarray(dsm, np.float32)
    out = dsm.copy()
    n = _close_lattice(dsm, np.int64(min_neighbours), out)
    return out, int(n)


@kernel(parallel=True)
def _close_lattice(dsm, min_neighbours, out):
    # rows in parallel; each empty cell gathers its neighbours' heights and, with enough of them, takes their median
    H, W = dsm.shape
    closed = np.zeros(H, np.int64)
    for y in prange(H):
        vals = np.empty(8, np.float32)
        for x in range(W):
            if not np.isnan(dsm[y, x]):
                continue
            k = 0
            for dy in range(-1, 2):
                yy = y + dy
                if yy < 0 or yy >= H:
                    continue
                for dx in range(-1, 2):
                    xx = x + dx
                    if (dy == 0 and dx == 0) or xx < 0 or xx >= W:
                        continue
                    v = dsm[yy, xx]
                    if not np.isnan(v):
                        vals[k] = v
                        k += 1
            if k >= min_neighbours:
                s = np.sort(vals[:k])
                out[y, x] = s[k // 2] if k % 2 else np.float32(0.5 * (s[k // 2 - 1] + s[k // 2]))
                closed[y] += 1
    return closed.sum()


def close_lattice_reference(dsm, min_neighbours=LATTICE_NEIGHBOURS):
    """:func:`close_lattice` as the plain loop, with NumPy's median (for tests)."""
    dsm = np.asarray(dsm, np.float32)
    out, n = dsm.copy(), 0
    H, W = dsm.shape
    for y in range(H):
        for x in range(W):
            if np.isnan(dsm[y, x]):
                nb = dsm[max(0, y - 1):y + 2, max(0, x - 1):x + 2]
                vals = nb[np.isfinite(nb)]
                if len(vals) >= min_neighbours:
                    out[y, x] = np.median(vals)
                    n += 1
    return out, n


#: widest gap ``--fill-holes`` fills (cells): GDAL searches that far from every empty cell (a million ran for
#: minutes), and a wider gap is no hole in a surface but a part the pairs did not see
MAX_FILL_CELLS = 256


def check_fill_holes(max_size):
    """``--fill-holes`` as an int from 0 to :data:`MAX_FILL_CELLS`, or :class:`RiverbedError`."""
    if not 0 <= max_size <= MAX_FILL_CELLS:
        raise RiverbedError(f"--fill-holes must be from 0 to {MAX_FILL_CELLS} cells, got {max_size}")
    return int(max_size)


def fill_holes(dsm, max_size):
    """Fill enclosed gaps of a DSM no wider than ``max_size`` cells.

    A gap is a connected group of empty (NaN) cells that does not touch the raster border; it is filled when its
    largest inscribed distance to data is at most ``max_size / 2`` cells (so a gap up to ``max_size`` cells across),
    by GDAL's inverse-distance interpolation (``rasterio.fill.fillnodata``). ``max_size`` at most
    :data:`MAX_FILL_CELLS`. Returns the filled DSM (float32) and a uint8 mask, 1 where a cell was filled.
    """
    check_fill_holes(max_size)
    dsm = np.asarray(dsm, np.float32)
    empty = np.isnan(dsm)
    mask = np.zeros(dsm.shape, np.uint8)
    if max_size <= 0 or not empty.any() or empty.all():
        return dsm.copy(), mask
    n, labels = cv2.connectedComponents(empty.astype(np.uint8), connectivity=8)
    dist = cv2.distanceTransform(empty.astype(np.uint8), cv2.DIST_L2, 5)
    border = np.unique(np.r_[labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    biggest = np.zeros(n, np.float32)
    np.maximum.at(biggest, labels[empty], dist[empty])
    fillable = (biggest <= max_size / 2.0 + 0.5)
    fillable[border] = False
    fillable[0] = False  # label 0 is the data
    target = fillable[labels] & empty
    if not target.any():
        return dsm.copy(), mask
    work = np.where(empty, 0, dsm).astype(np.float32)
    filled = fillnodata(work, mask=(~empty).astype(np.uint8), max_search_distance=float(max_size) + 1,
                        smoothing_iterations=0)
    out = dsm.copy()
    out[target] = filled[target]
    mask[target] = 1
    return out, mask


