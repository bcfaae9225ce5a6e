"""AD-Census stage 1, the matching cost (:func:`adcensus_cost`), and the ``uint8`` image checks.

``C(p, d) = rho(C_census, lambda_census) + rho(C_AD, lambda_AD)`` with the robust ``rho(c, lambda) = 1 - exp(-c /
lambda)``; ``C_AD`` is the mean over colour channels of ``|I_L(p) - I_R(p - d)|`` (0..255 scale), ``C_census`` the
Hamming distance of the census transforms (grey, default 9 x 7). The paper's cost is a float in ``[0, 2)``; here it is
fixed point, ``round(scale * rho)`` per term (``scale = 256`` units per 1.0 of cost by default), in a ``uint16``
volume, so the guidance functions (``gauss_modulate`` / ``riverbed_modulate`` / ``diffusion_modulate``, given the
volume as already scaled ``uint16``) and int16 SGM-style path kernels apply unchanged. A match leaving the right image
gets the fixed cost ``outside`` (paper units; default 1.0, half the range: measured better than 0.5 because the
refinement re-fills those pixels, docs/riverbed_plus.md).

:func:`cost_row` (one row of the volume) is shared with the fused cost + aggregation of :mod:`.cross`.
"""

import numpy as np
from numba import prange

from ...errors import RiverbedError
from ...runtime.kernel import kernel
from ..census import popcount64


def cost_luts(channels, lambda_ad, lambda_census, scale, nbits=64):
    """Fixed-point lookup tables of the two robust terms.

    ``ad[s] = round(scale * (1 - exp(-(s / channels) / lambda_ad)))`` for the sum ``s`` of absolute differences over
    ``channels`` channels, ``census[h] = round(scale * (1 - exp(-h / lambda_census)))`` for Hamming distances ``h``.
    """
    s = np.arange(255 * channels + 1, dtype=np.float64)
    ad = np.floor(scale * (1.0 - np.exp(-(s / channels) / lambda_ad)) + 0.5).astype(np.uint16)
    h = np.arange(nbits + 1, dtype=np.float64)
    cen = np.floor(scale * (1.0 - np.exp(-h / lambda_census)) + 0.5).astype(np.uint16)
    return ad, cen


@kernel(inline=True)
def cost_row(left, right, cl, cr, y, d_min, ad_lut, cen_lut, outside, out):
    # Costs of row y into out (W, D). left/right are planar (C, H, W) float32 with C = 1 or 3 (absolute differences
    # of integers in float32 are exact). Disparity-major: for one disparity the left and right pixels are both
    # contiguous, so the differences and Hamming distances vectorise; the costs are then scattered into the row.
    W, D = out.shape
    C = left.shape[0]
    s = np.empty(W, dtype=np.int32)
    h = np.empty(W, dtype=np.int32)
    cly = cl[y]
    cry = cr[y]
    for i in range(D):
        d = d_min + i
        x0 = min(W, max(0, d))  # valid x: 0 <= x - d < W
        x1 = max(x0, min(W, W + d))
        for x in range(0, x0):
            out[x, i] = outside
        for x in range(x1, W):
            out[x, i] = outside
        n = x1 - x0
        a0 = left[0, y, x0:x1]
        b0 = right[0, y, x0 - d:x1 - d]
        ca = cly[x0:x1]
        cb = cry[x0 - d:x1 - d]
        if C == 3:
            a1 = left[1, y, x0:x1]
            a2 = left[2, y, x0:x1]
            b1 = right[1, y, x0 - d:x1 - d]
            b2 = right[2, y, x0 - d:x1 - d]
            for k in range(n):
                s[k] = np.int32(abs(a0[k] - b0[k]) + abs(a1[k] - b1[k]) + abs(a2[k] - b2[k]))
                h[k] = np.int32(popcount64(ca[k] ^ cb[k]))
        else:
            for k in range(n):
                s[k] = np.int32(abs(a0[k] - b0[k]))
                h[k] = np.int32(popcount64(ca[k] ^ cb[k]))
        for k in range(n):
            out[x0 + k, i] = ad_lut[s[k]] + cen_lut[h[k]]


@kernel(parallel=True)
def cost_kernel(left, right, cl, cr, d_min, ad_lut, cen_lut, outside, cost):
    for y in prange(cost.shape[0]):
        cost_row(left, right, cl, cr, y, d_min, ad_lut, cen_lut, outside, cost[y])


def cost_inputs(left, right, census_left, census_right, d_min, d_max, lambda_ad, lambda_census, scale, outside):
    """Checked arguments of :func:`cost_kernel` / :func:`cost_row`: planar float32 images, the census transforms,
    ``d_min``, the lookup tables (:func:`cost_luts`) and the outside cost in cost units."""
    left = u8_image(left, "left")
    right = u8_image(right, "right")
    if left.shape != right.shape or census_left.shape != left.shape[:2] or census_right.shape != left.shape[:2]:
        raise RiverbedError(f"AD-Census inputs differ in shape: {left.shape}, {right.shape}, {census_left.shape}")
    if d_max < d_min:
        raise RiverbedError(f"empty disparity range [{d_min}, {d_max}]")
    if not 1 <= scale <= 16383 or not 0 <= outside <= 2:
        raise RiverbedError(f"AD-Census cost scale {scale} / outside cost {outside} out of range")
    ad, cen = cost_luts(left.shape[2], lambda_ad, lambda_census, scale)
    return (np.ascontiguousarray(np.moveaxis(left, 2, 0), dtype=np.float32),
            np.ascontiguousarray(np.moveaxis(right, 2, 0), dtype=np.float32),
            census_left, census_right, int(d_min), ad, cen, np.uint16(round(outside * scale)))


def adcensus_cost(left, right, census_left, census_right, d_min, d_max, lambda_ad=10.0, lambda_census=30.0,
                  scale=256, outside=1.0):
    """AD-Census matching cost volume in fixed point.

    Parameters
    ----------
    left, right : (H, W, C) uint8
        Colour (or grey, ``C = 1``) images on a 0..255 scale.
    census_left, census_right : (H, W) uint64
        Census transforms (:func:`census.census_transform`) of the grey images.
    d_min, d_max : int
        Inclusive disparity range, ``d = x_left - x_right``.
    lambda_ad, lambda_census : float
        Robust-function parameters (paper: 10 and 30).
    scale : int
        Cost units per 1.0 of the paper's cost; each term is ``round(scale * rho)`` (:func:`cost_luts`).
    outside : float
        Cost (paper units, 0..2) of a match outside the right image.

    Returns
    -------
    (H, W, D) uint16
        Costs in ``[0, 2 * scale]``.
    """
    args = cost_inputs(left, right, census_left, census_right, d_min, d_max, lambda_ad, lambda_census, scale,
                        outside)
    H, W = census_left.shape
    cost = np.empty((H, W, int(d_max) - int(d_min) + 1), dtype=np.uint16)
    cost_kernel(*args, cost)
    return cost


def u8_image(img, name):
    """``img`` as a contiguous ``(H, W, C)`` uint8 array (``C`` 1 or 3); ``name`` goes into the error."""
    img = np.asarray(img)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.dtype != np.uint8 or img.shape[2] not in (1, 3):
        raise RiverbedError(f"{name} image must be an (H, W), (H, W, 1) or (H, W, 3) uint8 array, got {img.dtype} "
                            f"{img.shape}")
    return np.ascontiguousarray(img)


def to_u8(guide):
    """A float 0..255 image (:func:`io.images.to_guide`) rounded to ``uint8`` ``H x W x C`` for AD and crosses."""
    return np.ascontiguousarray(np.clip(np.floor(np.asarray(guide, np.float32) + np.float32(0.5)), 0, 255)
                                .astype(np.uint8))


@kernel(parallel=True)
def _cost_tube_kernel(left, right, cl, cr, d_min, ad_lut, cen_lut, outside, flat, start, width, offset):
    # cost_row's costs, pixel by pixel, at each pixel's own disparities only
    C, H, W = left.shape
    for y in prange(H):
        for x in range(W):
            b = start[y, x]
            d0 = d_min + np.int64(offset[y, x])
            a = cl[y, x]
            for i in range(width[y, x]):
                xr = x - (d0 + i)
                if xr < 0 or xr >= W:
                    flat[b + i] = outside
                    continue
                s = np.int32(abs(left[0, y, x] - right[0, y, xr]))
                if C == 3:
                    s = np.int32(abs(left[0, y, x] - right[0, y, xr]) + abs(left[1, y, x] - right[1, y, xr]) +
                                 abs(left[2, y, x] - right[2, y, xr]))
                flat[b + i] = ad_lut[s] + cen_lut[np.int32(popcount64(a ^ cr[y, xr]))]


def adcensus_cost_tube(left, right, census_left, census_right, d_min, tubes, lambda_ad=10.0, lambda_census=30.0,
                       scale=256, outside=1.0):
    """:func:`adcensus_cost` at each pixel's own disparities only.

    ``tubes`` is a :class:`~riverbed_cli.matching.volume.TubeLayout` (disparities ``d_min + offset + i``); the other
    parameters are those of :func:`adcensus_cost`. Returns the flat ``(tubes.size,)`` uint16 volume, equal to the
    dense volume's entries at the tubes.
    """
    if tubes.shape != np.shape(census_left):
        raise RiverbedError(f"tube layout {tubes.shape} and images {np.shape(census_left)} differ in size")
    args = cost_inputs(left, right, census_left, census_right, d_min, d_min, lambda_ad, lambda_census, scale,
                       outside)
    flat = np.empty(tubes.size, dtype=np.uint16)
    _cost_tube_kernel(*args, flat, tubes.start, tubes.width, tubes.offset)
    return flat
