"""Diffusion-based LiDAR guidance of a cost volume (Shivakumar, Mohta, Pfrommer, Kumar, Taylor 2019, "Real time dense
depth estimation by fusing stereo with sparse depth measurements", ICRA 2019), the second baseline riverbed is
compared with (``--guide diffusion``).

How we read the paper
---------------------
The paper fuses sparse depth into Semi-Global Matching by editing the cost volume before aggregation. Its *naive
fusion* sets the cost of a LiDAR pixel to zero at the measured disparity. Its *diffusion-based fusion* first spreads
each measurement to a small image neighbourhood with an anisotropic (bilateral) weight, as one step of anisotropic
diffusion would: a neighbour ``q`` of the LiDAR pixel ``p`` receives

    w(q) = exp(-|q - p|^2 / (2 sigma_s^2) - |I(q) - I(p)|^2 / (2 sigma_i^2))    (w = 1 at p itself)

and the cost of ``q`` *at the spread disparity* ``d_p`` is lowered by that weight,

    C'(q, d_p) = (1 - w(q)) C(q, d_p),

all other disparities of ``q`` keeping their cost; SGM then carries the lowered costs along its paths. The paper gives
no formula for a non-integer ``d_p``: we split the reduction linearly over the two nearest integer disparities,
``C'(q, d) = (1 - w(q) * max(0, 1 - |d - d_p|)) C(q, d)`` (an integer ``d_p`` lowers one disparity only, as in the
paper). Where several measurements reach the same cost, the strongest reduction applies (the smallest factor); a
LiDAR pixel keeps its own measurement (naive fusion: cost 0 at ``d_p``).

Parameters (the paper states a small neighbourhood and a bilateral weight but, as far as we read it, no values):
window ``radius = 5`` (11 x 11), ``sigma_s = 10`` px, ``sigma_i = 20`` grey levels (colour differences are the mean
over channels of squared differences, as in the riverbed similarity). These are the best of a grid measured with SGM
on the Middlebury dev scenes at 5 % LiDAR (radius 1..7, sigma_s 1..10, sigma_i 10..20; docs/riverbed_plus.md): the
baseline is tuned, not handicapped (larger windows help a little more but stop being a "small neighbourhood").

Contrast with riverbed: Diffusion lowers one (or two) disparities of a neighbour and raises nothing, so a neighbour
whose true disparity differs from ``d_p`` keeps its other costs intact; riverbed also builds walls that push costs up
away from ``d_m``.

Conventions: left image reference, ``d = x_left - x_right``; volume ``H x W x D`` with ``d = d_min + i``.
"""

import math

import numpy as np
from numba import prange

from ..errors import RiverbedError
from ..geometry.coverage import lidar_rows
from ..geometry.interpolation import first_at_least
from ..runtime.kernel import kernel
from .guidance import check_volume, guide_image, scaled_volume
from .volume import volume_layout


@kernel(inline=True)
def bilateral_weight(guide, y, x, yy, xx, a, b):
    """Joint-bilateral weight of pixel (yy, xx) seen from (y, x): ``exp(-|p - q|^2 a - |I(p) - I(q)|^2 b)`` over the
    channels of ``guide`` (H, W, C); ``a = 1 / 2 sigma_s^2``, ``b = 1 / 2 sigma_i^2`` (per channel scaling by the
    caller)."""
    dd = 0.0
    for ch in range(guide.shape[2]):
        t = guide[y, x, ch] - guide[yy, xx, ch]
        dd += t * t
    return math.exp(-((yy - y) ** 2 + (xx - x) ** 2) * a - dd * b)


@kernel(parallel=True)
def _diffusion_kernel(flat, D0, sparse, ptr, cols, guide, d_min0, radius, a, b, dref, min_weight, tstart, twidth,
                      toffset):
    # Pixel-centric: every pixel visits the LiDAR pixels of its (2 radius + 1)^2 window (rows as CSR lists, so only
    # LiDAR pixels are touched), so rows are independent. With ``dref`` (H x W, or 0 x 0 for none) it also records
    # the disparity of the strongest weight >= min_weight (diffusion_support), in the same pass.
    H, W = sparse.shape
    n = (2 * radius + 1) * (2 * radius + 1) * 2
    want_ref = dref.shape[0] == H
    tube = tstart.shape[0] == H
    for y in prange(H):
        idx = np.empty(n, dtype=np.int64)
        fac = np.empty(n, dtype=np.float64)
        for x in range(W):
            if tube:
                base, D, d_min = tstart[y, x], np.int64(twidth[y, x]), d_min0 + np.int64(toffset[y, x])
            else:
                base, D, d_min = (y * W + x) * D0, D0, d_min0  # index 0 of this pixel is disparity d_min
            m = 0
            own = not math.isnan(sparse[y, x])
            best_w = -1.0
            for yy in range(max(0, y - radius), min(H, y + radius + 1)):
                row = cols[ptr[yy]:ptr[yy + 1]]
                j = first_at_least(row, x - radius)
                while j < row.shape[0] and row[j] <= x + radius:
                    xx = row[j]
                    j += 1
                    if own and (yy != y or xx != x):
                        continue  # a LiDAR pixel keeps its own measurement
                    dp = sparse[yy, xx]
                    w = bilateral_weight(guide, y, x, yy, xx, a, b)
                    if want_ref and w >= min_weight and w > best_w:
                        best_w = w
                        dref[y, x] = dp
                    f0 = math.floor(dp)
                    for k in range(2):
                        dk = f0 + k
                        share = 1.0 - abs(dk - dp)
                        i = np.int64(dk) - d_min
                        if share <= 0.0 or i < 0 or i >= D:
                            continue
                        f = 1.0 - w * share
                        # the strongest reduction per disparity
                        found = False
                        for t in range(m):
                            if idx[t] == i:
                                found = True
                                if f < fac[t]:
                                    fac[t] = f
                        if not found:
                            idx[m] = i
                            fac[m] = f
                            m += 1
            cy = flat[base:base + D]
            for t in range(m):
                i = idx[t]
                cy[i] = np.uint16(math.floor(fac[t] * cy[i] + 0.5))


def diffusion_modulate(cost, sparse, guide, d_min, radius=5, sigma_s=10.0, sigma_i=20.0, cost_scale=4,
                       inplace=False, support_weight=None, tubes=None):
    """Diffusion-based guidance (Shivakumar et al. 2019, as read in the module docstring).

    Parameters
    ----------
    cost : (H, W, D) uint8 or uint16
        Matching cost, ``d = d_min + i`` at index ``i``; a ``uint16`` volume holds costs already multiplied by
        ``cost_scale`` (as for :func:`guidance.gauss_modulate`).
    sparse : (H, W) float
        LiDAR disparities of the left image (``d = x_left - x_right``), NaN elsewhere.
    guide : (H, W) or (H, W, C) float
        Left image on a 0..255 scale, for the colour term of the bilateral weight.
    radius : int
        Half side of the square neighbourhood a measurement spreads to.
    sigma_s, sigma_i : float
        Spatial (px) and colour (grey levels) widths of the bilateral weight.
    cost_scale : int
        Fixed-point scale of the output (a ``uint8`` input is multiplied by it).
    inplace : bool
        Modulate a scaled ``uint16`` input in place.
    tubes : TubeLayout, optional
        Per-pixel tubes (:class:`~riverbed_cli.matching.volume.TubeLayout`): ``cost`` is the flat tube volume.
    support_weight : float, optional
        Also return :func:`diffusion_support` with ``min_weight = support_weight``, computed in the same pass.

    Returns
    -------
    (H, W, D) uint16
        Scaled costs; only costs at the spread disparities of pixels within ``radius`` of a LiDAR pixel change, and
        they only decrease. With ``support_weight``: ``(costs, support)``.
    """
    check_volume(cost, sparse, tubes)
    radius = int(radius)
    if radius < 0 or sigma_s <= 0 or sigma_i <= 0:
        raise RiverbedError(f"diffusion needs radius >= 0 and positive sigmas (got {radius}, {sigma_s}, {sigma_i})")
    guide = guide_image(guide, sparse.shape)
    out = scaled_volume(cost, cost_scale, inplace)
    C = guide.shape[2]
    sparse = np.ascontiguousarray(sparse, dtype=np.float32)
    ptr, cols = lidar_rows(sparse)
    shape = sparse.shape if support_weight is not None else (0, 0)
    dref = np.full(shape, np.nan, dtype=np.float32)
    flat, _, D0, ts, tw, to = volume_layout(out, sparse.shape, tubes)
    _diffusion_kernel(flat, D0, sparse, ptr, cols, guide, int(d_min), radius,
                      1.0 / (2.0 * sigma_s * sigma_s), 1.0 / (2.0 * sigma_i * sigma_i * C), dref,
                      float(support_weight or 0.0), ts, tw, to)
    if support_weight is None:
        return out
    dref[~np.isnan(sparse)] = sparse[~np.isnan(sparse)]  # a LiDAR pixel vouches for its own measurement
    return out, dref


def diffusion_support(sparse, guide, radius=5, sigma_s=10.0, sigma_i=20.0, min_weight=0.3):
    """The disparity the diffusion vouches for at each pixel: that of the LiDAR pixel with the largest bilateral weight
    ``w >= min_weight`` within ``radius`` (its own at a LiDAR pixel), NaN elsewhere. (H, W) float32.

    ``min_weight`` defaults to riverbed's similarity threshold ``gamma = 0.3``, so that both guides vouch under the
    same rule (AD-Census keeps vouched winners through its left-right check)."""
    empty = np.zeros(np.shape(sparse) + (0,), dtype=np.uint16)  # no disparities: the weights only
    return diffusion_modulate(empty, sparse, guide, 0, radius, sigma_s, sigma_i, 1, True, min_weight)[1]
