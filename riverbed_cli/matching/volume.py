"""``CostVolume``: the matching cost and what it takes to read it, as it travels from stage to stage.

A volume is dense, ``(H, W, D)`` with disparity ``d_min + i`` at index ``i``, or a *tube volume*: per pixel only its
own disparity interval (its tube, :mod:`.tubes`), the pixels' intervals one after another in a flat array
described by a :class:`TubeLayout`.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import RiverbedError
from ..runtime.kernel import kernel


@dataclass
class CostVolume:
    """A cost volume with its metadata.

    Attributes
    ----------
    data : (H, W, D) uint8 or uint16
        Costs of the left image's pixels; index ``i`` holds disparity ``d = d_min + i`` (``d = x_left - x_right``,
        px). Lower is better.
    d_min : int
        Disparity of index 0 (with ``offset``: of index 0 at offset 0).
    scale : int
        Stored units per plain cost unit (census: Hamming units; AD-Census: 1.0 of the paper's cost). Penalties of
        the aggregation must be multiplied by it.
    max_cost : int
        The largest value ``data`` may hold (stored units): bounds the aggregation's sums.
    tubes : TubeLayout, optional
        For a tube volume: ``data`` is flat and pixel ``(y, x)``'s disparities ``d_min + offset[y, x] + i``, ``i <
        width[y, x]``, sit at ``data[start[y, x] + i]``.
    """

    data: np.ndarray
    d_min: int
    scale: int
    max_cost: int
    tubes: object = None

    @property
    def n_disp(self):
        """Number of disparities ``D`` (of a tube volume: its widest tube)."""
        return int(self.tubes.max_width if self.tubes is not None else self.data.shape[2])

    @property
    def d_max(self):
        """Largest disparity held at offset 0 (inclusive)."""
        return self.d_min + self.n_disp - 1

    def like(self, data, max_cost):
        """A volume with the same disparities (and tubes) holding ``data``."""
        return CostVolume(data, self.d_min, self.scale, max_cost, self.tubes)


@dataclass
class TubeLayout:
    """Where each pixel's tube sits in a flat tube volume.

    ``offset`` (H, W) int32: the tube's first disparity minus ``d_min``; ``width`` (H, W) int32: its number of
    disparities (>= 1); ``start`` (H, W) int64: index of its first disparity in the flat array (row-major order);
    ``size``: length of the flat array; ``max_width``: the widest tube.
    """

    offset: np.ndarray
    width: np.ndarray
    start: np.ndarray
    size: int
    max_width: int

    @classmethod
    def from_bounds(cls, lo, hi, d_min):
        """The layout of tubes ``[lo, hi]`` (inclusive disparities, (H, W) int arrays)."""
        offset, width, start, size = _layout(np.ascontiguousarray(lo, np.int32), np.ascontiguousarray(hi, np.int32),
                                             int(d_min))
        return cls(offset, width, start, int(size), int(width.max()) if width.size else 0)

    @property
    def shape(self):
        return self.width.shape


@kernel
def _layout(lo, hi, d_min):
    # offsets, widths and start indices (row-major running sum of the widths) of tubes [lo, hi], and the total
    H, W = lo.shape
    offset = np.empty((H, W), np.int32)
    width = np.empty((H, W), np.int32)
    start = np.empty((H, W), np.int64)
    size = 0
    for y in range(H):
        for x in range(W):
            offset[y, x] = lo[y, x] - d_min
            w = hi[y, x] - lo[y, x] + 1
            width[y, x] = w
            start[y, x] = size
            size += w
    return offset, width, start, size


_NONE = np.zeros((0, 0), np.int64)
_NONE32 = np.zeros((0, 0), np.int32)


def volume_layout(data, shape, tubes=None):
    """What the kernels take: ``(flat, W, D, start, width, offset)``; for a dense volume ``D`` is its depth and the
    three layout arrays are empty (0 x 0), for a tube volume ``D`` is 0."""
    H, W = shape
    if tubes is None:
        if data.ndim != 3 or data.shape[:2] != (H, W):
            raise RiverbedError(f"cost volume {data.shape} does not match the image {H}x{W} (H x W)")
        if not data.flags.c_contiguous:
            raise RiverbedError("cost volume must be C-contiguous (the kernels modify it in place)")
        return data.reshape(-1), W, int(data.shape[2]), _NONE, _NONE32, _NONE32
    if data.ndim != 1 or data.size != tubes.size or tubes.shape != (H, W):
        raise RiverbedError(f"tube volume of {data.size} costs does not match its layout ({tubes.size} for "
                            f"{tubes.shape})")
    return data, W, 0, tubes.start, tubes.width, tubes.offset


@kernel(inline=True)
def spread_rows(i, n):
    """Row ``i`` of ``n`` in a parallel loop's order where the first half of the loop takes the even rows and the
    second half the odd ones: the threads' contiguous shares of the loop then hold rows from all over the image, as
    even as its rows' work (tube widths vary between its parts: the cut speed pair's lower half holds twice the tube
    cells of its upper half)."""
    h = (n + 1) // 2
    return 2 * i if i < h else 2 * (i - h) + 1


#: rows of a band of the row-parallel kernels' shares (:func:`band_pair_rows`; 32 pairs of 16 rows on the 500-row
#: speed pair). Chosen as the riverbed ownership's bands at its default window, when the ownership went by bands;
#: not measured against other sizes
BAND_ROWS = 8


@kernel(inline=True)
def band_pairs(H):
    """How many pairs of bands of :data:`BAND_ROWS` rows ``H`` rows hold (the last may be short): the iterations of a
    row-parallel kernel's ``prange`` over :func:`band_pair_rows`."""
    return (H + 2 * BAND_ROWS - 1) // (2 * BAND_ROWS)


@kernel(inline=True)
def band_pair_rows(i, m, H):
    """Rows ``[r0, r1)`` of iteration ``i`` of a ``prange(m)`` over the ``m = band_pairs(H)`` pairs of bands, in
    :func:`spread_rows`' order: with two threads, the first takes the even pairs and the second the odd ones.

    Every row-parallel kernel of a match shares its rows out this way, so that a thread reads and writes, stage after
    stage, the rows it wrote before. Where the VM placed its two vCPUs on cores far apart (a cache line's round trip
    between two threads about 500 ns instead of 100, benchmarks/core_latency.py), every line written by one thread
    and taken by the other crosses between them, and kernels with other shares (contiguous halves, every other row,
    blocks of equal work) made the 4-path match of the speed pair 4-6 ms slower there (docs/tubes.md)."""
    p = spread_rows(i, m)
    r0 = p * 2 * BAND_ROWS
    return r0, min(H, r0 + 2 * BAND_ROWS)
