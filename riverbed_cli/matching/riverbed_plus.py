"""riverbed+ (``--guide riverbed+``): the paper's riverbed guidance, extended through cross-based support regions to
the pixels stereo cannot match on its own.

Why
---
The riverbed enhancement reaches a pixel only if it lies in the ``s x s`` window of a LiDAR point and passes the
bilateral similarity test ``exp(-|p - p_L|^2 / 2 sigma_xy^2 - |I(p) - I(p_L)|^2 / 2 sigma_I^2) >= gamma``; with
``sigma_xy = 8`` and ``gamma = 0.3`` that is at most ~12 px from the point, much less across any colour change. At
0.16 % LiDAR (one point per ~25 x 25 px) most pixels get no guidance, and the ones that matter most -- occluded
background strips, weakly textured surfaces -- keep their gross errors (docs/riverbed_plus.md).

What (all of it is cost-volume guidance before aggregation; no disparity is predicted or interpolated)
----------------------------------------------------------------------------------------------------
1. **Riverbed, unchanged.** LiDAR pixels and their homogeneous pixels are modulated exactly as ``--guide riverbed``
   (:func:`guidance.riverbed_modulate`), so riverbed+ equals riverbed wherever riverbed acts.
2. **Reach: cross-based support regions, iterated.** Every pixel gets the cross of Mei et al. 2011 (arms grow while
   the colour stays within ``tau1`` of the pixel and of the previous arm pixel, within ``tau2`` past ``L2``, up to
   ``L1 - 1`` px; :func:`adcensus.cross_arms`). One *hop* takes, over a pixel's support region (its vertical arm's
   horizontal segments; the next hop the transposed region), the smallest and largest LiDAR disparity present.
   ``hops`` hops make the disparity range ``[lo(p), hi(p)]`` of all LiDAR points connected to ``p`` through a chain
   of ``hops`` overlapping homogeneous regions: it follows homogeneous surfaces for tens of pixels and stops at
   colour edges, where a square window either stops short or leaks. ``hops = "auto"`` uses
   ``round(spacing / 6)`` clipped to 1..8, ``spacing = 1 / sqrt(p)`` the mean LiDAR spacing in px (p the LiDAR
   share): 1 hop at 5 %, 2 at 1.23 %, 4 at 0.16 %.
3. **Confidence: only where stereo fails.** A first riverbed-guided pass with a left-right check marks the pixels
   whose match is inconsistent (occlusions, mismatches); only those (``confidence="lr"``; ``"none"`` extends to
   every pixel) that riverbed did not reach are extended. On surfaces where stereo works, slanted ones included, the
   range of distant LiDAR points would be a worse guide than the matching cost itself (measured: without the check,
   slanted surfaces -- KITTI's road, Reindeer's panel -- lose accuracy).
4. **Band and walls.** An extended pixel keeps its cost inside the band ``[lo - margin, hi + margin]`` (the range of
   the connected LiDAR disparities: a range, not a prediction -- a surface spanned by several points is covered by
   their range) and rises outside it along riverbed's additive Gaussian walls, ``F + k F_bar (1 - exp(-t^2 / 2c^2))``,
   ``t`` the distance past the band (same ``k``, ``c``, ``F_bar`` as riverbed).

The first pass makes riverbed+ cost about twice riverbed's matching time.

Conventions: left image reference, ``d = x_left - x_right``; volumes ``H x W x D`` with ``d = d_min + i``.
"""

import math

import numpy as np
from numba import prange

from ..errors import RiverbedError
from . import guidance
from ..runtime.kernel import kernel
from .config import CONFIDENCES, PlusConfig  # noqa: F401  (CONFIDENCES: the valid confidence rules)
from .adcensus import cross_arms, to_u8
from .volume import volume_layout
from .guidance import check_volume, lidar_points, scaled_volume

#: riverbed+ settings (frozen; defaults and meaning in :class:`~.config.PlusConfig`).
PlusParams = PlusConfig


def auto_hops(share, per_hop=6.0, largest=8):
    """Hops for a LiDAR share ``p``: ``round(spacing / per_hop)`` with ``spacing = 1 / sqrt(p)``, within 1..largest."""
    if share <= 0:
        return largest
    return int(min(max(round((1.0 / math.sqrt(share)) / per_hop), 1), largest))


@kernel(parallel=True)
def _segment_range(lo, hi, arms, vertical):
    # min of lo / max of hi over every pixel's horizontal (or vertical) arm segment
    H, W = lo.shape
    olo = np.empty_like(lo)
    ohi = np.empty_like(hi)
    for y in prange(H):
        for x in range(W):
            a = np.float32(np.inf)
            b = np.float32(-np.inf)
            if vertical:
                for yy in range(y - np.int64(arms[y, x, 2]), y + np.int64(arms[y, x, 3]) + 1):
                    a = min(a, lo[yy, x])
                    b = max(b, hi[yy, x])
            else:
                for xx in range(x - np.int64(arms[y, x, 0]), x + np.int64(arms[y, x, 1]) + 1):
                    a = min(a, lo[y, xx])
                    b = max(b, hi[y, xx])
            olo[y, x] = a
            ohi[y, x] = b
    return olo, ohi


def support_ranges(sparse, arms, hops):
    """Range ``[lo, hi]`` of the LiDAR disparities connected to each pixel through ``hops`` support-region hops.

    Parameters
    ----------
    sparse : (H, W) float
        LiDAR disparities, NaN elsewhere.
    arms : (H, W, 4) uint8
        Cross arms (left, right, up, down), :func:`adcensus.cross_arms`.
    hops : int
        Odd hops use the region "horizontal segments of the vertical arm", even hops the transposed one.

    Returns
    -------
    lo, hi : (H, W) float32
        ``+inf`` / ``-inf`` where no LiDAR point is connected.
    """
    if arms.shape != sparse.shape + (4,):
        raise RiverbedError(f"arms {arms.shape} do not match the sparse map {sparse.shape}")
    valid = np.isfinite(sparse)
    lo = np.where(valid, sparse, np.inf).astype(np.float32)
    hi = np.where(valid, sparse, -np.inf).astype(np.float32)
    for it in range(int(hops)):
        first_vertical = it % 2 == 1
        lo, hi = _segment_range(lo, hi, arms, first_vertical)
        lo, hi = _segment_range(lo, hi, arms, not first_vertical)
    return lo, hi


@kernel(parallel=True)
def _band_kernel(flat, D0, lo, hi, extend, d_min0, margin, wall, c, max_cost, tstart, twidth, toffset):
    # cost holds scaled costs; at extended pixels: unchanged inside [lo - margin, hi + margin], plus
    # wall * (1 - exp(-t^2 / 2c^2)) at distance t outside it.
    H, W = lo.shape
    inv2c2 = 1.0 / (2.0 * c * c)
    tube = tstart.shape[0] == H
    for y in prange(H):
        for x in range(W):
            if not extend[y, x]:
                continue
            if tube:
                base, D, d_min = tstart[y, x], np.int64(twidth[y, x]), d_min0 + np.int64(toffset[y, x])
            else:
                base, D, d_min = (y * W + x) * D0, D0, d_min0
            a = lo[y, x] - margin
            b = hi[y, x] + margin
            cy = flat[base:base + D]
            for i in range(D):
                d = d_min + i
                t = max(a - d, d - b, 0.0)
                if t > 0.0:
                    g = 1.0 - math.exp(-t * t * inv2c2)
                    cy[i] = np.uint16(min(cy[i] + wall * g + 0.5, max_cost))


def band_modulate(cost, lo, hi, extend, d_min, margin=2.0, k=10.0, c=1.0, wall_scale=1.0, cost_scale=4, max_cost=65535,
                  inplace=False, tubes=None):
    """Band-and-walls guidance at the pixels ``extend``: costs unchanged inside ``[lo - margin, hi + margin]``, raised
    by ``k * wall_scale * cost_scale * (1 - exp(-t^2 / 2c^2))`` at distance ``t`` outside, clipped at ``max_cost``.

    ``cost`` is uint8 (plain) or uint16 (already scaled by ``cost_scale``); returns the scaled uint16 volume.
    """
    if (tubes is None and (cost.ndim != 3 or lo.shape != cost.shape[:2])) or hi.shape != lo.shape \
            or extend.shape != lo.shape:
        raise RiverbedError(f"band inputs do not match the cost volume {cost.shape}")
    out = scaled_volume(cost, cost_scale, inplace)
    ext = np.ascontiguousarray(extend, dtype=np.bool_) & np.isfinite(lo) & np.isfinite(hi)
    flat, _, D0, ts, tw, to = volume_layout(out, lo.shape, tubes)
    _band_kernel(flat, D0, np.ascontiguousarray(lo, np.float32), np.ascontiguousarray(hi, np.float32), ext,
                 int(d_min), float(margin), float(k * wall_scale * cost_scale), float(c), float(max_cost), ts, tw, to)
    return out


def riverbed_plus_modulate(cost, sparse, guide, d_min, window, k=10.0, c=1.0, sigma_xy=8.0, sigma_i=8.0, gamma=0.3,
                           band=3.0, form="additive", cost_scale=4, max_cost=65535, wall_scale=None, plus=None,
                           unreliable=None, share=None, inplace=False, return_support=False, tubes=None):
    """riverbed+ guidance (module docstring).

    Parameters
    ----------
    cost, sparse, guide, d_min, window, k, c, sigma_xy, sigma_i, gamma, band, form, cost_scale, max_cost, wall_scale
        As for :func:`guidance.riverbed_modulate` (``wall_scale`` default: the mean cost at the LiDAR pixels).
    plus : PlusParams
    unreliable : (H, W) bool, optional
        Pixels whose first-pass match failed the left-right check; only they are extended (all pixels if None).
    share : float, optional
        LiDAR share for ``hops="auto"`` (default: :func:`guidance.lidar_share` of ``sparse``).

    Returns
    -------
    volume : (H, W, D) uint16
    info : dict
        ``hops``, ``extended`` (share of pixels extended); with ``return_support``, ``support``: the ``(lo, hi)``
        disparity interval guidance vouches for per pixel (riverbed's band at its pixels, the extended band at the
        extended ones, NaN elsewhere).
    """
    check_volume(cost, sparse, tubes)
    q = plus or PlusParams()
    rows, cols, _ = lidar_points(sparse)
    out = scaled_volume(cost, cost_scale, inplace)
    if wall_scale is None:
        wall_scale = guidance.mean_lidar_cost(out, rows, cols, cost_scale)
    g = np.asarray(guide, dtype=np.float32)
    owners = guidance.homogeneous_owners(sparse, g, window, sigma_xy, sigma_i, gamma)
    out = guidance.riverbed_modulate(out, sparse, g, d_min, window, k, c, sigma_xy, sigma_i, gamma, band, form,
                                     cost_scale, max_cost, owners=owners, inplace=True, wall_scale=wall_scale,
                                     tubes=tubes)
    if share is None:
        share = guidance.lidar_share(sparse)
    hops = auto_hops(share) if q.hops == "auto" else int(q.hops)
    arms = cross_arms(to_u8(g), q.arm_l1, q.arm_l2, q.arm_tau1, q.arm_tau2)
    lo, hi = support_ranges(sparse, arms, hops)
    extend = owners[0] < 0
    if unreliable is not None:
        if unreliable.shape != sparse.shape:
            raise RiverbedError(f"unreliable mask {unreliable.shape} and sparse map {sparse.shape} differ in size")
        extend &= unreliable
    out = band_modulate(out, lo, hi, extend, d_min, q.margin, k, c, wall_scale, cost_scale, max_cost, inplace=True,
                        tubes=tubes)
    extended = extend & np.isfinite(lo)
    info = {"hops": hops, "extended": round(float(extended.mean()), 4)}
    if return_support:
        slo, shi = riverbed_support(sparse, owners, band)
        slo[extended] = lo[extended] - q.margin
        shi[extended] = hi[extended] + q.margin
        info["support"] = (slo, shi)
    return out, info


def riverbed_support(sparse, owners, band=3.0):
    """Riverbed's band ``[d_m - band W, d_m + band W]`` at every owned pixel (the LiDAR disparity at LiDAR pixels),
    NaN elsewhere: the disparities riverbed guidance vouches for."""
    _, _, values = lidar_points(sparse)
    owner, dissim = owners
    lo = np.full(sparse.shape, np.nan, dtype=np.float32)
    hi = np.full(sparse.shape, np.nan, dtype=np.float32)
    m = owner >= 0
    dm = values[owner[m]].astype(np.float32)
    half = np.float32(band) * dissim[m]
    lo[m] = dm - half
    hi[m] = dm + half
    return lo, hi
