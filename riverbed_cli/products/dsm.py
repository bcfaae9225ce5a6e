"""DSM rasterisation: points (world coordinates, float64) to a north-up height grid.

Grid convention: cell ``(row, col)`` covers ``[xmin + col * r, xmin + (col + 1) * r) x (ymax - (row + 1) * r, ymax - row
* r]``; the GeoTIFF transform is ``Affine(r, 0, xmin, 0, -r, ymax)`` (pixel corners, as GDAL). Heights are float32 in the
units of the CRS; empty cells are ``nodata`` (NaN by default).
"""

import math
from dataclasses import dataclass

import cv2
import numpy as np
from affine import Affine
from numba import njit

from ..errors import RiverbedError

AGGREGATIONS = ("max", "mean", "median", "idw")


@dataclass
class Grid:
    """A north-up raster grid: origin at the top-left corner ``(xmin, ymax)``, square cells of ``resolution``."""

    xmin: float
    ymax: float
    resolution: float
    width: int
    height: int

    @property
    def transform(self):
        return Affine(self.resolution, 0.0, self.xmin, 0.0, -self.resolution, self.ymax)

    @property
    def bounds(self):
        r = self.resolution
        return self.xmin, self.ymax - self.height * r, self.xmin + self.width * r, self.ymax

    @classmethod
    def from_bounds(cls, xmin, ymin, xmax, ymax, resolution, max_cells=2_000_000_000):
        """The grid of ``resolution`` covering the bounds, snapped outwards to multiples of the resolution."""
        r = float(resolution)
        if not r > 0 or not math.isfinite(r):
            raise RiverbedError(f"resolution must be a positive number, got {resolution}")
        if not (xmax >= xmin and ymax >= ymin):
            raise RiverbedError(f"empty bounds ({xmin}, {ymin}, {xmax}, {ymax})")
        x0 = math.floor(xmin / r) * r
        y1 = math.ceil(ymax / r) * r
        if y1 == ymax and ymax == ymin:
            y1 += r
        w = max(1, int(math.ceil((xmax - x0) / r - 1e-9)) + (1 if math.floor(xmax / r) * r == xmax else 0))
        h = max(1, int(math.ceil((y1 - ymin) / r - 1e-9)) + (1 if math.floor(ymin / r) * r == ymin else 0))
        if w * h > max_cells:
            raise RiverbedError(f"DSM grid {w}x{h} at {r} is too large; raise --resolution or give --bounds")
        return cls(x0, y1, r, w, h)


def grid_indices(grid, x, y):
    """Row and column (int64) of each point; -1 for points outside the grid."""
    col = np.floor((np.asarray(x, np.float64) - grid.xmin) / grid.resolution).astype(np.int64)
    row = np.floor((grid.ymax - np.asarray(y, np.float64)) / grid.resolution).astype(np.int64)
    bad = (col < 0) | (col >= grid.width) | (row < 0) | (row >= grid.height)
    col[bad] = -1
    row[bad] = -1
    return row, col


@njit(cache=True)
def _max_kernel(row, col, z, out):
    for i in range(z.shape[0]):
        r = row[i]
        if r < 0:
            continue
        c = col[i]
        if np.isnan(out[r, c]) or z[i] > out[r, c]:
            out[r, c] = z[i]


@njit(cache=True)
def _sum_kernel(row, col, z, w, sums, weights):
    for i in range(z.shape[0]):
        r = row[i]
        if r < 0:
            continue
        c = col[i]
        sums[r, c] += w[i] * z[i]
        weights[r, c] += w[i]


@njit(cache=True)
def _count_kernel(row, col, counts):
    for i in range(row.shape[0]):
        if row[i] >= 0:
            counts[row[i], col[i]] += 1


class Accumulator:
    """Streams point chunks into a grid, so clouds larger than memory rasterise in bounded memory.

    ``max``, ``mean`` and ``idw`` (weights ``1 / (d^2 + (r/4)^2)`` to the cell centre, ``d`` the horizontal distance)
    keep running per-cell state; ``median`` keeps the heights (float32) until :meth:`result`.
    """

    def __init__(self, grid, agg="max"):
        if agg not in AGGREGATIONS:
            raise RiverbedError(f"unknown aggregation '{agg}' (use one of {', '.join(AGGREGATIONS)})")
        self.grid, self.agg = grid, agg
        shape = (grid.height, grid.width)
        self.counts = np.zeros(shape, np.int64)
        if agg == "max":
            self.value = np.full(shape, np.nan, np.float64)
        elif agg in ("mean", "idw"):
            self.sums = np.zeros(shape, np.float64)
            self.weights = np.zeros(shape, np.float64)
        else:
            self.keys, self.heights = [], []

    def add(self, x, y, z):
        row, col = grid_indices(self.grid, x, y)
        z = np.asarray(z, np.float64)
        _count_kernel(row, col, self.counts)
        if self.agg == "max":
            _max_kernel(row, col, z, self.value)
        elif self.agg == "mean":
            _sum_kernel(row, col, z, np.ones_like(z), self.sums, self.weights)
        elif self.agg == "idw":
            r = self.grid.resolution
            cx = self.grid.xmin + (col + 0.5) * r
            cy = self.grid.ymax - (row + 0.5) * r
            d2 = (np.asarray(x) - cx) ** 2 + (np.asarray(y) - cy) ** 2
            _sum_kernel(row, col, z, 1.0 / (d2 + (r / 4) ** 2), self.sums, self.weights)
        else:
            ok = row >= 0
            self.keys.append(row[ok] * self.grid.width + col[ok])
            self.heights.append(z[ok].astype(np.float32))

    def result(self):
        """(H, W) float32 heights, NaN where no point fell."""
        if self.agg == "max":
            return self.value.astype(np.float32)
        if self.agg in ("mean", "idw"):
            with np.errstate(invalid="ignore", divide="ignore"):
                return (self.sums / self.weights).astype(np.float32)
        out = np.full(self.grid.height * self.grid.width, np.nan, np.float32)
        if self.keys:
            keys = np.concatenate(self.keys)
            h = np.concatenate(self.heights)
            order = np.lexsort((h, keys))
            keys, h = keys[order], h[order]
            starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
            ends = np.r_[starts[1:], keys.size]
            lo = h[starts + (ends - starts - 1) // 2]
            hi = h[starts + (ends - starts) // 2]
            out[keys[starts]] = 0.5 * (lo + hi)
        return out.reshape(self.grid.height, self.grid.width)


def rasterize(x, y, z, grid, agg="max"):
    """Rasterise points into ``grid`` with one aggregation per cell (see :class:`Accumulator`)."""
    acc = Accumulator(grid, agg)
    acc.add(x, y, z)
    return acc.result()


def fill_holes(dsm, max_size):
    """Fill enclosed gaps of a DSM no wider than ``max_size`` cells.

    A gap is a connected group of empty (NaN) cells that does not touch the raster border; it is filled when its
    largest inscribed distance to data is at most ``max_size / 2`` cells (so a gap up to ``max_size`` cells across),
    by GDAL's inverse-distance interpolation (``rasterio.fill.fillnodata``).

    Returns
    -------
    filled : (H, W) float32
    mask : (H, W) uint8
        1 where a cell was filled, 0 elsewhere.
    """
    from rasterio.fill import fillnodata

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


def hillshade(dsm, resolution, azimuth=315.0, altitude=45.0, z_factor=1.0):
    """Grey hillshade (uint8) of a DSM, GDAL's formula; NaN cells are black."""
    z = np.asarray(dsm, np.float64)
    zf = np.where(np.isnan(z), np.nanmean(z) if np.isfinite(z).any() else 0.0, z)
    gy, gx = np.gradient(zf * z_factor, resolution)
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, gy)  # gy is along rows (south), so north-up aspect from -dz/dx and dz/dy
    az = math.radians(360.0 - azimuth + 90.0)
    alt = math.radians(altitude)
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    out = np.clip(255 * shade, 0, 255).astype(np.uint8)
    out[np.isnan(z)] = 0
    return out
