"""riverbed+ (work in progress): riverbed plus guidance over cross-based support regions."""

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from . import guidance
from .adcensus import cross_arms, to_u8
from .guidance import _scaled, lidar_points


@dataclass
class PlusParams:
    arm_l1: int = 34
    arm_l2: int = 17
    arm_tau1: int = 20
    arm_tau2: int = 6
    margin: float = 1.0
    k: float = 10.0
    c: float = 1.0
    inside: float = 1.0
    min_points: int = 1
    only_unowned: bool = True
    base: bool = True
    hops: int = 1
    slope: float = 0.0
    confidence: str = "none"
    dilate: int = 0
    check_slope: float = -1.0
    check_margin: float = 3.0
    blur: float = 0.0


@njit(cache=True, parallel=True)
def _region_ranges(arms, sparse, row_ptr, pt_cols, pt_vals):
    # For every pixel, min / max / count of the LiDAR disparities inside its H-V cross support region.
    H, W, _ = arms.shape
    lo = np.full((H, W), np.inf, dtype=np.float32)
    hi = np.full((H, W), -np.inf, dtype=np.float32)
    cnt = np.zeros((H, W), dtype=np.int32)
    for y in prange(H):
        for x in range(W):
            a = np.inf
            b = -np.inf
            n = 0
            for yy in range(y - np.int64(arms[y, x, 2]), y + np.int64(arms[y, x, 3]) + 1):
                x0 = x - np.int64(arms[yy, x, 0])
                x1 = x + np.int64(arms[yy, x, 1])
                s = row_ptr[yy]
                e = row_ptr[yy + 1]
                j = s + np.searchsorted(pt_cols[s:e], x0)
                while j < e and pt_cols[j] <= x1:
                    v = pt_vals[j]
                    a = min(a, v)
                    b = max(b, v)
                    n += 1
                    j += 1
            lo[y, x] = a
            hi[y, x] = b
            cnt[y, x] = n
    return lo, hi, cnt


@njit(cache=True, parallel=True)
def _seg_minmax(lo, hi, arms, vertical, slope):
    H, W = lo.shape
    olo = np.empty_like(lo)
    ohi = np.empty_like(hi)
    for y in prange(H):
        for x in range(W):
            a = np.inf
            b = -np.inf
            if vertical:
                for yy in range(y - np.int64(arms[y, x, 2]), y + np.int64(arms[y, x, 3]) + 1):
                    g = slope * abs(yy - y)
                    a = min(a, lo[yy, x] - g)
                    b = max(b, hi[yy, x] + g)
            else:
                for xx in range(x - np.int64(arms[y, x, 0]), x + np.int64(arms[y, x, 1]) + 1):
                    g = slope * abs(xx - x)
                    a = min(a, lo[y, xx] - g)
                    b = max(b, hi[y, xx] + g)
            olo[y, x] = a
            ohi[y, x] = b
    return olo, ohi


def region_ranges(sparse, arms, hops=1, slope=0.0):
    lo = np.where(np.isfinite(sparse), sparse, np.inf).astype(np.float32)
    hi = np.where(np.isfinite(sparse), sparse, -np.inf).astype(np.float32)
    for it in range(hops):
        lo, hi = _seg_minmax(lo, hi, arms, it % 2 == 1, float(slope))
        lo, hi = _seg_minmax(lo, hi, arms, it % 2 == 0, float(slope))
    return lo, hi


@njit(cache=True, parallel=True)
def _plus_kernel(cost, lo, hi, cnt, skip, d_min, margin, kf, c, inside, min_points, cap):
    H, W, D = cost.shape
    inv2c2 = 1.0 / (2.0 * c * c)
    for y in prange(H):
        for x in range(W):
            if cnt[y, x] < min_points or skip[y, x]:
                continue
            a = lo[y, x] - margin
            b = hi[y, x] + margin
            cy = cost[y, x]
            for i in range(D):
                d = d_min + i
                t = max(a - d, d - b, 0.0)
                g = 1.0 - math.exp(-t * t * inv2c2)
                cy[i] = np.uint16(min(inside * cy[i] + kf * g + 0.5, cap))


def riverbed_plus_modulate(cost, sparse, guide, d_min, window, p, cost_scale, cap, fbar=None, inplace=False, mask=None, first=None):
    q = p.plus or PlusParams()
    rows, cols, values = lidar_points(sparse)
    out = _scaled(cost, cost_scale, inplace)
    if fbar is None:
        fbar = float(out[rows, cols].mean()) / cost_scale if rows.size else 0.0
    skip = np.zeros(sparse.shape, dtype=np.bool_)
    if q.base:
        owners = guidance.homogeneous_owners(sparse, guide, window, p.sigma_xy, p.sigma_i, p.gamma)
        if q.only_unowned:
            skip = owners[0] >= 0
        out = guidance.riverbed_modulate(out, sparse, guide, d_min, window, p.k, p.c, p.sigma_xy, p.sigma_i, p.gamma,
                                         p.band, p.form, cost_scale, cap, owners=owners, inplace=True, fbar=fbar)
    g8 = to_u8(guide)
    if q.blur > 0:
        import cv2
        g8 = cv2.GaussianBlur(g8, (0, 0), q.blur)
        if g8.ndim == 2:
            g8 = g8[:, :, None]
    arms = cross_arms(g8, q.arm_l1, q.arm_l2, q.arm_tau1, q.arm_tau2)
    H, W = sparse.shape
    row_ptr = np.zeros(H + 1, dtype=np.int64)
    np.add.at(row_ptr, rows + 1, 1)
    row_ptr = np.cumsum(row_ptr)
    if q.hops == 1 and q.min_points > 1:
        lo, hi, cnt = _region_ranges(arms, sparse, row_ptr, cols.astype(np.int64), values.astype(np.float32))
    else:
        lo, hi = region_ranges(sparse, arms, q.hops, q.slope)
        cnt = np.isfinite(lo).astype(np.int32)
    if first is not None:
        m = ~np.isfinite(first)
        if q.check_slope >= 0:
            wl, wh = region_ranges(sparse, arms, q.hops, q.check_slope)
            with np.errstate(invalid="ignore"):
                m |= np.isfinite(wl) & ((first < wl - q.check_margin) | (first > wh + q.check_margin))
        mask = m
    if mask is not None:
        skip = skip | ~mask
    _plus_kernel(out, lo, hi, cnt, skip, int(d_min), float(q.margin), float(q.k * fbar * cost_scale), float(q.c),
                 float(q.inside), int(q.min_points), float(cap))
    return out
