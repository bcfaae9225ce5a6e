"""Ray casting on the scene's bilinear height field (Numba kernels): closed-form ray/patch intersection, the
two-level grid traversal (blocks, then cells), bilinear height lookup; :func:`cast_rays` and
:func:`surface_height` on a :class:`~riverbed_cli.sample.scene.Scene`."""

import math

import numpy as np
from numba import prange

from ..runtime.kernel import kernel


@kernel
def _first_line(o, d, t, g0, size):
    """Index ``k`` of the first grid line ``g0 + k * size`` a ray ``o + t d`` (1-D, ``d != 0``) meets after ``t``."""
    k = float(math.floor((o + t * d - g0) / size))
    if d > 0.0:
        k += 1.0
    return k, (g0 + k * size - o) / d


@kernel
def _patch_root(pu, pv, pz, du, dv, dz, L, h00, h10, h01, h11, cell):
    """First ``s`` in ``[0, L]`` where the ray ``p + s d`` meets the bilinear patch of one cell, or -1.

    ``pu, pv`` are relative to the cell's lower corner; the patch is ``h00 (1-a)(1-b) + h10 a (1-b) + h01 (1-a) b
    + h11 a b`` with ``a = u / cell``, ``b = v / cell``. Along the ray, height above the patch is a quadratic in
    ``s``; its smallest root in range is refined by one Newton step.
    """
    uu = pu / cell
    vv = pv / cell
    ut = du / cell
    vt = dv / cell
    b = h10 - h00
    c = h01 - h00
    e = h00 - h10 - h01 + h11
    s0 = h00 + b * uu + c * vv + e * uu * vv
    s1 = b * ut + c * vt + e * (uu * vt + vv * ut)
    s2 = e * ut * vt
    C = pz - s0
    B = dz - s1
    A = -s2
    if C <= 0.0:
        return 0.0
    gL = (A * L + B) * L + C
    root = -1.0
    tol = 1e-12 * (L + 1.0)
    if abs(A) * L * L <= 1e-14 * (abs(B) * L + abs(C)):
        if B < 0.0:
            s = -C / B
            if s <= L + tol:
                root = min(s, L)
    else:
        disc = B * B - 4.0 * A * C
        if disc >= 0.0:
            sq = math.sqrt(disc)
            q = -0.5 * (B + sq) if B >= 0.0 else -0.5 * (B - sq)
            r1 = q / A
            r2 = C / q if q != 0.0 else np.inf
            lo = min(r1, r2)
            hi = max(r1, r2)
            if -tol <= lo <= L + tol:
                root = min(max(lo, 0.0), L)
            elif -tol <= hi <= L + tol:
                root = min(max(hi, 0.0), L)
    if root < 0.0:
        if gL > 0.0:
            return -1.0
        # The quadratic says no root but the end is below: rounding; bisect.
        a, z = 0.0, L
        for _ in range(60):
            m = 0.5 * (a + z)
            if (A * m + B) * m + C > 0.0:
                a = m
            else:
                z = m
        return z
    g = (A * root + B) * root + C
    dg = 2.0 * A * root + B
    if dg != 0.0:
        s = root - g / dg
        if 0.0 <= s <= L:
            root = s
    return root


@kernel(inline=True)
def _traversal_start(ou, ov, du, dv, t, u0, v0, size):
    # Grid traversal set-up (cells of ``size``): per axis the next grid line, the ray parameter there and the step.
    ku, tu, su = 0.0, np.inf, 0.0
    kv, tv, sv = 0.0, np.inf, 0.0
    if du != 0.0:
        ku, tu = _first_line(ou, du, t, u0, size)
        su = 1.0 if du > 0.0 else -1.0
    if dv != 0.0:
        kv, tv = _first_line(ov, dv, t, v0, size)
        sv = 1.0 if dv > 0.0 else -1.0
    return ku, tu, su, kv, tv, sv


@kernel
def _cast_cells(ou, ov, oz, du, dv, dz, ta, tb, hgt, u0, v0, cell):
    """First hit in ``[ta, tb]`` by a cell-by-cell traversal, or -1."""
    nv, nu = hgt.shape
    t = ta
    ku, tu, su, kv, tv, sv = _traversal_start(ou, ov, du, dv, t, u0, v0, cell)
    while t < tb:
        tn = min(tu, tv, tb)
        if tn > t:
            tm = 0.5 * (t + tn)
            i = math.floor((ou + tm * du - u0) / cell)
            j = math.floor((ov + tm * dv - v0) / cell)
            i = min(max(i, 0), nu - 2)
            j = min(max(j, 0), nv - 2)
            h00 = float(hgt[j, i])
            h10 = float(hgt[j, i + 1])
            h01 = float(hgt[j + 1, i])
            h11 = float(hgt[j + 1, i + 1])
            za = oz + t * dz
            zb = oz + tn * dz
            if min(za, zb) <= max(max(h00, h10), max(h01, h11)):
                s = _patch_root(ou + t * du - (u0 + i * cell), ov + t * dv - (v0 + j * cell), za, du, dv, dz,
                                tn - t, h00, h10, h01, h11, cell)
                if s >= 0.0:
                    return t + s
            t = tn
        if tu <= tn:
            ku += su
            tu = (u0 + ku * cell - ou) / du
        if tv <= tn:
            kv += sv
            tv = (v0 + kv * cell - ov) / dv
    return -1.0


@kernel
def first_hit(ou, ov, oz, du, dv, dz, tmin, tmax, hgt, bmax, u0, v0, cell, bs, zlo, zhi):
    """Smallest ``t`` in ``[tmin, tmax]`` where the ray ``o + t d`` (grid frame) meets the surface, or -1.

    Clips the ray to the grid and to the height slab ``[zlo, zhi]``, then walks blocks of ``bs x bs`` cells,
    skipping those whose maximum height ``bmax`` lies below the ray, and walks the cells of the others.
    """
    nv, nu = hgt.shape
    u1 = u0 + (nu - 1) * cell
    v1 = v0 + (nv - 1) * cell
    t0, t1 = tmin, tmax
    if du != 0.0:
        a, b = (u0 - ou) / du, (u1 - ou) / du
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    elif ou < u0 or ou > u1:
        return -1.0
    if dv != 0.0:
        a, b = (v0 - ov) / dv, (v1 - ov) / dv
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    elif ov < v0 or ov > v1:
        return -1.0
    if dz != 0.0:
        a, b = (zlo - oz) / dz, (zhi - oz) / dz
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    elif oz > zhi:
        return -1.0
    if not t0 < t1:
        return -1.0
    bsz = cell * bs
    nbv, nbu = bmax.shape
    t = t0
    ku, tu, su, kv, tv, sv = _traversal_start(ou, ov, du, dv, t, u0, v0, bsz)
    while t < t1:
        tn = min(tu, tv, t1)
        if tn > t:
            tm = 0.5 * (t + tn)
            bu = min(max(math.floor((ou + tm * du - u0) / bsz), 0), nbu - 1)
            bv = min(max(math.floor((ov + tm * dv - v0) / bsz), 0), nbv - 1)
            if min(oz + t * dz, oz + tn * dz) <= bmax[bv, bu]:
                r = _cast_cells(ou, ov, oz, du, dv, dz, t, tn, hgt, u0, v0, cell)
                if r >= 0.0:
                    return r
            t = tn
        if tu <= tn:
            ku += su
            tu = (u0 + ku * bsz - ou) / du
        if tv <= tn:
            kv += sv
            tv = (v0 + kv * bsz - ov) / dv
    return -1.0


@kernel
def locate(pu, pv, nu, nv, u0, v0, cell):
    """Cell ``(i, j)`` containing a grid-frame point and the point's fractional position ``(a, b)`` in it."""
    fu = (pu - u0) / cell
    fv = (pv - v0) / cell
    i = min(max(math.floor(fu), 0), nu - 2)
    j = min(max(math.floor(fv), 0), nv - 2)
    return i, j, fu - i, fv - j


@kernel
def bilinear(arr, i, j, a, b):
    return ((1.0 - a) * (1.0 - b) * float(arr[j, i]) + a * (1.0 - b) * float(arr[j, i + 1])
            + (1.0 - a) * b * float(arr[j + 1, i]) + a * b * float(arr[j + 1, i + 1]))


@kernel(parallel=True)
def _heights_kernel(x, y, cr, sr, hgt, u0, v0, cell, out):
    nv, nu = hgt.shape
    for n in prange(x.shape[0]):
        pu = cr * x[n] + sr * y[n]
        pv = -sr * x[n] + cr * y[n]
        fu = (pu - u0) / cell
        fv = (pv - v0) / cell
        if fu < 0.0 or fv < 0.0 or fu > nu - 1 or fv > nv - 1:
            out[n] = np.nan
            continue
        i, j, a, b = locate(pu, pv, nu, nv, u0, v0, cell)
        out[n] = bilinear(hgt, i, j, a, b)


@kernel(parallel=True)
def _cast_kernel(orig, dirs, tmin, tmax, cr, sr, hgt, bmax, u0, v0, cell, bs, zlo, zhi, out):
    for n in prange(orig.shape[0]):
        ou = cr * orig[n, 0] + sr * orig[n, 1]
        ov = -sr * orig[n, 0] + cr * orig[n, 1]
        du = cr * dirs[n, 0] + sr * dirs[n, 1]
        dv = -sr * dirs[n, 0] + cr * dirs[n, 1]
        out[n] = first_hit(ou, ov, orig[n, 2], du, dv, dirs[n, 2], tmin[n], tmax[n], hgt, bmax, u0, v0, cell, bs, zlo,
                       zhi)


def surface_height(scene, x, y):
    """Height of the surface (local z) at local ``(x, y)`` (float64 arrays); NaN outside the scene."""
    x = np.ascontiguousarray(x, np.float64)
    y = np.ascontiguousarray(y, np.float64)
    out = np.empty(x.size)
    c, s = scene.rotation
    _heights_kernel(x.ravel(), y.ravel(), c, s, scene.height, scene.u0, scene.v0, scene.cell, out)
    return out.reshape(x.shape)


def cast_rays(scene, origins, directions, tmin=0.0, tmax=np.inf):
    """Distance along each ray (local coordinates, unit directions) to its first surface hit; -1 for a miss.

    Parameters
    ----------
    origins, directions : (N, 3) float64
        Ray origins and **unit** directions, world minus origin.
    tmin, tmax : float or (N,) array
        Search interval along the ray (m).
    """
    o = np.ascontiguousarray(origins, np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(directions, np.float64).reshape(-1, 3)
    n = len(o)
    tmin = np.ascontiguousarray(np.broadcast_to(np.asarray(tmin, np.float64), (n,)))
    tmax = np.ascontiguousarray(np.broadcast_to(np.asarray(tmax, np.float64), (n,)))
    out = np.empty(n)
    _cast_kernel(o, d, tmin, tmax, *scene.kernel_args(), out)
    return out
