"""Matching cost: census transform and Hamming-distance cost volume.

Conventions: the left image is the reference; disparity ``d = x_left - x_right``; the cost volume is ``H x W x D``
(disparity innermost) for ``d = d_min .. d_max`` inclusive, ``D = d_max - d_min + 1``.
"""

import numpy as np
from numba import njit, prange

from ..errors import RiverbedError

# SWAR popcount constants. They must be np.uint64: mixing uint64 with int64 silently gives float64 in Numba.
_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)
_S1 = np.uint64(1)
_S2 = np.uint64(2)
_S4 = np.uint64(4)
_S56 = np.uint64(56)


@njit(cache=True, inline="always")
def popcount64(x):
    """Number of set bits of a uint64 (branch-free bit tricks; LLVM lowers it to POPCNT where available)."""
    x = x - ((x >> _S1) & _M1)
    x = (x & _M2) + ((x >> _S2) & _M2)
    x = (x + (x >> _S4)) & _M4
    return (x * _H01) >> _S56


def parse_census_window(spec):
    """Parse ``"9x7"`` (width x height, both odd, at most 65 cells) into ``(width, height)``."""
    if isinstance(spec, str):
        try:
            w, h = (int(v) for v in spec.lower().split("x"))
        except ValueError:
            raise RiverbedError(f"census window '{spec}' is not WIDTHxHEIGHT, e.g. 9x7") from None
    else:
        w, h = (int(v) for v in spec)
    if w < 1 or h < 1 or w % 2 == 0 or h % 2 == 0:
        raise RiverbedError(f"census window {w}x{h}: width and height must be odd and positive")
    if w * h - 1 > 64:
        raise RiverbedError(f"census window {w}x{h} has {w * h - 1} bits; at most 64 fit (e.g. 9x7)")
    if w * h < 9:
        raise RiverbedError(f"census window {w}x{h} is too small; use at least 3x3")
    return w, h


@njit(cache=True, parallel=True)
def _census_kernel(img, hw, hh):
    H, W = img.shape
    out = np.zeros((H, W), dtype=np.uint64)
    one = np.uint64(1)
    for y in prange(H):
        for x in range(W):
            c = img[y, x]
            bits = np.uint64(0)
            for dy in range(-hh, hh + 1):
                yy = min(max(y + dy, 0), H - 1)
                for dx in range(-hw, hw + 1):
                    if dy == 0 and dx == 0:
                        continue
                    xx = min(max(x + dx, 0), W - 1)
                    bits = bits << one
                    if img[yy, xx] < c:
                        bits = bits | one
            out[y, x] = bits
    return out


def census_transform(grey, window=(9, 7)):
    """Census transform of a grey image.

    Parameters
    ----------
    grey : (H, W) array
        Grey image (any real dtype; only the ordering of values matters).
    window : (int, int) or str
        Window ``(width, height)``, both odd, ``width * height - 1 <= 64``.

    Returns
    -------
    (H, W) uint64
        One bit per neighbour in row-major window order (the centre skipped), set where the neighbour is darker than
        the centre. Neighbours outside the image take the value of the nearest border pixel.
    """
    w, h = parse_census_window(window)
    grey = np.ascontiguousarray(grey, dtype=np.float32)
    if grey.ndim != 2:
        raise RiverbedError(f"census_transform needs a 2-D grey image, got shape {grey.shape}")
    return _census_kernel(grey, w // 2, h // 2)


@njit(cache=True, parallel=True)
def _census_cost_kernel(cl, cr, d_min, D, outside):
    H, W = cl.shape
    cost = np.empty((H, W, D), dtype=np.uint8)
    for y in prange(H):
        for x in range(W):
            a = cl[y, x]
            for i in range(D):
                xr = x - (d_min + i)
                if xr < 0 or xr >= W:
                    cost[y, x, i] = outside
                else:
                    cost[y, x, i] = np.uint8(popcount64(a ^ cr[y, xr]))
    return cost


def census_cost(census_left, census_right, d_min, d_max, outside_cost):
    """Hamming-distance cost volume between two census images.

    Parameters
    ----------
    census_left, census_right : (H, W) uint64
        Census transforms of the left (reference) and right images.
    d_min, d_max : int
        Inclusive disparity range; ``d = x_left - x_right`` and ``d_min`` may be negative.
    outside_cost : int
        Cost where ``x_left - d`` falls outside the right image. A moderate constant: a maximal cost would make every
        pixel near the left border prefer the smallest disparity.

    Returns
    -------
    (H, W, D) uint8
        ``cost[y, x, i] = popcount(census_left[y, x] ^ census_right[y, x - (d_min + i)])``.
    """
    if census_left.shape != census_right.shape:
        raise RiverbedError(f"census images differ in shape: {census_left.shape} vs {census_right.shape}")
    if d_max < d_min:
        raise RiverbedError(f"empty disparity range [{d_min}, {d_max}]")
    D = int(d_max) - int(d_min) + 1
    return _census_cost_kernel(census_left, census_right, int(d_min), D, np.uint8(outside_cost))
