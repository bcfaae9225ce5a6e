"""AD-Census stereo matching (Mei, Sun, Zhou, Jiao, Wang, Zhang 2011, "On building an accurate stereo matching system
on graphics hardware"), the second matcher riverbed's guidance is shown with.

Stages (each a function on numpy arrays; :func:`adcensus_disparity` runs them in order):

1. **Cost** (:func:`adcensus_cost`): ``C(p, d) = rho(C_census, lambda_census) + rho(C_AD, lambda_AD)`` with the robust
   ``rho(c, lambda) = 1 - exp(-c / lambda)``; ``C_AD`` is the mean over colour channels of ``|I_L(p) - I_R(p - d)|``
   (0..255 scale), ``C_census`` the Hamming distance of the census transforms (grey, default 9 x 7). The paper's cost
   is a float in ``[0, 2)``; here it is fixed point, ``round(scale * rho)`` per term (``scale = 256`` units per 1.0 of
   cost by default), in a ``uint16`` volume, so the guidance functions (``gauss_modulate`` / ``riverbed_modulate`` /
   ``diffusion_modulate``, given the volume as already scaled ``uint16``) and int16 SGM-style path kernels apply
   unchanged. A match leaving the right image gets the fixed cost ``outside`` (paper units; default 1.0, half the
   range: measured better than 0.5 because the refinement re-fills those pixels, docs/riverbed_plus.md).
2. **Cross-based support regions** (:func:`cross_arms`): from every pixel ``p`` four arms (left, right, up, down)
   extend to ``p_l`` while ``D_c(p_l, p) < tau1`` and ``D_c(p_l, p_l + r) < tau1`` (``p_l + r`` the arm's previous
   pixel), ``D_s(p_l, p) < L1``, and ``D_c(p_l, p) < tau2`` once ``D_s(p_l, p) > L2``; ``D_c`` is the largest
   absolute difference over colour channels, ``D_s`` the distance in pixels (paper: ``L1 = 34, L2 = 17, tau1 = 20,
   tau2 = 6``; arms are at most ``L1 - 1`` long). Only the left (reference) image's crosses are used.
3. **Aggregation** (:func:`cross_aggregate`): ``iterations`` (4) passes of the average over the support region; odd
   iterations (1st, 3rd) take ``U(p)`` = the horizontal segments of the pixels on ``p``'s vertical arm (sum
   horizontally, then vertically), even ones the vertical segments of the pixels on the horizontal arm. Sums are
   exact integers (orthogonal integral images); the average is ``int(sum * float32(1 / |U(p)|) + 0.5)``, in the
   volume's cost units. :func:`adcensus_aggregate` fuses stages 1 and 3: each row's cost is computed in cache and
   summed along its segments at once, and the normalising pass of one iteration runs together with the first pass
   of the next, so the cost volume is never stored and the volume is swept 5 times instead of 9.
4. **Guidance** (optional, in :mod:`pipeline`): the aggregated volume is modulated with LiDAR disparities *before*
   scanline optimisation, as the census volume is before SGM (``guide_stage="initial"`` modulates the raw cost
   before aggregation instead).
5. **Scanline optimisation** (:func:`scanline_optimize`): 4 paths (left/right/up/down) of the SGM recursion with
   penalties from colour differences along the path, ``D1 = D_c(p, p - r)`` in the left image and
   ``D2 = D_c(p - d, p - d - r)`` in the right: ``(P1, P2) = (Pi1, Pi2)`` if both are below ``tau_so``, divided by 4
   if one is, by 10 if neither (paper: ``Pi1 = 1.0, Pi2 = 3.0, tau_so = 15``; ``D2 = D1`` where the right pixels
   leave the image). The result is the *sum* of the four paths (the paper's mean times 4: same minimum, same
   sub-pixel vertex).
6. **Refinement** (:func:`refine`): left-right check (right disparities taken from the same volume,
   ``min_d S(x_r + d, d)``; outliers differing by more than ``lr_threshold``) with outliers split into *mismatches*
   (some right pixel on the epipolar line maps back to ``p``, or the match leaves the right image: *out of view*,
   nothing there to be occluded behind) and *occlusions* (none does); iterative region voting
   (5 iterations; an outlier takes the most voted reliable disparity of its support region if more than
   ``vote_ts = 20`` reliable pixels vote and the winner has more than ``vote_th = 0.4`` of the votes; updates of one
   iteration are applied together, so the result does not depend on the pixel order); proper interpolation (the
   nearest reliable pixel in each of 16 directions; occlusions take the smallest of those disparities, mismatches
   the one of the most similar colour); depth-discontinuity adjustment (on disparity edges, the left or right
   neighbour's disparity when that neighbour's own cost is lower); parabola sub-pixel fit; median filter (3 x 3).
   With guidance, a winner inside the disparity interval the guide vouches for (riverbed's band at its homogeneous
   pixels, the LiDAR disparity for Gauss, ...; ``support`` of :func:`refine`) counts as reliable: occluded pixels and
   pixels whose match leaves the right image fail the left-right check by construction, and without this rule the
   refinement overwrites exactly the disparities LiDAR fixed (measured: Cones at 5 %, AD-Census + riverbed bad3
   4.9 % without, 1.6 % with it).

Where this differs from the paper: the right disparity map comes from the left volume (``min_d S(x_r + d, d)``), not
from a second matching pass; the crosses are the left image's only (Zhang et al.'s per-disparity intersection with the
right image's crosses measured slightly better on Cones, 3.8 % vs 4.4 % non-occluded bad1, at about twice the
aggregation cost); costs are fixed point (1/256 of the paper's unit).

Conventions: the left image is the reference; ``d = x_left - x_right``; volumes are ``H x W x D`` with
``d = d_min + i`` at index ``i``; images ``H x W x C`` ``uint8`` (0..255).
"""

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from ..errors import RiverbedError
from .census import popcount64
from .sgm import _path_start

GUIDE_STAGES = ("aggregated", "initial")


@dataclass
class ADCensusParams:
    """AD-Census settings; defaults are the paper's (Mei et al. 2011, Table 1) where it gives them."""

    lambda_ad: float = 10.0
    lambda_census: float = 30.0
    scale: int = 256  # fixed-point cost units per 1.0 of the paper's cost (raw costs then lie in [0, 512])
    outside: float = 1.0  # cost (paper units) where the match leaves the right image (measured: 0.5 is too low)
    arm_l1: int = 34
    arm_l2: int = 17
    arm_tau1: int = 20
    arm_tau2: int = 6
    iterations: int = 4
    pi1: float = 1.0
    pi2: float = 3.0
    tau_so: int = 15
    lr_threshold: int = 1
    vote_iterations: int = 5
    vote_ts: int = 20
    vote_th: float = 0.4
    interpolate: bool = True
    discontinuity: bool = True
    edge_threshold: float = 5.0  # Sobel |gx| + |gy| of the disparity map above which a pixel is a disparity edge
    guide_stage: str = "aggregated"  # where guidance modulates the volume: "aggregated" (before SO) or "initial"


# ---------------------------------------------------------------------------------------------------------------
# 1. cost


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


@njit(cache=True, inline="always")
def _cost_row(left, right, cl, cr, y, d_min, ad_lut, cen_lut, outside, out):
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


@njit(cache=True, parallel=True)
def _cost_kernel(left, right, cl, cr, d_min, ad_lut, cen_lut, outside, cost):
    for y in prange(cost.shape[0]):
        _cost_row(left, right, cl, cr, y, d_min, ad_lut, cen_lut, outside, cost[y])


def _cost_inputs(left, right, census_left, census_right, d_min, d_max, lambda_ad, lambda_census, scale, outside):
    left = _u8_image(left, "left")
    right = _u8_image(right, "right")
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
    args = _cost_inputs(left, right, census_left, census_right, d_min, d_max, lambda_ad, lambda_census, scale,
                        outside)
    H, W = census_left.shape
    cost = np.empty((H, W, int(d_max) - int(d_min) + 1), dtype=np.uint16)
    _cost_kernel(*args, cost)
    return cost


def _u8_image(img, name):
    img = np.asarray(img)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.dtype != np.uint8 or img.shape[2] not in (1, 3):
        raise RiverbedError(f"{name} image must be an (H, W), (H, W, 1) or (H, W, 3) uint8 array, got {img.dtype} "
                            f"{img.shape}")
    return np.ascontiguousarray(img)


# ---------------------------------------------------------------------------------------------------------------
# 2. cross-based support regions


@njit(cache=True, inline="always")
def _colour_dist(img, y0, x0, y1, x1):
    m = 0
    for ch in range(img.shape[2]):
        v = abs(np.int32(img[y0, x0, ch]) - np.int32(img[y1, x1, ch]))
        if v > m:
            m = v
    return m


@njit(cache=True, parallel=True)
def _arms_inputs(img, tau1):
    # planar float32 channels (a grey image is repeated into all three), and the adjacency tests
    # adjh[y, x]: D_c((y, x), (y, x + 1)) < tau1, adjv[y, x]: D_c((y, x), (y + 1, x)) < tau1 (1 / 0)
    H, W, C = img.shape
    F = np.empty((3, H, W), dtype=np.float32)
    adjh = np.zeros((H, W), dtype=np.int32)
    adjv = np.zeros((H, W), dtype=np.int32)
    for y in prange(H):
        for x in range(W):
            for ch in range(3):
                F[ch, y, x] = img[y, x, ch if ch < C else 0]
        for x in range(W):
            h = np.int32(0)
            v = np.int32(0)
            for ch in range(C):
                a = np.float32(img[y, x, ch])
                if x + 1 < W:
                    h = max(h, np.int32(abs(a - np.float32(img[y, x + 1, ch]))))
                if y + 1 < H:
                    v = max(v, np.int32(abs(a - np.float32(img[y + 1, x, ch]))))
            adjh[y, x] = x + 1 < W and h < tau1
            adjv[y, x] = y + 1 < H and v < tau1
    return F, adjh, adjv


@njit(cache=True, inline="always")
def _grow(p0, p1, p2, q0, q1, q2, adj, alive, length, n, k, l2, tau1, tau2):
    # step k of n arms at once: arm j is still alive if its k-th pixel q passes D_c(q, p) < tau1, the adjacency
    # test with its predecessor, and D_c(q, p) < tau2 once k > L2. Branch-free over j (vectorises).
    near = k <= l2
    grown = np.int32(0)
    for j in range(n):
        dc = max(abs(q0[j] - p0[j]), max(abs(q1[j] - p1[j]), abs(q2[j] - p2[j])))
        ok = np.int32((dc < tau1) & (adj[j] != 0) & (near | (dc < tau2)))
        a = alive[j] & ok
        alive[j] = a
        length[j] += a
        grown |= a
    return grown


@njit(cache=True, parallel=True)
def _arms_kernel(F, adjh, adjv, l1, l2, tau1, tau2):
    # One image row at a time, all arms of one direction grow together, one step k at a time, until none grows.
    C, H, W = F.shape
    arms = np.zeros((H, W, 4), dtype=np.uint8)
    for y in prange(H):
        alive = np.empty(W, dtype=np.int32)
        length = np.empty(W, dtype=np.int32)
        p0 = F[0, y]
        p1 = F[1, y]
        p2 = F[2, y]
        # left: the arm pixel of x is x - k
        alive[:] = 1
        length[:] = 0
        for k in range(1, min(l1, W)):
            alive[k - 1] = 0
            n = W - k
            if _grow(p0[k:], p1[k:], p2[k:], p0[:n], p1[:n], p2[:n], adjh[y, :n], alive[k:], length[k:], n, k, l2,
                     tau1, tau2) == 0:
                break
        for x in range(W):
            arms[y, x, 0] = length[x]
        # right: x + k
        alive[:] = 1
        length[:] = 0
        for k in range(1, min(l1, W)):
            alive[W - k] = 0
            n = W - k
            if _grow(p0[:n], p1[:n], p2[:n], p0[k:], p1[k:], p2[k:], adjh[y, k - 1:W - 1], alive[:n], length[:n], n,
                     k, l2, tau1, tau2) == 0:
                break
        for x in range(W):
            arms[y, x, 1] = length[x]
        # up: row y - k
        alive[:] = 1
        length[:] = 0
        for k in range(1, min(l1, y + 1)):
            r = y - k
            if _grow(p0, p1, p2, F[0, r], F[1, r], F[2, r], adjv[r], alive, length, W, k, l2, tau1, tau2) == 0:
                break
        for x in range(W):
            arms[y, x, 2] = length[x]
        # down: row y + k
        alive[:] = 1
        length[:] = 0
        for k in range(1, min(l1, H - y)):
            r = y + k
            if _grow(p0, p1, p2, F[0, r], F[1, r], F[2, r], adjv[r - 1], alive, length, W, k, l2, tau1,
                     tau2) == 0:
                break
        for x in range(W):
            arms[y, x, 3] = length[x]
    return arms


def cross_arms(img, l1=34, l2=17, tau1=20, tau2=6):
    """Arm lengths of the cross-based support region of every pixel (module docstring, stage 2).

    Parameters
    ----------
    img : (H, W) or (H, W, C) uint8
        The reference (left) image.

    Returns
    -------
    (H, W, 4) uint8
        Arm lengths (pixels, not counting ``p``) to the left, right, up and down, each at most ``l1 - 1``.
    """
    img = _u8_image(img, "guide")
    if not 1 <= l1 <= 128 or not 0 <= l2 <= l1:
        raise RiverbedError(f"cross arm limits L1={l1}, L2={l2} out of range (need 0 <= L2 <= L1 <= 128)")
    F, adjh, adjv = _arms_inputs(img, np.float32(tau1))
    return _arms_kernel(F, adjh, adjv, int(l1), int(l2), np.float32(tau1), np.float32(tau2))


# ---------------------------------------------------------------------------------------------------------------
# 3. aggregation


@njit(cache=True)
def _counts_kernel(arms):
    # prefix sums of the segment lengths along columns (hv) and rows (vh)
    H, W, _ = arms.shape
    ch = np.zeros((H + 1, W), dtype=np.int32)
    cv = np.zeros((H, W + 1), dtype=np.int32)
    for y in range(H):
        for x in range(W):
            ch[y + 1, x] = ch[y, x] + np.int32(arms[y, x, 0]) + np.int32(arms[y, x, 1]) + 1
            cv[y, x + 1] = cv[y, x] + np.int32(arms[y, x, 2]) + np.int32(arms[y, x, 3]) + 1
    hv = np.empty((H, W), dtype=np.int32)
    vh = np.empty((H, W), dtype=np.int32)
    for y in range(H):
        for x in range(W):
            hv[y, x] = ch[y + np.int64(arms[y, x, 3]) + 1, x] - ch[y - np.int64(arms[y, x, 2]), x]
            vh[y, x] = cv[y, x + np.int64(arms[y, x, 1]) + 1] - cv[y, x - np.int64(arms[y, x, 0])]
    return hv, vh


def support_counts(arms):
    """Pixel counts ``|U(p)|`` of the two support regions, ``(horizontal_first, vertical_first)``, both int32: the
    sum of the horizontal segment lengths over the vertical arm, and of the vertical ones over the horizontal arm."""
    return _counts_kernel(np.ascontiguousarray(arms))


@njit(cache=True, inline="always")
def _segment_sums(pre, lo, hi, out, f, norm):
    # out[d] = pre[hi, d] - pre[lo, d], or that times f (float32 1 / |U(p)|) rounded half up when norm
    D = out.shape[0]
    pa = pre[lo]
    pb = pre[hi]
    if norm:
        half = np.float32(0.5)
        for d in range(D):
            out[d] = np.uint16(np.float32(pb[d] - pa[d]) * f + half)
    else:
        for d in range(D):
            out[d] = pb[d] - pa[d]


@njit(cache=True, inline="always")
def _prefix_step(p0, p1, sx):
    # One step of a running sum over disparity rows: p1 = p0 + sx (int32).
    for d in range(p0.shape[0]):
        p1[d] = p0[d] + np.int32(sx[d])


@njit(cache=True, inline="always")
def _prefix(rows, pre):
    # Prefix sums along the first axis: pre[0] = 0, pre[x + 1] = pre[x] + rows[x].
    for d in range(pre.shape[1]):
        pre[0, d] = 0
    for x in range(rows.shape[0]):
        _prefix_step(pre[x], pre[x + 1], rows[x])


@njit(cache=True, inline="always")
def _row_segments(pre, arms_row, out_row, inv_row, norm):
    # every pixel x of a row: the sum (or with norm, the average) over its horizontal segment, from the row's prefix
    for x in range(out_row.shape[0]):
        lo = x - np.int64(arms_row[x, 0])
        hi = x + np.int64(arms_row[x, 1]) + 1
        _segment_sums(pre, lo, hi, out_row[x], inv_row[x], norm)


@njit(cache=True, parallel=True)
def _hstage(src, arms, out, inv, first_norm, chain):
    # One horizontal stage per row, in cache: segment sums of src (normalised with inv when first_norm); when chain,
    # the raw segment sums of that result (the first pass of the next iteration, also horizontal) go to out.
    H, W, D = src.shape
    for y in prange(H):
        pre = np.empty((W + 1, D), dtype=np.int32)
        _prefix(src[y], pre)
        if chain:
            mid = np.empty((W, D), dtype=np.uint16)
            _row_segments(pre, arms[y], mid, inv[y], first_norm)
            _prefix(mid, pre)
            _row_segments(pre, arms[y], out[y], inv[y], False)
        else:
            _row_segments(pre, arms[y], out[y], inv[y], first_norm)


@njit(cache=True, parallel=True)
def _cost_hstage(left, right, cl, cr, d_min, ad_lut, cen_lut, outside, arms, out):
    # The AD-Census cost of each row, computed in cache and summed along the horizontal segments (the first pass of
    # the first aggregation iteration) without ever storing the cost volume.
    H, W, D = out.shape
    for y in prange(H):
        row = np.empty((W, D), dtype=np.uint16)
        _cost_row(left, right, cl, cr, y, d_min, ad_lut, cen_lut, outside, row)
        pre = np.empty((W + 1, D), dtype=np.int32)
        _prefix(row, pre)
        _row_segments(pre, arms[y], out[y], np.ones(W, dtype=np.float32), False)


@njit(cache=True, parallel=True)
def _vstage(src, arms, out, inv, first_norm, chain, strip):
    # The vertical counterpart of _hstage, on strips of columns (prefix sums of a strip stay in L2 cache).
    H, W, D = src.shape
    ns = (W + strip - 1) // strip
    for s in prange(ns):
        x0 = s * strip
        x1 = min(W, x0 + strip)
        sw = x1 - x0
        pre = np.empty((sw, H + 1, D), dtype=np.int32)
        mid = np.empty((sw, H, D), dtype=np.uint16)
        for j in range(sw):
            for d in range(D):
                pre[j, 0, d] = 0
        for y in range(H):
            for j in range(sw):
                _prefix_step(pre[j, y], pre[j, y + 1], src[y, x0 + j])
        for y in range(H):
            for j in range(sw):
                x = x0 + j
                lo = y - np.int64(arms[y, x, 2])
                hi = y + np.int64(arms[y, x, 3]) + 1
                if chain:
                    _segment_sums(pre[j], lo, hi, mid[j, y], inv[y, x], first_norm)
                else:
                    _segment_sums(pre[j], lo, hi, out[y, x], inv[y, x], first_norm)
        if chain:
            for j in range(sw):
                pj = pre[j]
                mj = mid[j]
                for y in range(H):
                    _prefix_step(pj[y], pj[y + 1], mj[y])
            for y in range(H):
                for j in range(sw):
                    x = x0 + j
                    lo = y - np.int64(arms[y, x, 2])
                    hi = y + np.int64(arms[y, x, 3]) + 1
                    _segment_sums(pre[j], lo, hi, out[y, x], np.float32(1.0), False)


_STRIP = 4  # columns per strip: the strip's prefix sums (H x 4 x D int32) stay in L2 cache


def cross_aggregate(cost, arms, iterations=4, counts=None, inplace=False, work=None):
    """Cross-based cost aggregation (module docstring, stage 3).

    Parameters
    ----------
    cost : (H, W, D) uint16
        Cost volume.
    arms : (H, W, 4) uint8
        :func:`cross_arms`.
    iterations : int
        Number of aggregation passes; odd ones horizontal-first, even ones vertical-first.
    counts : (hv, vh) int32, optional
        :func:`support_counts` of ``arms``.
    inplace : bool
        Write the result into ``cost`` (its values are no longer needed) to save one volume of memory.
    work : list of arrays, optional
        Up to two scratch volumes of the shape of ``cost`` to reuse (uint16, or uint32 when sums of the costs could
        exceed uint16); missing ones are allocated and appended, so the caller can reuse them afterwards.

    Returns
    -------
    (H, W, D) uint16
        ``int(sum_{q in U(p)} C(q) * float32(1 / |U(p)|) + 0.5)`` iterated; the input is left unchanged unless
        ``inplace``.

    Implementation: iteration ``k`` is a raw pass (segment sums) and a normalising pass in the other direction;
    the normalising pass of iteration ``k`` and the raw pass of ``k + 1`` run in the same direction, so they are
    fused per row / per strip of columns and the intermediate averages never make a round trip through memory
    (``iterations + 1`` sweeps over the volume instead of ``2 * iterations``).
    """
    if cost.ndim != 3 or cost.dtype != np.uint16:
        raise RiverbedError(f"cost volume must be (H, W, D) uint16, got {cost.dtype} {cost.shape}")
    if arms.shape != cost.shape[:2] + (4,):
        raise RiverbedError(f"arms {arms.shape} do not match the cost volume {cost.shape}")
    if iterations <= 0:
        return cost if inplace else cost.copy()
    if counts is None:
        inv = _inverse_counts(arms)  # odd iterations (horizontal first), even ones (vertical first)
    else:
        inv = [(np.float32(1.0) / c.astype(np.float32)).astype(np.float32) for c in counts]
    one = np.ones(arms.shape[:2], dtype=np.float32)
    seg = 2 * int(arms.max(initial=0)) + 1
    # raw segment sums stay exact in uint16 when every segment sum of a cost fits
    raw_dtype = np.uint16 if int(cost.max(initial=0)) * seg <= 65535 else np.uint32
    work = [] if work is None else work
    good = [w for w in work if w.shape == cost.shape and w.dtype == raw_dtype]
    while len(good) < (2 if iterations > 1 else 1):
        good.append(np.empty(cost.shape, dtype=raw_dtype))
        work.append(good[-1])
    a, b = good[0], (good[1] if iterations > 1 else None)
    out = cost if inplace else np.empty(cost.shape, dtype=np.uint16)
    # stage 0: raw horizontal sums of the cost; stage j: normalise iteration j, raw pass of iteration j + 1;
    # stage `iterations`: normalise the last iteration. Stages alternate horizontal / vertical.
    _hstage(cost, arms, a, one, False, False)
    return _aggregate_stages(a, b, out, arms, iterations, inv)


def _aggregate_stages(a, b, out, arms, iterations, inv):
    # stages 1 .. iterations of cross_aggregate, from the raw horizontal sums in a
    src = a
    for j in range(1, iterations + 1):
        last = j == iterations
        dst = out if last else (b if src is a else a)
        f = inv[(j - 1) % 2]
        if j % 2 == 1:
            _vstage(src, arms, dst, f, True, not last, _STRIP)
        else:
            _hstage(src, arms, dst, f, True, not last)
        src = dst
    return out


def _inverse_counts(arms):
    hv, vh = support_counts(arms)
    return [(np.float32(1.0) / hv.astype(np.float32)).astype(np.float32),
            (np.float32(1.0) / vh.astype(np.float32)).astype(np.float32)]


def adcensus_aggregate(left, right, census_left, census_right, d_min, d_max, arms, params=None, work=None):
    """AD-Census cost (:func:`adcensus_cost`) and cross-based aggregation (:func:`cross_aggregate`) in one go.

    Equal to ``cross_aggregate(adcensus_cost(...), arms, params.iterations)``, but each row's cost is computed in
    cache and summed along its horizontal segments at once: the cost volume is never stored. ``work`` as for
    :func:`cross_aggregate` (uint16 scratch volumes, reusable afterwards).

    Returns
    -------
    (H, W, D) uint16
        Aggregated cost in units of ``1 / params.scale``.
    """
    p = params or ADCensusParams()
    args = _cost_inputs(left, right, census_left, census_right, d_min, d_max, p.lambda_ad, p.lambda_census,
                        p.scale, p.outside)
    H, W = census_left.shape
    shape = (H, W, int(d_max) - int(d_min) + 1)
    if arms.shape != (H, W, 4):
        raise RiverbedError(f"arms {arms.shape} do not match the images {(H, W)}")
    seg = 2 * int(arms.max(initial=0)) + 1
    if 2 * p.scale * seg > 65535:
        raise RiverbedError(f"AD-Census scale {p.scale} too large for arms of {seg} px (segment sums overflow uint16)")
    work = [] if work is None else work
    good = [w for w in work if w.shape == shape and w.dtype == np.uint16]
    while len(good) < 2:
        good.append(np.empty(shape, dtype=np.uint16))
        work.append(good[-1])
    a, b = good[0], good[1]
    if p.iterations <= 0:
        out = np.empty(shape, dtype=np.uint16)
        _cost_kernel(*args, out)
        return out
    _cost_hstage(*args, arms, a)
    return _aggregate_stages(a, b, np.empty(shape, dtype=np.uint16), arms, p.iterations, _inverse_counts(arms))


# ---------------------------------------------------------------------------------------------------------------
# 5. scanline optimisation

_SENTINEL = 16384


@njit(cache=True, inline="always")
def _so_step(prev, cur, c, acc, p1, p2, mp):
    m = np.int16(_SENTINEL)
    for d in range(c.shape[0]):
        v = min(prev[d + 1], min(prev[d], prev[d + 2]) + p1[d])
        v = min(v, mp + p2[d])
        v = np.int16(c[d] + v - mp)
        cur[d + 1] = v
        acc[d] += v
        m = min(m, v)
    return m


_so_start = _path_start  # a path starts with its own cost, as in SGM


@njit(cache=True, inline="always")
def _row_penalties(flags, bad_l, p1tab, p2tab, P1, P2, pad):
    # P1/P2 along a reversed, padded row of right-image flags (0: colour difference < tau_so, 1: >= tau_so,
    # 2: unknown, the right pixel or its predecessor leaves the image, then D2 = D1), for a left flag bad_l.
    # Reversed, so that the D disparities of a pixel read a contiguous slice (disparity d at x reads x - d).
    W = flags.shape[0]
    for j in range(P1.shape[0]):
        xr = W - 1 - (j - pad)
        f = flags[xr] if (xr >= 0 and xr < W) else np.int8(2)
        cat = bad_l + (bad_l if f == 2 else f)
        P1[j] = p1tab[cat]
        P2[j] = p2tab[cat]


@njit(cache=True)
def _so_pass(cost, out, left, right, d_min, p1tab, p2tab, tau, flip):
    # Two of the four paths in one raster pass: forward (flip False) runs left->right and top->bottom, the reverse
    # pass right->left and bottom->top.
    H, W, D = cost.shape
    step = -1 if flip else 1
    Lh = np.full((2, D + 2), np.int16(_SENTINEL), dtype=np.int16)
    Lv = np.full((2, W, D + 2), np.int16(_SENTINEL), dtype=np.int16)
    mv = np.zeros((2, W), dtype=np.int16)
    acc = np.empty(D, dtype=np.int16)
    pad = D + abs(d_min) + 1
    n = W + 2 * pad
    # [path (0 horizontal, 1 vertical), left flag (0/1)] -> reversed padded penalty rows
    P1 = np.empty((2, 2, n), dtype=np.int16)
    P2 = np.empty((2, 2, n), dtype=np.int16)
    fh = np.empty(W, dtype=np.int8)
    fv = np.empty(W, dtype=np.int8)
    bh = np.empty(W, dtype=np.int8)
    bv = np.empty(W, dtype=np.int8)
    for yy in range(H):
        y = H - 1 - yy if flip else yy
        py = y - step
        vs = yy % 2
        vp = 1 - vs
        for x in range(W):
            qx = x - step
            if qx < 0 or qx >= W:
                fh[x] = 2
                bh[x] = 0
            else:
                fh[x] = 1 if _colour_dist(right, y, x, y, qx) >= tau else 0
                bh[x] = 1 if _colour_dist(left, y, x, y, qx) >= tau else 0
            if yy == 0:
                fv[x] = 2
                bv[x] = 0
            else:
                fv[x] = 1 if _colour_dist(right, y, x, py, x) >= tau else 0
                bv[x] = 1 if _colour_dist(left, y, x, py, x) >= tau else 0
        for b in range(2):
            _row_penalties(fh, b, p1tab, p2tab, P1[0, b], P2[0, b], pad)
            _row_penalties(fv, b, p1tab, p2tab, P1[1, b], P2[1, b], pad)
        hs = 0
        mh = np.int16(0)
        for xx in range(W):
            x = W - 1 - xx if flip else xx
            c = cost[y, x]
            j0 = W - 1 - (x - d_min) + pad  # reversed index of x_r = x - d_min (disparity index 0)
            acc[:] = 0
            if xx == 0:
                mh = _so_start(Lh[hs], c, acc)
            else:
                b = bh[x]
                mh = _so_step(Lh[1 - hs], Lh[hs], c, acc, P1[0, b, j0:j0 + D], P2[0, b, j0:j0 + D], mh)
            hs = 1 - hs
            if yy == 0:
                mv[vs, x] = _so_start(Lv[vs, x], c, acc)
            else:
                b = bv[x]
                mv[vs, x] = _so_step(Lv[vp, x], Lv[vs, x], c, acc, P1[1, b, j0:j0 + D], P2[1, b, j0:j0 + D],
                                     mv[vp, x])
            o = out[y, x]
            for d in range(D):
                o[d] = np.uint16(acc[d])


@njit(cache=True, parallel=True)
def _so_two_passes(cost, fwd, bwd, left, right, d_min, p1tab, p2tab, tau):
    for t in prange(2):
        if t == 0:
            _so_pass(cost, fwd, left, right, d_min, p1tab, p2tab, tau, False)
        else:
            _so_pass(cost, bwd, left, right, d_min, p1tab, p2tab, tau, True)


def so_penalties(pi1, pi2, scale):
    """``(P1, P2)`` tables (int16) indexed by the number of colour differences ``>= tau_so`` (0, 1 or 2)."""
    p1 = np.array([round(scale * pi1), round(scale * pi1 / 4), round(scale * pi1 / 10)], dtype=np.int16)
    p2 = np.array([round(scale * pi2), round(scale * pi2 / 4), round(scale * pi2 / 10)], dtype=np.int16)
    return p1, p2


def scanline_optimize(cost, left, right, d_min, pi1=1.0, pi2=3.0, tau_so=15, scale=256, max_cost=None, out=None):
    """Scanline optimisation over 4 paths (module docstring, stage 5).

    Parameters
    ----------
    cost : (H, W, D) uint16
        Aggregated (possibly guided) cost in units of ``1 / scale``.
    left, right : (H, W, C) uint8
        The images (colour differences along the paths).
    pi1, pi2 : float
        Penalties in the paper's cost units (``P = round(scale * pi / {1, 4, 10})``).
    out : (fwd, bwd), optional
        Two uint16 volumes of the shape of ``cost`` to write into (e.g. the aggregation's scratch volumes).

    Returns
    -------
    (fwd, bwd) : two (H, W, D) uint16
        Sums of the left->right + top->bottom paths and of the right->left + bottom->top paths; their sum is the
        optimised cost.
    """
    left = _u8_image(left, "left")
    right = _u8_image(right, "right")
    if cost.ndim != 3 or cost.dtype not in (np.uint8, np.uint16) or cost.shape[:2] != left.shape[:2]:
        raise RiverbedError(f"cost volume must be uint8/uint16 (H, W, D) of the image size, got {cost.shape}")
    p1, p2 = so_penalties(pi1, pi2, scale)
    if not 0 <= p1[0] <= p2[0]:
        raise RiverbedError(f"scanline penalties need 0 <= Pi1 <= Pi2 (got {pi1}, {pi2})")
    if max_cost is None:
        max_cost = int(cost.max(initial=0))
    if int(max_cost) + int(p2[0]) >= _SENTINEL:
        raise RiverbedError(f"scanline optimisation: max cost {max_cost} + P2 {p2[0]} does not fit int16 paths")
    cost = np.ascontiguousarray(cost)
    if out is not None and all(o.shape == cost.shape and o.dtype == np.uint16 and o is not cost for o in out):
        fwd, bwd = out
    else:
        fwd = np.empty(cost.shape, dtype=np.uint16)
        bwd = np.empty(cost.shape, dtype=np.uint16)
    _so_two_passes(cost, fwd, bwd, left, right, int(d_min), p1, p2, int(tau_so))
    return fwd, bwd


# ---------------------------------------------------------------------------------------------------------------
# 6. selection and refinement


@njit(cache=True, parallel=True)
def _wta_lr_kernel(fwd, bwd, d_min, lr_threshold):
    # Winner index of the left image, and status: 0 reliable, 1 mismatch, 2 occlusion.
    H, W, D = fwd.shape
    best = np.empty((H, W), dtype=np.int32)
    status = np.zeros((H, W), dtype=np.int8)
    pad = D + abs(d_min) + 1
    n = W + 2 * pad
    for y in prange(H):
        s = np.empty(D, dtype=np.int32)
        # right-image winner min_i S(x_r + d_min + i, i), kept reversed and padded (x_r at W - 1 - x_r + pad), so
        # the disparities of one left pixel update a contiguous slice; strict < keeps the smallest i on ties.
        rcost = np.full(n, 2147483647, dtype=np.int32)
        rbest = np.full(n, -1, dtype=np.int32)
        fy = fwd[y]
        by = bwd[y]
        for x in range(W):
            fx = fy[x]
            bx = by[x]
            bv = np.int32(2147483647)
            for i in range(D):
                v = np.int32(fx[i]) + np.int32(bx[i])
                s[i] = v
                bv = min(bv, v)
            bi = 0
            while s[bi] != bv:
                bi += 1
            best[y, x] = bi
            j0 = W - 1 - (x - d_min) + pad
            rc = rcost[j0:j0 + D]
            rb = rbest[j0:j0 + D]
            for i in range(D):
                v = s[i]
                o = rc[i]
                better = v < o
                rc[i] = v if better else o
                rb[i] = np.int32(i) if better else rb[i]
        # back[x]: some right pixel's winner maps back to left pixel x (the epipolar line meets D_R)
        back = np.zeros(W, dtype=np.bool_)
        for xr in range(W):
            rbv = rbest[W - 1 - xr + pad]
            if rbv >= 0:
                back[xr + d_min + rbv] = True
        for x in range(W):
            bi = best[y, x]
            xr = x - (d_min + bi)
            if xr < 0 or xr >= W:
                # out of view: no right pixel to be occluded behind; filled like a mismatch (by colour), not with
                # the smallest neighbouring disparity (measured: AD-Census dev bad3 7.99 -> 7.17 %)
                status[y, x] = 1
            elif abs(bi - rbest[W - 1 - xr + pad]) > lr_threshold:
                status[y, x] = 1 if back[x] else 2
    return best, status


@njit(cache=True, inline="always")
def _vote_row(hist, votes, arms, yy, x, sign):
    # add (sign 1) or remove (sign -1) the votes of row yy's horizontal segment through column x
    row = votes[yy, x - np.int64(arms[yy, x, 0]):x + np.int64(arms[yy, x, 1]) + 1]
    for k in range(row.shape[0]):
        hist[row[k]] += sign


@njit(cache=True)
def _vote_column(votes, arms, D, ts, th, new_votes, x, hist):
    # Region voting down column x (Jacobi: every outlier votes with the reliable pixels of the iteration's start).
    # The support region of (y, x) is the union of the horizontal segments of the rows of its vertical arm, so
    # walking down the column the histogram is updated by the rows entering and leaving the arm instead of being
    # rebuilt for every outlier. votes = winner + 1 at reliable pixels, 0 at outliers (bin 0 collects them).
    H = votes.shape[0]
    hist[:] = 0
    changed = 0
    a = 0
    b = -1  # rows a..b are in the histogram (empty when b < a)
    for y in range(H):
        new_votes[y, x] = votes[y, x]
        if votes[y, x] != 0:
            continue
        na = y - np.int64(arms[y, x, 2])
        nb = y + np.int64(arms[y, x, 3])
        if b < a or na > b or nb < a:
            for yy in range(a, b + 1):
                _vote_row(hist, votes, arms, yy, x, -1)
            for yy in range(na, nb + 1):
                _vote_row(hist, votes, arms, yy, x, 1)
        else:
            for yy in range(na, a):
                _vote_row(hist, votes, arms, yy, x, 1)
            for yy in range(a, na):
                _vote_row(hist, votes, arms, yy, x, -1)
            for yy in range(b + 1, nb + 1):
                _vote_row(hist, votes, arms, yy, x, 1)
            for yy in range(nb + 1, b + 1):
                _vote_row(hist, votes, arms, yy, x, -1)
        a = na
        b = nb
        n = 0
        bi = 0
        bc = 0
        for i in range(1, D + 1):
            h = hist[i]
            n += h
            if h > bc:
                bc = h
                bi = i
        if n > ts and bc > th * n:
            new_votes[y, x] = bi
            changed += 1
    return changed


@njit(cache=True, parallel=True)
def _vote_kernel(votes, arms, D, ts, th, new_votes):
    W = votes.shape[1]
    changed = np.zeros(W, dtype=np.int64)
    for x in prange(W):
        changed[x] = _vote_column(votes, arms, D, ts, th, new_votes, x, np.empty(D + 1, dtype=np.int32))
    return changed.sum()


@njit(cache=True)
def _vote_kernel_serial(votes, arms, D, ts, th, new_votes):
    hist = np.empty(D + 1, dtype=np.int32)
    changed = 0
    for x in range(votes.shape[1]):
        changed += _vote_column(votes, arms, D, ts, th, new_votes, x, hist)
    return changed


def region_voting(best, status, arms, D, iterations=5, ts=20, th=0.4):
    """Iterative region voting (stage 6); returns new ``(best, status)`` (outliers that won a vote become 0)."""
    votes = np.where(status == 0, best + 1, 0).astype(np.int32)
    spare = np.empty_like(votes)
    for it in range(int(iterations)):
        # later iterations see few outliers: run them on one thread (no parallel region to synchronise)
        kernel = _vote_kernel if it == 0 else _vote_kernel_serial
        changed = kernel(votes, arms, int(D), int(ts), float(th), spare)
        votes, spare = spare, votes
        if changed == 0:
            break
    won = (status > 0) & (votes > 0)
    best = np.where(won, votes - 1, best).astype(best.dtype)
    status = np.where(won, np.int8(0), status).astype(status.dtype)
    return best, status


_ANGLES = np.arange(16) * (np.pi / 8)
_DIR_COS = np.cos(_ANGLES)
_DIR_SIN = np.sin(_ANGLES)


@njit(cache=True, parallel=True)
def _interp_kernel(best, status, img, reach, dcos, dsin):
    H, W = best.shape
    out = best.copy()
    for y in prange(H):
        for x in range(W):
            st = status[y, x]
            if st == 0:
                continue
            found = -1
            score = 1 << 30
            for k in range(16):
                for m in range(1, reach + 1):
                    yy = y + np.int64(math.floor(m * dsin[k] + 0.5))
                    xx = x + np.int64(math.floor(m * dcos[k] + 0.5))
                    if yy < 0 or yy >= H or xx < 0 or xx >= W:
                        break
                    if status[yy, xx] == 0:
                        b = best[yy, xx]
                        if st == 2:
                            sc = b  # occlusion: the smallest disparity (background)
                        else:
                            sc = 0  # mismatch: the most similar colour
                            for ch in range(img.shape[2]):
                                sc += abs(np.int32(img[y, x, ch]) - np.int32(img[yy, xx, ch]))
                        if sc < score:
                            score = sc
                            found = b
                        break
            if found >= 0:
                out[y, x] = found
    return out


@njit(cache=True, inline="always")
def _adjusted(best, fwd, bwd, y, x, threshold):
    # Depth-discontinuity adjustment at (y, x): on a disparity edge (Sobel |gx| + |gy| > threshold), the left or
    # right neighbour's disparity when that neighbour's own optimised cost is lower.
    H, W = best.shape
    b = best[y, x]
    if y == 0 or y == H - 1 or x == 0 or x == W - 1:
        return b
    gx = (best[y - 1, x + 1] - best[y - 1, x - 1]) + 2 * (best[y, x + 1] - best[y, x - 1]) + \
         (best[y + 1, x + 1] - best[y + 1, x - 1])
    gy = (best[y + 1, x - 1] - best[y - 1, x - 1]) + 2 * (best[y + 1, x] - best[y - 1, x]) + \
         (best[y + 1, x + 1] - best[y - 1, x + 1])
    if abs(gx) + abs(gy) <= threshold:
        return b
    out = b
    c0 = np.int32(fwd[y, x, b]) + np.int32(bwd[y, x, b])
    for xn in (x - 1, x + 1):
        bn = best[y, xn]
        cn = np.int32(fwd[y, xn, bn]) + np.int32(bwd[y, xn, bn])
        if cn < c0:
            c0 = cn
            out = bn
    return out


@njit(cache=True, parallel=True)
def _final_kernel(best, fwd, bwd, d_min, adjust, threshold, subpixel):
    # discontinuity adjustment (optional) and parabola sub-pixel fit on the optimised cost, in one pass
    H, W = best.shape
    D = fwd.shape[2]
    disp = np.empty((H, W), dtype=np.float32)
    for y in prange(H):
        for x in range(W):
            b = _adjusted(best, fwd, bwd, y, x, threshold) if adjust else best[y, x]
            val = np.float32(d_min + b)
            if subpixel and b > 0 and b < D - 1:
                a = np.int32(fwd[y, x, b - 1]) + np.int32(bwd[y, x, b - 1])
                m = np.int32(fwd[y, x, b]) + np.int32(bwd[y, x, b])
                c = np.int32(fwd[y, x, b + 1]) + np.int32(bwd[y, x, b + 1])
                den = a - 2 * m + c
                if den > 0 and m <= a and m <= c:
                    val += np.float32(0.5 * (a - c) / den)
            disp[y, x] = val
    return disp


def refine(fwd, bwd, d_min, img, arms, params=None, subpixel=True, return_status=False, support=None):
    """Multi-step refinement (module docstring, stage 6) of the optimised cost ``fwd + bwd``.

    ``support`` (optional ``(lo, hi)`` float maps, NaN where none) is the disparity interval that LiDAR guidance
    vouches for at each pixel; a winner within it (``+- lr_threshold``) counts as reliable even when the left-right
    check fails -- occluded pixels and pixels whose match leaves the right image fail that check by construction,
    and guidance is the only evidence they have.

    Returns
    -------
    disparity : (H, W) float32
        Dense, before the median filter (an outlier with no reliable pixel in any of the 16 directions keeps its
        winner-takes-all disparity; with ``interpolate=False`` the outliers left after voting do too).
    info : dict
        Pixel counts: ``outliers`` (left-right check), ``occlusions`` (among them), ``after_voting``; with
        ``return_status`` also ``status``, the (H, W) int8 left-right outcome (0 consistent, 1 mismatch, 2 occlusion).
    """
    import time

    p = params or ADCensusParams()
    D = fwd.shape[2]
    t = {}
    t0 = time.perf_counter()
    best, status = _wta_lr_kernel(fwd, bwd, int(d_min), int(p.lr_threshold))
    info = {"outliers": int((status > 0).sum()), "occlusions": int((status == 2).sum())}
    if support is not None:
        lo, hi = support
        d = best + int(d_min)
        with np.errstate(invalid="ignore"):
            vouched = (status > 0) & (d >= lo - p.lr_threshold) & (d <= hi + p.lr_threshold)
        status[vouched] = 0
        info["vouched"] = int(vouched.sum())
    t["left_right"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if return_status:
        info["status"] = status.copy()
    if p.vote_iterations > 0:
        best, status = region_voting(best, status, arms, D, p.vote_iterations, p.vote_ts, p.vote_th)
    info["after_voting"] = int((status > 0).sum())
    t["voting"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if p.interpolate:
        best = _interp_kernel(best, status, _u8_image(img, "left"), max(best.shape), _DIR_COS, _DIR_SIN)
    disp = _final_kernel(best, fwd, bwd, int(d_min), bool(p.discontinuity), float(p.edge_threshold), bool(subpixel))
    t["interpolation_subpixel"] = time.perf_counter() - t0
    info["seconds"] = {k: round(v, 4) for k, v in t.items()}
    return disp, info


# ---------------------------------------------------------------------------------------------------------------
# all stages


def to_u8(guide):
    """A float 0..255 image (:func:`io.images.to_guide`) rounded to ``uint8`` ``H x W x C`` for AD and crosses."""
    return np.ascontiguousarray(np.clip(np.floor(np.asarray(guide, np.float32) + np.float32(0.5)), 0, 255)
                                .astype(np.uint8))


def adcensus_disparity(left, right, d_min, d_max, params=None, census_window=(9, 7), grey=None, modulate=None,
                       subpixel=True, median=3, timings=None, return_status=False):
    """AD-Census disparity of a rectified pair (all stages, module docstring).

    Parameters
    ----------
    left, right : (H, W) or (H, W, C) uint8
        Images on a 0..255 scale (:func:`to_u8` of :func:`io.images.to_guide`).
    d_min, d_max : int
        Inclusive disparity range.
    params : ADCensusParams
    census_window : (int, int)
        Census window (width, height).
    grey : (left_grey, right_grey), optional
        Float grey images for the census transform (default: the channel mean of ``left`` / ``right``).
    modulate : callable, optional
        ``modulate(volume, max_cost) -> (volume, max_cost, support)``: guidance of the uint16 volume (cost units
        ``1 / params.scale``), called after cross aggregation (``guide_stage="aggregated"``, before scanline
        optimisation) or on the raw cost (``"initial"``); ``support`` is None or the ``(lo, hi)`` disparity
        interval the guidance vouches for per pixel (:func:`refine`).
    subpixel : bool
        Parabola sub-pixel fit. ``median``: median filter size (1: off).
    timings : dict, optional
        Filled with seconds per stage (cost, aggregation, guidance, optimisation, refinement).
    return_status : bool
        Add the left-right outcome map to ``info`` (:func:`refine`).

    Returns
    -------
    disparity : (H, W) float32
    info : dict
        Refinement counts (:func:`refine`).
    """
    import time

    from . import census
    from .disparity import median_filter

    p = params or ADCensusParams()
    if p.guide_stage not in GUIDE_STAGES:
        raise RiverbedError(f"unknown guide stage '{p.guide_stage}' (use {' or '.join(GUIDE_STAGES)})")
    timings = {} if timings is None else timings
    left = _u8_image(left, "left")
    right = _u8_image(right, "right")
    if left.shape != right.shape:
        raise RiverbedError(f"left and right images differ in shape: {left.shape} vs {right.shape}")
    t0 = time.perf_counter()
    if grey is None:
        grey = (left.mean(axis=2, dtype=np.float32), right.mean(axis=2, dtype=np.float32))
    cl = census.census_transform(grey[0], census_window)
    cr = census.census_transform(grey[1], census_window)
    max_cost = 2 * p.scale
    arms = cross_arms(left, p.arm_l1, p.arm_l2, p.arm_tau1, p.arm_tau2)
    timings["cost"] = time.perf_counter() - t0  # census transforms and crosses (the cost is fused below)

    support = None

    def guide(vol, max_cost):
        nonlocal support
        t = time.perf_counter()
        if modulate is not None:
            vol, max_cost, support = modulate(vol, max_cost)
        timings["guidance"] = time.perf_counter() - t
        return vol, max_cost

    work = []
    t0 = time.perf_counter()
    if p.guide_stage == "initial":
        cost = adcensus_cost(left, right, cl, cr, d_min, d_max, p.lambda_ad, p.lambda_census, p.scale, p.outside)
        timings["cost"] += time.perf_counter() - t0
        cost, max_cost = guide(cost, max_cost)
        t0 = time.perf_counter()
        agg = cross_aggregate(cost, arms, p.iterations, inplace=True, work=work)
    else:
        agg = adcensus_aggregate(left, right, cl, cr, d_min, d_max, arms, p, work)
    del cl, cr
    timings["aggregation"] = time.perf_counter() - t0
    if p.guide_stage == "aggregated":
        agg, max_cost = guide(agg, max_cost)
    t0 = time.perf_counter()
    scratch = [w for w in work if w.dtype == np.uint16]
    fwd, bwd = scanline_optimize(agg, left, right, d_min, p.pi1, p.pi2, p.tau_so, p.scale, max_cost,
                                 out=scratch[:2] if len(scratch) >= 2 else None)
    del agg, work, scratch
    timings["optimisation"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    disp, info = refine(fwd, bwd, d_min, left, arms, p, subpixel, return_status, support)
    del fwd, bwd
    disp = median_filter(disp, median)
    timings["refinement"] = time.perf_counter() - t0
    return disp, info
