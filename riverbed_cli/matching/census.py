"""Matching cost: census transform and Hamming-distance cost volume.

Conventions: the left image is the reference; disparity ``d = x_left - x_right``; the cost volume is ``H x W x D``
(disparity innermost) for ``d = d_min .. d_max`` inclusive, ``D = d_max - d_min + 1``.
"""

import numpy as np
from numba import prange

from ..errors import RiverbedError
from ..runtime.kernel import kernel
from ..settings import parse_census_window
from .kernels.lanes import LANES, lanes_census, lanes_census_bits, lanes_census_half
from .volume import band_pair_rows, band_pairs

# SWAR popcount constants. They must be np.uint64: mixing uint64 with int64 silently gives float64 in Numba.
_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)
_S1 = np.uint64(1)
_S2 = np.uint64(2)
_S4 = np.uint64(4)
_S56 = np.uint64(56)


@kernel(inline=True)
def popcount64(x):
    """Number of set bits of a uint64 (branch-free bit tricks; LLVM lowers it to POPCNT where available)."""
    x = x - ((x >> _S1) & _M1)
    x = (x & _M2) + ((x >> _S2) & _M2)
    x = (x + (x >> _S4)) & _M4
    return (x * _H01) >> _S56


@kernel(parallel=True)
def _census_kernel(pad, H, W, hw, hh):
    # pad is the image with hh rows / hw columns of replicated border on each side. A row's pixels LANES at a time,
    # all their bits in registers (lanes.lanes_census_bits); the row's last pixels one neighbour at a time over the
    # remaining columns (the loop over x innermost and branch-free, so it vectorises). Bits are appended in
    # row-major window order.
    out = np.empty((H, W), dtype=np.uint64)  # every word is written below (a serial zero fill took 0.1 ms)
    one = np.uint64(1)
    Wp = W + 2 * hw
    offsets = np.empty((2 * hh + 1) * (2 * hw + 1) - 1, np.int64)  # flat offsets of the neighbours in pad
    k = 0
    for dy in range(-hh, hh + 1):
        for dx in range(-hw, hw + 1):
            if dy != 0 or dx != 0:
                offsets[k] = dy * Wp + dx
                k += 1
    flat_pad = pad.reshape(-1)
    flat_out = out.reshape(-1)
    full = W // LANES * LANES
    m = band_pairs(H)
    for i in prange(m):  # the rows' shares of the cost kernel that reads them (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            for x0 in range(0, full, LANES):
                lanes_census_bits(flat_pad, (y + hh) * Wp + hw + x0, offsets, flat_out, y * W + x0)
            if full == W:
                continue
            row = out[y, full:]
            row[:] = 0
            centre = pad[y + hh, hw + full:hw + W]
            for dy in range(-hh, hh + 1):
                for dx in range(-hw, hw + 1):
                    if dy == 0 and dx == 0:
                        continue
                    nb = pad[y + hh + dy, hw + dx + full:hw + dx + W]
                    for x in range(W - full):
                        row[x] = (row[x] << one) | np.uint64(nb[x] < centre[x])
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
    H, W = grey.shape
    pad = np.pad(grey, ((h // 2, h // 2), (w // 2, w // 2)), mode="edge")
    return _census_kernel(pad, H, W, w // 2, h // 2)


@kernel(inline=True)
def _pixel_costs(flat, b, w, top, a, row, outside, scale):
    # The w costs of one pixel (census a) from flat[b]: index i compares the right row's column top - i. The
    # disparities whose column lies in the image form one run [i0, i1): outside it the constant, inside a loop with
    # no test (unsigned indices: no negative-index wrap-around either), which vectorises.
    W = row.shape[0]
    i0 = min(w, max(0, top - W + 1))
    i1 = max(i0, min(w, top + 1))
    for i in range(i0):
        flat[b + np.uint64(i)] = outside
    for i in range(i0, i1):
        flat[b + np.uint64(i)] = popcount64(a ^ row[np.uint64(top - i)]) * scale
    for i in range(i1, w):
        flat[b + np.uint64(i)] = outside


@kernel(parallel=True)
def _census_cost_kernel(cl, cr, d_min, cost, outside, scale):
    H, W, D = cost.shape
    flat = cost.reshape(-1)
    for y in prange(H):
        row = cr[y]
        for x in range(W):
            _pixel_costs(flat, np.uint64((y * W + x) * D), D, x - d_min, cl[y, x], row, outside, scale)


@kernel(parallel=True)
def _census_tube_kernel(cl, cr, d_min, flat, start, width, offset, outside, scale, vector):
    # vector (a uint16 volume, scale > 1): a row's pixels in order, LANES costs at a time (lanes.lanes_census) while
    # the chunk's right pixels lie in the image and it ends before the row's tubes do; its lanes past the pixel's
    # tube are the next pixels', which write theirs after. The rest, and uint8 volumes, one cost at a time (uint8
    # keeps its own loop: through the vector path's bookkeeping it took 1.18x as long on the aerial pair).
    H, W = cl.shape
    n = flat.shape[0]
    m = band_pairs(H)
    for k in prange(m):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(k, m, H)
        for y in range(r0, r1):
            row = cr[y]
            if not vector:
                for x in range(W):
                    _pixel_costs(flat, np.uint64(start[y, x]), np.int64(width[y, x]),
                                 x - d_min - np.int64(offset[y, x]), cl[y, x], row, outside, scale)
                continue
            # where the next row's tubes start: the next row is this thread's inside the pair, but the chunks stop
            # at the row's end all the same (the pair's last row is another thread's, and the same bits either way)
            end = start[y + 1, 0] if y + 1 < H else n
            for x in range(W):
                b = np.int64(start[y, x])
                w = np.int64(width[y, x])
                top = x - d_min - np.int64(offset[y, x])
                a = cl[y, x]
                half = LANES // 2
                if w <= half and top - half + 1 >= 0 and top < W and b + half <= end:  # most tubes: half the lanes
                    lanes_census_half(flat, b, a, row, top, scale)
                    continue
                i = 0
                while i < w and top - i - LANES + 1 >= 0 and top - i < W and b + i + LANES <= end:
                    lanes_census(flat, b + i, a, row, top - i, scale)
                    i += LANES
                if i < w:
                    _pixel_costs(flat, np.uint64(b + i), w - i, top - i, a, row, outside, scale)


def census_cost(census_left, census_right, d_min, d_max, outside_cost, scale=1, tubes=None):
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
    scale : int
        1 gives a ``uint8`` volume of Hamming distances; a larger scale gives ``uint16`` costs multiplied by it (the
        fixed-point units the guidance stage works in).
    tubes : TubeLayout, optional
        Per-pixel tubes (:class:`~riverbed_cli.matching.volume.TubeLayout`): only each pixel's own disparities are
        computed, into a flat volume (``d_max`` is then unused).

    Returns
    -------
    (H, W, D) uint8 (scale 1) or uint16, or with ``tubes`` the flat (tubes.size,) volume
        ``cost[y, x, i] = scale * popcount(census_left[y, x] ^ census_right[y, x - (d_min + i)])``.
    """
    if census_left.shape != census_right.shape:
        raise RiverbedError(f"census images differ in shape: {census_left.shape} vs {census_right.shape}")
    if tubes is None and d_max < d_min:
        raise RiverbedError(f"empty disparity range [{d_min}, {d_max}]")
    D = int(d_max) - int(d_min) + 1 if tubes is None else 0
    H, W = census_left.shape
    dtype = np.uint8 if scale == 1 else np.uint16
    if scale < 1 or 64 * scale > np.iinfo(dtype).max or not 0 <= outside_cost <= 64:
        raise RiverbedError(f"census cost scale {scale} / outside cost {outside_cost} out of range")
    if tubes is not None:
        if tubes.shape != (H, W):
            raise RiverbedError(f"tube layout {tubes.shape} and census images {(H, W)} differ in size")
        flat = np.empty(tubes.size, dtype=dtype)
        _census_tube_kernel(census_left, census_right, int(d_min), flat, tubes.start, tubes.width, tubes.offset,
                            dtype(outside_cost * scale), dtype(scale), dtype == np.uint16)
        return flat
    cost = np.empty((H, W, D), dtype=dtype)
    _census_cost_kernel(census_left, census_right, int(d_min), cost, dtype(outside_cost * scale), dtype(scale))
    return cost

